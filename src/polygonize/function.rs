//! The function interface of the `polygonize` stage: what the octree needs from a model, and its
//! implementation for [`ImplicitPolynomial`].
//!
//! Input: a model f (here the global polynomial; later a piecewise partition-of-unity model).
//! Output: point values, gradients, and *guaranteed enclosures* of f and ∇f over an axis-aligned
//! box, which the octree uses to discard cells where f cannot vanish.
//!
//! Invariants: [`ImplicitFunction::bounds_on_box`] returns an interval that contains the value that
//! [`ImplicitFunction::value`] computes at every point of the closed box (rounding included), so a
//! cell that the bound excludes never shows a sign change to the extraction.
//!
//! # Bounds for polynomials: the Taylor (centred) form
//!
//! For a box with centre c and half-widths h (in the polynomial's normalized coordinates q), the
//! polynomial is re-expanded around c in local coordinates t ∈ [−1, 1]³, q = c + h ⊙ t:
//!
//! ```text
//! f(c + h ⊙ t) = Σ_α b_α t^α,    b_α = (∂^α f(c) / α!) · h^α
//! ```
//!
//! by three one-dimensional Taylor shifts (synthetic division, O(n²) per line of coefficients).
//! Over the cube, a monomial t^α with all exponents even ranges over [0, 1], any other over
//! [−1, 1], so f ∈ b₀ + Σ_{α≠0} b_α·range(t^α). This is the centred form of interval analysis
//! (Moore, Kearfott & Cloud, *Introduction to Interval Analysis*, 2009, §6.4): its overestimation
//! shrinks like h² instead of h, which is what makes the octree adaptive — only cells within about
//! one cell of the zero set survive, so the number of cells grows 4× per level, not 8×. The
//! derivatives' enclosures come from the same coefficients. A rounding margin of
//! 8(n + 3)·ε_mach·Σ|a_α|·(|c| + h)^α (the magnitude of every term the evaluation can add) widens
//! each interval, so the enclosure also holds for the floating-point values.

use crate::cloud::Aabb;
use crate::poly::ImplicitPolynomial;

/// Highest degree evaluated on stack buffers; higher degrees fall back to allocating paths.
const STACK_DEGREE: usize = 24;

/// What the `polygonize` stage needs from an implicit model f (f < 0 inside, f > 0 outside), in
/// input coordinates.
///
/// Implement this for another model (for example a partition-of-unity blend of local fits) to
/// mesh it with [`crate::polygonize::polygonize`].
///
/// ```
/// use stablesurf::polygonize::ImplicitFunction;
/// use stablesurf::{Aabb, ImplicitPolynomial};
/// // f = x² + y² + z² − 1.
/// let mut coefficients = vec![0.0; 10];
/// coefficients[0] = -1.0;
/// for l in [4, 7, 9] {
///     coefficients[l] = 1.0;
/// }
/// let sphere = ImplicitPolynomial { degree: 2, coefficients, center: [0.0; 3], scale: 1.0 };
/// assert_eq!(sphere.value([1.0, 0.0, 0.0]), 0.0);
/// let (lo, hi) = sphere.bounds_on_box(&Aabb { min: [2.0, 0.0, 0.0], max: [3.0, 1.0, 1.0] });
/// assert!(lo > 0.0 && lo <= 3.0 && hi >= 18.0);
/// ```
pub trait ImplicitFunction: Sync {
    /// f at the input-space point `p`.
    fn value(&self, p: [f64; 3]) -> f64;

    /// f and its gradient ∇f with respect to input coordinates at `p`.
    fn value_gradient(&self, p: [f64; 3]) -> (f64, [f64; 3]);

    /// A guaranteed enclosure `(lo, hi)` of the values [`ImplicitFunction::value`] takes on the
    /// closed box `b`: `lo <= value(p) <= hi` for every p in `b`.
    fn bounds_on_box(&self, b: &Aabb) -> (f64, f64);

    /// Guaranteed enclosures of the three components of ∇f (input coordinates) on the closed box
    /// `b`. Return `(−∞, ∞)` for a component that cannot be bounded; the topology guard then
    /// refines that cell to its cap.
    fn gradient_bounds_on_box(&self, b: &Aabb) -> [(f64, f64); 3];

    /// Both enclosures at once: `(bounds_on_box(b), gradient_bounds_on_box(b))`. Override it when
    /// the two share work (the polynomial computes one local expansion for both).
    fn bounds_with_gradient_on_box(&self, b: &Aabb) -> ((f64, f64), [(f64, f64); 3]) {
        (self.bounds_on_box(b), self.gradient_bounds_on_box(b))
    }

