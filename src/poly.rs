//! The `ImplicitPolynomial` artifact: f(p) = Σ_l a_l m_l((p − center)/scale), and the model
//! (`ImplicitModel`) that the `fit` stage produces and `polygonize`/`export` consume.
//!
//! Monomial order (Sahin & Unel 2008, 2.1 and 6.16): degree by degree; inside degree r, for
//! s = j + k from 0 to r, for k from 0 to s, the monomial x^i y^j z^k with j = s − k and
//! i = r − s. The 1-based index is l = k + s(s+1)/2 + r(r+1)(r+2)/6 + 1. Degree 2 gives
//! 1, x, y, z, x², xy, xz, y², yz, z².
//!
//! Invariants: `coefficients.len() == n_coefficients(degree)`; `scale > 0`.

use serde::{Deserialize, Serialize};

use crate::cloud::Aabb;

/// Number of monomials of degree ≤ `degree` in three variables: (n+1)(n+2)(n+3)/6.
///
/// ```
/// assert_eq!(stablesurf::poly::n_coefficients(2), 10);
/// assert_eq!(stablesurf::poly::n_coefficients(8), 165);
/// ```
pub fn n_coefficients(degree: u32) -> usize {
    let n = degree as usize;
    (n + 1) * (n + 2) * (n + 3) / 6
}

/// Exponents `[i, j, k]` of every monomial of degree ≤ `degree`, in the paper's order.
///
/// ```
/// let e = stablesurf::poly::exponents(2);
/// assert_eq!(e[4], [2, 0, 0]); // x²
/// assert_eq!(e[8], [0, 1, 1]); // yz
/// ```
pub fn exponents(degree: u32) -> Vec<[u32; 3]> {
    let mut out = Vec::with_capacity(n_coefficients(degree));
    for r in 0..=degree {
        for s in 0..=r {
            for k in 0..=s {
                out.push([r - s, s - k, k]);
            }
        }
    }
    out
}

/// 0-based position of the monomial x^i y^j z^k in the paper's order.
///
/// ```
/// assert_eq!(stablesurf::poly::monomial_index([0, 1, 1]), 8);
/// ```
pub fn monomial_index(e: [u32; 3]) -> usize {
    let (j, k) = (e[1] as usize, e[2] as usize);
    let s = j + k;
    let r = e[0] as usize + s;
    k + s * (s + 1) / 2 + r * (r + 1) * (r + 2) / 6
}

/// An implicit polynomial surface f(p) = 0 in input coordinates.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImplicitPolynomial {
    /// Total degree n.
    pub degree: u32,
    /// The c = (n+1)(n+2)(n+3)/6 coefficients in the paper's monomial order, for the polynomial
    /// in normalized coordinates p̂ = (p − center)/scale.
    pub coefficients: Vec<f64>,
    /// Normalization centre μ (input coordinates).
    pub center: [f64; 3],
    /// Normalization scale s > 0 (input units per normalized unit).
    pub scale: f64,
}

impl ImplicitPolynomial {
    /// Version of this artifact's layout; bump it whenever a field changes.
    pub const FORMAT_VERSION: u32 = 1;

    /// Maps an input-space point to normalized coordinates p̂ = (p − center)/scale.
    pub fn normalize(&self, p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| (p[a] - self.center[a]) / self.scale)
    }

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
    pub fn eval_gradient_normalized(&self, q: [f64; 3]) -> (f64, [f64; 3]) {
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
    pub fn eval_gradient(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
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

/// How a model was fitted: the settings that produced it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FitRecord {
    /// `"3lrr"`, `"3l"` or `"ls"`.
    pub method: String,
    /// Layer offset ε in normalized units.
    pub epsilon: f64,
    /// The ridge weight κ used.
    pub kappa: f64,
    /// `"paper"`, `"stable"` or `"fixed"`: how κ was chosen.
    pub kappa_rule: String,
    /// Number of data points fitted.
    pub n_points: usize,
}

/// What the fit measured about its result.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FitDiagnostics {
    /// 2-norm condition number of the regularized system matrix MᵀM + κD.
    pub condition_number: f64,
    /// Minimum of the leading form on the unit sphere divided by its maximum absolute value.
    pub leading_form_min_relative: f64,
    /// Whether the zero set is certified closed and bounded (even degree, leading form positive).
    pub bounded: bool,
    /// Certified containment radius R in normalized units (the zero set lies in |p̂| < R),
    /// when the leading form is positive.
    pub containment_radius: Option<f64>,
    /// Mean first-order distance |f|/|∇f| from the data points to the zero set, input units.
    pub mean_distance: f64,
    /// Maximum first-order distance |f|/|∇f| from the data points to the zero set, input units.
    pub max_distance: f64,
    /// `mean_distance` divided by the data's bounding-box diagonal.
    pub mean_distance_relative: f64,
    /// `max_distance` divided by the data's bounding-box diagonal.
    pub max_distance_relative: f64,
    /// Messages about the fit a user should read (for example: no κ on the grid qualified).
    pub warnings: Vec<String>,
}

/// A fitted (or hand-written) implicit polynomial model: what `model.json` holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImplicitModel {
    /// The polynomial.
    pub polynomial: ImplicitPolynomial,
    /// The meshing region in input coordinates (the data's box grown by 10% per side), if known.
    pub bounds: Option<Aabb>,
    /// How it was fitted, if it was.
    pub fit: Option<FitRecord>,
    /// What the fit measured, if it was fitted.
    pub diagnostics: Option<FitDiagnostics>,
}

impl ImplicitModel {
    /// Version of this artifact's layout; bump it whenever a field changes.
    pub const FORMAT_VERSION: u32 = 1;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_matches_paper_formula() {
        for n in 0..=14 {
            let e = exponents(n);
            assert_eq!(e.len(), n_coefficients(n));
            for (l, &ex) in e.iter().enumerate() {
                assert_eq!(monomial_index(ex), l, "degree {n}, exponent {ex:?}");
            }
        }
    }

    #[test]
    fn sphere_value_and_gradient() {
        // f = x² + y² + z² − 1 in coordinates centred at (1, 2, 3) and scaled by 2.
        let mut coefficients = vec![0.0; 10];
        coefficients[0] = -1.0;
        coefficients[4] = 1.0;
        coefficients[7] = 1.0;
        coefficients[9] = 1.0;
        let f = ImplicitPolynomial { degree: 2, coefficients, center: [1.0, 2.0, 3.0], scale: 2.0 };
        let p = [1.0 + 2.0 * 0.6, 2.0, 3.0 + 2.0 * 0.8];
        let (v, g) = f.eval_gradient(p);
        assert!(v.abs() < 1e-14);
        assert!((f.eval(p) - v).abs() < 1e-15);
        // ∇f = 2 q / scale with q = (0.6, 0, 0.8).
        assert!((g[0] - 0.6).abs() < 1e-14 && g[1].abs() < 1e-14 && (g[2] - 0.8).abs() < 1e-14);
    }
}
