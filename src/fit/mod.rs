//! Stage `fit`: [`OrientedCloud`] → [`ImplicitModel`] by 3L with Euclidean-invariant ridge
//! regression (Sahin & Unel, *Stable Algebraic Surfaces for 3D Object Representation*, 2008).
//!
//! Input: points with unit outward normals (input coordinates). Output: an [`ImplicitModel`]
//! whose polynomial f is negative inside and positive outside, with the settings used
//! ([`FitRecord`]) and what the fit measured ([`FitDiagnostics`]); its `bounds` are the data's
//! box grown by 10% per side.
//!
//! The method, step by step (DESIGN.md, "The method, exactly"):
//!
//! 1. Radial normalization (paper 2.2): μ the centroid, s the mean distance |p − μ|; the fit is in
//!    p̂ = (p − μ)/s and the model stores μ and s.
//! 2. 3L (5.5): the rows of M are the monomials at p̂, p̂ + εn and p̂ − εn, with targets 0, +ε, −ε.
//! 3. Ridge regression (6.6): a = (MᵀM + κD)⁻¹ Mᵀb with D diagonal, D_ll = β_{i+j+k}/T_ll (6.18),
//!    T_ll = (i+j+k)!/(i! j! k!), β_r = Σ_t |p̂_t|^{2r} over the N data points. This D makes the
//!    fit Euclidean invariant: a rigid motion of the data moves the zero set with it.
//! 4. κ is fixed or chosen on the grid 0, 1e-8 … 1 (four steps a decade) by a rule
//!    ([`KappaRule`]); the accumulated system is reused across the grid, only κD changes.
//!
//! The solve. MᵀM and Mᵀb are assembled from moments Σ x^a y^b z^c of degree ≤ 2n accumulated in
//! one parallel, deterministic pass (`system`), so memory is independent of N; the system is
//! then solved by Cholesky in a symmetrically scaled basis (`solve`). The alternative route,
//! a streaming Householder QR of [M; √(κD)] that never squares the condition number, is kept as
//! [`FitSolver::Qr`]. On the torus reference case (10,000 points, ε = 0.05) both agree with
//! the independent reference: moments + scaled Cholesky to 2e-13 … 4e-11 relative over degrees
//! 4, 6, 8 and κ = 1e-5 … 1e-3, QR to 4e-12 (degree 6) and 4e-11 (degree 8), the two routes to
//! 5e-13 and 2e-11 of each other (tests/all/fit.rs). The moment route costs about C(2n+3, 3)
//! multiply-adds per row against c² for QR, and its memory does not grow with N, so it is the
//! default.
//!
//! Plain least squares (section 4, [`FitMethod::Ls`]) is the unit eigenvector of MᵀM (data rows
//! only) with the smallest eigenvalue, signed so that f increases along the normals.
//!
//! Invariants: output deterministic whatever the thread count (fixed chunks, fixed reduction
//! order, sequential factorizations); bad input is an `Err`, never a panic.

mod kappa;
pub mod moments;
mod solve;
mod system;

use std::str::FromStr;

use rayon::prelude::*;

use crate::cloud::{Aabb, OrientedCloud};
use crate::poly::{n_coefficients, FitDiagnostics, FitRecord, ImplicitModel, ImplicitPolynomial};

pub(crate) use system::Normalization;
use system::{Rows, System};

/// Highest supported degree (moments up to degree 2n are accumulated; beyond 20 the monomial
/// basis is hopelessly ill-conditioned in double precision).
pub(crate) const MAX_DEGREE: u32 = 20;

