//! Stage `fit` in detail mode: an [`OrientedCloud`] → [`MpuModel`], a multi-level partition of
//! unity of local low-degree ridge-regression fits (value and gradient rows by default, the 3L
//! rows of the paper on request: [`LocalConstraints`]), for scans whose fine detail one global
//! polynomial cannot carry.
//!
//! Input: points with unit outward normals (input coordinates) and [`DetailParams`]. Output: an
//! [`MpuModel`], f = Σ wᵢQᵢ / Σ wᵢ (f < 0 inside, f > 0 outside, ≈ signed distance in input
//! units near the data), which implements [`ImplicitFunction`] so that
//! [`crate::polygonize::polygonize`] meshes it over [`MpuModel::region`].
//!
//! Invariants: every leaf cell of the octree carries one ball and one local polynomial with
//! finite coefficients; the balls cover the root cube, hence the meshing region, so Σ wᵢ > 0
//! there; where no ball reaches (outside the root cube) f is the positive constant
//! [`MpuModel::diagonal`]; the model is a deterministic function of the input and the params,
//! whatever the thread count (children are fitted in parallel but collected in a fixed order).
//!
//! # Algorithm (Ohtake, Belyaev, Alexa, Turk & Seidel, *Multi-level partition of unity
//! implicits*, SIGGRAPH 2003, with the local fits of Sahin & Unel 2008)
//!
//! ```text
//! root cube: side 1.2 × the data's largest extent, centred on the data box
//! cell (side h) ── ball: centre = cell centre, R = 0.75·√3·h
//!   │               no point in the ball (a child off the surface)?
//!   │                 → the parent's local function, unchanged: no fit (see below)
//!   │               fewer than N_min = max(15, ⌈1.2·c⌉) points in the ball, or fewer
//!   │               than 24 with normals that fold (two facing sheets)?
//!   │                 → fit the N_min nearest points instead (the "grown" ball), at degree ≤ 2
//!   │                   (a plane when the ball held fewer than 5 points: a hole, empty space),
//!   │                   and never split; the weight keeps the support R
//!   ├─ local fit on the ball's points: Q = 0 and ∇Q = n (or 3L), ridge κD, auxiliary rows
//!   │    (see below), constant re-centred on the data; a ball of more than
//!   │    SUBSAMPLE_ABOVE = 1024 points is fitted on an even subsample of
//!   │    SUBSAMPLE_POINTS = 512 of them (`local.rs`), its error still measured on all
//!   ├─ max |Q|/|∇Q| over the ball's points > tolerance · diagonal and depth < max_depth
//!   │    → split into 8 children (each child's ball lies inside its parent's)
//!   └─ otherwise → leaf: (ball, Q) joins the blend
//! ```
//!
//! Safeguards against spurious pieces: every cell's centre and
//! corners become auxiliary rows whose target is the mean tangent-plane distance nⱼ·(q − pⱼ) of
//! the 6 nearest data points, kept only where those 6 agree in sign (MPU's off-surface points);
//! grown cells are fitted at degree 2 at most and never subdivided; the local ridge κ ≈ 1e-2
//! keeps each local fit tame away from its data (with gradient rows it leaves the constant term
//! free, and the constant is re-centred on the data afterwards, so that neither the ridge nor
//! the auxiliary rows offset the zero set: see `local.rs`).
//!
//! Empty children: a split cell's children off the surface hold no point in their balls (on
//! the bunny, 34,101 of its 87,648 leaves). Their balls are still needed, so that the blend
//! covers the root cube and keeps its sign away from the data, but there the parent's local
//! function (fitted to the data in the parent's ball, which holds the child's) is as good a
//! far-field estimate as a plane fitted to the child's 15 nearest points, and costs no search
//! and no fit (its measurement against that plane is in CHANGELOG.md).
//!
//! Blend weights: wᵢ(p) = b(3|p − cᵢ|/(2Rᵢ)), b the quadratic B-spline (see `index`).
//!
//! Cost on dense scans: the fit works on the points in Z (Morton) order, so a ball's points lie
//! close together in memory; a parent hands each child its ball in one pass over its own (the
//! root's children, whose balls hold most points, each find theirs when they start); a
//! cell that may split stops measuring its error once it exceeds the tolerance; the
//! subsample above caps the rows of a fit; and the nearest points of a grown cell and of an
//! auxiliary point come from a scan of the cell's, its parent's or its grandparent's ball when
//! that ball provably holds them (triangle inequality), from the k-d tree otherwise (the same
//! points up to the order of exactly equal distances).
//! Points far finer than the cells need are fitted at a stride ([`DetailParams::stride`]: every
//! k-th along the Z-order curve, which `run` picks from the points per cell of the mesh); the
//! residual diagnostics still measure every point. There `run` also refits the deepest cells
//! whose quadric misses the tolerance as cubics ([`DetailParams::refit_deepest`]).

mod chamfer;
mod exterior;
mod index;
mod local;
mod model;

pub use chamfer::{chamfer_distance, ChamferDistance};
pub(crate) use index::BallIndex;