    /// Why the model cannot be meshed (a malformed model), or `Ok(())`.
    ///
    /// # Errors
    /// A message naming what is wrong with the model.
    fn validate(&self) -> Result<(), String> {
        Ok(())
    }
}

impl ImplicitFunction for ImplicitPolynomial {
    fn value(&self, p: [f64; 3]) -> f64 {
        let n = self.degree as usize;
        if n > STACK_DEGREE {
            return self.eval(p);
        }
        let q = self.normalize(p);
        let mut px = [0.0; STACK_DEGREE + 1];
        let mut py = [0.0; STACK_DEGREE + 1];
        let mut pz = [0.0; STACK_DEGREE + 1];
        fill_powers(&mut px[..=n], q[0]);
        fill_powers(&mut py[..=n], q[1]);
        fill_powers(&mut pz[..=n], q[2]);
        let mut coefficients = self.coefficients.iter();
        let mut sum = 0.0;
        for r in 0..=n {
            for s in 0..=r {
                // Σ_k a_(r−s, s−k, k) y^(s−k) z^k, then times x^(r−s).
                let mut inner = 0.0;
                for k in 0..=s {
                    let Some(&a) = coefficients.next() else {
                        return sum + px[r - s] * inner;
                    };
                    inner += a * py[s - k] * pz[k];
                }
                sum += px[r - s] * inner;
            }
        }
        sum
    }

    fn value_gradient(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let n = self.degree as usize;
        if n > STACK_DEGREE {
            return self.eval_gradient(p);
        }
        let q = self.normalize(p);
        let mut px = [0.0; STACK_DEGREE + 2];
        let mut py = [0.0; STACK_DEGREE + 2];
        let mut pz = [0.0; STACK_DEGREE + 2];
        // Index 0 holds 0 (the "x^(−1)" of a derivative), index e + 1 holds x^e.
        fill_powers(&mut px[1..=n + 1], q[0]);
        fill_powers(&mut py[1..=n + 1], q[1]);
        fill_powers(&mut pz[1..=n + 1], q[2]);
        let mut coefficients = self.coefficients.iter();
        let mut f = 0.0;
        let mut g = [0.0; 3];
        'outer: for r in 0..=n {
            for s in 0..=r {
                let i = r - s;
                let (mut v, mut vy, mut vz) = (0.0, 0.0, 0.0);
                for k in 0..=s {
                    let Some(&a) = coefficients.next() else {
                        break 'outer;
                    };
                    let j = s - k;
                    v += a * py[j + 1] * pz[k + 1];
                    vy += a * j as f64 * py[j] * pz[k + 1];
                    vz += a * k as f64 * py[j + 1] * pz[k];
                }
                f += px[i + 1] * v;
                g[0] += i as f64 * px[i] * v;
                g[1] += px[i + 1] * vy;
                g[2] += px[i + 1] * vz;
            }
        }
        (f, g.map(|c| c / self.scale))
    }

    fn bounds_on_box(&self, b: &Aabb) -> (f64, f64) {
        match self.taylor(b) {
            Some(t) => t.value_bounds(),
            None => (f64::NEG_INFINITY, f64::INFINITY),
        }
    }

    fn gradient_bounds_on_box(&self, b: &Aabb) -> [(f64, f64); 3] {
        self.bounds_with_gradient_on_box(b).1
    }

    fn bounds_with_gradient_on_box(&self, b: &Aabb) -> ((f64, f64), [(f64, f64); 3]) {
        let mut gradient = [(f64::NEG_INFINITY, f64::INFINITY); 3];
        let Some(t) = self.taylor(b) else {
            return ((f64::NEG_INFINITY, f64::INFINITY), gradient);
        };
        for (axis, slot) in gradient.iter_mut().enumerate() {
            let per_t = self.scale * t.half_width[axis];
            if per_t > 0.0 && per_t.is_finite() {
                let (lo, hi) = t.derivative_bounds(axis);
                *slot = (lo / per_t, hi / per_t);
            }
        }
        (t.value_bounds(), gradient)
    }

    fn validate(&self) -> Result<(), String> {
        let expected = crate::poly::n_coefficients(self.degree);
        if self.coefficients.len() != expected {
            return Err(format!(
                "degree {} needs {expected} coefficients, the model has {}",
                self.degree,
                self.coefficients.len()
            ));
        }
        if self.coefficients.iter().any(|a| !a.is_finite()) {
            return Err("the model has a non-finite coefficient".into());
        }
        if !(self.scale > 0.0 && self.scale.is_finite()) || self.center.iter().any(|c| !c.is_finite())
        {
            return Err(format!(
                "the normalization needs a finite centre and a scale > 0, got centre {:?} and scale {}",
                self.center, self.scale
            ));
        }
        Ok(())
    }
}

