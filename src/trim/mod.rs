//! The trim stage: the mesh keeps the surface its data supports.
//!
//! Input: a [`TriangleMesh`] (the polygonize stage's output), the data points it was made from
//! and [`TrimParams`]. Output: [`Trimmed`], the mesh with the unsupported regions removed and
//! the small holes the cut leaves closed, and a [`TrimReport`]. Invariants: a mesh where every
//! triangle is supported comes back unchanged (the same vertices, triangles and order, so a
//! closed scan's outputs stay byte-identical); the output has no non-manifold edge or vertex
//! when the input had none, and a single view comes out as an open patch bounded by loops.
//!
//! Why: a blend of local fits extrapolates where the scan saw nothing. On one raw range scan
//! (one side of the object only) the zero set runs on past the data as curtains and sheets
//! out to the meshing box, most of the mesh's area. A closed scan has data all around, and
//! the small gaps it has (a few missing patches) are better closed by the model's surface
//! than left open.
//!
//! Method:
//!
//! 1. *Local spacing* at every data point: the median, over the point and its k nearest
//!    neighbours (the `normals` stage's bucket grid), of each one's distance to its nearest
//!    non-coincident neighbour. A median of nearest distances follows the scan's line and row
//!    spacing and ignores the sparse rows at a scan's grazing edge, which a k-th-neighbour
//!    distance would take as the spacing there.
//! 2. *Support of a triangle*: its centroid is supported when the nearest data point (from the
//!    same bucket grid, the smallest index among equally near points; the measure module's k-d
//!    tree for a centroid beyond the grid's search rings) is within `support_factor` × that
//!    point's spacing.
//! 3. *Regions*: the unsupported triangles joined by edges. A region is removed when it
//!    reaches the mesh's own boundary (a sheet cut by the meshing box) or when it holds more
//!    than `keep_area_share` of the mesh's area (the unseen back of a closed blob). When such a
//!    region opens the mesh, an enclosed region that reaches deeper than `hole_depth` local
//!    spacings and `hole_depth_share` of the diagonal from the data goes too (the unseen
//!    underside of a single view, which the blend bulges out past the data). Any other region
//!    enclosed by supported surface is a hole of the scan that the model closes, and is kept:
//!    a mesh that no removal opens stays closed.
//! 4. *Clean-up*: at a vertex where the kept triangles form several fans (joined only through
//!    that vertex), the fans other than the largest (by area) are removed, until no such vertex
//!    is left; then components with less than `island_share` of the kept area are removed.
//! 5. *Holes*: boundary loops whose length is at most `fill_perimeter` × the diagonal are
//!    closed by ear clipping in the loop's best plane (Newell's normal), when the projected loop
//!    is a simple polygon, no new edge exists already and no new triangle meets the mesh
//!    (the exact test of [`crate::mesh`]); otherwise the loop stays open.
//! 6. *Fairing*: a vertex of a kept unsupported triangle that lies itself farther than
//!    `support_factor` spacings from its nearest data point is free; a patch of free vertices
//!    (joined by edges) that touches a vertex that is not free is a hole of the scan when its
//!    deepest vertex lies farther than `fair_depth_share` of the diagonal from the data, or
//!    farther than `fair_depth_reaches` of its nearest point's reaches (the distance from that
//!    point to its `spacing_neighbours`-th neighbour). Its vertices move to the membrane its
//!    rim spans, each at the mean of its neighbours with the rest held fixed, so the patch the
//!    blend bulged out over the hole is drawn flat. Moves that make triangles cross are undone
//!    (the exact test). The model's zero set is not moved: over a faired hole the mesh leaves
//!    it (the bunny's open base and the teapot's inner walls; CHANGELOG.md has the figures).
//!    The reach rule takes the holes of a dense scan that are shallower than the share, such
//!    as the unseen wall of a step in the bunny's base, while the gaps between random samples
//!    stay (20,000 on a sphere, 10⁶ on a torus: none faired).
//!
//! The steps live in `spacing.rs` (1), `regions.rs` (2–4: regions by edges, fans, islands),
//! `holes.rs` (5) and `fair.rs` (6); this module holds the params, the report and the stage
//! function.
//!
//! Deterministic: every step runs in a fixed order (the parallel parts compute one value per
//! point or triangle), so the output is the same on any number of threads.

use std::sync::OnceLock;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::mesh::{self, TriangleMesh, VertexTriangles};
use crate::numerics::point_tree::PointTree;
use crate::numerics::union_find::UnionFind;
use crate::numerics::PointGrid;
use crate::vec3::triangle_area;

mod fair;
mod holes;
mod regions;
mod spacing;