pub use model::{
    AuxiliaryPoints, DetailDiagnostics, DetailError, DetailParams, LocalConstraints, MpuCell,
    MpuModel,
};
pub(crate) use model::{NOISE_MARGIN, NOISE_POINTS_PER_COEFFICIENT, ROBUST_CUTOFF};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cloud::{Aabb, OrientedCloud};
use crate::implicit::ImplicitFunction;
use crate::numerics::point_tree::{insert_nearest, PointTree};
use crate::poly::{n_coefficients, ImplicitPolynomial};
use crate::vec3;
use crate::vec3::dist2;

use local::{
    even_subsample, fit_local, AuxPoint, Constraints, LocalFit, RowWeights, SUBSAMPLE_ABOVE,
};

/// Version of this stage's algorithm; if you change any input to its cache key or anything
/// that changes its output for the same input and params, bump it.
pub(crate) const STAGE_VERSION: u32 = 11;

/// Levels near the root whose children are fitted in parallel (8³ tasks at most).
const PARALLEL_LEVELS: u32 = 3;

/// Levels whose children find their own points in their parent's ball when their task starts,
/// instead of all eight at once (see [`visit`]): at the root, each child's ball holds most of
/// the points (less peak memory, the same CPU time and model; CHANGELOG.md).
const LAZY_BALL_LEVELS: u32 = 1;

/// A grown cell whose own ball held fewer points than this lies over a hole or in empty space;
/// it is fitted with a plane, which closes a hole flat rather than carrying the rim's curvature
/// across it.
const PLANE_BELOW: usize = 5;

/// A ball whose normals fold (some point's normal at 90° or more from their sum: two sheets
/// facing each other across a thin gap, or a sharp crease) is fitted on its own and may be split
/// only when it holds at least this many points (1.2 × the 20 coefficients of a cubic); with
/// fewer it is treated as a grown cell: fitted at degree ≤ 2 to the `N_min` points nearest its
/// centre, and never split. A quadric fitted to the 15–23 points of a folded ball, and its
/// children fitted the same way, could join the two sheets by a bridge that no data point sees
/// (where a tube passes close to itself). At local degree 3 or 4, `N_min` (24 or 42) already
/// covers the rule.
const FOLD_MIN_POINTS: usize = 24;

/// `values[order[0]]`, `values[order[stride]]`, `values[order[2·stride]]`, …
fn gather<T: Copy>(values: &[T], order: &[u32], stride: usize) -> Vec<T> {
    order
        .iter()
        .step_by(stride)
        .map(|&i| values[i as usize])
        .collect()
}

/// Whether some normal of `ball` points 90° or more away from the sum of them all (every normal
/// does when they cancel out).
fn normals_fold(normals: &[[f64; 3]], ball: &[u32]) -> bool {
    let mut sum = [0.0f64; 3];
    for &i in ball {
        let n = normals[i as usize];
        for a in 0..3 {
            sum[a] += n[a];
        }
    }
    ball.iter().any(|&i| {
        let n = normals[i as usize];
        n[0] * sum[0] + n[1] * sum[1] + n[2] * sum[2] <= 0.0
    })
}

/// Nearest data points used to estimate an auxiliary point's signed distance.
const AUX_NEIGHBOURS: usize = 6;

/// Shared read-only state of one fit.
struct Ctx<'a> {
    points: &'a [[f64; 3]],
    normals: &'a [[f64; 3]],
    /// Per-point confidence weighing the point's rows in the local fits (`None`: 1).
    weights: Option<&'a [f32]>,
    tree: PointTree,
    params: &'a DetailParams,
    diagonal: f64,
    n_min: usize,
    n_min_grown: usize,
    /// Lower corner of the root cube.
    origin: [f64; 3],
    /// Lattice unit: the root side / 2^(max_depth + 1), so that every cell's centre and
    /// corners have integer coordinates.
    unit: f64,
}

/// Estimated signed distances of auxiliary points already computed in one subtree, by lattice
/// key (`None`: the 6 neighbours disagreed). The estimate depends only on the point, so sharing
/// it between the cells that have it as centre or corner changes nothing but the cost.
type AuxCache = std::collections::HashMap<u128, Option<f64>, BuildLatticeHasher>;

/// A multiplicative hash for lattice keys (the default SipHash is slower than needed here).
#[derive(Clone, Copy, Default)]
struct BuildLatticeHasher;

/// The hasher of [`BuildLatticeHasher`].
#[derive(Default)]
struct LatticeHasher(u64);