/// Errors of the fit stage.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    /// Fewer points than coefficients: lower `--degree` or give more points.
    #[error("{n_points} points are too few for degree {degree}: it has {min} coefficients, give at least {min} points or lower --degree")]
    TooFewPoints {
        /// Points given.
        n_points: usize,
        /// Degree asked for.
        degree: u32,
        /// Points needed (the number of coefficients).
        min: usize,
    },
    /// Points and normals differ in number.
    #[error("the cloud has {n_points} points but {n_normals} normals: give one normal per point")]
    NormalsMismatch {
        /// Number of points.
        n_points: usize,
        /// Number of normals.
        n_normals: usize,
    },
    /// A coordinate or a normal is NaN or infinite.
    #[error("point {index} has a non-finite coordinate or normal: remove it from the input")]
    NonFinite {
        /// Index of the first offending point.
        index: usize,
    },
    /// A normal has (almost) zero length.
    #[error("point {index} has a zero-length normal: recompute the normals")]
    ZeroNormal {
        /// Index of the first offending point.
        index: usize,
    },
    /// All points coincide.
    #[error("all points coincide: the cloud has no extent to fit")]
    DegenerateCloud,
    /// A fit from moments was asked for something that needs the points.
    #[error("a fit from moments cannot use {what}")]
    NeedsPoints {
        /// What needs the points, and what to use instead.
        what: &'static str,
    },
    /// The moments were accumulated with other settings than the fit asks for.
    #[error("{what}")]
    MomentsMismatch {
        /// What differs and what to change.
        what: String,
    },
    /// Degree out of range.
    #[error("degree {degree} is not supported: use a degree from 1 to {max}")]
    InvalidDegree {
        /// Degree asked for.
        degree: u32,
        /// Highest supported degree.
        max: u32,
    },
    /// ε must be positive and finite.
    #[error(
        "epsilon {epsilon} is invalid: use a positive layer offset such as 0.05 (normalized units)"
    )]
    InvalidEpsilon {
        /// ε asked for.
        epsilon: f64,
    },
    /// κ must be non-negative and finite.
    #[error("kappa {kappa} is invalid: use a non-negative number or auto")]
    InvalidKappa {
        /// κ asked for.
        kappa: f64,
    },
    /// Automatic κ needs an even degree (an odd-degree polynomial is never bounded).
    #[error("--kappa auto needs an even degree, and {degree} is odd: an odd-degree zero set is never closed and bounded, so no κ can make it so; use an even --degree or a fixed --kappa")]
    OddDegreeAutoKappa {
        /// Degree asked for.
        degree: u32,
    },
    /// The (regularized) system is singular to working precision.
    #[error("the fit's linear system is singular at kappa {kappa} (pivot {column} of {n_coefficients}): increase --kappa, lower --degree, or give points that cover the shape")]
    SingularSystem {
        /// κ of the failed solve.
        kappa: f64,
        /// The column where the factorization broke down.
        column: usize,
        /// Number of coefficients.
        n_coefficients: usize,
    },
    /// A numerical routine did not converge.
    #[error("the eigen-decomposition did not converge: check the input for extreme outliers")]
    NoConvergence,
}

/// The fitting method.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FitMethod {
    /// 3L with ridge regression (paper 6.6).
    #[default]
    ThreeLrr,
    /// Plain 3L (κ = 0).
    ThreeL,
    /// Plain least squares (paper section 4).
    Ls,
}

impl FitMethod {
    /// The CLI and model-file name: `"3lrr"`, `"3l"` or `"ls"`.
    pub fn as_str(&self) -> &'static str {
        match self {
            FitMethod::ThreeLrr => "3lrr",
            FitMethod::ThreeL => "3l",
            FitMethod::Ls => "ls",
        }
    }
}

impl FromStr for FitMethod {
    type Err = String;

    /// ```
    /// use stablesurf::fit::FitMethod;
    /// assert_eq!("3lrr".parse::<FitMethod>(), Ok(FitMethod::ThreeLrr));
    /// assert!("qr".parse::<FitMethod>().is_err());
    /// ```
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let name = s.to_ascii_lowercase();
        match [FitMethod::ThreeLrr, FitMethod::ThreeL, FitMethod::Ls]
            .into_iter()
            .find(|m| m.as_str() == name)
        {
            Some(method) => Ok(method),
            None => Err(format!("unknown fit method {name:?}: use 3lrr, 3l or ls")),
        }
    }
}

