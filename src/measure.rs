//! Accuracy measures between point sets and meshes (used by the pipeline's report and the tools).
//!
//! Input: points and a [`TriangleMesh`]. Output: distances in input units.
//!
//! The point-to-mesh distance is exact per candidate triangle (closest point on a triangle,
//! Ericson, *Real-Time Collision Detection*, 5.1.5); candidates are the triangles around the
//! mesh vertex nearest to the query (a k-d tree), which finds the true nearest triangle whenever
//! it shares a vertex with the nearest vertex — true for the well-shaped meshes polygonize makes,
//! and an upper bound on the distance otherwise.
//!
//! The other direction, mesh → points (`nearest_point_distances`), is the distance from each
//! mesh vertex to the nearest data point (`PointIndex`: a grid of the points, a k-d tree
//! where the grid is slow; [`crate::point_tree`]). The PLY writer stores it as MeshLab's vertex quality and
//! [`chamfer_distance`] averages it; both use this one function.
//!
//! The symmetric Chamfer distance ([`chamfer_distance`], the accuracy figure of the detail
//! mode): points → mesh is the mean over the data points of the distance to the mesh
//! ([`point_to_mesh_distances`]); mesh → points is the mean over the mesh *vertices* of the
//! distance to the nearest data point, unweighted by area. The symmetric figure is the mean of
//! the two (divide by the data diagonal for the relative figure).
//!
//! The run's report uses `accuracy`: data → mesh as above (over every k-th point of a cloud
//! of more than `ACCURACY_POINTS`), and mesh → data by *area*
//! (`mesh_to_points_by_area`): every triangle cut into congruent pieces small enough that each
//! point of the mesh lies within 0.5% of the diagonal of a piece's centroid (`area_samples`),
//! each centroid weighted by its piece's area, its distance to the
//! nearest data point from the `PointIndex` below. Its far share (the area farther than 1% of
//! the diagonal from every data point) shows surface the data does not support, which the data →
//! mesh figure cannot see.
//!
//! The nearest-point queries are [`crate::point_tree`]'s: one `PointIndex` of the data answers
//! all of an export's.

use crate::numerics::point_tree::{
    in_spatial_order, nearest_in, nearest_point_distances, PointIndex, PointTree,
};
use crate::vec3::{dist, dist2};
use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use crate::mesh::{TriangleMesh, VertexTriangles};

/// Directed and symmetric Chamfer distances (input units).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ChamferDistance {
    /// Mean distance from the data points to the mesh.
    pub points_to_mesh: f64,
    /// Mean distance from the mesh vertices to the nearest data point.
    pub mesh_to_points: f64,
    /// (points_to_mesh + mesh_to_points) / 2.
    pub symmetric: f64,
}

/// Summary of distances from a point set to a surface.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DistanceSummary {
    /// Mean distance, input units.
    pub mean: f64,
    /// Root mean square distance, input units.
    pub rms: f64,
    /// Largest distance, input units.
    pub max: f64,
    /// `mean` divided by the reference bounding-box diagonal.
    pub mean_relative: f64,
    /// `max` divided by the reference bounding-box diagonal.
    pub max_relative: f64,
    /// How many distances the figures come from.
    #[serde(default)]
    pub samples: usize,
}

impl DistanceSummary {
    /// Summarizes `distances`, relative figures against `diagonal`.
    pub fn from_distances(distances: &[f64], diagonal: f64) -> DistanceSummary {
        if distances.is_empty() {
            return DistanceSummary::default();
        }
        let n = distances.len() as f64;
        let mean = distances.iter().sum::<f64>() / n;
        let rms = (distances.iter().map(|d| d * d).sum::<f64>() / n).sqrt();
        let max = distances.iter().copied().fold(0.0, f64::max);
        let rel = |v: f64| if diagonal > 0.0 { v / diagonal } else { 0.0 };
        DistanceSummary {
            mean,
            rms,
            max,
            mean_relative: rel(mean),
            max_relative: rel(max),
            samples: distances.len(),
        }
    }
}

