//! Timestamp association of two trajectories (nearest stamp within a tolerance), as evo does.

use crate::EvalError;
use supermvo_dataset::Trajectory;

/// For each stamp of `a`, the index of the nearest stamp of `b` if within `max_diff`.
///
/// With `b` sorted this is a binary search; otherwise a linear scan. Ties go to the
/// earlier stamp of `b`. Several stamps of `a` may map to the same stamp of `b`.
pub fn matching_indices(a: &[f64], b: &[f64], max_diff: f64) -> (Vec<usize>, Vec<usize>) {
    let mut ia = Vec::new();
    let mut ib = Vec::new();
    if b.is_empty() {
        return (ia, ib);
    }
    let sorted = b.windows(2).all(|w| w[1] >= w[0]);
    for (i, &s) in a.iter().enumerate() {
        let best = if sorted {
            if s < b[0] - max_diff || s > b[b.len() - 1] + max_diff {
                continue;
            }
            let mut j = b.partition_point(|&x| x <= s);
            if j >= b.len() {
                j = b.len() - 1;
            }
            let diff_ub = b[j] - s;
            let diff_lb = if j > 0 { s - b[j - 1] } else { f64::INFINITY };
            if diff_ub <= max_diff && diff_ub < diff_lb {
                j
            } else if diff_lb <= max_diff && diff_lb <= diff_ub {
                j - 1
            } else {
                continue;
            }
        } else {
            let mut best = 0;
            let mut best_d = f64::INFINITY;
            for (j, &t) in b.iter().enumerate() {
                let d = (t - s).abs();
                if d < best_d {
                    best = j;
                    best_d = d;
                }
            }
            if best_d > max_diff {
                continue;
            }
            best
        };
        ia.push(i);
        ib.push(best);
    }
    (ia, ib)
}

/// Associates `reference` and `estimate` by timestamp: the shorter trajectory keeps each of
/// its poses that has a partner within `max_diff` seconds in the longer one.
///
/// Returns the two reduced trajectories, pose `i` of one matching pose `i` of the other.
pub fn associate(
    reference: &Trajectory,
    estimate: &Trajectory,
    max_diff: f64,
) -> Result<(Trajectory, Trajectory), EvalError> {
    let (Some(rs), Some(es)) = (&reference.stamps, &estimate.stamps) else {
        return Err(EvalError::NoTimestamps);
    };
    let est_longer = es.len() > rs.len();
    let (short, long) = if est_longer {
        (reference, estimate)
    } else {
        (estimate, reference)
    };
    let (Some(ss), Some(ls)) = (&short.stamps, &long.stamps) else {
        return Err(EvalError::NoTimestamps);
    };
    let (i_short, i_long) = matching_indices(ss, ls, max_diff);
    if i_short.is_empty() {
        return Err(EvalError::NoMatchingStamps {
            max_diff,
            ref_range: range(rs),
            est_range: range(es),
        });
    }
    let short = short.select(&i_short);
    let long = long.select(&i_long);
    Ok(if est_longer {
        (short, long)
    } else {
        (long, short)
    })
}

fn range(s: &[f64]) -> (f64, f64) {
    (
        s.first().copied().unwrap_or(f64::NAN),
        s.last().copied().unwrap_or(f64::NAN),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_within_tolerance_sorted_and_unsorted() {
        let a = [0.0, 1.0, 2.05, 3.5, 10.0];
        let b = [0.01, 0.99, 2.0, 2.1, 3.0];
        let (ia, ib) = matching_indices(&a, &b, 0.06);
        assert_eq!(ia, vec![0, 1, 2]);
        assert_eq!(ib, vec![0, 1, 2]);
        let b_unsorted = [3.0, 2.1, 0.99, 0.01, 2.0];
        let (ia, ib) = matching_indices(&a, &b_unsorted, 0.06);
        assert_eq!(ia, vec![0, 1, 2]);
        assert_eq!(ib, vec![3, 2, 4]);
        // an exact tie goes to the earlier stamp
        let (_, ib) = matching_indices(&[1.5], &[1.0, 2.0], 0.5);
        assert_eq!(ib, vec![0]);
    }
}