use crate::mesh::EdgeMap;
use fair::fair;
use holes::fill_holes;
use regions::{remove_extra_fans, remove_islands, unsupported_regions, Depth};
use spacing::{spacing_and_reach_at, spacing_at};

/// Version of this stage's algorithm: if you change anything that changes its output for the
/// same input and params, bump it (the stage's params and version enter the export stage's
/// cache key).
pub(crate) const STAGE_VERSION: u32 = 4;

/// Whether the stage trims.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum TrimMode {
    /// Keep the whole mesh.
    Off,
    /// Remove the surface the data do not support (see the module docs).
    #[default]
    Support,
}

/// Parameters of [`trim`]. Distances are relative to the data's bounding-box diagonal or to
/// the local sample spacing, so they hold at any scale.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrimParams {
    /// Trim or not.
    pub mode: TrimMode,
    /// A triangle is supported when a data point lies within this many local spacings of its
    /// centroid. Default 2.
    pub support_factor: f64,
    /// Neighbours over which the local spacing is a median. Default 8.
    pub spacing_neighbours: usize,
    /// An unsupported region enclosed by supported surface (it does not reach the mesh's
    /// boundary) and with no more than this share of the mesh's area is kept. Default 0.1.
    pub keep_area_share: f64,
    /// When the trim opens the mesh (a region reaches the boundary or exceeds
    /// `keep_area_share`), an enclosed unsupported region is removed too when it reaches deeper
    /// than this many local spacings *and* deeper than `hole_depth_share`: the region's deepest
    /// centroid, in its nearest data point's spacings, lies beyond this (the two depths are
    /// each the region's largest, possibly at different triangles). A hole of the scan up to about
    /// 2 × 10 samples across is closed; the unseen underside of a single view, which the blend
    /// bulges out past the data, is not (bunny top view: 20–40 spacings deep, 7.9% of the
    /// diagonal). The sparse vertices of a closed mesh leave regions 5–10 spacings deep between
    /// them. Default 10.
    pub hole_depth: f64,
    /// The other half of the `hole_depth` rule, as a share of the data's diagonal: a region
    /// that stays within it is kept however many spacings deep (the accuracy report counts
    /// such area as near the data). Default 0.01.
    pub hole_depth_share: f64,
    /// Boundary loops left by the cut and no longer than this (relative to the data's
    /// diagonal) are closed. Default 0.05.
    pub fill_perimeter: f64,
    /// Pieces with less than this share of the kept area are removed. Default 0.01.
    pub island_share: f64,
    /// A patch of kept unsupported surface is faired (step 6) when its deepest vertex lies
    /// farther than this share of the data's diagonal from every data point: a hole of the
    /// scan, not a gap between samples (the 20,000 random samples of a sphere leave gaps up to
    /// 1.36% of the diagonal deep, the bunny's open base 3.3%). Infinity fairs nothing.
    /// Default 0.015.
    #[serde(default = "default_fair_depth_share")]
    pub fair_depth_share: f64,
    /// A patch is faired too when its deepest vertex lies farther from the data than this many
    /// *reaches* of its nearest data point (the distance from that point to its
    /// `spacing_neighbours`-th nearest neighbour): a hole of the scan's own scale, such as the
    /// unseen wall of a step, which is shallower than `fair_depth_share` on a dense scan.
    /// Infinity fairs nothing more. Default 2.
    #[serde(default = "default_fair_depth_reaches")]
    pub fair_depth_reaches: f64,
    /// The noise the model averaged, as a share of the data's diagonal (the detail fit's
    /// [`crate::detail::DetailParams::noise`]): a noisy scan's points scatter by σ on both
    /// sides of the smooth surface fitted through them, further than their spacing where σ is
    /// large, so a triangle (or vertex) within `NOISE_SUPPORT`·σ of a data point is supported
    /// whatever the spacing says. Default 0 (exact data; left out of the cache key then).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub noise: f64,
}

/// A triangle within this many σ of the noise ([`TrimParams::noise`]) of a data point is
/// supported: the share of a Gaussian scatter's points farther than 3σ from its surface is
/// 0.3%, so a surface that 3σ does not reach is not where the points are.
pub(crate) const NOISE_SUPPORT: f64 = 3.0;

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn default_fair_depth_reaches() -> f64 {
    TrimParams::default().fair_depth_reaches
}

fn default_fair_depth_share() -> f64 {
    TrimParams::default().fair_depth_share
}

