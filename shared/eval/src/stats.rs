//! Summary statistics of an error sequence, as evo reports them.

use serde::{Deserialize, Serialize};

/// rmse, mean, median, std (population), min, max and sse of a set of errors.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    /// Root mean square.
    pub rmse: f64,
    /// Arithmetic mean.
    pub mean: f64,
    /// Median (mean of the two middle values for an even count).
    pub median: f64,
    /// Population standard deviation.
    pub std: f64,
    /// Smallest value.
    pub min: f64,
    /// Largest value.
    pub max: f64,
    /// Sum of squares.
    pub sse: f64,
}

impl Stats {
    /// Statistics of `errors`; `None` when empty.
    pub fn of(errors: &[f64]) -> Option<Stats> {
        if errors.is_empty() {
            return None;
        }
        let n = errors.len() as f64;
        let sum = pairwise_sum(errors);
        let mean = sum / n;
        let squares: Vec<f64> = errors.iter().map(|e| e * e).collect();
        let sse = pairwise_sum(&squares);
        let dev: Vec<f64> = errors.iter().map(|e| (e - mean) * (e - mean)).collect();
        let var = pairwise_sum(&dev) / n;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let mid = sorted.len() / 2;
        let median = if sorted.len().is_multiple_of(2) {
            0.5 * (sorted[mid - 1] + sorted[mid])
        } else {
            sorted[mid]
        };
        Some(Stats {
            rmse: (sse / n).sqrt(),
            mean,
            median,
            std: var.sqrt(),
            min: sorted[0],
            max: sorted[sorted.len() - 1],
            sse,
        })
    }
}

/// Pairwise (cascade) summation: error grows as O(log n) rather than O(n), the way NumPy sums.
fn pairwise_sum(v: &[f64]) -> f64 {
    if v.len() <= 128 {
        v.iter().sum()
    } else {
        let h = v.len() / 2;
        pairwise_sum(&v[..h]) + pairwise_sum(&v[h..])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values() {
        let s = Stats::of(&[3.0, 1.0, 4.0, 1.0, 5.0, 9.0]).unwrap();
        assert_eq!(s.median, 3.5);
        assert_eq!((s.min, s.max), (1.0, 9.0));
        assert_eq!(s.sse, 133.0);
        assert!((s.mean - 23.0 / 6.0).abs() < 1e-15);
        assert!((s.rmse - (133.0f64 / 6.0).sqrt()).abs() < 1e-15);
        let var = [3.0f64, 1.0, 4.0, 1.0, 5.0, 9.0]
            .iter()
            .map(|x| (x - 23.0 / 6.0).powi(2))
            .sum::<f64>()
            / 6.0;
        assert!((s.std - var.sqrt()).abs() < 1e-15);
        assert_eq!(Stats::of(&[2.0, 7.0, 1.0]).unwrap().median, 2.0);
        assert!(Stats::of(&[]).is_none());
    }
}
