//! Signed distance from an implicit polynomial's zero set, sampled on slices (the `slices` output).
//!
//! Input: an [`ImplicitPolynomial`] f (negative inside, as the 3L fit makes it) and a region
//! ([`Aabb`], input coordinates). Output: [`Slice`]s, K planes across the region along one axis,
//! each an R×R grid of signed distances in input units (negative inside), with the affine map
//! from grid indices to input coordinates. No IO: the EXR and PNG writers live in `export`.
//!
//! # Grid
//!
//! ```text
//!   row 0 ─▶ ┌───────────────┐  v = max    pixels are square: h = max(in-plane extents) / R;
//!            │ (col, row)    │             the R×R square is centred on the region's centre,
//!            │   centre of   │             so it covers the region's in-plane rectangle;
//!            │   each pixel  │             slice k lies at w = min_w + (k + ½)·(extent_w / K).
//!   row R−1  └───────────────┘  v = min
//!            u = min ──▶ u = max
//! ```
//!
//! In-plane axes (u, v): slicing along z uses (x, y); along y, (x, z); along x, (y, z). Columns
//! grow with u, rows grow downwards in v, so an image viewer shows v up. [`Slice::grid_to_world`]
//! maps (col, row, k) of a pixel centre to input coordinates exactly.
//!
//! # Methods and their error
//!
//! - [`DistanceMethod::Taubin`]: d ≈ f/|∇f| (Taubin 1991, first-order distance), one gradient
//!   evaluation per pixel. Exact on planes and correct to first order at the surface, with an
//!   error of order d²: for f = |p|² − r² it gives d(2r + d)/(2(r + d)), off by d²/(2(r + d)),
//!   so below 1e-4 only for |d| ≲ 0.014·√r; far from the surface it can be wrong by any factor
//!   and it is unbounded where ∇f vanishes (clamped to ± the region's diagonal there).
//! - [`DistanceMethod::Exact`] (default): the Euclidean distance to the zero set. The zero set is
//!   sampled on a grid over the region grown by 25% (sign changes on the edges of a 64-cell grid
//!   along the longest side, each projected onto f = 0 by Newton steps along ∇f); for a pixel p
//!   the nearest samples (k-d tree) start Newton's method on the closest-point conditions
//!   x − p + λ∇f(x) = 0, f(x) = 0 (with the Hessian of f). The result is the distance from p to
//!   a point x with |f(x)|/|∇f(x)| < 1e-10 (normalized units), so it is never below the true
//!   distance; it equals the true distance far below the float32 output's precision (a short
//!   last Newton step gives way to a projection onto f = 0, see `NEWTON_PROJECT_STEP`)
//!   whenever one of the nearest samples lies in the Newton basin of the true closest point,
//!   which holds unless a piece of the zero set is smaller than a seed cell (1/64 of the grown
//!   region) or the true closest point lies outside the grown region. The sign is the sign of
//!   f(p). Along a row of a slice, Newton's method is first run from the previous pixels'
//!   closest points (extrapolated along the row: an excellent start); the point it finds then
//!   bounds and covers seeds like a refined seed, so most pixels need only this warm solve.
//!   Cost: about one Hessian evaluation, two values of f and one 8-nearest-neighbour query per
//!   pixel, some 7× Taubin for a degree-8 model (`cargo bench --bench export -- slices`). Two
//!   shortcuts leave every value unchanged (bit for bit): the pixels of a row share two
//!   coordinates, so f's inner sums over them are computed once per row (and once per grid
//!   line for the seed grid), and the previous pixel's 8 nearest seeds bound the 8-nearest
//!   distance of the next query, whose k-d tree search then starts with that radius instead of
//!   best + cell.
//!
//! Invariants: values are finite; the output depends only on the inputs (rayon over fixed rows,
//! each row computed sequentially from its first pixel), whatever the thread count.

mod exact;
pub mod volume;

pub use exact::ExactDistance;

use rayon::prelude::*;

use crate::cloud::Aabb;
use crate::implicit::ImplicitFunction;
use crate::measure::GridMeshDistance;
use crate::mesh::TriangleMesh;
use crate::poly::ImplicitPolynomial;
use crate::vec3::dist;
use exact::{Evaluator, NearSeeds};

