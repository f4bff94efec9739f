#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

//! A Sim(3) pose graph undoes the scale drift of monocular odometry around a loop.

use nalgebra::{SMatrix, SVector, Vector3};
use supermvo_optim::lie::{LieGroup, Sim3};
use supermvo_optim::{Between, Lm, LmParams, PoseGraph, Prior};

fn yaw(theta: f64, t: Vector3<f64>) -> Sim3 {
    let xi = SVector::<f64, 7>::from_column_slice(&[0.0, theta, 0.0, 0.0, 0.0, 0.0, 0.0]);
    Sim3 {
        t,
        ..Sim3::exp(&xi)
    }
}

#[test]
fn loop_edge_with_scale_removes_scale_drift() {
    // Ground truth: 40 poses on a circle of radius 20, camera y axis up (as the tracker's).
    let n = 40;
    let truth: Vec<Sim3> = (0..n)
        .map(|k| {
            let a = k as f64 * std::f64::consts::TAU / n as f64;
            yaw(
                -a,
                Vector3::new(20.0 * a.sin(), 0.0, 20.0 * (1.0 - a.cos())),
            )
        })
        .collect();
    // Odometry whose scale shrinks by 2 % per step (0.45x over the loop).
    let mut odom = vec![truth[0]];
    for k in 1..n {
        let rel = truth[k - 1].between(&truth[k]);
        let shrink = 0.98f64.powi(k as i32);
        let rel = Sim3 {
            t: rel.t * shrink,
            ..rel
        };
        odom.push(odom[k - 1].compose(&rel));
    }
    let info = SMatrix::<f64, 7, 7>::from_diagonal(&SVector::<f64, 7>::from_column_slice(&[
        1e4, 1e4, 1e4, 1e2, 1e2, 1e2, 1e3,
    ]));
    let mut graph = PoseGraph::<Sim3, 7>::new((0..n).collect(), odom.clone());
    for k in 1..n {
        let z = odom[k - 1].between(&odom[k]);
        graph
            .between
            .push(Between::new(k - 1, k, z, &info).unwrap());
    }
    // The loop: the last pose seen from the first, with the scale ratio the points give
    // (one odometry unit at the end is 1 / 0.98^39 metres).
    let s_last = 0.98f64.powi(n as i32 - 1);
    let rel = truth[0].between(&truth[n - 1]);
    let z = Sim3 {
        s: 1.0 / s_last,
        ..rel
    };
    graph
        .between
        .push(Between::new(0, n - 1, z, &info).unwrap());
    graph
        .priors
        .push(Prior::with_variances(0, truth[0], &[1e-8; 7]));
    let err = |values: &[Sim3]| {
        values
            .iter()
            .zip(&truth)
            .map(|(a, b)| (a.t - b.t).norm())
            .fold(0.0, f64::max)
    };
    let before = err(&graph.values);
    let summary = Lm::new(&mut graph, LmParams::default()).unwrap().optimize();
    let after = err(&graph.values);
    assert!(
        summary.final_error < summary.initial_error * 1e-2,
        "{summary:?}"
    );
    assert!(before > 10.0, "the drift is visible: {before}");
    assert!(
        after < 0.2 * before,
        "max position error {before:.2} -> {after:.2} m"
    );
}