impl Default for TrimParams {
    fn default() -> Self {
        TrimParams {
            mode: TrimMode::Support,
            support_factor: 2.0,
            spacing_neighbours: 8,
            keep_area_share: 0.1,
            hole_depth: 10.0,
            hole_depth_share: 0.01,
            fill_perimeter: 0.05,
            island_share: 0.01,
            fair_depth_share: 0.015,
            fair_depth_reaches: 2.0,
            noise: 0.0,
        }
    }
}

impl TrimParams {
    /// No trimming.
    pub fn off() -> Self {
        TrimParams {
            mode: TrimMode::Off,
            ..TrimParams::default()
        }
    }
}

/// What [`trim`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TrimReport {
    /// Whether the stage trimmed (`false` for [`TrimMode::Off`]).
    pub enabled: bool,
    /// Triangles whose centroid no data point supports.
    pub unsupported_triangles: usize,
    /// Unsupported regions kept as holes of the scan that the model closes.
    pub holes_kept: usize,
    /// Triangles removed (unsupported regions, extra fans, islands).
    pub removed_triangles: usize,
    /// Area removed, input units squared.
    pub removed_area: f64,
    /// `removed_area` as a share of the input mesh's area (0 to 1).
    pub removed_area_share: f64,
    /// Small pieces removed.
    pub islands_removed: usize,
    /// Boundary loops closed by ear clipping.
    pub holes_filled: usize,
    /// Vertices of kept unsupported surface moved by the fairing (step 6).
    #[serde(default)]
    pub faired_vertices: usize,
    /// Triangles those fills added.
    pub fill_triangles: usize,
    /// Boundary loops of the output (0: closed).
    pub boundary_loops: usize,
    /// Whether the output has a boundary.
    pub open: bool,
}

/// The trimmed mesh and what was done.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trimmed {
    /// The mesh (the input itself when nothing was removed).
    pub mesh: TriangleMesh,
    /// Figures for the report.
    pub report: TrimReport,
}

/// Errors of [`trim`].
#[derive(Debug, thiserror::Error)]
pub enum TrimError {
    /// No usable data point (none, or a non-finite coordinate).
    #[error("cannot trim: the data has no usable point (a non-finite coordinate, or none); pass --trim off")]
    NoData,
    /// A parameter is out of range.
    #[error("cannot trim: {0}")]
    BadParams(String),
}