/// Highest polynomial degree the distance evaluator accepts.
pub(crate) const MAX_DEGREE: u32 = 32;

/// The axis slices are perpendicular to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Axis {
    /// Slices perpendicular to x; pixels span (y, z).
    X,
    /// Slices perpendicular to y; pixels span (x, z).
    Y,
    /// Slices perpendicular to z; pixels span (x, y). The default.
    #[default]
    Z,
}

impl Axis {
    /// The axis as `"x"`, `"y"` or `"z"`.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Axis::X => "x",
            Axis::Y => "y",
            Axis::Z => "z",
        }
    }

    /// World axes (u, v, w): columns, rows, slice normal.
    fn frame(self) -> [usize; 3] {
        match self {
            Axis::X => [1, 2, 0],
            Axis::Y => [0, 2, 1],
            Axis::Z => [0, 1, 2],
        }
    }
}

/// How the signed distance is computed (see the module docs for the error of each).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum DistanceMethod {
    /// First-order estimate f/|∇f|: fast, accurate only near the surface.
    Taubin,
    /// Distance to the zero set by closest-point search and Newton projection. The default.
    #[default]
    Exact,
    /// Distance to the polygonized zero set (the output mesh), signed by f: within the mesh's
    /// chord error of the exact distance (see `crate::measure::GridMeshDistance` for when the
    /// search can miss); works for any model, not only a polynomial. Needs the mesh
    /// ([`slices_from_mesh`]).
    Mesh,
}

impl DistanceMethod {
    /// The method as `"taubin"` or `"exact"`.
    pub fn name(self) -> &'static str {
        match self {
            DistanceMethod::Taubin => "taubin",
            DistanceMethod::Exact => "exact",
            DistanceMethod::Mesh => "mesh",
        }
    }
}

/// Parameters of [`slices`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct SliceParams {
    /// Axis the slices are perpendicular to; default z.
    pub axis: Axis,
    /// Number of slices K across the region, ≥ 1; default 16.
    pub count: usize,
    /// Pixels R along each side of a slice, 2 ..= 16384; default 256.
    pub resolution: usize,
    /// Distance method; default [`DistanceMethod::Exact`].
    pub method: DistanceMethod,
}

impl Default for SliceParams {
    fn default() -> Self {
        SliceParams {
            axis: Axis::Z,
            count: 16,
            resolution: 256,
            method: DistanceMethod::Exact,
        }
    }
}

/// One slice of the signed distance field.
#[derive(Clone, Debug, PartialEq)]
pub struct Slice {
    /// Index k of the slice, 0-based, along the axis from its minimum.
    pub index: usize,
    /// Number of slices K in the stack.
    pub count: usize,
    /// The axis the slice is perpendicular to.
    pub axis: Axis,
    /// The method that computed `data`.
    pub method: DistanceMethod,
    /// Pixels R along each side.
    pub resolution: usize,
    /// R×R signed distances in input units, negative inside, row-major; row 0 is the top of the
    /// image (largest v), column 0 the left (smallest u).
    pub data: Vec<f32>,
    /// Affine map from grid to input coordinates, column-vector convention:
    /// `world = M · [col, row, k, 1]ᵀ` with `M = grid_to_world` indexed `[world_axis][grid_axis]`;
    /// integer (col, row) are pixel centres.
    pub grid_to_world: [[f64; 4]; 4],
    /// Spacing along (columns, rows, slices) in input units: (h, h, extent_w / K).
    pub voxel_size: [f64; 3],
}

impl Slice {
    /// Input-space position of the centre of pixel (`col`, `row`).
    pub fn pixel_center(&self, col: usize, row: usize) -> [f64; 3] {
        let m = &self.grid_to_world;
        let g = [col as f64, row as f64, self.index as f64, 1.0];
        [0, 1, 2].map(|a| (0..4).map(|c| m[a][c] * g[c]).sum())
    }
}

