//! Revisits: keyframes whose place was seen before leave place recognition, so that the
//! loop closer's memory grows with the places seen, not with the time spent driving
//! through them (see `LoopConfig::cull_revisits`).

use super::{LoopCloser, REVISIT_GAP, TRIANGULATION_KEYFRAMES};

impl LoopCloser {
    /// Frees the place-recognition data of revisits (and all but the VLAD vector of
    /// keyframes with too few triangulated points to be verified as a place) that no later
    /// keyframe triangulates against any more (see `LoopConfig::cull_revisits`); `newest`
    /// is the keyframe just added.
    pub(super) fn cull_revisits(&mut self, newest: usize) {
        // the vocabulary is learned from the first keyframes' descriptors
        if !self.cfg.cull_revisits || self.vocabulary.is_none() {
            return;
        }
        let Some(last) = newest.checked_sub(TRIANGULATION_KEYFRAMES) else {
            return;
        };
        let min_points = self.cfg.min_inliers;
        for kf in &mut self.keyframes[last.saturating_sub(REVISIT_GAP)..=last] {
            if kf.culled {
                continue;
            }
            if kf.revisit.is_some() {
                // a revisit leaves place recognition whole
                kf.culled = true;
                kf.vlad = None;
                kf.release_features();
            } else if kf.desc.nrows() > 0 && kf.points.iter().flatten().count() < min_points {
                // it can never pass a candidate's verification; its VLAD vector stays, so
                // that candidates are ranked as before
                kf.release_features();
            }
        }
    }

    /// Marks keyframe `j` a revisit of `place`, and with it the keyframes since the last
    /// revisit when that one was at most `REVISIT_GAP` keyframes before and revisited the
    /// same stretch of the past: a keyframe driven between two revisits of one stretch is
    /// there too, though its own verification failed (a turn, motion blur).
    pub(super) fn mark_revisit(&mut self, j: usize, place: usize) {
        self.keyframes[j].revisit = Some(place);
        let before = j.saturating_sub(REVISIT_GAP + 1)..j;
        let Some((r, earlier)) = before
            .rev()
            .find_map(|k| self.keyframes[k].revisit.map(|p| (k, p)))
        else {
            return;
        };
        if earlier.abs_diff(place) <= 6 + 2 * (j - r) {
            for kf in &mut self.keyframes[r + 1..j] {
                kf.revisit.get_or_insert(place);
            }
        }
    }

    /// Keyframes that hold their place-recognition data (candidates for later loops).
    pub fn places(&self) -> usize {
        self.keyframes.iter().filter(|k| !k.culled).count()
    }
}
