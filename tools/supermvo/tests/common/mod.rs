//! Helpers shared by the CLI end-to-end tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The workspace root.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// `../shared/data/<sub>` if present. When absent, prints why and returns `None` (the test
/// then skips), unless `SUPERMVO_REQUIRE_SHARED=1`, in which case the test fails.
pub fn shared_data(sub: &str) -> Option<PathBuf> {
    let base = std::env::var_os("SUPERMVO_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("../shared"));
    let p = base.join("data").join(sub);
    if p.exists() {
        return Some(p);
    }
    if std::env::var("SUPERMVO_REQUIRE_SHARED").as_deref() == Ok("1") {
        panic!("{} is missing and SUPERMVO_REQUIRE_SHARED=1", p.display());
    }
    eprintln!(
        "SKIP: {} not found (set SUPERMVO_SHARED or place the shared data beside the repo)",
        p.display()
    );
    None
}

/// Runs the `supermvo` binary.
pub fn supermvo(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .args(args)
        .output()
        .expect("run supermvo")
}

/// Runs `supermvo` and expects failure with one clear error line containing every `needle`.
pub fn expect_error(args: &[&str], needles: &[&str]) {
    let out = supermvo(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "expected failure for {args:?}");
    assert_eq!(
        out.status.code(),
        Some(2),
        "clean error exit, not a panic: {stderr}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    for n in needles {
        assert!(stderr.contains(n), "stderr lacks '{n}':\n{stderr}");
    }
}

/// A valid 8-bit grayscale PNG of a gradient (stored deflate blocks, no image library).
pub fn gradient_png(w: u32, h: u32) -> Vec<u8> {
    fn crc(data: &[u8]) -> u32 {
        let mut c = 0xffff_ffffu32;
        for &b in data {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    0xedb8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
        }
        !c
    }
    fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
        out.extend((data.len() as u32).to_be_bytes());
        let mut body = kind.to_vec();
        body.extend(data);
        out.extend(&body);
        out.extend(crc(&body).to_be_bytes());
    }
    let mut raw = Vec::new();
    for y in 0..h {
        raw.push(0u8);
        raw.extend((0..w).map(|x| ((x * 13 + y * 7) % 256) as u8));
    }
    let (mut a, mut b) = (1u32, 0u32);
    for &v in &raw {
        a = (a + v as u32) % 65521;
        b = (b + a) % 65521;
    }
    let mut z = vec![0x78, 0x01, 0x01];
    z.extend((raw.len() as u16).to_le_bytes());
    z.extend((!(raw.len() as u16)).to_le_bytes());
    z.extend(&raw);
    z.extend(((b << 16) | a).to_be_bytes());
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend(w.to_be_bytes());
    ihdr.extend(h.to_be_bytes());
    ihdr.extend([8, 0, 0, 0, 0]);
    chunk(&mut png, b"IHDR", &ihdr);
    chunk(&mut png, b"IDAT", &z);
    chunk(&mut png, b"IEND", &[]);
    png
}

/// supermvo's cache, as the product resolves it.
pub use supermvo_inference::runtime::cache_dir;
/// The ONNX Runtime library `supermvo models fetch onnxruntime` unpacks into the cache.
pub use supermvo_inference::runtime::default_library_path as runtime_library;

/// `supermvo run SEQ --mode inprocess -q --frontend FRONTEND` with the model cache at `cache`
/// (ONNX Runtime from the usual cache), output in `cache/out`.
pub fn run_frontend_with_cache(cache: &Path, seq: &Path, frontend: &str, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .arg("run")
        .arg(seq)
        .args(["--mode", "inprocess", "-q", "--frontend", frontend])
        .arg("--out")
        .arg(cache.join("out"))
        .args(extra)
        .env("SUPERMVO_CACHE", cache)
        .env("ORT_DYLIB_PATH", runtime_library())
        .output()
        .unwrap()
}

/// Whether ONNX Runtime and the default models are in the cache; when not, prints why (the
/// test then skips), unless `SUPERMVO_REQUIRE_SHARED=1`, in which case it fails.
pub fn models_ready() -> bool {
    models_ready_for(&["xfeat", "lighterglue"])
}

/// ONNX Runtime and the cached models `names` are there (skip, or fail when
/// `SUPERMVO_REQUIRE_SHARED=1`, otherwise).
pub fn models_ready_for(names: &[&str]) -> bool {
    let home = cache_dir();
    let ok = runtime_library().is_file()
        && names
            .iter()
            .all(|n| home.join(format!("models/{n}.onnx")).is_file());
    if !ok {
        assert!(
            std::env::var("SUPERMVO_REQUIRE_SHARED").as_deref() != Ok("1"),
            "run 'supermvo models fetch' first ({names:?} needed)"
        );
        eprintln!("SKIP: models {names:?} not fetched");
    }
    ok
}

