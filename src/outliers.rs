//! Outlier removal: [`PointCloud`] → inlier [`PointCloud`] plus what was dropped.
//!
//! Input: a validated cloud (finite coordinates, indices in range) and [`OutlierParams`].
//! Output: an [`OutlierSplit`]: the inliers (borrowed unchanged when nothing is removed), the
//! number of points and faces dropped, and the box of the inliers. Pure: no IO, no environment;
//! the result is the same whatever the thread count.
//!
//! Two rules: points far outside the bulk of the data (below), on every input; and, on a bare
//! point cloud (no normals, no faces), isolated points (see [Isolated points](#isolated-points)).
//!
//! # Why
//!
//! The fit normalises by the centroid and scale of *all* points and the meshing box is the box of
//! *all* points, so a single stray point far away (a scanner glitch, `1e30` written for "no
//! data") shrinks the object to nothing in the normalised frame and the mesh loses it. This stage
//! drops such points before anything measures the cloud.
//!
//! # The rule
//!
//! 1. `c` = the coordinate-wise median of the points (the lower median for an even count);
//!    `d(p)` = the Euclidean distance from `c`.
//! 2. `r` = the `BULK_QUANTILE` quantile of the distances (the radius holding 99% of the points).
//! 3. A point is *far* when `d(p) > FAR_FACTOR · r`.
//! 4. Sort the distances. A cut is at the first position `j` where the point is far **and** the
//!    distance jumps from the previous point by more than `GAP_FACTOR · r`:
//!    `d[j] − d[j−1] > GAP_FACTOR · r`. Every point from `j` on is an outlier; nothing is removed
//!    when there is no such `j`.
//!
//! What it removes: a small group (at most 1% of the points, since only points past the 99%
//! radius can be far) lying well outside the bulk *and* cut off from it by an empty spherical
//! shell of thickness `GAP_FACTOR · r`: by the triangle inequality every removed point is at
//! least that far from every kept point.
//!
//! What it protects:
//! * Ordinary objects: a compact object has nothing past 3× its 99% radius.
//! * Long thin real features (an antenna, a handle, a tail): such a feature is sampled
//!   continuously, so its sorted distances have no gap of `GAP_FACTOR · r` and it is kept however
//!   far it extends and however few points it holds. Only the part past a hole in the sampling
//!   wider than `GAP_FACTOR · r` (and past 3·r) could go.
//! * Several real objects: a second object holding more than 1% of the points is where the 99%
//!   radius falls, so `r` reaches it and it is not far.
//! * Tiny inputs: fewer than `MIN_POINTS` points are returned unchanged, as are degenerate
//!   clouds whose 99% radius is zero (99% of the points on one position).
//!
//! Distances are computed from differences of quarter coordinates, rescaled when their squares
//! would overflow, so points at `±1e300` (even `±f64::MAX`) give finite distances, never `inf` or
//! `NaN`. Cost: O(N) selections for the medians and the quantile, plus a sort of the far points
//! only; one thread, deterministic.
//!
//! # Isolated points
//!
//! A stray return near the object (dust, a reflection, a mixed pixel at a silhouette) is not
//! far from the bulk, so the rule above keeps it; but the local fits near it pass through it and
//! the blend grows sheets and bubbles around it (the 36,671-point bunny with 0.1% noise and 73
//! points strewn in its box: 3 components, not watertight, 14% of the area more than 1% of the
//! diagonal from the data). So, on a cloud with neither normals nor faces (a raw scan's points):
//!
//! 1. `reach(p)` = the distance from `p` to its `ISOLATION_RANK`-th nearest other point, and
//!    `local(p)` = the median of `reach(q)` over its `ISOLATION_NEIGHBOURS` nearest `q`: the
//!    sampling of the surface around `p`;
//! 2. `p` and a neighbour `q` (one of its `ISOLATION_NEIGHBOURS` nearest) are linked when
//!    `|p − q| ≤ ISOLATION_FACTOR · local(p)` and `≤ ISOLATION_FACTOR · local(q)`;
//! 3. the points of a linked group of at most `ISOLATED_GROUP_MAX` points are isolated
//!    (fewer than a local fit needs), unless that would leave out half the cloud or more, or
//!    most points coincide with three others (no spacing to judge by).
//!
//! On a scanned surface every point is linked to its neighbours (they lie within a few
//! spacings), so a surface is one large group, and a sparse part (a scan's far range) is judged
//! by its own spacing. A stray point more than `ISOLATION_FACTOR` spacings off the surface
//! links to no surface point, whose own spacing is short, and strays link only among
//! themselves. Where the sampling changes abruptly by more than `ISOLATION_FACTOR` (a rod
//! sampled ten times more sparsely than the ball it leaves), the first point or two past the
//! change can be cut off with the strays. A cloud with normals or faces is left as it is: it comes from a tool that
//! already made a surface or normals of it (a mesh, a range grid, an oriented cloud), and the
//! test's k-nearest search would cost as much again as a run on such a cloud does without
//! normals to estimate (CHANGELOG.md).

