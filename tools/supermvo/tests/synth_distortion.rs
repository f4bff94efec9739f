//! Lens distortion with exact ground truth: the synthetic `dynamic` preset rendered through a
//! radial-tangential, an equidistant (fisheye) and a field-of-view lens (`supermvo synth
//! --distortion`, which writes the lens to `camera.yaml`), tracked with the lens model (the
//! default `undistort = "keypoints"`: keypoints found on the frames as rendered, then
//! undistorted) and, for comparison, as if the camera were a pinhole (`--camera` with the
//! intrinsics only). With the model the run must track every frame the pinhole rendering
//! tracks and stay within 10 % of its APE (issue 23); without it the APE must be at least 4x
//! the modelled run's. Measured: 0.80x, 0.85x and 0.82x the pinhole's APE (better than the
//! pinhole rendering itself; not analysed: the lenses magnify the image centre, where the
//! road's far landmarks are); remapping the frames instead (`undistort = "images"`, a second
//! resampling) gave 0.98x and 1.12x for the first two: docs/results.md. The daemon, which undistorts in its features process,
//! gives the in-process poses byte for byte (radial-tangential lens).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use std::path::Path;

const FRAMES: &str = "120";

fn render(root: &Path, lens: &str) -> std::path::PathBuf {
    let r = common::supermvo(&[
        "synth",
        "--preset",
        "dynamic",
        "--frames",
        FRAMES,
        "--distortion",
        lens,
        "-q",
        "--out",
        root.join(lens).to_str().unwrap(),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    root.join(lens).join("sequences/dynamic")
}

/// `(frames posed, APE RMSE)` of a run.
fn run(seq: &Path, out: &Path, extra: &[&str]) -> (u64, f64) {
    let report = common::run_inprocess(seq, out, extra);
    let ape = report["eval"]["ape"]["trans"]["rmse"].as_f64().unwrap();
    (report["estimated"].as_u64().unwrap(), ape)
}

#[test]
fn distorted_renderings_track_with_the_lens_model_and_not_without() {
    if !common::models_ready() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let pinhole = render(root, "none");
    let (posed, ape) = run(&pinhole, &root.join("out/none"), &[]);
    println!("pinhole: {posed} posed, APE {ape:.3} m");
    let intrinsics_only = root.join("pinhole.yaml");
    let calib = supermvo_dataset::Calibration::read_kitti(&pinhole.join("calib.txt")).unwrap();
    std::fs::write(
        &intrinsics_only,
        format!(
            "Camera.fx: {}\nCamera.fy: {}\nCamera.cx: {}\nCamera.cy: {}\n",
            calib.fx, calib.fy, calib.cx, calib.cy
        ),
    )
    .unwrap();
    for lens in ["radtan", "fisheye", "fov"] {
        let seq = render(root, lens);
        assert!(seq.join("camera.yaml").is_file());
        let (p, a) = run(&seq, &root.join(format!("out/{lens}")), &[]);
        let raw = ["--camera", intrinsics_only.to_str().unwrap()];
        let (pr, ar) = run(&seq, &root.join(format!("out/{lens}-raw")), &raw);
        println!(
            "{lens}: {p} posed, APE {a:.3} m ({:.2}x the pinhole's); without the model {pr} posed, {ar:.3} m ({:.1}x)",
            a / ape,
            ar / a
        );
        assert!(
            p >= posed,
            "{lens}: {p} posed, the pinhole rendering {posed}"
        );
        assert!(
            a < 1.1 * ape,
            "{lens}: {a:.3} m, the pinhole rendering {ape:.3} m"
        );
        assert!(
            ar > 4.0 * a,
            "{lens}: without the model {ar:.3} m, with {a:.3} m"
        );
        if lens == "radtan" {
            // the daemon undistorts in its features process: the same poses, byte for byte
            let out = root.join("out/radtan-daemon");
            let name = format!("lens-{}", std::process::id());
            let r = common::supermvo(&[
                "run",
                seq.to_str().unwrap(),
                "--mode",
                "multiprocess",
                "--name",
                &name,
                "-q",
                "--out",
                out.to_str().unwrap(),
            ]);
            assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
            let read = |dir: &Path| std::fs::read(dir.join("trajectory.kitti.txt")).unwrap();
            assert!(
                read(&out) == read(&root.join("out/radtan")),
                "the daemon's trajectory differs from the in-process one"
            );
        }
    }
}
