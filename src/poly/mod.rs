//! The `ImplicitPolynomial` artifact: f(p) = Σ_l a_l m_l((p − center)/scale), and the model
//! (`ImplicitModel`) that the `fit` stage produces and `polygonize`/`export` consume.
//!
//! Monomial order (Sahin & Unel 2008, 2.1 and 6.16): degree by degree; inside degree r, for
//! s = j + k from 0 to r, for k from 0 to s, the monomial x^i y^j z^k with j = s − k and
//! i = r − s. The 1-based index is l = k + s(s+1)/2 + r(r+1)(r+2)/6 + 1. Degree 2 gives
//! 1, x, y, z, x², xy, xz, y², yz, z².
//!
//! Evaluation: pointwise value, gradient and Hessian; [`ImplicitPolynomial::eval_many`] and
//! [`ImplicitPolynomial::eval_gradient_many`] run over blocks of 64 points with a Horner scheme
//! in x per (j, k) column (about c multiply-adds per point, vectorized over points, no `powi`);
//! `ImplicitPolynomial::eval_grid` reduces each grid line to a univariate polynomial (about
//! n + 1 multiply-adds per grid point).
//!
//! Boundedness (paper 6.2/6.3): f = Σ_k H_k with H_k homogeneous of degree k. For even n the zero
//! set is closed and bounded when the leading form H_n is positive on the unit sphere;
//! `ImplicitPolynomial::leading_form_extrema` finds its minimum (dense sampling plus Riemannian
//! Newton refinement), `ImplicitPolynomial::homogeneous_bound` bounds ‖H_k‖ from above, and
//! `ImplicitPolynomial::containment_radius` combines them into a radius outside which f > 0.
//!
//! Invariants: `coefficients.len() == n_coefficients(degree)`; `scale > 0`.
//!
//! The parts: `basis` (the monomial order), `eval` (pointwise, block and grid evaluation),
//! `forms` (homogeneous parts, the leading form's extrema on the sphere, the containment
//! radius); this module holds the artifacts themselves.

use serde::{Deserialize, Serialize};

use crate::cloud::Aabb;

mod basis;
mod eval;
mod forms;

pub(crate) use basis::exponents;
pub use basis::{monomial_index, n_coefficients};

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
    /// Maps an input-space point to normalized coordinates p̂ = (p − center)/scale.
    pub(crate) fn normalize(&self, p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| (p[a] - self.center[a]) / self.scale)
    }
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
    /// Mean first-order distance |f|/|∇f| from the data points to the zero set, input units
    /// (over every k-th point past `crate::fit::DISTANCE_POINTS` points).
    pub mean_distance: f64,
    /// Maximum first-order distance |f|/|∇f| from the data points to the zero set, input units
    /// (over the same points as `mean_distance`).
    pub max_distance: f64,
    /// `mean_distance` divided by the data's bounding-box diagonal.
    pub mean_distance_relative: f64,
    /// `max_distance` divided by the data's bounding-box diagonal.
    pub max_distance_relative: f64,
    /// Messages about the fit a user should read (for example: no κ on the grid qualified).
    pub warnings: Vec<String>,
    /// The ridge weight κ used.
    #[serde(default)]
    pub kappa: f64,
    /// Layer offset ε in normalized units (0 for plain least squares).
    #[serde(default)]
    pub epsilon: f64,
    /// Condition number of the symmetrically scaled system S(MᵀM + κD)S, S = diag(1/√A_ll):
    /// what governs the accuracy of the Cholesky solve.
    #[serde(default)]
    pub condition_number_scaled: f64,
    /// Minimum of the leading form on the unit sphere (normalized coordinates).
    #[serde(default)]
    pub leading_form_min: f64,
    /// `"moments"` (Cholesky of the moment-assembled system) or `"qr"` (streaming QR).
    #[serde(default)]
    pub solver: String,
    /// Automatic κ found no qualifying grid value and fell back to κ = 1e-2.
    #[serde(default)]
    pub kappa_fallback: bool,
    /// Whether automatic κ checked the meshed zero set (stable rule (c)/(d)).
    #[serde(default)]
    pub zero_set_checked: bool,
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
    /// Version of this artifact's layout; bump it whenever a field changes, its polynomial's
    /// included.
    pub(crate) const FORMAT_VERSION: u32 = 1;
}

/// Polynomials for the tests of this module and of the evaluators built on it.
#[cfg(test)]
pub(crate) mod test_support {
    use super::{n_coefficients, ImplicitPolynomial};

    /// A polynomial of degree `n` with coefficients uniform in [−1, 1), drawn by a 64-bit LCG
    /// from the state `state`, in the normalization `center`, `scale`.
    pub(crate) fn random_polynomial(
        n: u32,
        mut state: u64,
        center: [f64; 3],
        scale: f64,
    ) -> ImplicitPolynomial {
        let coefficients = (0..n_coefficients(n))
            .map(|_| {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
            })
            .collect();
        ImplicitPolynomial {
            degree: n,
            coefficients,
            center,
            scale,
        }
    }

    /// A deterministic pseudo-random polynomial of degree `n`.
    pub(crate) fn test_poly(n: u32, seed: u64) -> ImplicitPolynomial {
        let state = seed.wrapping_mul(0x9E3779B97F4A7C15).wrapping_add(7);
        random_polynomial(n, state, [0.3, -1.0, 2.0], 1.7)
    }
}
