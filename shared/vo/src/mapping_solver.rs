//! Where the local mapping's computations run when not in the tracker's own thread: the
//! daemon's back-end process (`supermvo_pipeline::remote_mapping`) triangulates each new
//! keyframe's landmarks and solves its local bundle adjustment. The tracker keeps the map
//! and its bookkeeping (which keypoint observes which landmark); what it hands over are
//! pure computations on numbers it sends, so a solver that answers at once gives exactly
//! what the tracker would have computed, and a run does not depend on where they ran.

use crate::ba::{BaOutcome, LocalBa};
use supermvo_geometry::essential::{triangulate_checked, Triangulated};
use supermvo_geometry::{Pose, Vec3};

/// One keyframe's triangulations: the keyframes' poses and, per query, the views of one
/// point `(pose index, bearing)`. Each query is triangulated by
/// [`supermvo_geometry::essential::triangulate_checked`] with the reprojection gate
/// `max_error` (normalised image units).
#[derive(Debug, Clone, PartialEq)]
pub struct TriangulationBatch {
    /// `T_cam_world` of each keyframe the queries name.
    pub poses: Vec<Pose>,
    /// Per point, its views `(index into poses, normalised bearing (x, y, 1))`.
    pub queries: Vec<Vec<(usize, Vec3)>>,
    /// Reprojection gate, normalised image units (pixels / focal).
    pub max_error: f64,
}

impl TriangulationBatch {
    /// Every query triangulated here: the point and its parallax, or `None` where it lies
    /// behind a view, misses the gate in one, or names a pose the batch lacks.
    pub fn solve(&self) -> Vec<Option<Triangulated>> {
        self.queries
            .iter()
            .map(|views| triangulate_views(|k| self.poses.get(k), views, self.max_error))
            .collect()
    }
}

/// The point that `views` `(keyframe, bearing)` triangulate to with the keyframes'
/// `T_cam_world` from `pose` ([`triangulate_checked`] with the gate `max_error`; `None` when
/// a keyframe has no pose). The one computation behind the tracker's own triangulations
/// and a batch's, so the two agree bit for bit.
pub(crate) fn triangulate_views<'a>(
    pose: impl Fn(usize) -> Option<&'a Pose>,
    views: &[(usize, Vec3)],
    max_error: f64,
) -> Option<Triangulated> {
    let views = views
        .iter()
        .map(|(k, b)| pose(*k).map(|p| (p.r, p.t, *b)))
        .collect::<Option<Vec<_>>>()?;
    triangulate_checked(&views, max_error)
}

/// Where the tracker's local mapping runs (see the module docs). A solver that answers at
/// once must give exactly what [`LocalBa::solve`] and [`TriangulationBatch::solve`] give
/// here.
pub trait MappingSolver {
    /// Solves `ba` in place with up to `iterations` iterations, or hands it off.
    fn solve(&mut self, ba: &mut LocalBa, iterations: usize) -> BaOutcome;

    /// Whether the solver takes a keyframe's triangulations at once (the tracker then hands
    /// them over; otherwise it does not build them). The default: no, only the bundle
    /// adjustment.
    fn triangulates(&self) -> bool {
        false
    }

    /// Triangulates every query of `batch` (in order), or `None` when it cannot answer now:
    /// the tracker then triangulates them itself, with the same result. Asked only of a
    /// solver that [`MappingSolver::triangulates`]; the default answers `None`.
    fn triangulate(&mut self, batch: &TriangulationBatch) -> Option<Vec<Option<Triangulated>>> {
        let _ = batch;
        None
    }
}
