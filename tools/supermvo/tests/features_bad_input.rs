//! Bad input to the learned front end: one clear error saying what to run, never a panic.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn cache_models() -> Option<(PathBuf, PathBuf)> {
    let (lib, model) = (
        common::runtime_library(),
        common::cache_dir().join("models/xfeat.onnx"),
    );
    if lib.is_file() && model.is_file() {
        return Some((lib, model));
    }
    assert!(
        std::env::var("SUPERMVO_REQUIRE_SHARED").as_deref() != Ok("1"),
        "run 'supermvo models fetch onnxruntime xfeat' first"
    );
    eprintln!("SKIP: ONNX Runtime or xfeat model not fetched");
    None
}

fn frame() -> Option<PathBuf> {
    common::shared_data("kitti/sequences/00/image_0/000000.png")
}

fn features(env: &[(&str, &str)], args: &[&str]) -> (bool, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_supermvo"));
    cmd.arg("features").args(args);
    for (k, v) in env {
        cmd.env(k, v);
    }
    let out = cmd.output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!err.contains("panicked"), "{err}");
    (out.status.success(), err)
}

#[test]
fn runtime_missing_or_wrong() {
    let Some(img) = frame() else { return };
    let img = img.to_str().unwrap();
    let (ok, err) = features(
        &[("ORT_DYLIB_PATH", "/nonexistent/libonnxruntime.so")],
        &[img],
    );
    assert!(!ok);
    assert!(
        err.contains("ONNX Runtime library not found at /nonexistent/libonnxruntime.so")
            && err.contains("supermvo models fetch onnxruntime"),
        "{err}"
    );
    // a shared library that is not ONNX Runtime
    let libc = [
        "/lib/x86_64-linux-gnu/libc.so.6",
        "/lib/aarch64-linux-gnu/libc.so.6",
        "/usr/lib/libc.so.6",
    ]
    .into_iter()
    .find(|p| Path::new(p).exists());
    if let Some(libc) = libc {
        let (ok, err) = features(&[("ORT_DYLIB_PATH", libc)], &[img]);
        assert!(!ok);
        assert!(
            err.contains("cannot use ONNX Runtime") && err.contains("OrtGetApiBase"),
            "{err}"
        );
    }
}

/// A library that answers ONNX Runtime's version query as 1.16.3 does: `OrtGetApiBase`
/// returns a table whose `GetApi` has no table for a newer API and whose
/// `GetVersionString` says "1.16.3" (what an old libonnxruntime.so found through
/// ORT_DYLIB_PATH does), built with the C compiler that tools/setup.sh installs.
#[test]
fn runtime_too_old() {
    let Some(img) = frame() else { return };
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("old_ort.c");
    std::fs::write(
        &src,
        "typedef struct { const void *(*get_api)(unsigned); const char *(*version)(void); } ApiBase;\n\
         static const void *get_api(unsigned v) { (void)v; return 0; }\n\
         static const char *version(void) { return \"1.16.3\"; }\n\
         static const ApiBase base = { get_api, version };\n\
         const ApiBase *OrtGetApiBase(void) { return &base; }\n",
    )
    .unwrap();
    let lib = dir.path().join("libonnxruntime.so.1.16.3");
    let built = Command::new("cc")
        .args(["-shared", "-fPIC", "-o"])
        .arg(&lib)
        .arg(&src)
        .status();
    if !matches!(built, Ok(s) if s.success()) {
        assert!(
            std::env::var("SUPERMVO_REQUIRE_SHARED").as_deref() != Ok("1"),
            "no C compiler: run tools/setup.sh"
        );
        eprintln!("SKIP: no C compiler to build the stand-in library");
        return;
    }
    let (ok, err) = features(
        &[("ORT_DYLIB_PATH", lib.to_str().unwrap())],
        &[img.to_str().unwrap()],
    );
    assert!(!ok);
    assert!(
        err.contains("cannot use ONNX Runtime")
            && err.contains("but got '1.16.3'")
            && err.contains("supermvo models fetch onnxruntime"),
        "{err}"
    );
    assert_eq!(
        err.lines().filter(|l| !l.trim().is_empty()).count(),
        1,
        "one error line: {err}"
    );
}

#[test]
fn model_missing_corrupt_or_wrong_interface() {
    let (Some(img), Some(_)) = (frame(), cache_models()) else {
        return;
    };
    let img = img.to_str().unwrap();
    let d = tempfile::tempdir().unwrap();
    let missing = d.path().join("nope.onnx");
    let (ok, err) = features(&[], &[img, "--model", missing.to_str().unwrap()]);
    assert!(
        !ok && err.contains("nope.onnx not found") && err.contains("supermvo models fetch xfeat"),
        "{err}"
    );
    let corrupt = d.path().join("corrupt.onnx");
    std::fs::write(&corrupt, b"this is not a protobuf").unwrap();
    let (ok, err) = features(&[], &[img, "--model", corrupt.to_str().unwrap()]);
    assert!(!ok && err.contains("corrupt or not an ONNX model"), "{err}");
    if let Some(wrong) = common::shared_data("../models/reference/lighterglue_L3.onnx") {
        let (ok, err) = features(&[], &[img, "--model", wrong.to_str().unwrap()]);
        assert!(
            !ok && err.contains("does not have the interface of xfeat") && err.contains("kpts0"),
            "{err}"
        );
    }
}

