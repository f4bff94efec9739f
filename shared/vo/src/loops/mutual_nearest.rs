//! Mutually nearest descriptors between two keyframes: the loop closer's only use of the
//! descriptors, and most of its time.
//!
//! The similarities are computed in blocks of one side's rows, so that each block of the
//! similarity matrix is scanned while it is in cache. Where only some rows can take part in
//! a pair (verification pairs only keypoints that have points on both sides), only those
//! rows' nearest neighbours are computed: each wanted row of one side against every row of
//! the other, which finds the same pairs as the whole matrix. Every similarity is the same
//! product, term for term, as in the whole matrix (the same `matrixmultiply` kernel,
//! whichever rows share a block), so the pairs are the same to the last bit.

use nalgebra::DMatrix;

/// Rows of the other side per block of the similarity matrix (256 kB at 1024 x 64 floats).
const BLOCK: usize = 64;

/// nalgebra multiplies with `matrixmultiply` only when every side is longer than this, and
/// with its own loop otherwise; a block is never cut this short, so that it is multiplied
/// as the whole matrix would be.
const SMALL: usize = 5;

/// Mutually nearest neighbours between two sets of unit descriptors (rows) with cosine
/// similarity at least `min_cos`, in the order of `a`'s rows.
pub(super) fn mutual_matches(
    a: &DMatrix<f32>,
    b: &DMatrix<f32>,
    min_cos: f32,
) -> Vec<(usize, usize)> {
    if a.nrows() == 0 || b.nrows() == 0 {
        return Vec::new();
    }
    let mut rows = RowBest::new(a.nrows());
    let mut best_a = vec![0usize; b.nrows()];
    for_each_block(a, b, |first, sim| {
        // one pass down each column (stored contiguously): its best row, and each row's
        // best column so far; ties go to the lowest index either way
        for (j, column) in sim.as_slice().chunks_exact(a.nrows()).enumerate() {
            rows.take(first + j, column);
            best_a[first + j] = first_argmax(column);
        }
    });
    rows.arg
        .iter()
        .zip(&rows.best)
        .enumerate()
        .filter(|&(i, (&j, &v))| v >= min_cos && best_a[j as usize] == i)
        .map(|(i, (&j, _))| (i, j as usize))
        .collect()
}

/// Each row's best column so far (the first on ties) and its value, kept as two arrays so
/// that [`RowBest::take`] vectorises.
struct RowBest {
    best: Vec<f32>,
    arg: Vec<u32>,
}

impl RowBest {
    fn new(rows: usize) -> Self {
        Self {
            best: vec![f32::MIN; rows],
            arg: vec![0; rows],
        }
    }

    /// Column `j` of the similarities (one value per row) offered to every row.
    fn take(&mut self, j: usize, column: &[f32]) {
        for ((rb, ra), &v) in self.best.iter_mut().zip(&mut self.arg).zip(column) {
            // a select, not a branch, so that it vectorises
            let better = v > *rb;
            *rb = if better { v } else { *rb };
            *ra = if better { j as u32 } else { *ra };
        }
    }
}

/// [`mutual_matches`] kept to the pairs of `a`'s rows `rows_a` and `b`'s rows `rows_b`
/// (ascending): the same pairs, computed from those rows' nearest neighbours alone when
/// that is less work than the whole matrix.
pub(super) fn mutual_matches_among(
    (a, rows_a): (&DMatrix<f32>, &[usize]),
    (b, rows_b): (&DMatrix<f32>, &[usize]),
    min_cos: f32,
) -> Vec<(usize, usize)> {
    let (na, nb) = (a.nrows(), b.nrows());
    let fewer = rows_a.len() * nb + rows_b.len() * na < na * nb;
    if !fewer || rows_a.len() <= SMALL || rows_b.len() <= SMALL {
        let (mut in_a, mut in_b) = (vec![false; na], vec![false; nb]);
        rows_a.iter().for_each(|&i| in_a[i] = true);
        rows_b.iter().for_each(|&j| in_b[j] = true);
        let mut pairs = mutual_matches(a, b, min_cos);
        pairs.retain(|&(i, j)| in_a[i] && in_b[j]);
        return pairs;
    }
    let from_a = nearest_rows(&selected(a, rows_a), b);
    let mut back = vec![u32::MAX; nb];
    for (&j, &i) in rows_b
        .iter()
        .zip(&nearest_rows(&selected(b, rows_b), a).arg)
    {
        back[j] = i;
    }
    rows_a
        .iter()
        .zip(from_a.arg.iter().zip(&from_a.best))
        .filter(|&(&i, (&j, &v))| v >= min_cos && back[j as usize] == i as u32)
        .map(|(&i, (&j, _))| (i, j as usize))
        .collect()
}

