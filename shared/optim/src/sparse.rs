//! A sparse symmetric positive-definite solver for a fixed block pattern, on faer.
//!
//! The sparsity pattern of `H` (lower triangle, `D x D` blocks) is fixed for a graph, so the
//! structure, the value slot of every block entry, the fill-reducing (AMD) symbolic
//! factorisation, the factor storage and the scratch memory are all set up once; each
//! solve only writes values and refactorises numerically.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, LltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, MatMut, Par, Side};
use nalgebra::SMatrix;

/// Cholesky solver for matrices with a fixed block pattern.
pub struct BlockCholesky<const D: usize> {
    n: usize,
    matrix: SparseColMat<usize, f64>,
    /// value slots of the lower-triangle entries of each block, row-major within the block
    slots: Vec<Vec<usize>>,
    diag: Vec<usize>,
    symbolic: SymbolicCholesky<usize>,
    factor: Vec<f64>,
    mem: MemBuffer,
}

impl<const D: usize> std::fmt::Debug for BlockCholesky<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "BlockCholesky({}x{}, {} factor values)",
            self.n,
            self.n,
            self.factor.len()
        )
    }
}

impl<const D: usize> BlockCholesky<D> {
    /// Sets up for `n_blocks` variables and the given lower-triangle block positions
    /// (`row >= col`; diagonal blocks must be included).
    pub fn new(n_blocks: usize, blocks: &[(usize, usize)]) -> Option<Self> {
        let n = n_blocks * D;
        let mut trip = Vec::new();
        for &(bi, bj) in blocks {
            for r in 0..D {
                for c in 0..D {
                    let (row, col) = (bi * D + r, bj * D + c);
                    if row >= col {
                        trip.push(Triplet::new(row, col, 0.0));
                    }
                }
            }
        }
        let matrix = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &trip).ok()?;
        let (cp, ri) = (
            matrix.symbolic().col_ptr().to_vec(),
            matrix.symbolic().row_idx().to_vec(),
        );
        let find = |row: usize, col: usize| -> Option<usize> {
            let s = &ri[cp[col]..cp[col + 1]];
            s.binary_search(&row).ok().map(|k| cp[col] + k)
        };
        let mut slots = Vec::with_capacity(blocks.len());
        for &(bi, bj) in blocks {
            let mut v = Vec::with_capacity(D * D);
            for r in 0..D {
                for c in 0..D {
                    let (row, col) = (bi * D + r, bj * D + c);
                    if row >= col {
                        v.push(find(row, col)?);
                    }
                }
            }
            slots.push(v);
        }
        let diag = (0..n).map(|c| find(c, c)).collect::<Option<Vec<_>>>()?;
        let symbolic = factorize_symbolic_cholesky(
            matrix.symbolic(),
            Side::Lower,
            SymmetricOrdering::Amd,
            Default::default(),
        )
        .ok()?;
        let factor = vec![0.0; symbolic.len_val()];
        let req = symbolic
            .factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default())
            .or(symbolic.solve_in_place_scratch::<f64>(1, Par::Seq));
        let mem = MemBuffer::try_new(req).ok()?;
        Some(Self {
            n,
            matrix,
            slots,
            diag,
            symbolic,
            factor,
            mem,
        })
    }

    /// Writes the block values (same order as the blocks given to [`BlockCholesky::new`]).
    pub fn set_blocks(&mut self, values: &[SMatrix<f64, D, D>]) {
        let vals = self.matrix.val_mut();
        for (m, slots) in values.iter().zip(&self.slots) {
            let mut k = 0;
            for r in 0..D {
                for c in 0..D {
                    // entries with row >= col inside a diagonal block; all in off-diagonal ones
                    if slots.len() == D * D || r >= c {
                        vals[slots[k]] = m[(r, c)];
                        k += 1;
                    }
                }
            }
        }
    }

    /// Solves `(H + lambda I) x = b` in place; false if the matrix is not positive definite.
    pub fn solve(&mut self, lambda: f64, b: &mut [f64]) -> bool {
        let mut damped = self.matrix.clone();
        {
            let vals = damped.val_mut();
            for &k in &self.diag {
                vals[k] += lambda;
            }
        }
        let stack = MemStack::new(&mut self.mem);
        let ok = self
            .symbolic
            .factorize_numeric_llt::<f64>(
                &mut self.factor,
                damped.as_ref(),
                Side::Lower,
                Default::default(),
                Par::Seq,
                stack,
                Default::default(),
            )
            .is_ok();
        if !ok {
            return false;
        }
        let llt = LltRef::new(&self.symbolic, &self.factor);
        let rhs = MatMut::from_column_major_slice_mut(b, self.n, 1);
        llt.solve_in_place_with_conj(Conj::No, rhs, Par::Seq, MemStack::new(&mut self.mem));
        b.iter().all(|v| v.is_finite())
    }
}
