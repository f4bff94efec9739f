//! The classical baseline: ORB (Rublee et al., ICCV 2011) keypoints and binary descriptors,
//! and a brute-force Hamming matcher. No network, no ONNX Runtime.
//!
//! * FAST-9 corners on an 8-level image pyramid (scale 1.2), ranked by the Harris response,
//!   with 3x3 non-maximum suppression and a per-level budget proportional to the level's
//!   area (so coarse levels get fewer features, as in the paper);
//! * orientation by the intensity centroid of a radius-15 disc;
//! * rotated BRIEF: 256 intensity comparisons on the Gaussian-smoothed level, at point pairs
//!   drawn once from an isotropic Gaussian (σ = 31/5, clipped to the 31x31 patch) by a fixed
//!   seed, rotated by the keypoint's orientation.
//!
//! Descriptors are 256 bits, stored as 8 `u32` words bit-cast into the `f32` descriptor slots
//! of [`Features`] (`dim` = 8) so they travel through every interface unchanged; only
//! [`OrbMatcher`] reads them, as bits.

use crate::{Extractor, Features, InferenceError, Matcher, Matches};
use supermvo_dataset::GrayImage;

/// ORB settings.
#[derive(Debug, Clone, PartialEq)]
pub struct OrbConfig {
    /// Keypoints per image at most.
    pub top_k: usize,
    /// Pyramid levels.
    pub levels: usize,
    /// Scale factor between levels.
    pub scale_factor: f32,
    /// FAST intensity threshold.
    pub fast_threshold: i16,
}

impl Default for OrbConfig {
    fn default() -> Self {
        Self {
            top_k: 1024,
            levels: 8,
            scale_factor: 1.2,
            fast_threshold: 20,
        }
    }
}

/// Descriptor words per keypoint (256 bits).
pub use supermvo_features::ORB_WORDS;
const PATCH_RADIUS: i32 = 15;
/// Pixels kept clear of the border: the rotated BRIEF pattern and the orientation disc.
const BORDER: i32 = 20;

/// The ORB extractor.
#[derive(Debug, Clone)]
pub struct Orb {
    cfg: OrbConfig,
    pattern: Vec<[(f32, f32); 2]>,
}

/// A grey image as bytes.
struct Plane {
    w: usize,
    h: usize,
    px: Vec<u8>,
}

impl Plane {
    #[inline]
    fn at(&self, x: i32, y: i32) -> i16 {
        self.px[y as usize * self.w + x as usize] as i16
    }
}

fn resize(src: &Plane, w: usize, h: usize) -> Plane {
    let (sx, sy) = (src.w as f32 / w as f32, src.h as f32 / h as f32);
    let mut px = vec![0u8; w * h];
    for y in 0..h {
        let fy = ((y as f32 + 0.5) * sy - 0.5).max(0.0);
        let y0 = (fy as usize).min(src.h - 1);
        let y1 = (y0 + 1).min(src.h - 1);
        let wy = fy - y0 as f32;
        for x in 0..w {
            let fx = ((x as f32 + 0.5) * sx - 0.5).max(0.0);
            let x0 = (fx as usize).min(src.w - 1);
            let x1 = (x0 + 1).min(src.w - 1);
            let wx = fx - x0 as f32;
            let g = |xx: usize, yy: usize| src.px[yy * src.w + xx] as f32;
            let v = (1.0 - wy) * ((1.0 - wx) * g(x0, y0) + wx * g(x1, y0))
                + wy * ((1.0 - wx) * g(x0, y1) + wx * g(x1, y1));
            px[y * w + x] = v.round().clamp(0.0, 255.0) as u8;
        }
    }
    Plane { w, h, px }
}

/// Separable Gaussian blur, σ = 2, 7 taps (the smoothing BRIEF's comparisons need).
fn blur(src: &Plane) -> Plane {
    const K: [f32; 7] = [0.0702, 0.1311, 0.1907, 0.2161, 0.1907, 0.1311, 0.0702];
    let (w, h) = (src.w, src.h);
    let mut tmp = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (k, c) in K.iter().enumerate() {
                let xx = (x as i32 + k as i32 - 3).clamp(0, w as i32 - 1) as usize;
                s += c * src.px[y * w + xx] as f32;
            }
            tmp[y * w + x] = s;
        }
    }
    let mut px = vec![0u8; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (k, c) in K.iter().enumerate() {
                let yy = (y as i32 + k as i32 - 3).clamp(0, h as i32 - 1) as usize;
                s += c * tmp[yy * w + x];
            }
            px[y * w + x] = s.round().clamp(0.0, 255.0) as u8;
        }
    }
    Plane { w, h, px }
}

