//! Deterministic hashing and band-limited procedural noise.
//!
//! Everything here is a pure function of its integer inputs, so a scene renders to the same
//! bytes on every machine and thread count.

/// A well-mixed 64-bit hash of `x` (SplitMix64's step and output function).
pub fn mix64(x: u64) -> u64 {
    supermvo_geometry::rng::splitmix64_mix(x.wrapping_add(0x9E37_79B9_7F4A_7C15))
}

/// Hash of a lattice point and a seed, uniform in [0, 1).
pub fn hash2(ix: i64, iy: i64, seed: u64) -> f32 {
    let h = mix64(mix64(mix64(seed) ^ ix as u64) ^ (iy as u64).rotate_left(32));
    (h >> 40) as f32 / (1u64 << 24) as f32
}

/// A small seeded generator (SplitMix64 sequence) for scene layout.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator for `seed`, decorrelated per `stream`.
    pub fn new(seed: u64, stream: u64) -> Self {
        Self(mix64(seed ^ mix64(stream)))
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix64(self.0)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        let u = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * u
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        self.range(0.0, 1.0) < p
    }

    /// A fresh 64-bit seed for an object.
    pub fn seed(&mut self) -> u64 {
        self.next_u64()
    }
}

fn smooth(t: f32) -> f32 {
    t * t * (3.0 - 2.0 * t)
}

/// Value noise in [0, 1) at `(x, y)` lattice units, smoothly interpolated.
pub fn value_noise(x: f32, y: f32, seed: u64) -> f32 {
    let (fx, fy) = (x.floor(), y.floor());
    let (ix, iy) = (fx as i64, fy as i64);
    let (tx, ty) = (smooth(x - fx), smooth(y - fy));
    let a = hash2(ix, iy, seed);
    let b = hash2(ix + 1, iy, seed);
    let c = hash2(ix, iy + 1, seed);
    let d = hash2(ix + 1, iy + 1, seed);
    let top = a + (b - a) * tx;
    let bottom = c + (d - c) * tx;
    top + (bottom - top) * ty
}

/// Fractal value noise around 0 (roughly in [-0.5, 0.5]) with octaves from `freq` (cycles
/// per metre) upwards, each octave faded out as its period approaches the pixel footprint
/// `footprint` (metres per pixel) so that distant surfaces do not alias.
pub fn fbm(u: f64, v: f64, freq: f64, octaves: u32, footprint: f64, seed: u64) -> f32 {
    let mut sum = 0.0f32;
    let mut amp = 0.5f32;
    let mut f = freq;
    for k in 0..octaves {
        // Cycles per pixel of this octave: fade between 0.25 and 0.5 (Nyquist).
        let cpp = f * footprint;
        let w = (2.0 - 4.0 * cpp).clamp(0.0, 1.0) as f32;
        if w <= 0.0 {
            // Replace the lost detail by its mean (0).
            break;
        }
        let n = value_noise(
            (u * f) as f32,
            (v * f) as f32,
            seed.wrapping_add(k as u64 * 7919),
        ) - 0.5;
        sum += amp * w * n;
        amp *= 0.5;
        f *= 2.0;
    }
    sum
}

/// Area coverage of `[lo, hi]` by a pixel of width `fw` centred at `x` (a box filter), so that
/// edges of painted shapes are anti-aliased.
pub fn coverage(x: f64, lo: f64, hi: f64, fw: f64) -> f32 {
    let fw = fw.max(1e-6);
    let a = ((x - lo) / fw + 0.5).clamp(0.0, 1.0);
    let b = ((hi - x) / fw + 0.5).clamp(0.0, 1.0);
    (a + b - 1.0).clamp(0.0, 1.0) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hashes_are_uniform_and_repeatable() {
        let mut mean = 0.0;
        for i in 0..10_000 {
            let h = hash2(i, -i * 3, 42);
            assert!((0.0..1.0).contains(&h));
            assert_eq!(h, hash2(i, -i * 3, 42));
            mean += h as f64;
        }
        mean /= 10_000.0;
        assert!((mean - 0.5).abs() < 0.02, "mean {mean}");
    }

    #[test]
    fn noise_is_continuous_and_band_limited() {
        let a = value_noise(3.2, 4.7, 1);
        let b = value_noise(3.2001, 4.7, 1);
        assert!((a - b).abs() < 1e-3);
        // A footprint far coarser than every octave leaves nothing but the mean.
        assert_eq!(fbm(1.3, 2.1, 4.0, 5, 10.0, 3), 0.0);
        assert!(fbm(1.3, 2.1, 4.0, 5, 0.001, 3) != 0.0);
    }

    #[test]
    fn coverage_is_a_box_filter() {
        assert_eq!(coverage(0.5, 0.0, 1.0, 0.1), 1.0);
        assert_eq!(coverage(2.0, 0.0, 1.0, 0.1), 0.0);
        assert!((coverage(1.0, 0.0, 1.0, 0.1) - 0.5).abs() < 1e-6);
    }
}
