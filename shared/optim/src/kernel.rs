//! Robust kernels, the one set every least-squares problem of the project uses: the loss of
//! a residual's squared norm and its iteratively-reweighted least-squares weight.

/// A robust kernel applied to a (whitened) residual's norm.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Kernel {
    /// Plain least squares.
    #[default]
    None,
    /// Huber with threshold k.
    Huber(f64),
    /// Cauchy with scale k.
    Cauchy(f64),
}

impl Kernel {
    /// Cost of a whitened residual with squared norm `s2` (GTSAM's `loss`, so that the
    /// plain case is `0.5 * s2`).
    pub fn loss(&self, s2: f64) -> f64 {
        match *self {
            Kernel::None => 0.5 * s2,
            Kernel::Huber(k) => {
                let s = s2.sqrt();
                if s <= k {
                    0.5 * s2
                } else {
                    k * s - 0.5 * k * k
                }
            }
            Kernel::Cauchy(k) => 0.5 * k * k * (1.0 + s2 / (k * k)).ln(),
        }
    }

    /// Iteratively-reweighted least-squares weight at squared norm `s2`.
    pub fn weight(&self, s2: f64) -> f64 {
        match *self {
            Kernel::None => 1.0,
            Kernel::Huber(k) => {
                let s = s2.sqrt();
                if s <= k {
                    1.0
                } else {
                    k / s
                }
            }
            Kernel::Cauchy(k) => 1.0 / (1.0 + s2 / (k * k)),
        }
    }
}