impl std::hash::Hasher for LatticeHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(8) ^ u64::from(b)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
    }
    fn write_u128(&mut self, v: u128) {
        let folded = (v as u64) ^ ((v >> 64) as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
        self.0 = (folded ^ (folded >> 29)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        self.0 ^= self.0 >> 32;
    }
}

impl std::hash::BuildHasher for BuildLatticeHasher {
    type Hasher = LatticeHasher;
    fn build_hasher(&self) -> LatticeHasher {
        LatticeHasher::default()
    }
}

/// What a subtree of the octree produced.
#[derive(Default)]
struct Part {
    cells: Vec<MpuCell>,
    fitted: usize,
    aux_kept: usize,
    aux_dropped: usize,
    max_local_error: f64,
    error: Option<DetailError>,
}

impl Part {
    fn append(&mut self, other: Part) {
        let Part {
            mut cells,
            fitted,
            aux_kept,
            aux_dropped,
            max_local_error,
            error,
        } = other;
        self.cells.append(&mut cells);
        self.fitted += fitted;
        self.aux_kept += aux_kept;
        self.aux_dropped += aux_dropped;
        self.max_local_error = self.max_local_error.max(max_local_error);
        if self.error.is_none() {
            self.error = error;
        }
    }
}

/// Fits the detail model.
///
/// # Errors
/// [`DetailError::TooFewPoints`], [`DetailError::NonFinite`], [`DetailError::LengthMismatch`],
/// [`DetailError::Degenerate`], [`DetailError::InvalidParams`], and
/// [`DetailError::LocalFit`] when a local system is singular (only possible with κ = 0).
///
/// ```
/// use stablesurf::detail::{fit_detail, DetailParams};
/// use stablesurf::testing::study::{sample, Shape, Variant};
/// use stablesurf::implicit::ImplicitFunction;
/// let cloud = sample(Shape::Sphere, Variant::Clean, 500, 1);
/// let model = fit_detail(&cloud, &DetailParams::default()).unwrap();
/// assert!(model.value([0.0, 0.0, 0.0]) < 0.0); // inside
/// assert!(model.value([1.5, 0.0, 0.0]) > 0.0); // outside
/// assert!((model.value([1.1, 0.0, 0.0]) - 0.1).abs() < 0.02); // ≈ signed distance
/// ```
pub fn fit_detail(cloud: &OrientedCloud, params: &DetailParams) -> Result<MpuModel, DetailError> {
    validate_params(params)?;
    let n = cloud.points.len();
    if cloud.normals.len() != n {
        return Err(DetailError::LengthMismatch {
            n_points: n,
            n_normals: cloud.normals.len(),
        });
    }
    if let Some(w) = &cloud.weights
        && (w.len() != n || w.iter().any(|&x| !(x.is_finite() && x > 0.0)))
    {
        return Err(DetailError::InvalidParams(format!(
            "the cloud has {} confidence weights for {n} points (each must be finite and \
                 positive); give one per point or none",
            w.len()
        )));
    }
    let n_min = ((1.2 * n_coefficients(params.degree) as f64).ceil() as usize).max(15);
    let n_min_grown = ((1.2 * n_coefficients(params.degree.min(2)) as f64).ceil() as usize).max(15);
    if n < n_min {
        return Err(DetailError::TooFewPoints {
            n_points: n,
            min: n_min,
        });
    }
    for (i, (p, nv)) in cloud.points.iter().zip(&cloud.normals).enumerate() {
        let len2 = nv[0] * nv[0] + nv[1] * nv[1] + nv[2] * nv[2];
        if p.iter().chain(nv).any(|v| !v.is_finite()) || (len2 - 1.0).abs() > 1e-3 {
            return Err(DetailError::NonFinite { index: i });
        }
    }
    let data_box = Aabb::from_points(&cloud.points).ok_or(DetailError::Degenerate)?;
    let diagonal = data_box.diagonal();
    let extent = (0..3)
        .map(|a| data_box.max[a] - data_box.min[a])
        .fold(0.0, f64::max);
    if !(extent > 0.0 && diagonal.is_finite()) {
        return Err(DetailError::Degenerate);
    }
    let side = 1.2 * extent;
    let center = data_box.center();
    let root = Aabb {
        min: center.map(|c| c - 0.5 * side),
        max: center.map(|c| c + 0.5 * side),
    };
    // Every stride-th point is fitted: at least `n_min` of them.
    let stride = params.stride as usize;
    let n_fit = n.div_ceil(stride);
    if n_fit < n_min {
        return Err(DetailError::InvalidParams(format!(
            "a stride of {stride} leaves {n_fit} of the {n} points, fewer than the {n_min} a fit \
             needs; choose a stride of at most {}",
            (n - 1) / (n_min - 1)
        )));
    }
    // Noisy points: enough of them in every fit to average the noise (at most all of them).
    let n_min = n_min.max(noise_points(params, params.degree)).min(n_fit);
    let n_min_grown = n_min_grown
        .max(noise_points(params, params.degree.min(2)))
        .min(n_fit);
    // The fit reads the points in Z order (`point_tree::spatial_order`): the points of a ball are
    // then close together in memory, and the passes over large balls read them nearly in
    // sequence instead of at random (a scan's file order is often arbitrary).
    let order = crate::numerics::point_tree::spatial_order(&cloud.points);
    // The points fitted: every stride-th of that order (all of them at stride 1), gathered
    // straight from the input; and the sample the residual diagnostics measure, every k-th of
    // the whole order as the export's accuracy measures (1M-point torus: this diagnostic was 8%
    // of the run's CPU over all the points).
    let fit_points = gather(&cloud.points, &order, stride);
    let mut fit_normals = gather(&cloud.normals, &order, stride);
    let fit_weights = cloud.weights.as_ref().map(|w| gather(w, &order, stride));
    let sampled = gather(
        &cloud.points,
        &order,
        crate::measure::kth_step(n, crate::measure::ACCURACY_POINTS),
    );
    drop(order);
    let tree = PointTree::new(&fit_points).ok_or_else(|| {
        DetailError::InvalidParams(format!("cannot index {n} points (at most 2^32 − 1)"))
    })?;
    // Noisy data: normals whose line reaches the empty space around a closed object sooner on
    // their inner side are turned to it (`exterior.rs`: a patch flipped by the orientation at a
    // part a few σ thin would otherwise grow a tube of inside out to the meshing box).
    let exterior_flipped = if params.noise > 0.0 {
        let gap = exterior::sampling_gap(&fit_points, &tree);
        exterior::orient_by_exterior(&fit_points, &mut fit_normals, params.noise * diagonal, gap)
    } else {
        0
    };
    // Noisy data: the normals of the second fit, from the first fit's gradient.
    let refitted_normals: Vec<[f64; 3]>;
    let mut ctx = Ctx {
        points: &fit_points,
        normals: &fit_normals,
        weights: fit_weights.as_deref(),
        tree,
        params,
        diagonal,
        n_min,
        n_min_grown,
        origin: root.min,
        unit: side / f64::from(1u32 << (params.max_depth + 1)),
    };
    let region = data_box.grown(0.1);
    let mut part = fit_octree(&ctx)?;
    // Noisy data: plane-fit normals scatter and tilt where the surface curves within their
    // neighbourhood (a nose tip, a thin edge), and the 3L rows at p ± εn carry that error into
    // the fit; the blend of the first fit averages it over many points. Its gradient is
    // therefore a better normal, and the fit is repeated with it (as iterative Poisson
    // reconstruction re-estimates its normals from its own field).
    let mut reoriented = 0;
    if params.noise > 0.0 {
        let first = MpuModel::new(
            region,
            root,
            diagonal,
            part.cells,
            DetailDiagnostics::default(),
        );
        (refitted_normals, reoriented) = gradient_normals(&first, &fit_points, &fit_normals);
        ctx.normals = &refitted_normals;
        part = fit_octree(&ctx)?;
    }
    let grown_cells = part.cells.iter().filter(|c| c.grown).count();
    let depth_reached = part.cells.iter().map(|c| c.level).max().unwrap_or(0);
    let diagnostics = DetailDiagnostics {
        points: n,
        cells: part.cells.len(),
        fitted_cells: part.fitted,
        grown_cells,
        depth_reached,
        auxiliary_kept: part.aux_kept,
        auxiliary_dropped: part.aux_dropped,
        max_residual: 0.0,
        mean_residual: 0.0,
        max_local_error: part.max_local_error / diagonal,
        reoriented_normals: reoriented,
        exterior_flipped,
    };
    let mut model = MpuModel::new(region, root, diagonal, part.cells, diagnostics);
    let (max_residual, mean_residual) = data_residuals(&model, &sampled);
    model.diagnostics.max_residual = max_residual / diagonal;
    model.diagnostics.mean_residual = mean_residual / diagonal;
    Ok(model)
}

fn validate_params(params: &DetailParams) -> Result<(), DetailError> {
    let bad = |m: String| Err(DetailError::InvalidParams(m));
    if !(2..=4).contains(&params.degree) {
        return bad(format!("degree is {}, choose 2, 3 or 4", params.degree));
    }
    for (name, v) in [
        ("tolerance", params.tolerance),
        ("finest_tolerance", params.finest_tolerance),
    ] {
        if !(v > 0.0 && v < 1.0) {
            return bad(format!(
                "{name} is {v}, choose a value in (0, 1), e.g. 2e-3"
            ));
        }
    }
    if params.stride == 0 {
        return bad("stride is 0, choose 1 (every point) or more".to_string());
    }
    if !(1..=20).contains(&params.max_depth) {
        return bad(format!(
            "max_depth is {}, choose a value from 1 to 20",
            params.max_depth
        ));
    }
    if !(params.epsilon > 0.0 && params.epsilon <= 2.0) {
        return bad(format!(
            "epsilon is {}, choose a value in (0, 2], e.g. 0.3",
            params.epsilon
        ));
    }
    if !(params.kappa >= 0.0 && params.kappa.is_finite()) {
        return bad(format!(
            "kappa is {}, choose a value ≥ 0, e.g. 1e-2",
            params.kappa
        ));
    }
    if !(params.support >= 0.6 && params.support <= 2.0) {
        return bad(format!(
            "support is {}, choose a value in [0.6, 2], e.g. 0.75 (below 0.5 the balls would not cover their cells)",
            params.support
        ));
    }
    Ok(())
}

/// The points a fit of `degree` needs to average the noise of [`DetailParams::noise`] down
/// to the split tolerance: c·(σ/tolerance)², at most [`NOISE_POINTS_PER_COEFFICIENT`]·c (0
/// without noise).
fn noise_points(params: &DetailParams, degree: u32) -> usize {
    if params.noise <= 0.0 {
        return 0;
    }
    let c = n_coefficients(degree) as f64;
    let ratio = params.noise / params.tolerance;
    (c * ratio * ratio)
        .min(NOISE_POINTS_PER_COEFFICIENT * c)
        .ceil() as usize
}

/// The octree of local fits over all of `ctx`'s points, from the root cube down.
fn fit_octree(ctx: &Ctx) -> Result<Part, DetailError> {
    let all: Vec<u32> = (0..ctx.points.len() as u32).collect();
    let (_, _, root_center, root_radius) = cell_geometry(ctx, [0; 3], 0);
    let [root_ball] = points_in_balls(ctx.points, &all, &[root_center], root_radius * root_radius);
    drop(all);
    let mut cache = AuxCache::default();
    let mut part = visit(ctx, [0; 3], 0, root_ball, None, [None, None], &mut cache);
    match part.error.take() {
        Some(e) => Err(e),
        None => Ok(part),
    }
}

/// The unit gradient of `model` at each of `points` (its normal in `normals` where the
/// gradient vanishes or is not finite), and how many of them point against the normal given.
fn gradient_normals(
    model: &MpuModel,
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
) -> (Vec<[f64; 3]>, usize) {
    let out: Vec<([f64; 3], bool)> = points
        .par_iter()
        .zip(normals)
        .map(|(&p, &n)| {
            let (_, g) = model.value_gradient(p);
            let len = vec3::norm(g);
            if len > 0.0 && len.is_finite() {
                let u = g.map(|c| c / len);
                (u, vec3::dot(u, n) < 0.0)
            } else {
                (n, false)
            }
        })
        .collect();
    let flipped = out.iter().filter(|o| o.1).count();
    (out.into_iter().map(|o| o.0).collect(), flipped)
}

/// Largest and mean |f|/|∇f| of the blend over `points` (fixed chunks, ordered reduction).
fn data_residuals(model: &MpuModel, points: &[[f64; 3]]) -> (f64, f64) {
    let per_chunk: Vec<(f64, f64)> = points
        .par_chunks(4096)
        .map(|chunk| {
            let (mut max, mut sum): (f64, f64) = (0.0, 0.0);
            for &p in chunk {
                let (f, g) = model.value_gradient(p);
                let gn = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
                let e = if gn > 0.0 { f.abs() / gn } else { f.abs() };
                max = max.max(e);
                sum += e;
            }
            (max, sum)
        })
        .collect();
    let max = per_chunk.iter().map(|c| c.0).fold(0.0, f64::max);
    let sum: f64 = per_chunk.iter().map(|c| c.1).sum();
    (max, sum / points.len().max(1) as f64)
}

/// The geometry of the cell `coords` (integer position among the cells of its level) at
/// `level`: its centre in lattice units (exact integers), its side in lattice units, its centre
/// in input coordinates and its ball's radius.
fn cell_geometry(ctx: &Ctx, coords: [u32; 3], level: u32) -> ([u64; 3], u64, [f64; 3], f64) {
    let step = 1u64 << (ctx.params.max_depth + 1 - level);
    let lattice_center = coords.map(|c| (2 * u64::from(c) + 1) * (step / 2));
    let center = [0, 1, 2].map(|a| ctx.origin[a] + lattice_center[a] as f64 * ctx.unit);
    let side = step as f64 * ctx.unit;
    let radius = ctx.params.support * 3f64.sqrt() * side;
    (lattice_center, step, center, radius)
}

/// The points of `candidates` inside each of the balls (`centers`, radius² `r2`), in
/// `candidates`' order: one pass for all the balls, so each point is read once.
fn points_in_balls<const N: usize>(
    points: &[[f64; 3]],
    candidates: &[u32],
    centers: &[[f64; 3]; N],
    r2: f64,
) -> [Vec<u32>; N] {
    let mut out: [Vec<u32>; N] = std::array::from_fn(|_| Vec::new());
    for &i in candidates {
        let p = points[i as usize];
        for (list, &c) in out.iter_mut().zip(centers) {
            if dist2(p, c) < r2 {
                list.push(i);
            }
        }
    }
    out
}

/// Largest ball [`Cover::nearest`] scans before the k-d tree is searched instead (512 against
/// 128: the six merged raw bunny views 2.6% less CPU, the bunny 1–3%; larger not measured).
const COVER_SCAN_MAX: usize = 512;

/// A ball of the fit and every data point strictly inside it: all points at squared distance
/// below `radius2` from `center`.
#[derive(Clone, Copy)]
struct Cover<'a> {
    points: &'a [u32],
    center: [f64; 3],
    radius2: f64,
}

