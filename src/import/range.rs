//! Stage `import`, range grids: a Stanford range image's grid of samples → triangles facing the
//! scanner, the scanner's position and a per-point edge falloff.
//!
//! Input: the points and the `range_grid` cells of a PLY file (row-major, `num_cols` ×
//! `num_rows`, each cell empty or one vertex index). Output: a [`RangeGrid`]: triangles wound so
//! that their normals face the estimated sensor, the [`RangeSurface`] (sensor and falloff) and
//! the figures `stablesurf info` prints.
//!
//! # Method
//!
//! - **Triangles.** Each grid square (r, c), (r, c+1), (r+1, c), (r+1, c+1) gives two triangles
//!   when its four corners hold samples (split along the shorter diagonal) and one when three
//!   do. Every triangle is counter-clockwise in (column, row) order, so neighbouring triangles
//!   agree in winding by construction. A triangle is cut (left out) at a depth discontinuity:
//!   an edge longer than [`LONG_EDGE_FACTOR`] times the median distance between grid
//!   neighbours, or a normal more than [`GRAZING_DEG`] from the ray to the sensor.
//! - **Sensor.** The samples of one scan line (a grid row, or a column) lie in a plane through
//!   the scanner (a laser sheet or a camera's scan plane). A plane is fitted to each line that is
//!   clearly not straight, and the point closest to all the planes in the least-squares sense is
//!   the sensor; in a direction the planes leave free (parallel planes: a scanner that
//!   translates along that direction) it takes the data's centroid. Rows and columns are tried
//!   separately and the family whose planes meet best (smallest rms distance) is used. On the
//!   Cyberware bunny scans the rows give about (0, 0.18, 1.3) in scan coordinates.
//! - **Winding sign.** All triangles are flipped together when the area-weighted cosine between
//!   their normals and the direction to the sensor is negative (without a sensor: when they
//!   face the data's centroid).
//! - **Falloff.** Points on the boundary of the kept triangles (or in none) are 1/4, the next
//!   ring 2/4, then 3/4, and 1 from four edges in, as VRIP ramps its weights down towards a
//!   range mesh's boundary.

use std::collections::VecDeque;

use serde::Serialize;

use crate::cloud::RangeSurface;
use crate::vec3::{cross, dot, norm, sub};

/// An edge longer than this many times the median grid-neighbour distance is a depth
/// discontinuity.
pub(crate) const LONG_EDGE_FACTOR: f64 = 4.0;

/// A triangle whose normal is more than this many degrees from the ray to the sensor is seen at
/// a grazing angle (a depth discontinuity or a silhouette) and is cut.
pub(crate) const GRAZING_DEG: f64 = 80.0;

/// Rings of the falloff: a point this many edges or more from the boundary has falloff 1.
const FALLOFF_RINGS: usize = 4;

/// What triangulating a range grid did, as `stablesurf info` prints it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RangeGridInfo {
    /// Grid columns and rows (`obj_info num_cols` / `num_rows`).
    pub cols: usize,
    /// Grid rows.
    pub rows: usize,
    /// Cells holding a sample.
    pub samples: usize,
    /// Grid squares with three or four samples at their corners.
    pub squares: usize,
    /// Triangles kept.
    pub triangles: usize,
    /// Triangles cut for an edge longer than [`LONG_EDGE_FACTOR`] × the median spacing (or no
    /// area).
    pub cut_long_edges: usize,
    /// Triangles cut for being seen at more than [`GRAZING_DEG`] from the sensor.
    pub cut_grazing: usize,
    /// Median distance between grid neighbours.
    pub median_spacing: f64,
    /// Estimated sensor position in the file's coordinates (`null` when not estimated).
    pub sensor: Option<[f64; 3]>,
    /// Which scan lines fixed the sensor: "rows" or "columns".
    pub sensor_from: Option<&'static str>,
}

/// A triangulated range grid.
#[derive(Clone, Debug)]
pub(crate) struct RangeGrid {
    /// Triangles facing the sensor.
    pub triangles: Vec<[u32; 3]>,
    /// The sensor and per-point falloff.
    pub surface: RangeSurface,
    /// Figures for `info`.
    pub info: RangeGridInfo,
}