/// Distances from a mesh's surface to the nearest data point, weighted by area
/// (`mesh_to_points_by_area`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct AreaDistanceSummary {
    /// Area-weighted mean distance from the mesh to the nearest data point, input units.
    pub mean: f64,
    /// Largest sampled distance, input units.
    pub max: f64,
    /// `mean` divided by the data's bounding-box diagonal.
    pub mean_relative: f64,
    /// `max` divided by the data's bounding-box diagonal.
    pub max_relative: f64,
    /// Share of the mesh's area (0 to 1) farther than `far_relative` × diagonal from every data
    /// point.
    pub far_area_share: f64,
    /// The threshold of `far_area_share`, relative to the diagonal (`FAR_RELATIVE`).
    pub far_relative: f64,
    /// The mesh's area, input units squared.
    pub area: f64,
    /// Sample points the figures come from.
    pub samples: usize,
}

/// Two-sided accuracy of a mesh against its data: the report's `accuracy`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Accuracy {
    /// Data → mesh: distance from every data point to the mesh, or from every k-th point when
    /// there are more than `ACCURACY_POINTS` (the fields `mean`, `rms`, `max`,
    /// `mean_relative`, `max_relative`, `samples` at the top level of the JSON object).
    #[serde(flatten)]
    pub data_to_mesh: DistanceSummary,
    /// Mesh → data, sampled by area.
    #[serde(default)]
    pub mesh_to_data: AreaDistanceSummary,
    /// Symmetric Chamfer distance relative to the diagonal: the mean of the two directions'
    /// `mean_relative`.
    #[serde(default)]
    pub chamfer_relative: f64,
}

impl Accuracy {
    /// The figures as the run's summary line prints them: both directions' mean distances and
    /// the far share of the area.
    pub fn describe(&self) -> String {
        let m = &self.mesh_to_data;
        format!(
            "mean distance data -> mesh {:.2e}, mesh -> data {:.2e} of the diagonal, {:.1}% of the mesh area farther than {}% of the diagonal from the data",
            self.data_to_mesh.mean_relative,
            m.mean_relative,
            100.0 * m.far_area_share,
            100.0 * m.far_relative
        )
    }
}

/// The threshold of [`AreaDistanceSummary::far_area_share`]: 1% of the data's diagonal.
pub(crate) const FAR_RELATIVE: f64 = 0.01;

/// How far from its nearest sample a point of the mesh may lie in [`area_samples`], relative to
/// the data's diagonal: half of [`FAR_RELATIVE`], so a sample stands for points at most that far
/// from it (the distance to the data changes by at most as much between them).
const AREA_SAMPLE_RELATIVE: f64 = 0.005;

/// Most pieces per side [`area_samples`] cuts a triangle into (at most 256 samples per
/// triangle, for the few long triangles where a surface meets the meshing box).
const AREA_SAMPLE_MAX_SPLITS: usize = 16;