/// Renders synthetic preset `preset` (default frames, seed 1) under `root`; returns the
/// sequence directory.
pub fn synth(root: &Path, preset: &str) -> PathBuf {
    let r = supermvo(&[
        "synth",
        "--preset",
        preset,
        "-q",
        "--out",
        root.to_str().expect("utf-8 path"),
    ]);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    root.join("sequences").join(preset)
}

/// `supermvo run SEQ --mode inprocess -q --out OUT EXTRA...`, which must succeed; returns
/// its report.
pub fn run_inprocess(seq: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    run_inprocess_with_env(seq, out, extra, &[])
}

/// [`run_inprocess`] with the environment variables `env` set for the run.
pub fn run_inprocess_with_env(
    seq: &Path,
    out: &Path,
    extra: &[&str],
    env: &[(&str, &Path)],
) -> serde_json::Value {
    let r = Command::new(env!("CARGO_BIN_EXE_supermvo"))
        .arg("run")
        .arg(seq)
        .args(["--mode", "inprocess", "-q", "--out"])
        .arg(out)
        .args(extra)
        .envs(env.iter().copied())
        .output()
        .expect("run supermvo");
    assert!(
        r.status.success(),
        "{}: {}",
        seq.display(),
        String::from_utf8_lossy(&r.stderr)
    );
    let text = std::fs::read_to_string(out.join("report.json")).expect("report.json");
    serde_json::from_str(&text).expect("report.json is JSON")
}

/// `ffmpeg -framerate 10 -i SEQ/image_0/%06d.png ARGS... OUT`: a KITTI sequence's frames as
/// a video, which must succeed.
pub fn encode_video(seq: &Path, out: &Path, args: &[&str]) {
    let r = Command::new("ffmpeg")
        .args([
            "-hide_banner",
            "-loglevel",
            "error",
            "-y",
            "-framerate",
            "10",
            "-i",
        ])
        .arg(seq.join("image_0/%06d.png"))
        .args(args)
        .arg(out)
        .output()
        .expect("run ffmpeg");
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
}

/// The folder `tools/python_tools.sh` installs the independent Python readers into (for
/// `PYTHONPATH`); when they are not installed, prints why and returns `None` (the test then
/// skips), unless `SUPERMVO_REQUIRE_SHARED=1`, in which case the test fails.
pub fn python_tools() -> Option<PathBuf> {
    let dir = cache_dir().join("python-tools");
    if dir.join(".pins").is_file() {
        return Some(dir);
    }
    assert!(
        std::env::var("SUPERMVO_REQUIRE_SHARED").as_deref() != Ok("1"),
        "{} is missing: run 'bash tools/python_tools.sh' (tools/test.sh does)",
        dir.display()
    );
    eprintln!(
        "SKIP: Python readers not installed ({}); run 'bash tools/python_tools.sh'",
        dir.display()
    );
    None
}

/// Whether the `ffmpeg` program runs (video input); when not, prints why (the test then
/// skips), unless `SUPERMVO_REQUIRE_SHARED=1`, in which case the test fails.
pub fn ffmpeg_ready() -> bool {
    let ok = Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var("SUPERMVO_REQUIRE_SHARED").as_deref() != Ok("1"),
            "ffmpeg is missing: run 'bash tools/setup.sh' (it installs Debian's ffmpeg)"
        );
        eprintln!("SKIP: ffmpeg not installed (bash tools/setup.sh installs it)");
    }
    ok
}

/// The intrinsics of a KITTI sequence's `calib.txt` (in `seq`) as an ORB-SLAM3-style camera
/// file, for the same frames read as an image folder or a video.
pub fn kitti_camera_yaml(seq: &Path) -> String {
    let calib = supermvo_dataset::Calibration::read_kitti(&seq.join("calib.txt")).unwrap();
    format!(
        "%YAML:1.0\nCamera.type: \"PinHole\"\nCamera.fx: {}\nCamera.fy: {}\nCamera.cx: {}\nCamera.cy: {}\n\
         Camera.k1: 0.0\nCamera.k2: 0.0\nCamera.p1: 0.0\nCamera.p2: 0.0\n",
        calib.fx, calib.fy, calib.cx, calib.cy
    )
}

/// The 12 numbers of every row of a KITTI trajectory file, exactly as written.
pub fn kitti_rows(path: &Path) -> Vec<Vec<f64>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect()
}

/// What `python3 tools/SCRIPT ARGS` (one of the independent readers, with the pinned
/// packages of [`python_tools`] on `pythonpath`) prints, as JSON; it must succeed.
pub fn python_tool_json<S: AsRef<std::ffi::OsStr>>(
    pythonpath: &Path,
    script: &str,
    args: &[S],
) -> serde_json::Value {
    let out = Command::new("python3")
        .arg(root().join("tools").join(script))
        .args(args)
        .env("PYTHONPATH", pythonpath)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{script}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// `tools/read_mcap.py FILE` (the independent MCAP reader) as JSON.
pub fn read_mcap(pythonpath: &Path, file: &Path) -> serde_json::Value {
    python_tool_json(pythonpath, "read_mcap.py", &[file])
}
