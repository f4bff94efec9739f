//! `supermvo run` reads its frames from the KITTI layout, an image folder, the EuRoC MAV
//! layout and the TUM RGB-D layout. Each layout is built here from the same 40 frames of
//! KITTI 07 (links to its PNG files, its timestamps, its intrinsics in a camera file), so
//! every layout must give the KITTI run's trajectory bit for bit (ORB front end, in
//! process: no models needed). A JPEG folder cannot be bit-identical; it must track.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use std::path::{Path, PathBuf};

const FRAMES: usize = 40;

/// KITTI 07's first frames as a KITTI sequence; returns its dir, the images and the times.
fn kitti_excerpt(src: &Path, root: &Path) -> (PathBuf, Vec<PathBuf>, Vec<String>) {
    let seq = root.join("kitti/sequences/07");
    std::fs::create_dir_all(seq.join("image_0")).unwrap();
    std::fs::copy(src.join("calib.txt"), seq.join("calib.txt")).unwrap();
    let times: Vec<String> = std::fs::read_to_string(src.join("times.txt"))
        .unwrap()
        .lines()
        .take(FRAMES)
        .map(str::to_string)
        .collect();
    std::fs::write(seq.join("times.txt"), times.join("\n") + "\n").unwrap();
    let mut images = Vec::new();
    for i in 0..FRAMES {
        let from = src.join(format!("image_0/{i:06}.png"));
        std::os::unix::fs::symlink(&from, seq.join(format!("image_0/{i:06}.png"))).unwrap();
        images.push(from);
    }
    (seq, images, times)
}

fn trajectory(seq: &Path, out: &Path, extra: &[&str]) -> String {
    let r = common::supermvo(
        &[
            &[
                "run",
                seq.to_str().unwrap(),
                "--mode",
                "inprocess",
                "--frontend",
                "orb",
                "-q",
                "--out",
                out.to_str().unwrap(),
            ][..],
            extra,
        ]
        .concat(),
    );
    assert!(
        r.status.success(),
        "{}: {}",
        seq.display(),
        String::from_utf8_lossy(&r.stderr)
    );
    std::fs::read_to_string(out.join("trajectory.tum.txt")).unwrap()
}

