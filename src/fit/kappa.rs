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
//! from the smallest up, and each stops at its first failing check. For (d) the box [−4, 4]³
//! is not meshed when the enclosures of the polygonize stage prove f > 0 on it outside the inner
//! box and the inner mesh stays off the inner box's faces (then both boxes hold the same zero
//! set, which (c) accepted).
//!
//! "Connected pieces of the data": the components of the graph joining data points closer than
//! 0.2 (normalized units, the same tolerance as (c)) among their 12 nearest neighbours, on at
//! most 20,000 points taken at a fixed stride. Data closer than 0.2 can be bridged by a zero set
//! that stays within 0.2 of the data, so it fairly counts as one piece.

use kiddo::{ImmutableKdTree, SquaredEuclidean};

use super::solve;
use super::system::{Normalization, System};
use super::FitError;
use crate::cloud::{Aabb, OrientedCloud};
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
            // (a): positive here and at every larger grid value.
            let mut candidates = Vec::new();
            for i in (0..kappas.len()).rev() {
                let g = solve_at(i);
                let ok = positive(&g);
                grid[i] = Some(g);
                if !ok {
                    break;
                }
                candidates.push(i);
            }
            candidates.reverse();
            let mut data: Option<Option<DataPieces>> = None;
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
                if data.is_none() {
                    data = Some(DataPieces::new(cloud, norm));
                }
                let Some(Some(pieces)) = data.as_ref() else {
                    warnings.push("kappa rule stable: the data could not be indexed, so the zero-set checks (c)/(d) were skipped".to_string());
                    chosen = Some(i);
                    break;
                };
                let (pass, used) = zero_set_check(&poly, radius, pieces);
                zero_set_checked = true;
                mesher = Some(used);
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
        let mut parent: Vec<u32> = (0..points.len() as u32).collect();
        let k = std::num::NonZeroUsize::new(12).unwrap_or(std::num::NonZeroUsize::MIN);
        for (i, p) in points.iter().enumerate() {
            let neighbours = tree
                .query(p)
                .nearest_n::<SquaredEuclidean<f64>>(k)
                .execute();
            for nb in neighbours {
                if nb.distance <= NEAR_DATA * NEAR_DATA {
                    union(&mut parent, i as u32, nb.item);
                }
            }
        }
        let (labels, n_pieces) = compact_labels(&mut parent);
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

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let grand = parent[parent[i as usize] as usize];
        parent[i as usize] = grand;
        i = grand;
    }
    i
}

fn union(parent: &mut [u32], a: u32, b: u32) {
    let (ra, rb) = (find(parent, a), find(parent, b));
    if ra != rb {
        // Smaller root wins: labels do not depend on visiting order details.
        let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
        parent[hi as usize] = lo;
    }
}

