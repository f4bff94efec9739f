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
//! * [`strongest::StrongestOnly`]: a matcher given only the strongest keypoints of each set.

pub mod aliked;
pub mod cache;
mod error;
pub mod lighterglue;
pub mod models;
pub mod orb;
pub mod runtime;
pub mod strongest;
pub mod superglue;
pub mod superpoint;
pub mod xfeat;

pub use error::InferenceError;
pub use supermvo_dataset::GrayImage;
pub use supermvo_features::{descriptor_distance, Features, FrameView, Matches};

/// Detects keypoints and computes descriptors.
pub trait Extractor {
    /// Features of one image. Any image size is accepted; an empty image is an error.
    fn extract(&mut self, image: &GrayImage) -> Result<Features, InferenceError>;
}

/// Matches two feature sets.
pub trait Matcher {
    /// Matches `a` against `b`.
    fn match_features(&mut self, a: &Features, b: &Features) -> Result<Matches, InferenceError>;

    /// Runs the largest computation a pair of this size can take (a network that adapts its
    /// width and depth to the pair runs all of both), so that the first calls are not slow
    /// and the runtime's memory reaches its working size before the first frame.
    fn warm_up(&mut self, a: &Features, b: &Features) -> Result<(), InferenceError> {
        self.match_features(a, b).map(|_| ())
    }
}

impl<E: Extractor + ?Sized> Extractor for Box<E> {
    fn extract(&mut self, image: &GrayImage) -> Result<Features, InferenceError> {
        (**self).extract(image)
    }
}

impl<M: Matcher + ?Sized> Matcher for Box<M> {
    fn match_features(&mut self, a: &Features, b: &Features) -> Result<Matches, InferenceError> {
        (**self).match_features(a, b)
    }

    fn warm_up(&mut self, a: &Features, b: &Features) -> Result<(), InferenceError> {
        (**self).warm_up(a, b)
    }
}