/// `out[e] = t^e`.
fn fill_powers(out: &mut [f64], t: f64) {
    let mut v = 1.0;
    for slot in out.iter_mut() {
        *slot = v;
        v *= t;
    }
}

/// A polynomial re-expanded around a box centre in local coordinates t ∈ [−1, 1]³.
struct LocalTaylor {
    degree: usize,
    /// Dense coefficients b_(i,j,k) at `(i·(n+1) + j)·(n+1) + k`, zero where i + j + k > n.
    coefficients: Vec<f64>,
    /// Half-widths of the box in normalized coordinates.
    half_width: [f64; 3],
    /// Rounding margin for the value.
    value_margin: f64,
    /// Rounding margins for ∂f/∂t_axis.
    derivative_margin: [f64; 3],
}

impl ImplicitPolynomial {
    /// The local Taylor expansion of f over the box `b`, or `None` for a malformed model or box.
    fn taylor(&self, b: &Aabb) -> Option<LocalTaylor> {
        let n = self.degree as usize;
        if self.coefficients.len() != crate::poly::n_coefficients(self.degree) {
            return None;
        }
        let center = self.normalize(b.center());
        let half_width = [0, 1, 2].map(|a| 0.5 * (b.max[a] - b.min[a]) / self.scale);
        if center.iter().chain(&half_width).any(|v| !v.is_finite()) {
            return None;
        }
        let m = n + 1;
        let mut dense = vec![0.0; m * m * m];
        // Magnitude Σ|a_α|(|c| + h)^α of the terms, and of the terms of each derivative, for the
        // rounding margin.
        let reach: Vec<Vec<f64>> = (0..3)
            .map(|a| {
                let mut p = vec![0.0; m];
                fill_powers(&mut p, center[a].abs() + half_width[a]);
                p
            })
            .collect();
        let mut magnitude = 0.0;
        let mut derivative_magnitude = [0.0; 3];
        let mut l = 0;
        for r in 0..=n {
            for s in 0..=r {
                for k in 0..=s {
                    let (i, j) = (r - s, s - k);
                    let a = self.coefficients[l];
                    l += 1;
                    dense[(i * m + j) * m + k] = a;
                    let e = [i, j, k];
                    let term = a.abs() * reach[0][i] * reach[1][j] * reach[2][k];
                    magnitude += term;
                    for axis in 0..3 {
                        if e[axis] > 0 {
                            let mut ed = e;
                            ed[axis] -= 1;
                            derivative_magnitude[axis] += a.abs()
                                * e[axis] as f64
                                * reach[0][ed[0]]
                                * reach[1][ed[1]]
                                * reach[2][ed[2]];
                        }
                    }
                }
            }
        }
        // Shift and scale along each axis: for every line of coefficients along `axis` (the
        // other two exponents fixed), p(x) ↦ p(c + h·x).
        let strides = [m * m, m, 1];
        for axis in 0..3 {
            let (c, h) = (center[axis], half_width[axis]);
            let (o1, o2) = match axis {
                0 => (1, 2),
                1 => (0, 2),
                _ => (0, 1),
            };
            for e1 in 0..=n {
                for e2 in 0..=n - e1 {
                    let top = n - e1 - e2;
                    let base = e1 * strides[o1] + e2 * strides[o2];
                    let st = strides[axis];
                    if c != 0.0 {
                        for i in 0..top {
                            for q in (i..top).rev() {
                                dense[base + q * st] += c * dense[base + (q + 1) * st];
                            }
                        }
                    }
                    let mut hp = 1.0;
                    for q in 0..=top {
                        dense[base + q * st] *= hp;
                        hp *= h;
                    }
                }
            }
        }
        let gamma = 8.0 * (n as f64 + 3.0) * f64::EPSILON;
        Some(LocalTaylor {
            degree: n,
            coefficients: dense,
            half_width,
            value_margin: gamma * magnitude,
            derivative_margin: [0, 1, 2].map(|a| gamma * derivative_magnitude[a] * half_width[a]),
        })
    }
}