/// Points spread over the mesh by area, and the area each stands for: every triangle is cut
/// into s × s congruent pieces and each piece gives its centroid, which lies within 2/3 of the
/// piece's longest edge of every point of the piece; s = ⌈(2/3) · longest edge / `reach`⌉
/// (from 1 to 16), so every point of the mesh is within `reach` of a sample. Deterministic:
/// triangles in order, pieces in a fixed order. Triangles with an index out of range or a
/// non-finite vertex give nothing.
pub(crate) fn area_samples(mesh: &TriangleMesh, reach: f64) -> (Vec<[f64; 3]>, Vec<f64>) {
    let n = mesh.positions.len();
    let mut points = Vec::with_capacity(mesh.triangles.len());
    let mut weights = Vec::with_capacity(mesh.triangles.len());
    for t in &mesh.triangles {
        if t.iter().any(|&i| i as usize >= n) {
            continue;
        }
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        if ![a, b, c].iter().flatten().all(|x| x.is_finite()) {
            continue;
        }
        let (ab, ac) = (crate::vec3::sub(b, a), crate::vec3::sub(c, a));
        let area = crate::vec3::triangle_area(a, b, c);
        let longest = dist(a, b).max(dist(b, c)).max(dist(c, a));
        // A piece's centroid is within 2/3 of its longest edge of each of its points.
        let cover = 2.0 / 3.0 * longest;
        let s = if reach > 0.0 && cover > reach {
            ((cover / reach).ceil() as usize).min(AREA_SAMPLE_MAX_SPLITS)
        } else {
            1
        };
        let w = area / (s * s) as f64;
        let sf = s as f64;
        let at = |u: f64, v: f64| [0, 1, 2].map(|k| a[k] + u * ab[k] + v * ac[k]);
        for i in 0..s {
            for j in 0..s - i {
                let (fi, fj) = (i as f64, j as f64);
                points.push(at((fi + 1.0 / 3.0) / sf, (fj + 1.0 / 3.0) / sf));
                weights.push(w);
                if i + j + 2 <= s {
                    points.push(at((fi + 2.0 / 3.0) / sf, (fj + 2.0 / 3.0) / sf));
                    weights.push(w);
                }
            }
        }
    }
    (points, weights)
}

/// Mesh → data distances by area: [`area_samples`] within half a percent of `diagonal` of every
/// point of the mesh, each sample's distance to the nearest data point of `data`, summed in sample
/// order. `far_relative` × `diagonal` is the threshold of the far share. `None` when there is no
/// usable triangle.
pub(crate) fn mesh_to_points_by_area(
    mesh: &TriangleMesh,
    data: &PointIndex<'_>,
    diagonal: f64,
    far_relative: f64,
) -> Option<AreaDistanceSummary> {
    let (samples, weights) = area_samples(mesh, AREA_SAMPLE_RELATIVE * diagonal);
    if samples.is_empty() {
        return None;
    }
    let distances = data.distances(&samples);
    let far = far_relative * diagonal;
    let (mut area, mut sum, mut far_area, mut max) = (0.0, 0.0, 0.0, 0.0f64);
    for (&d, &w) in distances.iter().zip(&weights) {
        area += w;
        sum += w * d;
        max = max.max(d);
        if d > far {
            far_area += w;
        }
    }
    let mean = if area > 0.0 { sum / area } else { 0.0 };
    let rel = |v: f64| if diagonal > 0.0 { v / diagonal } else { 0.0 };
    Some(AreaDistanceSummary {
        mean,
        max,
        mean_relative: rel(mean),
        max_relative: rel(max),
        far_area_share: if area > 0.0 { far_area / area } else { 0.0 },
        far_relative,
        area,
        samples: samples.len(),
    })
}

/// Most data points the data → mesh side of [`accuracy`] measures: a larger cloud is measured
/// on every k-th point (k = ⌈N / this⌉, the order of the file: scan lines and grid rows stay
/// evenly covered). A hundred thousand distances fix the mean to a few parts in a thousand;
/// past that the exact queries only cost time. The maximum is the sample's: a subsample can
/// miss the farthest point. The mesh → data side always searches all the points: a subsample
/// would lie farther from the mesh.
pub(crate) const ACCURACY_POINTS: usize = 100_000;

/// At most `most` of `points`: all of them, or every k-th from the first ([`kth_step`]).
pub(crate) fn every_kth(points: &[[f64; 3]], most: usize) -> Cow<'_, [[f64; 3]]> {
    match kth_step(points.len(), most) {
        1 => Cow::Borrowed(points),
        step => Cow::Owned(points.iter().step_by(step).copied().collect()),
    }
}

