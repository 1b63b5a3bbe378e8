//! Automatic κ for 3LRR: the grid 0, 1e-8 … 1 (four steps a decade) and the two rules.
//!
//! Input: the accumulated system (MᵀM, Mᵀb, D), the normalization and the data. Output: the
//! chosen κ, its coefficients, and warnings. Every grid value reuses the same MᵀM; only κD changes.
//!
//! - `paper` (section 6.3): the smallest grid κ whose leading form H_n is positive on the unit
//!   sphere.
//! - `stable`: the smallest grid κ such that
//!   - (a) H_n is positive at that κ and at every larger grid value (positivity is not
//!     monotone in κ, so a lone positive value between negative ones is rejected);
//!   - (b) a containment radius R exists: on |p̂| = r, f ≥ H_min·rⁿ − Σ_{k<n} ‖H_k‖·r^k, so the
//!     zero set lies in |p̂| < R (reported);
//!   - (c) the zero set, meshed coarsely in the normalized box [−1.6, 1.6]³, has one component
//!     per connected piece of the data, each within 0.2 of the data (its closest point: a
//!     closed zero set must bridge holes in the data, such as a part cut away, so not all of it
//!     can be near the data);
//!   - (d) in [−4, 4]³, and in [−R, R]³ when R is larger, it has no other component and does
//!     not touch the box.
//!
//!   (c) and (d) mesh with the polygonize stage (depth 6); if that stage cannot run, a uniform
//!   grid of 64³ cells stands in (the 26-connected components of the cells whose corners change
//!   sign), and the diagnostics say so.
//!
//! If no grid value qualifies, κ = 1e-2 is used and flagged.
//!
//! Cost. Grid values are solved (and their leading-form minima found) only where a rule looks:
//! `stable` walks down from κ = 1 and stops at the first non-positive leading form, `paper`
//! walks up from 0 and stops at the first positive one. The candidates of (b)–(d) are then tried
//! from the smallest up, and each stops at its first failing check, cheapest first:
//! - when R > 4, f is sampled at fixed points with 4 ≤ |p̂|∞ ≤ R (a log-polar probe, a few
//!   thousand values); f < 0 there proves that the zero set reaches |p̂|∞ ≥ 4 (f > 0 beyond R on
//!   the ray through that point), so it touches [−4, 4]³ or has a component outside it: (d)
//!   fails without any mesh;
//! - (c) on the inner mesh (the marching-tetrahedra mesh as extracted: the checks need its
//!   components and its vertices, which the edge collapses of the stage's default would not
//!   change in topology, only thin out);
//! - (d) in [−4, 4]³: when the inner mesh stays off the inner box's faces, the sign of f on the
//!   shell between the boxes decides, if it can be established: f > 0 there (certified by the
//!   frustum enclosures of `far_sign`, else by the box enclosures of `shell_sign`) means
//!   both boxes hold the same zero set, which (c) accepted; f < 0 at a point of the shell means
//!   the zero set reaches the shell (along the ray) without crossing the inner box's faces, so
//!   it is a further component or touches the outer box: (d) fails. Otherwise [−4, 4]³ is
//!   meshed;
//! - (d) in [−R, R]³ (R > 4) is meshed. When the Bernstein bounds of `far_positive` prove
//!   f > 0 from box norm 4 out to R (and `far_sign` from 1.6 to 4, when it can), the mesher
//!   skips the octree cells whose neighbourhood lies there (`FarCulled`): the mesh is the
//!   same, vertex for vertex, for a fraction of the work (the octree of a large box otherwise
//!   spends most of its time far out, where the Taylor enclosures are loose), and this mesh then
//!   runs right after the probe, before (c), being the cheapest decisive check (on the bunny
//!   it rejects κ = 1.8e-2 … 5.6e-2 on its own).
//!
//! Each solve and check is logged with its wall time at the `trace` level of the `log` crate
//! (target `stablesurf::fit::kappa`), a profiling aid that changes no decision.
//!
//! The shortcuts decide the same question as the meshes they replace, from the exact zero set;
//! over the κ study (108 cases, both rules) and on the bunny they give the same κ as meshing
//! everything.
//!
//! "Connected pieces of the data": the components of the graph joining data points closer than
//! 0.2 (normalized units, the same tolerance as (c)) among their 12 nearest neighbours, on at
//! most 20,000 points taken at a fixed stride. Data closer than 0.2 can be bridged by a zero set
//! that stays within 0.2 of the data, so it fairly counts as one piece.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;

use super::solve;
use super::system::{Normalization, System};
use super::FitError;
use crate::cloud::{Aabb, OrientedCloud};
use crate::implicit::{Enclosure, GridValues, ImplicitFunction};
use crate::numerics::UnionFind;
use crate::poly::ImplicitPolynomial;

/// The fallback κ when no grid value qualifies.
const FALLBACK_KAPPA: f64 = 1e-2;
/// Distance tolerance (normalized units) of the zero set to the data, rule (c).
const NEAR_DATA: f64 = 0.2;
/// Half side of the box of rule (c), normalized units.
const INNER_BOX: f64 = 1.6;
/// Minimum half side of the box of rule (d), normalized units.
const OUTER_BOX: f64 = 4.0;
/// Octree depth of the coarse meshes of (c) and (d).
const CHECK_DEPTH: u32 = 6;
/// Points used for the data pieces and the distance checks.
const MAX_CHECK_POINTS: usize = 20_000;

/// Logs `what` and the wall time since `start` at the `trace` level.
fn trace(start: std::time::Instant, what: std::fmt::Arguments) {
    log::trace!("{:>8.2} ms  {what}", start.elapsed().as_secs_f64() * 1e3);
}

/// The κ grid: 0, then 10^(−8 + i/4) for i = 0 … 32 (1e-8 … 1, four steps a decade).
///
/// ```
/// let g = stablesurf::fit::kappa_grid();
/// assert_eq!(g.len(), 34);
/// assert_eq!(g[0], 0.0);
/// assert!((g[1] - 1e-8).abs() < 1e-20 && (g[33] - 1.0).abs() < 1e-15);
/// ```
pub fn kappa_grid() -> Vec<f64> {
    let mut grid = vec![0.0];
    grid.extend((0..=32).map(|i| 10f64.powf(-8.0 + i as f64 / 4.0)));
    grid
}

/// The chosen κ and what the selection found.
#[derive(Clone, Debug)]
pub(crate) struct Selection {
    pub kappa: f64,
    pub coefficients: Vec<f64>,
    pub warnings: Vec<String>,
    pub fallback: bool,
    pub zero_set_checked: bool,
}

/// One grid value's solve.
struct GridFit {
    kappa: f64,
    coefficients: Option<Vec<f64>>,
    leading_min: f64,
}

