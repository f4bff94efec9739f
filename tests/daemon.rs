//! The multi-process daemon end to end: real stage processes over real iceoryx2 shared memory.
//! (Compiled as an integration test of `services`, which builds the stage binaries.)
//!
//! - lossless multi-process gives the in-process trajectory bit for bit (KITTI 03);
//! - `kill -9` of each stage in turn mid-run: restarted, the run completes, every frame is
//!   accounted for, nothing is left in shared memory;
//! - a hung (stopped) stage is restarted after the deadline;
//! - SIGINT/SIGTERM shut down cleanly with the trajectory written;
//! - stages whose supervisor is killed stop instead of lingering;
//! - bad input: missing stage binaries, bad config, a second pipeline of the same name.
//!
//! The tests run one at a time (they watch the shared-memory directories).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // test code

use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, Instant};
use supermvo_config::Config;
use supermvo_dataset::{GrayImage, Sequence};
use supermvo_pipeline::backend::read_records;
use supermvo_pipeline::supervisor::{self, SupervisorOptions};
use supermvo_pipeline::{features, matching, tracking};
use supermvo_vo::pipeline::VoPipeline;
use supermvo_vo::stage::Stage;
use supermvo_vo::tracker::{FrameInput, Tracker};

static SERIAL: Mutex<()> = Mutex::new(());

fn shared_data(sub: &str) -> Option<PathBuf> {
    let base = std::env::var_os("SUPERMVO_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared"));
    let p = base.join("data").join(sub);
    if p.exists() {
        return Some(p);
    }
    assert!(
        std::env::var("SUPERMVO_REQUIRE_SHARED").as_deref() != Ok("1"),
        "{} is missing and SUPERMVO_REQUIRE_SHARED=1",
        p.display()
    );
    eprintln!("SKIP: {} not found", p.display());
    None
}

fn models_ready() -> bool {
    let ok = ["xfeat", "lighterglue"]
        .iter()
        .all(|m| supermvo_inference::models::model_path(m).is_file())
        && supermvo_inference::runtime::init(None).is_ok();
    if !ok {
        assert!(
            std::env::var("SUPERMVO_REQUIRE_SHARED").as_deref() != Ok("1"),
            "run 'supermvo models fetch' first"
        );
        eprintln!("SKIP: models not fetched");
    }
    ok
}

/// Serialises the tests (they watch the shared-memory directories) and finds their inputs:
/// `None` (skip, printed) when the clip or the models are absent.
fn setup(
    clip: &str,
    need_models: bool,
) -> Option<(
    std::sync::MutexGuard<'static, ()>,
    PathBuf,
    BTreeSet<String>,
)> {
    let guard = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let seq = shared_data(&format!("kitti/sequences/{clip}"))?;
    if need_models && !models_ready() {
        return None;
    }
    // what processes of an earlier, crashed run left goes now, not while a test watches
    cleanup_dead_nodes();
    Some((guard, seq, ipc_files()))
}

/// Removes the shared memory of dead iceoryx2 nodes, as a starting supervisor does.
fn cleanup_dead_nodes() {
    let services = supermvo_messages::Services::new(&format!("cleanup-{}", std::process::id()));
    let node = supermvo_messages::create_node(&services.node_name("cleanup", 0).unwrap()).unwrap();
    node.try_cleanup_dead_nodes();
}