/// The step k that keeps at most `most` of `n` items: 1 when n ≤ `most`, else ⌈n / `most`⌉.
pub(crate) fn kth_step(n: usize, most: usize) -> usize {
    if n > most {
        n.div_ceil(most.max(1))
    } else {
        1
    }
}

/// The two-sided [`Accuracy`] of `mesh` against the data points indexed in `data`, relative to
/// `diagonal` (the data's bounding-box diagonal); the two directions run in parallel.
pub(crate) fn accuracy(data: &PointIndex<'_>, mesh: &TriangleMesh, diagonal: f64) -> Accuracy {
    let sampled = every_kth(data.points(), ACCURACY_POINTS);
    let (to_mesh, to_points) = rayon::join(
        || DistanceSummary::from_distances(&point_to_mesh_distances(&sampled, mesh), diagonal),
        || mesh_to_points_by_area(mesh, data, diagonal, FAR_RELATIVE).unwrap_or_default(),
    );
    Accuracy {
        data_to_mesh: to_mesh,
        mesh_to_data: to_points,
        chamfer_relative: 0.5 * (to_mesh.mean_relative + to_points.mean_relative),
    }
}

/// The mean of `f` over the area of `mesh`: on each triangle the mean of f at its three edge
/// midpoints (a rule exact for quadratic f), weighted by the triangle's area; 0 for a mesh
/// without area. For signed errors against a known surface (f its signed distance).
///
/// ```
/// use stablesurf::measure::area_mean;
/// use stablesurf::mesh::TriangleMesh;
/// // The unit square in z = 0 as two triangles: the mean of x is 1/2, of x² 1/3.
/// let square = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 4],
///     triangles: vec![[0, 1, 2], [0, 2, 3]],
/// };
/// assert!((area_mean(&square, |p| p[0]) - 0.5).abs() < 1e-15);
/// assert!((area_mean(&square, |p| p[0] * p[0]) - 1.0 / 3.0).abs() < 1e-15);
/// ```
pub fn area_mean(mesh: &TriangleMesh, f: impl Fn([f64; 3]) -> f64) -> f64 {
    let (mut weighted, mut area) = (0.0, 0.0);
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let w = crate::vec3::triangle_area(a, b, c);
        let mid = |p: [f64; 3], q: [f64; 3]| [0, 1, 2].map(|k| 0.5 * (p[k] + q[k]));
        weighted += w * (f(mid(a, b)) + f(mid(b, c)) + f(mid(c, a))) / 3.0;
        area += w;
    }
    if area > 0.0 {
        weighted / area
    } else {
        0.0
    }
}

