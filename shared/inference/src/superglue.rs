//! SuperGlue (official MagicLeap weights, exported by `supermvo models fetch superglue
//! --weights superglue_outdoor.pth`) over an ONNX Runtime session.
//!
//! The graph ends with the Sinkhorn iterations and outputs the log transport plan with
//! dustbins; matches are the mutual best entries whose probability exceeds the threshold
//! (SuperGlue's `match_threshold`, 0.2), selected as for LightGlue.

use crate::lighterglue::filter_matches;
use crate::runtime::{open_session_on, Device};
use crate::{Features, InferenceError, Matcher, Matches};
use std::path::Path;

/// Settings of the SuperGlue matcher.
#[derive(Debug, Clone, PartialEq)]
pub struct SuperGlueConfig {
    /// Minimum match probability (SuperGlue's `match_threshold`).
    pub threshold: f32,
    /// ONNX Runtime intra-op threads.
    pub threads: usize,
    /// ONNX Runtime's intra-op threads spin (busy-wait) between calls instead of sleeping:
    /// faster for a network that runs alone, slower where another network or stage needs the
    /// same cores (see `runtime::open_session_on`). Off by default.
    pub spin: bool,
    /// Where the network runs.
    pub device: Device,
}

impl Default for SuperGlueConfig {
    fn default() -> Self {
        Self {
            threshold: 0.2,
            threads: 2,
            spin: false,
            device: Device::Cpu,
        }
    }
}

/// SuperGlue over an ONNX Runtime session.
#[derive(Debug)]
pub struct SuperGlue {
    session: ort::session::Session,
    cfg: SuperGlueConfig,
}

const INPUTS: [&str; 6] = ["kpts0", "kpts1", "scores0", "scores1", "desc0", "desc1"];
const OUTPUTS: [&str; 1] = ["log_assignment"];

/// Normalises keypoints as SuperGlue does: `(kpts - size / 2) / (0.7 max(size))`.
pub fn normalize_keypoints(f: &Features) -> Vec<f32> {
    let (w, h) = (f.image_size.0 as f32, f.image_size.1 as f32);
    let scale = 0.7 * w.max(h);
    f.keypoints
        .iter()
        .flat_map(|k| [(k[0] - w / 2.0) / scale, (k[1] - h / 2.0) / scale])
        .collect()
}

impl SuperGlue {
    /// Opens `model` (a `superglue.onnx` exported from the official weights).
    pub fn new(model: &Path, cfg: SuperGlueConfig) -> Result<Self, InferenceError> {
        crate::runtime::init_for(None, cfg.device)?;
        let (session, _) = open_session_on(
            model,
            "superglue",
            (cfg.threads, cfg.spin),
            cfg.device,
            &INPUTS,
            &OUTPUTS,
        )?;
        Ok(Self { session, cfg })
    }

    /// The log transport plan `(m + 1) x (n + 1)`, row-major, dustbins last.
    pub fn log_assignment(
        &mut self,
        a: &Features,
        b: &Features,
    ) -> Result<Vec<f32>, InferenceError> {
        let err = |e: ort::Error| InferenceError::Run {
            model: "superglue".into(),
            message: e.to_string(),
        };
        if a.dim != b.dim {
            return Err(InferenceError::Run {
                model: "superglue".into(),
                message: format!("descriptor lengths differ: {} and {}", a.dim, b.dim),
            });
        }
        let (ka, kb) = (normalize_keypoints(a), normalize_keypoints(b));
        let (m, n, d) = (a.len(), b.len(), a.dim);
        let inputs = ort::inputs![
            "kpts0" => ort::value::TensorRef::from_array_view(([1, m, 2], &ka[..])).map_err(err)?,
            "kpts1" => ort::value::TensorRef::from_array_view(([1, n, 2], &kb[..])).map_err(err)?,
            "scores0" => ort::value::TensorRef::from_array_view(([1, m], &a.scores[..])).map_err(err)?,
            "scores1" => ort::value::TensorRef::from_array_view(([1, n], &b.scores[..])).map_err(err)?,
            "desc0" => ort::value::TensorRef::from_array_view(([1, m, d], &a.descriptors[..])).map_err(err)?,
            "desc1" => ort::value::TensorRef::from_array_view(([1, n, d], &b.descriptors[..])).map_err(err)?,
        ];
        let out = self.session.run(inputs).map_err(err)?;
        let (_, data) = out["log_assignment"]
            .try_extract_tensor::<f32>()
            .map_err(err)?;
        if data.len() != (m + 1) * (n + 1) {
            return Err(InferenceError::Run {
                model: "superglue".into(),
                message: format!(
                    "log_assignment has {} values, expected ({m} + 1) x ({n} + 1)",
                    data.len()
                ),
            });
        }
        Ok(data.to_vec())
    }
}

impl Matcher for SuperGlue {
    fn match_features(&mut self, a: &Features, b: &Features) -> Result<Matches, InferenceError> {
        if a.is_empty() || b.is_empty() {
            return Ok(Matches::default());
        }
        let la = self.log_assignment(a, b)?;
        Ok(filter_matches(
            &la,
            a.len(),
            b.len(),
            self.cfg.threshold,
            true,
        ))
    }
}
