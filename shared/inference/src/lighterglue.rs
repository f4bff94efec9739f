//! LightGlue-family matching (LighterGlue for XFeat) over an ONNX Runtime session.
//!
//! The network outputs the log assignment matrix; the matches are then selected here as
//! LightGlue's `filter_matches` does: for each keypoint of the first set the best column,
//! kept when it is a mutual best and `exp(score)` exceeds the threshold.
//!
//! Models exported with LightGlue's adaptive width and depth (`lighterglue` is) take two
//! scalar inputs, `min_matchability` (point pruning) and `depth_confidence` (early
//! stopping), and return `kept0`/`kept1`, the original indices of the rows and columns that
//! survived pruning (matches are mapped back through them), and `layers`, how many ran.

use crate::runtime::{open_session_on, Device};
use crate::{Features, InferenceError, Matcher, Matches};
use std::path::Path;

/// Settings of the matcher.
#[derive(Debug, Clone, PartialEq)]
pub struct LightGlueConfig {
    /// Minimum match confidence (LightGlue's `filter_threshold`); 0 keeps every mutual match.
    pub threshold: f32,
    /// Require the match to be the best in both directions.
    pub mutual: bool,
    /// ONNX Runtime intra-op threads.
    pub threads: usize,
    /// ONNX Runtime's intra-op threads spin (busy-wait) between calls instead of sleeping:
    /// faster for a network that runs alone, slower where another network or stage needs the
    /// same cores (see `runtime::open_session_on`). Off by default.
    pub spin: bool,
    /// Point pruning as LightGlue's `width_confidence`: after each layer, keypoints whose
    /// matchability is not above `1 - width_confidence` are dropped. 0.95 is the reference
    /// LighterGlue's setting; -1 disables pruning. Ignored by models exported without it.
    pub width_confidence: f32,
    /// Where the network runs (CUDA falls back to the CPU, with a warning, when unusable).
    pub device: Device,
    /// Early stopping as LightGlue's `depth_confidence`: after each layer, the remaining
    /// layers are skipped once more than this fraction of all keypoints have a confident
    /// token; -1 (the reference LighterGlue's setting) runs every layer. Ignored by models
    /// exported without it.
    pub depth_confidence: f32,
}

impl Default for LightGlueConfig {
    fn default() -> Self {
        Self {
            threshold: 0.1,
            mutual: true,
            threads: 2,
            spin: false,
            width_confidence: 0.95,
            depth_confidence: -1.0,
            device: Device::Cpu,
        }
    }
}

/// A LightGlue-style matcher (the ONNX graph of `tools/models/lightglue_onnx.py`).
#[derive(Debug)]
pub struct LightGlue {
    session: ort::session::Session,
    cfg: LightGlueConfig,
    name: String,
    /// The model has adaptive width and depth (the `min_matchability` and
    /// `depth_confidence` inputs and the `kept` outputs).
    adaptive: bool,
    device: Device,
}

/// A log assignment over the keypoints that survived pruning.
#[derive(Debug, Clone, PartialEq)]
pub struct Assignment {
    /// Row-major `(kept0.len() + 1) x (kept1.len() + 1)`, dustbins last.
    pub log_assignment: Vec<f32>,
    /// Original index of each row (all of `0..m` without pruning).
    pub kept0: Vec<usize>,
    /// Original index of each column.
    pub kept1: Vec<usize>,
    /// Layers that ran (fewer than the model has when it stopped early; 0 from models that
    /// do not report it).
    pub layers: usize,
}

const INPUTS: [&str; 4] = ["kpts0", "kpts1", "desc0", "desc1"];
const OUTPUTS: [&str; 1] = ["log_assignment"];
const ADAPTIVE_INPUTS: [&str; 2] = ["min_matchability", "depth_confidence"];
const ADAPTIVE_OUTPUTS: [&str; 3] = ["kept0", "kept1", "layers"];

/// Normalises keypoints as LightGlue does: `(kpts - size / 2) / (max(size) / 2)`.
pub fn normalize_keypoints(f: &Features) -> Vec<f32> {
    let (w, h) = (f.image_size.0 as f32, f.image_size.1 as f32);
    let scale = w.max(h) / 2.0;
    f.keypoints
        .iter()
        .flat_map(|k| [(k[0] - w / 2.0) / scale, (k[1] - h / 2.0) / scale])
        .collect()
}

