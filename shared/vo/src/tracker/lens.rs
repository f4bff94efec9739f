//! The tracker's lens: the calibration's pinhole camera and the radial coefficient the
//! tracker learns beyond it from its own local bundle adjustments (self-calibration).
//!
//! A calibration is never exact, and a monocular tracker is very sensitive to the part of
//! the lens model that shapes the rotational flow towards the image's sides: where it is
//! wrong, the landmarks of a turn take depths that are a few percent off, and the scale
//! steps at every turn exit (KITTI's rectified frames read as k1 of about +0.01;
//! docs/decisions/2026-12-07-kitti-lens-residual-and-turn-scale.md). After each local BA
//! the window is asked which k1 it would rather have ([`crate::ba::LocalBa::radial_residual`]:
//! one Gauss-Newton step on k1 with the keyframes and points eliminated), with every
//! keyframe free but the two oldest, so that anchors posed through the old lens do not
//! attenuate the reading. Only a window that turns determines it: under forward motion a
//! radial term and depth trade off, and the readings of straight windows wander. So the
//! tracker keeps the information-weighted mean of the lenses its turning windows ask for
//! (those whose keyframes span `TrackerConfig::lens_min_rotation_deg`, 10 degrees), and
//! starts learning only once that mean stands clear of the calibration by
//! `TrackerConfig::lens_min_k1` (0.005) beyond twice its scatter: keypoint noise biases the
//! readings by up to a few 1e-3 (the rendered `urban-loop` drive, whose lens is exact, reads
//! -0.0016), and the tracker is as sensitive to such a lens error as to the calibration's
//! own. From then on every turning window moves k1 by its own reading (the window as
//! solved, anchors fixed), kept between the calibration and twice the mean that opened the
//! gate, and every observation the map holds is re-read through the new lens, so that old
//! and new observations of a landmark agree (without that, the mixed bearings of the turn
//! in which k1 is learnt step the scale the other way).
//!
//! Frames: bearings are `(x, y, 1)` in the camera frame (normalised coordinates).

use super::Tracker;
use crate::ba::{LocalBa, RadialResidual};
use supermvo_dataset::Calibration;
use supermvo_geometry::{Pose, Vec3};

/// The largest radial coefficient the tracker learns beyond the calibration: a lens that
/// far off needs calibrating, not correcting.
const LENS_MAX_K1: f64 = 0.05;

/// Turning windows the tracker reads before it may start learning (one window's reading
/// can be off by more than a lens error worth correcting).
const LENS_ENGAGE_WINDOWS: usize = 3;

/// The tracker's camera: the calibration's pinhole intrinsics, and the radial coefficient
/// learnt beyond them of normalised coordinates, `x (1 + k1 |x|^2)` (0 until learnt, and
/// without `TrackerConfig::lens_self_calibration`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Lens {
    pub(crate) pinhole: Calibration,
    pub(crate) k1: f64,
}

impl std::ops::Deref for Lens {
    type Target = Calibration;
    fn deref(&self) -> &Calibration {
        &self.pinhole
    }
}

impl From<Calibration> for Lens {
    /// The calibration's pinhole camera, nothing learnt beyond it.
    fn from(pinhole: Calibration) -> Self {
        Self { pinhole, k1: 0.0 }
    }
}

impl Lens {
    /// The pixel where a point `q` in the camera frame (in front of it) is seen.
    pub(crate) fn project(&self, q: &Vec3) -> (f64, f64) {
        let c = &self.pinhole;
        if self.k1 == 0.0 {
            return (c.fx * q.x / q.z + c.cx, c.fy * q.y / q.z + c.cy);
        }
        let (x, y) = (q.x / q.z, q.y / q.z);
        let d = 1.0 + self.k1 * (x * x + y * y);
        (c.fx * x * d + c.cx, c.fy * y * d + c.cy)
    }
}

/// The bearing `(x, y, 1)` of keypoint `p`: its normalised coordinates with the learnt
/// radial term undone (to the last bit: iterated until it stops moving).
pub(crate) fn bearing(c: &Lens, p: &[f32; 2]) -> Vec3 {
    let (xd, yd) = ((p[0] as f64 - c.cx) / c.fx, (p[1] as f64 - c.cy) / c.fy);
    if c.k1 == 0.0 {
        return Vec3::new(xd, yd, 1.0);
    }
    let (mut x, mut y) = (xd, yd);
    for _ in 0..50 {
        let d = 1.0 + c.k1 * (x * x + y * y);
        let next = (xd / d, yd / d);
        if next == (x, y) {
            break;
        }
        (x, y) = next;
    }
    Vec3::new(x, y, 1.0)
}

