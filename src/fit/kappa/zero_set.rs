//! The coarse zero set of a candidate polynomial inside a box, for rules (c) and (d) of the
//! stable κ rule: meshed by the polygonize stage (depth 6, no simplification), optionally with
//! the octree cells that a far-field certificate proves positive skipped ([`FarCulled`]), or, if
//! that stage cannot run, the sign-change cells of a uniform grid.
//!
//! Input: a polynomial in normalized coordinates and the box's half side. Output:
//! [`CoarseZeroSet`], the connected pieces (as representative points), how far such a point may
//! lie from the true zero set, and whether the zero set reaches the box's boundary.

use super::{trace, CHECK_DEPTH};
use crate::cloud::Aabb;
use crate::implicit::{Enclosure, GridValues, ImplicitFunction};
use crate::poly::ImplicitPolynomial;

/// The coarse zero set inside a box: its connected pieces, each given by representative points
/// (mesh vertices, or centres of cells whose corners change sign), how far such a point may be
/// from the true zero set, and whether the zero set reaches the box's boundary.
pub(super) struct CoarseZeroSet {
    pub(super) components: Vec<Vec<[f64; 3]>>,
    pub(super) slack: f64,
    pub(super) touches_box: bool,
}

/// Which mesher produced a [`CoarseZeroSet`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Mesher {
    /// The polygonize stage (adaptive octree), as the rule specifies.
    Polygonize,
    /// A uniform grid of 2^depth cells per side, 26-connected sign-change cells: the stand-in
    /// used while polygonize reports that it cannot run.
    SignGrid,
}

/// Meshes the zero set of `poly` (normalized coordinates) coarsely in [−half, half]³: with the
/// polygonize stage when it runs, else with the uniform sign grid.
pub(super) fn coarse_zero_set(poly: &ImplicitPolynomial, half: f64) -> (CoarseZeroSet, Mesher) {
    coarse_zero_set_culled(poly, half, None)
}

/// [`coarse_zero_set`], given (optionally) a box norm `positive_beyond` such that f > 0 is
/// certified on every point of [−half, half]³ with |p|∞ ≥ `positive_beyond`: the octree then
/// skips the cells that cannot matter there ([`FarCulled`]), and the mesh is the same.
pub(super) fn coarse_zero_set_culled(
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
pub(super) struct FarCulled<'a> {
    pub(super) poly: &'a ImplicitPolynomial,
    pub(super) beyond: f64,
    pub(super) reach: f64,
}

impl FarCulled<'_> {
    /// Whether every point within `reach` of `b` (box norm) has box norm ≥ `beyond`.
    pub(super) fn certified_positive(&self, b: &Aabb) -> bool {
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
pub(super) const DISCARDED: Enclosure = Enclosure {
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
pub(super) fn sign_grid_zero_set(
    poly: &ImplicitPolynomial,
    half: f64,
    cells: usize,
) -> CoarseZeroSet {
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
