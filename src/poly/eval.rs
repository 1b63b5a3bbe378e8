//! Evaluation of an [`ImplicitPolynomial`]: value, gradient and Hessian at a point (in input or
//! normalized coordinates), values and gradients at many points in blocks of 64 with a Horner
//! scheme in x per (j, k) column, and values on a regular grid by one univariate polynomial per
//! grid line.
//!
//! Input: the polynomial and points in input coordinates (or normalized ones, for the `_normalized`
//! methods). Output: values and derivatives with respect to the same coordinates.

use super::basis::monomial_index;
use super::ImplicitPolynomial;

impl ImplicitPolynomial {
    /// f at the normalized point `q`.
    pub fn eval_normalized(&self, q: [f64; 3]) -> f64 {
        let n = self.degree as usize;
        let (px, py, pz) = (powers(q[0], n), powers(q[1], n), powers(q[2], n));
        let mut sum = 0.0;
        let mut l = 0;
        for r in 0..=n {
            for s in 0..=r {
                let xi = px[r - s];
                for k in 0..=s {
                    sum += self.coefficients[l] * xi * py[s - k] * pz[k];
                    l += 1;
                }
            }
        }
        sum
    }

    /// f at the input-space point `p`.
    pub fn eval(&self, p: [f64; 3]) -> f64 {
        self.eval_normalized(self.normalize(p))
    }

    /// f and its gradient ∂f/∂q at the normalized point `q`.
    pub(crate) fn eval_gradient_normalized(&self, q: [f64; 3]) -> (f64, [f64; 3]) {
        let n = self.degree as usize;
        let (px, py, pz) = (powers(q[0], n), powers(q[1], n), powers(q[2], n));
        let mut f = 0.0;
        let mut g = [0.0; 3];
        let mut l = 0;
        for r in 0..=n {
            for s in 0..=r {
                let i = r - s;
                for k in 0..=s {
                    let j = s - k;
                    let a = self.coefficients[l];
                    l += 1;
                    if a == 0.0 {
                        continue;
                    }
                    f += a * px[i] * py[j] * pz[k];
                    if i > 0 {
                        g[0] += a * i as f64 * px[i - 1] * py[j] * pz[k];
                    }
                    if j > 0 {
                        g[1] += a * j as f64 * px[i] * py[j - 1] * pz[k];
                    }
                    if k > 0 {
                        g[2] += a * k as f64 * px[i] * py[j] * pz[k - 1];
                    }
                }
            }
        }
        (f, g)
    }

    /// f and its gradient ∇f (with respect to input coordinates) at the input-space point `p`.
    pub(crate) fn eval_gradient(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let (f, g) = self.eval_gradient_normalized(self.normalize(p));
        (f, g.map(|c| c / self.scale))
    }
}

/// [1, t, t², …, tⁿ].
fn powers(t: f64, n: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(n + 1);
    let mut v = 1.0;
    for _ in 0..=n {
        out.push(v);
        v *= t;
    }
    out
}

/// Number of points evaluated together by the block evaluators (structure-of-arrays, so the
/// inner loops run over points and vectorize).
const EVAL_BLOCK: usize = 64;

/// The polynomial rearranged for Horner evaluation: for every (j, k) with j + k ≤ n, the
/// coefficients of x⁰ … x^{n−j−k} of the factor multiplying y^j z^k, stored contiguously.
#[derive(Clone, Debug)]
struct HornerLayout {
    degree: usize,
    /// `(j, k, offset)` per column; the column's coefficients are `coeffs[offset ..= offset + n − j − k]`.
    columns: Vec<(usize, usize, usize)>,
    coeffs: Vec<f64>,
}

impl HornerLayout {
    fn new(poly: &ImplicitPolynomial) -> HornerLayout {
        let n = poly.degree as usize;
        let mut columns = Vec::new();
        let mut coeffs = Vec::with_capacity(poly.coefficients.len());
        for k in 0..=n {
            for j in 0..=(n - k) {
                let offset = coeffs.len();
                for i in 0..=(n - j - k) {
                    let l = monomial_index([i as u32, j as u32, k as u32]);
                    coeffs.push(poly.coefficients.get(l).copied().unwrap_or(0.0));
                }
                columns.push((j, k, offset));
            }
        }
        HornerLayout {
            degree: n,
            columns,
            coeffs,
        }
    }
}