/// How κ is chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Kappa {
    /// Automatic, on the grid 0, 1e-8 … 1.
    #[default]
    Auto,
    /// A fixed value.
    Fixed(f64),
}

impl FromStr for Kappa {
    type Err = String;

    /// `"auto"` or a non-negative number.
    ///
    /// ```
    /// use stablesurf::fit::Kappa;
    /// assert_eq!("auto".parse::<Kappa>(), Ok(Kappa::Auto));
    /// assert_eq!("1e-3".parse::<Kappa>(), Ok(Kappa::Fixed(1e-3)));
    /// assert!("-1".parse::<Kappa>().is_err());
    /// ```
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s.eq_ignore_ascii_case("auto") {
            return Ok(Kappa::Auto);
        }
        match s.parse::<f64>() {
            Ok(v) if v.is_finite() && v >= 0.0 => Ok(Kappa::Fixed(v)),
            _ => Err(format!(
                "invalid kappa {s:?}: use auto or a non-negative number such as 1e-3"
            )),
        }
    }
}

/// The rule for automatic κ.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum KappaRule {
    /// Smallest κ whose leading form is positive definite (paper 6.3).
    Paper,
    /// The stricter rule (positivity at every larger κ, containment radius, clean zero set).
    #[default]
    Stable,
}

impl KappaRule {
    /// The CLI and model-file name: `"paper"` or `"stable"`.
    pub fn as_str(&self) -> &'static str {
        match self {
            KappaRule::Paper => "paper",
            KappaRule::Stable => "stable",
        }
    }
}

impl FromStr for KappaRule {
    type Err = String;

    /// ```
    /// use stablesurf::fit::KappaRule;
    /// assert_eq!("stable".parse::<KappaRule>(), Ok(KappaRule::Stable));
    /// ```
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let name = s.to_ascii_lowercase();
        match [KappaRule::Paper, KappaRule::Stable]
            .into_iter()
            .find(|r| r.as_str() == name)
        {
            Some(rule) => Ok(rule),
            None => Err(format!("unknown kappa rule {name:?}: use stable or paper")),
        }
    }
}

/// How the linear system is solved.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FitSolver {
    /// Moments accumulated in one parallel pass (memory independent of N), Cholesky of the
    /// symmetrically scaled MᵀM + κD.
    #[default]
    Moments,
    /// Streaming Householder QR of [M | b; √(κD) | 0] (memory O(c²), never squares the
    /// condition number; O(N·c²) work). κ selection still uses the moment system.
    Qr,
}

impl FitSolver {
    /// `"moments"` or `"qr"`.
    pub(crate) fn as_str(&self) -> &'static str {
        match self {
            FitSolver::Moments => "moments",
            FitSolver::Qr => "qr",
        }
    }
}

/// The ridge matrix D of 3LRR.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum RidgeMatrix {
    /// D_ll = β_{i+j+k}/T_ll (paper 6.18): Euclidean invariant.
    #[default]
    Invariant,
    /// D = identity (plain ridge regression): not invariant; for comparison only.
    Identity,
}

/// Parameters of the fit stage.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FitParams {
    /// Polynomial degree n (1 to `MAX_DEGREE`; automatic κ needs it even).
    pub degree: u32,
    /// The fitting method.
    pub method: FitMethod,
    /// κ, fixed or automatic (used by [`FitMethod::ThreeLrr`] only).
    pub kappa: Kappa,
    /// The rule for automatic κ.
    pub kappa_rule: KappaRule,
    /// Layer offset ε in normalized units (the data's mean distance to its centroid is 1).
    pub epsilon: f64,
    /// How the linear system is solved.
    #[serde(default)]
    pub solver: FitSolver,
    /// The ridge matrix D (the paper's invariant one unless comparing).
    #[serde(default)]
    pub ridge: RidgeMatrix,
}

impl Default for FitParams {
    fn default() -> Self {
        FitParams {
            degree: 8,
            method: FitMethod::ThreeLrr,
            kappa: Kappa::Auto,
            kappa_rule: KappaRule::Stable,
            epsilon: 0.05,
            solver: FitSolver::Moments,
            ridge: RidgeMatrix::Invariant,
        }
    }
}

