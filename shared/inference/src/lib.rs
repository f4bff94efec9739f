//! Learned keypoints and matching on ONNX Runtime.
//!
//! * [`runtime`]: finds and loads the ONNX Runtime shared library (`load-dynamic`): the
//!   path given, `ORT_DYLIB_PATH`, or the copy `supermvo models fetch onnxruntime` unpacks
//!   from the PyPI wheel into the cache.
//! * [`Extractor`] (image -> keypoints, scores, descriptors) and [`Matcher`] (two feature
//!   sets -> index pairs and scores): the interfaces every front end implements.
//! * [`xfeat::XFeat`]: XFeat (Potje et al., CVPR 2024) over an `ort` session, with the
//!   reference post-processing (softmax heatmap, 5x5 NMS, reliability-weighted scores,
//!   top-k, bicubic descriptor sampling) written in Rust.
//! * [`aliked::Aliked`]: ALIKED (the extractor LightGlue was trained with), detection and
//!   deformable descriptors in one graph; [`lighterglue::LightGlue`] runs both LighterGlue
//!   and LightGlue.

pub mod aliked;
mod error;
pub mod lighterglue;
pub mod models;
pub mod orb;
pub mod runtime;
pub mod superglue;
pub mod superpoint;
pub mod xfeat;

pub use error::InferenceError;
pub use supermvo_dataset::GrayImage;

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
}

/// Normalised distance between two descriptors of one front end, in [0, 1]: `1 - cos` for
/// float (L2-normalised) descriptors, the Hamming distance / 256 for ORB's 256 bits stored
/// as [`orb::ORB_WORDS`] bit-cast words.
pub fn descriptor_distance(a: &[f32], b: &[f32]) -> f32 {
    if a.len() == orb::ORB_WORDS {
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

/// Detects keypoints and computes descriptors.
pub trait Extractor {
    /// Features of one image. Any image size is accepted; an empty image is an error.
    fn extract(&mut self, image: &GrayImage) -> Result<Features, InferenceError>;
}

/// Matches two feature sets.
pub trait Matcher {
    /// Matches `a` against `b`.
    fn match_features(&mut self, a: &Features, b: &Features) -> Result<Matches, InferenceError>;
}