/// Picks κ by `rule`.
pub(crate) fn select(
    sys: &System,
    gram: &[f64],
    ridge: &[f64],
    norm: &Normalization,
    cloud: &OrientedCloud,
    rule: super::KappaRule,
) -> Result<Selection, FitError> {
    let degree = sys.degree;
    // Solves and leading-form minima are computed lazily, only where the rule looks: the stable
    // rule walks down from κ = 1 and stops at the first non-positive value (rule (a)), the paper
    // rule walks up from 0 and stops at the first positive one.
    let kappas = kappa_grid();
    let solve_at = |i: usize| {
        let kappa = kappas[i];
        let coefficients = solve::solve_ridge(gram, &sys.rhs, ridge, kappa)
            .ok()
            .map(|s| s.coefficients);
        let leading_min = coefficients.as_ref().map_or(f64::NAN, |a| {
            unit_poly(degree, a).leading_form_extrema().min
        });
        GridFit {
            kappa,
            coefficients,
            leading_min,
        }
    };
    let positive = |g: &GridFit| g.coefficients.is_some() && g.leading_min > 0.0;
    let mut grid: Vec<Option<GridFit>> = (0..kappas.len()).map(|_| None).collect();
    let mut warnings = Vec::new();
    let mut zero_set_checked = false;
    let mut mesher = None;
    let chosen = match rule {
        super::KappaRule::Paper => {
            let mut chosen = None;
            for (i, slot) in grid.iter_mut().enumerate() {
                let g = solve_at(i);
                let ok = positive(&g);
                *slot = Some(g);
                if ok {
                    chosen = Some(i);
                    break;
                }
            }
            chosen
        }
        super::KappaRule::Stable => {
            // (a): positive here and at every larger grid value. The walk is sequential; the
            // data's pieces, which the checks of (c) need, are indexed beside it.
            let (mut candidates, pieces) = rayon::join(
                || {
                    let mut candidates = Vec::new();
                    for i in (0..kappas.len()).rev() {
                        let t = std::time::Instant::now();
                        let g = solve_at(i);
                        trace(
                            t,
                            format_args!("solve kappa {:.1e} min {:.3e}", kappas[i], g.leading_min),
                        );
                        let ok = positive(&g);
                        grid[i] = Some(g);
                        if !ok {
                            break;
                        }
                        candidates.push(i);
                    }
                    candidates
                },
                || {
                    let t = std::time::Instant::now();
                    let pieces = DataPieces::new(cloud, norm);
                    trace(t, format_args!("data pieces"));
                    pieces
                },
            );
            candidates.reverse();
            let mut chosen = None;
            for &i in &candidates {
                let Some(fit_i) = grid[i].as_ref() else {
                    continue;
                };
                let Some(coefficients) = fit_i.coefficients.as_ref() else {
                    continue;
                };
                let poly = unit_poly(degree, coefficients);
                // (b): certified containment radius.
                let Some(radius) = poly.containment_radius_with(fit_i.leading_min) else {
                    continue;
                };
                let Some(pieces) = pieces.as_ref() else {
                    warnings.push("kappa rule stable: the data could not be indexed, so the zero-set checks (c)/(d) were skipped".to_string());
                    chosen = Some(i);
                    break;
                };
                let t = std::time::Instant::now();
                let (pass, used) = zero_set_check(&poly, radius, pieces);
                trace(
                    t,
                    format_args!(
                        "candidate kappa {:.1e} R {radius:.2} pass {pass}",
                        kappas[i]
                    ),
                );
                zero_set_checked = true;
                if used.is_some() {
                    mesher = used;
                }
                if pass {
                    chosen = Some(i);
                    break;
                }
            }
            if mesher == Some(Mesher::SignGrid) {
                warnings.push(format!(
                    "kappa rule stable: the polygonize stage could not run, so the zero-set checks (c)/(d) used a uniform sign-change grid of {} cells per side instead of the adaptive mesh",
                    1u32 << CHECK_DEPTH
                ));
            }
            chosen
        }
    };
    match chosen.and_then(|i| grid[i].as_ref()) {
        Some(g) => {
            let coefficients = g.coefficients.clone().unwrap_or_default();
            Ok(Selection {
                kappa: g.kappa,
                coefficients,
                warnings,
                fallback: false,
                zero_set_checked,
            })
        }
        None => {
            let solution =
                solve::solve_ridge(gram, &sys.rhs, ridge, FALLBACK_KAPPA).map_err(|e| match e {
                    solve::SolveFailure::NotPositiveDefinite { column } => {
                        FitError::SingularSystem {
                            kappa: FALLBACK_KAPPA,
                            column,
                            n_coefficients: sys.rhs.len(),
                        }
                    }
                    solve::SolveFailure::NoConvergence => FitError::NoConvergence,
                })?;
            warnings.push(format!(
                "no kappa on the grid 0, 1e-8 … 1 satisfied the {} rule; fell back to kappa = {FALLBACK_KAPPA}: check the result, or try another --degree",
                rule.as_str()
            ));
            Ok(Selection {
                kappa: FALLBACK_KAPPA,
                coefficients: solution.coefficients,
                warnings,
                fallback: true,
                zero_set_checked,
            })
        }
    }
}

/// The polynomial in normalized coordinates (centre 0, scale 1).
fn unit_poly(degree: u32, coefficients: &[f64]) -> ImplicitPolynomial {
    ImplicitPolynomial {
        degree,
        coefficients: coefficients.to_vec(),
        center: [0.0; 3],
        scale: 1.0,
    }
}

/// The data in normalized coordinates (a fixed-stride subset), its k-d tree and its pieces.
struct DataPieces {
    tree: ImmutableKdTree<f64, 3>,
    /// Piece label per indexed point.
    labels: Vec<u32>,
    n_pieces: usize,
}

impl DataPieces {
    fn new(cloud: &OrientedCloud, norm: &Normalization) -> Option<DataPieces> {
        let stride = cloud.points.len().div_ceil(MAX_CHECK_POINTS).max(1);
        let points: Vec<[f64; 3]> = cloud
            .points
            .iter()
            .step_by(stride)
            .map(|p| norm.apply(*p))
            .collect();
        let tree = ImmutableKdTree::<f64, 3>::new_from_slice(&points).ok()?;
        let mut sets = UnionFind::new(points.len());
        let k = std::num::NonZeroUsize::new(12).unwrap_or(std::num::NonZeroUsize::MIN);
        // The 12 nearest neighbours within NEAR_DATA, searched in parallel (the radius bound
        // prunes the search); the union-find pass is sequential. The components do not depend
        // on the order of the unions.
        let near: Vec<Vec<u32>> = points
            .par_iter()
            .map(|p| {
                tree.query(p)
                    .nearest_n::<SquaredEuclidean<f64>>(k)
                    .within(NEAR_DATA * NEAR_DATA)
                    .execute()
                    .into_iter()
                    .filter(|nb| nb.distance <= NEAR_DATA * NEAR_DATA)
                    .map(|nb| nb.item)
                    .collect()
            })
            .collect();
        for (i, neighbours) in near.iter().enumerate() {
            for &item in neighbours {
                sets.union(i as u32, item);
            }
        }
        let (labels, n_pieces) = compact_labels(&mut sets);
        Some(DataPieces {
            tree,
            labels,
            n_pieces,
        })
    }

    /// Distance from `q` to the nearest data point and that point's piece.
    fn nearest(&self, q: [f64; 3]) -> (f64, u32) {
        let nn = self
            .tree
            .query(&q)
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute();
        let label = self.labels.get(nn.item as usize).copied().unwrap_or(0);
        (nn.distance.sqrt(), label)
    }
}

/// Labels 0.. in order of first appearance, and their count.
fn compact_labels(sets: &mut UnionFind) -> (Vec<u32>, usize) {
    let mut map = std::collections::HashMap::new();
    let mut labels = Vec::with_capacity(sets.len());
    for i in 0..sets.len() as u32 {
        let root = sets.find(i);
        let next = map.len() as u32;
        labels.push(*map.entry(root).or_insert(next));
    }
    (labels, map.len())
}

/// The coarse zero set inside a box: its connected pieces, each given by representative points
/// (mesh vertices, or centres of cells whose corners change sign), how far such a point may be
/// from the true zero set, and whether the zero set reaches the box's boundary.
struct CoarseZeroSet {
    components: Vec<Vec<[f64; 3]>>,
    slack: f64,
    touches_box: bool,
}

/// Which mesher produced a [`CoarseZeroSet`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Mesher {
    /// The polygonize stage (adaptive octree), as the rule specifies.
    Polygonize,
    /// A uniform grid of 2^depth cells per side, 26-connected sign-change cells: the stand-in
    /// used while polygonize reports that it cannot run.
    SignGrid,
}

/// Meshes the zero set of `poly` (normalized coordinates) coarsely in [−half, half]³: with the
/// polygonize stage when it runs, else with the uniform sign grid.
fn coarse_zero_set(poly: &ImplicitPolynomial, half: f64) -> (CoarseZeroSet, Mesher) {
    coarse_zero_set_culled(poly, half, None)
}

