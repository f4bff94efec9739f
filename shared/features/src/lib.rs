//! Keypoints, descriptors and matches: what every front end (learned or ORB) produces and
//! every later stage reads. A crate of its own, without ONNX Runtime, so that the message
//! definitions, the tracker and the tools that only move or read features do not link the
//! inference runtime.

/// ORB's 256-bit descriptor stored as this many bit-cast `f32` words (how the ORB baseline
/// shares the float descriptor layout of the learned extractors).
pub const ORB_WORDS: usize = 8;

/// Keypoints of one image with their scores and L2-normalised descriptors.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Features {
    /// Keypoint positions `(x, y)` in pixels of the input image.
    pub keypoints: Vec<[f32; 2]>,
    /// Detection scores, one per keypoint, in descending order.
    pub scores: Vec<f32>,
    /// Descriptors, `keypoints.len() * dim` values, row per keypoint.
    pub descriptors: Vec<f32>,
    /// Descriptor length.
    pub dim: usize,
    /// `(width, height)` of the image the features come from.
    pub image_size: (usize, usize),
}

impl Features {
    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    /// True when there are no keypoints.
    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    /// Descriptor of keypoint `i`.
    pub fn descriptor(&self, i: usize) -> &[f32] {
        &self.descriptors[i * self.dim..(i + 1) * self.dim]
    }

    /// The `k` strongest keypoints (the first `k`: scores are in descending order) with
    /// their scores and descriptors; these features themselves, not a copy, when there are
    /// no more than `k`.
    pub fn strongest(&self, k: usize) -> std::borrow::Cow<'_, Features> {
        if self.len() <= k {
            return std::borrow::Cow::Borrowed(self);
        }
        std::borrow::Cow::Owned(Features {
            keypoints: self.keypoints[..k].to_vec(),
            scores: self.scores[..k].to_vec(),
            descriptors: self.descriptors[..k * self.dim].to_vec(),
            dim: self.dim,
            image_size: self.image_size,
        })
    }

    /// Moves every keypoint to `to(x, y)`, dropping (with its score and descriptor) each
    /// one for which it gives `None`; the order of the rest is kept.
    pub fn map_keypoints(&mut self, to: impl Fn(f32, f32) -> Option<[f32; 2]>) {
        let dim = self.dim;
        let mut kept = 0;
        for i in 0..self.keypoints.len() {
            let [x, y] = self.keypoints[i];
            let Some(p) = to(x, y) else {
                continue;
            };
            self.keypoints[kept] = p;
            self.scores[kept] = self.scores[i];
            self.descriptors
                .copy_within(i * dim..(i + 1) * dim, kept * dim);
            kept += 1;
        }
        self.keypoints.truncate(kept);
        self.scores.truncate(kept);
        self.descriptors.truncate(kept * dim);
    }
}

/// Normalised distance between two descriptors of one front end, in [0, 1]: `1 - cos` for
/// float (L2-normalised) descriptors, the Hamming distance / 256 for ORB's 256 bits stored
/// as [`ORB_WORDS`] bit-cast words.
pub fn descriptor_distance(a: &[f32], b: &[f32]) -> f32 {
    if a.len() == ORB_WORDS {
        let bits: u32 = a
            .iter()
            .zip(b)
            .map(|(x, y)| (x.to_bits() ^ y.to_bits()).count_ones())
            .sum();
        bits as f32 / 256.0
    } else {
        1.0 - a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>()
    }
}

/// Matches between two feature sets.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Matches {
    /// `(index in first set, index in second set)`.
    pub pairs: Vec<(usize, usize)>,
    /// Confidence of each pair.
    pub scores: Vec<f32>,
}

/// What a diagnostic view draws of one tracked frame (`supermvo run --record`, `supermvo
/// record`, `supermvo view`): its keypoints, the flow of its matches to the reference
/// keyframe, and, when it became a keyframe, the local map's points.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameView {
    /// Keypoints of the frame, pixels.
    pub keypoints: Vec<[f32; 2]>,
    /// Per match to the reference keyframe: `[x_ref, y_ref, x, y]`, pixels (none for a
    /// frame tracked by projection without the matcher).
    pub flow: Vec<[f32; 4]>,
    /// Positions (world frame) of the local map's points, on keyframes only.
    pub map_points: Option<Vec<[f32; 3]>>,
}

impl FrameView {
    /// The view of frame `cur` with `matches` to `reference`.
    pub fn new(cur: &Features, reference: Option<(&Features, &Matches)>) -> Self {
        let mut view = Self {
            keypoints: cur.keypoints.clone(),
            flow: Vec::new(),
            map_points: None,
        };
        if let Some((r, m)) = reference {
            view.set_flow(r, cur, m);
        }
        view
    }

    /// The flow of `matches` from `reference` to `cur` (`cur`'s keypoints are this view's).
    pub fn set_flow(&mut self, reference: &Features, cur: &Features, m: &Matches) {
        self.flow = m
            .pairs
            .iter()
            .filter_map(|&(a, b)| {
                let (p, q) = (reference.keypoints.get(a)?, cur.keypoints.get(b)?);
                Some([p[0], p[1], q[0], q[1]])
            })
            .collect();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_strongest_keypoints_are_the_first_with_their_scores_and_descriptors() {
        let f = Features {
            keypoints: vec![[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]],
            scores: vec![0.9, 0.5, 0.1],
            descriptors: vec![1.0, 0.0, 0.0, 1.0, 0.6, 0.8],
            dim: 2,
            image_size: (10, 8),
        };
        let two = f.strongest(2);
        assert_eq!(two.keypoints, vec![[1.0, 2.0], [3.0, 4.0]]);
        assert_eq!(two.scores, vec![0.9, 0.5]);
        assert_eq!(two.descriptors, vec![1.0, 0.0, 0.0, 1.0]);
        assert_eq!((two.dim, two.image_size), (2, (10, 8)));
        assert_eq!(*f.strongest(3), f);
        assert_eq!(*f.strongest(100), f);
        assert!(f.strongest(0).is_empty());
    }

    #[test]
    fn mapping_keypoints_drops_the_unmapped_with_their_scores_and_descriptors() {
        let mut f = Features {
            keypoints: vec![[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]],
            scores: vec![0.9, 0.8, 0.7],
            descriptors: vec![1.0, 0.0, 0.0, 1.0, 0.6, 0.8],
            dim: 2,
            image_size: (10, 10),
        };
        f.map_keypoints(|x, y| (x != 2.0).then_some([x + 0.5, y * 2.0]));
        assert_eq!(f.keypoints, vec![[1.5, 2.0], [3.5, 6.0]]);
        assert_eq!(f.scores, vec![0.9, 0.7]);
        assert_eq!(f.descriptors, vec![1.0, 0.0, 0.6, 0.8]);
        assert_eq!(f.len(), 2);
    }
}