/// For each row of `queries`, the first row of `d` most similar to it and the similarity
/// (row 0 at `f32::MIN` where `d` is empty).
fn nearest_rows(queries: &DMatrix<f32>, d: &DMatrix<f32>) -> RowBest {
    let mut rows = RowBest::new(queries.nrows());
    if queries.nrows() > 0 {
        for_each_block(queries, d, |first, sim| {
            for (j, column) in sim.as_slice().chunks_exact(queries.nrows()).enumerate() {
                rows.take(first + j, column);
            }
        });
    }
    rows
}

/// Hands `f` the similarities of every row of `a` with each block of `b`'s rows: the index
/// of the block's first row and the `a.nrows() x block` matrix (column-major).
fn for_each_block(a: &DMatrix<f32>, b: &DMatrix<f32>, mut f: impl FnMut(usize, &DMatrix<f32>)) {
    let mut sim = DMatrix::<f32>::zeros(0, 0);
    let mut first = 0;
    while first < b.nrows() {
        let rest = b.nrows() - first;
        // the last block takes a short remainder along rather than leave it alone
        let len = if rest <= BLOCK + SMALL { rest } else { BLOCK };
        if sim.ncols() != len {
            sim = DMatrix::zeros(a.nrows(), len);
        }
        sim.gemm(1.0, a, &b.rows(first, len).transpose(), 0.0);
        f(first, &sim);
        first += len;
    }
}

/// The rows `rows` of `m`, in that order.
fn selected(m: &DMatrix<f32>, rows: &[usize]) -> DMatrix<f32> {
    DMatrix::from_fn(rows.len(), m.ncols(), |r, c| m[(rows[r], c)])
}