/// [`coarse_zero_set`], given (optionally) a box norm `positive_beyond` such that f > 0 is
/// certified on every point of [−half, half]³ with |p|∞ ≥ `positive_beyond`: the octree then
/// skips the cells that cannot matter there ([`FarCulled`]), and the mesh is the same.
fn coarse_zero_set_culled(
    poly: &ImplicitPolynomial,
    half: f64,
    positive_beyond: Option<f64>,
) -> (CoarseZeroSet, Mesher) {
    use crate::polygonize::{polygonize, PolygonizeParams};
    let region = Aabb {
        min: [-half; 3],
        max: [half; 3],
    };
    let params = PolygonizeParams {
        depth: CHECK_DEPTH,
        // The checks need components and distances only: the edge collapses (which keep the
        // topology exactly) would only cost time.
        simplification: crate::polygonize::Simplification::None,
        ..Default::default()
    };
    let cell = 2.0 * half / f64::from(1u32 << CHECK_DEPTH);
    let t = std::time::Instant::now();
    let polygonized = match positive_beyond {
        Some(beyond) => {
            let culled = FarCulled {
                poly,
                beyond,
                reach: cell,
            };
            polygonize(&culled, &region, &params)
        }
        None => polygonize(poly, &region, &params),
    };
    if let Ok(out) = polygonized {
        trace(t, format_args!("    polygonize half {half:.2}: {} leaves, {} evaluations, {} guard splits, max level {}, {} vertices, {} triangles", out.cells, out.evaluations, out.guard_splits, out.max_level, out.mesh.positions.len(), out.mesh.triangles.len()));
        let mesh = out.mesh;
        let (count, labels) = crate::mesh::component_labels(&mesh);
        let mut components = vec![Vec::new(); count];
        for (p, &l) in mesh.positions.iter().zip(&labels) {
            components[l as usize].push(*p);
        }
        components.retain(|c| !c.is_empty());
        let touches_box = mesh
            .positions
            .iter()
            .any(|p| p.iter().any(|c| c.abs() > half - 0.5 * cell));
        return (
            CoarseZeroSet {
                components,
                slack: 0.0,
                touches_box,
            },
            Mesher::Polygonize,
        );
    }
    (
        sign_grid_zero_set(poly, half, 1usize << CHECK_DEPTH),
        Mesher::SignGrid,
    )
}

/// The polynomial as the polygonize stage sees it, except that a box whose `reach`-neighbourhood
/// lies where f > 0 is certified (box norm ≥ `beyond`) gets the enclosure (tiny, ∞), so the
/// octree discards it at once instead of refining it (the Taylor enclosures of a high-degree
/// polynomial are loose far from the origin, where the octree of a large box spends most of its
/// work).
///
/// The mesh is the same as with the polynomial itself when `reach` is at least the side of a
/// level-`depth` cell: every other box gets the polynomial's own answers, so every cell outside
/// the discarded ones is treated as before (a cell's fate depends only on its own and its
/// ancestors' enclosures); the leaves inside a discarded box, and every leaf touching it (a leaf
/// is at most `reach` wide, so it lies in the neighbourhood), have f > 0 at all their lattice
/// points, so they yield no triangle and no vertex whatever their neighbours, and the leaves
/// that do yield triangles see the same neighbours (the extraction's tetrahedra depend only on
/// the leaves touching a leaf). The certificates ([`far_positive`] and [`far_sign`], the same
/// Bernstein test) keep a relative margin of 1e-12 over the rounding of their coefficients: a
/// margin, not a rigorous error bound.
struct FarCulled<'a> {
    poly: &'a ImplicitPolynomial,
    beyond: f64,
    reach: f64,
}

impl FarCulled<'_> {
    /// Whether every point within `reach` of `b` (box norm) has box norm ≥ `beyond`.
    fn certified_positive(&self, b: &Aabb) -> bool {
        let mut nearest = 0.0f64;
        for a in 0..3 {
            let (lo, hi) = (b.min[a] - self.reach, b.max[a] + self.reach);
            let d = if lo > 0.0 {
                lo
            } else if hi < 0.0 {
                -hi
            } else {
                0.0
            };
            nearest = nearest.max(d);
        }
        nearest >= self.beyond
    }
}

/// The enclosure [`FarCulled`] gives a discarded box.
const DISCARDED: Enclosure = Enclosure {
    value: (f64::MIN_POSITIVE, f64::INFINITY),
    gradient: [(f64::NEG_INFINITY, f64::INFINITY); 3],
    value_error: 0.0,
};

impl ImplicitFunction for FarCulled<'_> {
    fn value(&self, p: [f64; 3]) -> f64 {
        self.poly.value(p)
    }

    fn value_gradient(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        self.poly.value_gradient(p)
    }

    fn bounds_on_box(&self, b: &Aabb) -> (f64, f64) {
        if self.certified_positive(b) {
            return DISCARDED.value;
        }
        self.poly.bounds_on_box(b)
    }

    fn gradient_bounds_on_box(&self, b: &Aabb) -> [(f64, f64); 3] {
        self.poly.gradient_bounds_on_box(b)
    }

    fn enclosure_on_box(&self, b: &Aabb) -> Enclosure {
        if self.certified_positive(b) {
            return DISCARDED;
        }
        self.poly.enclosure_on_box(b)
    }

    fn enclosure_and_grid_values(
        &self,
        b: &Aabb,
        axes: &[[f64; 2]; 3],
    ) -> (Enclosure, Option<GridValues>) {
        if self.certified_positive(b) {
            return (DISCARDED, None);
        }
        self.poly.enclosure_and_grid_values(b, axes)
    }

    fn validate(&self) -> Result<(), String> {
        self.poly.validate()
    }
}

