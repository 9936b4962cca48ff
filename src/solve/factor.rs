//! Prefactored sparse symmetric positive definite systems (faer's sparse LLᵀ with an AMD
//! fill-reducing ordering). Factorization happens once at bind time; each solve is one
//! forward and one back substitution on an `n x k` right-hand side, in place, using a
//! workspace allocated up front, so the per-frame path does not allocate.
//!
//! faer notes (measured, see `../shared/CRATES.md`): the low-level API is used because the
//! high-level `Llt::solve_in_place` allocates scratch per call; solves use `Par::Seq`
//! because `Par::rayon` made triangular solves 2–8x slower here.

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, LltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, MatMut, Par, Side};

/// Errors factoring a system matrix.
#[derive(Debug, thiserror::Error)]
pub enum FactorError {
    #[error("system matrix entry ({row}, {col}) is outside a {n}x{n} matrix")]
    OutOfBounds { row: usize, col: usize, n: usize },
    #[error("system matrix is not positive definite (is some part of the control mesh unconstrained?): {detail}")]
    NotPositiveDefinite { detail: String },
    #[error("sparse factorization failed: {detail}")]
    Faer { detail: String },
}

/// A factored `n x n` SPD matrix `A = P Lᵀ L Pᵀ`.
pub struct SparseCholesky {
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
    n: usize,
    nnz_l: usize,
}

/// Scratch memory for [`SparseCholesky::solve_in_place`], sized for `k` right-hand sides.
pub struct SolveScratch {
    mem: MemBuffer,
    k: usize,
}

impl SparseCholesky {
    /// Factors the matrix whose upper triangle (including the diagonal) is given as
    /// `(row, col, value)` with `row <= col`. Duplicate entries are summed.
    pub fn factor_upper(n: usize, upper: &[(usize, usize, f64)]) -> Result<Self, FactorError> {
        let mut entries: Vec<(usize, usize, f64)> = Vec::with_capacity(upper.len());
        for &(r, c, v) in upper {
            if r >= n || c >= n {
                return Err(FactorError::OutOfBounds { row: r, col: c, n });
            }
            let (r, c) = if r <= c { (r, c) } else { (c, r) };
            entries.push((r, c, v));
        }
        entries.sort_unstable_by_key(|&(r, c, _)| (c, r));
        let mut merged: Vec<Triplet<usize, usize, f64>> = Vec::with_capacity(entries.len());
        for (r, c, v) in entries {
            match merged.last_mut() {
                Some(t) if t.row == r && t.col == c => t.val += v,
                _ => merged.push(Triplet::new(r, c, v)),
            }
        }
        let a = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &merged).map_err(|e| {
            FactorError::Faer {
                detail: format!("{e:?}"),
            }
        })?;
        let symbolic = factorize_symbolic_cholesky(
            a.symbolic(),
            Side::Upper,
            SymmetricOrdering::Amd,
            Default::default(),
        )
        .map_err(|e| FactorError::Faer {
            detail: format!("{e:?}"),
        })?;
        let mut values = vec![0.0f64; symbolic.len_val()];
        let req = symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default());
        let mut mem = MemBuffer::try_new(req).map_err(|e| FactorError::Faer {
            detail: format!("{e:?}"),
        })?;
        symbolic
            .factorize_numeric_llt::<f64>(
                &mut values,
                a.as_ref(),
                Side::Upper,
                LltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .map_err(|e| FactorError::NotPositiveDefinite {
                detail: format!("{e:?}"),
            })?;
        let nnz_l = values.len();
        Ok(Self {
            symbolic,
            values,
            n,
            nnz_l,
        })
    }

    /// Matrix dimension.
    pub fn n(&self) -> usize {
        self.n
    }

    /// Stored values of the factor (a measure of fill-in).
    pub fn factor_len(&self) -> usize {
        self.nnz_l
    }

    /// Scratch for solving with `k` right-hand sides at once.
    pub fn scratch(&self, k: usize) -> SolveScratch {
        let req: StackReq = self.symbolic.solve_in_place_scratch::<f64>(k, Par::Seq);
        SolveScratch {
            mem: MemBuffer::new(req),
            k,
        }
    }

    /// Solves `A X = B` in place: `rhs` holds `B` (`n x k`, `k` no more than the scratch
    /// was sized for) and receives `X`. Does not allocate.
    pub fn solve_in_place(&self, rhs: MatMut<'_, f64>, scratch: &mut SolveScratch) {
        assert_eq!(rhs.nrows(), self.n, "rhs rows");
        assert!(
            rhs.ncols() <= scratch.k,
            "rhs has more columns than the scratch was sized for"
        );
        let llt = LltRef::<usize, f64>::new(&self.symbolic, &self.values);
        llt.solve_in_place_with_conj(Conj::No, rhs, Par::Seq, MemStack::new(&mut scratch.mem));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;

    #[test]
    fn solves_small_spd_system() {
        // 1D Laplacian plus identity: tridiagonal SPD.
        let n = 50;
        let mut upper = Vec::new();
        for i in 0..n {
            upper.push((i, i, 3.0));
            if i + 1 < n {
                upper.push((i, i + 1, -1.0));
            }
        }
        let chol = SparseCholesky::factor_upper(n, &upper).unwrap();
        let x_true = Mat::<f64>::from_fn(n, 3, |i, j| (i as f64 * 0.1 + j as f64).sin());
        // b = A x
        let b = Mat::<f64>::from_fn(n, 3, |i, j| {
            let mut s = 3.0 * x_true[(i, j)];
            if i > 0 {
                s -= x_true[(i - 1, j)];
            }
            if i + 1 < n {
                s -= x_true[(i + 1, j)];
            }
            s
        });
        let mut x = b.clone();
        let mut scratch = chol.scratch(3);
        chol.solve_in_place(x.as_mut(), &mut scratch);
        let err = (&x - &x_true).norm_max();
        assert!(err < 1e-12, "max error {err}");
    }

    #[test]
    fn singular_matrix_is_reported() {
        // Pure Laplacian of a path: singular (constant null space).
        let upper = vec![(0, 0, 1.0), (0, 1, -1.0), (1, 1, 1.0)];
        assert!(matches!(
            SparseCholesky::factor_upper(2, &upper),
            Err(FactorError::NotPositiveDefinite { .. })
        ));
    }
}
