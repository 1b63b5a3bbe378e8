//! Solvers of the fit stage: the ridge system (MᵀM + κD) a = Mᵀb by Cholesky in a symmetrically
//! scaled basis, symmetric eigen-decompositions (condition numbers, plain least squares), and a
//! streaming Householder QR of [M | b; √(κD) | 0] used as the accuracy reference.
//!
//! Scaling: with S = diag(1/√A_ll), Â = S A S has a unit diagonal, and Cholesky of Â is
//! backward stable with an error governed by cond(Â), which is far smaller than cond(A) (the
//! monomial columns differ in size by orders of magnitude). All factorizations here run
//! sequentially (`Par::Seq`), so results do not depend on the thread count.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::evd::{self_adjoint_evd, self_adjoint_evd_scratch, ComputeEigenvectors};
use faer::{Mat, Par};

use crate::numerics::cholesky;

/// Why a solve failed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum SolveFailure {
    /// A pivot of the scaled Cholesky factorization was not positive (at this column).
    NotPositiveDefinite { column: usize },
    /// The eigen-decomposition did not converge.
    NoConvergence,
}

/// The result of one ridge solve.
#[derive(Clone, Debug)]
pub(crate) struct RidgeSolution {
    /// The coefficients a.
    pub coefficients: Vec<f64>,
}

/// Solves (G + κ diag(d)) a = r by Cholesky of the symmetrically scaled matrix.
pub(crate) fn solve_ridge(
    gram: &[f64],
    rhs: &[f64],
    ridge: &[f64],
    kappa: f64,
) -> Result<RidgeSolution, SolveFailure> {
    let c = rhs.len();
    let (mut chol, s) = scaled_matrix(gram, ridge, kappa, c);
    // Relative pivot floor: a pivot this small means the scaled matrix is singular to working
    // precision.
    let floor = 1e-15 * c as f64;
    cholesky::factor(&mut chol, c, floor)
        .map_err(|column| SolveFailure::NotPositiveDefinite { column })?;
    let mut y: Vec<f64> = (0..c).map(|l| rhs[l] * s[l]).collect();
    cholesky::solve(&chol, c, &mut y);
    let coefficients = (0..c).map(|l| y[l] * s[l]).collect();
    Ok(RidgeSolution { coefficients })
}