/// Fills `table[e * len + b] = t_b^e` for e in 0..=n (powers by repeated multiplication).
fn power_table(t: &[f64], n: usize, table: &mut [f64]) {
    let len = t.len();
    table[..len].fill(1.0);
    for e in 1..=n {
        let (prev, cur) = table[(e - 1) * len..(e + 1) * len].split_at_mut(len);
        for b in 0..len {
            cur[b] = prev[b] * t[b];
        }
    }
}

impl ImplicitPolynomial {
    /// f and the Hessian ∂²f/∂q² at the normalized point `q` (with the gradient).
    pub(crate) fn eval_hessian_normalized(&self, q: [f64; 3]) -> (f64, [f64; 3], [[f64; 3]; 3]) {
        let n = self.degree as usize;
        let (px, py, pz) = (powers(q[0], n), powers(q[1], n), powers(q[2], n));
        // d[e][m] = m-th derivative factor of t^e: e(e−1)… t^{e−m}.
        let deriv = |p: &[f64], e: usize, m: usize| -> f64 {
            if m > e {
                return 0.0;
            }
            let mut factor = 1.0;
            for t in 0..m {
                factor *= (e - t) as f64;
            }
            factor * p[e - m]
        };
        let mut f = 0.0;
        let mut g = [0.0; 3];
        let mut h = [[0.0; 3]; 3];
        // The monomials in coefficient order (degree r, then s = j + k, then k: the exponents
        // [r − s, s − k, k], as [`exponent_of`] numbers them), walked alongside the coefficients.
        let exps = (0..=n).flat_map(|r| (0..=r).flat_map(move |s| (0..=s).map(move |k| (r, s, k))));
        for (&a, (r, s, k)) in self.coefficients.iter().zip(exps) {
            if a == 0.0 {
                continue;
            }
            let (i, j) = (r - s, s - k);
            let dx = [deriv(&px, i, 0), deriv(&px, i, 1), deriv(&px, i, 2)];
            let dy = [deriv(&py, j, 0), deriv(&py, j, 1), deriv(&py, j, 2)];
            let dz = [deriv(&pz, k, 0), deriv(&pz, k, 1), deriv(&pz, k, 2)];
            f += a * dx[0] * dy[0] * dz[0];
            g[0] += a * dx[1] * dy[0] * dz[0];
            g[1] += a * dx[0] * dy[1] * dz[0];
            g[2] += a * dx[0] * dy[0] * dz[1];
            h[0][0] += a * dx[2] * dy[0] * dz[0];
            h[1][1] += a * dx[0] * dy[2] * dz[0];
            h[2][2] += a * dx[0] * dy[0] * dz[2];
            h[0][1] += a * dx[1] * dy[1] * dz[0];
            h[0][2] += a * dx[1] * dy[0] * dz[1];
            h[1][2] += a * dx[0] * dy[1] * dz[1];
        }
        h[1][0] = h[0][1];
        h[2][0] = h[0][2];
        h[2][1] = h[1][2];
        (f, g, h)
    }

    /// f, ∇f and the Hessian ∇²f with respect to input coordinates at the input-space point `p`.
    ///
    /// ```
    /// use stablesurf::ImplicitPolynomial;
    /// // f = x² + y² + z² − 1, unit scale: the Hessian is 2 I.
    /// let mut coefficients = vec![0.0; 10];
    /// coefficients[0] = -1.0;
    /// for l in [4, 7, 9] { coefficients[l] = 1.0; }
    /// let f = ImplicitPolynomial { degree: 2, coefficients, center: [0.0; 3], scale: 1.0 };
    /// let (_, _, h) = f.eval_hessian([0.3, 0.1, 0.2]);
    /// assert_eq!(h, [[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]]);
    /// ```
    #[cfg(test)] // only the unit tests call it
    pub(crate) fn eval_hessian(&self, p: [f64; 3]) -> (f64, [f64; 3], [[f64; 3]; 3]) {
        let (f, g, h) = self.eval_hessian_normalized(self.normalize(p));
        let s2 = self.scale * self.scale;
        (
            f,
            g.map(|c| c / self.scale),
            h.map(|row| row.map(|c| c / s2)),
        )
    }