/// The index of the first largest value of `v` (0 if empty or all NaN), scanned eight
/// lanes at a time so that it vectorises: each lane keeps its own first maximum, and ties
/// between lanes go to the lowest index.
fn first_argmax(v: &[f32]) -> usize {
    const LANES: usize = 8;
    let (mut best, mut at) = ([f32::MIN; LANES], [0u32; LANES]);
    let chunks = v.chunks_exact(LANES);
    let rest = chunks.remainder();
    for (c, chunk) in chunks.enumerate() {
        for l in 0..LANES {
            let better = chunk[l] > best[l];
            best[l] = if better { chunk[l] } else { best[l] };
            at[l] = if better {
                (c * LANES + l) as u32
            } else {
                at[l]
            };
        }
    }
    let mut winner = (0usize, f32::MIN);
    for l in 0..LANES {
        let i = at[l] as usize;
        if best[l] > winner.1 || (best[l] == winner.1 && best[l] > f32::MIN && i < winner.0) {
            winner = (i, best[l]);
        }
    }
    let tail = v.len() - rest.len();
    for (k, &x) in rest.iter().enumerate() {
        if x > winner.1 {
            winner = (tail + k, x);
        }
    }
    winner.0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Uniform numbers in [0, 1) from a xorshift generator seeded with `s`.
    fn uniform(mut s: u64) -> impl FnMut() -> f32 {
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    /// The first largest value of `v` and its index, by a plain scan.
    fn first_max(v: Vec<f32>) -> (usize, f32) {
        v.iter()
            .enumerate()
            .fold((0, f32::MIN), |m, (i, &x)| if x > m.1 { (i, x) } else { m })
    }

    /// The pairs a plain scan of the whole similarity matrix finds (each row's first best
    /// column, kept where that column's first best row is the row).
    fn plain(a: &DMatrix<f32>, b: &DMatrix<f32>, min_cos: f32) -> Vec<(usize, usize)> {
        let sim = a * b.transpose();
        (0..a.nrows())
            .filter_map(|i| {
                let (j, v) = first_max(sim.row(i).iter().copied().collect());
                let back = first_max(sim.column(j).iter().copied().collect()).0;
                (v >= min_cos && back == i).then_some((i, j))
            })
            .collect()
    }

    #[test]
    fn mutual_matches_pair_equal_rows() {
        let a = DMatrix::<f32>::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1.0, 0.6, 0.8]);
        let b = DMatrix::<f32>::from_row_slice(2, 2, &[0.0, 1.0, 1.0, 0.0]);
        let m = mutual_matches(&a, &b, 0.9);
        assert_eq!(m, vec![(0, 1), (1, 0)]);
    }

    /// The blocked scan finds what a plain scan of every row and column finds, ties (coarse
    /// values) and odd sizes (blocks with a remainder, sides too short for `matrixmultiply`)
    /// included.
    #[test]
    fn mutual_matches_agree_with_a_plain_scan() {
        let mut u = uniform(0x2545_f491);
        for (na, nb, dim, levels) in [
            (37, 53, 3, 4.0),
            (64, 64, 3, 1e6),
            (5, 300, 3, 3.0),
            (129, 17, 3, 50.0),
            (300, 133, 64, 8.0),
            (70, 69, 64, 1e6),
        ] {
            let mut quantised =
                |n: usize| DMatrix::<f32>::from_fn(n, dim, |_, _| (u() * levels).round() / levels);
            let (a, b) = (quantised(na), quantised(nb));
            let expected = plain(&a, &b, 0.1);
            assert!(!expected.is_empty());
            assert_eq!(mutual_matches(&a, &b, 0.1), expected, "{na} x {nb}");
            let sim = &a * b.transpose();
            for column in sim.column_iter() {
                let v: Vec<f32> = column.iter().copied().collect();
                assert_eq!(first_argmax(&v), first_max(v.clone()).0, "{v:?}");
            }
        }
    }

    /// Kept to some rows on each side, the pairs are the whole matrix's pairs among those
    /// rows, whether they are computed from the wanted rows alone or from the whole matrix;
    /// unit descriptors of XFeat's size, near ties included (few distinct values).
    #[test]
    fn mutual_matches_among_rows_are_the_whole_matrix_pairs_among_them() {
        let mut u = uniform(0x9e37_79b9);
        for (na, nb, keep, levels) in [
            (400, 350, 0.2, 1e6),
            (400, 350, 0.3, 6.0),
            (200, 90, 0.9, 1e6),
            (64, 300, 0.05, 1e6),
            (150, 150, 0.5, 10.0),
        ] {
            let mut unit = |n: usize| {
                let mut m =
                    DMatrix::<f32>::from_fn(n, 64, |_, _| ((u() - 0.5) * levels).round() / levels);
                for mut r in m.row_iter_mut() {
                    let norm = r.norm().max(1e-6);
                    r /= norm;
                }
                m
            };
            let (a, b) = (unit(na), unit(nb));
            let mut pick = |n: usize| (0..n).filter(|_| u() < keep).collect::<Vec<_>>();
            let (rows_a, rows_b) = (pick(na), pick(nb));
            let expected: Vec<_> = plain(&a, &b, 0.0)
                .into_iter()
                .filter(|(i, j)| rows_a.contains(i) && rows_b.contains(j))
                .collect();
            let got = mutual_matches_among((&a, &rows_a), (&b, &rows_b), 0.0);
            assert_eq!(
                got,
                expected,
                "{na} x {nb}, {} and {} rows",
                rows_a.len(),
                rows_b.len()
            );
        }
    }
}