/// Labels 0.. in order of first appearance, and their count.
fn compact_labels(parent: &mut [u32]) -> (Vec<u32>, usize) {
    let mut map = std::collections::HashMap::new();
    let mut labels = Vec::with_capacity(parent.len());
    for i in 0..parent.len() as u32 {
        let root = find(parent, i);
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
    use crate::polygonize::{polygonize, PolygonizeParams};
    let region = Aabb {
        min: [-half; 3],
        max: [half; 3],
    };
    let params = PolygonizeParams {
        depth: CHECK_DEPTH,
        ..Default::default()
    };
    let cell = 2.0 * half / f64::from(1u32 << CHECK_DEPTH);
    if let Ok(out) = polygonize(poly, &region, &params) {
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

/// Rules (c) and (d) on coarse meshes of the zero set of `poly` (normalized coordinates).
fn zero_set_check(poly: &ImplicitPolynomial, radius: f64, data: &DataPieces) -> (bool, Mesher) {
    // (c): in the inner box, one component per data piece, each within NEAR_DATA of the data
    // (its closest point; a closed zero set must bridge holes in the data, so not every point
    // can be near it).
    let (inner, mesher) = coarse_zero_set(poly, INNER_BOX);
    if inner.components.len() != data.n_pieces {
        return (false, mesher);
    }
    let mut piece_seen = vec![false; data.n_pieces];
    for component in &inner.components {
        let closest = component
            .iter()
            .map(|p| data.nearest(*p))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        match closest {
            Some((dist, piece)) if dist <= NEAR_DATA + inner.slack => {
                match piece_seen.get_mut(piece as usize) {
                    Some(seen) if !*seen => *seen = true,
                    _ => return (false, mesher),
                }
            }
            _ => return (false, mesher),
        }
    }
    // (d): in [−4, 4]³, and in [−R, R]³ when R is larger, nothing else and no contact with the
    // box. The fixed box is checked on its own because a coarse mesh of a large [−R, R]³ can
    // miss a small stray piece.
    //
    // Shortcut, certified by the Taylor-form enclosures of the polygonize stage ([`shell_sign`]):
    // if f > 0 on [−4, 4]³ outside the inner box and the inner mesh stays off the inner box's
    // faces, the [−4, 4]³ zero set is the inner one, which (c) accepted, so that box need not be
    // meshed. (The same certificate for [−R, R]³ outside [−4, 4]³ was tried: on the bunny the
    // far field of f is so flat that it neither proves f > 0 nor finds f < 0 by level 8, and
    // costs more than the mesh.)
    let mut mesher = mesher;
    let outer_shell = if inner.touches_box {
        Shell::Unknown
    } else {
        shell_sign(poly, OUTER_BOX, INNER_BOX)
    };
    if outer_shell != Shell::Positive {
        let (outer, used) = coarse_zero_set(poly, OUTER_BOX);
        mesher = used;
        if outer.touches_box || outer.components.len() != data.n_pieces {
            return (false, mesher);
        }
    }
    if radius > OUTER_BOX {
        let (outer, used) = coarse_zero_set(poly, radius);
        mesher = used;
        if outer.touches_box || outer.components.len() != data.n_pieces {
            return (false, mesher);
        }
    }
    (true, mesher)
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

/// Deepest level of [`shell_sign`]'s octree.
const SHELL_MAX_LEVEL: u32 = 8;
/// Most cells [`shell_sign`] examines on one level before it gives up.
const SHELL_MAX_CELLS: usize = 40_000;

/// The sign of f (normalized coordinates) on the shell [−outer, outer]³ minus the open box
/// (−hole, hole)³: an octree over the outer box, level by level, drops the cells inside the
/// hole and those whose guaranteed enclosure (the polygonize stage's Taylor form,
/// [`ImplicitFunction::bounds_on_box`]) is positive, and stops at the first cell centre in the
/// shell where f < 0. The verdict does not depend on the thread count (each level is decided
/// as a whole).
fn shell_sign(poly: &ImplicitPolynomial, outer: f64, hole: f64) -> Shell {
    use crate::polygonize::ImplicitFunction;
    use rayon::prelude::*;
    enum Cell {
        Drop,
        Negative,
        Split,
    }
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
        let verdicts: Vec<Cell> = cells
            .par_iter()
            .map(|c| {
                let far = c.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                if far + h <= hole {
                    return Cell::Drop;
                }
                let b = Aabb {
                    min: c.map(|v| v - h),
                    max: c.map(|v| v + h),
                };
                let (lo, _) = poly.bounds_on_box(&b);
                if lo > 0.0 {
                    return Cell::Drop;
                }
                if far > hole && poly.value(*c) < 0.0 {
                    return Cell::Negative;
                }
                Cell::Split
            })
            .collect();
        if verdicts.iter().any(|v| matches!(v, Cell::Negative)) {
            return Shell::Negative;
        }
        if level == SHELL_MAX_LEVEL {
            return if verdicts.iter().all(|v| matches!(v, Cell::Drop)) {
                Shell::Positive
            } else {
                Shell::Unknown
            };
        }
        let q = 0.5 * h;
        cells = cells
            .iter()
            .zip(&verdicts)
            .filter(|(_, v)| matches!(v, Cell::Split))
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
        let sphere = |cx: f64| {
            let mut c = vec![0.0; 10];
            c[0] = cx * cx - 0.25;
            c[1] = -2.0 * cx;
            c[4] = 1.0;
            c[7] = 1.0;
            c[9] = 1.0;
            c
        };
        let (a, b) = (sphere(1.5), sphere(-1.5));
        // Product of two quadrics in the paper's order, by exponents.
        let e2 = crate::poly::exponents(2);
        let mut coefficients = vec![0.0; crate::poly::n_coefficients(4)];
        for (l, el) in e2.iter().enumerate() {
            for (m, em) in e2.iter().enumerate() {
                let idx =
                    crate::poly::monomial_index([el[0] + em[0], el[1] + em[1], el[2] + em[2]]);
                coefficients[idx] += a[l] * b[m];
            }
        }
        let poly = ImplicitPolynomial {
            degree: 4,
            coefficients,
            center: [0.0; 3],
            scale: 1.0,
        };
        let zero_set = sign_grid_zero_set(&poly, 4.0, 64);
        assert_eq!(zero_set.components.len(), 2);
        assert!(!zero_set.touches_box);
        let (meshed, _) = coarse_zero_set(&poly, 4.0);
        assert_eq!(meshed.components.len(), 2);
        // The spheres reach |x| = 2: f < 0 in the shell outside (−1.6, 1.6)³, and f > 0 is
        // certified outside (−2.5, 2.5)³.
        assert_eq!(shell_sign(&poly, 4.0, 1.6), Shell::Negative);
        assert_eq!(shell_sign(&poly, 4.0, 2.5), Shell::Positive);
    }
}