/// Removes the surface of `mesh` that `points` do not support and closes the small holes the
/// cut leaves (see the module docs).
///
/// ```
/// use stablesurf::trim::{trim, TrimParams};
/// use stablesurf::TriangleMesh;
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 3],
///     triangles: vec![[0, 1, 2]],
/// };
/// let points = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.3, 0.3, 0.0]];
/// let out = trim(&mesh, &points, &TrimParams::default()).unwrap();
/// assert_eq!(out.mesh, mesh);
/// ```
///
/// # Errors
/// [`TrimError::NoData`] when trimming is on and no data point is usable;
/// [`TrimError::BadParams`] for a parameter out of range.
pub fn trim(
    mesh: &TriangleMesh,
    points: &[[f64; 3]],
    params: &TrimParams,
) -> Result<Trimmed, TrimError> {
    let unchanged = |report: TrimReport| -> Trimmed {
        let check = mesh::boundary_loops(mesh);
        Trimmed {
            mesh: mesh.clone(),
            report: TrimReport {
                boundary_loops: check,
                open: check > 0,
                ..report
            },
        }
    };
    if params.mode == TrimMode::Off || mesh.triangles.is_empty() {
        return Ok(unchanged(TrimReport::default()));
    }
    validate(params)?;
    let n = mesh.positions.len();
    if mesh.triangles.iter().flatten().any(|&i| i as usize >= n)
        || mesh.positions.iter().flatten().any(|c| !c.is_finite())
    {
        // Not a mesh polygonize makes; leave it to the checks to report.
        return Ok(unchanged(TrimReport {
            enabled: true,
            ..TrimReport::default()
        }));
    }
    let grid = PointGrid::new(points).ok_or(TrimError::NoData)?;
    // The k-d tree only for centroids the grid's rings leave open (far from every point). It
    // is built outside the lock: its build runs in parallel, and a thread waiting for its
    // parts may pick up another centroid's query (two first queries may both build it).
    let tree: OnceLock<Option<PointTree>> = OnceLock::new();
    let nearest_of = |q: [f64; 3]| {
        if let Some((d2, j)) = grid.nearest_item(q) {
            return Ok((d2, j as usize));
        }
        let tree = match tree.get() {
            Some(tree) => tree,
            None => {
                let built = PointTree::new(points);
                tree.get_or_init(|| built)
            }
        };
        tree.as_ref()
            .map(|tree| tree.nearest(q))
            .ok_or(TrimError::NoData)
    };
    let diagonal = crate::cloud::Aabb::from_points(points).map_or(0.0, |b| b.diagonal());
    let noise_reach = NOISE_SUPPORT * params.noise * diagonal;
    let areas: Vec<f64> = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            triangle_area(a, b, c)
        })
        .collect();
    // Per triangle: the distance from its centroid to the nearest data point, and that point
    // (the smallest index among equally near ones).
    let nearest: Vec<(f64, usize)> = mesh
        .triangles
        .par_iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let centroid = [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0);
            let (d2, j) = nearest_of(centroid)?;
            Ok((d2.sqrt(), j))
        })
        .collect::<Result<_, TrimError>>()?;
    // The local spacing at those points only (a dense scan has many more points than the mesh
    // has triangles).
    let spacing = spacing_at(
        &grid,
        points,
        params.spacing_neighbours,
        nearest.iter().map(|&(_, j)| j),
    );
    // In the nearest point's local spacings, when that point does not support the triangle;
    // `None` when supported.
    let unsupported: Vec<Option<Depth>> = nearest
        .iter()
        .zip(&spacing)
        .map(|(&(d, _), &s)| {
            (d > params.support_factor * s && d > noise_reach).then_some(Depth {
                spacings: d / s,
                distance: d,
            })
        })
        .collect();
    let n_unsupported = unsupported.iter().filter(|u| u.is_some()).count();
    let mut report = TrimReport {
        enabled: true,
        unsupported_triangles: n_unsupported,
        ..TrimReport::default()
    };
    if n_unsupported == 0 {
        return Ok(unchanged(report));
    }
    let edges = EdgeMap::new(&mesh.triangles);
    let total_area: f64 = areas.iter().sum();
    let (mut removed, holes_kept) = unsupported_regions(
        mesh,
        &edges,
        &unsupported,
        &areas,
        params.keep_area_share * total_area,
        Depth {
            spacings: params.hole_depth,
            distance: params.hole_depth_share * diagonal,
        },
    );
    report.holes_kept = holes_kept;
    let kept: Vec<[u32; 3]> = if removed.iter().any(|&r| r) {
        let around = VertexTriangles::new(n, &mesh.triangles);
        remove_extra_fans(mesh, &around, &areas, &mut removed);
        report.islands_removed =
            remove_islands(mesh, &edges, &areas, params.island_share, &mut removed);
        report.removed_triangles = removed.iter().filter(|&&r| r).count();
        report.removed_area = areas
            .iter()
            .zip(&removed)
            .filter(|&(_, &r)| r)
            .map(|(a, _)| a)
            .sum();
        report.removed_area_share = if total_area > 0.0 {
            report.removed_area / total_area
        } else {
            0.0
        };
        let mut kept: Vec<[u32; 3]> = mesh
            .triangles
            .iter()
            .zip(&removed)
            .filter(|&(_, &r)| !r)
            .map(|(t, _)| *t)
            .collect();
        let (filled, fill_triangles) =
            fill_holes(&mesh.positions, &mut kept, params.fill_perimeter * diagonal);
        report.holes_filled = filled;
        report.fill_triangles = fill_triangles;
        kept
    } else {
        mesh.triangles.clone()
    };
    // The vertices to fair: on kept unsupported triangles, and themselves farther from their
    // nearest data point than `support_factor` of its spacings.
    let mut candidates = vec![false; n];
    for (t, _) in mesh
        .triangles
        .iter()
        .zip(unsupported.iter().zip(&removed))
        .filter(|&(_, (u, &r))| u.is_some() && !r)
    {
        for &v in t {
            candidates[v as usize] = true;
        }
    }
    let candidates: Vec<u32> = (0..n as u32).filter(|&v| candidates[v as usize]).collect();
    let vertex_nearest: Vec<(f64, usize)> = candidates
        .par_iter()
        .map(|&v| nearest_of(mesh.positions[v as usize]).map(|(d2, j)| (d2.sqrt(), j)))
        .collect::<Result<_, TrimError>>()?;
    let vertex_spacing = spacing_and_reach_at(
        &grid,
        points,
        params.spacing_neighbours,
        vertex_nearest.iter().map(|&(_, j)| j),
    );
    let mut free = vec![false; n];
    // Per vertex: its distance to the data, and that in its nearest point's reaches (0 when
    // the point's neighbours all coincide with it: no measure, so the reach rule passes).
    let mut depth = vec![(0.0, 0.0); n];
    for ((&v, &(d, _)), &(s, reach)) in candidates.iter().zip(&vertex_nearest).zip(&vertex_spacing)
    {
        free[v as usize] = d > params.support_factor * s && d > noise_reach;
        let reaches = if reach > 0.0 { d / reach } else { 0.0 };
        depth[v as usize] = (d, reaches);
    }
    keep_deep_patches(
        &kept,
        &mut free,
        &depth,
        params.fair_depth_share * diagonal,
        params.fair_depth_reaches,
    );
    let mut faired = TriangleMesh {
        positions: mesh.positions.clone(),
        normals: mesh.normals.clone(),
        triangles: Vec::new(),
    };
    report.faired_vertices = fair(&mut faired.positions, &mut faired.normals, &kept, &free);
    if report.removed_triangles == 0 && report.faired_vertices == 0 {
        return Ok(unchanged(report));
    }
    let out = compact(&faired, &kept);
    report.boundary_loops = mesh::boundary_loops(&out);
    report.open = report.boundary_loops > 0;
    Ok(Trimmed { mesh: out, report })
}