/// The bearing through `to` of the keypoint whose bearing through `from` is `b`: bit for
/// bit what [`bearing`] gives for that keypoint through `to`. The keypoint is recovered to
/// its `f32` pixel: the round trip is good to about 1e-10 px, within half of `f32`'s step
/// anywhere but the last micro-pixel before 0, which is taken as 0.
pub(crate) fn rebearing(from: &Lens, to: &Lens, b: &Vec3) -> Vec3 {
    let pixel = |c: f64| if c.abs() < 1e-6 { 0.0 } else { c as f32 };
    let (u, v) = from.project(b);
    bearing(to, &[pixel(u), pixel(v)])
}

/// The largest rotation between two of `poses`, in degrees.
fn rotation_span_deg<'a>(poses: impl Iterator<Item = &'a Pose> + Clone) -> f64 {
    let mut widest: f64 = 0.0;
    for (i, a) in poses.clone().enumerate() {
        for b in poses.clone().skip(i + 1) {
            let cos = (((a.r.transpose() * b.r).trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
            widest = widest.max(cos.acos().to_degrees());
        }
    }
    widest
}

/// How far the free keyframes of a window turn: the largest rotation between two of them,
/// in degrees (the fixed anchors may be older keyframes from before a turn).
fn window_rotation_deg(ba: &LocalBa) -> f64 {
    rotation_span_deg(
        ba.poses
            .iter()
            .zip(&ba.fixed)
            .filter(|(_, &f)| !f)
            .map(|(p, _)| p),
    )
}

/// The window's reading with every keyframe free but the two oldest (`ids`: each pose's
/// keyframe id), so that the anchors, posed through the old lens, do not attenuate it.
fn freed_reading(ba: &LocalBa, ids: &[usize]) -> Option<RadialResidual> {
    let mut order: Vec<usize> = (0..ids.len()).collect();
    order.sort_by_key(|&i| ids[i]);
    let mut freed = ba.clone();
    freed.fixed = vec![false; ids.len()];
    for &i in order.iter().take(2) {
        freed.fixed[i] = true;
    }
    freed.radial_residual()
}

impl Tracker {
    /// Reads what a solved window says about the lens (`TrackerConfig::lens_check`), and
    /// with `TrackerConfig::lens_self_calibration` learns from a window that turns (see the
    /// module docs).
    pub(crate) fn read_lens(&mut self, ba: &LocalBa, ids: &[usize]) {
        if !(self.cfg.lens_check || self.cfg.lens_self_calibration) {
            return;
        }
        // every window's reading is a diagnostic (`lens_check`); learning needs only the
        // turning windows'
        let checked = self.cfg.lens_check.then(|| ba.radial_residual());
        if let Some(reading) = checked {
            self.lens_readings.all.add(reading);
        }
        let span_deg = window_rotation_deg(ba);
        if span_deg < self.cfg.lens_min_rotation_deg {
            return;
        }
        let keyframe = self.map.keyframe_poses.len() - 1;
        if self.lens_readings.engaged.is_none() {
            let turning = &mut self.lens_readings.turning;
            turning.add(freed_reading(ba, ids));
            let Some(mean) = turning.mean() else {
                return;
            };
            let engaged = turning.windows >= LENS_ENGAGE_WINDOWS
                && mean.abs() - 2.0 * turning.scatter() >= self.cfg.lens_min_k1;
            tracing::debug!(keyframe, mean, span_deg, engaged, "lens read");
            if !(engaged && self.cfg.lens_self_calibration) {
                return;
            }
            self.lens_readings.engaged = Some(mean);
        }
        let Some(evidence) = self.lens_readings.engaged else {
            return;
        };
        let Some(r) = checked.unwrap_or_else(|| ba.radial_residual()) else {
            return;
        };
        // between the calibration and twice what the turning windows read
        let (low, high) = (evidence.min(0.0) * 2.0, evidence.max(0.0) * 2.0);
        let k1 = (self.calib.k1 + r.k1)
            .clamp(low, high)
            .clamp(-LENS_MAX_K1, LENS_MAX_K1);
        tracing::debug!(keyframe, reading = r.k1, k1, span_deg, "lens learnt");
        self.set_lens_k1(k1);
    }

    /// Sees through a lens with radial coefficient `k1` from now on, and re-reads every
    /// observation the map holds through it.
    fn set_lens_k1(&mut self, k1: f64) {
        if !k1.is_finite() || k1 == self.calib.k1 {
            return;
        }
        let old = self.calib;
        self.calib.k1 = k1;
        let new = self.calib;
        self.map.remap_bearings(|b| rebearing(&old, &new, b));
    }

    /// What the local BAs so far say about the lens (with `TrackerConfig::lens_check` or
    /// `lens_self_calibration`; `None` when both are off).
    pub fn lens_residual(&self) -> Option<LensResidual> {
        (self.cfg.lens_check || self.cfg.lens_self_calibration)
            .then(|| self.lens_readings.summary(self.calib.k1))
    }
}

/// The radial coefficient a run's local BAs ask for beyond the tracker's lens
/// ([`Tracker::lens_residual`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LensResidual {
    /// Information-weighted mean of the windows' readings (normalised coordinates,
    /// `x (1 + k1 |x|^2)`), each beyond the lens of its moment (with
    /// `TrackerConfig::lens_check`; `None` without, or when no window determined it).
    pub k1: Option<f64>,
    /// Its standard error were the windows independent (they share observations, so the
    /// true one is larger).
    pub std_error: Option<f64>,
    /// Windows that determined it.
    pub windows: usize,
    /// Information-weighted mean of the turning windows' unattenuated readings (every
    /// keyframe free but the two oldest), beyond the calibration, until the tracker
    /// engaged (`None`: no window turned enough). Unlike `k1`, about the lens error itself.
    pub turning_k1: Option<f64>,
    /// Turning windows in `turning_k1`.
    pub turning_windows: usize,
    /// The radial coefficient the tracker had learnt beyond the calibration at the end
    /// (`TrackerConfig::lens_self_calibration`; 0 without).
    pub learnt_k1: f64,
}

/// The readings accumulated over a run.
#[derive(Debug, Clone, Default)]
pub(crate) struct LensReadings {
    /// Every window's reading, each beyond the lens of its moment.
    all: Mean,
    /// The turning windows' unattenuated readings before the tracker engaged.
    turning: Mean,
    /// The turning windows' mean once it showed a lens error worth learning
    /// (`TrackerConfig::lens_min_k1`); from then on each turning window teaches, within
    /// the calibration and twice that mean.
    engaged: Option<f64>,
}

/// An information-weighted mean of readings.
#[derive(Debug, Clone, Default)]
struct Mean {
    weighted: f64,
    information: f64,
    variance: f64,
    windows: usize,
    /// The readings' sum and sum of squares, unweighted.
    sum: f64,
    sum_sq: f64,
}

impl Mean {
    fn add(&mut self, reading: Option<RadialResidual>) {
        let Some(r) = reading.filter(|r| r.k1.is_finite() && r.information.is_finite()) else {
            return;
        };
        self.weighted += r.information * r.k1;
        self.information += r.information;
        self.variance += r.residual_variance;
        self.windows += 1;
        self.sum += r.k1;
        self.sum_sq += r.k1 * r.k1;
    }

    /// The standard error of the readings' mean from their scatter (the readings'
    /// standard deviation over the square root of their number).
    fn scatter(&self) -> f64 {
        let n = self.windows as f64;
        if self.windows < 2 {
            return f64::INFINITY;
        }
        let var = (self.sum_sq - self.sum * self.sum / n) / (n - 1.0);
        (var.max(0.0) / n).sqrt()
    }

    fn mean(&self) -> Option<f64> {
        (self.windows > 0 && self.information > 0.0).then(|| self.weighted / self.information)
    }

    /// Its standard error were the windows independent.
    fn std_error(&self) -> f64 {
        (self.variance / self.windows as f64 / self.information).sqrt()
    }
}

impl LensReadings {
    /// The readings so far, with the tracker's learnt radial coefficient `learnt_k1`.
    fn summary(&self, learnt_k1: f64) -> LensResidual {
        let k1 = self.all.mean();
        LensResidual {
            k1,
            std_error: k1.map(|_| self.all.std_error()),
            windows: self.all.windows,
            turning_k1: self.turning.mean(),
            turning_windows: self.turning.windows,
            learnt_k1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lens(k1: f64) -> Lens {
        Lens {
            pinhole: Calibration {
                fx: 718.856,
                fy: 718.856,
                cx: 607.19,
                cy: 185.22,
            },
            k1,
        }
    }

    /// A bearing re-read through a new lens is the one the keypoint gives through it, to
    /// the bit (the map's observations stay comparable with fresh ones).
    #[test]
    fn a_rebearing_is_the_keypoints_bearing_through_the_new_lens() {
        let (a, b) = (lens(0.0), lens(0.013));
        for p in [
            [0.0f32, 0.0],
            [1240.5, 375.25],
            [611.0, 190.0],
            [3.75, 370.5],
        ] {
            let through_b = bearing(&b, &p);
            assert_eq!(rebearing(&a, &b, &bearing(&a, &p)), through_b, "{p:?}");
            assert_eq!(rebearing(&b, &a, &through_b), bearing(&a, &p), "{p:?}");
            let (u, v) = b.project(&through_b);
            assert!((u - p[0] as f64).abs() < 1e-9 && (v - p[1] as f64).abs() < 1e-9);
        }
    }

    #[test]
    fn the_rotation_span_is_the_widest_pair() {
        let yaw = |deg: f64| Pose {
            r: *nalgebra::Rotation3::from_euler_angles(0.0, deg.to_radians(), 0.0).matrix(),
            t: Vec3::zeros(),
        };
        let span = rotation_span_deg([yaw(5.0), yaw(-10.0), yaw(12.0)].iter());
        assert!((span - 22.0).abs() < 1e-9, "{span}");
        assert_eq!(rotation_span_deg([yaw(3.0)].iter()), 0.0);
    }
}