impl Cover<'_> {
    /// The `out.len()` nearest data points to `q` (squared distance and index, nearest first,
    /// ties in the cover's order) and their number, when the cover provably holds them: a point
    /// outside it lies at least √radius2 − |q − center| from `q` (triangle inequality), so the
    /// k nearest of its points are the k nearest of all when the k-th is nearer than that (with
    /// a relative margin of 1e-9 over the rounding of the distances). `None` when it does not,
    /// or has more than [`COVER_SCAN_MAX`] points.
    fn nearest(&self, points: &[[f64; 3]], q: [f64; 3], out: &mut [(f64, u32)]) -> Option<usize> {
        let k = out.len();
        if k == 0 || self.points.len() < k || self.points.len() > COVER_SCAN_MAX {
            return None;
        }
        let reach = (self.radius2.sqrt() - dist2(q, self.center).sqrt()) * (1.0 - 1e-9);
        if reach.is_nan() || reach <= 0.0 {
            return None;
        }
        let bound2 = reach * reach;
        let mut len = 0;
        for &i in self.points {
            let d = dist2(points[i as usize], q);
            let limit = if len == k { out[k - 1].0 } else { bound2 };
            if d < limit {
                insert_nearest(out, &mut len, d, i);
            }
        }
        (len == k).then_some(k)
    }
}

