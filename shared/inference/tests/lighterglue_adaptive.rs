//! LightGlue's adaptive width (point pruning) and depth (early stopping) in the exported
//! `lighterglue`, on consecutive KITTI frames: the same model run with each switched off and
//! on, and an early stop after three layers against the separately exported 3-layer graph.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use supermvo_inference::lighterglue::{LightGlue, LightGlueConfig};
use supermvo_inference::xfeat::{XFeat, XFeatConfig};
use supermvo_inference::{Extractor, GrayImage, Matcher};

mod common;

#[test]
fn pruning_keeps_the_matches_and_drops_unmatchable_points() {
    let Some((shared, m)) = common::setup(&["xfeat", "lighterglue"]) else {
        return;
    };
    let mut xfeat = XFeat::new(
        &m[0],
        XFeatConfig {
            top_k: 1024,
            ..Default::default()
        },
    )
    .unwrap();
    let open = |width_confidence: f32| {
        LightGlue::new(
            &m[1],
            "lighterglue",
            LightGlueConfig {
                width_confidence,
                ..Default::default()
            },
        )
        .unwrap()
    };
    let (mut full, mut pruned) = (open(-1.0), open(0.95));
    assert!(
        pruned.adaptive(),
        "the default lighterglue export has adaptive width and depth"
    );
    let (mut total, mut common_total, mut kept_total, mut points_total) = (0, 0, 0, 0);
    for (seq, frame) in [("00", 0), ("01", 10), ("03", 200), ("06", 20), ("07", 100)] {
        let load = |i: usize| {
            GrayImage::load(&shared.join(format!("data/kitti/sequences/{seq}/image_0/{i:06}.png")))
                .unwrap()
        };
        let (fa, fb) = (
            xfeat.extract(&load(frame)).unwrap(),
            xfeat.extract(&load(frame + 1)).unwrap(),
        );
        // pruning off: every point reaches the last layer
        let a = full.assignment(&fa, &fb).unwrap();
        assert_eq!(a.layers, 6, "early stopping is off by default");
        assert_eq!(a.kept0, (0..fa.len()).collect::<Vec<_>>());
        assert_eq!(a.kept1, (0..fb.len()).collect::<Vec<_>>());
        // pruning on: fewer points, strictly increasing original indices
        let p = pruned.assignment(&fa, &fb).unwrap();
        assert!(p.kept0.len() < fa.len() && p.kept1.len() < fb.len());
        assert!(p.kept0.windows(2).all(|w| w[0] < w[1]));
        assert!(p.kept1.windows(2).all(|w| w[0] < w[1]));
        let (mf, mp) = (
            full.match_features(&fa, &fb).unwrap(),
            pruned.match_features(&fa, &fb).unwrap(),
        );
        for &(i, j) in &mp.pairs {
            assert!(p.kept0.binary_search(&i).is_ok() && p.kept1.binary_search(&j).is_ok());
        }
        let common = mp.pairs.iter().filter(|q| mf.pairs.contains(q)).count();
        eprintln!(
            "{seq}/{frame:06}: kept {} and {} of {} and {}; matches {} pruned, {} unpruned, {common} in both",
            p.kept0.len(),
            p.kept1.len(),
            fa.len(),
            fb.len(),
            mp.pairs.len(),
            mf.pairs.len()
        );
        total += mf.pairs.len().max(mp.pairs.len());
        common_total += common;
        kept_total += p.kept0.len() + p.kept1.len();
        points_total += fa.len() + fb.len();
    }
    assert!(
        total > 1000,
        "too few matches ({total}) for a meaningful check"
    );
    // pruning removes points the network itself rates unmatchable, so the matches that
    // survive are nearly the same (measured: see docs/models.md, "Speed")
    assert!(
        common_total as f64 >= 0.95 * total as f64,
        "{common_total} of {total} matches in common"
    );
    assert!(
        (kept_total as f64) < 0.9 * points_total as f64,
        "pruning kept {kept_total} of {points_total} points"
    );
}

const DEPTHS: [f32; 8] = [0.3, 0.5, 0.7, 0.8, 0.9, 0.95, 0.99, 0.999];

/// `(depth_confidence, layers that ran, log assignment)` for each of `sessions` (one per
/// value of `DEPTHS`, pruning off).
fn depth_sweep(
    sessions: &mut [LightGlue],
    fa: &supermvo_inference::Features,
    fb: &supermvo_inference::Features,
) -> Vec<(f32, usize, Vec<f32>)> {
    DEPTHS
        .iter()
        .zip(sessions)
        .map(|(&depth, lg)| {
            let a = lg.assignment(fa, fb).unwrap();
            assert_eq!(a.kept0.len(), fa.len(), "pruning is off");
            (depth, a.layers, a.log_assignment)
        })
        .collect()
}

#[test]
fn early_stopping_returns_the_stopping_layers_assignment() {
    let Some((shared, m)) = common::setup(&["xfeat", "lighterglue", "lighterglue-l3"]) else {
        return;
    };
    let mut xfeat = XFeat::new(
        &m[0],
        XFeatConfig {
            top_k: 1024,
            ..Default::default()
        },
    )
    .unwrap();
    let mut l3 = LightGlue::new(&m[2], "lighterglue-l3", LightGlueConfig::default()).unwrap();
    assert!(!l3.adaptive());
    let mut sessions: Vec<LightGlue> = DEPTHS
        .iter()
        .map(|&depth_confidence| {
            LightGlue::new(
                &m[1],
                "lighterglue",
                LightGlueConfig {
                    width_confidence: -1.0,
                    depth_confidence,
                    ..Default::default()
                },
            )
            .unwrap()
        })
        .collect();
    let (mut compared, mut stops) = (0, Vec::new());
    for (seq, frame) in [("00", 0), ("01", 10), ("03", 200), ("06", 20), ("07", 100)] {
        let load = |i: usize| {
            GrayImage::load(&shared.join(format!("data/kitti/sequences/{seq}/image_0/{i:06}.png")))
                .unwrap()
        };
        let (fa, fb) = (
            xfeat.extract(&load(frame)).unwrap(),
            xfeat.extract(&load(frame + 1)).unwrap(),
        );
        let sweep = depth_sweep(&mut sessions, &fa, &fb);
        // a stricter confidence never stops earlier, and no stop happens before layer 1
        assert!(
            sweep.windows(2).all(|w| w[0].1 <= w[1].1),
            "{seq}: {:?}",
            sweep.iter().map(|s| s.1).collect::<Vec<_>>()
        );
        assert!(sweep.iter().all(|s| (1..=6).contains(&s.1)));
        stops.extend(sweep.iter().map(|s| s.1));
        // stopping after three layers gives exactly the 3-layer graph's assignment
        let reference = l3.assignment(&fa, &fb).unwrap().log_assignment;
        for (depth, _, la) in sweep.iter().filter(|s| s.1 == 3) {
            assert_eq!(la.len(), reference.len());
            let diff = la
                .iter()
                .zip(&reference)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(diff < 1e-4, "{seq} depth {depth}: max difference {diff}");
            compared += 1;
        }
    }
    eprintln!("layers run over the sweep: {stops:?}");
    assert!(
        compared > 0,
        "no sweep value stopped after three layers: {stops:?}"
    );
    assert!(
        stops.iter().any(|&s| s < 6) && stops.iter().any(|&s| s > 3),
        "{stops:?}"
    );
}