#[test]
fn empty_or_tiny_image() {
    let Some(_) = cache_models() else { return };
    let d = tempfile::tempdir().unwrap();
    let empty = d.path().join("empty.png");
    std::fs::write(&empty, b"").unwrap();
    let (ok, err) = features(&[], &[empty.to_str().unwrap()]);
    assert!(
        !ok && err.contains("empty.png") && err.contains("unreadable image"),
        "{err}"
    );
    let tiny = d.path().join("tiny.png");
    std::fs::write(&tiny, common::gradient_png(16, 16)).unwrap();
    let (ok, err) = features(&[], &[tiny.to_str().unwrap()]);
    assert!(
        !ok && err.contains("16x16") && err.contains("at least 32x32"),
        "{err}"
    );
}

/// `--device cuda` with the CPU build of ONNX Runtime: one warning saying why and what to
/// fetch, then the same keypoints as on the CPU.
#[test]
fn cuda_without_a_gpu_runtime_falls_back_to_the_cpu() {
    let Some(img) = frame() else { return };
    let Some((lib, _)) = cache_models() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let run = |device: &str| {
        let json = dir.path().join(format!("{device}.json"));
        let out = Command::new(env!("CARGO_BIN_EXE_supermvo"))
            .args(["features", "--top-k", "256", "--device", device, "--json"])
            .arg(&json)
            .arg(&img)
            .env("ORT_DYLIB_PATH", &lib)
            .output()
            .unwrap();
        let (stdout, stderr) = (
            String::from_utf8_lossy(&out.stdout).into_owned(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        );
        assert!(out.status.success(), "{stderr}");
        (stdout, stderr, std::fs::read(&json).unwrap())
    };
    let (out_cpu, err_cpu, cpu) = run("cpu");
    let (out_cuda, err_cuda, cuda) = run("cuda");
    assert!(
        out_cpu.contains("xfeat on CPU") && !err_cpu.contains("CUDA"),
        "{err_cpu}"
    );
    assert!(out_cuda.contains("xfeat on CPU"), "{out_cuda}");
    assert!(
        err_cuda.contains("CUDA was asked for but cannot be used")
            && err_cuda.contains("built without it")
            && err_cuda.contains("supermvo models fetch onnxruntime-gpu")
            && err_cuda.contains("running on the CPU"),
        "{err_cuda}"
    );
    assert_eq!(cpu, cuda, "the fallback computes the same keypoints");
}

/// `models list` reports the ONNX Runtime library a run would load, where that choice comes
/// from, and whether it loads: with ORT_DYLIB_PATH pointing at a file that is not ONNX
/// Runtime it says so instead of "present", and without it the cached copy loads.
#[test]
fn models_list_says_which_runtime_a_run_loads_and_whether_it_loads() {
    let Some((lib, _)) = cache_models() else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let fake = d.path().join("libonnxruntime.so");
    std::fs::write(&fake, b"not a shared library").unwrap();
    let list = |ort: &Path| {
        let out = Command::new(env!("CARGO_BIN_EXE_supermvo"))
            .args(["models", "list"])
            .env("ORT_DYLIB_PATH", ort)
            .output()
            .unwrap();
        assert!(out.status.success());
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        text.lines().next().unwrap_or_default().to_string()
    };
    let bad = list(&fake);
    assert!(
        bad.contains("from ORT_DYLIB_PATH") && bad.contains("unusable") && !bad.contains("present"),
        "{bad}"
    );
    let good = list(&lib);
    assert!(good.contains("(loads)"), "{good}");
}

/// `--top-k` takes the same range in `features` and in `run` (the configuration's), and the
/// error names the flag that was typed.
#[test]
fn top_k_out_of_range_is_refused_alike_by_every_command() {
    for args in [
        &["features", "a.png", "b.png", "--top-k", "0"][..],
        &["run", "seq", "--top-k", "0"][..],
        &["run", "seq", "--top-k", "10000"][..],
    ] {
        let out = common::supermvo(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains("--top-k") && err.contains("from 64 to 8192"),
            "{args:?}: {err}"
        );
    }
}

/// Every `run` flag that overrides a configuration key with a range is refused at the flag,
/// by its name, instead of later by the key's name (`pipeline.ba_window`) the user never typed.
#[test]
fn out_of_range_run_flags_are_refused_by_the_flag_name() {
    for (flag, value, range) in [
        ("--ba-window", "50", "from 0 to 30"),
        ("--keyframe-ratio", "1.5", "from 0 to 1"),
        ("--relocalisation-frames", "101", "from 0 to 100"),
        ("--workers", "0", "from 1 to 8"),
        ("--loops", "0", "from 1 to 100000"),
    ] {
        let out = common::supermvo(&["run", "seq", flag, value]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{flag}: {err}");
        assert!(err.contains(flag) && err.contains(range), "{flag}: {err}");
        assert!(!err.contains("pipeline."), "{flag}: {err}");
    }
}

/// `--profile` takes the built-in names only, and not together with `--config`.
#[test]
fn an_unknown_profile_or_one_beside_a_config_file_is_refused() {
    let out = common::supermvo(&["run", "seq", "--profile", "fast"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--profile") && err.contains("realtime"),
        "{err}"
    );
    let out = common::supermvo(&["run", "seq", "--profile", "realtime", "--config", "c.toml"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("--profile") && err.contains("--config"),
        "{err}"
    );
}
