//! `supermvo eval`.

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use std::path::{Path, PathBuf};
use supermvo_config::Config;
use supermvo_dataset::{read_times, read_trajectory, TrajectoryFormat};
use supermvo_eval::{evaluate, DeltaUnit, Evaluation, Stats};
use supermvo_geometry::AlignmentKind;

#[derive(Debug, Clone, Copy, ValueEnum)]
enum FormatArg {
    Kitti,
    Tum,
    Euroc,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum AlignArg {
    None,
    Se3,
    Sim3,
    Scale,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum UnitArg {
    Frames,
    Meters,
}

/// Arguments of `supermvo eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Ground-truth trajectory.
    #[arg(long, required_unless_present = "gt_dir")]
    gt: Option<PathBuf>,
    /// Estimated trajectory; repeat to compare several (labelled by file name, or NAME=PATH).
    #[arg(long, required_unless_present = "est_dir")]
    est: Vec<String>,
    /// A folder of KITTI ground truth (`poses/NN.txt`), evaluated against `--est-dir` as the
    /// KITTI devkit does: every `NN.txt` of the results, one table with the averages.
    #[arg(long, requires = "est_dir", conflicts_with_all = ["gt", "est"])]
    gt_dir: Option<PathBuf>,
    /// A folder of KITTI-format results (`NN.txt`, one row per frame).
    #[arg(long, requires = "gt_dir")]
    est_dir: Option<PathBuf>,
    /// File format. With `euroc`, the ground truth is EuRoC CSV and estimates are TUM.
    #[arg(long, value_enum, default_value = "kitti")]
    format: FormatArg,
    /// Format of the estimates when it differs from the ground truth's (for example `tum`
    /// against KITTI ground truth with `--gt-times`) [default: as --format; tum with euroc].
    #[arg(long, value_enum)]
    est_format: Option<FormatArg>,
    /// Timestamps of the KITTI ground truth, one a line (a KITTI `times.txt`): the poses are
    /// then associated with timestamped estimates (TUM) by time, so a run that did not pose
    /// every frame can be evaluated on the frames it posed.
    #[arg(long)]
    gt_times: Option<PathBuf>,
    /// Alignment of each estimate onto the ground truth [default: from config, "none"].
    #[arg(long, value_enum)]
    align: Option<AlignArg>,
    /// RPE step [default: from config, 1].
    #[arg(long)]
    delta: Option<f64>,
    /// Unit of the RPE step [default: from config, frames].
    #[arg(long, value_enum)]
    delta_unit: Option<UnitArg>,
    /// Maximum timestamp difference for association, seconds [default: from config, 0.01].
    #[arg(long)]
    t_max_diff: Option<f64>,
    /// Choose RPE pairs along the ground truth instead of the estimate.
    #[arg(long)]
    pairs_from_reference: bool,
    /// Write the results as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write PNG figures into this directory.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Configuration file (TOML) providing defaults.
    #[arg(long)]
    config: Option<PathBuf>,
    /// No list of the files written (as in `run` and `synth`: -q drops what is not a
    /// result; the table and errors still print).
    #[arg(long, short)]
    quiet: bool,
}

fn parse_est(spec: &str) -> (String, PathBuf) {
    if let Some((name, path)) = spec.split_once('=') {
        if !name.is_empty() && !name.contains(std::path::MAIN_SEPARATOR) {
            return (name.to_string(), PathBuf::from(path));
        }
    }
    let p = PathBuf::from(spec);
    let name = p
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| spec.to_string());
    (name, p)
}

fn print_stats(title: &str, unit: &str, s: &Stats) {
    outln!("  {title} ({unit})");
    for (k, v) in [
        ("rmse", s.rmse),
        ("mean", s.mean),
        ("median", s.median),
        ("std", s.std),
        ("min", s.min),
        ("max", s.max),
        ("sse", s.sse),
    ] {
        outln!("    {k:>7}  {v:.6}");
    }
}