/// Triangulates the grid `cells` (row-major, `cols` × `rows`, `u32::MAX` for an empty cell,
/// every other value `< points.len()`). Non-finite points are treated as empty cells.
pub(crate) fn triangulate(
    points: &[[f64; 3]],
    cols: usize,
    rows: usize,
    cells: &[u32],
) -> RangeGrid {
    let at = |r: usize, c: usize| -> Option<u32> {
        let v = *cells.get(r * cols + c)?;
        let p = points.get(v as usize)?;
        p.iter().all(|x| x.is_finite()).then_some(v)
    };
    let samples = (0..rows)
        .flat_map(|r| (0..cols).map(move |c| (r, c)))
        .filter(|&(r, c)| at(r, c).is_some())
        .count();
    let dist = |a: u32, b: u32| norm(sub(points[a as usize], points[b as usize]));

    // Median distance between grid neighbours.
    let mut spacings = Vec::new();
    for r in 0..rows {
        for c in 0..cols {
            let Some(a) = at(r, c) else { continue };
            if let Some(b) = (c + 1 < cols).then(|| at(r, c + 1)).flatten() {
                spacings.push(dist(a, b));
            }
            if let Some(b) = (r + 1 < rows).then(|| at(r + 1, c)).flatten() {
                spacings.push(dist(a, b));
            }
        }
    }
    let median_spacing = median(&mut spacings).unwrap_or(0.0);
    let max_edge = LONG_EDGE_FACTOR * median_spacing;

    // Candidate triangles, counter-clockwise in (column, row) order.
    let mut squares = 0;
    let mut cut_long_edges = 0;
    let mut candidates: Vec<[u32; 3]> = Vec::new();
    for r in 0..rows.saturating_sub(1) {
        for c in 0..cols.saturating_sub(1) {
            let (a, b, cc, d) = (at(r, c), at(r, c + 1), at(r + 1, c), at(r + 1, c + 1));
            let tris: [Option<[u32; 3]>; 2] = match (a, b, cc, d) {
                (Some(a), Some(b), Some(cc), Some(d)) => {
                    if dist(a, d) <= dist(b, cc) {
                        [Some([a, b, d]), Some([a, d, cc])]
                    } else {
                        [Some([a, b, cc]), Some([b, d, cc])]
                    }
                }
                (None, Some(b), Some(cc), Some(d)) => [Some([b, d, cc]), None],
                (Some(a), None, Some(cc), Some(d)) => [Some([a, d, cc]), None],
                (Some(a), Some(b), None, Some(d)) => [Some([a, b, d]), None],
                (Some(a), Some(b), Some(cc), None) => [Some([a, b, cc]), None],
                _ => continue,
            };
            squares += 1;
            for t in tris.into_iter().flatten() {
                let long = (0..3).any(|k| {
                    let l = dist(t[k], t[(k + 1) % 3]);
                    l.is_nan() || l > max_edge
                });
                if long || norm(normal(points, &t)) == 0.0 {
                    cut_long_edges += 1;
                } else {
                    candidates.push(t);
                }
            }
        }
    }

    let centroid = centroid(points, cells);
    // The grid's lines one way and the other, as the points each holds.
    let lines = |count: usize, length: usize, cell: fn(usize, usize) -> (usize, usize)| {
        (0..count).map(move |l| {
            (0..length)
                .filter_map(|k| {
                    let (r, c) = cell(l, k);
                    at(r, c)
                })
                .collect::<Vec<u32>>()
        })
    };
    let rows_fit = sensor_from_lines(points, centroid, lines(rows, cols, |r, c| (r, c)));
    let cols_fit = sensor_from_lines(points, centroid, lines(cols, rows, |c, r| (r, c)));
    let (sensor, sensor_from) = match (rows_fit, cols_fit) {
        (Some((s, e)), Some((_, f))) if e <= f => (Some(s), Some("rows")),
        (Some((s, _)), None) => (Some(s), Some("rows")),
        (_, Some((s, _))) => (Some(s), Some("columns")),
        (None, None) => (None, None),
    };

    // One sign for the whole grid.
    let toward = |t: &[u32; 3]| -> [f64; 3] {
        let m = tri_centroid(points, t);
        match sensor {
            Some(s) => sub(s, m),
            None => sub(m, centroid),
        }
    };
    let facing: f64 = candidates
        .iter()
        .map(|t| {
            let w = toward(t);
            let l = norm(w);
            if l > 0.0 {
                dot(normal(points, t), w) / l
            } else {
                0.0
            }
        })
        .sum();
    if facing < 0.0 {
        for t in &mut candidates {
            t.swap(1, 2);
        }
    }

    // Grazing triangles.
    let mut cut_grazing = 0;
    let mut triangles = Vec::with_capacity(candidates.len());
    let cos_max = GRAZING_DEG.to_radians().cos();
    for t in candidates {
        if sensor.is_some() {
            let (n, w) = (normal(points, &t), toward(&t));
            if dot(n, w) < cos_max * norm(n) * norm(w) {
                cut_grazing += 1;
                continue;
            }
        }
        triangles.push(t);
    }

    let falloff = falloff(points.len(), &triangles);
    RangeGrid {
        info: RangeGridInfo {
            cols,
            rows,
            samples,
            squares,
            triangles: triangles.len(),
            cut_long_edges,
            cut_grazing,
            median_spacing,
            sensor,
            sensor_from,
        },
        triangles,
        surface: RangeSurface { sensor, falloff },
    }
}