use std::borrow::Cow;

use rayon::prelude::*;

use crate::cloud::{Aabb, PointCloud};
use crate::numerics::{PointGrid, UnionFind};
use crate::vec3::{norm, sub};

/// Quantile of the distances to the median centre that defines the bulk radius `r`: 0.99, so up
/// to 1% of the points may be outliers without moving `r`, and at most 1% can ever be removed.
pub(crate) const BULK_QUANTILE: f64 = 0.99;

/// A point is far when its distance to the median centre exceeds `FAR_FACTOR · r`.
pub(crate) const FAR_FACTOR: f64 = 3.0;

/// The far points are cut only after a jump of more than `GAP_FACTOR · r` in the sorted distances
/// (an empty shell that thick around the bulk), so a continuously sampled feature is never cut.
pub(crate) const GAP_FACTOR: f64 = 0.5;

/// Clouds with fewer points are never trimmed: too few points to tell a bulk from a stray one.
pub(crate) const MIN_POINTS: usize = 20;

/// Two neighbouring points of a bare cloud are linked when they are at most this many times
/// either one's local spacing apart (see [Isolated points](self#isolated-points)).
pub(crate) const ISOLATION_FACTOR: f64 = 5.0;

/// A point's reach, its local spacing's measure, is the distance to its `ISOLATION_RANK`-th
/// nearest other point.
pub(crate) const ISOLATION_RANK: usize = 3;

/// How many nearest neighbours a point is linked to, and whose reaches give its local spacing.
pub(crate) const ISOLATION_NEIGHBOURS: usize = 8;

/// Linked groups of at most this many points are isolated: fewer than the 15 points a local
/// fit of degree 2 needs.
pub(crate) const ISOLATED_GROUP_MAX: usize = 14;

/// Parameters of [`remove_outliers`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutlierParams {
    /// Keep every point (the `--keep-outliers` escape hatch): nothing is removed.
    pub keep: bool,
    /// See `BULK_QUANTILE`.
    pub bulk_quantile: f64,
    /// See `FAR_FACTOR`.
    pub far_factor: f64,
    /// See `GAP_FACTOR`.
    pub gap_factor: f64,
    /// See `ISOLATION_FACTOR`; infinity keeps every isolated point.
    pub isolation_factor: f64,
}

impl Default for OutlierParams {
    fn default() -> Self {
        OutlierParams {
            keep: false,
            bulk_quantile: BULK_QUANTILE,
            far_factor: FAR_FACTOR,
            gap_factor: GAP_FACTOR,
            isolation_factor: ISOLATION_FACTOR,
        }
    }
}

/// The result of [`remove_outliers`].
#[derive(Clone, Debug, PartialEq)]
pub struct OutlierSplit<'a> {
    /// The inliers: `Cow::Borrowed(input)` when nothing was removed; otherwise the kept points in
    /// their input order with their normals, and the triangles whose three corners are all kept,
    /// re-indexed into the new arrays (faces touching a removed point are dropped).
    pub cloud: Cow<'a, PointCloud>,
    /// Number of points removed.
    pub removed: usize,
    /// Of them, the isolated points of a bare cloud (the rest are far from the bulk).
    pub isolated: usize,
    /// Number of triangles dropped because a corner was removed.
    pub removed_faces: usize,
    /// Input indices of the removed points, ascending (for a warning that names them).
    pub removed_indices: Vec<usize>,
    /// Box of the kept points ([`Aabb::from_points`] of `cloud.points`); a zero box at the origin
    /// for an empty input.
    pub bulk: Aabb,
    /// The median centre `c` of the rule (the origin for an empty input).
    pub center: [f64; 3],
    /// The bulk radius `r` (distance from `center` holding `BULK_QUANTILE` of the points), or
    /// `None` when the rule did not run (`keep`, fewer than `MIN_POINTS` points).
    pub bulk_radius: Option<f64>,
}

