//! XFeat keypoints and descriptors.
//!
//! The network runs in ONNX Runtime; everything around it follows the reference
//! `XFeat.detectAndCompute`:
//! 1. crop-free resize to multiples of 32 (bilinear, half-pixel centres);
//! 2. heatmap = softmax over the 65 logits of each 8x8 cell, dustbin dropped, unfolded to
//!    full resolution;
//! 3. keypoints = 5x5 local maxima above `detection_threshold`;
//! 4. score = heatmap (nearest) x reliability (bilinear), sampled as `grid_sample` does with
//!    `align_corners = false` on coordinates normalised by `(W - 1, H - 1)`;
//! 5. the `top_k` best (stable order), descriptors sampled bicubically from the
//!    L2-normalised dense map and L2-normalised again; coordinates scaled back.
//!
//! One step is ours and optional ([`XFeatConfig::subpixel`], off by default): the reference
//! returns integer pixel positions; with it each keypoint moves to the peak of a Gaussian
//! fitted to the heatmap through the maximum and its neighbours, along x and along y.
//! Scores and descriptors stay those of the integer position, so only the coordinates
//! change.

use crate::runtime::{open_session_on, Device};
use crate::{Extractor, Features, GrayImage, InferenceError};
use std::path::Path;

/// Settings of the XFeat extractor.
#[derive(Debug, Clone, PartialEq)]
pub struct XFeatConfig {
    /// Keep at most this many keypoints.
    pub top_k: usize,
    /// Minimum heatmap value of a keypoint.
    pub detection_threshold: f32,
    /// ONNX Runtime intra-op threads.
    pub threads: usize,
    /// ONNX Runtime's intra-op threads spin (busy-wait) between calls instead of sleeping:
    /// faster for a network that runs alone, slower where another network or stage needs the
    /// same cores (see `runtime::open_session_on`). Off by default.
    pub spin: bool,
    /// Where the network runs (CUDA falls back to the CPU, with a warning, when unusable).
    pub device: Device,
    /// Sub-pixel keypoints: each coordinate moves to the vertex of the parabola through the
    /// log-heatmap at the maximum and its two neighbours (a Gaussian peak fit), at most half
    /// a pixel. `false` (the default) gives the reference's integer positions.
    pub subpixel: bool,
    /// The network sees the image resized by this factor (then to multiples of 32);
    /// keypoints are returned in the image's own pixels. 1 (the default) is the reference.
    pub image_scale: f32,
}

impl Default for XFeatConfig {
    fn default() -> Self {
        Self {
            top_k: 2048,
            detection_threshold: 0.05,
            threads: 2,
            spin: false,
            device: Device::Cpu,
            subpixel: false,
            image_scale: 1.0,
        }
    }
}

/// XFeat over an ONNX Runtime session (one session, reused for every image).
#[derive(Debug)]
pub struct XFeat {
    session: ort::session::Session,
    cfg: XFeatConfig,
    device: Device,
}

/// Raw network outputs for one image (channel-major, `h = H/8`, `w = W/8`), borrowed from
/// the runtime's output tensors.
#[derive(Debug, Clone, Copy)]
pub struct XFeatRaw<'a> {
    /// Network input height and width (multiples of 32).
    pub input_size: (usize, usize),
    /// Dense descriptors `[64, h, w]`.
    pub descriptors: &'a [f32],
    /// Keypoint logits `[65, h, w]`.
    pub keypoint_logits: &'a [f32],
    /// Reliability `[h, w]`.
    pub reliability: &'a [f32],
}

const INPUTS: [&str; 1] = ["image"];
const OUTPUTS: [&str; 3] = ["descriptors", "keypoint_logits", "reliability"];

impl XFeat {
    /// Opens `model` (an `xfeat.onnx` exported by `supermvo models fetch xfeat`).
    pub fn new(model: &Path, cfg: XFeatConfig) -> Result<Self, InferenceError> {
        crate::runtime::init_for(None, cfg.device)?;
        let (session, device) = open_session_on(
            model,
            "xfeat",
            (cfg.threads, cfg.spin),
            cfg.device,
            &INPUTS,
            &OUTPUTS,
        )?;
        Ok(Self {
            session,
            cfg,
            device,
        })
    }