/// The median of `values` (reordered), or `None` when empty.
fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

/// The unnormalised right-hand normal of triangle `t`.
fn normal(points: &[[f64; 3]], t: &[u32; 3]) -> [f64; 3] {
    let [a, b, c] = t.map(|v| points[v as usize]);
    cross(sub(b, a), sub(c, a))
}

fn tri_centroid(points: &[[f64; 3]], t: &[u32; 3]) -> [f64; 3] {
    let [a, b, c] = t.map(|v| points[v as usize]);
    [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0)
}

/// The centroid of the grid's finite samples.
fn centroid(points: &[[f64; 3]], cells: &[u32]) -> [f64; 3] {
    let mut sum = [0.0; 3];
    let mut n = 0.0;
    for &v in cells {
        if let Some(p) = points
            .get(v as usize)
            .filter(|p| p.iter().all(|x| x.is_finite()))
        {
            sum = [0, 1, 2].map(|k| sum[k] + p[k]);
            n += 1.0;
        }
    }
    if n > 0.0 {
        sum.map(|x| x / n)
    } else {
        sum
    }
}

/// The least-squares point of the planes fitted to each scan line (see the module docs), and
/// the rms distance from it to the planes, or `None` when fewer than two directions are fixed.
fn sensor_from_lines(
    points: &[[f64; 3]],
    centroid: [f64; 3],
    lines: impl Iterator<Item = Vec<u32>>,
) -> Option<([f64; 3], f64)> {
    use nalgebra::{Matrix3, SymmetricEigen, Vector3};
    let mut m = Matrix3::<f64>::zeros();
    let mut rhs = Vector3::<f64>::zeros();
    let mut planes = Vec::new();
    let cen = Vector3::from(centroid);
    for line in lines {
        if line.len() < 10 {
            continue;
        }
        let pts: Vec<Vector3<f64>> = line
            .iter()
            .map(|&v| Vector3::from(points[v as usize]))
            .collect();
        let c = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
        let cov = pts
            .iter()
            .map(|p| (p - c) * (p - c).transpose())
            .sum::<Matrix3<f64>>();
        let eig = SymmetricEigen::new(cov);
        let mut order = [0, 1, 2];
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        // A straight line lies in many planes: only lines that clearly bend fix one.
        let bend = eig.eigenvalues[order[1]];
        if bend.is_nan() || bend <= 100.0 * eig.eigenvalues[order[0]].max(0.0) {
            continue;
        }
        let n: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned();
        m += n * n.transpose();
        rhs += n * n.dot(&(c - cen));
        planes.push((n, c));
    }
    if planes.len() < 3 {
        return None;
    }
    let eig = SymmetricEigen::new(m);
    let largest = eig.eigenvalues.max();
    let mut x = cen;
    let mut fixed = 0;
    for i in 0..3 {
        let w = eig.eigenvalues[i];
        if w > 1e-4 * largest {
            let v: Vector3<f64> = eig.eigenvectors.column(i).into_owned();
            x += v * (v.dot(&rhs) / w);
            fixed += 1;
        }
    }
    if fixed < 2 || !x.iter().all(|c| c.is_finite()) {
        return None;
    }
    let rms = (planes
        .iter()
        .map(|(n, c)| n.dot(&(x - c)).powi(2))
        .sum::<f64>()
        / planes.len() as f64)
        .sqrt();
    Some(([x[0], x[1], x[2]], rms))
}

