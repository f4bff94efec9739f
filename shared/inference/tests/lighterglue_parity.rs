//! LighterGlue export fidelity: our graph cut to 3 layers against the independent
//! `lighterglue_L3.onnx` on consecutive KITTI frame pairs (which applies the mutual check
//! and no confidence threshold, so ours runs with threshold 0 here).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use std::collections::HashSet;
use supermvo_inference::lighterglue::{normalize_keypoints, LightGlue, LightGlueConfig};
use supermvo_inference::runtime::open_session;
use supermvo_inference::xfeat::{XFeat, XFeatConfig};
use supermvo_inference::{Extractor, GrayImage, Matcher};

mod common;

#[test]
fn same_matches_as_independent_l3_export() {
    let Some((shared, m)) = common::setup(&["xfeat", "lighterglue-l3"]) else {
        return;
    };
    let (xfeat_path, l3_path) = (&m[0], &m[1]);
    let mut xfeat = XFeat::new(
        xfeat_path,
        XFeatConfig {
            top_k: 1024,
            ..Default::default()
        },
    )
    .unwrap();
    let mut ours = LightGlue::new(
        l3_path,
        "lighterglue-l3",
        LightGlueConfig {
            threshold: 0.0,
            ..Default::default()
        },
    )
    .unwrap();
    let mut reference = open_session(
        &shared.join("models/reference/lighterglue_L3.onnx"),
        "lighterglue_L3",
        2,
        &["kpts0"],
        &["matches", "scores"],
    )
    .unwrap();
    let (mut total, mut common_total) = (0usize, 0usize);
    for (seq, frame) in [
        ("00", 0),
        ("00", 80),
        ("01", 10),
        ("03", 200),
        ("06", 20),
        ("07", 100),
    ] {
        let load = |i: usize| {
            GrayImage::load(&shared.join(format!("data/kitti/sequences/{seq}/image_0/{i:06}.png")))
                .unwrap()
        };
        let (fa, fb) = (
            xfeat.extract(&load(frame)).unwrap(),
            xfeat.extract(&load(frame + 1)).unwrap(),
        );
        let mine = ours.match_features(&fa, &fb).unwrap();
        let (ka, kb) = (normalize_keypoints(&fa), normalize_keypoints(&fb));
        let out = reference
            .run(ort::inputs![
                "kpts0" => ort::value::TensorRef::from_array_view(([1, fa.len(), 2], &ka[..])).unwrap(),
                "kpts1" => ort::value::TensorRef::from_array_view(([1, fb.len(), 2], &kb[..])).unwrap(),
                "desc0" => ort::value::TensorRef::from_array_view(([1, fa.len(), 64], &fa.descriptors[..])).unwrap(),
                "desc1" => ort::value::TensorRef::from_array_view(([1, fb.len(), 64], &fb.descriptors[..])).unwrap(),
            ])
            .unwrap();
        let (_, m) = out["matches"].try_extract_tensor::<i64>().unwrap();
        let (_, s) = out["scores"].try_extract_tensor::<f32>().unwrap();
        let theirs: Vec<(usize, usize)> = m
            .chunks(2)
            .map(|p| (p[0] as usize, p[1] as usize))
            .collect();
        let set: HashSet<_> = theirs.iter().copied().collect();
        let common = mine.pairs.iter().filter(|p| set.contains(p)).count();
        let denom = mine.pairs.len().max(theirs.len());
        assert!(
            common as f32 >= 0.99 * denom as f32,
            "{seq}/{frame}: {common} common of {} ours, {} reference",
            mine.pairs.len(),
            theirs.len()
        );
        for (k, p) in theirs.iter().enumerate() {
            if let Some(i) = mine.pairs.iter().position(|q| q == p) {
                assert!(
                    (mine.scores[i] - s[k]).abs() < 1e-3,
                    "{seq}/{frame} score of {p:?}: {} vs {}",
                    mine.scores[i],
                    s[k]
                );
            }
        }
        eprintln!(
            "{seq}/{frame:06}: {} matches ours, {} reference, {common} identical",
            mine.pairs.len(),
            theirs.len()
        );
        total += denom;
        common_total += common;
    }
    assert!(
        total > 1000,
        "too few matches overall ({total}) for a meaningful check"
    );
    eprintln!("identical matches: {common_total} of {total}");
}