/// Fits an implicit polynomial to oriented points.
///
/// ```
/// use stablesurf::fit::{fit, FitParams, Kappa};
/// use stablesurf::OrientedCloud;
/// // 400 points on the unit sphere around (1, 2, 3).
/// let mut cloud = OrientedCloud::default();
/// for i in 0..400 {
///     let z = 1.0 - (2.0 * i as f64 + 1.0) / 400.0;
///     let r = (1.0 - z * z).sqrt();
///     let phi = 2.399963 * i as f64;
///     let n = [r * phi.cos(), r * phi.sin(), z];
///     cloud.points.push([1.0 + n[0], 2.0 + n[1], 3.0 + n[2]]);
///     cloud.normals.push(n);
/// }
/// let params = FitParams { degree: 2, kappa: Kappa::Fixed(1e-4), ..FitParams::default() };
/// let model = fit(&cloud, &params).unwrap();
/// assert!(model.polynomial.eval([1.0, 2.0, 3.0]) < 0.0); // inside
/// assert!(model.polynomial.eval([1.0, 2.0, 4.0]).abs() < 1e-3); // on the sphere
/// assert!(model.diagnostics.unwrap().bounded);
/// ```
///
/// # Errors
/// Too few points for the degree, non-finite input, zero normals, coincident points, invalid
/// degree/ε/κ, automatic κ with an odd degree, or a singular system ([`FitError`]).
pub fn fit(cloud: &OrientedCloud, params: &FitParams) -> Result<ImplicitModel, FitError> {
    check_params(params)?;
    let degree = params.degree;
    let checked = validate(cloud, degree, n_coefficients(degree))?;
    let cloud = checked.as_ref().unwrap_or(cloud);
    let norm = Normalization::of(&cloud.points);
    if !(norm.scale.is_finite() && norm.scale > 0.0) {
        return Err(FitError::DegenerateCloud);
    }
    let rows = match params.method {
        FitMethod::Ls => Rows::Data,
        _ => Rows::ThreeLayers {
            epsilon: params.epsilon,
        },
    };
    let sys = system::accumulate(cloud, &norm, degree, rows);
    let bbox = Aabb::from_points(&cloud.points).ok_or(FitError::DegenerateCloud)?;
    solve_system(&sys, &norm, bbox, cloud.points.len(), params, Some(cloud))
}

/// Fits from merged pass-3 moments ([`moments`]): the same model as [`fit`] on all the points
/// (to rounding), except that the first-order distances to the data are not measured (0, with a
/// warning).
///
/// # Errors
/// As [`fit`]; and [`FitError::NeedsPoints`] for what the moments cannot carry (the stable κ
/// rule, the `ls` method, the QR solver), [`FitError::MomentsMismatch`] when the parts were
/// accumulated at another degree or ε than `params` asks for.
pub fn fit_from_moments(
    merged: &moments::SystemMoments,
    params: &FitParams,
) -> Result<ImplicitModel, FitError> {
    check_params(params)?;
    if params.method == FitMethod::Ls {
        return Err(FitError::NeedsPoints {
            what: "the ls method (it signs its solution with the normals): use --method 3lrr or 3l",
        });
    }
    if params.solver == FitSolver::Qr {
        return Err(FitError::NeedsPoints {
            what: "the QR solver (it streams the rows): use the moment solver",
        });
    }
    if params.method == FitMethod::ThreeLrr
        && params.kappa == Kappa::Auto
        && params.kappa_rule == KappaRule::Stable
    {
        return Err(FitError::NeedsPoints {
            what: "the stable kappa rule (it checks the zero set against the points): pass a fixed --kappa or --kappa-rule paper",
        });
    }
    if merged.degree != params.degree {
        return Err(FitError::MomentsMismatch {
            what: format!(
                "the moments were accumulated at degree {} but the fit asks for degree {}: pass --degree {} or recompute the moments",
                merged.degree, params.degree, merged.degree
            ),
        });
    }
    if merged.epsilon != params.epsilon {
        return Err(FitError::MomentsMismatch {
            what: format!(
                "the moments were accumulated at epsilon {} but the fit asks for epsilon {}: pass --epsilon {} or recompute the moments",
                merged.epsilon, params.epsilon, merged.epsilon
            ),
        });
    }
    let min = n_coefficients(params.degree);
    let n_points = usize::try_from(merged.n_points).unwrap_or(usize::MAX);
    if n_points < min {
        return Err(FitError::TooFewPoints {
            n_points,
            degree: params.degree,
            min,
        });
    }
    let norm = Normalization {
        center: merged.frame.center,
        scale: merged.frame.scale,
    };
    if !(norm.scale.is_finite() && norm.scale > 0.0) {
        return Err(FitError::DegenerateCloud);
    }
    let sys = System {
        degree: merged.degree,
        moments: merged.moments.clone(),
        rhs: merged.rhs.clone(),
        beta: merged.beta.clone(),
    };
    solve_system(&sys, &norm, merged.bounds, n_points, params, None)
}

