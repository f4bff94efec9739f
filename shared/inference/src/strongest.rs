//! A matcher that sees only the strongest keypoints of each set: extraction can keep more
//! keypoints than the matcher is given (`pipeline.matcher_top_k` below `pipeline.top_k`),
//! so the tracker finds its landmarks among all of them by projection while the matcher's
//! cost, which grows with the keypoints it is given, stays that of the smaller set.
//!
//! The indices of the matches are those of the full sets: the strongest keypoints come
//! first ([`Features::strongest`]).

use crate::{Features, InferenceError, Matcher, Matches};

/// `inner` given the `k` strongest keypoints of each set.
pub struct StrongestOnly<M> {
    inner: M,
    k: usize,
}

impl<M> std::fmt::Debug for StrongestOnly<M> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "StrongestOnly({})", self.k)
    }
}

impl<M: Matcher> StrongestOnly<M> {
    /// Matches with `inner` on the `k` strongest keypoints of each set.
    pub fn new(inner: M, k: usize) -> Self {
        Self { inner, k }
    }
}

impl<M: Matcher> Matcher for StrongestOnly<M> {
    fn match_features(&mut self, a: &Features, b: &Features) -> Result<Matches, InferenceError> {
        self.inner
            .match_features(&a.strongest(self.k), &b.strongest(self.k))
    }

    fn warm_up(&mut self, a: &Features, b: &Features) -> Result<(), InferenceError> {
        self.inner
            .warm_up(&a.strongest(self.k), &b.strongest(self.k))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Records the sizes it is given and matches keypoint i to keypoint i.
    #[derive(Default)]
    struct Diagonal {
        seen: Vec<(usize, usize)>,
    }

    impl Matcher for Diagonal {
        fn match_features(
            &mut self,
            a: &Features,
            b: &Features,
        ) -> Result<Matches, InferenceError> {
            self.seen.push((a.len(), b.len()));
            let n = a.len().min(b.len());
            Ok(Matches {
                pairs: (0..n).map(|i| (i, i)).collect(),
                scores: vec![1.0; n],
            })
        }
    }

    fn features(n: usize) -> Features {
        Features {
            keypoints: (0..n).map(|i| [i as f32, 0.0]).collect(),
            scores: (0..n).map(|i| 1.0 - i as f32 / n as f32).collect(),
            descriptors: vec![0.5; n * 4],
            dim: 4,
            image_size: (640, 480),
        }
    }

    #[test]
    fn the_matcher_is_given_the_strongest_keypoints_and_its_indices_hold() {
        let mut m = StrongestOnly::new(Diagonal::default(), 3);
        let out = m.match_features(&features(5), &features(4)).unwrap();
        assert_eq!(out.pairs, vec![(0, 0), (1, 1), (2, 2)]);
        m.warm_up(&features(2), &features(8)).unwrap();
        assert_eq!(m.inner.seen, vec![(3, 3), (2, 3)]);
    }
}