    /// f at many input-space points, written to `out` (`out.len() == points.len()`).
    ///
    /// Points are processed in blocks of 64 with a Horner scheme in x per (j, k) column, so the
    /// cost is about c multiply-adds per point and the loops vectorize; no `powi`.
    ///
    /// # Panics
    /// If `out.len() != points.len()`.
    ///
    /// ```
    /// use stablesurf::ImplicitPolynomial;
    /// let f = ImplicitPolynomial { degree: 1, coefficients: vec![1.0, 2.0, 3.0, 4.0], center: [0.0; 3], scale: 1.0 };
    /// let mut out = vec![0.0; 2];
    /// f.eval_many(&[[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]], &mut out);
    /// assert_eq!(out, vec![3.0, 8.0]);
    /// ```
    pub fn eval_many(&self, points: &[[f64; 3]], out: &mut [f64]) {
        assert_eq!(
            points.len(),
            out.len(),
            "eval_many: output length differs from input"
        );
        self.eval_many_impl(points, out, None);
    }

    /// f and ∇f (input coordinates) at many input-space points.
    ///
    /// # Panics
    /// If `values.len()` or `gradients.len()` differs from `points.len()`.
    pub fn eval_gradient_many(
        &self,
        points: &[[f64; 3]],
        values: &mut [f64],
        gradients: &mut [[f64; 3]],
    ) {
        assert_eq!(
            points.len(),
            values.len(),
            "eval_gradient_many: output length differs from input"
        );
        assert_eq!(
            points.len(),
            gradients.len(),
            "eval_gradient_many: output length differs from input"
        );
        self.eval_many_impl(points, values, Some(gradients));
    }

    fn eval_many_impl(
        &self,
        points: &[[f64; 3]],
        values: &mut [f64],
        mut gradients: Option<&mut [[f64; 3]]>,
    ) {
        let layout = HornerLayout::new(self);
        let n = layout.degree;
        let inv_scale = 1.0 / self.scale;
        let mut xs = [0.0; EVAL_BLOCK];
        let mut ys = [0.0; EVAL_BLOCK];
        let mut zs = [0.0; EVAL_BLOCK];
        let mut py = vec![0.0; (n + 1) * EVAL_BLOCK];
        let mut pz = vec![0.0; (n + 1) * EVAL_BLOCK];
        let mut t = [0.0; EVAL_BLOCK];
        let mut dt = [0.0; EVAL_BLOCK];
        let mut f = [0.0; EVAL_BLOCK];
        let mut gx = [0.0; EVAL_BLOCK];
        let mut gy = [0.0; EVAL_BLOCK];
        let mut gz = [0.0; EVAL_BLOCK];
        let want_gradient = gradients.is_some();
        for (block_idx, block) in points.chunks(EVAL_BLOCK).enumerate() {
            let len = block.len();
            for (b, p) in block.iter().enumerate() {
                xs[b] = (p[0] - self.center[0]) * inv_scale;
                ys[b] = (p[1] - self.center[1]) * inv_scale;
                zs[b] = (p[2] - self.center[2]) * inv_scale;
            }
            power_table(&ys[..len], n, &mut py[..(n + 1) * len]);
            power_table(&zs[..len], n, &mut pz[..(n + 1) * len]);
            f[..len].fill(0.0);
            gx[..len].fill(0.0);
            gy[..len].fill(0.0);
            gz[..len].fill(0.0);
            for &(j, k, offset) in &layout.columns {
                let m = n - j - k;
                let c = &layout.coeffs[offset..=offset + m];
                // Horner in x: t = Σ_i c_i x^i, dt = dt/dx.
                t[..len].fill(c[m]);
                dt[..len].fill(0.0);
                for i in (0..m).rev() {
                    for b in 0..len {
                        dt[b] = dt[b] * xs[b] + t[b];
                        t[b] = t[b] * xs[b] + c[i];
                    }
                }
                let yj = &py[j * len..(j + 1) * len];
                let zk = &pz[k * len..(k + 1) * len];
                for b in 0..len {
                    f[b] += t[b] * yj[b] * zk[b];
                }
                if want_gradient {
                    for b in 0..len {
                        gx[b] += dt[b] * yj[b] * zk[b];
                    }
                    if j > 0 {
                        let yj1 = &py[(j - 1) * len..j * len];
                        let jf = j as f64;
                        for b in 0..len {
                            gy[b] += jf * t[b] * yj1[b] * zk[b];
                        }
                    }
                    if k > 0 {
                        let zk1 = &pz[(k - 1) * len..k * len];
                        let kf = k as f64;
                        for b in 0..len {
                            gz[b] += kf * t[b] * yj[b] * zk1[b];
                        }
                    }
                }
            }
            let start = block_idx * EVAL_BLOCK;
            values[start..start + len].copy_from_slice(&f[..len]);
            if let Some(grad) = gradients.as_deref_mut() {
                for b in 0..len {
                    grad[start + b] = [gx[b] * inv_scale, gy[b] * inv_scale, gz[b] * inv_scale];
                }
            }
        }
    }

