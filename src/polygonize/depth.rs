//! The meshing resolution that matches the data: the finest cells about as large as the
//! spacing of the points, as Poisson reconstruction's octree adapts to its samples.
//!
//! Input: the data points and the meshing region. Output: a [`DataResolution`]: the points'
//! level log₂(L / s), where L is the region's longest side and s the median distance from a
//! point to its nearest other point (measured on an even sample of at most
//! [`SPACING_SAMPLES`] points). Above [`FULL_CLOUD_MAX`] points the neighbours are searched
//! among every k-th point only (about that many), and their spacing scaled by √(kept / all),
//! the law of points spread over a surface, so the cost does not grow with the cloud. That law
//! holds for points spread at random; a subset of a regular sampling (a subdivided mesh, a
//! range grid) is less even than the whole, so its scaled spacing reads finer: levels from the
//! subset against all points (the region 1.2× the extent), the bunny's vertices Loop-subdivided
//! once 8.91 against 8.49 and twice 10.10 against 9.48, midpoint-subdivided twice 10.11 against
//! 9.51, `bun.conf`'s merged views 9.32 against 9.22, the 10⁶-point torus 10.83 against 10.80.
//! None of these changes a decision below (all are dense at depth 7 either way); a cloud of
//! more than [`FULL_CLOUD_MAX`] points up to about half a level under the dense rule may be
//! taken as dense, which costs CPU (tighter fits), not accuracy.
//!
//! - **Depth**: the coarsest whose finest cells are at most 2^¼ ≈ 1.19 times the spacing,
//!   `ceil(log₂(L / s) − ¼)`, clamped to [`DATA_DEPTH_MIN`]..=[`DATA_DEPTH_MAX`]. A mesh much
//!   finer than the spacing adds triangles the data cannot place, and costs about 4× the time
//!   a level; one coarser blurs what the data shows.
//! - **Dense**: when the points are [`DENSE_LEVELS`] level or more finer than the mesh (2 or
//!   more across a cell), they sample the facets' interiors: `run` takes the fitted chords'
//!   whole least-squares move ([`super::PolygonizeParams::chord_share`] 1, not the default
//!   quarter), after which the fit's own error is most of the distance to the points, and it
//!   cuts detail mode's split tolerance to 0.27× (`pipeline::DENSE_TOLERANCE`) and splits the
//!   mesh's curved edges ([`super::PolygonizeParams::refine`], with the depth meshed: a
//!   `--depth` asked for is compared with the points the same way). From 1 level the rule
//!   takes the raw range views of ../shared/data and their merge through `bun.conf`; the bunny
//!   itself and every other input of ../shared/data lie below it (the figures behind the level
//!   are in docs/defaults.md, "Detail mode's depth").
//! - **Fit stride**: where the cells of the depth meshed hold at least [`FIT_CELL_POINTS`]
//!   (12) points on average (those holding any), detail mode fits every k-th point along the
//!   Z-order curve, k = ⌊mean / [`FIT_STRIDE_POINTS`]⌋ ([`fit_stride`]), and refits the deepest
//!   cells whose quadric misses the tolerance as cubics
//!   ([`crate::detail::DetailParams::refit_deepest`]): each ball of the fit costs per point (its
//!   rows, its error measure, the scans for its neighbours), while a few points per cell pin
//!   the surface as well, and the time saved pays for the cubics, which follow relief finer
//!   than a quadric can (docs/defaults.md, "The deepest cells as cubics"). Refits at every
//!   point of a noisy merge such as `bun.conf` cost much CPU for little, since its noise fails
//!   the tolerance everywhere. The merged bunny views of `bun.conf`, the Loop bunny subdivided
//!   once and every input of ../shared/data fit every point, without refits.
//!
//! Why these levels: depth 6 halves the CPU of the sparsest scans for a small loss of accuracy,
//! and depth 7 keeps the accuracy of scans a little denser; on far denser points a finer
//! tolerance at depth 7 costs less than depth 8 for the same accuracy (the measurements are in
//! docs/defaults.md, "Detail mode's depth: the points' spacing").
//!
//! Deterministic: the sample is every k-th point in input order and the nearest-neighbour
//! search is exact.