/// Removes the points far from and cut off from the bulk of `cloud` (see the module docs for
/// the rule, what it removes and what it protects).
///
/// ```
/// use stablesurf::outliers::{remove_outliers, OutlierParams};
/// use stablesurf::PointCloud;
/// let mut points: Vec<[f64; 3]> = (0..100)
///     .map(|i| {
///         let t = i as f64 * 0.7;
///         [t.cos(), t.sin(), (i as f64 / 50.0) - 1.0]
///     })
///     .collect();
/// points.push([1e30, 1e30, 1e30]);
/// let cloud = PointCloud { points, ..Default::default() };
/// let split = remove_outliers(&cloud, &OutlierParams::default());
/// assert_eq!((split.removed, split.removed_indices.clone()), (1, vec![100]));
/// assert_eq!(split.cloud.points.len(), 100);
/// assert!(split.bulk.max[0] <= 1.0);
/// ```
pub fn remove_outliers<'a>(cloud: &'a PointCloud, params: &OutlierParams) -> OutlierSplit<'a> {
    let n = cloud.points.len();
    let center = if n == 0 {
        [0.0; 3]
    } else {
        median_center(&cloud.points)
    };
    let unchanged = |bulk_radius| OutlierSplit {
        cloud: Cow::Borrowed(cloud),
        removed: 0,
        isolated: 0,
        removed_faces: 0,
        removed_indices: Vec::new(),
        bulk: bulk_box(&cloud.points),
        center,
        bulk_radius,
    };
    if params.keep || n < MIN_POINTS {
        return unchanged(None);
    }
    let (radius, far) = far_isolated(&cloud.points, center, params);
    let bare = cloud.normals.is_none() && cloud.triangles.is_empty() && cloud.range.is_none();
    let isolated = if bare && params.isolation_factor.is_finite() {
        // Judged among the points the far rule keeps.
        let kept: Vec<usize> = (0..n).filter(|i| far.binary_search(i).is_err()).collect();
        let points: Vec<[f64; 3]> = kept.iter().map(|&i| cloud.points[i]).collect();
        isolated_points(&points, params.isolation_factor)
            .into_iter()
            .map(|i| kept[i])
            .collect()
    } else {
        Vec::new()
    };
    if far.is_empty() && isolated.is_empty() {
        return unchanged(Some(radius));
    }
    let mut removed_indices = far;
    removed_indices.extend_from_slice(&isolated);
    removed_indices.sort_unstable();
    let (inliers, removed_faces) = without(cloud, &removed_indices);
    OutlierSplit {
        bulk: bulk_box(&inliers.points),
        cloud: Cow::Owned(inliers),
        removed: removed_indices.len(),
        isolated: isolated.len(),
        removed_faces,
        removed_indices,
        center,
        bulk_radius: Some(radius),
    }
}

/// Box of `points`, or a zero box at the origin when there are none.
fn bulk_box(points: &[[f64; 3]]) -> Aabb {
    Aabb::from_points(points).unwrap_or(Aabb {
        min: [0.0; 3],
        max: [0.0; 3],
    })
}

/// Coordinate-wise (lower) median of a non-empty point set, by O(N) selection.
fn median_center(points: &[[f64; 3]]) -> [f64; 3] {
    let mid = (points.len() - 1) / 2;
    let mut coordinate = Vec::with_capacity(points.len());
    [0, 1, 2].map(|a| {
        coordinate.clear();
        coordinate.extend(points.iter().map(|p| p[a]));
        *coordinate.select_nth_unstable_by(mid, f64::total_cmp).1
    })
}

