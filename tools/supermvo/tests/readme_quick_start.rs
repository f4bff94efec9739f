//! The README's "Quick start on KITTI", run verbatim: its bash block, line by line, in a
//! clean folder where `dataset` is the KITTI layout of `../shared/data/kitti` (the user's
//! download) and `supermvo` is this build. Every command must succeed, and the last one
//! must print the evaluation table.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code
mod common;

/// The commands of the first bash block after `heading` in the README.
fn bash_block_after(readme: &str, heading: &str) -> Vec<String> {
    let section = &readme[readme.find(heading).unwrap()..];
    let start = section.find("```bash\n").unwrap() + "```bash\n".len();
    let body = &section[start..];
    let body = &body[..body.find("```").unwrap()];
    body.lines()
        .map(|l| l.split(" #").next().unwrap_or("").trim().to_string())
        .filter(|l| !l.is_empty())
        .collect()
}

#[test]
fn the_readme_quick_start_on_kitti_runs_verbatim() {
    let Some(kitti) = common::shared_data("kitti") else {
        return;
    };
    if !common::models_ready() {
        return;
    }
    let readme = std::fs::read_to_string(common::root().join("README.md")).unwrap();
    let commands = bash_block_after(&readme, "## Quick start on KITTI");
    assert!(commands.len() >= 3, "{commands:?}");
    assert!(
        commands.iter().all(|c| c.starts_with("supermvo ")),
        "{commands:?}"
    );
    let tmp = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink(&kitti, tmp.path().join("dataset")).unwrap();
    let bin_dir = std::path::Path::new(env!("CARGO_BIN_EXE_supermvo"))
        .parent()
        .unwrap()
        .to_path_buf();
    let path = format!(
        "{}:{}",
        bin_dir.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let mut last = String::new();
    for c in &commands {
        let r = std::process::Command::new("bash")
            .args(["-c", c])
            .current_dir(tmp.path())
            .env("PATH", &path)
            .output()
            .unwrap();
        let (out, err) = (
            String::from_utf8_lossy(&r.stdout),
            String::from_utf8_lossy(&r.stderr),
        );
        assert!(r.status.success(), "`{c}` failed:\n{out}\n{err}");
        last = out.into_owned();
    }
    assert!(
        last.contains("APE") && last.contains("rmse") && last.contains("alignment"),
        "the quick start ends with the evaluation table:\n{last}"
    );
    for f in ["trajectory_xz.png", "ape_trajectory_kitti.png"] {
        assert!(tmp.path().join("out/kitti00").join(f).is_file(), "{f}");
    }
}
