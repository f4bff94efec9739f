//! SuperPoint (official MagicLeap weights, exported by `supermvo models fetch superpoint
//! --weights superpoint_v1.pth`) over an ONNX Runtime session.
//!
//! The network gives 65-channel detector logits and coarse descriptors at 1/8 resolution;
//! the post-processing follows the SuperPoint paper and MagicLeap's reference: softmax over
//! the 65 channels, the "no keypoint" channel dropped and the rest laid out as 8x8 cells of
//! a full-resolution heatmap, non-maximum suppression within `nms_radius`, a detection
//! threshold, `border` pixels removed, the `top_k` strongest kept, and descriptors sampled
//! bilinearly from the coarse map at each keypoint and L2-normalised.

use crate::runtime::{open_session_on, Device};
use crate::xfeat::resize_bilinear;
use crate::{Extractor, Features, GrayImage, InferenceError};
use std::path::Path;

/// Settings of the SuperPoint extractor (MagicLeap's reference defaults).
#[derive(Debug, Clone, PartialEq)]
pub struct SuperPointConfig {
    /// Keep at most this many keypoints.
    pub top_k: usize,
    /// Minimum heatmap value of a keypoint.
    pub detection_threshold: f32,
    /// Radius of the non-maximum suppression, pixels.
    pub nms_radius: usize,
    /// Keypoints closer than this to the border are removed, pixels.
    pub border: usize,
    /// ONNX Runtime intra-op threads.
    pub threads: usize,
    /// ONNX Runtime's intra-op threads spin (busy-wait) between calls instead of sleeping:
    /// faster for a network that runs alone, slower where another network or stage needs the
    /// same cores (see `runtime::open_session_on`). Off by default.
    pub spin: bool,
    /// Where the network runs.
    pub device: Device,
}

impl Default for SuperPointConfig {
    fn default() -> Self {
        Self {
            top_k: 2048,
            detection_threshold: 0.005,
            nms_radius: 4,
            border: 4,
            threads: 2,
            spin: false,
            device: Device::Cpu,
        }
    }
}

/// SuperPoint over an ONNX Runtime session.
#[derive(Debug)]
pub struct SuperPoint {
    session: ort::session::Session,
    cfg: SuperPointConfig,
}

const INPUTS: [&str; 1] = ["image"];
const OUTPUTS: [&str; 2] = ["scores_logits", "descriptors"];

impl SuperPoint {
    /// Opens `model` (a `superpoint.onnx` exported from the official weights).
    pub fn new(model: &Path, cfg: SuperPointConfig) -> Result<Self, InferenceError> {
        crate::runtime::init_for(None, cfg.device)?;
        let (session, _) = open_session_on(
            model,
            "superpoint",
            (cfg.threads, cfg.spin),
            cfg.device,
            &INPUTS,
            &OUTPUTS,
        )?;
        Ok(Self { session, cfg })
    }
}