    /// f on the regular grid `origin + (ix·step[0], iy·step[1], iz·step[2])` (input coordinates),
    /// `ix < dims[0]` fastest, then `iy`, then `iz`: `out[ix + dims[0]·(iy + dims[1]·iz)]`.
    ///
    /// Each grid line in x is a univariate polynomial whose n + 1 coefficients are computed once
    /// per line, so the cost is about n + 1 multiply-adds per grid point.
    pub(crate) fn eval_grid(&self, origin: [f64; 3], step: [f64; 3], dims: [usize; 3]) -> Vec<f64> {
        let layout = HornerLayout::new(self);
        let n = layout.degree;
        let total = dims[0] * dims[1] * dims[2];
        let mut out = vec![0.0; total];
        let q = |a: usize, i: usize| (origin[a] + i as f64 * step[a] - self.center[a]) / self.scale;
        let xs: Vec<f64> = (0..dims[0]).map(|i| q(0, i)).collect();
        let mut line = vec![0.0; n + 1];
        for iz in 0..dims[2] {
            let pz = powers(q(2, iz), n);
            for iy in 0..dims[1] {
                let py = powers(q(1, iy), n);
                line.fill(0.0);
                for &(j, k, offset) in &layout.columns {
                    let w = py[j] * pz[k];
                    for (i, c) in layout.coeffs[offset..=offset + n - j - k]
                        .iter()
                        .enumerate()
                    {
                        line[i] += c * w;
                    }
                }
                let row =
                    &mut out[dims[0] * (iy + dims[1] * iz)..dims[0] * (iy + 1 + dims[1] * iz)];
                for (v, &x) in row.iter_mut().zip(&xs) {
                    let mut acc = line[n];
                    for i in (0..n).rev() {
                        acc = acc * x + line[i];
                    }
                    *v = acc;
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poly::test_support::test_poly;

    #[test]
    fn sphere_value_and_gradient() {
        // f = x² + y² + z² − 1 in coordinates centred at (1, 2, 3) and scaled by 2.
        let mut coefficients = vec![0.0; 10];
        coefficients[0] = -1.0;
        coefficients[4] = 1.0;
        coefficients[7] = 1.0;
        coefficients[9] = 1.0;
        let f = ImplicitPolynomial {
            degree: 2,
            coefficients,
            center: [1.0, 2.0, 3.0],
            scale: 2.0,
        };
        let p = [1.0 + 2.0 * 0.6, 2.0, 3.0 + 2.0 * 0.8];
        let (v, g) = f.eval_gradient(p);
        assert!(v.abs() < 1e-14);
        assert!((f.eval(p) - v).abs() < 1e-15);
        // ∇f = 2 q / scale with q = (0.6, 0, 0.8).
        assert!((g[0] - 0.6).abs() < 1e-14 && g[1].abs() < 1e-14 && (g[2] - 0.8).abs() < 1e-14);
    }

    fn test_points() -> Vec<[f64; 3]> {
        (0..200)
            .map(|i| {
                let t = i as f64;
                [
                    0.3 + 1.5 * (0.37 * t).sin(),
                    -1.0 + 1.2 * (0.21 * t).cos(),
                    2.0 + (0.13 * t).sin() * 1.9,
                ]
            })
            .collect()
    }

    #[test]
    fn fast_evaluators_match_pointwise() {
        for n in [1, 2, 5, 8, 14] {
            let f = test_poly(n, n as u64);
            let pts = test_points();
            let mut v = vec![0.0; pts.len()];
            let mut g = vec![[0.0; 3]; pts.len()];
            f.eval_gradient_many(&pts, &mut v, &mut g);
            let mut v2 = vec![0.0; pts.len()];
            f.eval_many(&pts, &mut v2);
            for (i, p) in pts.iter().enumerate() {
                let (fv, fg) = f.eval_gradient(*p);
                let scale = 1.0 + fv.abs();
                assert!((v[i] - fv).abs() <= 1e-11 * scale, "degree {n}");
                assert!((v2[i] - fv).abs() <= 1e-11 * scale, "degree {n}");
                for a in 0..3 {
                    assert!(
                        (g[i][a] - fg[a]).abs() <= 1e-10 * (1.0 + fg[a].abs()),
                        "degree {n}"
                    );
                }
            }
        }
    }

    #[test]
    fn grid_matches_pointwise() {
        let f = test_poly(6, 3);
        let (origin, step, dims) = ([-0.5, -2.0, 1.0], [0.3, 0.25, 0.2], [5, 4, 3]);
        let v = f.eval_grid(origin, step, dims);
        for iz in 0..3 {
            for iy in 0..4 {
                for ix in 0..5 {
                    let p = [
                        origin[0] + ix as f64 * 0.3,
                        origin[1] + iy as f64 * 0.25,
                        origin[2] + iz as f64 * 0.2,
                    ];
                    let expected = f.eval(p);
                    assert!(
                        (v[ix + 5 * (iy + 4 * iz)] - expected).abs()
                            <= 1e-11 * (1.0 + expected.abs())
                    );
                }
            }
        }
    }

    #[test]
    fn hessian_matches_finite_differences() {
        let f = test_poly(5, 9);
        let p = [0.7, -0.4, 1.9];
        let (_, _, h) = f.eval_hessian(p);
        let step = 1e-5;
        for a in 0..3 {
            let mut lo = p;
            let mut hi = p;
            lo[a] -= step;
            hi[a] += step;
            let (_, g_lo) = f.eval_gradient(lo);
            let (_, g_hi) = f.eval_gradient(hi);
            for b in 0..3 {
                let fd = (g_hi[b] - g_lo[b]) / (2.0 * step);
                assert!(
                    (h[a][b] - fd).abs() <= 1e-6 * (1.0 + fd.abs()),
                    "H[{a}][{b}] = {} vs {fd}",
                    h[a][b]
                );
            }
        }
    }
}

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn implicit_polynomial_eval_grid() {
        use crate::ImplicitPolynomial;
        let f = ImplicitPolynomial {
            degree: 1,
            coefficients: vec![0.0, 1.0, 10.0, 100.0],
            center: [0.0; 3],
            scale: 1.0,
        };
        let v = f.eval_grid([0.0; 3], [1.0; 3], [2, 2, 2]);
        assert_eq!(v, vec![0.0, 1.0, 10.0, 11.0, 100.0, 101.0, 110.0, 111.0]);
    }
}
