//! Robust kernels against a false loop closure, and the anchor requirement.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use nalgebra::{SMatrix, SVector};
use supermvo_optim::lie::{LieGroup, Se2};
use supermvo_optim::{Between, Kernel, Lm, LmParams, PoseGraph, Prior, PRIOR_VARIANCES_SE2};

/// A square loop of 40 poses with odometry and one true loop closure, plus one false loop
/// closure that claims pose 10 sits on top of pose 30 (they are 10 m apart).
fn square_with_false_loop(kernel: Kernel) -> (PoseGraph<Se2, 3>, Vec<Se2>) {
    let mut truth = Vec::new();
    for k in 0..40 {
        let side = k / 10;
        let s = (k % 10) as f64;
        let p = match side {
            0 => Se2::new(s, 0.0, 0.0),
            1 => Se2::new(10.0, s, std::f64::consts::FRAC_PI_2),
            2 => Se2::new(10.0 - s, 10.0, std::f64::consts::PI),
            _ => Se2::new(0.0, 10.0 - s, -std::f64::consts::FRAC_PI_2),
        };
        truth.push(p);
    }
    let info = SMatrix::<f64, 3, 3>::from_diagonal(&SVector::<f64, 3>::new(100.0, 100.0, 1000.0));
    // initial values: odometry with a small systematic heading drift
    let drift = Se2::new(0.0, 0.0, 0.01);
    let mut init = vec![truth[0]];
    let mut g = PoseGraph::new((0..40).collect(), Vec::new());
    for k in 1..40 {
        let z = truth[k - 1].between(&truth[k]);
        g.between.push(Between::new(k - 1, k, z, &info).unwrap());
        let prev = init[k - 1];
        init.push(prev.compose(&z).compose(&drift));
    }
    g.between
        .push(Between::new(39, 0, truth[39].between(&truth[0]), &info).unwrap());
    g.between
        .push(Between::new(10, 30, Se2::new(0.0, 0.0, 0.0), &info).unwrap());
    for f in &mut g.between {
        f.kernel = kernel;
    }
    g.values = init;
    g.priors
        .push(Prior::with_variances(0, truth[0], &PRIOR_VARIANCES_SE2));
    (g, truth)
}

fn rmse(values: &[Se2], truth: &[Se2]) -> f64 {
    (values
        .iter()
        .zip(truth)
        .map(|(a, b)| (a.x - b.x).powi(2) + (a.y - b.y).powi(2))
        .sum::<f64>()
        / values.len() as f64)
        .sqrt()
}

#[test]
fn cauchy_and_huber_resist_a_false_loop() {
    let mut results = Vec::new();
    for kernel in [Kernel::None, Kernel::Huber(1.0), Kernel::Cauchy(1.0)] {
        let (mut g, truth) = square_with_false_loop(kernel);
        Lm::new(&mut g, LmParams::default()).unwrap().optimize();
        results.push(rmse(&g.values, &truth));
    }
    let (plain, huber, cauchy) = (results[0], results[1], results[2]);
    eprintln!("rmse: plain {plain}, huber {huber}, cauchy {cauchy}");
    assert!(
        plain > 1.0,
        "the false loop should distort the plain least-squares solution (rmse {plain})"
    );
    assert!(
        cauchy < 0.05,
        "Cauchy should ignore the false loop (rmse {cauchy})"
    );
    // Huber bounds the false edge's influence (constant pull k in whitened units) but does
    // not remove it: the 20-edge chain between the two poses still yields to that pull.
    assert!(
        huber < plain,
        "Huber should limit the damage (rmse {huber} vs {plain})"
    );
    assert!(
        huber > cauchy,
        "a redescending kernel (Cauchy) should do better than Huber here"
    );
}

#[test]
fn graph_without_anchor_is_refused() {
    let (mut g, _) = square_with_false_loop(Kernel::None);
    g.priors.clear();
    let err = Lm::new(&mut g, LmParams::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("no prior"), "{err}");
}

#[test]
fn step_and_error_allow_a_budgeted_run() {
    let (mut g, _) = square_with_false_loop(Kernel::Cauchy(1.0));
    let mut lm = Lm::new(&mut g, LmParams::default()).unwrap();
    let mut errors = vec![lm.error()];
    for _ in 0..3 {
        if !lm.step() {
            break;
        }
        errors.push(lm.error());
    }
    assert!(
        errors.windows(2).all(|w| w[1] <= w[0]),
        "error must not increase: {errors:?}"
    );
    assert!(errors.len() >= 2);
}
