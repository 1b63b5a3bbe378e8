//! Dense Cholesky factorization A = L Lᵀ of a small symmetric positive definite matrix, and the
//! solve of L Lᵀ x = b, for the ridge systems of the fit stage and the local quadric fits of
//! detail mode.
//!
//! Storage: `a` is row-major `n × n`; the factorization reads the lower triangle of A (the
//! diagonal included) and overwrites it with L, leaving the strict upper triangle untouched.
//!
//! Invariants: each entry of L is formed by one sum in increasing index order followed by one
//! division (or a square root on the diagonal), so results depend only on the input bits.

/// Factors A = L Lᵀ in place (see the module docs for the storage). A pivot (the diagonal
/// before its square root) must exceed `min_pivot`; the first one that does not (NaN included)
/// stops the factorization, and its column is returned as the error.
pub(crate) fn factor(a: &mut [f64], n: usize, min_pivot: f64) -> Result<(), usize> {
    debug_assert!(a.len() >= n * n);
    for j in 0..n {
        let (head, tail) = a.split_at_mut(j * n);
        let row_j = &mut tail[..n];
        for k in 0..j {
            let row_k = &head[k * n..k * n + n];
            let mut sum = row_j[k];
            for m in 0..k {
                sum -= row_j[m] * row_k[m];
            }
            row_j[k] = sum / row_k[k];
        }
        let mut d = row_j[j];
        for v in &row_j[..j] {
            d -= v * v;
        }
        if d.is_nan() || d <= min_pivot {
            return Err(j);
        }
        row_j[j] = d.sqrt();
    }
    Ok(())
}

/// Solves L Lᵀ x = b in place (`y` holds b on entry, x on return) with the factor from
/// [`factor`].
pub(crate) fn solve(l: &[f64], n: usize, y: &mut [f64]) {
    for i in 0..n {
        let mut sum = y[i];
        for m in 0..i {
            sum -= l[i * n + m] * y[m];
        }
        y[i] = sum / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut sum = y[i];
        for m in i + 1..n {
            sum -= l[m * n + i] * y[m];
        }
        y[i] = sum / l[i * n + i];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_small_system() {
        // A = [[4, 2, 0], [2, 5, 1], [0, 1, 3]], x = [1, −1, 2].
        let mut a = vec![4.0, 2.0, 0.0, 2.0, 5.0, 1.0, 0.0, 1.0, 3.0];
        let mut b = vec![2.0, -1.0, 5.0];
        factor(&mut a, 3, 0.0).unwrap();
        solve(&a, 3, &mut b);
        for (x, e) in b.iter().zip([1.0, -1.0, 2.0]) {
            assert!((x - e).abs() < 1e-14);
        }
    }

    #[test]
    fn rejects_a_matrix_that_is_not_positive_definite() {
        let mut a = vec![1.0, 2.0, 2.0, 1.0];
        assert_eq!(factor(&mut a, 2, 0.0), Err(1));
        let mut a = vec![f64::NAN, 0.0, 0.0, 1.0];
        assert_eq!(factor(&mut a, 2, 0.0), Err(0));
    }
}