/// A quarter of the distance from `p` to `c`, finite for every pair of finite points.
///
/// The differences are taken on quarter coordinates (no overflow however far apart), and the norm
/// is rescaled when the plain sum of squares would overflow or underflow. All comparisons of the
/// rule are ratios of distances, so the common factor 1/4 does not matter.
fn quarter_distance(p: [f64; 3], c: [f64; 3]) -> f64 {
    let d = [0, 1, 2].map(|a| 0.25 * p[a] - 0.25 * c[a]);
    let s = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    if s.is_finite() && s >= f64::MIN_POSITIVE {
        return s.sqrt();
    }
    let m = d.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    if m == 0.0 {
        return 0.0;
    }
    // Each |d| ≤ f64::MAX / 2, so m · √3 stays finite.
    let t = d.map(|x| x / m);
    m * (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt()
}

/// The bulk radius (in quarter units) and the ascending input indices of the outliers.
fn far_isolated(
    points: &[[f64; 3]],
    center: [f64; 3],
    params: &OutlierParams,
) -> (f64, Vec<usize>) {
    let n = points.len();
    let distances: Vec<f64> = points
        .iter()
        .map(|&p| quarter_distance(p, center))
        .collect();
    let q = params.bulk_quantile.clamp(0.0, 1.0);
    // floor(q · (n − 1)): the index of the quantile in the sorted distances.
    let q_index = ((q * (n - 1) as f64).floor() as usize).min(n - 1);
    let mut sorted = distances.clone();
    let (_, &mut radius, _) = sorted.select_nth_unstable_by(q_index, f64::total_cmp);
    if radius <= 0.0 {
        // 99% of the points on the centre: no scale to judge the rest by.
        return (0.0, Vec::new());
    }
    let far = params.far_factor * radius;
    let gap = params.gap_factor * radius;
    // The far points, sorted by (distance, index); only they can be cut, and the cut needs the
    // largest distance below them (the last point before the first far one).
    let mut far_points: Vec<(f64, usize)> = distances
        .iter()
        .enumerate()
        .filter(|&(_, &d)| d > far)
        .map(|(i, &d)| (d, i))
        .collect();
    if far_points.is_empty() {
        return (4.0 * radius, Vec::new());
    }
    far_points.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut previous = distances
        .iter()
        .copied()
        .filter(|&d| d <= far)
        .fold(0.0_f64, f64::max);
    let mut cut = None;
    for (k, &(d, _)) in far_points.iter().enumerate() {
        if d - previous > gap {
            cut = Some(k);
            break;
        }
        previous = d;
    }
    let mut removed: Vec<usize> = match cut {
        Some(k) => far_points[k..].iter().map(|&(_, i)| i).collect(),
        None => Vec::new(),
    };
    removed.sort_unstable();
    (4.0 * radius, removed)
}

/// The ascending indices of the isolated points of `points` (see
/// [Isolated points](self#isolated-points)), with `factor` for [`ISOLATION_FACTOR`]; none when
/// there are too few points to have [`ISOLATION_NEIGHBOURS`] neighbours.
fn isolated_points(points: &[[f64; 3]], factor: f64) -> Vec<usize> {
    let n = points.len();
    let Some(grid) = PointGrid::new(points) else {
        return Vec::new();
    };
    let neighbours = grid.all_nearest(points, ISOLATION_NEIGHBOURS);
    if neighbours.stride() < ISOLATION_NEIGHBOURS {
        return Vec::new();
    }
    let distance = |i: usize, j: u32| norm(sub(points[i], points[j as usize]));
    let reach: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| distance(i, neighbours.row(i)[ISOLATION_RANK - 1]))
        .collect();
    let mut sorted = reach.clone();
    let (_, &mut median_reach, _) = sorted.select_nth_unstable_by(n / 2, f64::total_cmp);
    if median_reach <= 0.0 {
        // Most points coincide in fours or more: no spacing to judge by.
        return Vec::new();
    }
    let local: Vec<f64> = (0..n)
        .into_par_iter()
        .map(|i| {
            let mut r = [0.0; ISOLATION_NEIGHBOURS];
            for (slot, &j) in r.iter_mut().zip(neighbours.row(i)) {
                *slot = reach[j as usize];
            }
            r.sort_unstable_by(f64::total_cmp);
            0.5 * (r[ISOLATION_NEIGHBOURS / 2 - 1] + r[ISOLATION_NEIGHBOURS / 2])
        })
        .collect();
    let mut groups = UnionFind::new(n);
    for i in 0..n {
        for &j in neighbours.row(i) {
            let d = distance(i, j);
            if d <= factor * local[i] && d <= factor * local[j as usize] {
                groups.union(i as u32, j);
            }
        }
    }
    let root: Vec<u32> = (0..n as u32).map(|i| groups.find(i)).collect();
    let mut size = vec![0usize; n];
    for &r in &root {
        size[r as usize] += 1;
    }
    let isolated: Vec<usize> = (0..n)
        .filter(|&i| size[root[i] as usize] <= ISOLATED_GROUP_MAX)
        .collect();
    if 2 * isolated.len() >= n {
        // No surface at this scale: nothing to judge the points against.
        return Vec::new();
    }
    isolated
}

