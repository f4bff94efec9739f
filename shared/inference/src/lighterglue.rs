//! LightGlue-family matching (LighterGlue for XFeat) over an ONNX Runtime session.
//!
//! The network outputs the log assignment matrix; the matches are then selected here as
//! LightGlue's `filter_matches` does: for each keypoint of the first set the best column,
//! kept when it is a mutual best and `exp(score)` exceeds the threshold.

use crate::runtime::open_session;
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
}

impl Default for LightGlueConfig {
    fn default() -> Self {
        Self {
            threshold: 0.1,
            mutual: true,
            threads: 2,
        }
    }
}

/// A LightGlue-style matcher (the ONNX graph of `tools/models/lightglue_onnx.py`).
#[derive(Debug)]
pub struct LightGlue {
    session: ort::session::Session,
    cfg: LightGlueConfig,
    name: String,
}

const INPUTS: [&str; 4] = ["kpts0", "kpts1", "desc0", "desc1"];
const OUTPUTS: [&str; 1] = ["log_assignment"];

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
        crate::runtime::init(None)?;
        let session = open_session(model, name, cfg.threads, &INPUTS, &OUTPUTS)?;
        Ok(Self {
            session,
            cfg,
            name: name.to_string(),
        })
    }

    /// The log assignment matrix `(m + 1) x (n + 1)` for two feature sets.
    pub fn log_assignment(
        &mut self,
        a: &Features,
        b: &Features,
    ) -> Result<Vec<f32>, InferenceError> {
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
        let inputs = ort::inputs![
            "kpts0" => tensor([1, m, 2], &ka).map_err(err)?,
            "kpts1" => tensor([1, n, 2], &kb).map_err(err)?,
            "desc0" => tensor([1, m, d], &a.descriptors).map_err(err)?,
            "desc1" => tensor([1, n, d], &b.descriptors).map_err(err)?,
        ];
        let out = self.session.run(inputs).map_err(err)?;
        let (_, data) = out["log_assignment"]
            .try_extract_tensor::<f32>()
            .map_err(err)?;
        Ok(data.to_vec())
    }
}

impl Matcher for LightGlue {
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
            self.cfg.mutual,
        ))
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