/// Clears `free` on every patch of free vertices (joined by the edges of `triangles`) whose
/// deepest vertex lies no farther than `min_depth` from the data and no farther than
/// `min_reaches` of its nearest point's reaches (`depth`, per vertex: the distance and the
/// reaches), or that no edge joins to a vertex that is not free (a closed piece all of it far
/// from the data has no rim to span a membrane).
fn keep_deep_patches(
    triangles: &[[u32; 3]],
    free: &mut [bool],
    depth: &[(f64, f64)],
    min_depth: f64,
    min_reaches: f64,
) {
    let n = free.len();
    let mut patches = UnionFind::new(n);
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if free[a as usize] && free[b as usize] {
                patches.union(a, b);
            }
        }
    }
    let mut deep = vec![false; n];
    let mut anchored = vec![false; n];
    for v in (0..n).filter(|&v| free[v]) {
        let r = patches.find(v as u32) as usize;
        let (d, reaches) = depth[v];
        deep[r] |= d > min_depth || reaches > min_reaches;
    }
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k] as usize, t[(k + 1) % 3] as usize);
            if free[a] != free[b] {
                let inner = if free[a] { a } else { b };
                anchored[patches.find(inner as u32) as usize] = true;
            }
        }
    }
    for (v, f) in free.iter_mut().enumerate() {
        if *f {
            let r = patches.find(v as u32) as usize;
            *f = anchored[r] && deep[r];
        }
    }
}

fn validate(params: &TrimParams) -> Result<(), TrimError> {
    let positive = |name: &str, v: f64| {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(TrimError::BadParams(format!(
                "{name} must be a positive number, got {v}"
            )))
        }
    };
    positive("the support factor", params.support_factor)?;
    if !(params.keep_area_share.is_finite() && (0.0..=1.0).contains(&params.keep_area_share)) {
        return Err(TrimError::BadParams(format!(
            "keep_area_share must be from 0 to 1, got {}",
            params.keep_area_share
        )));
    }
    for (name, v) in [
        ("hole_depth", params.hole_depth),
        ("hole_depth_share", params.hole_depth_share),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(TrimError::BadParams(format!(
                "{name} must be 0 or more, got {v}"
            )));
        }
    }
    for (name, v) in [
        ("fair_depth_share", params.fair_depth_share),
        ("fair_depth_reaches", params.fair_depth_reaches),
    ] {
        if v.is_nan() || v < 0.0 {
            return Err(TrimError::BadParams(format!(
                "{name} must be 0 or more, got {v}"
            )));
        }
    }
    if !(params.fill_perimeter.is_finite() && params.fill_perimeter >= 0.0) {
        return Err(TrimError::BadParams(format!(
            "fill_perimeter must be 0 or more, got {}",
            params.fill_perimeter
        )));
    }
    if !(params.island_share.is_finite() && (0.0..1.0).contains(&params.island_share)) {
        return Err(TrimError::BadParams(format!(
            "island_share must be from 0 to below 1, got {}",
            params.island_share
        )));
    }
    if params.spacing_neighbours == 0 || params.spacing_neighbours > 64 {
        return Err(TrimError::BadParams(format!(
            "spacing_neighbours must be from 1 to 64, got {}",
            params.spacing_neighbours
        )));
    }
    Ok(())
}

/// The mesh of `triangles` over `mesh`'s vertices, unreferenced vertices left out (kept ones
/// in their order).
fn compact(mesh: &TriangleMesh, triangles: &[[u32; 3]]) -> TriangleMesh {
    let mut new_index = vec![u32::MAX; mesh.positions.len()];
    for t in triangles {
        for &v in t {
            new_index[v as usize] = 0;
        }
    }
    let mut out = TriangleMesh::default();
    for (i, slot) in new_index.iter_mut().enumerate() {
        if *slot == 0 {
            *slot = out.positions.len() as u32;
            out.positions.push(mesh.positions[i]);
            if let Some(&n) = mesh.normals.get(i) {
                out.normals.push(n);
            }
        }
    }
    out.triangles = triangles
        .iter()
        .map(|t| t.map(|v| new_index[v as usize]))
        .collect();
    out
}

