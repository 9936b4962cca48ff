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
    factorize_symbolic_cholesky, CholeskySymbolicParams, LltRef, SymbolicCholesky,
    SymbolicCholeskyRaw, SymmetricOrdering,
};
use faer::sparse::linalg::SupernodalThreshold;
use faer::sparse::{SparseColMat, Triplet};
use faer::{Conj, MatMut, Par, Side};
use glam::DVec3;

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

/// Which factorization faer builds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FactorKind {
    /// faer decides (supernodal for all but tiny systems).
    Auto,
    /// Simplicial (column by column): enables [`SparseCholesky::solve3`], whose
    /// interleaved three-column substitution is faster than faer's supernodal solve on
    /// the control meshes measured here (see `rigless bench --suite capsules`).
    Simplicial,
}

/// A factored `n x n` SPD matrix: `P A Pᵀ = L Lᵀ`, with `(P x)_i = x_{fwd_i}`.
pub struct SparseCholesky {
    symbolic: SymbolicCholesky<usize>,
    values: Vec<f64>,
    n: usize,
    nnz_l: usize,
    simplicial: Option<Simplicial>,
}

/// The simplicial factor in compressed columns (diagonal first in each column) and the
/// fill-reducing permutation, with 32-bit indices for the substitution loops.
struct Simplicial {
    col_ptr: Vec<u32>,
    row_idx: Vec<u32>,
    fwd: Vec<u32>,
    inv: Vec<u32>,
    /// `1 / L_jj` per column (the substitutions multiply rather than divide).
    inv_diag: Vec<f64>,
}

/// Scratch memory for [`SparseCholesky::solve_in_place`], sized for `k` right-hand sides.
pub struct SolveScratch {
    mem: MemBuffer,
    k: usize,
}

impl SparseCholesky {
    /// Factors the matrix whose upper triangle (including the diagonal) is given as
    /// `(row, col, value)` with `row <= col`. Duplicate entries are summed.
    pub fn factor_upper(
        n: usize,
        upper: &[(usize, usize, f64)],
        kind: FactorKind,
    ) -> Result<Self, FactorError> {
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
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: match kind {
                FactorKind::Auto => SupernodalThreshold::AUTO,
                FactorKind::Simplicial => SupernodalThreshold::FORCE_SIMPLICIAL,
            },
            ..Default::default()
        };
        let symbolic =
            factorize_symbolic_cholesky(a.symbolic(), Side::Upper, SymmetricOrdering::Amd, params)
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
        let simplicial = match symbolic.raw() {
            SymbolicCholeskyRaw::Simplicial(sym) if kind == FactorKind::Simplicial => {
                let to_u32 = |v: &[usize]| v.iter().map(|&x| x as u32).collect::<Vec<_>>();
                let (fwd, inv) = match symbolic.perm() {
                    Some(p) => (to_u32(p.arrays().0), to_u32(p.arrays().1)),
                    None => ((0..n as u32).collect(), (0..n as u32).collect()),
                };
                let factor = sym.factor();
                let col_ptr = to_u32(factor.col_ptr());
                let inv_diag = col_ptr[..n]
                    .iter()
                    .map(|&a| 1.0 / values[a as usize])
                    .collect();
                Some(Simplicial {
                    col_ptr,
                    row_idx: to_u32(factor.row_idx()),
                    fwd,
                    inv,
                    inv_diag,
                })
            }
            _ => None,
        };
        if n > u32::MAX as usize || nnz_l > u32::MAX as usize {
            return Err(FactorError::Faer {
                detail: format!("{n} unknowns and {nnz_l} factor entries exceed 32-bit indices"),
            });
        }
        Ok(Self {
            symbolic,
            values,
            n,
            nnz_l,
            simplicial,
        })
    }

    /// Solves `A X = B` for three right-hand sides stored as rows (`x[i]` is row `i` of
    /// the `n x 3` matrix), in place, with `work` (`len n`) as scratch. Needs a
    /// [`FactorKind::Simplicial`] factor; falls back to faer's solve otherwise (which
    /// allocates). Does not allocate on the simplicial path.
    pub fn solve3(&self, x: &mut [DVec3], work: &mut [DVec3]) {
        let Some(s) = &self.simplicial else {
            let mut m = faer::Mat::<f64>::from_fn(self.n, 3, |i, j| x[i][j]);
            let mut scratch = self.scratch(3);
            self.solve_in_place(m.as_mut(), &mut scratch);
            for (i, v) in x.iter_mut().enumerate() {
                *v = DVec3::new(m[(i, 0)], m[(i, 1)], m[(i, 2)]);
            }
            return;
        };
        s.substitute3(&self.values, x, work);
    }
}

impl Simplicial {
    /// [`SparseCholesky::solve3`]'s substitutions, with the factor's values `lv`.
    fn substitute3(&self, lv: &[f64], x: &mut [DVec3], work: &mut [DVec3]) {
        let (s, n) = (self, self.inv_diag.len());
        let (cp, ri) = (&s.col_ptr, &s.row_idx);
        for (w, &f) in work.iter_mut().zip(&s.fwd) {
            *w = x[f as usize];
        }
        // L y = P b: columns left to right, diagonal first in each column.
        for j in 0..n {
            let (a, b) = (cp[j] as usize, cp[j + 1] as usize);
            let yj = work[j] * s.inv_diag[j];
            work[j] = yj;
            for (&r, &l) in ri[a + 1..b].iter().zip(&lv[a + 1..b]) {
                work[r as usize] -= yj * l;
            }
        }
        // Lᵀ z = y: columns right to left.
        for j in (0..n).rev() {
            let (a, b) = (cp[j] as usize, cp[j + 1] as usize);
            let mut acc = work[j];
            for (&r, &l) in ri[a + 1..b].iter().zip(&lv[a + 1..b]) {
                acc -= work[r as usize] * l;
            }
            work[j] = acc * s.inv_diag[j];
        }
        for (v, &i) in x.iter_mut().zip(&s.inv) {
            *v = work[i as usize];
        }
    }
}

impl SparseCholesky {
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
        let chol = SparseCholesky::factor_upper(n, &upper, FactorKind::Auto).unwrap();
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
        // The interleaved simplicial solve gives the same answer.
        let simp = SparseCholesky::factor_upper(n, &upper, FactorKind::Simplicial).unwrap();
        let mut rows: Vec<DVec3> = (0..n)
            .map(|i| DVec3::new(b[(i, 0)], b[(i, 1)], b[(i, 2)]))
            .collect();
        let mut work = vec![DVec3::ZERO; n];
        simp.solve3(&mut rows, &mut work);
        let err3 = (0..n)
            .map(|i| {
                (rows[i] - DVec3::new(x_true[(i, 0)], x_true[(i, 1)], x_true[(i, 2)]))
                    .abs()
                    .max_element()
            })
            .fold(0.0, f64::max);
        assert!(err3 < 1e-12, "max error {err3}");
    }

    #[test]
    fn singular_matrix_is_reported() {
        // Pure Laplacian of a path: singular (constant null space).
        let upper = vec![(0, 0, 1.0), (0, 1, -1.0), (1, 1, 1.0)];
        assert!(matches!(
            SparseCholesky::factor_upper(2, &upper, FactorKind::Simplicial),
            Err(FactorError::NotPositiveDefinite { .. })
        ));
    }
}