fn print_report(label: &str, ev: &Evaluation) {
    let r = &ev.report;
    outln!(
        "== {label}: {} matched poses, reference path {:.3} m",
        r.matched_poses,
        r.reference_length_m
    );
    if r.alignment.kind != AlignmentKind::None {
        outln!(
            "  alignment {:?}: scale {:.6}",
            r.alignment.kind,
            r.alignment.scale
        );
    }
    print_stats("APE translation", "m", &r.ape.trans);
    print_stats("APE rotation angle", "deg", &r.ape.rot_deg);
    match (&r.rpe, &r.rpe_error) {
        (Some(rpe), _) => {
            let unit = if rpe.delta_unit == DeltaUnit::Frames {
                "frames"
            } else {
                "m"
            };
            print_stats(
                &format!(
                    "RPE translation, delta {} {unit}, {} pairs",
                    rpe.delta, rpe.pairs
                ),
                "m",
                &rpe.trans,
            );
            print_stats("RPE rotation angle", "deg", &rpe.rot_deg);
        }
        (None, Some(msg)) => outln!("  RPE: not computed: {msg}"),
        (None, None) => {}
    }
    match &r.kitti {
        Some(k) => outln!(
            "  KITTI metric: t_err {:.4} %, r_err {:.4} deg/100m over {} segments",
            k.t_err_pct,
            k.r_err_deg_per_100m,
            k.segments
        ),
        None => outln!("  KITTI metric: not computed (ground truth shorter than 100 m)"),
    }
}

/// The KITTI devkit's evaluation of a results folder: every `NN.txt` in `est_dir` against
/// `gt_dir/NN.txt` (KITTI format, pose for pose), one row each, then the averages over all
/// segments (the devkit's) and the mean APE.
fn evaluate_folders(
    gt_dir: &Path,
    est_dir: &Path,
    opts: &supermvo_eval::EvalOptions,
) -> Result<()> {
    let mut names: Vec<String> = std::fs::read_dir(est_dir)
        .with_context(|| format!("reading --est-dir {}", est_dir.display()))?
        .filter_map(|e| e.ok())
        .filter_map(|e| e.file_name().into_string().ok())
        .filter(|n| n.ends_with(".txt"))
        .collect();
    names.sort();
    if names.is_empty() {
        bail!("--est-dir {}: no NN.txt results", est_dir.display());
    }
    outln!(
        "{:<10} {:>6} {:>9} {:>14} {:>9}",
        "sequence",
        "poses",
        "t_err %",
        "r_err deg/100m",
        "APE (m)"
    );
    let (mut t_sum, mut r_sum, mut segments, mut apes) = (0.0, 0.0, 0usize, Vec::new());
    for name in &names {
        let seq = name.trim_end_matches(".txt");
        let gt_path = gt_dir.join(name);
        if !gt_path.is_file() {
            outln!("{seq:<10} no ground truth at {}", gt_path.display());
            continue;
        }
        let gt = read_trajectory(&gt_path, TrajectoryFormat::Kitti)?;
        let est = read_trajectory(&est_dir.join(name), TrajectoryFormat::Kitti)?;
        let ev = evaluate(&gt, &est, opts).with_context(|| {
            format!(
                "evaluating {} against {}",
                est_dir.join(name).display(),
                gt_path.display()
            )
        })?;
        let r = &ev.report;
        let ape = r.ape.trans.rmse;
        apes.push(ape);
        match &r.kitti {
            Some(k) => {
                outln!(
                    "{seq:<10} {:>6} {:>9.4} {:>14.4} {ape:>9.3}",
                    r.matched_poses,
                    k.t_err_pct,
                    k.r_err_deg_per_100m
                );
                t_sum += k.t_err_pct * k.segments as f64;
                r_sum += k.r_err_deg_per_100m * k.segments as f64;
                segments += k.segments;
            }
            None => outln!(
                "{seq:<10} {:>6} {:>9} {:>14} {ape:>9.3}",
                r.matched_poses,
                "-",
                "-"
            ),
        }
    }
    if segments > 0 {
        let mean_ape = apes.iter().sum::<f64>() / apes.len() as f64;
        outln!(
            "{:<10} {:>6} {:>9.4} {:>14.4} {mean_ape:>9.3}",
            "average",
            "",
            t_sum / segments as f64,
            r_sum / segments as f64
        );
    }
    Ok(())
}

