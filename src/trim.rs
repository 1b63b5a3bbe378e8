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
//! 2. *Support of a triangle*: its centroid is supported when the nearest data point (the
//!    measure module's k-d tree) is within `support_factor` × that point's spacing.
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
//!
//! Deterministic: every step runs in a fixed order (the parallel parts compute one value per
//! point or triangle), so the output is the same on any number of threads.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::measure::PointTree;
use crate::mesh::{self, TriangleMesh, VertexTriangles};
use crate::numerics::{PointGrid, UnionFind};
use crate::vec3::{cross, dot, norm, sub};

/// Version of this stage's algorithm: if you change anything that changes its output for the
/// same input and params, bump it (the stage's params and version enter the export stage's
/// cache key).
pub const STAGE_VERSION: u32 = 2;

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
    let tree = PointTree::new(points).ok_or(TrimError::NoData)?;
    let diagonal = crate::cloud::Aabb::from_points(points).map_or(0.0, |b| b.diagonal());
    let areas: Vec<f64> = mesh
        .triangles
        .iter()
        .map(|t| triangle_area(&mesh.positions, *t))
        .collect();
    // Per triangle: the distance from its centroid to the nearest data point, and that point.
    let nearest: Vec<(f64, usize)> = mesh
        .triangles
        .par_iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let centroid = [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0);
            let (d2, j) = tree.nearest(centroid);
            (d2.sqrt(), j)
        })
        .collect();
    // The local spacing at those points only (a dense scan has many more points than the mesh
    // has triangles).
    let mut wanted: Vec<u32> = nearest.iter().map(|&(_, j)| j as u32).collect();
    wanted.sort_unstable();
    wanted.dedup();
    let spacing_of = local_spacing(&grid, points, params.spacing_neighbours, &wanted);
    let spacing = |j: usize| spacing_of[wanted.binary_search(&(j as u32)).unwrap_or(0)];
    // In the nearest point's local spacings, when that point does not support the triangle;
    // `None` when supported.
    let unsupported: Vec<Option<Depth>> = nearest
        .iter()
        .map(|&(d, j)| {
            (d > params.support_factor * spacing(j)).then_some(Depth {
                spacings: d / spacing(j),
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
    if !removed.iter().any(|&r| r) {
        return Ok(unchanged(report));
    }
    let around = VertexTriangles::new(n, &mesh.triangles);
    remove_extra_fans(mesh, &around, &areas, &mut removed);
    report.islands_removed =
        remove_islands(mesh, &edges, &areas, params.island_share, &mut removed);
    report.removed_triangles = removed.iter().filter(|&&r| r).count();
    report.removed_area = areas
        .iter()
        .zip(&removed)
        .filter(|(_, &r)| r)
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
        .filter(|(_, &r)| !r)
        .map(|(t, _)| *t)
        .collect();
    let (filled, fill_triangles) =
        fill_holes(&mesh.positions, &mut kept, params.fill_perimeter * diagonal);
    report.holes_filled = filled;
    report.fill_triangles = fill_triangles;
    let out = compact(mesh, &kept);
    report.boundary_loops = mesh::boundary_loops(&out);
    report.open = report.boundary_loops > 0;
    Ok(Trimmed { mesh: out, report })
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

fn triangle_area(positions: &[[f64; 3]], t: [u32; 3]) -> f64 {
    let [a, b, c] = t.map(|i| positions[i as usize]);
    0.5 * norm(cross(sub(b, a), sub(c, a)))
}

/// The local spacing (step 1 of the module docs) at each of the points `wanted` (indices into
/// `points`, sorted, distinct), in their order.
fn local_spacing(grid: &PointGrid, points: &[[f64; 3]], k: usize, wanted: &[u32]) -> Vec<f64> {
    let k = k.min(points.len().saturating_sub(1));
    if k == 0 {
        return vec![0.0; wanted.len()];
    }
    let neighbours = grid.nearest_of(points, wanted, k);
    // Each point's distance to its nearest neighbour at a positive distance (0 when all its k
    // neighbours coincide with it), for the wanted points and their neighbours.
    let mut around: Vec<u32> = wanted
        .iter()
        .copied()
        .chain(neighbours.flat().iter().copied())
        .collect();
    around.sort_unstable();
    around.dedup();
    let dist = |i: usize, j: u32| norm(sub(points[i], points[j as usize]));
    let around_neighbours = grid.nearest_of(points, &around, k);
    let nearest: Vec<f64> = around
        .par_iter()
        .enumerate()
        .map(|(r, &i)| {
            around_neighbours
                .row(r)
                .iter()
                .map(|&j| dist(i as usize, j))
                .find(|&d| d > 0.0)
                .unwrap_or(0.0)
        })
        .collect();
    let nearest_of = |j: u32| nearest[around.binary_search(&j).unwrap_or(0)];
    wanted
        .par_iter()
        .enumerate()
        .map(|(r, &i)| {
            let mut values: Vec<f64> = std::iter::once(nearest_of(i))
                .chain(neighbours.row(r).iter().map(|&j| nearest_of(j)))
                .collect();
            values.sort_unstable_by(f64::total_cmp);
            values[values.len() / 2]
        })
        .collect()
}

/// The triangles on each undirected edge, in compressed rows over the sorted edges.
struct EdgeMap {
    /// For each triangle, the index of each of its three edges (edge k runs from corner k to
    /// corner k + 1).
    of_triangle: Vec<[u32; 3]>,
    /// `start[e]..start[e + 1]` are edge e's triangles in `triangles`.
    start: Vec<u32>,
    triangles: Vec<u32>,
}

impl EdgeMap {
    fn new(tris: &[[u32; 3]]) -> EdgeMap {
        let mut uses: Vec<(u32, u32, u32, u8)> = tris
            .iter()
            .enumerate()
            .flat_map(|(ti, t)| {
                (0..3).map(move |k| {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    (a.min(b), a.max(b), ti as u32, k as u8)
                })
            })
            .collect();
        uses.par_sort_unstable();
        let mut of_triangle = vec![[0u32; 3]; tris.len()];
        let mut start = Vec::new();
        let mut triangles = Vec::with_capacity(uses.len());
        let mut e = 0u32;
        for (i, u) in uses.iter().enumerate() {
            if i == 0 || (uses[i - 1].0, uses[i - 1].1) != (u.0, u.1) {
                if i > 0 {
                    e += 1;
                }
                start.push(i as u32);
            }
            of_triangle[u.2 as usize][u.3 as usize] = e;
            triangles.push(u.2);
        }
        start.push(uses.len() as u32);
        EdgeMap {
            of_triangle,
            start,
            triangles,
        }
    }

    fn triangles_of(&self, e: u32) -> &[u32] {
        &self.triangles[self.start[e as usize] as usize..self.start[e as usize + 1] as usize]
    }
}

/// How far an unsupported triangle's centroid lies from the data; for a region, the largest of
/// each over its triangles (taken separately: one triangle may give the spacings, another the
/// distance).
#[derive(Clone, Copy, Debug, Default)]
struct Depth {
    /// In local spacings of the nearest data point.
    spacings: f64,
    /// In input units.
    distance: f64,
}

/// Step 3: which triangles to remove, and how many unsupported regions are kept. Whether a
/// region opens the mesh is decided over the whole mesh: an opening in one piece lets deep
/// enclosed regions go in every piece.
fn unsupported_regions(
    mesh: &TriangleMesh,
    edges: &EdgeMap,
    unsupported: &[Option<Depth>],
    areas: &[f64],
    keep_area: f64,
    keep_depth: Depth,
) -> (Vec<bool>, usize) {
    let n = mesh.triangles.len();
    let mut removed = vec![false; n];
    let mut seen = vec![false; n];
    let mut kept_regions = 0;
    let mut opened = false;
    // Enclosed regions that are deep: removed only when the mesh is opened anyway.
    let mut deep_regions: Vec<Vec<u32>> = Vec::new();
    let mut stack = Vec::new();
    let mut region = Vec::new();
    for first in 0..n {
        if unsupported[first].is_none() || seen[first] {
            continue;
        }
        seen[first] = true;
        stack.push(first as u32);
        region.clear();
        let mut area = 0.0;
        let mut depth = Depth::default();
        let mut reaches_boundary = false;
        while let Some(t) = stack.pop() {
            region.push(t);
            area += areas[t as usize];
            if let Some(d) = unsupported[t as usize] {
                depth.spacings = depth.spacings.max(d.spacings);
                depth.distance = depth.distance.max(d.distance);
            }
            for &e in &edges.of_triangle[t as usize] {
                let on = edges.triangles_of(e);
                if on.len() == 1 {
                    reaches_boundary = true;
                }
                for &u in on {
                    if unsupported[u as usize].is_some() && !seen[u as usize] {
                        seen[u as usize] = true;
                        stack.push(u);
                    }
                }
            }
        }
        let deep = depth.spacings > keep_depth.spacings && depth.distance > keep_depth.distance;
        if reaches_boundary || area > keep_area {
            opened = true;
            for &t in &region {
                removed[t as usize] = true;
            }
        } else if deep {
            deep_regions.push(region.clone());
        } else {
            kept_regions += 1;
        }
    }
    if opened {
        for t in deep_regions.iter().flatten() {
            removed[*t as usize] = true;
        }
    } else {
        kept_regions += deep_regions.len();
    }
    (removed, kept_regions)
}

/// Step 4, fans: at every vertex whose kept triangles form more than one fan, removes all
/// fans but the one of largest area (ties: the one with the smallest triangle index), until no
/// such vertex is left.
fn remove_extra_fans(
    mesh: &TriangleMesh,
    around: &VertexTriangles,
    areas: &[f64],
    removed: &mut [bool],
) {
    let n = mesh.positions.len();
    // The vertices to look at: those of removed triangles (only they can have lost a fan's
    // link); a removal adds its triangles' vertices again.
    let mut queue: Vec<u32> = Vec::new();
    let mut queued = vec![false; n];
    for (t, &r) in mesh.triangles.iter().zip(removed.iter()) {
        if r {
            for &v in t {
                if !queued[v as usize] {
                    queued[v as usize] = true;
                    queue.push(v);
                }
            }
        }
    }
    queue.sort_unstable();
    let mut head = 0;
    let mut local: Vec<u32> = Vec::new();
    let mut sets = UnionFind::default();
    while head < queue.len() {
        let v = queue[head];
        head += 1;
        queued[v as usize] = false;
        local.clear();
        local.extend(
            around
                .of(v as usize)
                .iter()
                .copied()
                .filter(|&t| !removed[t as usize]),
        );
        if local.len() < 2 {
            continue;
        }
        sets.reset(local.len());
        // Two triangles around v are in one fan when they share an edge through v.
        for i in 0..local.len() {
            let ti = mesh.triangles[local[i] as usize];
            for (j, &other) in local.iter().enumerate().skip(i + 1) {
                let tj = mesh.triangles[other as usize];
                let shared = ti.iter().filter(|&&w| w != v && tj.contains(&w)).count();
                if shared > 0 {
                    sets.union(i as u32, j as u32);
                }
            }
        }
        let roots: Vec<usize> = (0..local.len() as u32)
            .map(|i| sets.find(i) as usize)
            .collect();
        let mut fans: Vec<usize> = roots.clone();
        fans.sort_unstable();
        fans.dedup();
        if fans.len() < 2 {
            continue;
        }
        let fan_area = |r: usize| -> f64 {
            (0..local.len())
                .filter(|&i| roots[i] == r)
                .map(|i| areas[local[i] as usize])
                .sum()
        };
        // The fan roots are in order of their smallest slot, and slots follow triangle order.
        let mut best = fans[0];
        let mut best_area = fan_area(best);
        for &r in &fans[1..] {
            let a = fan_area(r);
            if a > best_area {
                (best, best_area) = (r, a);
            }
        }
        for i in 0..local.len() {
            if roots[i] != best {
                let t = local[i] as usize;
                removed[t] = true;
                for &w in &mesh.triangles[t] {
                    if !queued[w as usize] {
                        queued[w as usize] = true;
                        queue.push(w);
                    }
                }
            }
        }
    }
}

/// Step 4, islands: removes the edge-connected pieces of kept triangles with less than
/// `share` of the kept area; returns how many.
fn remove_islands(
    mesh: &TriangleMesh,
    edges: &EdgeMap,
    areas: &[f64],
    share: f64,
    removed: &mut [bool],
) -> usize {
    let n = mesh.triangles.len();
    let mut label = vec![u32::MAX; n];
    let mut piece_area: Vec<f64> = Vec::new();
    let mut stack = Vec::new();
    for first in 0..n {
        if removed[first] || label[first] != u32::MAX {
            continue;
        }
        let id = piece_area.len() as u32;
        let mut area = 0.0;
        label[first] = id;
        stack.push(first as u32);
        while let Some(t) = stack.pop() {
            area += areas[t as usize];
            for &e in &edges.of_triangle[t as usize] {
                for &u in edges.triangles_of(e) {
                    if !removed[u as usize] && label[u as usize] == u32::MAX {
                        label[u as usize] = id;
                        stack.push(u);
                    }
                }
            }
        }
        piece_area.push(area);
    }
    let total: f64 = piece_area.iter().sum();
    let small: Vec<bool> = piece_area.iter().map(|&a| a < share * total).collect();
    for t in 0..n {
        if !removed[t] && small[label[t] as usize] {
            removed[t] = true;
        }
    }
    small.iter().filter(|&&s| s).count()
}

/// Most vertices of a loop [`fill_holes`] closes.
const FILL_MAX_VERTICES: usize = 512;

/// Step 5: closes the boundary loops of `triangles` no longer than `max_perimeter`; returns
/// the number of loops closed and of triangles added.
fn fill_holes(
    positions: &[[f64; 3]],
    triangles: &mut Vec<[u32; 3]>,
    max_perimeter: f64,
) -> (usize, usize) {
    if max_perimeter <= 0.0 {
        return (0, 0);
    }
    let boundary = mesh::boundary_edges(triangles);
    if boundary.is_empty() {
        return (0, 0);
    }
    // Each boundary vertex of a manifold mesh starts exactly one boundary edge.
    let mut next: std::collections::BTreeMap<u32, u32> = std::collections::BTreeMap::new();
    for &[a, b] in &boundary {
        if next.insert(a, b).is_some() {
            // Not manifold at a: no loop is well defined; close nothing.
            return (0, 0);
        }
    }
    let mut existing: std::collections::HashSet<(u32, u32)> = triangles
        .iter()
        .flat_map(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
        .collect();
    let mut visited: std::collections::BTreeSet<u32> = std::collections::BTreeSet::new();
    let mut fills: Vec<Vec<[u32; 3]>> = Vec::new();
    for &[start, _] in &boundary {
        if visited.contains(&start) {
            continue;
        }
        let mut lp = vec![start];
        visited.insert(start);
        let mut v = start;
        let mut closed = false;
        while let Some(&w) = next.get(&v) {
            if w == start {
                closed = true;
                break;
            }
            if !visited.insert(w) || lp.len() > FILL_MAX_VERTICES {
                break;
            }
            lp.push(w);
            v = w;
        }
        // Mark the rest of a loop that was too long, so it is not traced again.
        let mut w = v;
        while let Some(&x) = next.get(&w) {
            if !visited.insert(x) {
                break;
            }
            w = x;
        }
        if !closed || lp.len() < 3 {
            continue;
        }
        let perimeter: f64 = (0..lp.len())
            .map(|i| {
                norm(sub(
                    positions[lp[(i + 1) % lp.len()] as usize],
                    positions[lp[i] as usize],
                ))
            })
            .sum();
        if perimeter > max_perimeter {
            continue;
        }
        // The fill runs against the boundary's direction, so its edges pair with the mesh's.
        lp.reverse();
        if let Some(tris) = ear_clip(positions, &lp, &existing) {
            for t in &tris {
                for k in 0..3 {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    existing.insert((a.min(b), a.max(b)));
                }
            }
            fills.push(tris);
        }
    }
    if fills.is_empty() {
        return (0, 0);
    }
    // Fills that meet the mesh (or another fill) are taken back.
    let base = triangles.len();
    let mut all = triangles.clone();
    let mut owner = Vec::new();
    for (f, tris) in fills.iter().enumerate() {
        all.extend_from_slice(tris);
        owner.extend(std::iter::repeat_n(f, tris.len()));
    }
    let active: Vec<bool> = (0..all.len()).map(|i| i >= base).collect();
    let probe = TriangleMesh {
        positions: positions.to_vec(),
        normals: Vec::new(),
        triangles: all,
    };
    let hits = mesh::intersecting_triangles_among(&probe, Some(&active));
    let mut bad = vec![false; fills.len()];
    for (i, &h) in hits.iter().enumerate().skip(base) {
        if h {
            bad[owner[i - base]] = true;
        }
    }
    let (mut loops, mut added) = (0, 0);
    for (f, tris) in fills.into_iter().enumerate() {
        if !bad[f] {
            loops += 1;
            added += tris.len();
            triangles.extend(tris);
        }
    }
    (loops, added)
}

/// Ear clipping of the loop `lp` (vertex indices, in the order its fill triangles run) in the
/// plane of its Newell normal; `None` when the projected loop is not a simple polygon or an ear
/// would add an edge that `existing` already holds.
fn ear_clip(
    positions: &[[f64; 3]],
    lp: &[u32],
    existing: &std::collections::HashSet<(u32, u32)>,
) -> Option<Vec<[u32; 3]>> {
    let m = lp.len();
    let p = |i: usize| positions[lp[i] as usize];
    let mut normal = [0.0; 3];
    for i in 0..m {
        let (a, b) = (p(i), p((i + 1) % m));
        normal[0] += (a[1] - b[1]) * (a[2] + b[2]);
        normal[1] += (a[2] - b[2]) * (a[0] + b[0]);
        normal[2] += (a[0] - b[0]) * (a[1] + b[1]);
    }
    let len = norm(normal);
    if len.is_nan() || len <= 0.0 {
        return None;
    }
    let nz = normal.map(|c| c / len);
    let helper = if nz[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let u = {
        let c = cross(helper, nz);
        let l = norm(c);
        c.map(|x| x / l)
    };
    let v = cross(nz, u);
    let flat: Vec<[f64; 2]> = (0..m).map(|i| [dot(p(i), u), dot(p(i), v)]).collect();
    let orient = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
        (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    };
    // A simple polygon: no two edges that are not neighbours meet.
    let meet = |a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]| {
        let (d1, d2) = (orient(a, b, c), orient(a, b, d));
        let (d3, d4) = (orient(c, d, a), orient(c, d, b));
        d1 * d2 <= 0.0 && d3 * d4 <= 0.0
    };
    for i in 0..m {
        for j in i + 2..m {
            if i == 0 && j == m - 1 {
                continue;
            }
            if meet(flat[i], flat[(i + 1) % m], flat[j], flat[(j + 1) % m]) {
                return None;
            }
        }
    }
    let mut ring: Vec<usize> = (0..m).collect();
    let mut out = Vec::with_capacity(m - 2);
    while ring.len() > 3 {
        let r = ring.len();
        let mut clipped = false;
        for k in 0..r {
            let (ia, ib, ic) = (ring[(k + r - 1) % r], ring[k], ring[(k + 1) % r]);
            let (a, b, c) = (flat[ia], flat[ib], flat[ic]);
            if orient(a, b, c) <= 0.0 {
                continue;
            }
            let inside = ring.iter().any(|&j| {
                j != ia
                    && j != ib
                    && j != ic
                    && orient(a, b, flat[j]) >= 0.0
                    && orient(b, c, flat[j]) >= 0.0
                    && orient(c, a, flat[j]) >= 0.0
            });
            let (x, y) = (lp[ia], lp[ic]);
            if inside || existing.contains(&(x.min(y), x.max(y))) {
                continue;
            }
            out.push([lp[ia], lp[ib], lp[ic]]);
            ring.remove(k);
            clipped = true;
            break;
        }
        if !clipped {
            return None;
        }
    }
    out.push([lp[ring[0]], lp[ring[1]], lp[ring[2]]]);
    Some(out)
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
    use super::*;

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
        for (w, s) in wanted.iter().zip(&some) {
            assert_eq!(*s, all[*w as usize], "point {w}");
        }
        assert!(some.iter().all(|&s| s > 0.0));
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
                // Nothing opens the mesh: the deep hole is closed by the model all the same.
                assert_eq!(out.mesh, mesh);
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