/// Checks degree, ε and κ.
fn check_params(params: &FitParams) -> Result<(), FitError> {
    let degree = params.degree;
    if degree == 0 || degree > MAX_DEGREE {
        return Err(FitError::InvalidDegree {
            degree,
            max: MAX_DEGREE,
        });
    }
    if params.method != FitMethod::Ls {
        check_degree_epsilon(degree, params.epsilon)?;
    }
    if let Kappa::Fixed(kappa) = params.kappa
        && !(kappa.is_finite() && kappa >= 0.0)
    {
        return Err(FitError::InvalidKappa { kappa });
    }
    let auto_kappa = params.method == FitMethod::ThreeLrr && params.kappa == Kappa::Auto;
    if auto_kappa && degree % 2 == 1 {
        return Err(FitError::OddDegreeAutoKappa { degree });
    }
    Ok(())
}

/// Checks a degree and a 3L ε.
fn check_degree_epsilon(degree: u32, epsilon: f64) -> Result<(), FitError> {
    if degree == 0 || degree > MAX_DEGREE {
        return Err(FitError::InvalidDegree {
            degree,
            max: MAX_DEGREE,
        });
    }
    if !(epsilon.is_finite() && epsilon > 0.0) {
        return Err(FitError::InvalidEpsilon { epsilon });
    }
    Ok(())
}

