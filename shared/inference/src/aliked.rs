//! ALIKED (Zhao et al., IEEE TIM 2023; the `aliked-n16` weights LightGlue was trained
//! with) over an ONNX Runtime session.
//!
//! The whole extractor is one graph (`tools/models/aliked_onnx.py`): the network at the
//! image's own size, ALIKED's detection (5x5 non-maximum suppression with recovery rounds,
//! a 2-pixel border, top-k, soft-argmax refinement) and its deformable descriptor head at
//! the selected keypoints. The graph returns the `top_k` strongest maxima; here those whose
//! score is not above the detection threshold are dropped (ALIKED's threshold mode, as
//! LightGlue uses it: at most `top_k` keypoints scoring above 0.2).

use crate::runtime::{open_session_on, Device};
use crate::{Extractor, Features, GrayImage, InferenceError};
use std::path::Path;

/// Settings of the ALIKED extractor.
#[derive(Debug, Clone, PartialEq)]
pub struct AlikedConfig {
    /// Keep at most this many keypoints.
    pub top_k: usize,
    /// Minimum score (after non-maximum suppression) of a keypoint; ALIKED's 0.2.
    pub detection_threshold: f32,
    /// ONNX Runtime intra-op threads.
    pub threads: usize,
    /// ONNX Runtime's intra-op threads spin (busy-wait) between calls instead of sleeping:
    /// faster for a network that runs alone, slower where another network or stage needs the
    /// same cores (see `runtime::open_session_on`). Off by default.
    pub spin: bool,
    /// Where the network runs.
    pub device: Device,
}

impl Default for AlikedConfig {
    fn default() -> Self {
        Self {
            top_k: 2048,
            detection_threshold: 0.2,
            threads: 2,
            spin: false,
            device: Device::Cpu,
        }
    }
}

/// ALIKED over an ONNX Runtime session.
#[derive(Debug)]
pub struct Aliked {
    session: ort::session::Session,
    cfg: AlikedConfig,
}

const INPUTS: [&str; 2] = ["image", "top_k"];
const OUTPUTS: [&str; 4] = ["keypoints", "detection_scores", "scores", "descriptors"];

impl Aliked {
    /// Opens `model` (an `aliked.onnx` exported by `supermvo models fetch aliked`).
    pub fn new(model: &Path, cfg: AlikedConfig) -> Result<Self, InferenceError> {
        crate::runtime::init_for(None, cfg.device)?;
        let (session, _) = open_session_on(
            model,
            "aliked",
            (cfg.threads, cfg.spin),
            cfg.device,
            &INPUTS,
            &OUTPUTS,
        )?;
        Ok(Self { session, cfg })
    }
}

/// The keypoints among the graph's `top_k` whose detection score is above `threshold`
/// (the graph sorts them by that score, descending); `dim` values of `descriptors` each.
pub fn select(
    keypoints: &[f32],
    detection_scores: &[f32],
    descriptors: &[f32],
    dim: usize,
    threshold: f32,
    image_size: (usize, usize),
) -> Features {
    let keep: Vec<usize> = (0..detection_scores.len())
        .filter(|&i| detection_scores[i] > threshold)
        .collect();
    Features {
        keypoints: keep
            .iter()
            .map(|&i| [keypoints[2 * i], keypoints[2 * i + 1]])
            .collect(),
        scores: keep.iter().map(|&i| detection_scores[i]).collect(),
        descriptors: keep
            .iter()
            .flat_map(|&i| descriptors[i * dim..(i + 1) * dim].iter().copied())
            .collect(),
        dim,
        image_size,
    }
}

impl Extractor for Aliked {
    fn extract(&mut self, image: &GrayImage) -> Result<Features, InferenceError> {
        if image.width < 32 || image.height < 32 {
            return Err(InferenceError::BadImage(format!(
                "image is {}x{}; ALIKED needs at least 32x32 pixels",
                image.width, image.height
            )));
        }
        let (w, h) = (image.width, image.height);
        let input: Vec<f32> = image.data.iter().map(|&p| p as f32 / 255.0).collect();
        let top_k = [self.cfg.top_k.min(w * h) as i64];
        let err = |e: ort::Error| InferenceError::Run {
            model: "aliked".into(),
            message: e.to_string(),
        };
        let image_t =
            ort::value::TensorRef::from_array_view(([1usize, 1, h, w], &input[..])).map_err(err)?;
        let top_k_t =
            ort::value::TensorRef::from_array_view(([1usize], &top_k[..])).map_err(err)?;
        let outputs = self
            .session
            .run(ort::inputs!["image" => image_t, "top_k" => top_k_t])
            .map_err(err)?;
        let (_, kpts) = outputs["keypoints"]
            .try_extract_tensor::<f32>()
            .map_err(err)?;
        let (_, det) = outputs["detection_scores"]
            .try_extract_tensor::<f32>()
            .map_err(err)?;
        let (shape, desc) = outputs["descriptors"]
            .try_extract_tensor::<f32>()
            .map_err(err)?;
        let dim = shape.last().copied().unwrap_or(0).max(0) as usize;
        if kpts.len() != 2 * det.len() || desc.len() != dim * det.len() {
            return Err(InferenceError::Run {
                model: "aliked".into(),
                message: format!(
                    "inconsistent outputs: {} keypoint values, {} scores, {} descriptor values",
                    kpts.len(),
                    det.len(),
                    desc.len()
                ),
            });
        }
        Ok(select(
            kpts,
            det,
            desc,
            dim,
            self.cfg.detection_threshold,
            (w, h),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn select_keeps_the_keypoints_above_the_threshold_with_their_descriptors() {
        let kpts = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let det = [0.9, 0.5, 0.1];
        let desc = [1.0, 0.0, 0.0, 1.0, 0.6, 0.8];
        let f = select(&kpts, &det, &desc, 2, 0.2, (10, 8));
        assert_eq!(f.keypoints, vec![[1.0, 2.0], [3.0, 4.0]]);
        assert_eq!(f.scores, vec![0.9, 0.5]);
        assert_eq!(f.descriptors, vec![1.0, 0.0, 0.0, 1.0]);
        assert_eq!((f.dim, f.image_size), (2, (10, 8)));
        assert!(select(&kpts, &det, &desc, 2, 0.95, (10, 8)).is_empty());
    }
}