impl LocalTaylor {
    /// Enclosure of f over the box.
    fn value_bounds(&self) -> (f64, f64) {
        let (n, m) = (self.degree, self.degree + 1);
        let mut lo = 0.0;
        let mut hi = 0.0;
        for i in 0..=n {
            for j in 0..=n - i {
                for k in 0..=n - i - j {
                    let b = self.coefficients[(i * m + j) * m + k];
                    accumulate(&mut lo, &mut hi, b, [i, j, k]);
                }
            }
        }
        (lo - self.value_margin, hi + self.value_margin)
    }

    /// Enclosure of ∂f/∂t_axis over the box (local coordinates).
    fn derivative_bounds(&self, axis: usize) -> (f64, f64) {
        let (n, m) = (self.degree, self.degree + 1);
        let mut lo = 0.0;
        let mut hi = 0.0;
        for i in 0..=n {
            for j in 0..=n - i {
                for k in 0..=n - i - j {
                    let mut e = [i, j, k];
                    if e[axis] == 0 {
                        continue;
                    }
                    let b = self.coefficients[(i * m + j) * m + k] * e[axis] as f64;
                    e[axis] -= 1;
                    accumulate(&mut lo, &mut hi, b, e);
                }
            }
        }
        (
            lo - self.derivative_margin[axis],
            hi + self.derivative_margin[axis],
        )
    }
}

/// Adds the range of b·t^e over t ∈ [−1, 1]³ to the interval [lo, hi].
fn accumulate(lo: &mut f64, hi: &mut f64, b: f64, e: [usize; 3]) {
    if e == [0, 0, 0] {
        *lo += b;
        *hi += b;
    } else if e.iter().all(|x| x % 2 == 0) {
        // t^e ∈ [0, 1].
        if b > 0.0 {
            *hi += b;
        } else {
            *lo += b;
        }
    } else {
        *lo -= b.abs();
        *hi += b.abs();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poly::n_coefficients;

    /// A pseudo-random degree-`n` polynomial with a non-trivial normalization.
    fn random_poly(n: u32, seed: u64) -> ImplicitPolynomial {
        let mut state = seed;
        let coefficients = (0..n_coefficients(n))
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
            })
            .collect();
        ImplicitPolynomial { degree: n, coefficients, center: [0.3, -0.2, 0.5], scale: 1.7 }
    }

    #[test]
    fn fast_evaluation_matches_reference() {
        for n in [0, 1, 2, 5, 8] {
            let f = random_poly(n, 7 + n as u64);
            for p in [[0.1, 0.2, 0.3], [-1.5, 0.7, 2.0], [3.0, -2.0, 0.0]] {
                let reference = f.eval(p);
                let (rv, rg) = f.eval_gradient(p);
                let (v, g) = f.value_gradient(p);
                let tol = 1e-12 * (1.0 + reference.abs());
                assert!((f.value(p) - reference).abs() < tol, "degree {n}");
                assert!((v - rv).abs() < tol, "degree {n}");
                for a in 0..3 {
                    assert!((g[a] - rg[a]).abs() < 1e-11 * (1.0 + rg[a].abs()), "degree {n}");
                }
            }
        }
    }

    #[test]
    fn bounds_enclose_samples_and_tighten_quadratically() {
        let f = random_poly(6, 3);
        let mut previous_excess = f64::INFINITY;
        for level in 0..6 {
            let h = 0.8 / f64::from(1u32 << level);
            let b = Aabb { min: [0.1, -0.3, 0.2], max: [0.1 + h, -0.3 + h, 0.2 + h] };
            let (lo, hi) = f.bounds_on_box(&b);
            let grads = f.gradient_bounds_on_box(&b);
            let (mut smin, mut smax) = (f64::INFINITY, f64::NEG_INFINITY);
            for ix in 0..=6 {
                for iy in 0..=6 {
                    for iz in 0..=6 {
                        let p = [ix, iy, iz].map(|i| i as f64 / 6.0);
                        let p = [0, 1, 2].map(|a| b.min[a] + p[a] * (b.max[a] - b.min[a]));
                        let (v, g) = f.value_gradient(p);
                        assert!(lo <= v && v <= hi, "value {v} outside [{lo}, {hi}]");
                        for a in 0..3 {
                            assert!(grads[a].0 <= g[a] && g[a] <= grads[a].1);
                        }
                        smin = smin.min(v);
                        smax = smax.max(v);
                    }
                }
            }
            // The centred form's overestimation shrinks about 4× per halving (quadratic).
            let excess = (hi - lo) - (smax - smin);
            if level >= 3 {
                assert!(excess < 0.4 * previous_excess, "level {level}: {excess} vs {previous_excess}");
            }
            previous_excess = excess;
        }
    }
}