/// The zero set as 26-connected components of the cells (of a `cells`³ grid over
/// [−half, half]³) whose eight corner values change sign.
fn sign_grid_zero_set(poly: &ImplicitPolynomial, half: f64, cells: usize) -> CoarseZeroSet {
    let step = 2.0 * half / cells as f64;
    let nv = cells + 1;
    let values = poly.eval_grid([-half; 3], [step; 3], [nv, nv, nv]);
    let vid = |i: usize, j: usize, k: usize| i + nv * (j + nv * k);
    let cid = |i: usize, j: usize, k: usize| i + cells * (j + cells * k);
    let mut crossing = vec![false; cells * cells * cells];
    let mut touches_box = false;
    for k in 0..cells {
        for j in 0..cells {
            for i in 0..cells {
                let mut pos = false;
                let mut neg = false;
                for corner in 0..8 {
                    let v =
                        values[vid(i + (corner & 1), j + ((corner >> 1) & 1), k + (corner >> 2))];
                    pos |= v > 0.0;
                    neg |= v <= 0.0;
                }
                if pos && neg {
                    crossing[cid(i, j, k)] = true;
                    let edge = |t: usize| t == 0 || t + 1 == cells;
                    touches_box |= edge(i) || edge(j) || edge(k);
                }
            }
        }
    }
    let mut seen = vec![false; crossing.len()];
    let mut components = Vec::new();
    let mut stack = Vec::new();
    let centre = |c: usize| {
        let (i, j, k) = (c % cells, (c / cells) % cells, c / (cells * cells));
        [i, j, k].map(|t| -half + (t as f64 + 0.5) * step)
    };
    for start in 0..crossing.len() {
        if !crossing[start] || seen[start] {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let mut points = Vec::new();
        while let Some(c) = stack.pop() {
            points.push(centre(c));
            let (i, j, k) = (c % cells, (c / cells) % cells, c / (cells * cells));
            for dk in -1i64..=1 {
                for dj in -1i64..=1 {
                    for di in -1i64..=1 {
                        let (ii, jj, kk) = (i as i64 + di, j as i64 + dj, k as i64 + dk);
                        let limit = cells as i64;
                        if ii < 0 || jj < 0 || kk < 0 || ii >= limit || jj >= limit || kk >= limit {
                            continue;
                        }
                        let d = cid(ii as usize, jj as usize, kk as usize);
                        if crossing[d] && !seen[d] {
                            seen[d] = true;
                            stack.push(d);
                        }
                    }
                }
            }
        }
        components.push(points);
    }
    CoarseZeroSet {
        components,
        slack: 0.5 * step * 3f64.sqrt(),
        touches_box,
    }
}

/// Rules (c) and (d) on coarse meshes of the zero set of `poly` (normalized coordinates), with
/// certificates standing in for the meshes of (d) where they decide the same question exactly.
/// Also returns the mesher used, if any mesh was made.
fn zero_set_check(
    poly: &ImplicitPolynomial,
    radius: f64,
    data: &DataPieces,
) -> (bool, Option<Mesher>) {
    // (d), beyond [−4, 4]³ first, because a probe there is cheap: f < 0 at a point p with
    // |p|∞ ≥ 4 means the zero set reaches |p|∞ ≥ 4 (f > 0 beyond R along the ray through p),
    // so it touches [−4, 4]³ or has a component outside it, in [−R, R]³: (d) fails.
    let t = std::time::Instant::now();
    if radius > OUTER_BOX && far_probe_negative(poly, OUTER_BOX, radius) {
        trace(t, format_args!("  probe negative"));
        return (false, None);
    }
    trace(t, format_args!("  probe"));
    // (d) in [−R, R]³ when R > 4: a coarse mesh (the fixed box is checked on its own below,
    // because a coarse mesh of a large [−R, R]³ can miss a small stray piece). When f > 0 is
    // certified from box norm 4 out to R, the mesher skips the far cells ([`FarCulled`]: the
    // same mesh for a fraction of the work), from 1.6 when the shell between the boxes is
    // positive too; that mesh then goes first, being the cheapest. (Every check must pass, so
    // their order changes the cost, never the outcome.) The shell's sign is kept for (d) in
    // [−4, 4]³ below.
    let large_box_fails = |positive_beyond: Option<f64>| {
        let t = std::time::Instant::now();
        let (outer, used) = coarse_zero_set_culled(poly, radius, positive_beyond);
        trace(
            t,
            format_args!(
                "  R mesh: {} components touches {}",
                outer.components.len(),
                outer.touches_box
            ),
        );
        (
            outer.touches_box || outer.components.len() != data.n_pieces,
            used,
        )
    };
    let mut early_shell = None;
    let mut large_box_done = false;
    if radius > OUTER_BOX {
        let t = std::time::Instant::now();
        if far_positive(poly, OUTER_BOX, radius, FAR_POSITIVE_RATIO) {
            let shell = far_sign(poly, INNER_BOX, OUTER_BOX);
            early_shell = Some(shell);
            let beyond = if shell == Shell::Positive {
                INNER_BOX
            } else {
                OUTER_BOX
            };
            trace(
                t,
                format_args!("  far_positive 4..R, far_sign {shell:?}: beyond {beyond}"),
            );
            // f < 0 at a point p of the shell while f > 0 on the inner box's faces: the
            // region {f < 0} around p cannot reach into the inner box, so the zero set bounding
            // it lies outside the box and is a component besides those (c) would count there,
            // or (c) fails: both ways a check fails, and no mesh is needed (on the bunny this
            // rejects the small κ values that the large box's mesh would).
            if shell == Shell::Negative && far_sign(poly, INNER_BOX, INNER_BOX) == Shell::Positive {
                trace(
                    t,
                    format_args!("  inner faces positive: a component outside"),
                );
                return (false, None);
            }
            let (fails, used) = large_box_fails(Some(beyond));
            large_box_done = true;
            if fails {
                return (false, Some(used));
            }
        } else {
            trace(t, format_args!("  far_positive 4..R: not proved"));
        }
    }
    // (c): in the inner box, one component per data piece, each within NEAR_DATA of the data
    // (its closest point; a closed zero set must bridge holes in the data, so not every point
    // can be near it).
    let t = std::time::Instant::now();
    let (inner, mesher) = coarse_zero_set(poly, INNER_BOX);
    trace(
        t,
        format_args!(
            "  inner mesh: {} components, {} vertices",
            inner.components.len(),
            inner.components.iter().map(Vec::len).sum::<usize>()
        ),
    );
    let t = std::time::Instant::now();
    if inner.components.len() != data.n_pieces {
        return (false, Some(mesher));
    }
    let near_enough = NEAR_DATA + inner.slack;
    if data.n_pieces == 1 {
        // One piece: every data point carries its label, so only the distance matters, and
        // the first vertex near enough settles it (most are).
        let near = inner
            .components
            .iter()
            .all(|component| component.iter().any(|p| data.nearest(*p).0 <= near_enough));
        if !near {
            return (false, Some(mesher));
        }
    } else {
        let mut piece_seen = vec![false; data.n_pieces];
        for component in &inner.components {
            let closest = component
                .iter()
                .map(|p| data.nearest(*p))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            match closest {
                Some((dist, piece)) if dist <= near_enough => {
                    match piece_seen.get_mut(piece as usize) {
                        Some(seen) if !*seen => *seen = true,
                        _ => return (false, Some(mesher)),
                    }
                }
                _ => return (false, Some(mesher)),
            }
        }
    }
    trace(t, format_args!("  (c) distances"));
    // (d) in [−4, 4]³: nothing else and no contact with the box. When the inner mesh stays off
    // the inner box's faces, the shell between the boxes decides it: f > 0 there (certified by
    // [`far_sign`], or by the box enclosures of [`shell_sign`] when that fails) means the
    // [−4, 4]³ zero set is the inner one, which (c) accepted; f < 0 at a point of the shell
    // means the zero set reaches the shell along the ray through it, and since it cannot cross
    // the inner box's faces, that is a further component or contact with the outer box: (d)
    // fails. Otherwise [−4, 4]³ is meshed.
    let mut outer_shell = Shell::Unknown;
    if !inner.touches_box {
        let t = std::time::Instant::now();
        outer_shell = match early_shell {
            Some(shell) => shell,
            None => far_sign(poly, INNER_BOX, OUTER_BOX.min(radius)),
        };
        trace(t, format_args!("  far_sign {outer_shell:?}"));
        if outer_shell == Shell::Unknown {
            let t = std::time::Instant::now();
            outer_shell = shell_sign(poly, OUTER_BOX, INNER_BOX);
            trace(t, format_args!("  shell_sign {outer_shell:?}"));
        }
        if outer_shell == Shell::Negative {
            return (false, Some(mesher));
        }
    }
    let mut mesher = mesher;
    if outer_shell != Shell::Positive {
        let t = std::time::Instant::now();
        let (outer, used) = coarse_zero_set(poly, OUTER_BOX);
        trace(
            t,
            format_args!(
                "  outer mesh: {} components touches {}",
                outer.components.len(),
                outer.touches_box
            ),
        );
        mesher = used;
        if outer.touches_box || outer.components.len() != data.n_pieces {
            return (false, Some(mesher));
        }
    }
    if radius > OUTER_BOX && !large_box_done {
        let (fails, used) = large_box_fails(None);
        mesher = used;
        if fails {
            return (false, Some(mesher));
        }
    }
    (true, Some(mesher))
}

/// What [`shell_sign`] established about f on a shell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Shell {
    /// f > 0 on the whole shell (certified by enclosures).
    Positive,
    /// f < 0 at some point of the shell (a point value).
    Negative,
    /// Neither within the refinement limits.
    Unknown,
}

/// Patches per face side and radial steps per doubling of [`far_probe_negative`].
const PROBE_PATCHES: usize = 24;
/// Radial samples per doubling of the box norm in [`far_probe_negative`].
const PROBE_STEPS_PER_OCTAVE: usize = 8;

/// Whether f (normalized coordinates) is negative at one of a fixed set of sample points with
/// box norm |p|∞ in [s_lo, s_hi]: on each face of the cube |q|∞ = 1 the centres of a
/// `PROBE_PATCHES`² grid of patches, scaled by box norms spaced geometrically (eight a doubling)
/// from s_lo to s_hi. A negative sample is a proof (a point value); none proves nothing.
///
/// The value at p = s·q is f(s·q) = Σ_k s^k H_k(q): the forms H_k are evaluated once per
/// direction q (from [`FaceForms`]) and each radius costs one Horner step per degree, about 40×
/// less than evaluating f afresh. The verdict is that of the plain point values
/// ([`ImplicitPolynomial::eval_many`]): a radial value is trusted only when it is farther from 0
/// than `PROBE_MARGIN` × Σ_k s^k Σ|a_e q^e| (both evaluations differ from the exact value by a
/// few hundred units of rounding of that sum at most), and the rare sample closer to 0 is
/// evaluated as before.
fn far_probe_negative(poly: &ImplicitPolynomial, s_lo: f64, s_hi: f64) -> bool {
    use rayon::prelude::*;
    if !(s_lo > 0.0 && s_hi > s_lo && s_hi.is_finite()) {
        return false;
    }
    let steps = ((s_hi / s_lo).log2() * PROBE_STEPS_PER_OCTAVE as f64)
        .ceil()
        .max(1.0) as usize;
    let ratio = (s_hi / s_lo).powf(1.0 / steps as f64);
    let radii: Vec<f64> = (0..=steps).map(|j| s_lo * ratio.powi(j as i32)).collect();
    let forms = FaceForms::new(poly);
    let side = forms.degree + 1;
    (0..6 * PROBE_PATCHES).into_par_iter().any(|row| {
        let face = row / PROBE_PATCHES;
        let i = row % PROBE_PATCHES;
        let axis = face / 2;
        let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        let (b, c) = (b.min(c), b.max(c));
        let step = 2.0 / PROBE_PATCHES as f64;
        let u = -1.0 + (i as f64 + 0.5) * step;
        let mut pu = vec![1.0; side];
        let mut pv = vec![1.0; side];
        for e in 1..side {
            pu[e] = pu[e - 1] * u;
        }
        let mut h = vec![0.0; side];
        let mut a = vec![0.0; side];
        let mut unsure = Vec::new();
        for j in 0..PROBE_PATCHES {
            let v = -1.0 + (j as f64 + 0.5) * step;
            for e in 1..side {
                pv[e] = pv[e - 1] * v;
            }
            for (k, form) in forms.forms[face].iter().enumerate() {
                let (mut hk, mut ak) = (0.0, 0.0);
                for iu in 0..=k {
                    for jv in 0..=(k - iu) {
                        let t = form[iu * side + jv] * pu[iu] * pv[jv];
                        hk += t;
                        ak += t.abs();
                    }
                }
                h[k] = hk;
                a[k] = ak;
            }
            for &s in &radii {
                let (mut f, mut m) = (0.0, 0.0);
                for (hk, ak) in h.iter().zip(&a).rev() {
                    f = f * s + hk;
                    m = m * s + ak;
                }
                if f < -PROBE_MARGIN * m {
                    return true;
                }
                if f.abs() <= PROBE_MARGIN * m || !f.is_finite() {
                    let mut p = [0.0; 3];
                    p[axis] = sign * s;
                    p[b] = u * s;
                    p[c] = v * s;
                    unsure.push(p);
                }
            }
        }
        if unsure.is_empty() {
            return false;
        }
        let mut values = vec![0.0; unsure.len()];
        poly.eval_many(&unsure, &mut values);
        values.iter().any(|&f| f < 0.0)
    })
}