/// [`Cover::nearest`] from the first of `covers` that provably holds the answer.
fn nearest_in_covers(
    covers: &[Option<Cover>],
    points: &[[f64; 3]],
    q: [f64; 3],
    out: &mut [(f64, u32)],
) -> Option<usize> {
    covers
        .iter()
        .flatten()
        .find_map(|c| c.nearest(points, q, out))
}

/// Fits the cell `coords` (integer position among the cells of its level) at `level`, whose
/// ball holds the points `ball` (in increasing index order), and recurses; `parent_poly` is
/// the parent's local function (`None` at the root), which an empty ball takes as its own.
fn visit(
    ctx: &Ctx,
    coords: [u32; 3],
    level: u32,
    mut ball: Vec<u32>,
    parent_poly: Option<&ImplicitPolynomial>,
    ancestors: [Option<Cover<'_>>; 2],
    cache: &mut AuxCache,
) -> Part {
    let params = ctx.params;
    let (lattice_center, step, center, radius) = cell_geometry(ctx, coords, level);
    let at = |l: [u64; 3]| [0, 1, 2].map(|a| ctx.origin[a] + l[a] as f64 * ctx.unit);
    let mut fit_radius = radius;
    let mut cover_radius2 = radius * radius;
    let mut part = Part::default();
    if let Some(poly) = parent_poly
        && ball.is_empty()
    {
        part.cells.push(MpuCell {
            center,
            radius,
            fit_radius: radius,
            level,
            grown: true,
            poly: poly.clone(),
        });
        return part;
    }
    let grown = ball.len() < ctx.n_min
        || (ball.len() < FOLD_MIN_POINTS && normals_fold(ctx.normals, &ball));
    let degree = if grown {
        if ball.len() < PLANE_BELOW {
            1
        } else {
            params.degree.min(2)
        }
    } else {
        params.degree
    };
    if grown {
        let k = if degree < params.degree {
            ctx.n_min_grown
        } else {
            ctx.n_min
        };
        let mut nearest = vec![(0.0, 0u32); k];
        // The parent's or grandparent's ball usually holds the k nearest, and a scan of its
        // points is cheaper than a search of the tree.
        let found = match nearest_in_covers(&ancestors, ctx.points, center, &mut nearest) {
            Some(found) => found,
            None => ctx
                .tree
                .nearest_n_within(center, f64::INFINITY, &mut nearest),
        };
        nearest.truncate(found);
        if nearest.is_empty() {
            return part;
        }
        ball = nearest.iter().map(|nn| nn.1).collect();
        let far2 = nearest.iter().map(|nn| nn.0).fold(0.0, f64::max);
        fit_radius = radius.max(far2.sqrt() * (1.0 + 1e-9));
        // The k nearest: every point closer than the farthest of them is among them.
        cover_radius2 = far2;
    }
    let own = Cover {
        points: &ball,
        center,
        radius2: cover_radius2,
    };
    // MPU's auxiliary rows: the cell's centre and corners.
    let mut aux: Vec<AuxPoint> = Vec::new();
    if params.auxiliary == AuxiliaryPoints::CentreAndCorners {
        let half = step / 2;
        let mut candidates = [lattice_center; 9];
        for (corner, slot) in candidates.iter_mut().skip(1).enumerate() {
            *slot = [0, 1, 2].map(|a| {
                if (corner >> a) & 1 == 1 {
                    lattice_center[a] + half
                } else {
                    lattice_center[a] - half
                }
            });
        }
        for l in candidates {
            let key = u128::from(l[0]) | (u128::from(l[1]) << 42) | (u128::from(l[2]) << 84);
            let q = at(l);
            let estimate = *cache.entry(key).or_insert_with(|| {
                auxiliary_estimate(ctx, q, [Some(own), ancestors[0], ancestors[1]])
            });
            match estimate {
                Some(t) => {
                    aux.push((q, t));
                    part.aux_kept += 1;
                }
                None => part.aux_dropped += 1,
            }
        }
    }
    // A ball far denser than a local fit needs is fitted on an even subsample; the split
    // criterion still measures every point of the ball.
    let subsample;
    let fit_points: &[u32] = if !grown && ball.len() > SUBSAMPLE_ABOVE {
        subsample = even_subsample(&ball);
        &subsample
    } else {
        &ball
    };
    let tolerance = if level + 2 >= params.max_depth {
        params.finest_tolerance
    } else {
        params.tolerance
    };
    let may_split = !grown && level < params.max_depth;
    let constraints = match params.constraints {
        LocalConstraints::Gradient => Constraints::Gradient,
        LocalConstraints::ThreeLevels => Constraints::ThreeLevels(params.epsilon),
    };
    // The ball's fit at `degree` with the fitted points' robust weights, its error measured up
    // to `stop_above`.
    let fit_weighted = |degree: u32, stop_above: f64, robust: Option<&[f64]>| {
        fit_local(
            ctx.points,
            ctx.normals,
            fit_points,
            &ball,
            stop_above,
            &aux,
            degree,
            constraints,
            params.kappa,
            fit_radius,
            Some((center, radius)),
            RowWeights {
                confidence: ctx.weights,
                robust,
            },
        )
    };
    // A cell that may split needs its error only up to the tolerance; a leaf needs it all, and
    // so does a noisy cell, whose split is decided by the root mean square.
    let noise = params.noise * ctx.diagonal;
    let stop_above = if may_split && noise == 0.0 {
        tolerance * ctx.diagonal
    } else {
        f64::INFINITY
    };
    // Noisy data: the fit once more with Tukey's biweight of each fitted point's residual, so
    // that the points far off the first fit (outliers, a neighbouring sheet) weigh little or
    // nothing, and without the points whose normal points against the first fit's gradient
    // (the orientation of noisy points fails in patches, whose 3L rows ask for the opposite
    // side); kept when enough points keep their weight.
    let robust = |fit: &LocalFit| -> Option<Vec<f64>> {
        let cutoff = ROBUST_CUTOFF * noise;
        let weights: Vec<f64> = fit_points
            .iter()
            .map(|&i| {
                let (f, g) = fit.poly.value_gradient(ctx.points[i as usize]);
                let u = f.abs() / vec3::norm(g).max(1e-300) / cutoff;
                if u < 1.0 && vec3::dot(g, ctx.normals[i as usize]) > 0.0 {
                    (1.0 - u * u) * (1.0 - u * u)
                } else {
                    0.0
                }
            })
            .collect();
        let kept: f64 = weights.iter().sum();
        (kept >= 0.5 * fit_points.len() as f64).then_some(weights)
    };
    let fit_at = |degree: u32, stop_above: f64| {
        let fit = fit_weighted(degree, stop_above, None)?;
        if noise == 0.0 {
            return Some(fit);
        }
        match robust(&fit) {
            Some(weights) => fit_weighted(degree, stop_above, Some(&weights)).or(Some(fit)),
            None => Some(fit),
        }
    };
    let Some(fit) = fit_at(degree, stop_above) else {
        part.error = Some(DetailError::LocalFit { level, center });
        return part;
    };
    part.fitted = 1;
    let fit = match fit {
        // A deepest cell the quadric leaves out of tolerance: the cubic, where it does better.
        fit if params.refit_deepest
            && degree == 2
            && !grown
            && level == params.max_depth
            && fit.max_error > tolerance * ctx.diagonal =>
        {
            match fit_at(3, f64::INFINITY) {
                Some(cubic) if cubic.max_error < fit.max_error => cubic,
                _ => fit,
            }
        }
        fit => fit,
    };
    let split = may_split
        && if noise > 0.0 {
            let t = tolerance * ctx.diagonal;
            fit.rms_error * fit.rms_error > (NOISE_MARGIN * noise).powi(2) + t * t
        } else {
            fit.max_error > tolerance * ctx.diagonal
        };
    if !split {
        if !grown {
            part.max_local_error = fit.max_error;
        }
        part.cells.push(MpuCell {
            center,
            radius,
            fit_radius,
            level,
            grown,
            poly: fit.poly,
        });
        return part;
    }
    // Each child's ball lies inside this one's, so its points are found among this ball's.
    let children: [[u32; 3]; 8] =
        std::array::from_fn(|i| [0, 1, 2].map(|a| 2 * coords[a] + ((i >> a) & 1) as u32));
    let child_centers = children.map(|c| cell_geometry(ctx, c, level + 1).2);
    let child_radius = cell_geometry(ctx, children[0], level + 1).3;
    let r2 = child_radius * child_radius;
    let visit_child = |c: [u32; 3], b: Vec<u32>, cache: &mut AuxCache| {
        let ancestors = [Some(own), ancestors[0]];
        visit(ctx, c, level + 1, b, Some(&fit.poly), ancestors, cache)
    };
    let parts: Vec<Part> = if level < LAZY_BALL_LEVELS {
        // Near the root a child's ball holds most of the points: each task finds its own when
        // it starts, so the eight lists are not all held at once (they were the detail fit's
        // largest allocation). The list is the same as the one pass below gives.
        children
            .into_par_iter()
            .zip(child_centers)
            .map(|(c, center)| {
                let [b] = points_in_balls(ctx.points, &ball, &[center], r2);
                visit_child(c, b, &mut AuxCache::default())
            })
            .collect()
    } else {
        // Smaller balls: one pass over this one gives all eight.
        let balls = points_in_balls(ctx.points, &ball, &child_centers, r2);
        let tasks: Vec<([u32; 3], Vec<u32>)> = children.into_iter().zip(balls).collect();
        if level < PARALLEL_LEVELS {
            tasks
                .into_par_iter()
                .map(|(c, b)| visit_child(c, b, &mut AuxCache::default()))
                .collect()
        } else {
            tasks
                .into_iter()
                .map(|(c, b)| visit_child(c, b, cache))
                .collect()
        }
    };
    for p in parts {
        part.append(p);
    }
    part
}

/// MPU's estimate of the signed distance at an auxiliary point `q`: the mean tangent-plane
/// distance nⱼ·(q − pⱼ) of its 6 nearest data points, or `None` when they disagree in sign.
/// The 6 come from the first of `near` (the balls of the cell whose centre or corner `q` is, of
/// its parent and grandparent) that provably holds them, else from the k-d tree.
fn auxiliary_estimate(ctx: &Ctx, q: [f64; 3], near: [Option<Cover>; 3]) -> Option<f64> {
    let mut nearest = [(0.0, 0u32); AUX_NEIGHBOURS];
    let found = match nearest_in_covers(&near, ctx.points, q, &mut nearest) {
        Some(found) => found,
        None => ctx.tree.nearest_n_within(q, f64::INFINITY, &mut nearest),
    };
    let mut sum = 0.0;
    let (mut pos, mut neg) = (0, 0);
    for &(_, i) in &nearest[..found] {
        let p = ctx.points[i as usize];
        let nv = ctx.normals[i as usize];
        let d = nv[0] * (q[0] - p[0]) + nv[1] * (q[1] - p[1]) + nv[2] * (q[2] - p[2]);
        sum += d;
        if d > 0.0 {
            pos += 1;
        } else if d < 0.0 {
            neg += 1;
        }
    }
    (found == AUX_NEIGHBOURS && (pos == AUX_NEIGHBOURS || neg == AUX_NEIGHBOURS))
        .then(|| sum / AUX_NEIGHBOURS as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a jittered lattice (distinct distances almost everywhere, some exact ties).
    fn cloud() -> Vec<[f64; 3]> {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut points = Vec::new();
        for i in 0..600 {
            let jitter = if i % 5 == 0 { 0.0 } else { 0.3 };
            let l = [i % 10, (i / 10) % 10, i / 100].map(|c| c as f64 * 0.1);
            points.push(l.map(|c| c + jitter * 0.1 * (next() - 0.5)));
        }
        points
    }

    #[test]
    fn cover_answers_only_what_it_holds_and_then_as_a_full_search() {
        let points = cloud();
        let tree = PointTree::new(&points).unwrap();
        let (mut answered, mut declined) = (0, 0);
        for (c, r) in [
            ([0.45, 0.45, 0.25], 0.12),
            ([0.2, 0.7, 0.3], 0.2),
            ([0.5; 3], 0.3),
        ] {
            let members: Vec<u32> = (0..points.len() as u32)
                .filter(|&i| dist2(points[i as usize], c) < r * r)
                .collect();
            let cover = Cover {
                points: &members,
                center: c,
                radius2: r * r,
            };
            for q in [
                c,
                [c[0] + 0.03, c[1], c[2]],
                [c[0] + 0.05, c[1] - 0.04, c[2] + 0.02],
            ] {
                for k in [1, 6, 15] {
                    let mut got = vec![(0.0, 0u32); k];
                    let Some(n) = cover.nearest(&points, q, &mut got) else {
                        declined += 1;
                        continue;
                    };
                    answered += 1;
                    let mut want = vec![(0.0, 0u32); k];
                    assert_eq!(tree.nearest_n_within(q, f64::INFINITY, &mut want), n);
                    // The same distances; the same points up to the order of exact ties.
                    assert_eq!(
                        got.iter().map(|g| g.0).collect::<Vec<_>>(),
                        want.iter().map(|w| w.0).collect::<Vec<_>>()
                    );
                    let last = got[k - 1].0;
                    let strictly_nearer = |v: &[(f64, u32)]| {
                        let mut s: Vec<u32> =
                            v.iter().filter(|g| g.0 < last).map(|g| g.1).collect();
                        s.sort_unstable();
                        s
                    };
                    assert_eq!(strictly_nearer(&got), strictly_nearer(&want));
                }
            }
        }
        assert!(answered >= 10 && declined >= 1, "{answered} {declined}");
    }
}
