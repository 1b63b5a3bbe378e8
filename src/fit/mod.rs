//! Stage `fit`: [`OrientedCloud`] → [`ImplicitModel`] by 3L with Euclidean-invariant ridge
//! regression (Sahin & Unel 2008).
//!
//! (Skeleton: the fit helper replaces this file; the public signatures below are the contract
//! the CLI and pipeline use.)

use crate::cloud::OrientedCloud;
use crate::poly::ImplicitModel;

/// Errors of the fit stage.
#[derive(Debug, thiserror::Error)]
pub enum FitError {
    /// Not built yet.
    #[error("fitting is not built yet")]
    NotBuilt,
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

/// How κ is chosen.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Kappa {
    /// Automatic, on the grid 0, 1e-8 … 1.
    #[default]
    Auto,
    /// A fixed value.
    Fixed(f64),
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

/// Parameters of the fit stage.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FitParams {
    /// Polynomial degree n.
    pub degree: u32,
    /// The fitting method.
    pub method: FitMethod,
    /// κ, fixed or automatic.
    pub kappa: Kappa,
    /// The rule for automatic κ.
    pub kappa_rule: KappaRule,
    /// Layer offset ε in normalized units.
    pub epsilon: f64,
}

impl Default for FitParams {
    fn default() -> Self {
        FitParams {
            degree: 6,
            method: FitMethod::ThreeLrr,
            kappa: Kappa::Auto,
            kappa_rule: KappaRule::Stable,
            epsilon: 0.05,
        }
    }
}

/// Fits an implicit polynomial to oriented points.
///
/// # Errors
/// Too few points, non-finite input, singular system.
pub fn fit(_cloud: &OrientedCloud, _params: &FitParams) -> Result<ImplicitModel, FitError> {
    Err(FitError::NotBuilt)
}