/// `cloud` without the points at `removed` (ascending input indices, non-empty): the kept points
/// and normals in input order, the triangles with all corners kept re-indexed; and the number of
/// triangles dropped.
fn without(cloud: &PointCloud, removed: &[usize]) -> (PointCloud, usize) {
    // Destructured so that a new per-point field fails to compile here until it is carried over.
    let PointCloud {
        points,
        normals,
        triangles,
        range,
        colours,
        intensity,
        scans,
    } = cloud;
    const GONE: u32 = u32::MAX;
    let mut new_index = vec![0_u32; points.len()];
    let mut next = removed.iter().peekable();
    let mut kept = 0_u32;
    for (i, slot) in new_index.iter_mut().enumerate() {
        if next.peek() == Some(&&i) {
            next.next();
            *slot = GONE;
        } else {
            *slot = kept;
            kept += 1;
        }
    }
    let keep = |i: usize| new_index[i] != GONE;
    let points: Vec<[f64; 3]> = (0..points.len())
        .filter(|&i| keep(i))
        .map(|i| points[i])
        .collect();
    let normals = normals.as_ref().map(|normals| {
        (0..normals.len())
            .filter(|&i| keep(i))
            .map(|i| normals[i])
            .collect()
    });
    let kept_triangles: Vec<[u32; 3]> = triangles
        .iter()
        .filter(|t| t.iter().all(|&i| keep(i as usize)))
        .map(|t| t.map(|i| new_index[i as usize]))
        .collect();
    let removed_faces = triangles.len() - kept_triangles.len();
    let range = range.as_ref().map(|r| crate::cloud::RangeSurface {
        sensor: r.sensor,
        falloff: (0..r.falloff.len())
            .filter(|&i| keep(i))
            .map(|i| r.falloff[i])
            .collect(),
    });
    let colours = colours
        .as_ref()
        .map(|c| (0..c.len()).filter(|&i| keep(i)).map(|i| c[i]).collect());
    let intensity = intensity
        .as_ref()
        .map(|v| (0..v.len()).filter(|&i| keep(i)).map(|i| v[i]).collect());
    // A scan's points are consecutive, so its new count is its old one less the removed points
    // in its run.
    let scans = scans.as_ref().map(|scans| {
        let mut start = 0;
        scans
            .iter()
            .map(|s| {
                let end = start + s.n_points;
                let n_points = (start..end.min(new_index.len()))
                    .filter(|&i| keep(i))
                    .count();
                start = end;
                crate::cloud::ScanOrigin {
                    sensor: s.sensor,
                    n_points,
                }
            })
            .collect()
    });
    (
        PointCloud {
            points,
            normals,
            triangles: kept_triangles,
            range,
            colours,
            intensity,
            scans,
        },
        removed_faces,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` points spread evenly over the sphere of radius `r` about `c` (Fibonacci lattice).
    fn sphere(n: usize, c: [f64; 3], r: f64) -> Vec<[f64; 3]> {
        let golden = std::f64::consts::PI * (3.0 - 5.0_f64.sqrt());
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let s = (1.0 - z * z).sqrt();
                let t = golden * i as f64;
                [c[0] + r * s * t.cos(), c[1] + r * s * t.sin(), c[2] + r * z]
            })
            .collect()
    }

    fn cloud(points: Vec<[f64; 3]>) -> PointCloud {
        PointCloud {
            points,
            ..Default::default()
        }
    }

    fn removed(points: Vec<[f64; 3]>) -> usize {
        remove_outliers(&cloud(points), &OutlierParams::default()).removed
    }

    #[test]
    fn one_point_at_1e30_is_removed() {
        let mut points = sphere(500, [0.0; 3], 1.0);
        points.push([1e30, 1e30, 1e30]);
        let c = cloud(points);
        let split = remove_outliers(&c, &OutlierParams::default());
        assert_eq!(split.removed, 1);
        assert_eq!(split.removed_indices, vec![500]);
        assert_eq!(split.cloud.points[..], c.points[..500]);
        assert!(split.bulk.max.iter().all(|&x| x <= 1.0));
        assert!(split.bulk.min.iter().all(|&x| x >= -1.0));
        let r = split.bulk_radius.unwrap();
        assert!(r.is_finite() && (r - 1.0).abs() < 0.1, "{r}");
    }

    #[test]
    fn three_far_points_are_removed() {
        let mut points = sphere(500, [5.0, -2.0, 1.0], 1.0);
        points.insert(17, [1e30, -1e30, 3.0]);
        points.push([-1e300, 1e300, -1e300]);
        points.push([200.0, 0.0, 0.0]);
        let c = cloud(points);
        let split = remove_outliers(&c, &OutlierParams::default());
        assert_eq!(split.removed, 3);
        assert_eq!(split.removed_indices, vec![17, 501, 502]);
        assert!(split
            .cloud
            .points
            .iter()
            .all(|p| p.iter().all(|x| x.is_finite() && x.abs() < 10.0)));
    }

    #[test]
    fn extreme_coordinates_give_finite_distances() {
        let m = f64::MAX;
        assert!(quarter_distance([m, -m, m], [-m, m, -m]).is_finite());
        assert!(quarter_distance([1e-320, 0.0, 0.0], [0.0; 3]) > 0.0);
        assert_eq!(quarter_distance([3.0; 3], [3.0; 3]), 0.0);
        let d = quarter_distance([4.0, 0.0, 3.0 * 1e200], [0.0; 3]);
        assert!((d / (0.25 * 3e200) - 1.0).abs() < 1e-12);
        let mut points = sphere(100, [0.0; 3], 1.0);
        points.push([m, m, m]);
        points.push([-m, -m, -m]);
        assert_eq!(removed(points), 2);
    }

    /// `n` points on the unit sphere and `extra` more at `at(0..extra)`, under 1% of the
    /// whole (asserted).
    fn sphere_and(n: usize, extra: usize, at: impl Fn(usize) -> [f64; 3]) -> Vec<[f64; 3]> {
        let mut points = sphere(n, [0.0; 3], 1.0);
        points.extend((0..extra).map(at));
        assert!(extra * 100 < points.len());
        points
    }

    #[test]
    fn long_thin_cylinder_with_a_sphere_is_kept() {
        // A ball of radius 1 with a rod of radius 0.02 running out to x = 40: the rod holds well
        // under 1% of the points, so only the gap test keeps it.
        let rod = 150;
        let points = sphere_and(20_000, rod, |i| {
            let x = 1.0 + 39.0 * i as f64 / (rod - 1) as f64;
            let t = i as f64 * 2.4;
            [x, 0.02 * t.cos(), 0.02 * t.sin()]
        });
        let input = cloud(points);
        let split = remove_outliers(&input, &OutlierParams::default());
        // The far rule keeps the whole rod; the isolation rule (a bare cloud) cuts off its two
        // points next to the ball, where the spacing jumps from 0.025 to 0.26.
        assert_eq!(split.removed - split.isolated, 0);
        assert_eq!(split.removed_indices, vec![20_001, 20_002]);
    }

    #[test]
    fn sphere_with_a_dense_antenna_is_kept() {
        // Sampled every 0.1 (the sphere's own spacing is √(4π/N) ≈ 0.035), the antenna is far
        // longer than the object and holds under 1% of the points.
        let antenna = 90;
        let mut points = sphere_and(10_000, antenna, |i| [0.0, 0.0, 1.0 + 0.1 * (i + 1) as f64]);
        assert_eq!(removed(points.clone()), 0);
        // The same antenna with a stray point well past its tip and a gap: only that point goes.
        points.push([0.0, 0.0, 30.0]);
        let c = cloud(points);
        let split = remove_outliers(&c, &OutlierParams::default());
        assert_eq!(split.removed_indices, vec![c.points.len() - 1]);
    }

    #[test]
    fn two_clusters_are_both_kept() {
        let mut points = sphere(300, [0.0; 3], 1.0);
        points.extend(sphere(300, [1000.0, 0.0, 0.0], 1.0));
        assert_eq!(removed(points), 0);
        // An unequal split, the small cluster still above 1%.
        let mut points = sphere(1000, [0.0; 3], 1.0);
        points.extend(sphere(20, [0.0, 500.0, 0.0], 0.5));
        assert_eq!(removed(points), 0);
    }

    #[test]
    fn triangles_are_remapped_and_normals_stay_aligned() {
        let mut points = sphere(200, [0.0; 3], 1.0);
        // Outliers at input indices 3 and 100.
        points[3] = [1e30, 0.0, 0.0];
        points[100] = [0.0, -1e9, 0.0];
        let normals: Vec<[f64; 3]> = (0..points.len()).map(|i| [i as f64, 0.0, 1.0]).collect();
        let triangles = vec![
            [0, 1, 2],
            [2, 3, 4],       // touches 3
            [4, 5, 6],       // shifts by 1
            [99, 100, 101],  // touches 100
            [101, 150, 199], // shifts by 2
            [199, 0, 50],
        ];
        let n = points.len();
        let c = PointCloud {
            points,
            normals: Some(normals),
            triangles,
            range: None,
            colours: Some((0..n).map(|i| [i as u16, 0, 0]).collect()),
            intensity: Some((0..n).map(|i| i as f32).collect()),
            // Two scans: 0..150 (holding both outliers) and 150..200.
            scans: Some(vec![
                crate::cloud::ScanOrigin {
                    sensor: [5.0, 0.0, 0.0],
                    n_points: 150,
                },
                crate::cloud::ScanOrigin {
                    sensor: [-5.0, 0.0, 0.0],
                    n_points: 50,
                },
            ]),
        };
        let split = remove_outliers(&c, &OutlierParams::default());
        assert_eq!(split.removed_indices, vec![3, 100]);
        let out = split.cloud.as_ref();
        let colours = out.colours.as_ref().unwrap();
        let intensity = out.intensity.as_ref().unwrap();
        assert_eq!((colours[3][0], intensity[3]), (4, 4.0));
        assert_eq!((colours[197][0], intensity[197]), (199, 199.0));
        let scans = out.scans.as_ref().unwrap();
        assert_eq!((scans[0].n_points, scans[1].n_points), (148, 50));
        assert_eq!(scans[1].sensor, [-5.0, 0.0, 0.0]);
        assert_eq!((split.removed, split.removed_faces), (2, 2));
        let out = split.cloud.as_ref();
        assert_eq!(out.points.len(), 198);
        assert_eq!(
            out.triangles,
            vec![[0, 1, 2], [3, 4, 5], [99, 148, 197], [197, 0, 49]]
        );
        let normals = out.normals.as_ref().unwrap();
        assert_eq!(normals.len(), out.points.len());
        // Each kept point still carries its own normal (which records its input index).
        for (j, (p, nrm)) in out.points.iter().zip(normals).enumerate() {
            let i = nrm[0] as usize;
            assert_eq!(*p, c.points[i], "point {j}");
            assert!(i != 3 && i != 100);
        }
        // Every kept triangle names the same positions as before.
        for t in &out.triangles {
            assert!(t.iter().all(|&i| (i as usize) < out.points.len()));
        }
        assert_eq!(out.points[148], c.points[150]);
    }

    #[test]
    fn keep_removes_nothing_and_borrows() {
        let mut points = sphere(500, [0.0; 3], 1.0);
        points.push([1e30, 1e30, 1e30]);
        let c = cloud(points);
        let params = OutlierParams {
            keep: true,
            ..Default::default()
        };
        let split = remove_outliers(&c, &params);
        assert_eq!((split.removed, split.removed_faces), (0, 0));
        assert!(matches!(split.cloud, Cow::Borrowed(_)));
        assert_eq!(split.bulk.max, [1e30; 3]);
        // Nothing to remove: borrowed too.
        let clean = cloud(sphere(500, [0.0; 3], 1.0));
        let split = remove_outliers(&clean, &OutlierParams::default());
        assert!(matches!(split.cloud, Cow::Borrowed(_)) && split.removed == 0);
    }

    #[test]
    fn tiny_degenerate_and_duplicate_inputs_remove_nothing() {
        assert_eq!(removed(Vec::new()), 0);
        let empty = cloud(Vec::new());
        assert_eq!(
            remove_outliers(&empty, &OutlierParams::default()).bulk.min,
            [0.0; 3]
        );
        for n in 1..=10 {
            let mut points = sphere(n - 1, [0.0; 3], 1.0);
            points.push([1e30, 1e30, 1e30]);
            assert_eq!(removed(points), 0, "{n} points");
        }
        // All on one position, with or without a far point: no scale, nothing removed.
        assert_eq!(removed(vec![[1.0, 2.0, 3.0]; 1000]), 0);
        let mut points = vec![[1.0, 2.0, 3.0]; 1000];
        points.push([1e30, 0.0, 0.0]);
        assert_eq!(removed(points), 0);
        // Heavy duplication of a real object changes nothing, the far point still goes.
        let mut points: Vec<[f64; 3]> = sphere(300, [0.0; 3], 1.0).repeat(4);
        points.push([0.0, 1e30, 0.0]);
        points.push([0.0, 1e30, 0.0]);
        assert_eq!(removed(points), 2);
    }

    #[test]
    fn result_does_not_depend_on_point_order() {
        let mut points = sphere(400, [0.0; 3], 1.0);
        points.push([50.0, 0.0, 0.0]);
        points.push([0.0, 1e20, 0.0]);
        let forward = cloud(points.clone());
        let a = remove_outliers(&forward, &OutlierParams::default());
        points.reverse();
        let backward = cloud(points);
        let b = remove_outliers(&backward, &OutlierParams::default());
        assert_eq!(a.removed, 2);
        assert_eq!(b.removed_indices, vec![0, 1]);
        assert_eq!(a.bulk, b.bulk);
        assert_eq!(a.bulk_radius, b.bulk_radius);
    }

    /// The scans in `../shared/data`: nothing removed from the meshes nor from the raw range
    /// scans, and the counts printed for every file (`cargo test --lib outliers -- --nocapture`). Skipped with a notice when the
    /// directory is absent, except under CI, where that is a failure.
    #[test]
    fn shared_data_scans_lose_nothing() {
        use std::path::Path;
        let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data"));
        if !dir.is_dir() {
            assert!(
                std::env::var_os("CI").is_none(),
                "CI is set but the test data directory {} is missing",
                dir.display()
            );
            println!("skipped: no test data at {}", dir.display());
            return;
        }
        let closed = [
            "bunny_zipper.ply",
            "duck.ply",
            "fandisk.obj",
            "fertility.ply",
            "max_planck.obj",
            "patella_vhf_left.ply",
            "quadknot.obj",
            "spot.obj",
            "teapot.obj",
        ];
        let raw = [
            "bun000.ply",
            "bunny-scans/bun090.ply",
            "bunny-scans/bun180.ply",
            "bunny-scans/bun270.ply",
            "bunny-scans/bun315.ply",
            "bunny-scans/top2.ply",
        ];
        let mut failures = Vec::new();
        for name in closed.iter().chain(&raw) {
            let path = dir.join(name);
            let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            let c = crate::import::import_bytes(&bytes, &path)
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            let split = remove_outliers(&c, &OutlierParams::default());
            // How far the farthest point lies, in bulk radii: the margin to FAR_FACTOR.
            let r = split.bulk_radius.unwrap_or(0.0);
            let max = c
                .points
                .iter()
                .map(|&p| 4.0 * quarter_distance(p, split.center))
                .fold(0.0_f64, f64::max);
            println!(
                "{name}: {} points, {} removed, {} faces dropped, farthest {:.3} r",
                c.points.len(),
                split.removed,
                split.removed_faces,
                max / r
            );
            // The raw range scans too: their stray points all lie within 1.2 r.
            if split.removed != 0 {
                failures.push(*name);
            }
            // A raw scan's points alone (no grid, no normals), as an XYZ file of them would
            // come: the isolation rule leaves out at most 0.1% (the views of bunny-scans/ lose
            // 12 to 16 points, in groups of 1 to 13 lying 6 to 26 median spacings from the
            // rest; bun000 none).
            if raw.contains(name) {
                let bare = cloud(c.points.clone());
                let split = remove_outliers(&bare, &OutlierParams::default());
                println!("{name}, points only: {} removed", split.removed);
                if split.removed * 1000 > c.points.len() {
                    failures.push(*name);
                }
            }
        }
        assert!(failures.is_empty(), "points removed from {failures:?}");
    }

    /// A 20,000-point Fibonacci sphere (spacing about 0.025) with strays beside it: single
    /// points 0.2 to 0.5 outside and inside, and a group of three 0.01 apart.
    fn sphere_with_strays() -> (Vec<[f64; 3]>, usize) {
        let mut points = sphere(20_000, [0.0; 3], 1.0);
        let strays = [
            [1.2, 0.0, 0.0],
            [0.0, -1.35, 0.0],
            [0.0, 0.0, 1.5],
            [0.5, 0.3, 0.1],
            [-0.4, 0.0, -0.5],
            [0.9, 0.9, 0.0],
            [0.91, 0.9, 0.0],
            [0.9, 0.91, 0.0],
        ];
        points.extend(strays);
        (points, strays.len())
    }

    #[test]
    fn strays_beside_a_bare_cloud_are_isolated_and_nothing_else() {
        let (points, strays) = sphere_with_strays();
        let n = points.len();
        let bare = cloud(points.clone());
        let split = remove_outliers(&bare, &OutlierParams::default());
        assert_eq!(split.isolated, strays);
        assert_eq!(split.removed_indices, ((n - strays)..n).collect::<Vec<_>>());
        // The same points with normals, or with the rule off: nothing is removed.
        let oriented = PointCloud {
            normals: Some(vec![[0.0, 0.0, 1.0]; n]),
            ..cloud(points.clone())
        };
        assert_eq!(
            remove_outliers(&oriented, &OutlierParams::default()).removed,
            0
        );
        let off = OutlierParams {
            isolation_factor: f64::INFINITY,
            ..Default::default()
        };
        assert_eq!(remove_outliers(&cloud(points), &off).removed, 0);
    }

    #[test]
    fn random_and_unevenly_sampled_surfaces_keep_every_point() {
        // 20,000 uniformly random points on the unit sphere (random gaps, no lattice).
        let mut rng = crate::numerics::Lcg::new(7);
        let random: Vec<[f64; 3]> = (0..20_000)
            .map(|_| {
                let z = 2.0 * rng.uniform() - 1.0;
                let t = 2.0 * std::f64::consts::PI * rng.uniform();
                let s = (1.0 - z * z).sqrt();
                [s * t.cos(), s * t.sin(), z]
            })
            .collect();
        assert_eq!(removed(random), 0);
        // Random points whose density falls tenfold from one pole to the other (a scan's near
        // and far range): a sparse part is judged by its own spacing.
        let uneven: Vec<[f64; 3]> = (0..60_000)
            .filter_map(|_| {
                let z = 2.0 * rng.uniform() - 1.0;
                let t = 2.0 * std::f64::consts::PI * rng.uniform();
                let s = (1.0 - z * z).sqrt();
                let keep = rng.uniform() < 0.1 + 0.9 * (1.0 + z) / 2.0;
                keep.then_some([s * t.cos(), s * t.sin(), z])
            })
            .collect();
        assert!(uneven.len() > 30_000);
        assert_eq!(removed(uneven), 0);
    }
}
