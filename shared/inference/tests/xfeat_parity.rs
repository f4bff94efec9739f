//! XFeat fidelity against the independent exports in ../shared/models/reference.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use supermvo_inference::runtime::open_session;
use supermvo_inference::xfeat::{resize_bilinear, XFeat, XFeatConfig};
use supermvo_inference::{Extractor, GrayImage};

mod common;
use common::run;

#[test]
fn raw_outputs_match_independent_export() {
    let Some((shared, m)) = common::setup(&["xfeat"]) else {
        return;
    };
    let ours = &m[0];
    let mut a = open_session(
        ours,
        "xfeat",
        2,
        &["image"],
        &["descriptors", "keypoint_logits", "reliability"],
    )
    .unwrap();
    let mut b = open_session(
        &shared.join("models/reference/n4m_xfeat.onnx"),
        "n4m_xfeat",
        2,
        &["input"],
        &[],
    )
    .unwrap();
    let mut worst = 0.0f32;
    // first and a middle frame of every clip: three image sizes
    for (seq, frame) in [
        ("00", 0),
        ("00", 100),
        ("01", 30),
        ("03", 150),
        ("06", 0),
        ("07", 80),
    ] {
        let img = GrayImage::load(
            &shared.join(format!("data/kitti/sequences/{seq}/image_0/{frame:06}.png")),
        )
        .unwrap();
        let (w, h) = ((img.width / 32) * 32, (img.height / 32) * 32);
        let x = resize_bilinear(&img, w, h);
        let x3: Vec<f32> = x.iter().chain(&x).chain(&x).copied().collect();
        let oa = run(&mut a, "image", [1, 1, h, w], &x);
        let ob = run(&mut b, "input", [1, 3, h, w], &x3);
        for (ta, tb) in oa.iter().zip(&ob) {
            assert_eq!(ta.len(), tb.len());
            let d = ta
                .iter()
                .zip(tb)
                .map(|(p, q)| (p - q).abs())
                .fold(0.0f32, f32::max);
            worst = worst.max(d);
            assert!(d <= 1e-4, "seq {seq} frame {frame}: max abs diff {d}");
        }
    }
    eprintln!("largest raw-output difference vs n4m_xfeat.onnx: {worst:e}");
}

#[test]
fn keypoints_match_independent_end_to_end_export() {
    // xfeat_1024_640x360.onnx includes detection, top-1024 selection and descriptor
    // sampling in the graph; our Rust post-processing must pick the same keypoints.
    let Some((shared, m)) = common::setup(&["xfeat"]) else {
        return;
    };
    let ours = &m[0];
    let full = GrayImage::load(&shared.join("data/kitti/sequences/00/image_0/000010.png")).unwrap();
    // a 360x640 portrait image: 360-pixel-wide crop, stretched vertically
    let (w, h) = (360usize, 640usize);
    let mut data = vec![0u8; w * h];
    for y in 0..h {
        let sy = (y * full.height) / h;
        for x in 0..w {
            data[y * w + x] = full.get(400 + x, sy);
        }
    }
    let img = GrayImage::new(w, h, data).unwrap();
    let mut xfeat = XFeat::new(
        ours,
        XFeatConfig {
            top_k: 1024,
            // the reference export returns integer positions
            subpixel: false,
            ..Default::default()
        },
    )
    .unwrap();
    let f = xfeat.extract(&img).unwrap();
    let mut reference = open_session(
        &shared.join("models/reference/xfeat_1024_640x360.onnx"),
        "ref",
        2,
        &["images"],
        &[],
    )
    .unwrap();
    let x: Vec<f32> = img.data.iter().map(|&v| v as f32).collect();
    let x3: Vec<f32> = x.iter().chain(&x).chain(&x).copied().collect();
    let out = run(&mut reference, "images", [1, 3, h, w], &x3);
    let (kp, desc, scores) = (&out[0], &out[1], &out[2]);
    assert_eq!(kp.len() / 2, f.len());
    // Compare as sets: scores that tie to float precision may come out in either order.
    let mut same = 0;
    for i in 0..f.len() {
        let (rx, ry) = (kp[2 * i], kp[2 * i + 1]);
        let Some(j) = (0..f.len()).find(|&j| {
            (rx - f.keypoints[j][0]).abs() < 1e-3 && (ry - f.keypoints[j][1]).abs() < 1e-3
        }) else {
            continue;
        };
        same += 1;
        assert!(
            (scores[i] - f.scores[j]).abs() < 1e-3,
            "score of ({rx}, {ry}): {} vs {}",
            scores[i],
            f.scores[j]
        );
        let cos: f32 = (0..64).map(|c| desc[64 * i + c] * f.descriptor(j)[c]).sum();
        assert!(cos > 0.9999, "descriptor of ({rx}, {ry}): cosine {cos}");
    }
    assert!(
        same as f32 >= 0.99 * f.len() as f32,
        "only {same} of {} keypoints found in both",
        f.len()
    );
}

/// The optional sub-pixel fit moves the reference's keypoints by at most half a pixel (of
/// the network's input grid) and changes nothing else: same keypoints in the same order,
/// same scores and descriptors; most keypoints do move.
#[test]
fn subpixel_keypoints_refine_the_reference_positions() {
    let Some((shared, m)) = common::setup(&["xfeat"]) else {
        return;
    };
    let img = GrayImage::load(&shared.join("data/kitti/sequences/00/image_0/000000.png")).unwrap();
    let open = |subpixel| {
        XFeat::new(
            &m[0],
            XFeatConfig {
                top_k: 1024,
                subpixel,
                ..Default::default()
            },
        )
        .unwrap()
    };
    let integer = open(false).extract(&img).unwrap();
    let refined = open(true).extract(&img).unwrap();
    assert_eq!(integer.len(), refined.len());
    assert_eq!(integer.scores, refined.scores);
    assert_eq!(integer.descriptors, refined.descriptors);
    // input-grid pixel in image pixels (1241x376 -> 1216x352)
    let (rw, rh) = (img.width as f32 / 1216.0, img.height as f32 / 352.0);
    let mut moved = 0;
    for (a, b) in integer.keypoints.iter().zip(&refined.keypoints) {
        let (dx, dy) = ((b[0] - a[0]) / rw, (b[1] - a[1]) / rh);
        assert!(
            dx.abs() <= 0.5 + 1e-4 && dy.abs() <= 0.5 + 1e-4,
            "{a:?} -> {b:?}"
        );
        if dx != 0.0 || dy != 0.0 {
            moved += 1;
        }
    }
    assert!(
        moved * 2 > refined.len(),
        "only {moved} of {} keypoints moved",
        refined.len()
    );
}