/// Relative distance from 0 (of the sum of the terms' magnitudes) beyond which
/// [`far_probe_negative`] trusts the sign of its radial evaluation: far above the rounding of
/// either evaluation of a polynomial of degree ≤ 20 (a few hundred units of 1.1e-16).
const PROBE_MARGIN: f64 = 1e-9;

/// Deepest subdivision level of [`far_sign`].
const FAR_MAX_LEVEL: u32 = 10;
/// Most cells [`far_sign`] examines on one level before it gives up.
const FAR_MAX_CELLS: usize = 20_000;

/// The homogeneous parts H_k of a polynomial (normalized coordinates) restricted to the six
/// faces of the cube |q|∞ = 1: on the face q_a = σ, H_k(q) is a polynomial in the other two
/// coordinates (u, v), stored densely by (i, j) for u^i v^j, i + j ≤ k.
struct FaceForms {
    degree: usize,
    /// `forms[face][k][i * (degree + 1) + j]`, face = 2·axis + (σ < 0).
    forms: Vec<Vec<Vec<f64>>>,
    /// The same forms for k ≥ 1 in groups of [`FORM_LANES`] side by side, which
    /// [`FaceForms::lower_bounds`] reads: `groups[face][g][i * (top + 1) + j]` holds the
    /// coefficient of u^i v^j of H_k, k = 1 + 4g + lane, for i + j ≤ top = 4 + 4g (zero where
    /// i + j > k or k > degree).
    groups: Vec<Vec<Vec<[f64; FORM_LANES]>>>,
    /// [`bernstein_ratios`] of the degree.
    bernstein: Vec<f64>,
}

/// Face forms processed side by side by [`FaceForms::lower_bounds`].
const FORM_LANES: usize = 4;

impl FaceForms {
    fn new(poly: &ImplicitPolynomial) -> FaceForms {
        let n = poly.degree as usize;
        let side = n + 1;
        let exps = crate::poly::exponents(poly.degree);
        let mut forms = vec![vec![vec![0.0; side * side]; n + 1]; 6];
        for (face, per_face) in forms.iter_mut().enumerate() {
            let axis = face / 2;
            let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
            let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
            let (b, c) = (b.min(c), b.max(c));
            for (e, &coef) in exps.iter().zip(&poly.coefficients) {
                let k = (e[0] + e[1] + e[2]) as usize;
                let s = if e[axis] % 2 == 1 { sign } else { 1.0 };
                if let Some(form) = per_face.get_mut(k) {
                    form[e[b] as usize * side + e[c] as usize] += s * coef;
                }
            }
        }
        let groups = forms
            .iter()
            .map(|per_face| {
                (1..=n)
                    .step_by(FORM_LANES)
                    .map(|k0| {
                        let top = k0 + FORM_LANES - 1;
                        let side_g = top + 1;
                        let mut group = vec![[0.0; FORM_LANES]; side_g * side_g];
                        for (lane, form) in per_face.iter().skip(k0).take(FORM_LANES).enumerate() {
                            let k = k0 + lane;
                            for i in 0..=k {
                                for j in 0..=k - i {
                                    group[i * side_g + j][lane] = form[i * side + j];
                                }
                            }
                        }
                        group
                    })
                    .collect()
            })
            .collect();
        FaceForms {
            degree: n,
            forms,
            groups,
            bernstein: bernstein_ratios(n),
        }
    }

    /// Lower bounds of H_k, k = 0 … n, on the patch (u, v) ∈ [uc ± w] × [vc ± w] of `face`:
    /// the Taylor expansion at the patch centre, each non-constant term bounded by its absolute
    /// value at the half width (a centred form, exact for the constant term), less a rounding
    /// margin.
    ///
    /// The forms are shifted four at a time, one lane each ([`FaceForms::groups`]), with the
    /// steps of the group's top degree: a form of lower degree k gets extra steps only where its
    /// entries are zero (i + j > k), which add zero to a coefficient that is not −0 (it starts
    /// at +0) and leave it bit for bit unchanged, so every bound is the one of the form's own
    /// steps.
    fn lower_bounds(&self, face: usize, uc: f64, vc: f64, w: f64) -> Vec<f64> {
        let n = self.degree;
        let mut out = Vec::with_capacity(n + 1);
        // H_0 is a constant: no shift, nothing spread.
        let h0 = self.forms[face][0][0];
        out.push(h0 - 0.0 - 1e-12 * (h0.abs() + h0.abs()));
        let mut d = Vec::new();
        for (g, group) in self.groups[face].iter().enumerate() {
            let k0 = 1 + g * FORM_LANES;
            let top = k0 + FORM_LANES - 1;
            let side = top + 1;
            d.clear();
            d.extend_from_slice(group);
            // Taylor shift in u (for each power j of v), then in v (for each power i of u).
            for j in 0..=top {
                let m = top - j;
                for i in 0..m {
                    for t in (i..m).rev() {
                        let next = d[(t + 1) * side + j];
                        for (a, b) in d[t * side + j].iter_mut().zip(next) {
                            *a += uc * b;
                        }
                    }
                }
            }
            for i in 0..=top {
                let m = top - i;
                for jj in 0..m {
                    for t in (jj..m).rev() {
                        let next = d[i * side + t + 1];
                        for (a, b) in d[i * side + t].iter_mut().zip(next) {
                            *a += vc * b;
                        }
                    }
                }
            }
            let mut spread = [0.0; FORM_LANES];
            let mut magnitude = d[0].map(f64::abs);
            let mut wi = 1.0;
            for i in 0..=top {
                let mut wij = wi;
                for j in 0..=(top - i) {
                    let entry = d[i * side + j];
                    for lane in 0..FORM_LANES {
                        if i + j > 0 {
                            spread[lane] += entry[lane].abs() * wij;
                        }
                        magnitude[lane] += entry[lane].abs();
                    }
                    wij *= w;
                }
                wi *= w;
            }
            for lane in 0..FORM_LANES.min(n + 1 - k0) {
                out.push(d[0][lane] - spread[lane] - 1e-12 * magnitude[lane]);
            }
        }
        out
    }
}

/// The factors C(i, j) / C(n, j) (i, j ≤ n, row-major) that turn power-basis coefficients on
/// [0, 1] into Bernstein ones, for [`positive_on_interval`].
fn bernstein_ratios(n: usize) -> Vec<f64> {
    let binom = |a: usize, b: usize| -> f64 {
        let mut r = 1.0;
        for t in 0..b {
            r = r * (a - t) as f64 / (t + 1) as f64;
        }
        r
    };
    let mut ratios = vec![0.0; (n + 1) * (n + 1)];
    for i in 0..=n {
        for j in 0..=i {
            ratios[i * (n + 1) + j] = binom(i, j) / binom(n, j);
        }
    }
    ratios
}