    /// The device the network runs on (the CPU when CUDA was asked for but is unusable).
    pub fn device(&self) -> Device {
        self.device
    }

    /// Runs the network on an image already sized to multiples of 32, values in [0, 1], and
    /// hands `f` its outputs in place (no copy).
    pub fn with_raw<R>(
        &mut self,
        input: &[f32],
        height: usize,
        width: usize,
        f: impl FnOnce(&XFeatRaw<'_>) -> R,
    ) -> Result<R, InferenceError> {
        let err = |e: ort::Error| InferenceError::Run {
            model: "xfeat".into(),
            message: e.to_string(),
        };
        let tensor = ort::value::TensorRef::from_array_view(([1usize, 1, height, width], input))
            .map_err(err)?;
        let outputs = self
            .session
            .run(ort::inputs!["image" => tensor])
            .map_err(err)?;
        let view = |name: &str| -> Result<&[f32], InferenceError> {
            let (_, data) = outputs[name].try_extract_tensor::<f32>().map_err(err)?;
            Ok(data)
        };
        Ok(f(&XFeatRaw {
            input_size: (height, width),
            descriptors: view("descriptors")?,
            keypoint_logits: view("keypoint_logits")?,
            reliability: view("reliability")?,
        }))
    }
}

/// Resizes to `(out_w, out_h)` with bilinear interpolation and half-pixel centres (as
/// `F.interpolate(mode="bilinear", align_corners=False)`), returning values in [0, 1].
/// The columns' source pixels and weights are computed once, not once per row.
pub fn resize_bilinear(img: &GrayImage, out_w: usize, out_h: usize) -> Vec<f32> {
    let (w, h) = (img.width, img.height);
    let sx = w as f32 / out_w as f32;
    let sy = h as f32 / out_h as f32;
    let grey: [f32; 256] = std::array::from_fn(|v| v as f32 / 255.0);
    let coord = |d: usize, s: f32, n: usize| -> (usize, usize, f32) {
        let c = ((d as f32 + 0.5) * s - 0.5).max(0.0);
        let i0 = (c.floor() as usize).min(n - 1);
        let i1 = (i0 + 1).min(n - 1);
        (i0, i1, c - i0 as f32)
    };
    let columns: Vec<(usize, usize, f32)> = (0..out_w).map(|ox| coord(ox, sx, w)).collect();
    let mut out = vec![0.0f32; out_w * out_h];
    for (oy, row) in out.chunks_exact_mut(out_w.max(1)).enumerate() {
        let (y0, y1, fy) = coord(oy, sy, h);
        let (r0, r1) = (
            &img.data[y0 * w..(y0 + 1) * w],
            &img.data[y1 * w..(y1 + 1) * w],
        );
        for (o, &(x0, x1, fx)) in row.iter_mut().zip(&columns) {
            let top = grey[r0[x0] as usize] * (1.0 - fx) + grey[r0[x1] as usize] * fx;
            let bot = grey[r1[x0] as usize] * (1.0 - fx) + grey[r1[x1] as usize] * fx;
            *o = top * (1.0 - fy) + bot * fy;
        }
    }
    out
}

/// Cubic convolution weights (A = -0.75, as PyTorch's bicubic).
fn cubic_weights(t: f32) -> [f32; 4] {
    const A: f32 = -0.75;
    let w1 = |x: f32| ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0;
    let w2 = |x: f32| ((A * x - 5.0 * A) * x + 8.0 * A) * x - 4.0 * A;
    [w2(t + 1.0), w1(t), w1(1.0 - t), w2(2.0 - t)]
}

/// Offset of the heatmap's peak from the local maximum at `(x, y)`, per axis: the vertex of
/// the parabola through the logarithms of the three values (exact for a Gaussian peak),
/// clamped to half a pixel; 0 on the image border or where the three values do not bend
/// down.
fn subpixel_offset(heat: &[f32], (w, h): (usize, usize), (x, y): (usize, usize)) -> (f32, f32) {
    let at = |xx: usize, yy: usize| heat[yy * w + xx].max(f32::MIN_POSITIVE).ln();
    let vertex = |before: f32, centre: f32, after: f32| {
        let curvature = before - 2.0 * centre + after;
        if curvature < 0.0 {
            (0.5 * (before - after) / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    let c = at(x, y);
    let dx = if x > 0 && x + 1 < w {
        vertex(at(x - 1, y), c, at(x + 1, y))
    } else {
        0.0
    };
    let dy = if y > 0 && y + 1 < h {
        vertex(at(x, y - 1), c, at(x, y + 1))
    } else {
        0.0
    };
    (dx, dy)
}

/// The full-resolution heatmap (step 2): per 8x8 cell the softmax over its 65 logits, the
/// dustbin dropped. The channels are walked one at a time over every cell (the logits are
/// channel-major), each cell's maximum and sum taken in channel order.
fn heatmap(logits: &[f32], (hh, ww): (usize, usize)) -> Vec<f32> {
    let (h8, w8) = (hh / 8, ww / 8);
    let cells = h8 * w8;
    let channel = |c: usize| &logits[c * cells..(c + 1) * cells];
    let mut max = vec![f32::NEG_INFINITY; cells];
    for c in 0..65 {
        for (m, &l) in max.iter_mut().zip(channel(c)) {
            *m = m.max(l);
        }
    }
    let mut e = vec![0.0f32; 65 * cells];
    let mut sum = vec![0.0f32; cells];
    for c in 0..65 {
        let ec = &mut e[c * cells..(c + 1) * cells];
        for (((ec, s), &l), &m) in ec.iter_mut().zip(&mut sum).zip(channel(c)).zip(&max) {
            *ec = (l - m).exp();
            *s += *ec;
        }
    }
    let mut heat = vec![0.0f32; hh * ww];
    for cy in 0..h8 {
        for r in 0..8 {
            let row = &mut heat[(cy * 8 + r) * ww..(cy * 8 + r + 1) * ww];
            for cx in 0..w8 {
                let idx = cy * w8 + cx;
                for q in 0..8 {
                    row[cx * 8 + q] = e[(r * 8 + q) * cells + idx] / sum[idx];
                }
            }
        }
    }
    heat
}

/// The largest of the five values centred on each of `row`'s (the row's ends clamp the
/// window), into `out`. The interior is one expression per value, which the compiler
/// vectorises; the maximum is exact, so the result does not depend on the order.
fn max5(row: &[f32], out: &mut [f32]) {
    let n = row.len();
    let clamped = |x: usize| {
        let (a, b) = (x.saturating_sub(2), (x + 2).min(n - 1));
        row[a..=b].iter().copied().fold(f32::NEG_INFINITY, f32::max)
    };
    if n < 5 {
        out.iter_mut()
            .enumerate()
            .for_each(|(x, o)| *o = clamped(x));
        return;
    }
    for (o, w) in out[2..n - 2].iter_mut().zip(row.windows(5)) {
        *o = w[0].max(w[1]).max(w[2]).max(w[3]).max(w[4]);
    }
    for x in [0, 1, n - 2, n - 1] {
        out[x] = clamped(x);
    }
}

/// The 5x5 local maxima of `heat` above `threshold` (step 3), row-major.
fn local_maxima(heat: &[f32], (hh, ww): (usize, usize), threshold: f32) -> Vec<(usize, usize)> {
    let mut rowmax = vec![0.0f32; hh * ww];
    for (row, out) in heat.chunks_exact(ww).zip(rowmax.chunks_exact_mut(ww)) {
        max5(row, out);
    }
    let mut cand: Vec<(usize, usize)> = Vec::new();
    for y in 0..hh {
        let (a, b) = (y.saturating_sub(2), (y + 2).min(hh - 1));
        for (x, &v) in heat[y * ww..(y + 1) * ww].iter().enumerate() {
            if v <= threshold {
                continue;
            }
            let local_max = (a..=b)
                .map(|yy| rowmax[yy * ww + x])
                .fold(f32::NEG_INFINITY, f32::max);
            if v == local_max {
                cand.push((x, y));
            }
        }
    }
    cand
}

/// The dense descriptors (channel-major, 64 channels) divided by each cell's L2 norm, laid
/// out cell-major, so that sampling a cell reads its 64 values in a row.
fn normalised_cells(dense: &[f32], cells: usize) -> Vec<f32> {
    let mut norms = vec![0.0f32; cells];
    for c in 0..64 {
        for (n, &d) in norms.iter_mut().zip(&dense[c * cells..(c + 1) * cells]) {
            *n += d.powi(2);
        }
    }
    norms.iter_mut().for_each(|n| *n = n.sqrt().max(1e-12));
    // transposed in blocks of 16 cells, so that reads and writes stay in a few cache lines
    let mut out = vec![0.0f32; cells * 64];
    for first in (0..cells).step_by(16) {
        let last = (first + 16).min(cells);
        for c in 0..64 {
            let channel = &dense[c * cells + first..c * cells + last];
            for ((i, &d), &n) in (first..last).zip(channel).zip(&norms[first..last]) {
                out[i * 64 + c] = d / n;
            }
        }
    }
    out
}

/// A pixel coordinate `p` of an `n`-pixel side as `grid_sample` reads it on a map of `size`
/// values (`align_corners = false`, the reference's normalisation by `n - 1`).
fn to_grid(p: f32, n: f32, size: f32) -> f32 {
    (p / (n - 1.0)) * size - 0.5
}

/// Steps 4 and 5: each candidate's score (heatmap, nearest, times reliability, bilinear,
/// with `grid_sample` semantics) and the `top_k` best with a positive score, in a stable
/// order (ties keep the row-major order).
fn best_candidates(
    raw: &XFeatRaw,
    heat: &[f32],
    cand: &[(usize, usize)],
    top_k: usize,
) -> Vec<(f32, usize, usize)> {
    let (hh, ww) = raw.input_size;
    let (h8, w8) = (hh / 8, ww / 8);
    let (wf, hf) = (ww as f32, hh as f32);
    let sample_bilinear = |map: &[f32], mw: usize, mh: usize, ix: f32, iy: f32| -> f32 {
        let (x0, y0) = (ix.floor(), iy.floor());
        let (fx, fy) = (ix - x0, iy - y0);
        let mut acc = 0.0;
        for (dy, wy) in [(0i64, 1.0 - fy), (1, fy)] {
            for (dx, wx) in [(0i64, 1.0 - fx), (1, fx)] {
                let (xx, yy) = (x0 as i64 + dx, y0 as i64 + dy);
                if xx >= 0 && yy >= 0 && (xx as usize) < mw && (yy as usize) < mh {
                    acc += wx * wy * map[yy as usize * mw + xx as usize];
                }
            }
        }
        acc
    };
    let mut scored: Vec<(f32, usize, usize)> = cand
        .iter()
        .map(|&(x, y)| {
            if x == 0 && y == 0 {
                return (-1.0, x, y); // the reference marks (0, 0) as padding
            }
            let nx = to_grid(x as f32, wf, wf).round_ties_even();
            let ny = to_grid(y as f32, hf, hf).round_ties_even();
            let hv = if nx >= 0.0 && ny >= 0.0 && (nx as usize) < ww && (ny as usize) < hh {
                heat[ny as usize * ww + nx as usize]
            } else {
                0.0
            };
            let rv = sample_bilinear(
                raw.reliability,
                w8,
                h8,
                to_grid(x as f32, wf, w8 as f32),
                to_grid(y as f32, hf, h8 as f32),
            );
            (hv * rv, x, y)
        })
        .collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    scored.truncate(top_k);
    scored.retain(|s| s.0 > 0.0);
    scored
}

/// Post-processing of raw outputs into at most `top_k` features (see module docs).
pub fn postprocess(raw: &XFeatRaw, image_size: (usize, usize), cfg: &XFeatConfig) -> Features {
    let (hh, ww) = raw.input_size;
    let (h8, w8) = (hh / 8, ww / 8);
    let cells = h8 * w8;
    // 2. full-resolution heatmap
    let heat = heatmap(raw.keypoint_logits, (hh, ww));
    // 3. 5x5 non-maximum suppression (separable max filter), row-major order
    let cand = local_maxima(&heat, (hh, ww), cfg.detection_threshold);
    // 4-5. the best candidates by score
    let scored = best_candidates(raw, &heat, &cand, cfg.top_k);
    // dense descriptors, L2-normalised per cell, sampled bicubically
    let normalised = normalised_cells(raw.descriptors, cells);
    let read = |wgt: f32, cell: usize, d: &mut [f32; 64]| {
        for (dc, &v) in d.iter_mut().zip(&normalised[cell * 64..(cell + 1) * 64]) {
            *dc += wgt * v;
        }
    };
    sampled_features(
        raw.input_size,
        image_size,
        (&scored, &heat),
        cfg.subpixel,
        read,
    )
}

/// The features of the `scored` keypoints (score, x, y on the network's `(hh, ww)` input):
/// each descriptor sampled bicubically from the normalised dense map, `read(weight, cell,
/// descriptor)` adding one cell's weighted values, then L2-normalised; the coordinates
/// moved to the `heat` map's sub-pixel peak when asked, and scaled to `image_size`.
fn sampled_features(
    (hh, ww): (usize, usize),
    image_size: (usize, usize),
    (scored, heat): (&[(f32, usize, usize)], &[f32]),
    subpixel: bool,
    mut read: impl FnMut(f32, usize, &mut [f32; 64]),
) -> Features {
    let (h8, w8) = (hh / 8, ww / 8);
    let (wf, hf) = (ww as f32, hh as f32);
    let (rw, rh) = (image_size.0 as f32 / wf, image_size.1 as f32 / hf);
    let mut out = Features {
        dim: 64,
        image_size,
        ..Default::default()
    };
    out.descriptors.reserve(scored.len() * 64);
    for &(s, x, y) in scored {
        let ix = to_grid(x as f32, wf, w8 as f32);
        let iy = to_grid(y as f32, hf, h8 as f32);
        let (x0, y0) = (ix.floor() as i64, iy.floor() as i64);
        let wx = cubic_weights(ix - x0 as f32);
        let wy = cubic_weights(iy - y0 as f32);
        let mut d = [0.0f32; 64];
        for (j, wyj) in wy.iter().enumerate() {
            let yy = y0 - 1 + j as i64;
            if yy < 0 || yy as usize >= h8 {
                continue;
            }
            for (i, wxi) in wx.iter().enumerate() {
                let xx = x0 - 1 + i as i64;
                if xx < 0 || xx as usize >= w8 {
                    continue;
                }
                read(wyj * wxi, yy as usize * w8 + xx as usize, &mut d);
            }
        }
        let n = d.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
        out.descriptors.extend(d.iter().map(|v| v / n));
        let (dx, dy) = if subpixel {
            subpixel_offset(heat, (ww, hh), (x, y))
        } else {
            (0.0, 0.0)
        };
        out.keypoints
            .push([(x as f32 + dx) * rw, (y as f32 + dy) * rh]);
        out.scores.push(s);
    }
    out
}

/// The network's input size for `image` resized by `scale`: each side cut down to a multiple
/// of 32, at least 32, as the reference does.
///
/// A reduced frame is slightly squeezed (KITTI's 1241x376 at 0.75 becomes 928x256, 9 % less
/// high than wide). Rounding to the nearest multiple instead (928x288) was measured and not
/// kept: the real-time profile (768 keypoints) lost track on KITTI 03 with it
/// (docs/decisions/2026-12-06-xfeat-at-three-quarters-nearest-rounding.md).
fn network_size(image: &GrayImage, scale: f32) -> (usize, usize) {
    let side = |n: usize| {
        let scaled = if scale == 1.0 {
            n
        } else {
            (n as f32 * scale).round() as usize
        };
        ((scaled / 32) * 32).max(32)
    };
    (side(image.width), side(image.height))
}

impl Extractor for XFeat {
    fn extract(&mut self, image: &GrayImage) -> Result<Features, InferenceError> {
        if image.width < 32 || image.height < 32 {
            return Err(InferenceError::BadImage(format!(
                "image is {}x{}; XFeat needs at least 32x32 pixels",
                image.width, image.height
            )));
        }
        let (w32, h32) = network_size(image, self.cfg.image_scale);
        let input = resize_bilinear(image, w32, h32);
        let cfg = self.cfg.clone();
        self.with_raw(&input, h32, w32, |raw| {
            postprocess(raw, (image.width, image.height), &cfg)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The straightforward forms the fast ones above must equal bit for bit.
    mod reference {
        use super::super::*;

        /// Resizes to `(out_w, out_h)` with bilinear interpolation and half-pixel centres (as
        /// `F.interpolate(mode="bilinear", align_corners=False)`), returning values in [0, 1].
        pub(super) fn resize_bilinear(img: &GrayImage, out_w: usize, out_h: usize) -> Vec<f32> {
            let (w, h) = (img.width, img.height);
            let sx = w as f32 / out_w as f32;
            let sy = h as f32 / out_h as f32;
            let src = |x: usize, y: usize| img.data[y * w + x] as f32 / 255.0;
            let coord = |d: usize, s: f32, n: usize| -> (usize, usize, f32) {
                let c = ((d as f32 + 0.5) * s - 0.5).max(0.0);
                let i0 = (c.floor() as usize).min(n - 1);
                let i1 = (i0 + 1).min(n - 1);
                (i0, i1, c - i0 as f32)
            };
            let mut out = vec![0.0f32; out_w * out_h];
            for oy in 0..out_h {
                let (y0, y1, fy) = coord(oy, sy, h);
                for ox in 0..out_w {
                    let (x0, x1, fx) = coord(ox, sx, w);
                    let top = src(x0, y0) * (1.0 - fx) + src(x1, y0) * fx;
                    let bot = src(x0, y1) * (1.0 - fx) + src(x1, y1) * fx;
                    out[oy * out_w + ox] = top * (1.0 - fy) + bot * fy;
                }
            }
            out
        }

        /// Post-processing of raw outputs into at most `top_k` features (see module docs).
        pub(super) fn postprocess(
            raw: &XFeatRaw,
            image_size: (usize, usize),
            cfg: &XFeatConfig,
        ) -> Features {
            let (hh, ww) = raw.input_size;
            let (h8, w8) = (hh / 8, ww / 8);
            let cells = h8 * w8;
            // 2. full-resolution heatmap
            let mut heat = vec![0.0f32; hh * ww];
            for cy in 0..h8 {
                for cx in 0..w8 {
                    let idx = cy * w8 + cx;
                    let mut m = f32::NEG_INFINITY;
                    for c in 0..65 {
                        m = m.max(raw.keypoint_logits[c * cells + idx]);
                    }
                    let mut e = [0.0f32; 65];
                    let mut sum = 0.0f32;
                    for (c, ec) in e.iter_mut().enumerate() {
                        *ec = (raw.keypoint_logits[c * cells + idx] - m).exp();
                        sum += *ec;
                    }
                    for r in 0..8 {
                        for q in 0..8 {
                            heat[(cy * 8 + r) * ww + cx * 8 + q] = e[r * 8 + q] / sum;
                        }
                    }
                }
            }
            // 3. 5x5 non-maximum suppression (separable max filter), row-major order
            let mut rowmax = vec![0.0f32; hh * ww];
            for y in 0..hh {
                for x in 0..ww {
                    let (a, b) = (x.saturating_sub(2), (x + 2).min(ww - 1));
                    rowmax[y * ww + x] = heat[y * ww + a..=y * ww + b]
                        .iter()
                        .copied()
                        .fold(f32::NEG_INFINITY, f32::max);
                }
            }
            let mut cand: Vec<(usize, usize)> = Vec::new();
            for y in 0..hh {
                let (a, b) = (y.saturating_sub(2), (y + 2).min(hh - 1));
                for x in 0..ww {
                    let v = heat[y * ww + x];
                    if v <= cfg.detection_threshold {
                        continue;
                    }
                    let local_max = (a..=b)
                        .map(|yy| rowmax[yy * ww + x])
                        .fold(f32::NEG_INFINITY, f32::max);
                    if v == local_max {
                        cand.push((x, y));
                    }
                }
            }
            let scored = super::super::best_candidates(raw, &heat, &cand, cfg.top_k);
            // dense descriptors, L2-normalised per cell (divided by the cell's norm where sampled)
            let dense = raw.descriptors;
            let norms: Vec<f32> = (0..cells)
                .map(|i| {
                    (0..64)
                        .map(|c| dense[c * cells + i].powi(2))
                        .sum::<f32>()
                        .sqrt()
                        .max(1e-12)
                })
                .collect();
            let read = |wgt: f32, base: usize, d: &mut [f32; 64]| {
                for (c, dc) in d.iter_mut().enumerate() {
                    *dc += wgt * (dense[c * cells + base] / norms[base]);
                }
            };
            super::super::sampled_features(
                raw.input_size,
                image_size,
                (&scored, &heat),
                cfg.subpixel,
                read,
            )
        }
    }

    #[test]
    fn subpixel_offset_recovers_a_gaussian_peak() {
        let (w, h) = (20usize, 16usize);
        let (px, py) = (10.3f32, 7.8f32);
        let heat: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                (-((x - px).powi(2) + (y - py).powi(2)) / (2.0 * 1.3f32.powi(2))).exp()
            })
            .collect();
        let (dx, dy) = subpixel_offset(&heat, (w, h), (10, 8));
        assert!(
            (dx - 0.3).abs() < 1e-4 && (dy + 0.2).abs() < 1e-4,
            "{dx} {dy}"
        );
        // no neighbour on one side: that axis stays put
        assert_eq!(subpixel_offset(&heat, (w, h), (0, 8)).0, 0.0);
        // a flat or rising neighbourhood is not a peak to fit
        let flat = vec![0.25f32; w * h];
        assert_eq!(subpixel_offset(&flat, (w, h), (10, 8)), (0.0, 0.0));
        // a peak with one neighbour far above the other is clamped to half a pixel
        let mut skew = vec![1e-30f32; w * h];
        skew[8 * w + 10] = 1.0;
        skew[8 * w + 11] = 0.999;
        let (dx, _) = subpixel_offset(&skew, (w, h), (10, 8));
        assert!(dx > 0.0 && dx <= 0.5, "{dx}");
    }

    #[test]
    fn cubic_weights_sum_to_one_and_interpolate() {
        for t in [0.0f32, 0.25, 0.5, 0.9] {
            let w = cubic_weights(t);
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        }
        assert_eq!(cubic_weights(0.0), [0.0, 1.0, 0.0, 0.0]);
    }

    #[test]
    fn the_network_sides_are_cut_down_to_multiples_of_32() {
        let kitti = GrayImage::new(1241, 376, vec![0; 1241 * 376]).unwrap();
        assert_eq!(network_size(&kitti, 1.0), (1216, 352));
        // 930.75 x 282 cut down to 928 x 256
        assert_eq!(network_size(&kitti, 0.75), (928, 256));
        for scale in [0.25f32, 0.5, 0.6, 0.75, 0.9] {
            let (w, h) = network_size(&kitti, scale);
            assert!(w % 32 == 0 && h % 32 == 0);
            assert!((w as f32) <= 1241.0 * scale + 0.5 && (w as f32) > 1241.0 * scale - 32.5);
            assert!((h as f32) <= 376.0 * scale + 0.5 && (h as f32) > 376.0 * scale - 32.5);
        }
        // never below one 32-pixel block
        let tiny = GrayImage::new(40, 40, vec![0; 1600]).unwrap();
        assert_eq!(network_size(&tiny, 0.25), (32, 32));
    }

    #[test]
    fn resize_identity_keeps_pixels() {
        let img = GrayImage::new(4, 2, vec![0, 51, 102, 153, 204, 255, 0, 51]).unwrap();
        let out = resize_bilinear(&img, 4, 2);
        for (a, b) in out.iter().zip(&img.data) {
            assert!((a - *b as f32 / 255.0).abs() < 1e-6);
        }
    }

    #[test]
    fn single_peak_gives_one_keypoint() {
        // 64x64 input: an 8x8 grid of cells; make cell (2, 3) put all mass on sub-pixel (5, 6)
        let (hh, ww) = (64usize, 64usize);
        let cells = 64;
        let mut logits = vec![0.0f32; 65 * cells];
        for i in 0..cells {
            logits[64 * cells + i] = 10.0; // dustbin everywhere
        }
        let cell = 3 * 8 + 2;
        logits[(6 * 8 + 5) * cells + cell] = 30.0;
        let descriptors: Vec<f32> = (0..64 * cells).map(|i| (i % 7) as f32 + 1.0).collect();
        let reliability = vec![0.5; cells];
        let raw = XFeatRaw {
            input_size: (hh, ww),
            descriptors: &descriptors,
            keypoint_logits: &logits,
            reliability: &reliability,
        };
        let f = postprocess(&raw, (128, 64), &XFeatConfig::default());
        assert_eq!(f.len(), 1);
        assert_eq!(
            f.keypoints[0],
            [(2 * 8 + 5) as f32 * 2.0, (3 * 8 + 6) as f32]
        );
        assert!((f.scores[0] - 0.5).abs() < 1e-3);
        let n: f32 = f.descriptor(0).iter().map(|v| v * v).sum();
        assert!((n - 1.0).abs() < 1e-5);
    }

    /// A deterministic sequence of values in [0, 1).
    fn uniform(seed: u64, n: usize) -> Vec<f32> {
        let mut x = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect()
    }

    /// Bit patterns of everything a feature set holds.
    fn bits(f: &Features) -> (Vec<[u32; 2]>, Vec<u32>, Vec<u32>) {
        (
            f.keypoints.iter().map(|k| k.map(f32::to_bits)).collect(),
            f.scores.iter().map(|v| v.to_bits()).collect(),
            f.descriptors.iter().map(|v| v.to_bits()).collect(),
        )
    }

    /// The channel-wise heatmap, the row-wise suppression and the cell-major descriptors
    /// give the reference's features bit for bit: random network outputs of several sizes,
    /// peaked logits (many candidates), sub-pixel keypoints on and off, top-k above and
    /// below the candidates.
    #[test]
    fn postprocessing_equals_the_straightforward_form_bit_for_bit() {
        for (seed, (hh, ww)) in [(1u64, (64usize, 96usize)), (2, (96, 160)), (3, (352, 1216))] {
            let cells = (hh / 8) * (ww / 8);
            let logits: Vec<f32> = uniform(seed, 65 * cells)
                .iter()
                .enumerate()
                .map(|(i, u)| {
                    if i < 64 * cells {
                        12.0 * u - 4.0
                    } else {
                        2.0 * u
                    }
                })
                .collect();
            let descriptors: Vec<f32> = uniform(seed + 10, 64 * cells)
                .iter()
                .map(|u| u - 0.5)
                .collect();
            let reliability = uniform(seed + 20, cells);
            let raw = XFeatRaw {
                input_size: (hh, ww),
                descriptors: &descriptors,
                keypoint_logits: &logits,
                reliability: &reliability,
            };
            for (top_k, subpixel) in [(30, false), (1024, false), (1024, true), (100_000, true)] {
                let cfg = XFeatConfig {
                    top_k,
                    subpixel,
                    ..XFeatConfig::default()
                };
                let size = (ww * 5 / 4, hh * 9 / 8);
                let fast = postprocess(&raw, size, &cfg);
                let plain = reference::postprocess(&raw, size, &cfg);
                assert!(!fast.keypoints.is_empty());
                assert_eq!(bits(&fast), bits(&plain), "{hh}x{ww}, top {top_k}");
            }
        }
    }

    /// The resize with its columns computed once equals the per-pixel form bit for bit,
    /// shrinking and enlarging, odd sizes included.
    #[test]
    fn the_resize_equals_the_straightforward_form_bit_for_bit() {
        for (seed, (w, h), (ow, oh)) in [
            (1u64, (1241usize, 376usize), (1216usize, 352usize)),
            (2, (37, 23), (64, 32)),
            (3, (100, 61), (32, 32)),
            (4, (5, 3), (5, 3)),
        ] {
            let data = uniform(seed, w * h)
                .iter()
                .map(|u| (u * 256.0) as u8)
                .collect();
            let img = GrayImage::new(w, h, data).unwrap();
            let fast: Vec<u32> = resize_bilinear(&img, ow, oh)
                .iter()
                .map(|v| v.to_bits())
                .collect();
            let plain: Vec<u32> = reference::resize_bilinear(&img, ow, oh)
                .iter()
                .map(|v| v.to_bits())
                .collect();
            assert_eq!(fast, plain, "{w}x{h} -> {ow}x{oh}");
        }
    }
}