use rayon::prelude::*;

use crate::cloud::Aabb;
use crate::numerics::point_grid::PointGrid;

/// The coarsest depth the rule picks.
pub const DATA_DEPTH_MIN: u32 = 6;

/// The finest depth the rule picks.
pub const DATA_DEPTH_MAX: u32 = 7;

/// The finest cells may be up to 2^this times the spacing (see the module docs).
const CELL_OVER_SPACING_LOG2: f64 = 0.25;

/// How many levels finer than the mesh the points must be for `run` to cut detail mode's
/// split tolerance and take the chords' whole move (see the module docs).
pub(crate) const DENSE_LEVELS: f64 = 1.0;

/// Detail mode fits every k-th point of a cloud whose points average at least this many to
/// an occupied cell of the mesh's finest level ([`fit_stride`]).
pub(crate) const FIT_CELL_POINTS: usize = 12;

/// ... k = ⌊mean / this⌋: about this many points of each such cell are fitted.
pub(crate) const FIT_STRIDE_POINTS: usize = 3;

/// The largest stride [`fit_stride`] picks.
pub(crate) const FIT_STRIDE_MAX: u32 = 64;

/// At most this many points are measured for their nearest-neighbour distance.
const SPACING_SAMPLES: usize = 20_000;

/// Above this many points the spacing is measured on an even subset of about this many and
/// scaled to the whole cloud.
const FULL_CLOUD_MAX: usize = 80_000;

/// How finely a cloud samples its meshing region (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DataResolution {
    /// log₂(L / s): L the region's longest side, s the points' median nearest-neighbour
    /// distance.
    pub level: f64,
}

impl DataResolution {
    /// The resolution of `points` inside `region`; `None` when the spacing cannot be measured
    /// (fewer than two distinct points, or a non-finite coordinate) or the region is empty.
    pub fn of(points: &[[f64; 3]], region: &Aabb) -> Option<DataResolution> {
        let spacing = median_spacing(points)?;
        let longest = (0..3)
            .map(|a| region.max[a] - region.min[a])
            .fold(0.0, f64::max);
        let level = (longest / spacing).log2();
        level.is_finite().then_some(DataResolution { level })
    }

    /// The meshing depth: the coarsest whose finest cells are at most 2^¼ times the spacing,
    /// within [`DATA_DEPTH_MIN`]..=[`DATA_DEPTH_MAX`].
    pub fn depth(&self) -> u32 {
        (self.level - CELL_OVER_SPACING_LOG2)
            .ceil()
            .clamp(f64::from(DATA_DEPTH_MIN), f64::from(DATA_DEPTH_MAX)) as u32
    }

    /// Whether the points are at least `DENSE_LEVELS` levels finer than the cells of
    /// [`DataResolution::depth`]: detail mode's split tolerance is then cut and the chords take
    /// their whole move.
    pub fn dense(&self) -> bool {
        self.finer_than(self.depth())
    }

    /// Whether the points are at least [`DENSE_LEVELS`] levels finer than the cells of `depth`:
    /// detail mode's `run` then splits the mesh's curved edges
    /// ([`super::PolygonizeParams::refine`]).
    pub(crate) fn finer_than(&self, depth: u32) -> bool {
        self.level >= f64::from(depth) + DENSE_LEVELS
    }
}

/// The depth whose finest cells are about the spacing of `points` inside `region`
/// ([`DataResolution::depth`]; see the module docs); `None` when the spacing cannot be measured
/// (fewer than two distinct points, or a non-finite coordinate).
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
#[cfg(test)] // only the unit tests call it
pub(crate) fn depth_for_data(points: &[[f64; 3]], region: &Aabb) -> Option<u32> {
    DataResolution::of(points, region).map(|r| r.depth())
}