/// Keypoints, scores and descriptors from the network's outputs: `logits` `[65, h8, w8]`,
/// `coarse` `[dim, h8, w8]` for an input of `(h8 * 8, w8 * 8)` pixels; keypoints are scaled
/// to `image_size`.
pub fn postprocess(
    logits: &[f32],
    coarse: &[f32],
    (h8, w8): (usize, usize),
    image_size: (usize, usize),
    cfg: &SuperPointConfig,
) -> Features {
    let (hh, ww) = (h8 * 8, w8 * 8);
    let cells = h8 * w8;
    let dim = coarse.len() / cells.max(1);
    let mut heat = vec![0.0f32; hh * ww];
    for idx in 0..cells {
        let m = (0..65)
            .map(|c| logits[c * cells + idx])
            .fold(f32::NEG_INFINITY, f32::max);
        let sum: f32 = (0..65).map(|c| (logits[c * cells + idx] - m).exp()).sum();
        let (cy, cx) = (idx / w8, idx % w8);
        for c in 0..64 {
            heat[(cy * 8 + c / 8) * ww + cx * 8 + c % 8] =
                (logits[c * cells + idx] - m).exp() / sum;
        }
    }
    let keep = simple_nms(&heat, ww, hh, cfg.nms_radius);
    let mut kept: Vec<(f32, usize, usize)> = Vec::new();
    let b = cfg.border;
    for y in b..hh.saturating_sub(b) {
        for x in b..ww.saturating_sub(b) {
            let v = heat[y * ww + x];
            if keep[y * ww + x] && v > cfg.detection_threshold {
                kept.push((v, x, y));
            }
        }
    }
    kept.sort_by(|p, q| q.0.total_cmp(&p.0));
    kept.truncate(cfg.top_k);
    let (rw, rh) = (
        image_size.0 as f32 / ww as f32,
        image_size.1 as f32 / hh as f32,
    );
    let mut out = Features {
        dim,
        image_size,
        ..Default::default()
    };
    out.descriptors.reserve(kept.len() * dim);
    let mut d = vec![0.0f32; dim];
    for &(s, x, y) in &kept {
        // the reference's sampling (grid_sample, align_corners): pixel x maps to
        // (x - 3.5) / (8 w8 - 4.5) * (w8 - 1) on the coarse grid, bilinear
        let grid = |p: usize, n: usize| {
            ((p as f32 - 3.5) / (8.0 * n as f32 - 4.5) * (n - 1) as f32).clamp(0.0, (n - 1) as f32)
        };
        let (gx, gy) = (grid(x, w8), grid(y, h8));
        let (x0, y0) = (gx.floor() as usize, gy.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w8 - 1), (y0 + 1).min(h8 - 1));
        let (fx, fy) = (gx - x0 as f32, gy - y0 as f32);
        let corners = [
            (y0 * w8 + x0, (1.0 - fx) * (1.0 - fy)),
            (y0 * w8 + x1, fx * (1.0 - fy)),
            (y1 * w8 + x0, (1.0 - fx) * fy),
            (y1 * w8 + x1, fx * fy),
        ];
        for (c, dc) in d.iter_mut().enumerate() {
            *dc = corners
                .iter()
                .map(|&(i, w)| w * coarse[c * cells + i])
                .sum();
        }
        let n = d.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
        out.descriptors.extend(d.iter().map(|v| v / n));
        out.keypoints
            .push([(x as f32 + 0.5) * rw - 0.5, (y as f32 + 0.5) * rh - 0.5]);
        out.scores.push(s);
    }
    out
}

/// Maximum over the `(2r+1)^2` window around each pixel (windows clipped at the borders).
fn max_filter(map: &[f32], w: usize, h: usize, r: usize) -> Vec<f32> {
    let mut rows = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            rows[y * w + x] = map[y * w + a..=y * w + b]
                .iter()
                .copied()
                .fold(f32::NEG_INFINITY, f32::max);
        }
    }
    let mut out = vec![0.0f32; w * h];
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            out[y * w + x] = (a..=b)
                .map(|yy| rows[yy * w + x])
                .fold(f32::NEG_INFINITY, f32::max);
        }
    }
    out
}

/// SuperPoint's non-maximum suppression as MagicLeap's reference does it: the local maxima
/// of `(2r+1)^2` windows, then twice more the maxima among the pixels farther than `r` from
/// every point kept so far (so a point whose only stronger neighbour was itself suppressed
/// survives).
fn simple_nms(heat: &[f32], w: usize, h: usize, r: usize) -> Vec<bool> {
    let peaks = |map: &[f32]| -> Vec<bool> {
        let m = max_filter(map, w, h, r);
        map.iter().zip(&m).map(|(v, m)| v == m).collect()
    };
    let mut keep = peaks(heat);
    for _ in 0..2 {
        let near: Vec<f32> = keep.iter().map(|&k| if k { 1.0 } else { 0.0 }).collect();
        let suppressed: Vec<bool> = max_filter(&near, w, h, r)
            .iter()
            .map(|&v| v > 0.0)
            .collect();
        let rest: Vec<f32> = heat
            .iter()
            .zip(&suppressed)
            .map(|(&v, &s)| if s { 0.0 } else { v })
            .collect();
        for ((k, new), s) in keep.iter_mut().zip(peaks(&rest)).zip(&suppressed) {
            *k |= new && !s;
        }
    }
    keep
}