/// Errors of the distance computation.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DistanceError {
    /// A parameter is out of range; the message names it and its valid range.
    #[error("{0}")]
    InvalidParams(String),
    /// The polynomial is malformed (coefficient count, non-finite numbers, scale ≤ 0, degree).
    #[error("invalid polynomial: {0}")]
    InvalidPolynomial(String),
    /// The region is empty, flat or not finite; give a box with positive extent on every axis.
    #[error("the slicing region must be finite with positive extent on every axis")]
    InvalidRegion,
    /// The exact method found no zero set in the (grown) region; use a region that contains the
    /// surface, or `--distance taubin`.
    #[error("the zero set of the polynomial does not cross the slicing region (grown by 25%); use a region around the surface or the taubin distance")]
    NoSurface,
}

/// Computes the K slices of the signed distance of `poly` across `region`.
///
/// ```
/// use stablesurf::cloud::Aabb;
/// use stablesurf::distance::{slices, DistanceMethod, SliceParams};
/// use stablesurf::ImplicitPolynomial;
/// // The unit sphere: f = x² + y² + z² − 1.
/// let mut c = vec![0.0; 10];
/// (c[0], c[4], c[7], c[9]) = (-1.0, 1.0, 1.0, 1.0);
/// let sphere = ImplicitPolynomial { degree: 2, coefficients: c, center: [0.0; 3], scale: 1.0 };
/// let region = Aabb { min: [-1.5; 3], max: [1.5; 3] };
/// let params = SliceParams { count: 3, resolution: 8, ..Default::default() };
/// let s = slices(&sphere, &region, &params).unwrap();
/// assert_eq!((s.len(), s[1].data.len()), (3, 64));
/// let p = s[1].pixel_center(3, 4);
/// let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
/// assert!((s[1].data[4 * 8 + 3] as f64 - (r - 1.0)).abs() < 1e-6);
/// ```
///
/// # Errors
/// [`DistanceError::InvalidParams`] for a count of 0 or a resolution outside 2 ..= 16384;
/// [`DistanceError::InvalidPolynomial`], [`DistanceError::InvalidRegion`]; and, for the exact
/// method, [`DistanceError::NoSurface`] when no zero set crosses the grown region.
pub fn slices(
    poly: &ImplicitPolynomial,
    region: &Aabb,
    params: &SliceParams,
) -> Result<Vec<Slice>, DistanceError> {
    check_params(params)?;
    check_region(region)?;
    let eval = Evaluator::new(poly)?;
    let clamp = region.diagonal();
    match params.method {
        DistanceMethod::Exact => {
            let exact = ExactDistance::with_evaluator(eval, region)?;
            // Along a row, each pixel's closest-point search is warm-started from the previous
            // pixel's foot point (the row is one task, so the result does not depend on threads).
            // The foot point moves smoothly along a row, so the start is extrapolated from the
            // last three feet (a parabola) when they are close, else from the last two (a line):
            // one Newton step fewer. On the bunny model's 4 × 128² slices the parabola took the
            // Hessians from 1.35 to 1.09 per pixel; 365 of 262,144 values of the 16 × 128²
            // slices moved, by one float32 step (both within the output's precision).
            Ok(fill_grid(region, params, |row| {
                let mut feet: [Option<[f64; 3]>; 3] = [None, None, None];
                // The row's pixels share their v and w coordinates: f's inner sums are computed
                // once per row, and the previous pixel's nearest seeds bound the seed search.
                let line = row
                    .first()
                    .map(|&p| exact.eval.line(exact.eval.normalize(p)));
                let mut near = NearSeeds::default();
                row.iter()
                    .map(|&p| {
                        let start = match feet {
                            [Some(a), Some(b), Some(c)]
                                if dist(a, b) < exact.cell && dist(b, c) < exact.cell =>
                            {
                                Some([0, 1, 2].map(|k| 3.0 * (c[k] - b[k]) + a[k]))
                            }
                            [_, Some(a), Some(b)] if dist(a, b) < exact.cell => {
                                Some([0, 1, 2].map(|c| 2.0 * b[c] - a[c]))
                            }
                            [_, _, b] => b,
                        };
                        let (d, x) = exact.distance_from(p, start, line.as_ref(), &mut near);
                        feet = [feet[1], feet[2], x];
                        d as f32
                    })
                    .collect()
            }))
        }
        DistanceMethod::Taubin => Ok(fill_grid(region, params, |row| {
            row.iter().map(|&p| eval.taubin(p, clamp) as f32).collect()
        })),
        DistanceMethod::Mesh => Err(DistanceError::InvalidParams(
            "the mesh distance needs the model's mesh (slices_from_mesh)".into(),
        )),
    }
}