fn bin_dir() -> PathBuf {
    Path::new(env!("CARGO_BIN_EXE_supermvo-ingest"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// Files iceoryx2 keeps for live nodes and services.
fn ipc_files() -> BTreeSet<String> {
    let mut s = BTreeSet::new();
    for dir in ["/dev/shm", "/tmp/iceoryx2"] {
        let mut stack = vec![PathBuf::from(dir)];
        while let Some(d) = stack.pop() {
            let Ok(rd) = std::fs::read_dir(&d) else {
                continue;
            };
            for e in rd.flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    s.insert(p.display().to_string());
                }
            }
        }
    }
    s
}

/// Frames the back end has recorded so far in `out/frames.csv` (0 before it exists).
fn recorded(out: &Path) -> usize {
    read_records(&out.join("frames.csv")).map_or(0, |r| r.len())
}

/// `(stage, pid)` of each live stage process in `out/processes.json` (empty before it exists).
fn stage_pids(out: &Path) -> Vec<(String, i32)> {
    let Ok(text) = std::fs::read_to_string(out.join("processes.json")) else {
        return Vec::new();
    };
    let v: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
    v.as_array()
        .into_iter()
        .flatten()
        .filter_map(|p| Some((p["stage"].as_str()?.to_string(), p["pid"].as_i64()? as i32)))
        .collect()
}

/// The pid of `stage`'s process, when listed.
fn pid_of(out: &Path, stage: &str) -> Option<i32> {
    stage_pids(out)
        .into_iter()
        .find_map(|(s, pid)| (s == stage).then_some(pid))
}

fn options(name: &str, seq: &Path, out: &Path, max_frames: usize) -> SupervisorOptions {
    let mut config = Config::default();
    config.pipeline.name = format!("{name}-{}", std::process::id());
    config.pipeline.max_frames = max_frames;
    SupervisorOptions {
        config,
        seq: seq.to_path_buf(),
        out: out.to_path_buf(),
        bin_dir: bin_dir(),
        quiet: true,
    }
}

#[test]
fn multiprocess_lossless_equals_inprocess_bit_for_bit_on_kitti_03() {
    let Some((_g, seq_dir, before)) = setup("03", true) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let opts = options("parity", &seq_dir, tmp.path(), 0);
    let metrics = supervisor::run(&opts).unwrap();
    let records = read_records(&tmp.path().join("frames.csv")).unwrap();
    // KITTI 03 never revisits a place: loop closure (on by default) must accept nothing.
    assert!(opts.config.pipeline.loop_closure);
    assert!(
        !tmp.path().join("loops.json").exists(),
        "false loop on KITTI 03: {}",
        std::fs::read_to_string(tmp.path().join("loops.json")).unwrap_or_default()
    );

    // the same stages, in this process, one frame after the other
    let seq = Sequence::open(&seq_dir).unwrap();
    let p = &opts.config.pipeline;
    let mut vo = VoPipeline::new(
        features::extractor(p, supermvo_config::NetworkPlacement::Alternating).unwrap(),
        matching::matcher(p, supermvo_config::NetworkPlacement::Alternating).unwrap(),
        Tracker::new(seq.calib, tracking::tracker_config(p)),
        None,
    );
    let n = seq.images.len();
    assert_eq!(records.len(), n + 1, "every frame and the end of stream");
    let outputs: Vec<_> = (0..n)
        .map(|i| {
            vo.process(FrameInput {
                index: i,
                stamp: seq.times[i],
                image: GrayImage::load(&seq.images[i]).unwrap(),
            })
            .unwrap()
        })
        .collect();
    // every frame's pose, those of the frames seen while initialising (posed later, with
    // the frame that initialised) included
    let mut poses: Vec<Option<[f64; 12]>> = outputs
        .iter()
        .map(|o| o.t_world_cam.map(|p| p.to_row_major_3x4()))
        .collect();
    let late: Vec<_> = outputs.iter().flat_map(|o| o.backfilled.iter()).collect();
    assert!(!late.is_empty(), "03's first frames are posed late");
    for l in late {
        poses[l.index] = Some(l.t_world_cam.to_row_major_3x4());
    }
    for (i, (rec, out)) in records.iter().zip(&outputs).enumerate() {
        assert_eq!(rec.seq, i as u64);
        assert_eq!(rec.status, "ok");
        assert_eq!(rec.stamp.to_bits(), seq.times[i].to_bits());
        // bit for bit: compare the f64 bit patterns
        let bits = |p: Option<[f64; 12]>| p.map(|a| a.map(f64::to_bits));
        let recorded = rec.t_world_cam.map(|p| p.to_row_major_3x4());
        assert_eq!(bits(recorded), bits(poses[i]), "frame {i}");
        assert_eq!(rec.keyframe, out.keyframe, "frame {i}");
    }
    assert_eq!(records[n].status, "end");
    // the lens learnt while driving (the default) is learnt alike in the daemon, whose
    // tracking stage reads it from the windows the back end solved, and reported
    let lens = std::fs::read_to_string(tmp.path().join(tracking::LENS_FILE)).unwrap();
    let lens: supermvo_vo::tracker::LensResidual = serde_json::from_str(&lens).unwrap();
    assert!(p.lens_self_calibration);
    assert_eq!(Some(lens), vo.tracker().lens_residual());
    assert!(lens.learnt_k1 > 0.0, "{lens:?}");
    // the local mapping ran in the back-end process: the triangulations of every keyframe
    // tracked against the map (not those that initialise one) and every local BA (the
    // tracker does such work itself only when no back end answers)
    let lines = |name: &str| {
        std::fs::read_to_string(tmp.path().join(name))
            .unwrap()
            .lines()
            .count()
            - 1
    };
    let solved = lines("local_ba.csv");
    assert!(solved >= 50, "{solved} local BAs solved in the back end");
    let triangulated = lines("triangulation.csv");
    let keyframes = records.iter().filter(|r| r.keyframe).count();
    assert!(
        10 * triangulated >= 9 * keyframes && triangulated >= 50,
        "{triangulated} keyframes triangulated in the back end of {keyframes}"
    );
    let log = std::fs::read_to_string(tmp.path().join("logs/tracking-0.log")).unwrap();
    assert!(!log.contains("done here"), "{log}");
    assert_eq!(metrics.frames.get("ok"), Some(&n));
    assert!(metrics.restarts.is_empty());
    assert!(metrics.end_to_end_ms.count == n);
    // every stage reports the CPU it spends per frame from its own accounting, and the
    // networks cost most of it
    for stage in ["ingest", "features", "matching", "tracking", "backend"] {
        let cpu = &metrics.stage_cpu_ms[stage];
        assert!(cpu.count + 1 >= n && cpu.mean > 0.0, "{stage}: {cpu:?}");
    }
    let (features, tracking) = (
        &metrics.stage_cpu_ms["features"],
        &metrics.stage_cpu_ms["tracking"],
    );
    assert!(
        features.mean > tracking.mean,
        "{features:?} vs {tracking:?}"
    );
    assert_eq!(
        ipc_files(),
        before,
        "shared-memory files left after shutdown"
    );
}

#[test]
fn killed_stages_are_restarted_and_every_frame_is_accounted_for() {
    let Some((_g, seq_dir, before)) = setup("00", true) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let frames = 150;
    let mut opts = options("fault", &seq_dir, tmp.path(), frames);
    opts.config.pipeline.gap_timeout_ms = 3000;
    let out = tmp.path().to_path_buf();
    let handle = std::thread::spawn(move || supervisor::run(&opts));

    let stages = ["ingest", "features", "matching", "tracking", "backend"];
    let t0 = Instant::now();
    for (k, stage) in stages.iter().enumerate() {
        let at = 10 + 22 * k;
        while recorded(&out) < at {
            assert!(
                t0.elapsed() < Duration::from_secs(400),
                "run stalled before killing {stage}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        let pid = pid_of(&out, stage).unwrap();
        kill(Pid::from_raw(pid), Signal::SIGKILL).unwrap();
        eprintln!("killed {stage} (pid {pid}) after {} frames", recorded(&out));
        // wait for its successor before the next kill
        while pid_of(&out, stage) == Some(pid) {
            assert!(t0.elapsed() < Duration::from_secs(400));
            std::thread::sleep(Duration::from_millis(10));
        }
    }
    let metrics = handle.join().unwrap().unwrap();
    eprintln!(
        "{}",
        serde_json::to_string_pretty(&metrics.restarts).unwrap()
    );
    assert_eq!(metrics.restarts.len(), stages.len());
    for r in &metrics.restarts {
        assert!(r.respawn_ms < 1000.0, "{r:?}");
        assert!(r.ready_ms.is_some(), "{r:?} never came back up");
        assert!(r.reason.contains("signal: 9"), "{r:?}");
    }
    // every frame is in the record exactly once, processed or reported
    let records = read_records(&out.join("frames.csv")).unwrap();
    let seqs: Vec<u64> = records.iter().map(|r| r.seq).collect();
    assert_eq!(seqs, (0..=frames as u64).collect::<Vec<_>>());
    assert_eq!(records.last().unwrap().status, "end");
    let ok = records.iter().filter(|r| r.status == "ok").count();
    let reported: usize = metrics.frames.values().sum();
    assert_eq!(reported, frames);
    eprintln!(
        "frames: {:?}; {} with a pose",
        metrics.frames, metrics.estimated
    );
    assert!(ok >= frames - 20, "{:?}", metrics.frames);
    assert!(out.join("trajectory.tum.txt").is_file());
    assert_eq!(
        ipc_files(),
        before,
        "shared-memory files left after shutdown"
    );
}

#[test]
fn missing_binaries_and_bad_config_start_nothing() {
    let Some((_g, seq_dir, before)) = setup("06", false) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let mut opts = options("bad", &seq_dir, &tmp.path().join("out"), 5);
    opts.bin_dir = tmp.path().join("no-binaries");
    let err = supervisor::run(&opts).unwrap_err().to_string();
    assert!(
        err.contains("stage binaries missing") && err.contains("supermvo-features"),
        "{err}"
    );
    assert!(!tmp.path().join("out/processes.json").exists());

    // config errors come from the supervisor binary as one line naming key and range
    let cfg = tmp.path().join("c.toml");
    for (text, needles) in [
        (
            "[pipeline]\nworkerz = 2\n",
            vec!["unknown field", "workerz", "line 2"],
        ),
        (
            "[pipeline]\nfeatures_workers = 9\n",
            vec!["pipeline.features_workers", "[1, 8]"],
        ),
    ] {
        std::fs::write(&cfg, text).unwrap();
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_supermvo-supervisor"))
            .args([
                "--config",
                cfg.to_str().unwrap(),
                "--seq",
                seq_dir.to_str().unwrap(),
            ])
            .arg("--out")
            .arg(tmp.path().join("out2"))
            .output()
            .unwrap();
        assert!(!out.status.success());
        let stderr = String::from_utf8_lossy(&out.stderr);
        for n in needles {
            assert!(stderr.contains(n), "{n:?} not in {stderr}");
        }
        assert!(
            stderr.starts_with("error: ") && !stderr.contains("panicked"),
            "{stderr}"
        );
    }
    assert_eq!(ipc_files(), before);
}

#[test]
fn a_second_pipeline_under_a_running_name_is_refused() {
    let Some((_g, seq_dir, before)) = setup("06", true) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let first = options("twice", &seq_dir, &tmp.path().join("a"), 20);
    let second = options("twice", &seq_dir, &tmp.path().join("b"), 20);
    let a_out = tmp.path().join("a");
    let handle = std::thread::spawn(move || supervisor::run(&first));
    let t0 = Instant::now();
    while !a_out.join("processes.json").exists() {
        assert!(t0.elapsed() < Duration::from_secs(60));
        std::thread::sleep(Duration::from_millis(10));
    }
    let err = supervisor::run(&second).unwrap_err().to_string();
    assert!(err.contains("is already running"), "{err}");
    assert!(!tmp.path().join("b/processes.json").exists());
    // the first one is undisturbed
    let m = handle.join().unwrap().unwrap();
    assert_eq!(m.frames.values().sum::<usize>(), 20);
    assert_eq!(ipc_files(), before);
}

#[test]
fn sigint_and_sigterm_shut_down_cleanly_with_the_trajectory_written() {
    let Some((_g, seq_dir, before)) = setup("00", true) else {
        return;
    };
    for signal in [Signal::SIGINT, Signal::SIGTERM] {
        let tmp = tempfile::tempdir().unwrap();
        let cfg = tmp.path().join("c.toml");
        std::fs::write(
            &cfg,
            format!("[pipeline]\nname = \"sig-{}\"\n", std::process::id()),
        )
        .unwrap();
        let out = tmp.path().join("out");
        let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_supermvo-supervisor"))
            .args([
                "--config",
                cfg.to_str().unwrap(),
                "--seq",
                seq_dir.to_str().unwrap(),
                "-q",
            ])
            .arg("--out")
            .arg(&out)
            .stdout(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let t0 = Instant::now();
        while recorded(&out) < 10 {
            assert!(t0.elapsed() < Duration::from_secs(120));
            std::thread::sleep(Duration::from_millis(20));
        }
        kill(Pid::from_raw(child.id() as i32), signal).unwrap();
        let status = child.wait().unwrap();
        assert!(status.success(), "{signal:?}: {status}");
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap())
                .unwrap();
        assert_eq!(m["interrupted"], true);
        let recorded = read_records(&out.join("frames.csv")).unwrap();
        assert!(
            recorded.len() >= 10 && recorded.len() < 160,
            "{}",
            recorded.len()
        );
        let traj = std::fs::read_to_string(out.join("trajectory.tum.txt")).unwrap();
        assert_eq!(
            traj.lines().count(),
            recorded.iter().filter(|r| r.t_world_cam.is_some()).count(),
            "{signal:?}: the trajectory holds every recorded pose"
        );
        assert_eq!(ipc_files(), before, "{signal:?}: shared memory left behind");
    }
}

/// Whether process `pid` has ended (gone, or a zombie nobody reaps).
fn process_ended(pid: i32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        Ok(stat) => stat
            .rsplit_once(')')
            .is_some_and(|(_, rest)| rest.trim_start().starts_with('Z')),
        Err(_) => true,
    }
}

#[test]
fn stages_stop_when_their_supervisor_is_killed() {
    let Some((_g, seq_dir, before)) = setup("07", true) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let name = format!("orphans-{}", std::process::id());
    let config = tmp.path().join("config.toml");
    std::fs::write(&config, format!("[pipeline]\nname = \"{name}\"\n")).unwrap();
    let out = tmp.path().join("out");
    let mut supervisor = std::process::Command::new(bin_dir().join("supermvo-supervisor"))
        .arg("--config")
        .arg(&config)
        .arg("--seq")
        .arg(&seq_dir)
        .arg("--out")
        .arg(&out)
        .arg("--quiet")
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // wait until every stage runs and frames flow
    let t0 = Instant::now();
    let pids: Vec<i32> = loop {
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "the pipeline never started"
        );
        let pids: Vec<i32> = stage_pids(&out).into_iter().map(|(_, p)| p).collect();
        if pids.len() == 5 && recorded(&out) >= 5 {
            break pids;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    kill(Pid::from_raw(supervisor.id() as i32), Signal::SIGKILL).unwrap();
    supervisor.wait().unwrap();
    loop {
        let alive: Vec<i32> = pids
            .iter()
            .copied()
            .filter(|&p| !process_ended(p))
            .collect();
        if alive.is_empty() {
            break;
        }
        if t0.elapsed() > Duration::from_secs(180) {
            for &p in &alive {
                let _ = kill(Pid::from_raw(p), Signal::SIGKILL);
            }
            panic!("stages {alive:?} still running after their supervisor was killed");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    // the dead processes' shared memory goes with the next cleanup, as a new supervisor's
    cleanup_dead_nodes();
    assert_eq!(
        ipc_files(),
        before,
        "shared-memory files left after cleanup"
    );
}

#[test]
fn a_hung_stage_is_restarted_after_the_deadline() {
    let Some((_g, seq_dir, before)) = setup("06", true) else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let mut opts = options("hang", &seq_dir, tmp.path(), 40);
    opts.config.pipeline.deadline_ms = 2000;
    let out = tmp.path().to_path_buf();
    let handle = std::thread::spawn(move || supervisor::run(&opts));
    let t0 = Instant::now();
    while recorded(&out) < 10 {
        assert!(t0.elapsed() < Duration::from_secs(120));
        std::thread::sleep(Duration::from_millis(20));
    }
    let pid = pid_of(&out, "features").unwrap();
    // a stopped process is alive but silent: only the deadline can catch it
    kill(Pid::from_raw(pid), Signal::SIGSTOP).unwrap();
    let m = handle.join().unwrap().unwrap();
    assert_eq!(m.restarts.len(), 1, "{:?}", m.restarts);
    assert!(m.restarts[0].reason.contains("silent"), "{:?}", m.restarts);
    assert_eq!(m.frames.values().sum::<usize>(), 40, "{:?}", m.frames);
    assert_eq!(ipc_files(), before);
}
