#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use nalgebra::Vector3;
use std::path::Path;
use supermvo_dataset::GrayImage;
use supermvo_synth::render::CameraModel;
use supermvo_synth::Sequence;

fn camera(scale: f64) -> CameraModel {
    let k = CameraModel::kitti();
    CameraModel {
        width: (k.width as f64 * scale).round() as usize,
        height: (k.height as f64 * scale).round() as usize,
        fx: k.fx * scale,
        fy: k.fy * scale,
        cx: k.cx * scale,
        cy: k.cy * scale,
    }
}

fn files(root: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// One seed gives identical files, whatever the number of rendering threads; another seed
/// gives a different world.
#[test]
fn same_seed_same_files_other_seed_other_images() {
    for preset in ["dynamic", "lighting"] {
        let seq = Sequence::new(preset, 7, Some(6), camera(0.3)).unwrap();
        let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        let wa = seq.write(a.path(), 1, false, &|_| {}).unwrap();
        let wb = seq.write(b.path(), 2, false, &|_| {}).unwrap();
        assert!(!wa.reused && !wb.reused);
        let (fa, fb) = (files(a.path()), files(b.path()));
        assert_eq!(fa.len(), 6 + 4, "6 frames, calib, times, poses, manifest");
        assert_eq!(fa, fb, "{preset}: two renders with one seed differ");
        // Writing again reuses the sequence on disk.
        assert!(seq.write(a.path(), 2, false, &|_| {}).unwrap().reused);
        let other = Sequence::new(preset, 8, Some(6), camera(0.3)).unwrap();
        let c = tempfile::tempdir().unwrap();
        other.write(c.path(), 2, false, &|_| {}).unwrap();
        let frame = format!("sequences/{preset}/image_0/000003.png");
        let img = |root: &Path| std::fs::read(root.join(&frame)).unwrap();
        assert_ne!(
            img(a.path()),
            img(c.path()),
            "{preset}: seeds 7 and 8 rendered the same frame"
        );
    }
}

/// Read back as a KITTI sequence, the ground truth and calibration put known 3D points (the
/// centres of painted lane dashes) on pixels that show paint, at the rendered depth, with
/// asphalt a metre to the side.
#[test]
fn projected_lane_dashes_land_on_painted_pixels() {
    for preset in ["urban-loop", "highway"] {
        let seq = Sequence::new(preset, 3, Some(40), camera(0.5)).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let written = seq.write(dir.path(), 2, false, &|_| {}).unwrap();
        let kitti = supermvo_dataset::Sequence::open(&written.sequence_dir).unwrap();
        let gt = kitti
            .read_ground_truth(&kitti.default_ground_truth().unwrap())
            .unwrap();
        let k = &kitti.calib;
        let dashes = seq.dash_centres();
        let mut checked = 0;
        for i in 0..seq.frames {
            let img = GrayImage::load(&kitti.images[i]).unwrap();
            let depth = seq.render(i).depth;
            let cam_from_gt = gt.poses[i].inverse();
            let project = |p_world: &Vector3<f64>| {
                let q = seq.world_to_ground_truth_frame(p_world);
                let p = cam_from_gt.r * q + cam_from_gt.t;
                let (u, v) = (k.fx * p.x / p.z + k.cx, k.fy * p.y / p.z + k.cy);
                (p.z, u, v)
            };
            for c in &dashes {
                let (z, u, v) = project(c);
                let (x, y) = (u.floor() as i64, v.floor() as i64);
                if !(4.0..15.0).contains(&z)
                    || x < 2
                    || y < 2
                    || x >= img.width as i64 - 2
                    || y >= img.height as i64 - 2
                {
                    continue;
                }
                let (x, y) = (x as usize, y as usize);
                let rendered = depth[y * img.width + x] as f64;
                if (rendered - z).abs() > 0.02 * z {
                    continue; // hidden behind a car
                }
                assert!(
                    img.get(x, y) > 150,
                    "{preset} frame {i}: dash at ({u:.1}, {v:.1}) shows {}",
                    img.get(x, y)
                );
                // A metre across the road, on asphalt (the road runs along the path).
                let (s, _) = seq
                    .preset
                    .scene
                    .path
                    .project(nalgebra::Vector2::new(c.x, c.y));
                let (_, t) = seq.preset.scene.path.at(s);
                let side = c + Vector3::new(-t.y, t.x, 0.0);
                let (zs, us, vs) = project(&side);
                if zs > 1.0
                    && us >= 0.0
                    && vs >= 0.0
                    && (us as usize) < img.width
                    && (vs as usize) < img.height
                {
                    let a = img.get(us as usize, vs as usize);
                    assert!(
                        a < 140,
                        "{preset} frame {i}: asphalt next to the dash shows {a}"
                    );
                }
                checked += 1;
            }
        }
        assert!(
            checked >= 20,
            "{preset}: only {checked} dashes were in view"
        );
    }
}

#[test]
fn bad_requests_are_refused_with_the_reason() {
    let e = Sequence::new("mars", 1, None, camera(0.5))
        .unwrap_err()
        .to_string();
    assert!(e.contains("mars") && e.contains("urban-loop"), "{e}");
    let e = Sequence::new("highway", 1, Some(1), camera(0.5))
        .unwrap_err()
        .to_string();
    assert!(e.contains("--frames"), "{e}");
    // More frames than the highway is long (1.41 km: the car would stand still at its end);
    // the loop takes any number, and a street is built as long as the frames need.
    let e = Sequence::new("highway", 1, Some(3000), camera(0.2))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("--frames 3000") && e.contains("highway") && e.contains("at most"),
        "{e}"
    );
    assert!(Sequence::new("urban-loop", 1, Some(3000), camera(0.2)).is_ok());
    for (frames, metres) in [(500, 500.0), (3000, 2400.0)] {
        let long = Sequence::new("lighting", 1, Some(frames), camera(0.2)).unwrap();
        let (road, drive) = (&long.preset.scene.path, &long.preset.drive);
        let last = drive.arc_length(long.time(frames - 1));
        assert!(
            road.length() >= metres && road.length() >= last + 100.0,
            "{frames} frames: a {:.0} m street for a drive to {last:.0} m",
            road.length()
        );
    }
    // An output root that is a file.
    let f = tempfile::NamedTempFile::new().unwrap();
    let seq = Sequence::new("highway", 1, Some(2), camera(0.2)).unwrap();
    let e = seq
        .write(f.path(), 1, false, &|_| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains(&f.path().display().to_string()), "{e}");
}

#[test]
fn lighting_changes_exposure_and_others_do_not() {
    let lit = Sequence::new("lighting", 1, Some(100), camera(0.2)).unwrap();
    let gains: Vec<f32> = (0..100).map(|i| lit.gain(i)).collect();
    let (lo, hi) = gains
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &g| (a.min(g), b.max(g)));
    assert!(hi / lo > 1.5, "gain only varies from {lo} to {hi}");
    let steady = Sequence::new("dynamic", 1, Some(100), camera(0.2)).unwrap();
    assert!((0..100).all(|i| steady.gain(i) == 1.0));
}