/// The 16 pixels of the radius-3 Bresenham circle.
const CIRCLE: [(i32, i32); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// Whether 9 contiguous circle pixels are all brighter than `p + t` or all darker than `p - t`.
fn is_fast_corner(img: &Plane, x: i32, y: i32, t: i16) -> bool {
    let p = img.at(x, y);
    // quick rejection: of the 4 compass pixels, at least 2 consecutive must pass
    let c = |i: usize| img.at(x + CIRCLE[i].0, y + CIRCLE[i].1);
    let (a, b, cc, d) = (c(0), c(4), c(8), c(12));
    let bright = [a, b, cc, d].iter().filter(|&&v| v > p + t).count();
    let dark = [a, b, cc, d].iter().filter(|&&v| v < p - t).count();
    if bright < 2 && dark < 2 {
        return false;
    }
    let mut vals = [0i16; 16];
    for (i, v) in vals.iter_mut().enumerate() {
        *v = c(i);
    }
    for sign in [1i16, -1] {
        let mut run = 0;
        for i in 0..16 + 9 {
            let v = vals[i % 16];
            let pass = if sign > 0 { v > p + t } else { v < p - t };
            if pass {
                run += 1;
                if run >= 9 {
                    return true;
                }
            } else {
                run = 0;
            }
        }
    }
    false
}

/// Harris corner response over a 7x7 window (k = 0.04), Sobel gradients.
fn harris(img: &Plane, x: i32, y: i32) -> f32 {
    let (mut a, mut b, mut c) = (0f32, 0f32, 0f32);
    for dy in -3..=3 {
        for dx in -3..=3 {
            let (u, v) = (x + dx, y + dy);
            let ix = (img.at(u + 1, v - 1) + 2 * img.at(u + 1, v) + img.at(u + 1, v + 1)
                - img.at(u - 1, v - 1)
                - 2 * img.at(u - 1, v)
                - img.at(u - 1, v + 1)) as f32;
            let iy = (img.at(u - 1, v + 1) + 2 * img.at(u, v + 1) + img.at(u + 1, v + 1)
                - img.at(u - 1, v - 1)
                - 2 * img.at(u, v - 1)
                - img.at(u + 1, v - 1)) as f32;
            a += ix * ix;
            b += iy * iy;
            c += ix * iy;
        }
    }
    let s = 1.0 / (4.0 * 49.0 * 255.0);
    let (a, b, c) = (a * s * s, b * s * s, c * s * s);
    a * b - c * c - 0.04 * (a + b) * (a + b)
}

/// Orientation of the intensity centroid of the radius-15 disc around `(x, y)`.
fn orientation(img: &Plane, x: i32, y: i32) -> f32 {
    let (mut m01, mut m10) = (0f32, 0f32);
    for dy in -PATCH_RADIUS..=PATCH_RADIUS {
        let span = ((PATCH_RADIUS * PATCH_RADIUS - dy * dy) as f32).sqrt() as i32;
        for dx in -span..=span {
            let v = img.at(x + dx, y + dy) as f32;
            m10 += dx as f32 * v;
            m01 += dy as f32 * v;
        }
    }
    m01.atan2(m10)
}

/// The BRIEF point pairs: a fixed-seed isotropic Gaussian (σ = 31/5) clipped to the patch.
fn brief_pattern() -> Vec<[(f32, f32); 2]> {
    let mut rng = supermvo_geometry::rng::SplitMix64::new(0x5EED_0F0B);
    let mut next = || rng.next_f64();
    let mut gauss = || {
        let (u1, u2) = (next().max(1e-12), next());
        ((-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()) as f32
    };
    let sigma = 31.0 / 5.0;
    let mut pick = || (gauss() * sigma).clamp(-13.0, 13.0);
    (0..256)
        .map(|_| [(pick(), pick()), (pick(), pick())])
        .collect()
}

impl Orb {
    /// An ORB extractor.
    pub fn new(cfg: OrbConfig) -> Self {
        Self {
            cfg,
            pattern: brief_pattern(),
        }
    }

    fn describe(&self, img: &Plane, x: i32, y: i32, angle: f32, out: &mut [u32; ORB_WORDS]) {
        let (s, c) = angle.sin_cos();
        for (i, [(ax, ay), (bx, by)]) in self.pattern.iter().enumerate() {
            let rot = |px: f32, py: f32| {
                let u = (c * px - s * py).round() as i32;
                let v = (s * px + c * py).round() as i32;
                img.at(x + u, y + v)
            };
            if rot(*ax, *ay) < rot(*bx, *by) {
                out[i / 32] |= 1 << (i % 32);
            }
        }
    }
}

impl Extractor for Orb {
    fn extract(&mut self, image: &GrayImage) -> Result<Features, InferenceError> {
        if image.width < 2 * BORDER as usize + 8 || image.height < 2 * BORDER as usize + 8 {
            return Err(InferenceError::BadImage(format!(
                "image is {}x{}; ORB needs at least {}x{} pixels",
                image.width,
                image.height,
                2 * BORDER + 8,
                2 * BORDER + 8
            )));
        }
        let base = Plane {
            w: image.width,
            h: image.height,
            px: image.data.clone(),
        };
        let levels = self.cfg.levels.max(1);
        let f = 1.0 / self.cfg.scale_factor;
        // per-level budget proportional to area: n_l ∝ f^(2l)
        let weights: Vec<f32> = (0..levels).map(|l| f.powi(2 * l as i32)).collect();
        let total: f32 = weights.iter().sum();
        let mut keypoints = Vec::new();
        let mut scores = Vec::new();
        let mut descriptors = Vec::new();
        let mut level_img = base;
        for (l, wgt) in weights.iter().enumerate() {
            if l > 0 {
                let s = self.cfg.scale_factor.powi(l as i32);
                let (w, h) = (
                    (image.width as f32 / s).round() as usize,
                    (image.height as f32 / s).round() as usize,
                );
                if w < 2 * BORDER as usize + 8 || h < 2 * BORDER as usize + 8 {
                    break;
                }
                level_img = resize(&level_img, w, h);
            }
            let budget = ((self.cfg.top_k as f32 * wgt / total).round() as usize).max(1);
            let (w, h) = (level_img.w as i32, level_img.h as i32);
            // FAST corners with their Harris response, then 3x3 non-maximum suppression
            let mut response = vec![0f32; (w * h) as usize];
            let mut corners = Vec::new();
            for y in BORDER..h - BORDER {
                for x in BORDER..w - BORDER {
                    if is_fast_corner(&level_img, x, y, self.cfg.fast_threshold) {
                        let r = harris(&level_img, x, y);
                        response[(y * w + x) as usize] = r;
                        corners.push((x, y, r));
                    }
                }
            }
            corners.retain(|&(x, y, r)| {
                (-1..=1).all(|dy| {
                    (-1..=1).all(|dx| {
                        (dx == 0 && dy == 0) || response[((y + dy) * w + x + dx) as usize] < r
                    })
                })
            });
            // strongest first; ties by position so the order is deterministic
            corners.sort_by(|a, b| b.2.total_cmp(&a.2).then((a.1, a.0).cmp(&(b.1, b.0))));
            corners.truncate(budget);
            let smooth = blur(&level_img);
            let scale = self.cfg.scale_factor.powi(l as i32);
            for (x, y, r) in corners {
                let angle = orientation(&level_img, x, y);
                let mut d = [0u32; ORB_WORDS];
                self.describe(&smooth, x, y, angle, &mut d);
                // level pixel centres map to (x + 0.5) * scale - 0.5 in the full image
                keypoints.push([
                    (x as f32 + 0.5) * scale - 0.5,
                    (y as f32 + 0.5) * scale - 0.5,
                ]);
                scores.push(r);
                descriptors.extend(d.iter().map(|&v| f32::from_bits(v)));
            }
        }
        // one list, strongest first
        let mut order: Vec<usize> = (0..keypoints.len()).collect();
        order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
        order.truncate(self.cfg.top_k);
        Ok(Features {
            keypoints: order.iter().map(|&i| keypoints[i]).collect(),
            scores: order.iter().map(|&i| scores[i]).collect(),
            descriptors: order
                .iter()
                .flat_map(|&i| descriptors[i * ORB_WORDS..(i + 1) * ORB_WORDS].to_vec())
                .collect(),
            dim: ORB_WORDS,
            image_size: (image.width, image.height),
        })
    }
}

/// Brute-force Hamming matching of ORB descriptors: mutual nearest neighbours within
/// `max_distance` bits that pass Lowe's ratio test.
#[derive(Debug, Clone)]
pub struct OrbMatcher {
    /// Largest Hamming distance accepted (of 256).
    pub max_distance: u32,
    /// Best distance must be below `ratio` times the second best.
    pub ratio: f32,
}

impl Default for OrbMatcher {
    fn default() -> Self {
        Self {
            max_distance: 64,
            ratio: 0.8,
        }
    }
}

fn words(f: &Features, i: usize) -> [u32; ORB_WORDS] {
    let mut w = [0u32; ORB_WORDS];
    for (k, v) in w.iter_mut().enumerate() {
        *v = f.descriptors[i * ORB_WORDS + k].to_bits();
    }
    w
}

fn hamming(a: &[u32; ORB_WORDS], b: &[u32; ORB_WORDS]) -> u32 {
    a.iter().zip(b).map(|(x, y)| (x ^ y).count_ones()).sum()
}

impl Matcher for OrbMatcher {
    fn match_features(&mut self, a: &Features, b: &Features) -> Result<Matches, InferenceError> {
        for f in [a, b] {
            if f.dim != ORB_WORDS || f.descriptors.len() != f.len() * ORB_WORDS {
                return Err(InferenceError::BadImage(format!(
                    "the ORB matcher needs ORB descriptors ({ORB_WORDS} words), got dimension {}",
                    f.dim
                )));
            }
        }
        let wa: Vec<_> = (0..a.len()).map(|i| words(a, i)).collect();
        let wb: Vec<_> = (0..b.len()).map(|i| words(b, i)).collect();
        let best = |from: &[[u32; ORB_WORDS]], to: &[[u32; ORB_WORDS]]| -> Vec<(usize, u32, u32)> {
            from.iter()
                .map(|d| {
                    let (mut bi, mut b1, mut b2) = (usize::MAX, u32::MAX, u32::MAX);
                    for (j, e) in to.iter().enumerate() {
                        let h = hamming(d, e);
                        if h < b1 {
                            (b2, b1, bi) = (b1, h, j);
                        } else if h < b2 {
                            b2 = h;
                        }
                    }
                    (bi, b1, b2)
                })
                .collect()
        };
        let ab = best(&wa, &wb);
        let ba = best(&wb, &wa);
        let mut pairs = Vec::new();
        let mut scores = Vec::new();
        for (i, &(j, d1, d2)) in ab.iter().enumerate() {
            if j == usize::MAX || d1 > self.max_distance {
                continue;
            }
            if (d1 as f32) >= self.ratio * d2 as f32 {
                continue;
            }
            if ba[j].0 != i {
                continue;
            }
            pairs.push((i, j));
            scores.push(1.0 - d1 as f32 / 256.0);
        }
        Ok(Matches { pairs, scores })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured test image: random blocks (deterministic).
    fn blocks(w: usize, h: usize, seed: u64) -> GrayImage {
        let mut s = seed;
        let mut cell = vec![0u8; 64 * 64];
        for v in cell.iter_mut() {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            *v = (s >> 56) as u8;
        }
        let data = (0..w * h)
            .map(|i| cell[((i / w) / 8 % 64) * 64 + (i % w) / 8 % 64])
            .collect();
        GrayImage {
            width: w,
            height: h,
            data,
        }
    }

    fn shift(img: &GrayImage, dx: usize, dy: usize) -> GrayImage {
        let mut data = vec![0u8; img.data.len()];
        for y in 0..img.height {
            for x in 0..img.width {
                let (sx, sy) = (x.saturating_sub(dx), y.saturating_sub(dy));
                data[y * img.width + x] = img.data[sy * img.width + sx];
            }
        }
        GrayImage {
            width: img.width,
            height: img.height,
            data,
        }
    }

    #[test]
    fn matches_a_shifted_image_at_the_shift() {
        let a = blocks(320, 240, 7);
        let b = shift(&a, 5, 3);
        let mut orb = Orb::new(OrbConfig {
            top_k: 500,
            ..Default::default()
        });
        let (fa, fb) = (orb.extract(&a).unwrap(), orb.extract(&b).unwrap());
        assert!(fa.len() > 200, "{}", fa.len());
        let m = OrbMatcher::default().match_features(&fa, &fb).unwrap();
        assert!(m.pairs.len() > 100, "{}", m.pairs.len());
        let good = m
            .pairs
            .iter()
            .filter(|&&(i, j)| {
                let (p, q) = (fa.keypoints[i], fb.keypoints[j]);
                (q[0] - p[0] - 5.0).abs() < 1.5 && (q[1] - p[1] - 3.0).abs() < 1.5
            })
            .count();
        assert!(
            good * 10 >= m.pairs.len() * 9,
            "{good} of {}",
            m.pairs.len()
        );
    }

    #[test]
    fn deterministic_and_rejects_tiny_images() {
        let a = blocks(200, 120, 3);
        let mut orb = Orb::new(OrbConfig::default());
        let f1 = orb.extract(&a).unwrap();
        let f2 = orb.extract(&a).unwrap();
        assert_eq!(f1.keypoints, f2.keypoints);
        let bits = |f: &Features| {
            f.descriptors
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&f1), bits(&f2));
        let tiny = GrayImage {
            width: 20,
            height: 20,
            data: vec![0; 400],
        };
        assert!(orb.extract(&tiny).is_err());
    }

    #[test]
    fn hamming_counts_bits() {
        let a = [0u32; ORB_WORDS];
        let mut b = [0u32; ORB_WORDS];
        b[0] = 0b1011;
        b[7] = 1 << 31;
        assert_eq!(hamming(&a, &b), 4);
    }
}