/// S (G + κD) S and the diagonal of S; S_ll = 1/√(G_ll + κ d_l) (1 where that is not positive).
pub(crate) fn scaled_matrix(
    gram: &[f64],
    ridge: &[f64],
    kappa: f64,
    c: usize,
) -> (Vec<f64>, Vec<f64>) {
    let s: Vec<f64> = (0..c)
        .map(|l| {
            let d = gram[l * c + l] + kappa * ridge[l];
            if d > 0.0 && d.is_finite() {
                1.0 / d.sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let mut a = vec![0.0; c * c];
    for l in 0..c {
        for m in 0..c {
            let mut v = gram[l * c + m];
            if l == m {
                v += kappa * ridge[l];
            }
            a[l * c + m] = v * s[l] * s[m];
        }
    }
    (a, s)
}

/// Eigenvalues (ascending) and, if asked, eigenvectors (columns, c×c column-major) of a
/// symmetric row-major matrix.
pub(crate) fn symmetric_eigen(
    a: &[f64],
    c: usize,
    vectors: bool,
) -> Result<(Vec<f64>, Option<Vec<f64>>), SolveFailure> {
    let mat = Mat::<f64>::from_fn(c, c, |i, j| a[i * c + j]);
    let mut s = faer::diag::Diag::<f64>::zeros(c);
    let compute = if vectors {
        ComputeEigenvectors::Yes
    } else {
        ComputeEigenvectors::No
    };
    let mut u = if vectors {
        Some(Mat::<f64>::zeros(c, c))
    } else {
        None
    };
    let mut buffer = MemBuffer::new(self_adjoint_evd_scratch::<f64>(
        c,
        compute,
        Par::Seq,
        Default::default(),
    ));
    self_adjoint_evd(
        mat.as_ref(),
        s.as_mut(),
        u.as_mut().map(|u| u.as_mut()),
        Par::Seq,
        MemStack::new(&mut buffer),
        Default::default(),
    )
    .map_err(|_| SolveFailure::NoConvergence)?;
    let values: Vec<f64> = s.column_vector().iter().copied().collect();
    let vecs = u.map(|u| {
        let mut out = vec![0.0; c * c];
        for j in 0..c {
            for i in 0..c {
                out[j * c + i] = u[(i, j)];
            }
        }
        out
    });
    Ok((values, vecs))
}

/// 2-norm condition number λ_max/λ_min of G + κ diag(d) and of its scaled form S(G + κD)S.
pub(crate) fn condition_numbers(
    gram: &[f64],
    ridge: &[f64],
    kappa: f64,
    c: usize,
) -> Result<(f64, f64), SolveFailure> {
    let mut a = gram.to_vec();
    for l in 0..c {
        a[l * c + l] += kappa * ridge[l];
    }
    let cond = |values: &[f64]| {
        let max = values.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let min = values.iter().fold(f64::INFINITY, |m, v| m.min(*v));
        if min > 0.0 {
            max / min
        } else {
            f64::INFINITY
        }
    };
    let (values, _) = symmetric_eigen(&a, c, false)?;
    let (scaled, _) = scaled_matrix(gram, ridge, kappa, c);
    let (scaled_values, _) = symmetric_eigen(&scaled, c, false)?;
    Ok((cond(&values), cond(&scaled_values)))
}

/// A streaming Householder QR of the least-squares problem [rows | targets]: the rows arrive in
/// tiles; after each tile the (c+1)×(c+1) triangle R of [M | b] so far is kept, so memory is
/// O(c·(c + tile)) whatever the number of rows.
pub(crate) struct StreamingQr {
    c: usize,
    /// Upper-triangular (c+1)×(c+1) factor, column-major, of [M | b] so far.
    r: Mat<f64>,
    /// Pending rows [m(q) | b], at most `tile` of them.
    pending: Vec<Vec<f64>>,
    tile: usize,
}

impl StreamingQr {
    pub(crate) fn new(c: usize) -> StreamingQr {
        StreamingQr {
            c,
            r: Mat::zeros(0, c + 1),
            pending: Vec::new(),
            tile: 4096,
        }
    }

    /// Adds one row `[m | b]` (length c + 1).
    pub(crate) fn push(&mut self, row: Vec<f64>) {
        debug_assert_eq!(row.len(), self.c + 1);
        self.pending.push(row);
        if self.pending.len() == self.tile {
            self.flush();
        }
    }

    fn flush(&mut self) {
        if self.pending.is_empty() {
            return;
        }
        let w = self.c + 1;
        let top = self.r.nrows();
        let rows = top + self.pending.len();
        let mut a = Mat::<f64>::zeros(rows, w);
        for i in 0..top {
            for j in i..w {
                a[(i, j)] = self.r[(i, j)];
            }
        }
        for (t, row) in self.pending.iter().enumerate() {
            for j in 0..w {
                a[(top + t, j)] = row[j];
            }
        }
        self.pending.clear();
        let size = rows.min(w);
        let block = faer::linalg::qr::no_pivoting::factor::recommended_block_size::<f64>(rows, w);
        let mut q_coeff = Mat::<f64>::zeros(block, size);
        let mut buffer = MemBuffer::new(
            faer::linalg::qr::no_pivoting::factor::qr_in_place_scratch::<f64>(
                rows,
                w,
                block,
                Par::Seq,
                Default::default(),
            ),
        );
        let _info = faer::linalg::qr::no_pivoting::factor::qr_in_place(
            a.as_mut(),
            q_coeff.as_mut(),
            Par::Seq,
            MemStack::new(&mut buffer),
            Default::default(),
        );
        let mut r = Mat::<f64>::zeros(size, w);
        for i in 0..size {
            for j in i..w {
                r[(i, j)] = a[(i, j)];
            }
        }
        self.r = r;
    }

    /// Solves min ‖M a − b‖ by back substitution on R; `None` when R is singular.
    pub(crate) fn solve(mut self) -> Option<Vec<f64>> {
        self.flush();
        let c = self.c;
        if self.r.nrows() < c {
            return None;
        }
        let mut a = vec![0.0; c];
        for i in (0..c).rev() {
            let mut sum = self.r[(i, c)];
            for (j, aj) in a.iter().enumerate().skip(i + 1) {
                sum -= self.r[(i, j)] * aj;
            }
            let d = self.r[(i, i)];
            if d == 0.0 || !d.is_finite() {
                return None;
            }
            a[i] = sum / d;
        }
        Some(a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cholesky_solves_small_system() {
        let g = vec![4.0, 1.0, 0.0, 1.0, 3.0, 1.0, 0.0, 1.0, 2.0];
        let r = vec![1.0, 2.0, 3.0];
        let sol = solve_ridge(&g, &r, &[0.0; 3], 0.0).unwrap();
        for i in 0..3 {
            let v: f64 = (0..3).map(|j| g[i * 3 + j] * sol.coefficients[j]).sum();
            assert!((v - r[i]).abs() < 1e-14);
        }
    }

    #[test]
    fn singular_system_is_reported() {
        let g = vec![1.0, 1.0, 1.0, 1.0];
        assert!(solve_ridge(&g, &[1.0, 1.0], &[0.0; 2], 0.0).is_err());
        // The ridge term makes it solvable.
        assert!(solve_ridge(&g, &[1.0, 1.0], &[1.0; 2], 0.1).is_ok());
    }

    #[test]
    fn streaming_qr_matches_normal_equations() {
        let mut qr = StreamingQr::new(2);
        qr.tile = 3;
        let rows = [
            [1.0, 0.0, 1.0],
            [1.0, 1.0, 2.0],
            [1.0, 2.0, 2.9],
            [1.0, 3.0, 4.2],
            [1.0, 4.0, 4.9],
        ];
        for row in rows {
            qr.push(row.to_vec());
        }
        let a = qr.solve().unwrap();
        // Normal equations for a line fit.
        let mut g = vec![0.0; 4];
        let mut r = vec![0.0; 2];
        for row in rows {
            for i in 0..2 {
                r[i] += row[i] * row[2];
                for j in 0..2 {
                    g[i * 2 + j] += row[i] * row[j];
                }
            }
        }
        let b = solve_ridge(&g, &r, &[0.0; 2], 0.0).unwrap().coefficients;
        assert!((a[0] - b[0]).abs() < 1e-12 && (a[1] - b[1]).abs() < 1e-12);
    }

    #[test]
    fn eigenvalues_of_diagonal() {
        let (v, _) = symmetric_eigen(&[3.0, 0.0, 0.0, 1.0], 2, false).unwrap();
        assert!((v[0] - 1.0).abs() < 1e-14 && (v[1] - 3.0).abs() < 1e-14);
    }
}