#[test]
fn every_input_layout_gives_the_kitti_runs_trajectory() {
    let Some(src) = common::shared_data("kitti/sequences/07") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let (kitti, images, times) = kitti_excerpt(&src, root);
    let reference = trajectory(&kitti, &root.join("out/kitti"), &[]);
    assert!(reference.lines().count() >= FRAMES * 9 / 10, "{reference}");

    // an image folder, names unpadded so that text order (frame_10 before frame_2) is wrong,
    // with times.txt and camera.yaml beside the frames
    let folder = root.join("folder");
    std::fs::create_dir_all(&folder).unwrap();
    for (i, img) in images.iter().enumerate() {
        std::os::unix::fs::symlink(img, folder.join(format!("frame_{i}.png"))).unwrap();
    }
    std::fs::write(folder.join("times.txt"), times.join("\n") + "\n").unwrap();
    std::fs::write(folder.join("camera.yaml"), common::kitti_camera_yaml(&src)).unwrap();
    assert_eq!(
        trajectory(&folder, &root.join("out/folder"), &[]),
        reference
    );

    // EuRoC MAV: mav0/cam0/data.csv (nanoseconds) and sensor.yaml
    let cam0 = root.join("euroc/mav0/cam0");
    std::fs::create_dir_all(cam0.join("data")).unwrap();
    let mut csv = String::from("#timestamp [ns],filename\n");
    for (img, t) in images.iter().zip(&times) {
        let ns = (t.trim().parse::<f64>().unwrap() * 1e9).round() as u64;
        std::os::unix::fs::symlink(img, cam0.join(format!("data/{ns}.png"))).unwrap();
        csv.push_str(&format!("{ns},{ns}.png\n"));
    }
    std::fs::write(cam0.join("data.csv"), csv).unwrap();
    let calib = supermvo_dataset::Calibration::read_kitti(&src.join("calib.txt")).unwrap();
    let (w, h) = image::image_dimensions(&images[0]).unwrap();
    std::fs::write(
        cam0.join("sensor.yaml"),
        format!(
            "%YAML:1.0\nresolution: [{w}, {h}]\ncamera_model: pinhole\nintrinsics: [{}, {}, {}, {}]\n\
             distortion_model: radial-tangential\ndistortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n",
            calib.fx, calib.fy, calib.cx, calib.cy
        ),
    )
    .unwrap();
    let euroc = trajectory(&root.join("euroc"), &root.join("out/euroc"), &[]);
    // the same poses; the stamps went through nanoseconds
    let poses = |t: &str| -> Vec<String> {
        t.lines()
            .map(|l| l.split_whitespace().skip(1).collect::<Vec<_>>().join(" "))
            .collect()
    };
    assert_eq!(poses(&euroc), poses(&reference));

    // TUM RGB-D: rgb.txt and rgb/, the camera file given with --camera
    let tum = root.join("tum");
    std::fs::create_dir_all(tum.join("rgb")).unwrap();
    let mut list = String::from("# color images\n# timestamp filename\n");
    for (i, (img, t)) in images.iter().zip(&times).enumerate() {
        std::os::unix::fs::symlink(img, tum.join(format!("rgb/{i}.png"))).unwrap();
        list.push_str(&format!("{} rgb/{i}.png\n", t.trim()));
    }
    std::fs::write(tum.join("rgb.txt"), list).unwrap();
    let cam = root.join("kitti07.yaml");
    std::fs::write(&cam, common::kitti_camera_yaml(&src)).unwrap();
    let tum_traj = trajectory(
        &tum,
        &root.join("out/tum"),
        &["--camera", cam.to_str().unwrap()],
    );
    assert_eq!(poses(&tum_traj), poses(&reference));

    // TUM monoVO: images/, times.txt ("id time exposure"), camera.txt with the intrinsics
    // relative to the image size (DSO's convention, half a pixel off) and omega 0 (pinhole)
    let mono = root.join("monovo");
    std::fs::create_dir_all(mono.join("images")).unwrap();
    let mut list = String::new();
    for (i, (img, t)) in images.iter().zip(&times).enumerate() {
        std::os::unix::fs::symlink(img, mono.join(format!("images/{i:05}.png"))).unwrap();
        list.push_str(&format!("{i:05} {} 10.0\n", t.trim()));
    }
    std::fs::write(mono.join("times.txt"), list).unwrap();
    let (wf, hf) = (w as f64, h as f64);
    std::fs::write(
        mono.join("camera.txt"),
        format!(
            "FOV {} {} {} {} 0\n{w} {h}\ncrop\n{w} {h}\n",
            calib.fx / wf,
            calib.fy / hf,
            (calib.cx + 0.5) / wf,
            (calib.cy + 0.5) / hf
        ),
    )
    .unwrap();
    let mono_traj = trajectory(&mono, &root.join("out/monovo"), &[]);
    // the intrinsics went through a division and back: equal poses to rounding
    let values =
        |t: &str| -> Vec<f64> { t.split_whitespace().map(|v| v.parse().unwrap()).collect() };
    let (a, b) = (values(&mono_traj), values(&reference));
    assert_eq!(a.len(), b.len(), "{mono_traj}");
    assert!(
        a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-6),
        "{mono_traj}"
    );

    // without a camera file, a TUM folder is refused with what to do
    std::fs::remove_file(&cam).unwrap();
    common::expect_error(
        &[
            "run",
            tum.to_str().unwrap(),
            "--mode",
            "inprocess",
            "--frontend",
            "orb",
        ],
        &["needs a camera file", "--camera"],
    );
}