/// Computes the K slices of the signed distance to `mesh` across `region`
/// ([`DistanceMethod::Mesh`]): the unsigned distance to the triangles around the nearest mesh
/// vertex (`crate::measure::GridMeshDistance`), signed by `f` (negative where f < 0). `mesh` is
/// the polygonized zero set of `f`; any [`ImplicitFunction`] works, so this also serves models
/// that are not one polynomial. `params.method` is ignored (the slices record `Mesh`).
///
/// ```
/// use stablesurf::cloud::Aabb;
/// use stablesurf::distance::{slices_from_mesh, SliceParams};
/// use stablesurf::polygonize::{polygonize, PolygonizeParams};
/// use stablesurf::ImplicitPolynomial;
/// let mut c = vec![0.0; 10];
/// (c[0], c[4], c[7], c[9]) = (-1.0, 1.0, 1.0, 1.0);
/// let sphere = ImplicitPolynomial { degree: 2, coefficients: c, center: [0.0; 3], scale: 1.0 };
/// let region = Aabb { min: [-1.5; 3], max: [1.5; 3] };
/// let mesh = polygonize(&sphere, &region, &PolygonizeParams { depth: 6, ..Default::default() })?.mesh;
/// let params = SliceParams { count: 3, resolution: 16, ..Default::default() };
/// let s = slices_from_mesh(&sphere, &mesh, &region, &params).unwrap();
/// let p = s[1].pixel_center(5, 9);
/// let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
/// // Within the mesh's chord error of the true distance (cells of 3/64).
/// assert!((s[1].data[9 * 16 + 5] as f64 - (r - 1.0)).abs() < 2e-3);
/// # Ok::<(), stablesurf::polygonize::PolygonizeError>(())
/// ```
///
/// # Errors
/// [`DistanceError::InvalidParams`] for a bad count or resolution, [`DistanceError::InvalidRegion`],
/// and [`DistanceError::NoSurface`] when the mesh has no triangles.
pub fn slices_from_mesh<F: ImplicitFunction + ?Sized>(
    f: &F,
    mesh: &TriangleMesh,
    region: &Aabb,
    params: &SliceParams,
) -> Result<Vec<Slice>, DistanceError> {
    check_params(params)?;
    check_region(region)?;
    let index = GridMeshDistance::new(mesh).ok_or(DistanceError::NoSurface)?;
    let params = SliceParams {
        method: DistanceMethod::Mesh,
        ..*params
    };
    // Warm-started along each row from the previous pixel's closest vertex (one task per row,
    // so the result does not depend on the thread count). The sign needs f only where it can
    // change: if f differs in sign at two neighbouring pixels h apart, its zero set crosses the
    // segment between them, and that crossing lies within the mesh's chord error e of the mesh,
    // so d_prev + d ≤ h + 2e. Elsewhere the previous pixel's sign carries over (e is bounded
    // generously by a seed cell).
    let [u, v, _] = params.axis.frame();
    let h = (region.max[u] - region.min[u]).max(region.max[v] - region.min[v])
        / params.resolution as f64;
    let margin = h + 2.0 * index.seed_cell();
    Ok(fill_grid(region, &params, |row| {
        let mut warm = None;
        let mut previous: Option<(f64, bool)> = None;
        row.iter()
            .map(|&p| {
                let (d, vertex) = index.distance_from(p, warm);
                warm = Some(vertex);
                let inside = match previous {
                    Some((d_prev, inside)) if d_prev + d > margin => inside,
                    _ => f.value(p) < 0.0,
                };
                previous = Some((d, inside));
                (if inside { -d } else { d }) as f32
            })
            .collect()
    }))
}