/// Closest point to `p` on the triangle `(a, b, c)`.
pub fn closest_point_on_triangle(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> [f64; 3] {
    let sub = |u: [f64; 3], v: [f64; 3]| [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
    let dot = |u: [f64; 3], v: [f64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    let lerp =
        |u: [f64; 3], d: [f64; 3], t: f64| [u[0] + t * d[0], u[1] + t * d[1], u[2] + t * d[2]];
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return lerp(a, ab, d1 / (d1 - d3));
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return lerp(a, ac, d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return lerp(b, sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    [0, 1, 2].map(|k| a[k] + ab[k] * v + ac[k] * w)
}

/// A triangle mesh indexed for distance queries: a k-d tree over its vertices and the triangles
/// around each vertex (see the module docs for the candidate set and its error).
pub(crate) struct MeshDistance<'a> {
    mesh: &'a TriangleMesh,
    around: VertexTriangles,
    tree: PointTree,
}

impl<'a> MeshDistance<'a> {
    /// Indexes `mesh`; `None` when it has no triangles, an index out of range or a vertex that
    /// is not finite.
    pub(crate) fn new(mesh: &'a TriangleMesh) -> Option<Self> {
        let n = mesh.positions.len();
        if mesh.triangles.is_empty()
            || !mesh.positions.iter().flatten().all(|c| c.is_finite())
            || mesh.triangles.iter().flatten().any(|&i| i as usize >= n)
        {
            return None;
        }
        let around = VertexTriangles::new(n, &mesh.triangles);
        let tree = PointTree::new(&mesh.positions)?;
        Some(MeshDistance { mesh, around, tree })
    }

    /// Unsigned distance from `p` to the triangles around the mesh vertex nearest to `p` (the
    /// distance to the mesh whenever the closest triangle touches that vertex, and never more
    /// than it plus the longest edge at the nearest vertex otherwise) and that vertex, given a
    /// vertex `hint` near `p` (typically the answer for a neighbouring query): it bounds the tree
    /// search, not the result. The hint is first walked along the mesh towards `p` (see
    /// [`Self::descend`]), so the search starts from an almost tight radius.
    fn distance_near(&self, p: [f64; 3], hint: Option<usize>) -> (f64, usize) {
        let hint = hint.map(|v| self.mesh.positions[self.descend(p, v)]);
        let (d2, v) = nearest_in(&self.tree, p, hint);
        (self.fan_distance(p, v).min(d2.sqrt()), v)
    }

    /// Walks from vertex `v` to ever closer vertices of the triangles around it until none is
    /// closer to `p` (a vertex where the distance is locally smallest on the mesh, usually the
    /// nearest one), for at most [`HINT_STEPS`] steps.
    fn descend(&self, p: [f64; 3], mut v: usize) -> usize {
        let positions = &self.mesh.positions;
        let mut dv = dist2(p, positions[v]);
        for _ in 0..HINT_STEPS {
            let mut next = v;
            for &ti in self.around.of(v) {
                for w in self.mesh.triangles[ti as usize] {
                    let d = dist2(p, positions[w as usize]);
                    if d < dv {
                        (dv, next) = (d, w as usize);
                    }
                }
            }
            if next == v {
                break;
            }
            v = next;
        }
        v
    }

    /// Distance from `p` to the triangles around vertex `v`.
    fn fan_distance(&self, p: [f64; 3], v: usize) -> f64 {
        let mut best2 = f64::INFINITY;
        for &ti in self.around.of(v) {
            best2 = best2.min(self.triangle_distance2(p, ti));
        }
        best2.sqrt()
    }

    /// Squared distance from `p` to triangle `ti` (the square root of the smallest is the
    /// smallest distance, so a minimum over triangles takes one root).
    fn triangle_distance2(&self, p: [f64; 3], ti: u32) -> f64 {
        let [a, b, c] = self.mesh.triangles[ti as usize].map(|i| self.mesh.positions[i as usize]);
        dist2(p, closest_point_on_triangle(p, a, b, c))
    }

    /// The distinct neighbours of every vertex, in the order the triangles around it list
    /// them (first occurrence): offsets into one array, as for [`VertexTriangles`].
    fn neighbours(&self) -> (Vec<u32>, Vec<u32>) {
        let n = self.mesh.positions.len();
        let mut offsets = Vec::with_capacity(n + 1);
        let mut list = Vec::with_capacity(6 * n);
        offsets.push(0u32);
        for v in 0..n {
            let start = list.len();
            for &ti in self.around.of(v) {
                for w in self.mesh.triangles[ti as usize] {
                    if w as usize != v && !list[start..].contains(&w) {
                        list.push(w);
                    }
                }
            }
            offsets.push(list.len() as u32);
        }
        (offsets, list)
    }
}

/// Distance from the points of a grid to a mesh, for many queries far from the surface (the
/// distance slices). A k-d tree over all vertices degrades there: near the medial axis many
/// vertices are almost equally far, and the search visits them all. This index keeps one seed
/// vertex per cell of a coarse grid; a query starts from the previous query's closest vertex
/// (warm start along a row of pixels) and from its nearest seeds, walks each to a vertex where
/// the distance is locally smallest and measures the triangles touching that vertex or its
/// neighbours (the closest triangle of a mesh with slivers need not touch the closest vertex). A seed farther than the best distance found plus two coarse cells cannot lead
/// closer (every vertex lies within a cell diagonal of a seed), so it is skipped. The result is
/// the distance to the mesh whenever one of the walks ends at the vertex nearest the closest
/// point, which fails only where a piece of surface smaller than a coarse cell is closest.
pub(crate) struct GridMeshDistance<'a> {
    mesh: MeshDistance<'a>,
    /// Distinct neighbours of each vertex (offsets, list), for the walks.
    neighbours: (Vec<u32>, Vec<u32>),
    seeds: Vec<u32>,
    seed_tree: PointTree,
    cell: f64,
}

/// Steps of the walk that improves a hint of [`MeshDistance::distance_near`].
const HINT_STEPS: usize = 16;

/// Seed cells along the longest side of the mesh's bounding box.
const SEED_CELLS: f64 = 64.0;
/// At most this many seed walks per query, from the nearest seeds.
const N_WALKS: usize = 3;

impl<'a> GridMeshDistance<'a> {
    /// Indexes `mesh`; `None` as for `MeshDistance::new`.
    pub(crate) fn new(mesh: &'a TriangleMesh) -> Option<Self> {
        let index = MeshDistance::new(mesh)?;
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in &mesh.positions {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let longest = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        let cell = if longest > 0.0 {
            longest / SEED_CELLS
        } else {
            1.0
        };
        // The first vertex (in index order) of every occupied coarse cell.
        let mut taken = std::collections::HashSet::new();
        let mut seeds = Vec::new();
        for (i, p) in mesh.positions.iter().enumerate() {
            let key = [0, 1, 2].map(|a| ((p[a] - lo[a]) / cell) as i64);
            if index.around.of(i).is_empty() {
                continue;
            }
            if taken.insert(key) {
                seeds.push(i as u32);
            }
        }
        let points: Vec<[f64; 3]> = seeds.iter().map(|&i| mesh.positions[i as usize]).collect();
        let seed_tree = PointTree::new(&points)?;
        Some(GridMeshDistance {
            neighbours: index.neighbours(),
            mesh: index,
            seeds,
            seed_tree,
            cell,
        })
    }

    /// Walks from vertex `v` to ever closer neighbouring vertices of `p` until none is closer:
    /// a vertex where the distance to `p` is locally smallest on the mesh. Among equally close
    /// neighbours the first in [`MeshDistance::neighbours`] order wins.
    fn descend(&self, p: [f64; 3], mut v: usize) -> usize {
        let (offsets, list) = &self.neighbours;
        let positions = &self.mesh.mesh.positions;
        let mut dv = dist2(p, positions[v]);
        loop {
            let mut next = v;
            let range = offsets[v] as usize..offsets[v + 1] as usize;
            for &w in &list[range] {
                let d = dist2(p, positions[w as usize]);
                if d < dv {
                    (dv, next) = (d, w as usize);
                }
            }
            if next == v {
                return v;
            }
            v = next;
        }
    }

    /// Distance from `p` to the triangles that touch vertex `v` or one of its neighbours (the
    /// closest triangle of a sliver-rich mesh need not touch the closest vertex, but it is one
    /// of these unless its edges are longer than the ring), given `fan`, the distance to the
    /// triangles around `v` ([`MeshDistance::fan_distance`]), which are not measured again.
    fn ring_distance(&self, p: [f64; 3], v: usize, fan: f64) -> f64 {
        // A triangle of the ring that is not in the fan touches one to three neighbours of v:
        // it is measured from the first of them in the neighbour list, so exactly once.
        let (offsets, list) = &self.neighbours;
        let ring = &list[offsets[v] as usize..offsets[v + 1] as usize];
        let triangles = &self.mesh.mesh.triangles;
        let mut best2 = f64::INFINITY;
        for (i, &w) in ring.iter().enumerate() {
            for &tj in self.mesh.around.of(w as usize) {
                let elsewhere = triangles[tj as usize]
                    .iter()
                    .any(|&u| u as usize == v || (u != w && ring[..i].contains(&u)));
                if !elsewhere {
                    best2 = best2.min(self.mesh.triangle_distance2(p, tj));
                }
            }
        }
        fan.min(best2.sqrt())
    }

    /// Side of the coarse seed grid's cells, input units.
    pub(crate) fn seed_cell(&self) -> f64 {
        self.cell
    }

    /// Unsigned distance from `p` to the mesh (see the type's docs) and the vertex the best walk
    /// ended at, to warm-start the next query with `warm`.
    pub(crate) fn distance_from(&self, p: [f64; 3], warm: Option<usize>) -> (f64, usize) {
        // Each walk ends at a vertex; the fan (1-ring) distance ranks the ends, and the best
        // end's 2-ring gives the result.
        let mut best = (f64::INFINITY, 0);
        let mut ends = [usize::MAX; N_WALKS + 1];
        let mut n_ends = 0;
        if let Some(w) = warm {
            let v = self.descend(p, w);
            best = (self.mesh.fan_distance(p, v), v);
            ends[0] = v;
            n_ends = 1;
        }
        // Seeds beyond best + two cells are not walked, so a warm start bounds the search.
        let mut nearest = [(0.0, 0u32); N_WALKS];
        let radius2 = if best.0.is_finite() {
            (best.0 + 2.0 * self.cell).powi(2)
        } else {
            f64::INFINITY
        };
        let found = self.seed_tree.nearest_n_within(p, radius2, &mut nearest);
        for &(d2, seed) in &nearest[..found] {
            if d2.sqrt() > best.0 + 2.0 * self.cell {
                break;
            }
            let v = self.descend(p, self.seeds[seed as usize] as usize);
            if ends[..n_ends].contains(&v) {
                continue;
            }
            ends[n_ends] = v;
            n_ends += 1;
            let d = self.mesh.fan_distance(p, v);
            if d < best.0 {
                best = (d, v);
            }
        }
        let (d, v) = best;
        (self.ring_distance(p, v, d), v)
    }
}

/// Distance from each point to the mesh (see the module docs for the candidate set).
/// Returns an empty vector when the mesh has no triangles or a non-finite vertex.
pub fn point_to_mesh_distances(points: &[[f64; 3]], mesh: &TriangleMesh) -> Vec<f64> {
    let Some(index) = MeshDistance::new(mesh) else {
        return Vec::new();
    };
    // Queried in spatial order (scans interleave their lines), each query's nearest vertex
    // bounds the next one's search; the distances are the same as without it.
    in_spatial_order(points, |i, hint| {
        let (d, v) = index.distance_near(points[i], hint);
        (d, Some(v))
    })
}

/// The Chamfer distance between `points` and `mesh` (see the module docs); `None` when either is
/// empty or the mesh cannot be indexed.
///
/// ```
/// use stablesurf::measure::chamfer_distance;
/// use stablesurf::TriangleMesh;
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 3],
///     triangles: vec![[0, 1, 2]],
/// };
/// let c = chamfer_distance(&[[0.2, 0.2, 0.5]], &mesh).unwrap();
/// assert!((c.points_to_mesh - 0.5).abs() < 1e-12);
/// ```
pub fn chamfer_distance(points: &[[f64; 3]], mesh: &TriangleMesh) -> Option<ChamferDistance> {
    if points.is_empty() || mesh.positions.is_empty() || mesh.triangles.is_empty() {
        return None;
    }
    let (to_mesh, to_points) = rayon::join(
        || point_to_mesh_distances(points, mesh),
        || nearest_point_distances(&mesh.positions, points),
    );
    let to_points = to_points?;
    if to_mesh.len() != points.len() {
        return None;
    }
    let points_to_mesh = to_mesh.iter().sum::<f64>() / to_mesh.len() as f64;
    let mesh_to_points = to_points.iter().sum::<f64>() / to_points.len() as f64;
    Some(ChamferDistance {
        points_to_mesh,
        mesh_to_points,
        symmetric: 0.5 * (points_to_mesh + mesh_to_points),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_point_regions() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let q = closest_point_on_triangle([0.2, 0.2, 1.0], a, b, c);
        assert!((q[0] - 0.2).abs() < 1e-15 && (q[1] - 0.2).abs() < 1e-15 && q[2] == 0.0);
        assert_eq!(closest_point_on_triangle([-1.0, -1.0, 0.0], a, b, c), a);
        assert_eq!(
            closest_point_on_triangle([0.5, -1.0, 0.0], a, b, c),
            [0.5, 0.0, 0.0]
        );
        let q = closest_point_on_triangle([1.0, 1.0, 0.0], a, b, c);
        assert!((q[0] - 0.5).abs() < 1e-15 && (q[1] - 0.5).abs() < 1e-15);
    }

    #[test]
    fn distance_to_a_square_made_of_two_triangles() {
        let mesh = crate::mesh::unit_square();
        let d = point_to_mesh_distances(&[[0.3, 0.6, 0.25], [2.0, 0.5, 0.0]], &mesh);
        assert!((d[0] - 0.25).abs() < 1e-12);
        assert!((d[1] - 1.0).abs() < 1e-12);
        let s = DistanceSummary::from_distances(&d, 2.0);
        assert!((s.mean - 0.625).abs() < 1e-12 && (s.max_relative - 0.5).abs() < 1e-12);
    }

    #[test]
    fn area_samples_cover_the_area_and_find_the_far_part() {
        // A unit square (two triangles) at z = 0 and a second one at z = 1; data on the first.
        let mut mesh = crate::mesh::unit_square();
        let lifted: Vec<[f64; 3]> = mesh.positions.iter().map(|p| [p[0], p[1], 1.0]).collect();
        mesh.positions.extend(lifted);
        mesh.normals.extend([[0.0, 0.0, 1.0]; 4]);
        mesh.triangles.extend([[4, 5, 6], [4, 6, 7]]);
        let (points, weights) = area_samples(&mesh, 0.3);
        // Longest edge √2: (2/3)·√2 / 0.3 = 3.14 → 4 pieces per side, 16 samples per triangle.
        assert_eq!(points.len(), 4 * 16);
        assert!((weights.iter().sum::<f64>() - 2.0).abs() < 1e-12);
        let data: Vec<[f64; 3]> = (0..=20)
            .flat_map(|i| (0..=20).map(move |j| [i as f64 / 20.0, j as f64 / 20.0, 0.0]))
            .collect();
        let index = PointIndex::new(&data).unwrap();
        let s = mesh_to_points_by_area(&mesh, &index, 100.0, 0.01).unwrap();
        assert!((s.far_area_share - 0.5).abs() < 1e-12, "{s:?}");
        assert!((s.area - 2.0).abs() < 1e-12);
        assert!(s.max >= 1.0 && s.mean > 0.5);
        let a = accuracy(&index, &mesh, 100.0);
        assert!(a.data_to_mesh.max < 1e-12 && a.data_to_mesh.samples == data.len());
        assert!((a.chamfer_relative - 0.5 * a.mesh_to_data.mean_relative).abs() < 1e-15);
    }

    #[test]
    fn large_clouds_are_measured_on_every_kth_point() {
        let points: Vec<[f64; 3]> = (0..10).map(|i| [i as f64, 0.0, 0.0]).collect();
        assert!(matches!(every_kth(&points, 10), Cow::Borrowed(_)));
        let kept: Vec<f64> = every_kth(&points, 4).iter().map(|p| p[0]).collect();
        assert_eq!(kept, vec![0.0, 3.0, 6.0, 9.0]);
        assert_eq!(every_kth(&points, 5).len(), 5);
    }
}
