//! Implicit functions: what the meshing and the checks need from a model f (f < 0 inside,
//! f > 0 outside), and its implementation for [`ImplicitPolynomial`](crate::ImplicitPolynomial).
//!
//! Input: a model f (the global polynomial, or the partition-of-unity blend of local fits in
//! [`crate::detail`]). Output: point values, gradients, and *guaranteed enclosures* of f and ∇f
//! over an axis-aligned box, which the octree of [`crate::polygonize`](mod@crate::polygonize) uses to discard cells where
//! f cannot vanish, and which the κ checks of [`crate::fit`](mod@crate::fit) and the model's distance slices use
//! too. This module belongs to no stage: every stage that evaluates a model imports it from here.
//!
//! Invariants: [`ImplicitFunction::bounds_on_box`] returns an interval that contains the value that
//! [`ImplicitFunction::value`] computes at every point of the closed box (rounding included), so a
//! cell that the bound excludes never shows a sign change to the extraction.

use crate::cloud::Aabb;

mod polynomial;

/// Guaranteed enclosures of f and ∇f over a box (see [`ImplicitFunction::enclosure_on_box`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Enclosure {
    /// `(lo, hi)` with lo ≤ value(p) ≤ hi on the box.
    pub value: (f64, f64),
    /// Enclosures of ∂f/∂x, ∂f/∂y, ∂f/∂z (input coordinates) on the box.
    pub gradient: [(f64, f64); 3],
    /// A bound on |value(p) − f(p)|, the rounding error of a point value, on the box.
    pub value_error: f64,
}

/// f at the 8 points of a 2×2×2 grid, from [`ImplicitFunction::enclosure_and_grid_values`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridValues {
    /// The values, point i at coordinate `axes[a][(i >> a) & 1]` on axis a.
    pub values: [f64; 8],
    /// A bound on |values\[i\] − f(point i)| against the exact f (rounding included).
    pub error: f64,
}

/// What the `polygonize` stage needs from an implicit model f (f < 0 inside, f > 0 outside), in
/// input coordinates.
///
/// Implement this for another model (for example a partition-of-unity blend of local fits) to
/// mesh it with [`crate::polygonize::polygonize`].
///
/// ```
/// use stablesurf::implicit::ImplicitFunction;
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
/// // f ranges over [3, 10] on this box; the enclosure contains that and excludes 0.
/// assert!(lo > 0.0 && lo <= 3.0 && hi >= 10.0);
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

    /// Both enclosures at once, with a bound on the rounding error of [`ImplicitFunction::value`]
    /// over the box. The default combines the two methods above and assumes exact point values
    /// (`value_error` 0); override it when the two share work (the polynomial computes one local
    /// expansion for both) or when point values round.
    fn enclosure_on_box(&self, b: &Aabb) -> Enclosure {
        Enclosure {
            value: self.bounds_on_box(b),
            gradient: self.gradient_bounds_on_box(b),
            value_error: 0.0,
        }
    }

    /// The enclosure on `b` ([`ImplicitFunction::enclosure_on_box`]) together with f at the 8
    /// points of the grid `axes` (point i has coordinate `axes[a][(i >> a) & 1]` on axis a,
    /// x fastest; every point lies in `b`) and a bound on the error of those values against the
    /// exact f, when the model gets them cheaply from the enclosure's work (the octree uses them
    /// for the 8 children's centres). The default returns no values, and the octree evaluates
    /// [`ImplicitFunction::value`] at each centre it needs.
    fn enclosure_and_grid_values(
        &self,
        b: &Aabb,
        axes: &[[f64; 2]; 3],
    ) -> (Enclosure, Option<GridValues>) {
        let _ = axes;
        (self.enclosure_on_box(b), None)
    }

    /// Why the model cannot be meshed (a malformed model), or `Ok(())`.
    ///
    /// # Errors
    /// A message naming what is wrong with the model.
    fn validate(&self) -> Result<(), String> {
        Ok(())
    }
}
