//! Absolute and relative pose errors with the definitions of evo (Grupp, 2017):
//!
//! * APE: `E_i = P_i^-1 Q_i` (estimate P, reference Q); translation error `|t_P - t_Q|`,
//!   rotation error = angle of `R(E_i)`, full error `|E_i - I|_F`.
//! * RPE: `E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)` over index pairs `(i, j)` chosen `delta`
//!   frames or metres apart along the path of the estimate (or the reference).

use crate::{EvalError, Stats};
use serde::{Deserialize, Serialize};
use supermvo_geometry::{rotation_angle, Pose};

/// Unit of the RPE step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum DeltaUnit {
    /// Index distance.
    #[default]
    Frames,
    /// Travelled path length.
    Meters,
}

/// Per-pose errors and their statistics.
#[derive(Debug, Clone, PartialEq)]
pub struct ErrorSeries {
    /// One error per pose (APE) or per pair (RPE).
    pub values: Vec<f64>,
    /// Statistics of `values`.
    pub stats: Stats,
}

impl ErrorSeries {
    fn new(values: Vec<f64>) -> Result<Self, EvalError> {
        let stats = Stats::of(&values).ok_or(EvalError::NoPairs)?;
        Ok(Self { values, stats })
    }
}

/// APE of an (already associated and aligned) estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct Ape {
    /// Translation error, metres.
    pub trans: ErrorSeries,
    /// Rotation angle error, degrees.
    pub rot_deg: ErrorSeries,
    /// Frobenius norm of `E - I` (unitless).
    pub full: ErrorSeries,
}

/// RPE of an (already associated and aligned) estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct Rpe {
    /// Translation error of the relative motion, metres.
    pub trans: ErrorSeries,
    /// Rotation angle error of the relative motion, degrees.
    pub rot_deg: ErrorSeries,
    /// The `(i, j)` pairs evaluated.
    pub pairs: Vec<(usize, usize)>,
}

fn check_lengths(reference: &[Pose], estimate: &[Pose]) -> Result<(), EvalError> {
    if reference.len() != estimate.len() {
        return Err(EvalError::LengthMismatch {
            reference: reference.len(),
            estimate: estimate.len(),
        });
    }
    if reference.is_empty() {
        return Err(EvalError::NoPairs);
    }
    Ok(())
}

fn frobenius_from_identity(e: &Pose) -> f64 {
    let m = e.to_matrix() - nalgebra::Matrix4::identity();
    m.norm()
}

/// Absolute pose error of `estimate` against `reference`, pose by pose.
pub fn ape(reference: &[Pose], estimate: &[Pose]) -> Result<Ape, EvalError> {
    check_lengths(reference, estimate)?;
    let n = reference.len();
    let (mut tr, mut rot, mut full) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    for (q, p) in reference.iter().zip(estimate) {
        tr.push((p.t - q.t).norm());
        let e = p.between(q);
        rot.push(rotation_angle(&e.r).to_degrees());
        full.push(frobenius_from_identity(&e));
    }
    Ok(Ape {
        trans: ErrorSeries::new(tr)?,
        rot_deg: ErrorSeries::new(rot)?,
        full: ErrorSeries::new(full)?,
    })
}

/// Index pairs `delta` apart. Frames: `(0, d), (d, 2d), ...`. Metres: consecutive
/// poses at which the path travelled since the previous one first reaches `delta`.
pub fn delta_pairs(
    poses: &[Pose],
    delta: f64,
    unit: DeltaUnit,
) -> Result<Vec<(usize, usize)>, EvalError> {
    let ids: Vec<usize> = match unit {
        DeltaUnit::Frames => {
            if delta < 1.0 || delta.fract() != 0.0 {
                return Err(EvalError::BadDelta(format!(
                    "a frame delta must be a positive integer, got {delta}"
                )));
            }
            (0..poses.len()).step_by(delta as usize).collect()
        }
        DeltaUnit::Meters => {
            if delta <= 0.0 || !delta.is_finite() {
                return Err(EvalError::BadDelta(format!(
                    "a metre delta must be positive, got {delta}"
                )));
            }
            let mut ids = vec![0];
            let mut path = 0.0;
            for i in 1..poses.len() {
                path += (poses[i].t - poses[i - 1].t).norm();
                if path >= delta {
                    ids.push(i);
                    path = 0.0;
                }
            }
            ids
        }
    };
    let pairs: Vec<(usize, usize)> = ids.windows(2).map(|w| (w[0], w[1])).collect();
    if pairs.is_empty() {
        let unit = match unit {
            DeltaUnit::Frames => "frames",
            DeltaUnit::Meters => "m",
        };
        return Err(EvalError::BadDelta(format!(
            "delta = {delta} {unit} gives no pose pairs on this trajectory ({} poses); use a smaller delta",
            poses.len()
        )));
    }
    Ok(pairs)
}