/// Solves an accumulated system and assembles the model. `cloud` (validated) is needed by the
/// `ls` method, the stable κ rule, the QR solver and the distance diagnostics; without it those
/// distances are reported as 0 with a warning.
fn solve_system(
    sys: &System,
    norm: &Normalization,
    bbox: Aabb,
    n_points: usize,
    params: &FitParams,
    cloud: Option<&OrientedCloud>,
) -> Result<ImplicitModel, FitError> {
    let degree = params.degree;
    let norm = *norm;
    let c = n_coefficients(degree);
    // Only the paper rule runs without points (fit_from_moments refuses the rest).
    let no_points = OrientedCloud::default();
    let points = cloud.unwrap_or(&no_points);
    let gram = sys.gram();
    let ridge = match params.ridge {
        RidgeMatrix::Invariant => sys.ridge_diagonal(),
        RidgeMatrix::Identity => vec![1.0; c],
    };
    let mut warnings = Vec::new();
    let mut selection = None;
    let (kappa, kappa_rule, mut coefficients) = match params.method {
        FitMethod::Ls => (
            0.0,
            "fixed",
            least_squares(&gram, c, points, &norm, degree)?,
        ),
        FitMethod::ThreeL => (0.0, "fixed", solve_fixed(sys, &gram, &ridge, 0.0)?),
        FitMethod::ThreeLrr => match params.kappa {
            Kappa::Fixed(k) => (k, "fixed", solve_fixed(sys, &gram, &ridge, k)?),
            Kappa::Auto => {
                let sel = kappa::select(sys, &gram, &ridge, &norm, points, params.kappa_rule)?;
                warnings.extend(sel.warnings.iter().cloned());
                let out = (
                    sel.kappa,
                    params.kappa_rule.as_str(),
                    sel.coefficients.clone(),
                );
                selection = Some(sel);
                out
            }
        },
    };
    if params.solver == FitSolver::Qr && params.method != FitMethod::Ls {
        coefficients = solve_qr(points, &norm, degree, params.epsilon, kappa, &ridge)?;
    }
    let polynomial = ImplicitPolynomial {
        degree,
        coefficients,
        center: norm.center,
        scale: norm.scale,
    };
    let (condition_number, condition_number_scaled) = match params.method {
        FitMethod::Ls => solve::condition_numbers(&gram, &ridge, 0.0, c),
        _ => solve::condition_numbers(&gram, &ridge, kappa, c),
    }
    .map_err(|_| FitError::NoConvergence)?;
    let extrema = polynomial.leading_form_extrema();
    let bounded = degree.is_multiple_of(2) && extrema.min > 0.0;
    let containment_radius = if bounded {
        polynomial.containment_radius_with(extrema.min)
    } else {
        None
    };
    let (mean_distance, max_distance) = match cloud {
        Some(cloud) => first_order_distances(&polynomial, &cloud.points),
        None => {
            warnings.push(
                "fitted from moments: the distances to the data were not measured (0 is written)"
                    .to_string(),
            );
            (0.0, 0.0)
        }
    };
    let diagonal = bbox.diagonal();
    if !bounded {
        warnings.push(if degree % 2 == 1 {
            "odd degree: the zero set is not bounded".to_string()
        } else {
            "the leading form is not positive on the unit sphere: the zero set may be unbounded; use --kappa auto or a larger --kappa".to_string()
        });
    }
    let diagnostics = FitDiagnostics {
        condition_number,
        leading_form_min_relative: extrema.min_relative(),
        bounded,
        containment_radius,
        mean_distance,
        max_distance,
        mean_distance_relative: mean_distance / diagonal,
        max_distance_relative: max_distance / diagonal,
        warnings,
        kappa,
        epsilon: if params.method == FitMethod::Ls {
            0.0
        } else {
            params.epsilon
        },
        condition_number_scaled,
        leading_form_min: extrema.min,
        solver: params.solver.as_str().to_string(),
        kappa_fallback: selection.as_ref().is_some_and(|s| s.fallback),
        zero_set_checked: selection.as_ref().is_some_and(|s| s.zero_set_checked),
    };
    Ok(ImplicitModel {
        polynomial,
        bounds: Some(bbox.grown(0.1)),
        fit: Some(FitRecord {
            method: params.method.as_str().to_string(),
            epsilon: if params.method == FitMethod::Ls {
                0.0
            } else {
                params.epsilon
            },
            kappa,
            kappa_rule: kappa_rule.to_string(),
            n_points,
        }),
        diagnostics: Some(diagnostics),
    })
}

/// Checks the cloud (at least `min` points); returns a copy with renormalized normals when some
/// are not unit length.
fn validate(
    cloud: &OrientedCloud,
    degree: u32,
    min: usize,
) -> Result<Option<OrientedCloud>, FitError> {
    let n_points = cloud.points.len();
    if cloud.normals.len() != n_points {
        return Err(FitError::NormalsMismatch {
            n_points,
            n_normals: cloud.normals.len(),
        });
    }
    if n_points < min {
        return Err(FitError::TooFewPoints {
            n_points,
            degree,
            min,
        });
    }
    let mut needs_renormalizing = false;
    for (index, (p, n)) in cloud.points.iter().zip(&cloud.normals).enumerate() {
        if !p.iter().chain(n.iter()).all(|v| v.is_finite()) {
            return Err(FitError::NonFinite { index });
        }
        let len2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
        if len2 < 1e-24 {
            return Err(FitError::ZeroNormal { index });
        }
        if (len2 - 1.0).abs() > 1e-12 {
            needs_renormalizing = true;
        }
    }
    if !needs_renormalizing {
        return Ok(None);
    }
    let normals = cloud
        .normals
        .iter()
        .map(|n| {
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            n.map(|c| c / len)
        })
        .collect();
    Ok(Some(OrientedCloud {
        points: cloud.points.clone(),
        normals,
        weights: cloud.weights.clone(),
    }))
}