/// The same frames as JPEG (lossy, so not bit-identical) track as the PNG run does.
#[test]
fn a_jpeg_folder_tracks() {
    let Some(src) = common::shared_data("kitti/sequences/07") else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let folder = tmp.path().join("jpeg");
    std::fs::create_dir_all(&folder).unwrap();
    for i in 0..FRAMES {
        let img = image::open(src.join(format!("image_0/{i:06}.png")))
            .unwrap()
            .to_luma8();
        img.save(folder.join(format!("{i}.jpg"))).unwrap();
    }
    std::fs::write(folder.join("camera.yaml"), common::kitti_camera_yaml(&src)).unwrap();
    let traj = trajectory(&folder, &tmp.path().join("out"), &[]);
    // no times.txt: 10 Hz assumed
    let first = traj
        .lines()
        .next()
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap();
    assert_eq!(first.parse::<f64>().unwrap(), 0.0);
    assert!(traj.lines().count() >= FRAMES * 9 / 10, "{traj}");
}

/// A video of the same frames, decoded by ffmpeg: losslessly encoded (FFV1, grey) it gives
/// the KITTI run's poses bit for bit, at the video's presentation times; as H.264 (lossy,
/// what cameras write) it tracks. The camera file lies beside the video, named after it.
#[test]
fn a_video_gives_the_kitti_runs_trajectory() {
    let Some(src) = common::shared_data("kitti/sequences/07") else {
        return;
    };
    if !common::ffmpeg_ready() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let (kitti, _, _) = kitti_excerpt(&src, root);
    let reference = trajectory(&kitti, &root.join("out/kitti"), &[]);
    let poses = |t: &str| -> Vec<String> {
        t.lines()
            .map(|l| l.split_whitespace().skip(1).collect::<Vec<_>>().join(" "))
            .collect()
    };
    let stamps = |t: &str| -> Vec<f64> {
        t.lines()
            .map(|l| l.split_whitespace().next().unwrap().parse().unwrap())
            .collect()
    };

    let lossless = root.join("clip.mkv");
    common::encode_video(&kitti, &lossless, &["-c:v", "ffv1", "-pix_fmt", "gray"]);
    std::fs::write(root.join("clip.yaml"), common::kitti_camera_yaml(&src)).unwrap();
    let video = trajectory(&lossless, &root.join("out/ffv1"), &[]);
    assert_eq!(poses(&video), poses(&reference));
    // presentation times of a 10 frames/s video
    let kitti_frames: Vec<usize> = stamps(&reference)
        .iter()
        .map(|t| {
            let all: Vec<f64> = std::fs::read_to_string(kitti.join("times.txt"))
                .unwrap()
                .lines()
                .map(|l| l.trim().parse().unwrap())
                .collect();
            all.iter().position(|x| (x - t).abs() < 1e-9).unwrap()
        })
        .collect();
    for (t, i) in stamps(&video).iter().zip(kitti_frames) {
        assert!((t - i as f64 * 0.1).abs() < 1e-6, "frame {i} at {t}");
    }

    let h264 = root.join("clip.mp4");
    common::encode_video(
        &kitti,
        &h264,
        &["-c:v", "libx264", "-crf", "18", "-pix_fmt", "yuv420p"],
    );
    let cam = root.join("kitti07.yaml");
    std::fs::write(&cam, common::kitti_camera_yaml(&src)).unwrap();
    let lossy = trajectory(
        &h264,
        &root.join("out/h264"),
        &["--camera", cam.to_str().unwrap()],
    );
    assert!(lossy.lines().count() >= FRAMES * 9 / 10, "{lossy}");

    // a video without a camera file is refused with what to do; a file that is not a video
    // is one clear error naming it
    std::fs::rename(&h264, root.join("other.mp4")).unwrap();
    let other = root.join("other.mp4");
    common::expect_error(
        &[
            "run",
            other.to_str().unwrap(),
            "--mode",
            "inprocess",
            "--frontend",
            "orb",
        ],
        &["other.mp4", "needs a camera file", "--camera"],
    );
    let broken = root.join("broken.mp4");
    std::fs::write(&broken, b"not a video").unwrap();
    std::fs::write(root.join("broken.yaml"), common::kitti_camera_yaml(&src)).unwrap();
    common::expect_error(
        &[
            "run",
            broken.to_str().unwrap(),
            "--mode",
            "inprocess",
            "--frontend",
            "orb",
        ],
        &["broken.mp4", "not a readable video"],
    );
}