/// Runs `supermvo eval`.
pub fn run(args: &EvalArgs) -> Result<()> {
    let cfg = match &args.config {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    let mut ec = cfg.eval.clone();
    if let Some(a) = args.align {
        ec.align = match a {
            AlignArg::None => AlignmentKind::None,
            AlignArg::Se3 => AlignmentKind::Se3,
            AlignArg::Sim3 => AlignmentKind::Sim3,
            AlignArg::Scale => AlignmentKind::Scale,
        };
    }
    if let Some(d) = args.delta {
        ec.delta = d;
    }
    if let Some(u) = args.delta_unit {
        ec.delta_unit = match u {
            UnitArg::Frames => DeltaUnit::Frames,
            UnitArg::Meters => DeltaUnit::Meters,
        };
    }
    if let Some(t) = args.t_max_diff {
        ec.t_max_diff = t;
    }
    ec.pairs_from_reference |= args.pairs_from_reference;
    ec.validate().context("invalid evaluation options")?;
    let opts = ec.options();

    let format = |f: FormatArg| match f {
        FormatArg::Kitti => TrajectoryFormat::Kitti,
        FormatArg::Tum => TrajectoryFormat::Tum,
        FormatArg::Euroc => TrajectoryFormat::Euroc,
    };
    if let (Some(gt_dir), Some(est_dir)) = (&args.gt_dir, &args.est_dir) {
        return evaluate_folders(gt_dir, est_dir, &opts);
    }
    let Some(gt_path) = &args.gt else {
        bail!("give --gt (with --est) or --gt-dir (with --est-dir)");
    };
    let gt_format = format(args.format);
    let est_format = match (args.est_format, args.format) {
        (Some(f), _) => format(f),
        (None, FormatArg::Euroc) => TrajectoryFormat::Tum,
        (None, f) => format(f),
    };
    let mut gt = read_trajectory(gt_path, gt_format).context("reading ground truth")?;
    if let Some(times) = &args.gt_times {
        if gt_format != TrajectoryFormat::Kitti {
            bail!("--gt-times gives a KITTI ground truth its timestamps; --format {gt_format} files carry their own");
        }
        let stamps = read_times(times).context("reading --gt-times")?;
        if stamps.len() != gt.poses.len() {
            bail!(
                "--gt-times {} has {} timestamps but --gt {} has {} poses; give the times.txt of the same sequence",
                times.display(),
                stamps.len(),
                gt_path.display(),
                gt.poses.len()
            );
        }
        gt.stamps = Some(stamps);
    }
    let estimates: Vec<(String, PathBuf)> = args.est.iter().map(|s| parse_est(s)).collect();
    // labels name the JSON entries and the figures: two alike would overwrite each other
    for (i, (label, _)) in estimates.iter().enumerate() {
        if estimates[..i].iter().any(|(l, _)| l == label) {
            bail!("two estimates share the label '{label}'; name them with NAME=PATH");
        }
    }
    let mut results: Vec<(String, Evaluation)> = Vec::new();
    for (label, path) in estimates {
        let est = read_trajectory(&path, est_format).context("reading estimate")?;
        let ev = evaluate(&gt, &est, &opts).with_context(|| {
            format!(
                "evaluating {} against {}",
                path.display(),
                gt_path.display()
            )
        })?;
        print_report(&label, &ev);
        results.push((label, ev));
    }
    if let Some(json) = &args.json {
        write_json(json, &results)?;
    }
    if let Some(dir) = &args.plot {
        let files = supermvo_plot::write_all(dir, &results)?;
        if !args.quiet {
            for f in files {
                outln!("wrote {}", f.display());
            }
        }
    }
    Ok(())
}

fn write_json(path: &Path, results: &[(String, Evaluation)]) -> Result<()> {
    let value = match results {
        [(_, ev)] => serde_json::to_value(&ev.report)?,
        many => {
            let mut map = serde_json::Map::new();
            for (label, ev) in many {
                map.insert(label.clone(), serde_json::to_value(&ev.report)?);
            }
            serde_json::Value::Object(map)
        }
    };
    let text = serde_json::to_string_pretty(&value)?;
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}