fn solve_fixed(
    sys: &System,
    gram: &[f64],
    ridge: &[f64],
    kappa: f64,
) -> Result<Vec<f64>, FitError> {
    solve::solve_ridge(gram, &sys.rhs, ridge, kappa)
        .map(|s| s.coefficients)
        .map_err(|e| solve_error(e, kappa, sys.rhs.len()))
}

fn solve_error(e: solve::SolveFailure, kappa: f64, n_coefficients: usize) -> FitError {
    match e {
        solve::SolveFailure::NotPositiveDefinite { column } => FitError::SingularSystem {
            kappa,
            column,
            n_coefficients,
        },
        solve::SolveFailure::NoConvergence => FitError::NoConvergence,
    }
}

/// Plain least squares (paper section 4): the unit eigenvector of MᵀM (data rows) with the
/// smallest eigenvalue, signed so that Σ ∇f(p̂_t)·n_t > 0 (f increases outwards).
fn least_squares(
    gram: &[f64],
    c: usize,
    cloud: &OrientedCloud,
    norm: &Normalization,
    degree: u32,
) -> Result<Vec<f64>, FitError> {
    let (_, vectors) =
        solve::symmetric_eigen(gram, c, true).map_err(|_| FitError::NoConvergence)?;
    let vectors = vectors.ok_or(FitError::NoConvergence)?;
    let mut a = vectors[..c].to_vec();
    let poly = ImplicitPolynomial {
        degree,
        coefficients: a.clone(),
        center: norm.center,
        scale: norm.scale,
    };
    let mut values = vec![0.0; cloud.points.len()];
    let mut gradients = vec![[0.0; 3]; cloud.points.len()];
    poly.eval_gradient_many(&cloud.points, &mut values, &mut gradients);
    let flux: f64 = gradients
        .iter()
        .zip(&cloud.normals)
        .map(|(g, n)| g[0] * n[0] + g[1] * n[1] + g[2] * n[2])
        .sum();
    if flux < 0.0 {
        a.iter_mut().for_each(|v| *v = -*v);
    }
    Ok(a)
}

/// The QR route: streams the rows of [M | b] and then √(κD) into a Householder QR.
fn solve_qr(
    cloud: &OrientedCloud,
    norm: &Normalization,
    degree: u32,
    epsilon: f64,
    kappa: f64,
    ridge: &[f64],
) -> Result<Vec<f64>, FitError> {
    let exps = crate::poly::exponents(degree);
    let c = exps.len();
    let n = degree as usize;
    let mut qr = solve::StreamingQr::new(c);
    let row_of = |q: [f64; 3], target: f64| {
        let mut px = vec![1.0; n + 1];
        let mut py = vec![1.0; n + 1];
        let mut pz = vec![1.0; n + 1];
        for e in 1..=n {
            px[e] = px[e - 1] * q[0];
            py[e] = py[e - 1] * q[1];
            pz[e] = pz[e - 1] * q[2];
        }
        let mut row: Vec<f64> = exps
            .iter()
            .map(|e| px[e[0] as usize] * py[e[1] as usize] * pz[e[2] as usize])
            .collect();
        row.push(target);
        row
    };
    for (p, nrm) in cloud.points.iter().zip(&cloud.normals) {
        let q = norm.apply(*p);
        qr.push(row_of(q, 0.0));
        qr.push(row_of([0, 1, 2].map(|a| q[a] + epsilon * nrm[a]), epsilon));
        qr.push(row_of([0, 1, 2].map(|a| q[a] - epsilon * nrm[a]), -epsilon));
    }
    if kappa > 0.0 {
        for (l, d) in ridge.iter().enumerate() {
            let mut row = vec![0.0; c + 1];
            row[l] = (kappa * d).sqrt();
            qr.push(row);
        }
    }
    qr.solve().ok_or(FitError::SingularSystem {
        kappa,
        column: 0,
        n_coefficients: c,
    })
}