fn check_params(params: &SliceParams) -> Result<(), DistanceError> {
    if params.count == 0 {
        return Err(DistanceError::InvalidParams(
            "the slice count must be at least 1".into(),
        ));
    }
    if !(2..=16384).contains(&params.resolution) {
        return Err(DistanceError::InvalidParams(format!(
            "the slice resolution must be between 2 and 16384 pixels, not {}",
            params.resolution
        )));
    }
    Ok(())
}

/// Lays the K×R×R pixel grid over `region` (see the module docs) and fills it row by row:
/// `row` gets the centres of one row's pixels in column order and returns their distances. One
/// rayon task per (slice, row), so the result does not depend on the thread count.
fn fill_grid(
    region: &Aabb,
    params: &SliceParams,
    row: impl Fn(&[[f64; 3]]) -> Vec<f32> + Sync,
) -> Vec<Slice> {
    let [u, v, w] = params.axis.frame();
    let r = params.resolution;
    let k_count = params.count;
    let extent = |a: usize| region.max[a] - region.min[a];
    let h = extent(u).max(extent(v)) / r as f64;
    let spacing = extent(w) / k_count as f64;
    let center = region.center();
    let half = r as f64 / 2.0;

    let rows: Vec<Vec<f32>> = (0..k_count * r)
        .into_par_iter()
        .map(|task| {
            let (k, i) = (task / r, task % r);
            let mut p = [0.0; 3];
            p[w] = region.min[w] + (k as f64 + 0.5) * spacing;
            p[v] = center[v] + (half - i as f64 - 0.5) * h;
            let centres: Vec<[f64; 3]> = (0..r)
                .map(|col| {
                    p[u] = center[u] + (col as f64 + 0.5 - half) * h;
                    p
                })
                .collect();
            row(&centres)
        })
        .collect();

    let mut out = Vec::with_capacity(k_count);
    let mut rows = rows.into_iter();
    for k in 0..k_count {
        let mut data = Vec::with_capacity(r * r);
        for row in rows.by_ref().take(r) {
            data.extend_from_slice(&row);
        }
        let mut m = [[0.0; 4]; 4];
        m[u][0] = h;
        m[v][1] = -h;
        m[w][2] = spacing;
        m[u][3] = center[u] + (0.5 - half) * h;
        m[v][3] = center[v] + (half - 0.5) * h;
        m[w][3] = region.min[w] + 0.5 * spacing;
        m[3][3] = 1.0;
        out.push(Slice {
            index: k,
            count: k_count,
            axis: params.axis,
            method: params.method,
            resolution: r,
            data,
            grid_to_world: m,
            voxel_size: [h, h, spacing],
        });
    }
    out
}

/// Taubin's first-order signed distance f/|∇f| at `p`, input units. Where ∇f = 0 the result is
/// ±infinity (0 when f = 0 too); [`slices`] clamps it to the region's diagonal.
///
/// # Errors
/// [`DistanceError::InvalidPolynomial`] when `poly` is malformed.
#[cfg(test)] // only the unit tests call it
pub(crate) fn taubin_distance(
    poly: &ImplicitPolynomial,
    p: [f64; 3],
) -> Result<f64, DistanceError> {
    Ok(Evaluator::new(poly)?.taubin(p, f64::INFINITY))
}