/// Per point: (ring + 1) / [`FALLOFF_RINGS`], capped at 1, where ring 0 is the boundary of the
/// triangles (edges of one triangle) and the points in no triangle.
fn falloff(n: usize, triangles: &[[u32; 3]]) -> Vec<f32> {
    let mut edges: Vec<(u32, u32)> = triangles
        .iter()
        .flat_map(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
        .collect();
    edges.sort_unstable();
    let mut ring = vec![usize::MAX; n];
    let mut used = vec![false; n];
    let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); n];
    let mut queue = VecDeque::new();
    let mut s = 0;
    while s < edges.len() {
        let mut e = s + 1;
        while e < edges.len() && edges[e] == edges[s] {
            e += 1;
        }
        let (a, b) = edges[s];
        used[a as usize] = true;
        used[b as usize] = true;
        neighbours[a as usize].push(b);
        neighbours[b as usize].push(a);
        if e - s == 1 {
            for v in [a, b] {
                if ring[v as usize] == usize::MAX {
                    ring[v as usize] = 0;
                    queue.push_back(v);
                }
            }
        }
        s = e;
    }
    for (v, r) in ring.iter_mut().enumerate() {
        if !used[v] {
            *r = 0;
        }
    }
    while let Some(v) = queue.pop_front() {
        let next = ring[v as usize] + 1;
        if next >= FALLOFF_RINGS {
            continue;
        }
        for &u in &neighbours[v as usize] {
            if ring[u as usize] == usize::MAX {
                ring[u as usize] = next;
                queue.push_back(u);
            }
        }
    }
    ring.iter()
        .map(|&r| (r.min(FALLOFF_RINGS - 1) + 1) as f32 / FALLOFF_RINGS as f32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grid of `cols` × `rows` samples of a sphere of radius 1 about (0, 0, 0), seen from a
    /// pinhole at (0, 0, 5): rows are planes through the sensor.
    fn sphere_grid(cols: usize, rows: usize) -> (Vec<[f64; 3]>, Vec<u32>) {
        let sensor = [0.0, 0.0, 5.0];
        let mut points = Vec::new();
        let mut cells = Vec::new();
        for r in 0..rows {
            for c in 0..cols {
                let u = (c as f64 / (cols - 1) as f64 - 0.5) * 0.5;
                let v = (r as f64 / (rows - 1) as f64 - 0.5) * 0.5;
                let d = [u, v, -1.0];
                let l = norm(d);
                let d = d.map(|x| x / l);
                // Ray sensor + t d hits |x| = 1.
                let b = dot(sensor, d);
                let disc = b * b - (dot(sensor, sensor) - 1.0);
                if disc <= 0.0 {
                    cells.push(u32::MAX);
                    continue;
                }
                let t = -b - disc.sqrt();
                cells.push(points.len() as u32);
                points.push([0, 1, 2].map(|k| sensor[k] + t * d[k]));
            }
        }
        (points, cells)
    }

    #[test]
    fn sphere_grid_faces_the_sensor_and_finds_it() {
        let (points, cells) = sphere_grid(40, 30);
        let grid = triangulate(&points, 40, 30, &cells);
        let s = grid.info.sensor.expect("a sensor");
        assert!(norm(sub(s, [0.0, 0.0, 5.0])) < 0.05, "{s:?}");
        assert!(grid.triangles.len() > 1000);
        for t in &grid.triangles {
            let n = normal(&points, t);
            let m = tri_centroid(&points, t);
            assert!(dot(n, m) > 0.0, "faces the sensor, outward on the sphere");
        }
        // The rim of the visible cap is grazing: some cut there; interior falloff 1.
        assert!(grid.surface.falloff.contains(&1.0));
        assert!(grid.surface.falloff.iter().all(|&f| f > 0.0 && f <= 1.0));
    }

    #[test]
    fn a_depth_jump_is_cut() {
        let (mut points, cells) = sphere_grid(20, 20);
        // Push the right half back by 10 spacings: the seam's triangles go.
        let whole = triangulate(&points, 20, 20, &cells);
        for (i, &v) in cells.iter().enumerate() {
            if v != u32::MAX && i % 20 >= 10 {
                points[v as usize][2] -= 0.5;
            }
        }
        let cut = triangulate(&points, 20, 20, &cells);
        assert!(cut.info.cut_long_edges >= whole.info.cut_long_edges + 19);
        assert!(cut.triangles.len() < whole.triangles.len());
    }
}