/// Most data points the fit's first-order distances ([`FitDiagnostics::mean_distance`] and
/// `max_distance`) are measured at: a larger cloud is measured on every k-th point (k = ⌈N /
/// this⌉), as many as the run's accuracy measures ([`crate::measure::ACCURACY_POINTS`]).
pub(crate) const DISTANCE_POINTS: usize = crate::measure::ACCURACY_POINTS;

/// Mean and maximum of the first-order distance |f|/|∇f| at the points (input units), summed in
/// fixed chunks in a fixed order; past [`DISTANCE_POINTS`] points, at every k-th
/// (the rule of the run's accuracy). Points where ∇f = 0 are skipped.
fn first_order_distances(poly: &ImplicitPolynomial, points: &[[f64; 3]]) -> (f64, f64) {
    let points = crate::measure::every_kth(points, DISTANCE_POINTS);
    let partials: Vec<(f64, f64, usize)> = points
        .par_chunks(4096)
        .map(|chunk| {
            let mut values = vec![0.0; chunk.len()];
            let mut gradients = vec![[0.0; 3]; chunk.len()];
            poly.eval_gradient_many(chunk, &mut values, &mut gradients);
            let mut sum = 0.0;
            let mut max = 0.0f64;
            let mut count = 0;
            for (f, g) in values.iter().zip(&gradients) {
                let gn = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
                if gn > 0.0 && f.is_finite() {
                    let d = f.abs() / gn;
                    sum += d;
                    max = max.max(d);
                    count += 1;
                }
            }
            (sum, max, count)
        })
        .collect();
    let (sum, max, count) = partials.iter().fold((0.0, 0.0f64, 0usize), |acc, p| {
        (acc.0 + p.0, acc.1.max(p.1), acc.2 + p.2)
    });
    if count == 0 {
        (f64::NAN, f64::NAN)
    } else {
        (sum / count as f64, max)
    }
}

/// The pieces of one fit that tests and tools inspect: the ridge diagonal D, β, and the
/// normalization, computed exactly as [`fit`] does.
#[derive(Clone, Debug, PartialEq)]
pub struct FitSystemSummary {
    /// Normalization centre μ.
    pub center: [f64; 3],
    /// Normalization scale s.
    pub scale: f64,
    /// β_0 … β_n.
    pub beta: Vec<f64>,
    /// The diagonal of D in the paper's order.
    pub ridge_diagonal: Vec<f64>,
    /// Mᵀb in the paper's order.
    pub rhs: Vec<f64>,
    /// The diagonal of MᵀM.
    pub gram_diagonal: Vec<f64>,
}

/// Accumulates the 3L system of `cloud` at `degree` and ε and returns its D, β, Mᵀb and the
/// diagonal of MᵀM (for checks against reference implementations).
///
/// # Errors
/// As [`fit`] for invalid input.
pub fn system_summary(
    cloud: &OrientedCloud,
    degree: u32,
    epsilon: f64,
) -> Result<FitSystemSummary, FitError> {
    if degree == 0 || degree > MAX_DEGREE {
        return Err(FitError::InvalidDegree {
            degree,
            max: MAX_DEGREE,
        });
    }
    let checked = validate(cloud, degree, n_coefficients(degree))?;
    let cloud = checked.as_ref().unwrap_or(cloud);
    let norm = Normalization::of(&cloud.points);
    let sys = system::accumulate(cloud, &norm, degree, Rows::ThreeLayers { epsilon });
    let gram = sys.gram();
    let c = sys.rhs.len();
    Ok(FitSystemSummary {
        center: norm.center,
        scale: norm.scale,
        ridge_diagonal: sys.ridge_diagonal(),
        beta: sys.beta.clone(),
        rhs: sys.rhs.clone(),
        gram_diagonal: (0..c).map(|l| gram[l * c + l]).collect(),
    })
}