/// Whether Σ_k c_k s^k > 0 for every s in [s0, s1] (0 < s0 ≤ s1), by the Bernstein
/// coefficients on that interval: all positive proves it (the polynomial is a convex
/// combination of them); otherwise the answer is "not proved". `ratios` are
/// [`bernstein_ratios`] of the degree `c.len() − 1`.
fn positive_on_interval(c: &[f64], ratios: &[f64], s0: f64, s1: f64) -> bool {
    let n = c.len().saturating_sub(1);
    let mut g = c.to_vec();
    // Taylor shift by s0, then scale by h = s1 − s0: g(t) = Σ c_k (s0 + h t)^k.
    for i in 0..n {
        for t in (i..n).rev() {
            g[t] += s0 * g[t + 1];
        }
    }
    let h = s1 - s0;
    let mut hp = 1.0;
    for gj in g.iter_mut() {
        *gj *= hp;
        hp *= h;
    }
    // Power basis on [0, 1] to Bernstein: b_i = Σ_{j ≤ i} C(i, j) / C(n, j) g_j.
    let magnitude: f64 = g.iter().map(|v| v.abs()).sum();
    (0..=n).all(|i| {
        let row = &ratios[i * (n + 1)..=i * (n + 1) + i];
        let b: f64 = row.iter().zip(&g).map(|(r, gj)| r * gj).sum();
        b.is_finite() && b > 1e-12 * magnitude
    })
}

/// What one octree cell of [`far_sign`] or [`shell_sign`] settles about f.
enum Verdict {
    /// f > 0 on the cell (certified) or the cell is outside the region: dropped.
    Drop,
    /// f < 0 at a point of the cell.
    Negative,
    /// Neither: refine.
    Split,
}

/// The shell's sign once a level's verdicts are in: negative as soon as one cell is; at the
/// last level positive only if every cell was dropped, else unknown; `None` to refine further.
fn level_outcome(verdicts: &[Verdict], last_level: bool) -> Option<Shell> {
    if verdicts.iter().any(|v| matches!(v, Verdict::Negative)) {
        return Some(Shell::Negative);
    }
    if !last_level {
        return None;
    }
    Some(if verdicts.iter().all(|v| matches!(v, Verdict::Drop)) {
        Shell::Positive
    } else {
        Shell::Unknown
    })
}

/// A frustum of the shell between |p̂|∞ = s₀ and s₁: face, patch centre u, v, patch half width,
/// radial interval s₀, s₁.
type Frustum = (usize, f64, f64, f64, f64, f64);

/// The starting frustums of the shell s_lo ≤ |p̂|∞ ≤ s_hi: each whole face of the cube, its
/// radial range cut where s doubles (a flat frustum per face when s_lo = s_hi: the surface of
/// the cube |p̂|∞ = s_lo).
fn whole_faces(s_lo: f64, s_hi: f64) -> Vec<Frustum> {
    let mut cells = Vec::new();
    for face in 0..6 {
        if s_hi == s_lo {
            cells.push((face, 0.0, 0.0, 1.0, s_lo, s_lo));
            continue;
        }
        let mut s0 = s_lo;
        while s0 < s_hi {
            let s1 = (2.0 * s0).min(s_hi);
            cells.push((face, 0.0, 0.0, 1.0, s0, s1));
            s0 = s1;
        }
    }
    cells
}

/// The sign of f (normalized coordinates) on the points whose box norm |p|∞ lies in
/// [s_lo, s_hi] (0 < s_lo; s_lo = s_hi gives the cube's surface, whose frustums are flat and
/// split across only; an empty range is positive): each point is p = s·q with q on a face of
/// the cube |q|∞ = 1, and f(s·q) = Σ_k s^k H_k(q), so lower bounds of each H_k on a patch of a
/// face give a polynomial in s below f on the whole frustum (patch × [s0, s1]), which is
/// positive when its Bernstein coefficients are. Frustums not proved positive are split (the patch in four, the
/// radial interval in two, geometrically) level by level, and the first frustum whose centre
/// has f < 0 stops the search. The patches are exact in s, which is why this proves f > 0 far
/// from the data where the box enclosures of [`shell_sign`] cannot (f grows like sⁿ there, and
/// the box forms lose that cancellation). The verdict does not depend on the thread count.
fn far_sign(poly: &ImplicitPolynomial, s_lo: f64, s_hi: f64) -> Shell {
    use rayon::prelude::*;
    if !(s_lo > 0.0 && s_hi.is_finite()) {
        return Shell::Unknown;
    }
    if s_hi < s_lo {
        return Shell::Positive;
    }
    if poly.coefficients.iter().any(|c| !c.is_finite()) {
        return Shell::Unknown;
    }
    let forms = FaceForms::new(poly);
    let mut cells = whole_faces(s_lo, s_hi);
    for level in 0..=FAR_MAX_LEVEL {
        if cells.is_empty() {
            return Shell::Positive;
        }
        if cells.len() > FAR_MAX_CELLS {
            return Shell::Unknown;
        }
        let by_bernstein = std::sync::atomic::AtomicUsize::new(0);
        let verdicts: Vec<Verdict> = cells
            .par_iter()
            .map(|&(face, uc, vc, w, s0, s1)| {
                let lower = forms.lower_bounds(face, uc, vc, w);
                if positive_on_interval(&lower, &forms.bernstein, s0, s1) {
                    by_bernstein.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    return Verdict::Drop;
                }
                let axis = face / 2;
                let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
                let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
                let (b, c) = (b.min(c), b.max(c));
                // The frustum's bounding box, and the Taylor-form enclosure of f on it: second
                // order, so it also proves f > 0 near a shallow positive minimum, where the
                // per-degree bounds above (first order in the patch size) cannot.
                let span = |lo: f64, hi: f64| {
                    let v = [lo * s0, lo * s1, hi * s0, hi * s1];
                    (
                        v.iter().copied().fold(f64::INFINITY, f64::min),
                        v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                    )
                };
                let mut bmin = [0.0; 3];
                let mut bmax = [0.0; 3];
                let (lo_a, hi_a) = if sign > 0.0 { (s0, s1) } else { (-s1, -s0) };
                bmin[axis] = lo_a;
                bmax[axis] = hi_a;
                (bmin[b], bmax[b]) = span(uc - w, uc + w);
                (bmin[c], bmax[c]) = span(vc - w, vc + w);
                let (lo, _) = poly.bounds_on_box(&Aabb {
                    min: bmin,
                    max: bmax,
                });
                if lo > 0.0 {
                    return Verdict::Drop;
                }
                let s = (s0 * s1).sqrt();
                let mut p = [0.0; 3];
                p[axis] = sign * s;
                p[b] = uc * s;
                p[c] = vc * s;
                if poly.value(p) < 0.0 {
                    Verdict::Negative
                } else {
                    Verdict::Split
                }
            })
            .collect();
        log::trace!("      far_sign {s_lo:.2}..{s_hi:.2} level {level}: {} frustums, {} by bernstein, {} split", cells.len(), by_bernstein.into_inner(), verdicts.iter().filter(|v| matches!(v, Verdict::Split)).count());
        if let Some(shell) = level_outcome(&verdicts, level == FAR_MAX_LEVEL) {
            return shell;
        }
        cells = cells
            .iter()
            .zip(&verdicts)
            .filter(|(_, v)| matches!(v, Verdict::Split))
            .flat_map(|(&(face, uc, vc, w, s0, s1), _)| {
                // Split so that the frustums stay about as wide as they are deep: the patch
                // (tangential extent 2w·s) in four, the radial interval in two, or both.
                let sm = (s0 * s1).sqrt();
                let tangential = 2.0 * w * sm;
                let radial = s1 - s0;
                let split_patch = tangential > 0.75 * radial;
                let split_radial = radial > 0.75 * tangential;
                let h = if split_patch { 0.5 * w } else { w };
                let patches: Vec<(f64, f64)> = if split_patch {
                    vec![
                        (uc - h, vc - h),
                        (uc + h, vc - h),
                        (uc - h, vc + h),
                        (uc + h, vc + h),
                    ]
                } else {
                    vec![(uc, vc)]
                };
                let radials: Vec<(f64, f64)> = if split_radial {
                    vec![(s0, sm), (sm, s1)]
                } else {
                    vec![(s0, s1)]
                };
                let mut children = Vec::with_capacity(8);
                for &(a, b) in &radials {
                    for &(u, v) in &patches {
                        children.push((face, u, v, h, a, b));
                    }
                }
                children
            })
            .collect();
    }
    Shell::Unknown
}