#[cfg(test)]
mod tests {
    use super::spacing::{local_spacing, spacing_at};
    use super::*;
    use crate::vec3::{norm, sub};

    #[test]
    fn the_spacing_at_some_points_is_the_spacing_computed_at_all() {
        // A jittered sheet with doubled points (coincident neighbours) and a denser strip.
        let mut points = Vec::new();
        let mut rng = crate::numerics::Lcg::new(7);
        let mut next = || rng.uniform();
        for i in 0..3000 {
            let p = [
                next(),
                next() * if i % 3 == 0 { 0.2 } else { 1.0 },
                0.01 * next(),
            ];
            points.push(p);
            if i % 7 == 0 {
                points.push(p);
            }
        }
        let grid = PointGrid::new(&points).unwrap();
        let k = 8;
        // The median over each point and its k neighbours of their nearest positive distances,
        // from the neighbour lists of all points.
        let lists = grid.all_nearest(&points, k);
        let dist = |i: usize, j: u32| norm(sub(points[i], points[j as usize]));
        let nearest: Vec<f64> = (0..points.len())
            .map(|i| {
                lists
                    .row(i)
                    .iter()
                    .map(|&j| dist(i, j))
                    .find(|&d| d > 0.0)
                    .unwrap_or(0.0)
            })
            .collect();
        let all: Vec<f64> = (0..points.len())
            .map(|i| {
                let mut v: Vec<f64> = std::iter::once(nearest[i])
                    .chain(lists.row(i).iter().map(|&j| nearest[j as usize]))
                    .collect();
                v.sort_unstable_by(f64::total_cmp);
                v[v.len() / 2]
            })
            .collect();
        let wanted: Vec<u32> = (0..points.len() as u32).step_by(5).collect();
        let some = local_spacing(&grid, &points, k, &wanted);
        for (&w, &(s, reach)) in wanted.iter().zip(&some) {
            assert_eq!(s, all[w as usize], "point {w}");
            // The reach: the distance to the k-th nearest neighbour.
            let kth = *lists.row(w as usize).last().unwrap();
            assert_eq!(reach, dist(w as usize, kth), "point {w}");
        }
        assert!(some.iter().all(|&(s, reach)| s > 0.0 && reach >= s));
        // In any order, with repeats: the same spacing at each point asked for.
        let at: Vec<usize> = (0..points.len())
            .rev()
            .step_by(3)
            .chain([0, 0, 7])
            .collect();
        let spacing = spacing_at(&grid, &points, k, at.iter().copied());
        for (&j, &s) in at.iter().zip(&spacing) {
            assert_eq!(s, all[j], "point {j}");
        }
    }

    /// A flat grid of n × n squares over [0, 1]², two triangles each, counter-clockwise from +z.
    fn grid(n: usize) -> TriangleMesh {
        let mut mesh = TriangleMesh::default();
        for j in 0..=n {
            for i in 0..=n {
                mesh.positions
                    .push([i as f64 / n as f64, j as f64 / n as f64, 0.0]);
                mesh.normals.push([0.0, 0.0, 1.0]);
            }
        }
        let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
        for j in 0..n {
            for i in 0..n {
                mesh.triangles
                    .push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                mesh.triangles
                    .push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
            }
        }
        mesh
    }

    #[test]
    fn off_and_fully_supported_leave_the_mesh_as_it_is() {
        let mesh = grid(8);
        let points: Vec<[f64; 3]> = mesh.positions.clone();
        let out = trim(&mesh, &points, &TrimParams::off()).unwrap();
        assert_eq!(out.mesh, mesh);
        assert!(!out.report.enabled && out.report.open && out.report.boundary_loops == 1);
        let out = trim(&mesh, &points, &TrimParams::default()).unwrap();
        assert_eq!(out.mesh, mesh);
        assert_eq!(out.report.removed_triangles, 0);
    }

    #[test]
    fn a_sheet_past_the_data_is_removed() {
        // Data on the left half only: the right half reaches the mesh boundary and goes.
        let mesh = grid(20);
        let points: Vec<[f64; 3]> = mesh
            .positions
            .iter()
            .copied()
            .filter(|p| p[0] <= 0.5)
            .collect();
        let out = trim(&mesh, &points, &TrimParams::default()).unwrap();
        let r = out.report;
        assert!(
            r.removed_area_share > 0.35 && r.removed_area_share < 0.5,
            "{r:?}"
        );
        assert_eq!(r.boundary_loops, 1);
        let check = mesh::check(&out.mesh);
        assert_eq!(
            (check.non_manifold_edges, check.non_manifold_vertices),
            (0, 0)
        );
        assert!(out
            .mesh
            .positions
            .iter()
            .all(|p| p[0] <= 0.5 + 4.0 * 0.05 + 1e-9));
    }