impl Extractor for SuperPoint {
    fn extract(&mut self, image: &GrayImage) -> Result<Features, InferenceError> {
        if image.width < 32 || image.height < 32 {
            return Err(InferenceError::BadImage(format!(
                "image is {}x{}; SuperPoint needs at least 32x32 pixels",
                image.width, image.height
            )));
        }
        let (w8, h8) = (image.width / 8, image.height / 8);
        let input = resize_bilinear(image, w8 * 8, h8 * 8);
        let err = |e: ort::Error| InferenceError::Run {
            model: "superpoint".into(),
            message: e.to_string(),
        };
        let tensor =
            ort::value::TensorRef::from_array_view(([1usize, 1, h8 * 8, w8 * 8], &input[..]))
                .map_err(err)?;
        let outputs = self
            .session
            .run(ort::inputs!["image" => tensor])
            .map_err(err)?;
        let (_, logits) = outputs["scores_logits"]
            .try_extract_tensor::<f32>()
            .map_err(err)?;
        let (_, coarse) = outputs["descriptors"]
            .try_extract_tensor::<f32>()
            .map_err(err)?;
        Ok(postprocess(
            logits,
            coarse,
            (h8, w8),
            (image.width, image.height),
            &self.cfg,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_confident_cell_gives_one_keypoint_with_its_descriptor() {
        let (h8, w8) = (4, 6);
        let cells = h8 * w8;
        // every cell says "no keypoint" except cell (row 2, col 3), position (5, 6) inside it
        let mut logits = vec![0.0f32; 65 * cells];
        for i in 0..cells {
            logits[64 * cells + i] = 10.0;
        }
        let cell = 2 * w8 + 3;
        logits[(6 * 8 + 5) * cells + cell] = 20.0;
        logits[64 * cells + cell] = 0.0;
        let dim = 4;
        let coarse: Vec<f32> = (0..dim * cells)
            .map(|k| if k / cells == 1 { 1.0 } else { 0.0 })
            .collect();
        let cfg = SuperPointConfig::default();
        let f = postprocess(&logits, &coarse, (h8, w8), (w8 * 8, h8 * 8), &cfg);
        assert_eq!(f.len(), 1);
        assert_eq!(f.keypoints[0], [3.0 * 8.0 + 5.0, 2.0 * 8.0 + 6.0]);
        assert!(f.scores[0] > 0.99);
        assert_eq!(f.dim, dim);
        assert!((f.descriptor(0)[1] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn nms_keeps_a_point_whose_stronger_neighbour_was_suppressed() {
        // A (1.0) at x = 0, B (0.9) at x = 4, C (0.8) at x = 8, radius 4: B lies within A's
        // window and is suppressed; C's only stronger neighbour is B, so C is kept
        let (w, h) = (16, 1);
        let mut heat = vec![0.0f32; w * h];
        heat[0] = 1.0;
        heat[4] = 0.9;
        heat[8] = 0.8;
        let keep = simple_nms(&heat, w, h, 4);
        let kept: Vec<usize> = (0..w).filter(|&i| keep[i] && heat[i] > 0.0).collect();
        assert_eq!(kept, vec![0, 8]);
    }

    #[test]
    fn border_keypoints_are_removed() {
        let (h8, w8) = (4, 4);
        let cells = h8 * w8;
        let mut logits = vec![0.0f32; 65 * cells];
        for i in 0..cells {
            logits[64 * cells + i] = 10.0;
        }
        logits[cells] = 20.0; // cell 0, position (1, 0): within 4 px of the border
        logits[64 * cells] = 0.0;
        let f = postprocess(
            &logits,
            &vec![1.0; 2 * cells],
            (h8, w8),
            (32, 32),
            &SuperPointConfig::default(),
        );
        assert!(f.is_empty());
    }
}