/// [`far_positive`]'s frustums are split across while wider than this times their depth: long
/// thin frustums suit it, since its bound is exact along the rays and loose only across them.
const FAR_POSITIVE_RATIO: f64 = 0.25;

/// Whether f > 0 is certified on the points with box norm in [s_lo, s_hi] (0 < s_lo < s_hi
/// finite) by the Bernstein test of [`far_sign`]'s face forms alone: no point values, no box
/// enclosures (a point value < 0 at a frustum's centre ends the search). A frustum not proved
/// positive is split across (the patch in four) while it is
/// wider than `ratio` times its depth, else along (the radial interval in two); `false` means
/// "not proved" (the refinement limits were reached). Used only as a certificate that lets the
/// mesher skip cells ([`FarCulled`]), so it may give up where [`far_sign`] would not.
fn far_positive(poly: &ImplicitPolynomial, s_lo: f64, s_hi: f64, ratio: f64) -> bool {
    use rayon::prelude::*;
    if !(s_lo > 0.0 && s_hi.is_finite()) || poly.coefficients.iter().any(|c| !c.is_finite()) {
        return false;
    }
    let forms = FaceForms::new(poly);
    let mut cells = whole_faces(s_lo, s_hi);
    let mut total = 0usize;
    for level in 0..=2 * FAR_MAX_LEVEL {
        if cells.is_empty() {
            log::trace!("      far_positive {s_lo:.2}..{s_hi:.2} ratio {ratio}: {total} frustums, {level} levels");
            return true;
        }
        if cells.len() > 4 * FAR_MAX_CELLS {
            break;
        }
        total += cells.len();
        let negative = std::sync::atomic::AtomicBool::new(false);
        cells = cells
            .par_iter()
            .flat_map_iter(|&(face, uc, vc, w, s0, s1)| {
                let lower = forms.lower_bounds(face, uc, vc, w);
                let mut children = Vec::new();
                if positive_on_interval(&lower, &forms.bernstein, s0, s1) {
                    return children;
                }
                let sm = (s0 * s1).sqrt();
                // f < 0 at the frustum's centre: nothing to prove, stop early.
                let axis = face / 2;
                let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
                let (b, c) = (b.min(c), b.max(c));
                let mut p = [0.0; 3];
                p[axis] = if face.is_multiple_of(2) { sm } else { -sm };
                p[b] = uc * sm;
                p[c] = vc * sm;
                if poly.value(p) < 0.0 {
                    negative.store(true, std::sync::atomic::Ordering::Relaxed);
                    return children;
                }
                if 2.0 * w * sm > ratio * (s1 - s0) {
                    let h = 0.5 * w;
                    for (u, v) in [
                        (uc - h, vc - h),
                        (uc + h, vc - h),
                        (uc - h, vc + h),
                        (uc + h, vc + h),
                    ] {
                        children.push((face, u, v, h, s0, s1));
                    }
                } else {
                    children.push((face, uc, vc, w, s0, sm));
                    children.push((face, uc, vc, w, sm, s1));
                }
                children
            })
            .collect();
        if negative.into_inner() {
            break;
        }
    }
    log::trace!("      far_positive {s_lo:.2}..{s_hi:.2} ratio {ratio}: {total} frustums, gave up");
    false
}

/// Deepest level of [`shell_sign`]'s octree.
const SHELL_MAX_LEVEL: u32 = 8;
/// Most cells [`shell_sign`] examines on one level before it gives up.
const SHELL_MAX_CELLS: usize = 40_000;