/// Mutual-best selection on a `(m + 1) x (n + 1)` log assignment (row-major).
pub fn filter_matches(
    log_assignment: &[f32],
    m: usize,
    n: usize,
    threshold: f32,
    mutual: bool,
) -> Matches {
    let stride = n + 1;
    let row_best: Vec<(usize, f32)> = (0..m)
        .map(|i| {
            let row = &log_assignment[i * stride..i * stride + n];
            row.iter()
                .enumerate()
                .fold((0, f32::NEG_INFINITY), |best, (j, &v)| {
                    if v > best.1 {
                        (j, v)
                    } else {
                        best
                    }
                })
        })
        .collect();
    let mut col_best = vec![(0usize, f32::NEG_INFINITY); n];
    for i in 0..m {
        for (j, cb) in col_best.iter_mut().enumerate() {
            let v = log_assignment[i * stride + j];
            if v > cb.1 {
                *cb = (i, v);
            }
        }
    }
    let mut out = Matches::default();
    for (i, &(j, v)) in row_best.iter().enumerate() {
        if n == 0 || (mutual && col_best[j].0 != i) {
            continue;
        }
        let score = v.exp();
        if score > threshold {
            out.pairs.push((i, j));
            out.scores.push(score);
        }
    }
    out
}

fn tensor(shape: [usize; 3], data: &[f32]) -> ort::Result<ort::value::TensorRef<'_, f32>> {
    ort::value::TensorRef::from_array_view((shape, data))
}

impl LightGlue {
    /// Opens a matcher model; `name` is used in messages (`lighterglue`, ...).
    pub fn new(model: &Path, name: &str, cfg: LightGlueConfig) -> Result<Self, InferenceError> {
        crate::runtime::init_for(None, cfg.device)?;
        let (session, device) = open_session_on(
            model,
            name,
            (cfg.threads, cfg.spin),
            cfg.device,
            &INPUTS,
            &OUTPUTS,
        )?;
        let has = |names: &[&str], actual: &[&str]| -> Vec<bool> {
            names.iter().map(|n| actual.contains(n)).collect()
        };
        let inputs: Vec<&str> = session.inputs().iter().map(|i| i.name()).collect();
        let outputs: Vec<&str> = session.outputs().iter().map(|o| o.name()).collect();
        let found = [
            has(&ADAPTIVE_INPUTS, &inputs),
            has(&ADAPTIVE_OUTPUTS, &outputs),
        ]
        .concat();
        let adaptive = found.iter().all(|&b| b);
        if !adaptive && found.iter().any(|&b| b) {
            return Err(InferenceError::ModelInterface {
                path: model.to_path_buf(),
                name: name.to_string(),
                expected: format!(
                    "the adaptive inputs {ADAPTIVE_INPUTS:?} together with outputs {ADAPTIVE_OUTPUTS:?}, or none of them"
                ),
                found: format!("inputs {inputs:?}, outputs {outputs:?}"),
            });
        }
        Ok(Self {
            session,
            cfg,
            name: name.to_string(),
            adaptive,
            device,
        })
    }

    /// The device the network runs on (the CPU when CUDA was asked for but is unusable).
    pub fn device(&self) -> Device {
        self.device
    }

    /// Whether the model has LightGlue's adaptive width (pruning) and depth (early stopping).
    pub fn adaptive(&self) -> bool {
        self.adaptive
    }

