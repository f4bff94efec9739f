//! Trajectory evaluation with the definitions of evo and the KITTI odometry devkit.
//!
//! [`evaluate`] runs the whole chain: timestamp association (TUM/EuRoC) or length check
//! (KITTI), Umeyama alignment, APE, RPE and the KITTI metric, and returns a [`Report`]
//! that serialises to the JSON documented in docs/evaluation.md.

mod associate;
mod kitti_metric;
mod metrics;
mod stats;

pub use associate::{associate, matching_indices};
pub use kitti_metric::{
    kitti_metric, kitti_metric_with, KittiLengthError, KittiMetric, KITTI_LENGTHS, KITTI_STEP,
};
pub use metrics::{ape, delta_pairs, rpe, Ape, DeltaUnit, ErrorSeries, Rpe};
pub use stats::Stats;

use serde::{Deserialize, Serialize};
use supermvo_dataset::Trajectory;
use supermvo_geometry::{umeyama, AlignmentKind, Sim3, UmeyamaError};

/// Why an evaluation could not be done.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EvalError {
    /// Pose-by-pose comparison of trajectories of different lengths (KITTI format).
    #[error("trajectories have different lengths: reference {reference} poses, estimate {estimate} poses (KITTI files are compared line by line, so they need the same number of poses)")]
    LengthMismatch {
        /// Reference length.
        reference: usize,
        /// Estimate length.
        estimate: usize,
    },
    /// Association needs timestamps on both sides.
    #[error("timestamp association needs timestamps in both trajectories; use --format tum or euroc, or kitti for index-wise comparison")]
    NoTimestamps,
    /// No stamp of one trajectory is within the tolerance of the other.
    #[error("the trajectories share no timestamps within {max_diff} s (reference spans {:.6}..{:.6} s, estimate {:.6}..{:.6} s); check the time base or raise --t-max-diff", ref_range.0, ref_range.1, est_range.0, est_range.1)]
    NoMatchingStamps {
        /// Tolerance used.
        max_diff: f64,
        /// First and last reference stamp.
        ref_range: (f64, f64),
        /// First and last estimate stamp.
        est_range: (f64, f64),
    },
    /// Nothing to compare.
    #[error("no poses to compare")]
    NoPairs,
    /// The RPE step is invalid or selects no pair.
    #[error("{0}")]
    BadDelta(String),
    /// Alignment failed.
    #[error("alignment failed: {0}")]
    Align(#[from] UmeyamaError),
}

/// Options of one evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalOptions {
    /// Alignment of the estimate onto the reference before computing errors.
    pub align: AlignmentKind,
    /// RPE step.
    pub delta: f64,
    /// Unit of the RPE step.
    pub delta_unit: DeltaUnit,
    /// Maximum timestamp difference for association, seconds.
    pub t_max_diff: f64,
    /// Choose RPE pairs on the reference path rather than the estimate's (evo's default).
    pub pairs_from_reference: bool,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            align: AlignmentKind::None,
            delta: 1.0,
            delta_unit: DeltaUnit::Frames,
            t_max_diff: 0.01,
            pairs_from_reference: false,
        }
    }
}

/// Statistics of APE.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ApeStats {
    /// Translation, metres.
    pub trans: Stats,
    /// Rotation angle, degrees.
    pub rot_deg: Stats,
    /// Full transformation (unitless).
    pub full: Stats,
}

/// Statistics of RPE.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RpeStats {
    /// Translation, metres.
    pub trans: Stats,
    /// Rotation angle, degrees.
    pub rot_deg: Stats,
    /// Step used.
    pub delta: f64,
    /// Unit of the step.
    pub delta_unit: DeltaUnit,
    /// Number of pairs.
    pub pairs: usize,
}

/// The alignment applied to the estimate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlignmentReport {
    /// Kind of alignment.
    pub kind: AlignmentKind,
    /// Scale factor.
    pub scale: f64,
    /// Rotation matrix, row-major.
    pub rotation: [[f64; 3]; 3],
    /// Translation.
    pub translation: [f64; 3],
}

impl AlignmentReport {
    fn new(kind: AlignmentKind, s: &Sim3) -> Self {
        let r = s.rotation_matrix();
        Self {
            kind,
            scale: s.scale,
            rotation: [
                [r[(0, 0)], r[(0, 1)], r[(0, 2)]],
                [r[(1, 0)], r[(1, 1)], r[(1, 2)]],
                [r[(2, 0)], r[(2, 1)], r[(2, 2)]],
            ],
            translation: [s.translation.x, s.translation.y, s.translation.z],
        }
    }
}