/// The detail fit's stride ([`crate::detail::DetailParams::stride`]) for `points` meshed at
/// `depth` over `region`: with m the mean number of points in the cells of that depth holding
/// any (cubes of side the region's longest side / 2^depth from its minimum corner; points
/// outside the region are not counted), 1 below [`FIT_CELL_POINTS`] and ⌊m /
/// [`FIT_STRIDE_POINTS`]⌋ from there, at most [`FIT_STRIDE_MAX`]. A fit needs a few points per
/// cell of the mesh, and each of its balls costs per point: on points far finer than the mesh,
/// every k-th point along the Z-order curve pins the surface as well, and the time saved pays
/// for cubic refits of the deepest cells ([`crate::detail::DetailParams::refit_deepest`], which
/// `run` sets with a stride above 1; see the module docs). 1 when no point lies in the region.
pub(crate) fn fit_stride(points: &[[f64; 3]], region: &Aabb, depth: u32) -> u32 {
    let depth = depth.min(20);
    let per_axis = (1u64 << depth) as f64;
    let longest = (0..3)
        .map(|a| region.max[a] - region.min[a])
        .fold(0.0, f64::max);
    let side = longest / per_axis;
    if !(side > 0.0 && side.is_finite()) {
        return 1;
    }
    let mut cells: Vec<u64> = points
        .par_iter()
        .filter_map(|p| {
            let c = [0, 1, 2].map(|a| ((p[a] - region.min[a]) / side).floor());
            c.iter()
                .all(|&v| (0.0..per_axis).contains(&v))
                .then(|| ((c[0] as u64) << (2 * depth)) | ((c[1] as u64) << depth) | c[2] as u64)
        })
        .collect();
    let inside = cells.len();
    cells.par_sort_unstable();
    cells.dedup();
    if cells.is_empty() {
        return 1;
    }
    let mean = inside / cells.len();
    if mean < FIT_CELL_POINTS {
        return 1;
    }
    (mean / FIT_STRIDE_POINTS).clamp(1, FIT_STRIDE_MAX as usize) as u32
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

    /// The depth is the coarsest whose cells are at most 2^¼ spacings: a level of 6.3 (cells
    /// of 2^0.3 spacings at depth 6) goes to 7, 6.2 stays at 6; the dense rule starts 1 level
    /// finer than the mesh.
    #[test]
    fn thresholds_of_the_rule() {
        let at = |level| DataResolution { level };
        assert_eq!(at(6.2).depth(), 6);
        assert_eq!(at(6.3).depth(), 7);
        assert_eq!(at(7.26).depth(), 7);
        assert!(!at(7.99).dense());
        assert!(at(8.0).dense());
        assert!(at(10.0).dense());
        // Only the finest depth can be dense: below it the depth follows the level.
        assert!(!at(6.2).dense());
        assert!(!at(5.0).dense());
    }
}

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn fit_stride() {
        use crate::polygonize::fit_stride;
        use crate::Aabb;
        // The unit square sampled 1000 to a side, meshed at depth 7 over a box of side 1.2: the
        // 108 × 108 cells of 1.2 / 128 it meets hold 85 points on average, so every 28th is fitted.
        let points: Vec<[f64; 3]> = (0..1_000_000)
            .map(|i| [(i % 1000) as f64 * 1e-3, (i / 1000) as f64 * 1e-3, 0.0])
            .collect();
        let region = Aabb {
            min: [-0.1, -0.1, -0.6],
            max: [1.1, 1.1, 0.6],
        };
        assert_eq!(fit_stride(&points, &region, 7), 28);
        // At depth 8, 214 × 214 cells of 21 points: every 7th.
        assert_eq!(fit_stride(&points, &region, 8), 7);
        // At depth 9 the cells hold about 2.3² ≈ 5.5 points: every point.
        assert_eq!(fit_stride(&points, &region, 9), 1);
    }
}