/// Relative pose error over pairs chosen on the estimate (evo's default) or the reference.
pub fn rpe(
    reference: &[Pose],
    estimate: &[Pose],
    delta: f64,
    unit: DeltaUnit,
    pairs_from_reference: bool,
) -> Result<Rpe, EvalError> {
    check_lengths(reference, estimate)?;
    let pairs = delta_pairs(
        if pairs_from_reference {
            reference
        } else {
            estimate
        },
        delta,
        unit,
    )?;
    let mut tr = Vec::with_capacity(pairs.len());
    let mut rot = Vec::with_capacity(pairs.len());
    for &(i, j) in &pairs {
        let q_rel = reference[i].between(&reference[j]);
        let p_rel = estimate[i].between(&estimate[j]);
        let e = q_rel.between(&p_rel);
        tr.push(e.t.norm());
        rot.push(rotation_angle(&e.r).to_degrees());
    }
    Ok(Rpe {
        trans: ErrorSeries::new(tr)?,
        rot_deg: ErrorSeries::new(rot)?,
        pairs,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use supermvo_geometry::{so3_exp, Vec3};

    #[test]
    fn ape_of_offset_trajectory() {
        let reference: Vec<Pose> = (0..10)
            .map(|i| {
                Pose::new(
                    so3_exp(&Vec3::new(0.0, 0.1 * i as f64, 0.0)),
                    Vec3::new(i as f64, 0.0, 0.0),
                )
            })
            .collect();
        let estimate: Vec<Pose> = reference
            .iter()
            .map(|p| {
                Pose::new(
                    p.r * so3_exp(&Vec3::new(0.0, 0.0, 0.01)),
                    p.t + Vec3::new(0.0, 0.5, 0.0),
                )
            })
            .collect();
        let a = ape(&reference, &estimate).unwrap();
        assert!((a.trans.stats.rmse - 0.5).abs() < 1e-12);
        assert!((a.rot_deg.stats.max - 0.01f64.to_degrees()).abs() < 1e-9);
        assert!(matches!(
            ape(&reference, &estimate[..3]),
            Err(EvalError::LengthMismatch { .. })
        ));
    }

    #[test]
    fn pairs_by_frames_and_meters() {
        let poses: Vec<Pose> = (0..11)
            .map(|i| {
                Pose::new(
                    supermvo_geometry::Mat3::identity(),
                    Vec3::new(i as f64 * 0.6, 0.0, 0.0),
                )
            })
            .collect();
        assert_eq!(
            delta_pairs(&poses, 5.0, DeltaUnit::Frames).unwrap(),
            vec![(0, 5), (5, 10)]
        );
        // every 2 poses travel 1.2 m >= 1 m
        assert_eq!(
            delta_pairs(&poses, 1.0, DeltaUnit::Meters).unwrap(),
            vec![(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
        );
        assert!(delta_pairs(&poses, 100.0, DeltaUnit::Meters).is_err());
        assert!(delta_pairs(&poses, 1.5, DeltaUnit::Frames).is_err());
    }

    #[test]
    fn rpe_of_scaled_motion() {
        let reference: Vec<Pose> = (0..5)
            .map(|i| {
                Pose::new(
                    supermvo_geometry::Mat3::identity(),
                    Vec3::new(i as f64, 0.0, 0.0),
                )
            })
            .collect();
        let estimate: Vec<Pose> = reference
            .iter()
            .map(|p| Pose::new(p.r, p.t * 1.1))
            .collect();
        let r = rpe(&reference, &estimate, 1.0, DeltaUnit::Frames, false).unwrap();
        assert_eq!(r.pairs.len(), 4);
        assert!((r.trans.stats.mean - 0.1).abs() < 1e-12);
    }
}
