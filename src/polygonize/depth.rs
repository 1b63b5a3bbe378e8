//! The meshing depth that matches the data: the finest cells about as large as the spacing of
//! the points, as Poisson reconstruction's octree adapts to its samples.
//!
//! Input: the data points and the meshing region. Output: a depth in
//! [`DATA_DEPTH_MIN`]..=[`DATA_DEPTH_MAX`]: `round(log₂(L / s))`, where L is the region's
//! longest side and s the median distance from a point to its nearest other point (measured
//! on an even sample of at most [`SPACING_SAMPLES`] points). Above [`FULL_CLOUD_MAX`] points
//! the neighbours are searched among every k-th point only (about that many), and their
//! spacing scaled by √(kept / all), the law of points spread over a surface, so the cost does
//! not grow with the cloud (those clouds are dense enough for the finest depth unless their
//! surface is huge). A mesh much finer than the spacing adds triangles the data cannot place, and
//! costs about 4× the time a level; one coarser blurs what the data shows.
//!
//! Measured in detail mode on the oriented points of ../shared/data against Open3D's Poisson
//! at depth 8 (symmetric Chamfer distance / diagonal, CPU seconds of the whole run; L / s of
//! the points' own box, which detail mode's meshing box exceeds by 10% per side, +0.26 in
//! log₂; docs/defaults.md has the table): the sparse
//! scans (L / s between 30 and 70: quadknot, patella, fandisk, spot, duck) cost about half the
//! CPU at depth 6, and their Chamfer distance grows by 0.2–2.5% over depth 7's: still below
//! Poisson's except the duck's (1.004× Poisson's, 0.99× at depth 7). Fertility and Max Planck
//! (L / s ≈ 100) lose 3.5–4% at depth 6, more than Poisson's, so they stay at 7, as do the
//! bunny, the teapot and the 20,000-point synthetic shapes (L / s above 120). Depths above 7
//! are left to `--depth`: on a million points depth 8 costs 1.5× the CPU of depth 7.
//!
//! Deterministic: the sample is every k-th point in input order and the nearest-neighbour
//! search is exact.

use crate::cloud::Aabb;
use crate::numerics::point_grid::PointGrid;

/// The coarsest depth the rule picks.
pub const DATA_DEPTH_MIN: u32 = 6;

/// The finest depth the rule picks.
pub const DATA_DEPTH_MAX: u32 = 7;

/// At most this many points are measured for their nearest-neighbour distance.
const SPACING_SAMPLES: usize = 20_000;

/// Above this many points the spacing is measured on an even subset of about this many and
/// scaled to the whole cloud.
const FULL_CLOUD_MAX: usize = 80_000;

/// The depth whose finest cells are about the spacing of `points` inside `region` (see the
/// module docs); `None` when the spacing cannot be measured (fewer than two distinct points,
/// or a non-finite coordinate).
///
/// ```
/// use stablesurf::polygonize::depth_for_data;
/// use stablesurf::Aabb;
/// // A 100 × 100 grid of points 0.01 apart on the unit square: L / s = 1.1 / 0.01 = 110.
/// let points: Vec<[f64; 3]> = (0..10_000)
///     .map(|i| [(i % 100) as f64 * 0.01, (i / 100) as f64 * 0.01, 0.0])
///     .collect();
/// let region = Aabb { min: [-0.05, -0.05, -0.5], max: [1.05, 1.05, 0.5] };
/// assert_eq!(depth_for_data(&points, &region), Some(7));
/// // Every other row and column: s = 0.02, L / s = 55, one level coarser.
/// let sparse: Vec<[f64; 3]> = points
///     .iter()
///     .copied()
///     .filter(|p| ((p[0] / 0.01).round() as i64) % 2 == 0 && ((p[1] / 0.01).round() as i64) % 2 == 0)
///     .collect();
/// assert_eq!(depth_for_data(&sparse, &region), Some(6));
/// ```
pub fn depth_for_data(points: &[[f64; 3]], region: &Aabb) -> Option<u32> {
    let spacing = median_spacing(points)?;
    let longest = (0..3)
        .map(|a| region.max[a] - region.min[a])
        .fold(0.0, f64::max);
    if !(longest.is_finite() && longest > 0.0) {
        return None;
    }
    let level = (longest / spacing).log2().round();
    Some(level.clamp(f64::from(DATA_DEPTH_MIN), f64::from(DATA_DEPTH_MAX)) as u32)
}

/// The median distance from a point of an even sample of `points` to its nearest other point
/// (0-distance duplicates skipped); `None` when no point has a distinct neighbour.
fn median_spacing(points: &[[f64; 3]]) -> Option<f64> {
    if points.len() > FULL_CLOUD_MAX {
        let kept: Vec<[f64; 3]> = points
            .iter()
            .step_by(points.len().div_ceil(FULL_CLOUD_MAX))
            .copied()
            .collect();
        let scale = (kept.len() as f64 / points.len() as f64).sqrt();
        return median_spacing(&kept).map(|s| s * scale);
    }
    let grid = PointGrid::new(points)?;
    let stride = points.len().div_ceil(SPACING_SAMPLES).max(1);
    let sample: Vec<u32> = (0..points.len())
        .step_by(stride)
        .map(|i| i as u32)
        .collect();
    // The point itself, and a duplicate or two, are skipped (a point with 4 or more
    // duplicates is left out).
    let mut distances: Vec<f64> = grid
        .nearest_positive_of(points, &sample, 4)
        .into_iter()
        .flatten()
        .collect();
    if distances.is_empty() {
        return None;
    }
    let mid = distances.len() / 2;
    let (_, median, _) = distances.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*median)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_spacing_without_two_distinct_points() {
        let region = Aabb {
            min: [0.0; 3],
            max: [1.0; 3],
        };
        assert_eq!(depth_for_data(&[], &region), None);
        assert_eq!(depth_for_data(&[[0.5; 3]; 10], &region), None);
    }

    /// A large cloud's spacing comes from a subset scaled by the surface law: on a 401 × 399
    /// grid of spacing 0.0025 (159,999 points), every 2nd point in order is a checkerboard of
    /// diagonal spacing 0.0025·√2, scaled by √(80,000 / 159,999) back to 0.0025 (within 1e-5).
    #[test]
    fn large_clouds_are_measured_on_a_subset() {
        let points: Vec<[f64; 3]> = (0..159_999)
            .map(|i| [(i % 401) as f64 * 0.0025, (i / 401) as f64 * 0.0025, 0.0])
            .collect();
        let s = median_spacing(&points).unwrap();
        assert!((s / 0.0025 - 1.0).abs() < 1e-5, "{s}");
        let region = Aabb {
            min: [-0.1, -0.1, -0.5],
            max: [1.1, 1.1, 0.5],
        };
        assert_eq!(depth_for_data(&points, &region), Some(DATA_DEPTH_MAX));
    }

    #[test]
    fn clamped_to_the_rule_range() {
        let region = Aabb {
            min: [0.0; 3],
            max: [1.0; 3],
        };
        // Two points 0.5 apart: L / s = 2, far below the range.
        let far = [[0.25, 0.5, 0.5], [0.75, 0.5, 0.5]];
        assert_eq!(depth_for_data(&far, &region), Some(DATA_DEPTH_MIN));
        // Points 1e-4 apart: L / s = 10⁴, far above it.
        let dense: Vec<[f64; 3]> = (0..1000).map(|i| [i as f64 * 1e-4, 0.5, 0.5]).collect();
        assert_eq!(depth_for_data(&dense, &region), Some(DATA_DEPTH_MAX));
    }
}