    #[test]
    fn centroids_beyond_the_grids_rings_get_their_nearest_point_from_the_tree() {
        // Data on a line along x: the bucket grid is one row of thin cells, so a centroid
        // half the sheet away from the line is not settled within the grid's rings and asks
        // the k-d tree (built outside its lock while other centroids are being queried).
        let mesh = grid(20);
        let points: Vec<[f64; 3]> = (0..2000).map(|i| [i as f64 / 1999.0, 0.0, 0.0]).collect();
        let grid_index = PointGrid::new(&points).unwrap();
        assert!(grid_index.nearest_item([0.5, 0.5, 0.0]).is_none());
        let out = trim(&mesh, &points, &TrimParams::default()).unwrap();
        let r = out.report;
        // Everything but the strip along the line lies many spacings from the data and reaches
        // the mesh's boundary: removed.
        assert!(r.removed_area_share > 0.9, "{r:?}");
        assert!(
            out.mesh.positions.iter().all(|p| p[1] <= 0.1 + 1e-9),
            "{r:?}"
        );
        // The same on one thread.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let one = pool.install(|| trim(&mesh, &points, &TrimParams::default()).unwrap());
        assert_eq!(one.mesh, out.mesh);
    }

    #[test]
    fn an_enclosed_region_is_kept_only_when_shallow_or_nothing_opens_the_mesh() {
        // A 100 × 100 grid (spacing 0.01) with no data in a disk of radius 0.15 around (0.4,
        // 0.5): an enclosed region of ~6% of the area whose centre lies 0.15 from the data, i.e.
        // 15 spacings and 11% of the data's diagonal. With `open`, no data beyond x = 0.8
        // either: that strip reaches the mesh's boundary and opens it.
        let mesh = grid(100);
        let outside_disk =
            |p: &[f64; 3]| ((p[0] - 0.4).powi(2) + (p[1] - 0.5).powi(2)).sqrt() > 0.15;
        for open in [false, true] {
            let points: Vec<[f64; 3]> = mesh
                .positions
                .iter()
                .copied()
                .filter(|p| outside_disk(p) && (!open || p[0] <= 0.8))
                .collect();
            for lenient in [
                TrimParams {
                    hole_depth: 20.0,
                    ..TrimParams::default()
                },
                TrimParams {
                    hole_depth_share: 0.2,
                    ..TrimParams::default()
                },
            ] {
                let out = trim(&mesh, &points, &lenient).unwrap();
                assert_eq!(out.report.holes_kept, 1, "{:?}", out.report);
                assert_eq!(out.report.boundary_loops, 1, "{:?}", out.report);
            }
            let out = trim(&mesh, &points, &TrimParams::default()).unwrap();
            let r = out.report;
            if !open {
                // Nothing opens the mesh: the deep hole is closed by the model all the same
                // (faired, but flat it stays: every vertex within 1e-15 of where it was).
                assert_eq!(out.mesh.triangles, mesh.triangles);
                for (p, q) in out.mesh.positions.iter().zip(&mesh.positions) {
                    assert!(norm(sub(*p, *q)) < 1e-15, "{p:?} {q:?}");
                }
                assert_eq!((r.holes_kept, r.removed_triangles), (1, 0), "{r:?}");
                continue;
            }
            assert_eq!(r.holes_kept, 0, "{r:?}");
            assert!(
                r.removed_area_share > 0.2 && r.removed_area_share < 0.28,
                "{r:?}"
            );
            assert_eq!(r.boundary_loops, 2, "{r:?}");
            let check = mesh::check(&out.mesh);
            assert_eq!(
                (check.non_manifold_edges, check.non_manifold_vertices),
                (0, 0)
            );
        }
    }

