//! The in-process pipeline: extractor, matcher, tracker and loop closer one after the other,
//! and the loop closer's feedback to the tracker (the daemon runs the same loop closer in its
//! back-end process and sends the corrections back over shared memory).

use crate::stage::Stage;
use crate::tracker::{FrameInput, FrameMeta, FrameOutput, Tracker};
use supermvo_inference::{Extractor, FrameView, InferenceError, Matcher};

/// Extractor, matcher and tracker in one process, one after the other: the reference
/// implementation the multi-process daemon must reproduce bit for bit.
pub struct VoPipeline {
    extractor: Box<dyn Extractor + Send>,
    matcher: Box<dyn Matcher + Send>,
    tracker: Tracker,
    loops: Option<crate::loops::LoopCloser>,
    /// Whether each frame's [`FrameView`] is kept (for recording), and the last one.
    keep_views: bool,
    view: Option<FrameView>,
}

impl std::fmt::Debug for VoPipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "VoPipeline({:?}, {:?})", self.tracker, self.loops)
    }
}

impl VoPipeline {
    /// A pipeline over the given front end; with a loop closer, keyframes go to it and its
    /// corrections go back to the tracker.
    pub fn new(
        extractor: Box<dyn Extractor + Send>,
        matcher: Box<dyn Matcher + Send>,
        tracker: Tracker,
        loops: Option<crate::loops::LoopCloser>,
    ) -> Self {
        Self {
            extractor,
            matcher,
            tracker,
            loops,
            keep_views: false,
            view: None,
        }
    }

    /// Keeps a [`FrameView`] of every frame (keypoints, match flow, the map's points on
    /// keyframes) for [`VoPipeline::take_view`]; off by default, as it copies the keypoints.
    pub fn keep_views(mut self) -> Self {
        self.keep_views = true;
        self
    }

    /// The last frame's view, when views are kept.
    pub fn take_view(&mut self) -> Option<FrameView> {
        self.view.take()
    }

    /// The loop closer, when there is one.
    pub fn loop_closer(&self) -> Option<&crate::loops::LoopCloser> {
        self.loops.as_ref()
    }

    /// The tracker.
    pub fn tracker(&self) -> &Tracker {
        &self.tracker
    }
}

/// Hands one tracked frame to the loop closer and applies the correction it returns to the
/// tracker before the next frame (the daemon's lossless hand-off reproduces this order). The
/// loop closer takes keyframes and lost frames; the caller keeps every frame's pose (with
/// the corrections applied when it was reported, [`crate::loops::LoopCloser::corrections`]
/// before the frame) for [`crate::loops::LoopCloser::trajectory`].
pub fn close_loops(
    loops: &mut crate::loops::LoopCloser,
    tracker: &mut Tracker,
    out: &FrameOutput,
) -> Option<crate::loops::Correction> {
    if out.state == crate::tracker::TrackingState::Lost {
        loops.add_lost_frame();
    }
    let pose = out.t_world_cam.filter(|_| out.keyframe)?;
    let (_, features) = tracker.reference()?;
    let correction = loops.add_keyframe(out.index, &pose, features)?;
    tracker.apply_correction(&correction.sim3);
    Some(correction)
}

impl Stage for VoPipeline {
    type Input = FrameInput;
    type Output = FrameOutput;
    type Error = InferenceError;

    fn name(&self) -> &'static str {
        "vo"
    }

    fn process(&mut self, input: FrameInput) -> Result<FrameOutput, InferenceError> {
        let cur = self.extractor.extract(&input.image)?;
        let meta = FrameMeta {
            index: input.index,
            stamp: input.stamp,
        };
        let mut view = self.keep_views.then(|| FrameView::new(&cur, None));
        let matcher = &mut self.matcher;
        let out = self.tracker.track_frame(meta, cur, |reference, cur| {
            let m = matcher.match_features(reference, cur)?;
            if let Some(v) = view.as_mut() {
                v.set_flow(reference, cur, &m);
            }
            Ok(m)
        })?;
        if let Some(v) = view.as_mut().filter(|_| out.keyframe) {
            v.map_points = Some(self.tracker.map_points());
        }
        self.view = view;
        if let Some(loops) = self.loops.as_mut() {
            close_loops(loops, &mut self.tracker, &out);
        }
        Ok(out)
    }
}