fn check_region(region: &Aabb) -> Result<(), DistanceError> {
    let ok = (0..3).all(|a| {
        let e = region.max[a] - region.min[a];
        region.min[a].is_finite() && region.max[a].is_finite() && e > 0.0 && e.is_finite()
    });
    if ok {
        Ok(())
    } else {
        Err(DistanceError::InvalidRegion)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poly::n_coefficients;

    /// The sphere of radius `r` around `c`, fitted-style: normalized by `scale`.
    fn sphere(c: [f64; 3], r: f64, scale: f64) -> ImplicitPolynomial {
        let rn = r / scale;
        let mut coefficients = vec![0.0; 10];
        coefficients[0] = -rn * rn;
        coefficients[4] = 1.0;
        coefficients[7] = 1.0;
        coefficients[9] = 1.0;
        ImplicitPolynomial {
            degree: 2,
            coefficients,
            center: c,
            scale,
        }
    }

    /// (x² + y² + z² + R² − r²)² − 4R²(x² + y²): a torus around z, degree 4.
    pub(super) fn torus(big: f64, small: f64) -> ImplicitPolynomial {
        let mut c = vec![0.0; n_coefficients(4)];
        let mut add = |e: [u32; 3], a: f64| c[crate::poly::monomial_index(e)] += a;
        let k = big * big - small * small;
        // (s + k)² − 4R²(x² + y²) with s = x² + y² + z².
        for (e1, e2) in [
            ([2, 0, 0], [2, 0, 0]),
            ([0, 2, 0], [0, 2, 0]),
            ([0, 0, 2], [0, 0, 2]),
        ] {
            add([e1[0] + e2[0], e1[1] + e2[1], e1[2] + e2[2]], 1.0);
        }
        add([2, 2, 0], 2.0);
        add([2, 0, 2], 2.0);
        add([0, 2, 2], 2.0);
        for e in [[2, 0, 0], [0, 2, 0], [0, 0, 2]] {
            add(e, 2.0 * k);
        }
        add([0, 0, 0], k * k);
        add([2, 0, 0], -4.0 * big * big);
        add([0, 2, 0], -4.0 * big * big);
        ImplicitPolynomial {
            degree: 4,
            coefficients: c,
            center: [0.0; 3],
            scale: 1.0,
        }
    }

    /// The torus (R 1, r 0.4), a box around it and its mesh at depth 6 (edges up to a cell
    /// diagonal, √3·0.05).
    fn torus_mesh() -> (ImplicitPolynomial, Aabb, TriangleMesh) {
        let poly = torus(1.0, 0.4);
        let region = Aabb {
            min: [-1.6, -1.6, -0.6],
            max: [1.6, 1.6, 0.6],
        };
        let params = crate::polygonize::PolygonizeParams {
            depth: 6,
            ..Default::default()
        };
        let mesh = crate::polygonize::polygonize(&poly, &region, &params)
            .unwrap()
            .mesh;
        (poly, region, mesh)
    }

    #[test]
    fn mesh_distance_slices_match_analytic_torus() {
        // Every pixel of a slice stack through the torus (medial circle included) against the
        // analytic distance: within the mesh's chord error. Edges are at most a cell diagonal
        // e = √3·0.05 long; their sagitta on the tube of radius 0.4 is e²/(8·0.4) ≈ 2.3e-3.
        let (big, small) = (1.0, 0.4);
        let (poly, region, mesh) = torus_mesh();
        let params = SliceParams {
            axis: Axis::Z,
            count: 5,
            resolution: 48,
            method: DistanceMethod::Mesh,
        };
        let stack = slices_from_mesh(&poly, &mesh, &region, &params).unwrap();
        let mut worst: f64 = 0.0;
        for s in &stack {
            assert_eq!(s.method, DistanceMethod::Mesh);
            for row in 0..48 {
                for col in 0..48 {
                    let p = s.pixel_center(col, row);
                    let rho = (p[0] * p[0] + p[1] * p[1]).sqrt();
                    let truth = ((rho - big).powi(2) + p[2] * p[2]).sqrt() - small;
                    worst = worst.max((s.data[row * 48 + col] as f64 - truth).abs());
                }
            }
        }
        assert!(worst < 2.5e-3, "worst error {worst}");
        // Without a mesh the method is refused.
        assert!(matches!(
            slices(&poly, &region, &params),
            Err(DistanceError::InvalidParams(_))
        ));
    }

    #[test]
    fn mesh_distance_slices_match_every_triangle() {
        // The mesh distance against the distance to every triangle of the same mesh, at every
        // third pixel of slices through a torus polygonized with slivers: never below it (it is
        // the distance to some triangle), equal to it (1e-6 relative, float32) at 99.5% of the
        // pixels, and never off by more than 2e-4 (edges are up to 0.087 long). Measuring only
        // the fan unless its closest point lies on its rim fails this (36 of 2136 off, by up to
        // 6.2e-4, near the tube's axis, where the facets make many local minima).
        let (poly, region, mesh) = torus_mesh();
        let params = SliceParams {
            axis: Axis::Y,
            count: 4,
            resolution: 40,
            method: DistanceMethod::Mesh,
        };
        let stack = slices_from_mesh(&poly, &mesh, &region, &params).unwrap();
        let (mut checked, mut off, mut worst) = (0, 0, 0f64);
        for s in &stack {
            for pixel in (0..40 * 40).step_by(3) {
                let p = s.pixel_center(pixel % 40, pixel / 40);
                let truth = mesh
                    .triangles
                    .iter()
                    .map(|t| {
                        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
                        dist(p, crate::measure::closest_point_on_triangle(p, a, b, c))
                    })
                    .fold(f64::INFINITY, f64::min);
                let got = f64::from(s.data[pixel].abs());
                // float32 output: 1e-6 relative covers its rounding.
                assert!(got >= truth * (1.0 - 1e-6), "{got} below {truth} at {p:?}");
                checked += 1;
                if got > truth * (1.0 + 1e-6) + 1e-9 {
                    off += 1;
                    worst = worst.max(got - truth);
                }
            }
        }
        assert!(off * 200 <= checked, "{off} of {checked} off");
        assert!(worst < 2e-4, "worst {worst}");
    }

    #[test]
    fn taubin_is_second_order_accurate_on_sphere() {
        let s = sphere([1.0, -2.0, 0.5], 2.0, 0.8);
        for d in [-0.01, 0.001, 0.02] {
            let p = [1.0 + (2.0 + d) * 0.6, -2.0, 0.5 + (2.0 + d) * 0.8];
            let t = taubin_distance(&s, p).unwrap();
            // f/|∇f| − d = −d²/(2(r + d)).
            assert!(
                (t - (d - d * d / (2.0 * (2.0 + d)))).abs() < 1e-12,
                "{t} at {d}"
            );
        }
    }

    #[test]
    fn slice_geometry_and_errors() {
        let s = sphere([0.0; 3], 1.0, 1.0);
        let region = Aabb {
            min: [-2.0, -1.0, 0.0],
            max: [2.0, 1.0, 1.0],
        };
        let params = SliceParams {
            axis: Axis::Y,
            count: 2,
            resolution: 4,
            method: DistanceMethod::Taubin,
        };
        let out = slices(&s, &region, &params).unwrap();
        // Pixels are 1 × 1 (x extent 4 / 4); slices at y = −0.5 and 0.5; row 0 at the top (z max).
        assert_eq!(out[0].voxel_size, [1.0, 1.0, 1.0]);
        assert_eq!(out[0].pixel_center(0, 0), [-1.5, -0.5, 2.0]);
        assert_eq!(out[1].pixel_center(3, 3), [1.5, 0.5, -1.0]);
        let bad = |p: SliceParams| slices(&s, &region, &p).unwrap_err();
        assert!(matches!(
            bad(SliceParams { count: 0, ..params }),
            DistanceError::InvalidParams(_)
        ));
        assert!(matches!(
            bad(SliceParams {
                resolution: 1,
                ..params
            }),
            DistanceError::InvalidParams(_)
        ));
        let flat = Aabb {
            min: [0.0; 3],
            max: [1.0, 1.0, 0.0],
        };
        assert_eq!(
            slices(&s, &flat, &params).unwrap_err(),
            DistanceError::InvalidRegion
        );
        let far = Aabb {
            min: [10.0; 3],
            max: [11.0; 3],
        };
        let exact = SliceParams {
            method: DistanceMethod::Exact,
            ..params
        };
        assert_eq!(
            slices(&s, &far, &exact).unwrap_err(),
            DistanceError::NoSurface
        );
    }

    #[test]
    fn slices_do_not_depend_on_thread_count() {
        let t = torus(1.0, 0.3);
        let region = Aabb {
            min: [-1.5, -1.5, -0.5],
            max: [1.5, 1.5, 0.5],
        };
        let params = SliceParams {
            count: 2,
            resolution: 24,
            ..Default::default()
        };
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let a = one.install(|| slices(&t, &region, &params).unwrap());
        let b = slices(&t, &region, &params).unwrap();
        assert_eq!(a, b);
    }
}
