//! Automatic κ for 3LRR: the grid 0, 1e-8 … 1 (four steps a decade) and the two rules.
//!
//! Input: the accumulated system (MᵀM, Mᵀb, D), the normalization and the data. Output: the
//! chosen κ, its coefficients, and warnings. Every grid value reuses the same MᵀM; only κD changes.
//!
//! - `paper` (section 6.3): the smallest grid κ whose leading form H_n is positive on the unit
//!   sphere.
//! - `stable`: the smallest grid κ such that
//!   (a) H_n is positive at that κ and at every larger grid value (positivity is not monotone
//!       in κ, so a lone positive value between negative ones is rejected);
//!   (b) a containment radius R exists: on |p̂| = r, f ≥ H_min·rⁿ − Σ_{k<n} ‖H_k‖·r^k, so the zero
//!       set lies in |p̂| < R (reported);
//!   (c) the zero set, meshed coarsely in the normalized box [−1.6, 1.6]³, has one component per
//!       connected piece of the data, each within 0.2 of the data;
//!   (d) in [−B, B]³, B = max(4, R), it has no other component and does not touch the box.
//!   (c) and (d) need the polygonize stage; while it reports that it is unavailable they are
//!   skipped and the diagnostics say so.
//!
//! If no grid value qualifies, κ = 1e-2 is used and flagged.
//!
//! "Connected pieces of the data": the components of the graph joining data points closer than
//! 0.2 (normalized units, the same tolerance as (c)) among their 12 nearest neighbours, on at
//! most 20,000 points taken at a fixed stride. A zero set that stays within 0.2 of the data
//! cannot jump a gap wider than 0.4, so pieces closer than 0.2 are fairly counted as one.

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
    let grid: Vec<GridFit> = kappa_grid()
        .into_iter()
        .map(|kappa| {
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
        })
        .collect();
    let positive = |g: &GridFit| g.coefficients.is_some() && g.leading_min > 0.0;
    let mut warnings = Vec::new();
    let mut zero_set_checked = false;
    let chosen = match rule {
        super::KappaRule::Paper => grid.iter().position(positive),
        super::KappaRule::Stable => {
            // (a): positive here and at every larger grid value.
            let mut candidates = Vec::new();
            for i in (0..grid.len()).rev() {
                if !positive(&grid[i]) {
                    break;
                }
                candidates.push(i);
            }
            candidates.reverse();
            let mut data: Option<Option<DataPieces>> = None;
            let mut chosen = None;
            let mut unavailable = None;
            for &i in &candidates {
                let Some(coefficients) = grid[i].coefficients.as_ref() else {
                    continue;
                };
                let poly = unit_poly(degree, coefficients);
                // (b): certified containment radius.
                let Some(radius) = poly.containment_radius_with(grid[i].leading_min) else {
                    continue;
                };
                if data.is_none() {
                    data = Some(DataPieces::new(cloud, norm));
                }
                let check = match data.as_ref() {
                    Some(Some(pieces)) => zero_set_check(&poly, radius, pieces),
                    _ => ZeroSetCheck::Unavailable("the data could not be indexed".to_string()),
                };
                match check {
                    ZeroSetCheck::Pass => {
                        zero_set_checked = true;
                        chosen = Some(i);
                        break;
                    }
                    ZeroSetCheck::Fail => zero_set_checked = true,
                    ZeroSetCheck::Unavailable(reason) => {
                        unavailable = Some(reason);
                        chosen = Some(i);
                        break;
                    }
                }
            }
            if let Some(reason) = unavailable {
                warnings.push(format!(
                    "kappa rule stable checked only (a) positivity at this and every larger kappa and (b) the containment radius; the zero-set checks (c)/(d) were skipped: {reason}"
                ));
            }
            chosen
        }
    };
    match chosen {
        Some(i) => {
            let coefficients = grid[i].coefficients.clone().unwrap_or_default();
            Ok(Selection {
                kappa: grid[i].kappa,
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

/// Outcome of the zero-set checks (c)/(d).
enum ZeroSetCheck {
    Pass,
    Fail,
    /// The polygonize stage could not run (not built, or refused the region).
    Unavailable(String),
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

/// Components of a triangle mesh by shared vertices, after welding vertices that coincide to
/// 1e-9 of the box (meshers may duplicate vertices on cell faces). Returns per-vertex labels.
fn mesh_components(positions: &[[f64; 3]], triangles: &[[u32; 3]], weld: f64) -> (Vec<u32>, usize) {
    let mut key_to_id = std::collections::HashMap::new();
    let mut welded = Vec::with_capacity(positions.len());
    for p in positions {
        let key = p.map(|c| (c / weld).round() as i64);
        let next = key_to_id.len() as u32;
        welded.push(*key_to_id.entry(key).or_insert(next));
    }
    let mut parent: Vec<u32> = (0..key_to_id.len() as u32).collect();
    for t in triangles {
        let ids = t.map(|v| welded.get(v as usize).copied().unwrap_or(0));
        union(&mut parent, ids[0], ids[1]);
        union(&mut parent, ids[0], ids[2]);
    }
    let (labels, count) = compact_labels(&mut parent);
    (welded.iter().map(|&w| labels[w as usize]).collect(), count)
}

/// Rules (c) and (d) on coarse meshes of the zero set of `poly` (normalized coordinates).
fn zero_set_check(poly: &ImplicitPolynomial, radius: f64, data: &DataPieces) -> ZeroSetCheck {
    use crate::polygonize::{polygonize, PolygonizeParams};
    let params = PolygonizeParams { depth: CHECK_DEPTH, ..Default::default() };
    // (c): the inner box.
    let inner = Aabb {
        min: [-INNER_BOX; 3],
        max: [INNER_BOX; 3],
    };
    let mesh = match polygonize(poly, &inner, &params) {
        Ok(out) => out.mesh,
        Err(e) => return ZeroSetCheck::Unavailable(format!("polygonize failed: {e}")),
    };
    if mesh.triangles.is_empty() {
        return ZeroSetCheck::Fail;
    }
    let (labels, n_components) =
        mesh_components(&mesh.positions, &mesh.triangles, 1e-9 * INNER_BOX);
    if n_components != data.n_pieces {
        return ZeroSetCheck::Fail;
    }
    // Every vertex within NEAR_DATA of the data, and component ↔ piece one to one.
    let mut piece_of_component = vec![u32::MAX; n_components];
    for (v, p) in mesh.positions.iter().enumerate() {
        let (dist, piece) = data.nearest(*p);
        if dist > NEAR_DATA {
            return ZeroSetCheck::Fail;
        }
        let comp = labels[v] as usize;
        if piece_of_component[comp] == u32::MAX {
            piece_of_component[comp] = piece;
        }
    }
    let mut seen = vec![false; data.n_pieces];
    for &piece in &piece_of_component {
        match seen.get_mut(piece as usize) {
            Some(s) if !*s => *s = true,
            _ => return ZeroSetCheck::Fail,
        }
    }
    // (d): the outer box; nothing beyond the components near the data, and no contact with the box.
    let half = OUTER_BOX.max(radius);
    let outer = Aabb {
        min: [-half; 3],
        max: [half; 3],
    };
    let mesh = match polygonize(poly, &outer, &params) {
        Ok(out) => out.mesh,
        Err(e) => return ZeroSetCheck::Unavailable(format!("polygonize failed: {e}")),
    };
    let cell = 2.0 * half / f64::from(1u32 << CHECK_DEPTH);
    if mesh
        .positions
        .iter()
        .any(|p| p.iter().any(|c| c.abs() > half - 0.5 * cell))
    {
        return ZeroSetCheck::Fail;
    }
    let (_, n_outer) = mesh_components(&mesh.positions, &mesh.triangles, 1e-9 * half);
    if n_outer != data.n_pieces {
        return ZeroSetCheck::Fail;
    }
    ZeroSetCheck::Pass
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mesh_components_counts_welded_pieces() {
        // Two triangles sharing an edge through duplicated vertices, and one apart.
        let positions = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1.0, 0.0],
            [5.0, 5.0, 5.0],
            [6.0, 5.0, 5.0],
            [5.0, 6.0, 5.0],
        ];
        let triangles = [[0, 1, 2], [3, 5, 4], [6, 7, 8]];
        let (labels, count) = mesh_components(&positions, &triangles, 1e-9);
        assert_eq!(count, 2);
        assert_eq!(labels[0], labels[5]);
        assert_ne!(labels[0], labels[6]);
    }
}