/// Everything one evaluation measured (serialised as the `--json` output).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// Absolute pose error.
    pub ape: ApeStats,
    /// Relative pose error; `None` with the reason in `rpe_error` when the step selects no pair.
    pub rpe: Option<RpeStats>,
    /// Why RPE could not be computed, if it could not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rpe_error: Option<String>,
    /// The KITTI metric; `None` when the ground truth is shorter than 100 m.
    pub kitti: Option<KittiMetric>,
    /// The alignment applied.
    pub alignment: AlignmentReport,
    /// Number of pose pairs compared.
    pub matched_poses: usize,
    /// Path length of the (associated) reference, metres.
    pub reference_length_m: f64,
}

/// Associated and aligned trajectories with their per-pose errors (for plots).
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// Associated reference.
    pub reference: Trajectory,
    /// Associated estimate, after alignment.
    pub estimate: Trajectory,
    /// APE series.
    pub ape: Ape,
    /// Summary.
    pub report: Report,
}

/// Aligns `estimate` onto `reference` (pose `i` with pose `i`), returning the transform.
///
/// `Scale` estimates a Sim(3) but applies only its scale, as `evo -s` does.
pub fn align(
    reference: &Trajectory,
    estimate: &Trajectory,
    kind: AlignmentKind,
) -> Result<(Trajectory, Sim3), EvalError> {
    if kind == AlignmentKind::None {
        return Ok((estimate.clone(), Sim3::identity()));
    }
    let with_scale = matches!(kind, AlignmentKind::Sim3 | AlignmentKind::Scale);
    let s = umeyama(&estimate.positions(), &reference.positions(), with_scale)?;
    let applied = if kind == AlignmentKind::Scale {
        Sim3 {
            scale: s.scale,
            ..Sim3::identity()
        }
    } else {
        s
    };
    let poses = estimate
        .poses
        .iter()
        .map(|p| {
            let r = applied.rotation_matrix();
            supermvo_geometry::Pose::new(r * p.r, applied.transform_point(&p.t))
        })
        .collect();
    Ok((
        Trajectory {
            stamps: estimate.stamps.clone(),
            poses,
            quaternions: None,
        },
        applied,
    ))
}

/// Full evaluation of `estimate` against `reference`.
///
/// With timestamps on both sides, poses are associated by nearest stamp; otherwise they are
/// compared index by index and must be equally many.
pub fn evaluate(
    reference: &Trajectory,
    estimate: &Trajectory,
    opts: &EvalOptions,
) -> Result<Evaluation, EvalError> {
    let (reference, estimate) = if reference.stamps.is_some() && estimate.stamps.is_some() {
        associate(reference, estimate, opts.t_max_diff)?
    } else {
        if reference.len() != estimate.len() {
            return Err(EvalError::LengthMismatch {
                reference: reference.len(),
                estimate: estimate.len(),
            });
        }
        (reference.clone(), estimate.clone())
    };
    let (estimate, sim3) = align(&reference, &estimate, opts.align)?;
    let ape_result = ape(&reference.poses, &estimate.poses)?;
    let (rpe_stats, rpe_error) = match rpe(
        &reference.poses,
        &estimate.poses,
        opts.delta,
        opts.delta_unit,
        opts.pairs_from_reference,
    ) {
        Ok(r) => (
            Some(RpeStats {
                trans: r.trans.stats,
                rot_deg: r.rot_deg.stats,
                delta: opts.delta,
                delta_unit: opts.delta_unit,
                pairs: r.pairs.len(),
            }),
            None,
        ),
        Err(EvalError::BadDelta(msg)) => (None, Some(msg)),
        Err(e) => return Err(e),
    };
    let report = Report {
        ape: ApeStats {
            trans: ape_result.trans.stats,
            rot_deg: ape_result.rot_deg.stats,
            full: ape_result.full.stats,
        },
        rpe: rpe_stats,
        rpe_error,
        kitti: kitti_metric(&reference.poses, &estimate.poses),
        alignment: AlignmentReport::new(opts.align, &sim3),
        matched_poses: reference.len(),
        reference_length_m: reference.path_length(),
    };
    Ok(Evaluation {
        reference,
        estimate,
        ape: ape_result,
        report,
    })
}