    #[test]
    fn a_bulge_over_a_hole_is_faired_and_the_supported_surface_stays() {
        // The 100 × 100 grid (spacing 0.01) with no data in a disk of radius 0.15, over which
        // the mesh bulges up to 0.05 (as a blend's quadrics do over a hole of the scan).
        let mut mesh = grid(100);
        let r = |p: &[f64; 3]| ((p[0] - 0.5).powi(2) + (p[1] - 0.5).powi(2)).sqrt();
        for p in &mut mesh.positions {
            p[2] = 0.05 * (1.0 - (r(p) / 0.15).powi(2)).max(0.0);
        }
        let points: Vec<[f64; 3]> = mesh
            .positions
            .iter()
            .copied()
            .filter(|p| r(p) > 0.15)
            .collect();
        let out = trim(&mesh, &points, &TrimParams::default()).unwrap();
        let report = out.report;
        assert_eq!(out.mesh.triangles, mesh.triangles);
        assert!(report.faired_vertices > 500, "{report:?}");
        let height = |m: &TriangleMesh| m.positions.iter().map(|p| p[2]).fold(0.0, f64::max);
        // The supported surface keeps its bits; the bulge sinks towards the plane of its rim.
        for (p, q) in out.mesh.positions.iter().zip(&mesh.positions) {
            if r(q) > 0.16 {
                assert_eq!(p, q);
            }
        }
        assert!(
            height(&out.mesh) < 0.5 * height(&mesh),
            "{}",
            height(&out.mesh)
        );
        let check = mesh::check(&out.mesh);
        assert_eq!(check.self_intersecting_faces, 0);
        assert!(check.orientation_consistent);
        for (n, p) in out.mesh.normals.iter().zip(&out.mesh.positions) {
            assert!(
                (norm(*n) - 1.0).abs() < 1e-12 && n[2] > 0.5,
                "{n:?} at {p:?}"
            );
        }
        // Shallower than `fair_depth_share` (0.158 against 0.2 × 1.414) but 7.9 reaches deep
        // (the nearest points lie on the hole's rim, whose 8th neighbours lie 2 spacings
        // away): a hole of the scan's own scale, faired all the same.
        let shallow = TrimParams {
            fair_depth_share: 0.2,
            ..TrimParams::default()
        };
        let out = trim(&mesh, &points, &shallow).unwrap();
        assert_eq!(out.report.faired_vertices, report.faired_vertices);
        // Under both depths: left as it is.
        for fair_depth_reaches in [8.0, f64::INFINITY] {
            let params = TrimParams {
                fair_depth_reaches,
                ..shallow
            };
            let out = trim(&mesh, &points, &params).unwrap();
            assert_eq!((out.report.faired_vertices, &out.mesh), (0, &mesh));
        }
    }

    #[test]
    fn gaps_between_random_samples_are_not_faired() {
        // 20,000 points spread at random over the unit square and a mesh of it 0.01 fine: the
        // gaps between the samples leave free vertices (farther than 2 local spacings from
        // the data, whose nearest-neighbour distances scatter widely), none of them 2 reaches
        // deep (nor 1.5% of the diagonal), so nothing is faired.
        let mesh = grid(100);
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let points: Vec<[f64; 3]> = (0..20_000).map(|_| [next(), next(), 0.0]).collect();
        let out = trim(&mesh, &points, &TrimParams::default()).unwrap();
        assert!(out.report.unsupported_triangles > 0, "{:?}", out.report);
        assert_eq!(out.report.faired_vertices, 0, "{:?}", out.report);
        // The gaps are there: at half a reach every free patch is faired.
        let eager = TrimParams {
            fair_depth_reaches: 0.5,
            ..TrimParams::default()
        };
        assert!(trim(&mesh, &points, &eager).unwrap().report.faired_vertices > 0);
    }

    #[test]
    fn ear_clipping_closes_a_small_hole_consistently() {
        // A grid with one interior vertex's fan removed: a hexagonal hole, closed again.
        let mesh = grid(6);
        let hole = 3 * 7 + 3;
        let mut kept: Vec<[u32; 3]> = mesh
            .triangles
            .iter()
            .copied()
            .filter(|t| !t.contains(&hole))
            .collect();
        let before = kept.len();
        let (loops, added) = fill_holes(&mesh.positions, &mut kept, 10.0);
        assert_eq!((loops, added), (1, 4));
        assert_eq!(kept.len(), before + 4);
        let out = compact(&mesh, &kept);
        let check = mesh::check(&out);
        assert!(check.orientation_consistent && check.non_manifold_edges == 0);
        assert_eq!(check.boundary_loops, 1);
        assert_eq!(check.self_intersecting_faces, 0);
    }

    #[test]
    fn bad_params_are_errors() {
        let mesh = grid(2);
        let params = TrimParams {
            support_factor: -1.0,
            ..TrimParams::default()
        };
        assert!(matches!(
            trim(&mesh, &mesh.positions, &params),
            Err(TrimError::BadParams(_))
        ));
        assert!(matches!(
            trim(&mesh, &[], &TrimParams::default()),
            Err(TrimError::NoData)
        ));
    }
}