    /// The log assignment over the keypoints that survive pruning (all of them when the model
    /// is not adaptive or `width_confidence` is not positive).
    pub fn assignment(&mut self, a: &Features, b: &Features) -> Result<Assignment, InferenceError> {
        let err = |e: ort::Error| InferenceError::Run {
            model: self.name.clone(),
            message: e.to_string(),
        };
        if a.dim != b.dim {
            return Err(InferenceError::Run {
                model: self.name.clone(),
                message: format!("descriptor sizes differ: {} vs {}", a.dim, b.dim),
            });
        }
        let (ka, kb) = (normalize_keypoints(a), normalize_keypoints(b));
        let (m, n, d) = (a.len(), b.len(), a.dim);
        let mut inputs = ort::inputs![
            "kpts0" => tensor([1, m, 2], &ka).map_err(err)?,
            "kpts1" => tensor([1, n, 2], &kb).map_err(err)?,
            "desc0" => tensor([1, m, d], &a.descriptors).map_err(err)?,
            "desc1" => tensor([1, n, d], &b.descriptors).map_err(err)?,
        ];
        if self.adaptive {
            let wc = self.cfg.width_confidence;
            let min_matchability = if wc > 0.0 { 1.0 - wc } else { -1.0 };
            let dc = self.cfg.depth_confidence;
            let depth_confidence = if dc > 0.0 { dc } else { -1.0 };
            for (name, v) in ADAPTIVE_INPUTS
                .iter()
                .zip([min_matchability, depth_confidence])
            {
                let scalar =
                    ort::value::Tensor::from_array((Vec::<usize>::new(), vec![v])).map_err(err)?;
                inputs.push(((*name).into(), scalar.into()));
            }
        }
        let out = self.session.run(inputs).map_err(err)?;
        let (_, data) = out["log_assignment"]
            .try_extract_tensor::<f32>()
            .map_err(err)?;
        let log_assignment = data.to_vec();
        let (kept0, kept1, layers) = if self.adaptive {
            let kept = |key: &str, len: usize| -> Result<Vec<usize>, InferenceError> {
                let (_, idx) = out[key].try_extract_tensor::<i64>().map_err(err)?;
                idx.iter()
                    .map(|&i| usize::try_from(i).ok().filter(|&i| i < len))
                    .collect::<Option<Vec<_>>>()
                    .ok_or_else(|| InferenceError::Run {
                        model: self.name.clone(),
                        message: format!("'{key}' holds an index outside 0..{len}"),
                    })
            };
            let (_, layers) = out["layers"].try_extract_tensor::<i64>().map_err(err)?;
            let layers = layers
                .first()
                .and_then(|&l| usize::try_from(l).ok())
                .ok_or_else(|| InferenceError::Run {
                    model: self.name.clone(),
                    message: "'layers' is empty or negative".into(),
                })?;
            (kept("kept0", m)?, kept("kept1", n)?, layers)
        } else {
            ((0..m).collect(), (0..n).collect(), 0)
        };
        if log_assignment.len() != (kept0.len() + 1) * (kept1.len() + 1) {
            return Err(InferenceError::Run {
                model: self.name.clone(),
                message: format!(
                    "log_assignment has {} values, expected ({} + 1) x ({} + 1)",
                    log_assignment.len(),
                    kept0.len(),
                    kept1.len()
                ),
            });
        }
        Ok(Assignment {
            log_assignment,
            kept0,
            kept1,
            layers,
        })
    }
}

impl Matcher for LightGlue {
    fn match_features(&mut self, a: &Features, b: &Features) -> Result<Matches, InferenceError> {
        if a.is_empty() || b.is_empty() {
            return Ok(Matches::default());
        }
        let la = self.assignment(a, b)?;
        let mut matches = filter_matches(
            &la.log_assignment,
            la.kept0.len(),
            la.kept1.len(),
            self.cfg.threshold,
            self.cfg.mutual,
        );
        for p in &mut matches.pairs {
            *p = (la.kept0[p.0], la.kept1[p.1]);
        }
        Ok(matches)
    }

    /// With no point pruned and every layer run (the largest tensors and the most of them
    /// alive).
    fn warm_up(&mut self, a: &Features, b: &Features) -> Result<(), InferenceError> {
        let configured = self.cfg.clone();
        (self.cfg.width_confidence, self.cfg.depth_confidence) = (-1.0, -1.0);
        let full = self.match_features(a, b);
        self.cfg = configured;
        full.map(|_| ())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mutual_best_and_threshold() {
        // 2 x 2 core with dustbins; row 0 prefers col 1, row 1 prefers col 1 too (weaker)
        let l = |p: f32| p.ln();
        let la = vec![
            l(0.1),
            l(0.8),
            l(0.1),
            l(0.2),
            l(0.5),
            l(0.3),
            l(0.1),
            l(0.1),
            0.0,
        ];
        let m = filter_matches(&la, 2, 2, 0.1, true);
        assert_eq!(m.pairs, vec![(0, 1)]);
        assert!((m.scores[0] - 0.8).abs() < 1e-6);
        let m = filter_matches(&la, 2, 2, 0.1, false);
        assert_eq!(m.pairs, vec![(0, 1), (1, 1)]);
        assert!(filter_matches(&la, 2, 2, 0.9, true).pairs.is_empty());
    }

    #[test]
    fn keypoint_normalisation() {
        let f = Features {
            keypoints: vec![[0.0, 0.0], [100.0, 50.0]],
            image_size: (200, 100),
            ..Default::default()
        };
        assert_eq!(normalize_keypoints(&f), vec![-1.0, -0.5, 0.0, 0.0]);
    }
}