/// The sign of f (normalized coordinates) on the shell [−outer, outer]³ minus the open box
/// (−hole, hole)³: an octree over the outer box, level by level, drops the cells inside the
/// hole and those whose guaranteed enclosure (the Taylor form of
/// [`ImplicitFunction::bounds_on_box`]) is positive, and stops at the first cell centre in the
/// shell where f < 0. The verdict does not depend on the thread count (each level is decided
/// as a whole).
fn shell_sign(poly: &ImplicitPolynomial, outer: f64, hole: f64) -> Shell {
    use rayon::prelude::*;
    let mut cells: Vec<[f64; 3]> = vec![[0.0; 3]];
    let mut half = outer;
    for level in 0..=SHELL_MAX_LEVEL {
        if cells.is_empty() {
            return Shell::Positive;
        }
        if cells.len() > SHELL_MAX_CELLS {
            return Shell::Unknown;
        }
        let h = half;
        let verdicts: Vec<Verdict> = cells
            .par_iter()
            .map(|c| {
                let far = c.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                if far + h <= hole {
                    return Verdict::Drop;
                }
                let b = Aabb {
                    min: c.map(|v| v - h),
                    max: c.map(|v| v + h),
                };
                let (lo, _) = poly.bounds_on_box(&b);
                if lo > 0.0 {
                    return Verdict::Drop;
                }
                if far > hole && poly.value(*c) < 0.0 {
                    return Verdict::Negative;
                }
                Verdict::Split
            })
            .collect();
        if let Some(shell) = level_outcome(&verdicts, level == SHELL_MAX_LEVEL) {
            return shell;
        }
        let q = 0.5 * h;
        cells = cells
            .iter()
            .zip(&verdicts)
            .filter(|(_, v)| matches!(v, Verdict::Split))
            .flat_map(|(c, _)| {
                (0..8)
                    .map(move |k| [0, 1, 2].map(|a| c[a] + if (k >> a) & 1 == 1 { q } else { -q }))
            })
            .collect();
        half = q;
    }
    Shell::Unknown
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sign_grid_counts_two_spheres() {
        // f = ((x − 1.5)² + y² + z² − 0.25)((x + 1.5)² + y² + z² − 0.25) > 0 far away: two
        // components, not touching the box [−4, 4]³.
        let poly = two_spheres([1.5, 0.0, 0.0], 0.5, [-1.5, 0.0, 0.0], 0.5);
        let zero_set = sign_grid_zero_set(&poly, 4.0, 64);
        assert_eq!(zero_set.components.len(), 2);
        assert!(!zero_set.touches_box);
        let (meshed, _) = coarse_zero_set(&poly, 4.0);
        assert_eq!(meshed.components.len(), 2);
        // The spheres reach |x| = 2: f < 0 in the shell outside (−1.6, 1.6)³, and f > 0 is
        // certified outside (−2.5, 2.5)³.
        assert_eq!(shell_sign(&poly, 4.0, 1.6), Shell::Negative);
        assert_eq!(shell_sign(&poly, 4.0, 2.5), Shell::Positive);
        // The frustum certificate agrees, out to a far radius, and so does the probe.
        assert_eq!(far_sign(&poly, 1.6, 4.0), Shell::Negative);
        assert_eq!(far_sign(&poly, 2.5, 50.0), Shell::Positive);
        assert!(far_probe_negative(&poly, 1.6, 4.0));
        assert!(!far_probe_negative(&poly, 2.5, 50.0));
    }

    /// The product of two spheres' equations (centres `a`, `b`, radii `ra`, `rb`), a quartic.
    fn two_spheres(a: [f64; 3], ra: f64, b: [f64; 3], rb: f64) -> ImplicitPolynomial {
        let sphere = |c: [f64; 3], r: f64| {
            let mut q = vec![0.0; 10];
            q[0] = c.iter().map(|v| v * v).sum::<f64>() - r * r;
            for (axis, e) in [[1, 0, 0], [0, 1, 0], [0, 0, 1]].into_iter().enumerate() {
                q[crate::poly::monomial_index(e)] = -2.0 * c[axis];
                let mut sq = [0; 3];
                sq[axis] = 2;
                q[crate::poly::monomial_index(sq)] = 1.0;
            }
            q
        };
        let (qa, qb) = (sphere(a, ra), sphere(b, rb));
        let e2 = crate::poly::exponents(2);
        let mut coefficients = vec![0.0; crate::poly::n_coefficients(4)];
        for (l, el) in e2.iter().enumerate() {
            for (m, em) in e2.iter().enumerate() {
                let idx =
                    crate::poly::monomial_index([el[0] + em[0], el[1] + em[1], el[2] + em[2]]);
                coefficients[idx] += qa[l] * qb[m];
            }
        }
        ImplicitPolynomial {
            degree: 4,
            coefficients,
            center: [0.0; 3],
            scale: 1.0,
        }
    }

    #[test]
    fn far_checks_find_a_distant_piece_and_certify_its_absence() {
        // The unit sphere and a sphere of radius 0.5 centred at (0, −7, 3): the far piece has
        // box norms 6.5 … 7.5.
        let poly = two_spheres([0.0; 3], 1.0, [0.0, -7.0, 3.0], 0.5);
        let radius = poly.containment_radius().unwrap_or(f64::INFINITY);
        assert!(radius > 7.5, "containment radius {radius}");
        assert!(far_probe_negative(&poly, OUTER_BOX, radius));
        assert_eq!(far_sign(&poly, OUTER_BOX, radius), Shell::Negative);
        // Between the two pieces, and beyond the far one, f > 0 is certified.
        assert_eq!(far_sign(&poly, 1.2, 5.5), Shell::Positive);
        assert_eq!(far_sign(&poly, 8.0, radius.max(9.0)), Shell::Positive);
        assert!(!far_probe_negative(&poly, 1.2, 5.5));
        // An empty range is trivially positive; a non-finite one is not decided.
        assert_eq!(far_sign(&poly, 4.0, 3.0), Shell::Positive);
        assert_eq!(far_sign(&poly, 4.0, f64::INFINITY), Shell::Unknown);
    }

    #[test]
    fn cube_surface_sign_and_the_component_outside_the_inner_box() {
        // The unit sphere and a sphere of radius 0.5 centred at (2.5, 0, 0): f > 0 on the
        // surface |p|∞ = 1.6 (between them), f < 0 on the surface |p|∞ = 2.5 (inside the
        // second), and on |p|∞ = 1 the first sphere crosses the faces.
        let poly = two_spheres([0.0; 3], 1.0, [2.5, 0.0, 0.0], 0.5);
        assert_eq!(far_sign(&poly, INNER_BOX, INNER_BOX), Shell::Positive);
        assert_eq!(far_sign(&poly, 2.5, 2.5), Shell::Negative);
        assert_ne!(far_sign(&poly, 1.0, 1.0), Shell::Positive);
        // R > 4, f > 0 beyond 4, and f < 0 in the shell 1.6 … 4 with positive inner faces:
        // the check fails before any mesh (no mesher reported). The data, the unit sphere,
        // is one piece.
        let radius = poly.containment_radius().unwrap_or(f64::INFINITY);
        let cloud = crate::fit::study::sample(
            crate::fit::study::Shape::Sphere,
            crate::fit::study::Variant::Clean,
            3000,
            1,
        );
        let norm = Normalization {
            center: [0.0; 3],
            scale: 1.0,
        };
        let pieces = DataPieces::new(&cloud, &norm).expect("indexed");
        assert_eq!(pieces.n_pieces, 1);
        assert!(radius > OUTER_BOX && radius.is_finite(), "radius {radius}");
        assert!(far_positive(&poly, OUTER_BOX, radius, FAR_POSITIVE_RATIO));
        assert_eq!(zero_set_check(&poly, radius, &pieces), (false, None));
        // The meshes agree: [−R, R]³ holds two components, one more than the data's pieces.
        let (outer, _) = coarse_zero_set_culled(&poly, radius, Some(OUTER_BOX));
        assert_eq!(outer.components.len(), 2);
        assert!(!outer.touches_box);
    }

    /// The mesh of `poly` in [−half, half]³ with and without the far cells skipped.
    fn culled_and_plain(
        poly: &ImplicitPolynomial,
        half: f64,
        beyond: f64,
    ) -> (crate::mesh::TriangleMesh, crate::mesh::TriangleMesh) {
        use crate::polygonize::{polygonize, PolygonizeParams, Simplification};
        let region = Aabb {
            min: [-half; 3],
            max: [half; 3],
        };
        let params = PolygonizeParams {
            depth: CHECK_DEPTH,
            simplification: Simplification::None,
            ..Default::default()
        };
        let culled = FarCulled {
            poly,
            beyond,
            reach: 2.0 * half / f64::from(1u32 << CHECK_DEPTH),
        };
        let a = polygonize(&culled, &region, &params).map(|o| o.mesh);
        let b = polygonize(poly, &region, &params).map(|o| o.mesh);
        (a.unwrap_or_default(), b.unwrap_or_default())
    }

    #[test]
    fn skipping_certified_far_cells_keeps_the_mesh() {
        // Two spheres, the far one at box norms 6.5 … 7.5: f > 0 is certified beyond 8, and the
        // mesh of [−12, 12]³ is the same, vertex for vertex, when the mesher skips those cells.
        let poly = two_spheres([0.0; 3], 1.0, [0.0, -7.0, 3.0], 0.5);
        assert!(far_positive(&poly, 8.0, 12.0, FAR_POSITIVE_RATIO));
        assert!(!far_positive(&poly, 4.0, 12.0, FAR_POSITIVE_RATIO));
        let (culled, plain) = culled_and_plain(&poly, 12.0, 8.0);
        assert!(!plain.positions.is_empty());
        assert_eq!(culled, plain);
        // A degree-8 fit of the heart (automatic κ, normalized coordinates), meshed in
        // [−R, R]³ as rule (d) does, with f > 0 certified from box norm 4 to R.
        let cloud = crate::fit::study::sample(
            crate::fit::study::Shape::Heart,
            crate::fit::study::Variant::Clean,
            1500,
            1,
        );
        let params = crate::fit::FitParams {
            degree: 8,
            ..Default::default()
        };
        let model = crate::fit::fit(&cloud, &params).unwrap_or_else(|e| panic!("fit: {e}"));
        let poly = unit_poly(8, &model.polynomial.coefficients);
        let radius = poly.containment_radius().unwrap_or(0.0);
        assert!(radius > OUTER_BOX, "containment radius {radius}");
        assert!(far_positive(&poly, OUTER_BOX, radius, FAR_POSITIVE_RATIO));
        let (culled, plain) = culled_and_plain(&poly, radius, OUTER_BOX);
        assert!(!plain.positions.is_empty());
        assert_eq!(culled, plain);
    }

    #[test]
    fn bernstein_test_proves_positivity_only_when_true() {
        // (s − 2)² + 0.1 > 0 everywhere; (s − 2)² − 0.1 < 0 near s = 2.
        let plus = [4.1, -4.0, 1.0];
        let minus = [3.9, -4.0, 1.0];
        // (Bernstein coefficients prove positivity on a short enough interval only.)
        let ratios = bernstein_ratios(2);
        assert!(positive_on_interval(&plus, &ratios, 1.9, 2.1));
        assert!(!positive_on_interval(&minus, &ratios, 1.9, 2.1));
        // Away from its roots (2 ± 0.316) the second one is positive, and is proved so.
        assert!(positive_on_interval(&minus, &ratios, 2.5, 4.0));
        assert!(positive_on_interval(&minus, &ratios, 0.5, 1.5));
    }

    #[test]
    fn face_forms_bound_the_homogeneous_parts() {
        // Lower bounds of H_k on a patch are below H_k at sampled points of the patch.
        let poly = two_spheres([0.3, -0.2, 0.1], 1.0, [0.0, -7.0, 3.0], 0.5);
        let forms = FaceForms::new(&poly);
        let exps = crate::poly::exponents(4);
        for face in 0..6usize {
            let axis = face / 2;
            let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
            let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
            let (b, c) = (b.min(c), b.max(c));
            let (uc, vc, w) = (0.25, -0.5, 0.25);
            let lower = forms.lower_bounds(face, uc, vc, w);
            for iu in 0..=4 {
                for iv in 0..=4 {
                    let u = uc - w + 0.5 * w * iu as f64;
                    let v = vc - w + 0.5 * w * iv as f64;
                    let mut q = [0.0; 3];
                    q[axis] = sign;
                    q[b] = u;
                    q[c] = v;
                    for (k, lo) in lower.iter().enumerate() {
                        let h: f64 = exps
                            .iter()
                            .zip(&poly.coefficients)
                            .filter(|(e, _)| (e[0] + e[1] + e[2]) as usize == k)
                            .map(|(e, a)| {
                                a * q[0].powi(e[0] as i32)
                                    * q[1].powi(e[1] as i32)
                                    * q[2].powi(e[2] as i32)
                            })
                            .sum();
                        assert!(
                            *lo <= h + 1e-12,
                            "face {face} k {k}: bound {lo} > value {h}"
                        );
                    }
                }
            }
        }
    }
}
