//! Exact k-nearest-neighbour and nearest-distance queries on a uniform grid of buckets: the k
//! nearest for the plane fits of the `normals` stage and the local sample spacings of `trim`
//! ([`PointGrid::new`]), the nearest distance for the mesh → data queries of `measure` (the
//! PLY's vertex quality, the accuracy by area; [`PointGrid::for_nearest`]).
//!
//! Input: the points (finite coordinates, any number up to `u32::MAX`). Output: for a point of
//! the set, its k nearest neighbours, nearest first, ties in distance broken by the smaller
//! index: exactly the k smallest (squared distance, index) pairs, whatever the grid's cell size.
//!
//! Why a grid and not a k-d tree: the queries here are many (every point asks for its 16
//! nearest, three quarters of a scan's points then ask for their 128 nearest) and each answer
//! lies in a small ball of nearly known radius. The points are sorted by cell (a counting sort,
//! cells numbered x fastest), so the cells of a row along x hold one contiguous run of points
//! and a ball query reads a few dozen contiguous runs: no tree descent, no heap, no allocation
//! but the answer, which is faster than a k-d tree for these dense, evenly sized queries.
//!
//! Method of a query for the k nearest of point i: every point in the ball of radius r around
//! it (the cells overlapping the ball's bounding cube, each point's squared distance compared
//! with r²) is collected; if at least k + 1 were found (i itself among them), the k + 1
//! smallest by (distance, index) are the answer, since every point outside the ball is farther
//! than each of them; else r is grown and the query repeated. The starting r is a hint (the
//! caller's, or the previous answer's k-th distance in the same block of nearby points), so it
//! changes the speed, never the result.
//!
//! Distances are squared Euclidean summed as ((dx² + dy²) + dz²), the same operations as
//! [`super::point_tree::PointTree`]'s, so both order non-tied neighbours alike.
//!
//! Method of a nearest-distance query ([`PointGrid::nearest2`]): its own cell, then rings of
//! cells around it (Chebyshev distance 1, 2, …), each row of a ring trimmed to the cells that
//! can hold a point closer than the best so far, until every cell outside the rings scanned is
//! at least as far as that best; `None` past [`MAX_RING`] rings (the caller's k-d tree answers
//! it). Cell bounds are widened by a slack far above the rounding of the cell coordinates and
//! the face cells reach to infinity (they hold the clamped outliers), so pruning never drops a
//! point that could be nearer; the answer is the minimum of the same squared distances a k-d
//! tree computes, bit for bit. Such a grid is a counting sort (O(N)): over millions of scan
//! points it is built in a fraction of a k-d tree's time (median splits at every level). The
//! same search also gives the nearest point's index ([`PointGrid::nearest_item`], the smallest
//! index at equal distance) and a point's nearest *positive* distance with the count of points
//! at distance 0 ([`PointGrid::nearest_positive2`]: points at the query all lie in its own cell,
//! which is always scanned whole).

use rayon::prelude::*;

use crate::vec3::{norm, sub};

/// Largest number of cells the grid may have, per point (the cell size grows to keep it).
const CELLS_PER_POINT: usize = 2;

/// Modes of the ring search (`PointGrid::ring_search`): the nearest squared distance; the
/// nearest positive one and the count of points at zero; the nearest with its index.
const PLAIN: u8 = 0;
const POSITIVE: u8 = 1;
const ITEM: u8 = 2;

/// What a ring search found (see its mode).
#[derive(Clone, Copy, Debug)]
struct Found {
    d2: f64,
    zeros: u32,
    item: u32,
}

/// Rings of cells a [`PointGrid::nearest2`] query searches at most before it gives up (answer
/// `None`): 9³ cells, so that a query far from every point wastes little before the caller's
/// k-d tree answers it.
const MAX_RING: usize = 4;

/// Largest mean number of points sharing a point's cell (Σ count² / N) that
/// [`PointGrid::for_nearest`] accepts; beyond it the points are too clustered for cells of one
/// size.
const MAX_OCCUPANCY: f64 = 256.0;

/// Points sampled per axis for the quantiles of [`PointGrid::for_nearest`]'s box.
const BOX_SAMPLES: usize = 1 << 16;

/// Points per task of [`PointGrid::all_nearest`] (fixed, so the hints, which only change the
/// speed, follow the same sequence on any thread count).
const BLOCK: usize = 1024;

/// The points bucketed in a uniform grid (see the module docs).
#[derive(Clone, Debug)]
pub(crate) struct PointGrid {
    /// The grid's lowest corner.
    origin: [f64; 3],
    /// Side of a cell.
    cell: f64,
    /// Number of cells along each axis.
    dims: [usize; 3],
    /// `start[c]..start[c + 1]` are the points of cell c (c = x + dims₀(y + dims₁ z)) in `sorted`.
    start: Vec<u32>,
    /// The points in cell order.
    sorted: Vec<[f64; 3]>,
    /// The input index of each of `sorted`.
    items: Vec<u32>,
    /// Per axis, the widening of every cell bound in [`PointGrid::nearest2`] (a safe margin
    /// over the rounding of the cell coordinates).
    slack: [f64; 3],
}

/// A key whose integer order is the order of `(distance, index)` by `f64::total_cmp` and then
/// index: the distance's bits mapped as `total_cmp` maps them (sign bit set for non-negative
/// values, all bits flipped for negative ones), followed by the index. Comparing one `u128`
/// is much cheaper than the two-level comparison, and the keys are distinct, so an unstable
/// sort gives the same order as a stable one.
#[inline]
fn order_key(distance: f64, index: u32) -> u128 {
    let bits = distance.to_bits();
    let ordered = if bits >> 63 == 1 {
        !bits
    } else {
        bits | 1 << 63
    };
    (u128::from(ordered) << 32) | u128::from(index)
}

impl PointGrid {
    /// Buckets `points` for k-nearest queries (about one cell per point); `None` when there are
    /// none, more than `u32::MAX`, or a non-finite coordinate.
    pub(crate) fn new(points: &[[f64; 3]]) -> Option<PointGrid> {
        if !usable(points) {
            return None;
        }
        PointGrid::bucketed(points, robust_box(points, usize::MAX), 1.0)
    }

    /// Buckets `points` for [`PointGrid::nearest2`] (about two cells per point, the box from a
    /// sample); `None` as [`PointGrid::new`], and when the points are too clustered for cells of
    /// one size (on average more than [`MAX_OCCUPANCY`] points share a point's cell).
    pub(crate) fn for_nearest(points: &[[f64; 3]]) -> Option<PointGrid> {
        if !usable(points) {
            return None;
        }
        let grid = PointGrid::bucketed(points, robust_box(points, BOX_SAMPLES), 2.0)?;
        let occupancy = grid
            .start
            .windows(2)
            .map(|w| f64::from(w[1] - w[0]).powi(2))
            .sum::<f64>()
            / points.len() as f64;
        (occupancy <= MAX_OCCUPANCY).then_some(grid)
    }

    /// The grid over `points` (usable) in the box `(lo, hi)` (points outside it go to the cells
    /// at its faces), with cells sized for about `cells_per_point` cells per point over the box.
    fn bucketed(
        points: &[[f64; 3]],
        (lo, hi): ([f64; 3], [f64; 3]),
        cells_per_point: f64,
    ) -> Option<PointGrid> {
        let n = points.len();
        let extent = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let longest = extent.iter().fold(0.0f64, |m, &e| m.max(e));
        if !longest.is_finite() {
            return None;
        }
        // The volume per point (a flat axis counts as one cell thick): about one point per cell
        // in a cloud that fills its box, a few per occupied cell on a scanned surface.
        let floor = if longest > 0.0 { longest * 1e-6 } else { 1.0 };
        let volume: f64 = extent.iter().map(|&e| e.max(floor)).product();
        let mut cell = (volume / (cells_per_point * n as f64)).cbrt().max(floor);
        let dims = loop {
            let dims = extent.map(|e| (e / cell).floor() as usize + 1);
            let cells = dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d));
            match cells {
                Some(c) if c <= CELLS_PER_POINT * n + 8 => break dims,
                _ => cell *= 1.25,
            }
        };
        let n_cells = dims[0] * dims[1] * dims[2];
        let index = |p: &[f64; 3]| {
            let c = [0, 1, 2].map(|a| (((p[a] - lo[a]) / cell) as usize).min(dims[a] - 1));
            c[0] + dims[0] * (c[1] + dims[1] * c[2])
        };
        let cells: Vec<u32> = points.par_iter().map(|p| index(p) as u32).collect();
        let mut start = vec![0u32; n_cells + 1];
        for &c in &cells {
            start[c as usize + 1] += 1;
        }
        for c in 0..n_cells {
            start[c + 1] += start[c];
        }
        let mut next = start.clone();
        let mut items = vec![0u32; n];
        for (i, &c) in cells.iter().enumerate() {
            let slot = &mut next[c as usize];
            items[*slot as usize] = i as u32;
            *slot += 1;
        }
        let sorted = items.iter().map(|&i| points[i as usize]).collect();
        let slack = [0, 1, 2].map(|a| 1e-9 * (lo[a].abs() + hi[a].abs() + cell * dims[a] as f64));
        Some(PointGrid {
            origin: lo,
            cell,
            dims,
            start,
            sorted,
            items,
            slack,
        })
    }

    /// The input indices of the points in cell order: nearby points mostly close together (an
    /// order for cache-friendly sweeps over a cloud).
    pub(crate) fn order(&self) -> &[u32] {
        &self.items
    }

    /// Number of points.
    pub(crate) fn len(&self) -> usize {
        self.items.len()
    }

    /// The cell coordinate of `x` along `axis`, clamped to the grid.
    fn cell_of(&self, x: f64, axis: usize) -> usize {
        let c = (x - self.origin[axis]) / self.cell;
        if c <= 0.0 {
            0
        } else {
            (c as usize).min(self.dims[axis] - 1)
        }
    }

    /// A lower bound of |x − y| along `axis` for x = `q` and y any point of cell `i`: the gap
    /// between `q` and the cell, less the slack (0 when `q` is within the widened cell). The
    /// grid's first and last cells reach to −∞ and +∞ (they hold the points clamped into them).
    fn gap(&self, q: f64, axis: usize, i: usize) -> f64 {
        let below = if i == 0 {
            f64::NEG_INFINITY
        } else {
            self.origin[axis] + i as f64 * self.cell
        };
        let above = if i + 1 == self.dims[axis] {
            f64::INFINITY
        } else {
            self.origin[axis] + (i + 1) as f64 * self.cell
        };
        let g = if q < below {
            below - q
        } else if q > above {
            q - above
        } else {
            0.0
        };
        (g - self.slack[axis] - 1e-9 * q.abs()).max(0.0)
    }

    /// The smallest squared distance from `q` (finite) to the points, summed as
    /// `vec3::dist2` sums it; `None` when it was not settled within [`MAX_RING`] rings of
    /// cells around `q`'s cell.
    pub(crate) fn nearest2(&self, q: [f64; 3]) -> Option<f64> {
        self.ring_search::<PLAIN>(q).map(|found| found.d2)
    }

    /// The nearest point to `q` (finite): its squared distance and index, the smallest index
    /// among equally near points; `None` when not settled within [`MAX_RING`] rings.
    pub(crate) fn nearest_item(&self, q: [f64; 3]) -> Option<(f64, u32)> {
        self.ring_search::<ITEM>(q)
            .map(|found| (found.d2, found.item))
    }

    /// The smallest *positive* squared distance from `q` (finite) to the points (∞ when every
    /// point coincides with `q`) and the number of points at `q` itself; `None` when not
    /// settled within [`MAX_RING`] rings. Points at `q` all lie in `q`'s own cell, which every
    /// search scans in full, so the count is exact.
    pub(crate) fn nearest_positive2(&self, q: [f64; 3]) -> Option<(f64, u32)> {
        self.ring_search::<POSITIVE>(q)
            .map(|found| (found.d2, found.zeros))
    }

    /// The search of [`PointGrid::nearest2`] (`MODE` [`PLAIN`]),
    /// [`PointGrid::nearest_positive2`] ([`POSITIVE`]) or [`PointGrid::nearest_item`]
    /// ([`ITEM`]): rings of cells around `q`'s cell until no unscanned cell can hold a nearer
    /// point.
    fn ring_search<const MODE: u8>(&self, q: [f64; 3]) -> Option<Found> {
        let c = [0, 1, 2].map(|a| self.cell_of(q[a], a));
        let mut best = Found {
            d2: f64::INFINITY,
            zeros: 0,
            item: u32::MAX,
        };
        for k in 0..=MAX_RING + 1 {
            if k > 0 {
                // Every cell not yet scanned is outside the block of the rings before this one:
                // beyond one of its faces, so at least that face's gap away.
                let r = k - 1;
                let mut outside = f64::INFINITY;
                for a in 0..3 {
                    if c[a] > r {
                        outside = outside.min(self.gap(q[a], a, c[a] - r - 1));
                    }
                    if c[a] + r + 1 < self.dims[a] {
                        outside = outside.min(self.gap(q[a], a, c[a] + r + 1));
                    }
                }
                if outside == f64::INFINITY || lower(outside * outside) >= best.d2 {
                    return Some(best);
                }
            }
            if k > MAX_RING {
                break;
            }
            self.scan_ring::<MODE>(q, c, k, &mut best);
        }
        None
    }

    /// Lowers `best` to the squared distance of any point in the ring of cells at Chebyshev
    /// distance `k` from cell `c` that is closer.
    fn scan_ring<const MODE: u8>(&self, q: [f64; 3], c: [usize; 3], k: usize, found: &mut Found) {
        let range = |a: usize| c[a].saturating_sub(k)..=(c[a] + k).min(self.dims[a] - 1);
        for z in range(2) {
            let gz = self.gap(q[2], 2, z);
            let gz2 = gz * gz;
            if lower(gz2) >= found.d2 {
                continue;
            }
            let z_face = z.abs_diff(c[2]) == k;
            for y in range(1) {
                let gy = self.gap(q[1], 1, y);
                let gyz2 = gy * gy + gz2;
                if lower(gyz2) >= found.d2 {
                    continue;
                }
                let row = self.dims[0] * (y + self.dims[1] * z);
                if z_face || y.abs_diff(c[1]) == k {
                    let (mut x0, mut x1) = (*range(0).start(), *range(0).end());
                    // Trimmed to the cells that may hold a closer point.
                    while x0 < x1 && self.cell_beyond(q[0], x0, gyz2, found.d2) {
                        x0 += 1;
                    }
                    while x1 > x0 && self.cell_beyond(q[0], x1, gyz2, found.d2) {
                        x1 -= 1;
                    }
                    if !self.cell_beyond(q[0], x0, gyz2, found.d2) {
                        self.scan_min::<MODE>(q, row + x0, row + x1 + 1, found);
                    }
                } else {
                    for x in [c[0].checked_sub(k), Some(c[0] + k)].into_iter().flatten() {
                        if x < self.dims[0] && !self.cell_beyond(q[0], x, gyz2, found.d2) {
                            self.scan_min::<MODE>(q, row + x, row + x + 1, found);
                        }
                    }
                }
            }
        }
    }

    /// Whether cell `x` of a row whose (y, z) squared gap is `gyz2` lies at or beyond `best`.
    #[inline]
    fn cell_beyond(&self, qx: f64, x: usize, gyz2: f64, best: f64) -> bool {
        let gx = self.gap(qx, 0, x);
        lower(gx * gx + gyz2) >= best
    }

    /// Lowers `found` by the points of cells `from..to` (consecutive in `sorted`); in mode
    /// [`POSITIVE`] by those at a positive distance only, counting the others; in mode [`ITEM`]
    /// keeping the nearest point's index (the smallest at equal distance).
    #[inline]
    fn scan_min<const MODE: u8>(&self, q: [f64; 3], from: usize, to: usize, found: &mut Found) {
        let (from, to) = (self.start[from] as usize, self.start[to] as usize);
        let mut b = found.d2;
        for (p, &item) in self.sorted[from..to].iter().zip(&self.items[from..to]) {
            let d2 = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
            match MODE {
                POSITIVE if d2 == 0.0 => found.zeros += 1,
                ITEM => {
                    if d2 < b || (d2 == b && item < found.item) {
                        b = d2;
                        found.item = item;
                    }
                }
                _ => b = b.min(d2),
            }
        }
        found.d2 = b;
    }

    /// Appends to `keys` the [`order_key`] of every point within squared distance `r2` of `q`;
    /// returns whether the ball's bounding cube covered the whole grid.
    fn collect_ball(&self, q: [f64; 3], r2: f64, keys: &mut Vec<u128>) -> bool {
        let r = r2.sqrt();
        let lo = [0, 1, 2].map(|a| self.cell_of(q[a] - r, a));
        let hi = [0, 1, 2].map(|a| self.cell_of(q[a] + r, a));
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                let row = self.dims[0] * (y + self.dims[1] * z);
                let from = self.start[row + lo[0]] as usize;
                let to = self.start[row + hi[0] + 1] as usize;
                for (p, &item) in self.sorted[from..to].iter().zip(&self.items[from..to]) {
                    let d = sub(*p, q);
                    let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                    if d2 <= r2 {
                        keys.push(order_key(d2, item));
                    }
                }
            }
        }
        (0..3).all(|a| lo[a] == 0 && hi[a] == self.dims[a] - 1)
    }

    /// The `k` nearest neighbours of `points[i]` (itself excluded), nearest first, ties by
    /// index, where `points` are the points the grid was made of; `hint2` is a squared radius
    /// likely to hold k + 1 points (any positive value gives the same answer). Also returns the
    /// squared distance of the farthest of the k + 1 nearest (i included), a hint for the next
    /// query nearby.
    pub(crate) fn nearest(
        &self,
        points: &[[f64; 3]],
        i: usize,
        k: usize,
        hint2: f64,
        keys: &mut Vec<u128>,
    ) -> (Vec<u32>, f64) {
        let mut out = Vec::with_capacity(k);
        let farthest = self.nearest_into(points, i, k, hint2, keys, &mut out);
        (out, farthest)
    }

    /// [`PointGrid::nearest`], the answer appended to `out` (no allocation once `out` and
    /// `keys` have grown); returns the same hint.
    pub(crate) fn nearest_into(
        &self,
        points: &[[f64; 3]],
        i: usize,
        k: usize,
        hint2: f64,
        keys: &mut Vec<u128>,
        out: &mut Vec<u32>,
    ) -> f64 {
        let farthest = self.nearest_keys(points, i, k, hint2, keys);
        out.extend(listed(keys, i, k));
        farthest
    }

    /// Leaves in `keys` the [`order_key`]s of the k + 1 nearest points (i included), sorted;
    /// returns the squared distance of the last.
    fn nearest_keys(
        &self,
        points: &[[f64; 3]],
        i: usize,
        k: usize,
        hint2: f64,
        keys: &mut Vec<u128>,
    ) -> f64 {
        keys.clear();
        let want = (k + 1).min(self.len());
        if want == 0 {
            return 0.0;
        }
        let q = points[i];
        let mut r2 = if hint2 > 0.0 && hint2.is_finite() {
            hint2
        } else {
            self.cell * self.cell
        };
        loop {
            keys.clear();
            let whole_grid = self.collect_ball(q, r2, keys);
            if keys.len() >= want {
                break;
            }
            // Grow the ball for about twice the points still missing (the area of a surface
            // patch, or the volume of a cloud, grows at least like r²); once its cube covers
            // every cell, or r² overflows, take every point.
            let ratio = want as f64 / keys.len().max(1) as f64;
            r2 *= (2.0 * ratio).max(2.0);
            if whole_grid || !r2.is_finite() {
                keys.clear();
                self.collect_ball(q, f64::INFINITY, keys);
                break;
            }
        }
        let want = want.min(keys.len());
        if want == 0 {
            return 0.0;
        }
        if want < keys.len() {
            keys.select_nth_unstable(want - 1);
            keys.truncate(want);
        }
        keys.sort_unstable();
        keys.last().map_or(0.0, |&key| distance_of_key(key))
    }

    /// The `k` nearest neighbours of every point of `points` (the points the grid was made
    /// of), as [`PointGrid::nearest`] gives them, in one flat array.
    pub(crate) fn all_nearest(&self, points: &[[f64; 3]], k: usize) -> Neighbours {
        // In cell order, so that each query's hint is the answer of a point next to it.
        self.nearest_in_order(points, k, &self.items, |i| i)
    }

    /// For each of the points `of` (indices into `points`, the points the grid was made of),
    /// its distance to the nearest other point at a positive distance, as the first positive
    /// distance of its `k`-nearest list gives it: `None` when `k` or more other points coincide
    /// with it, or none lies apart from it. One ring search each
    /// ([`PointGrid::nearest_positive2`], counting the coincident points); the points it
    /// leaves open (beyond its rings) get their `k`-nearest lists.
    pub(crate) fn nearest_positive_of(
        &self,
        points: &[[f64; 3]],
        of: &[u32],
        k: usize,
    ) -> Vec<Option<f64>> {
        // Queried in cell order, so that consecutive queries read the same cells (the answers
        // do not depend on the order). `Err(())`: left open by the ring search.
        let rows = self.rows_in_cell_order(points, of);
        let answers: Vec<Result<Option<f64>, ()>> = rows
            .par_iter()
            .map(|&r| {
                let (best2, zeros) = self
                    .nearest_positive2(points[of[r as usize] as usize])
                    .ok_or(())?;
                // `zeros` counts the point itself.
                Ok((zeros as usize <= k && best2 < f64::INFINITY).then(|| best2.sqrt()))
            })
            .collect();
        let mut out = vec![Err(()); of.len()];
        for (&r, answer) in rows.iter().zip(answers) {
            out[r as usize] = answer;
        }
        let open: Vec<usize> = (0..out.len()).filter(|&r| out[r].is_err()).collect();
        if !open.is_empty() {
            let open_of: Vec<u32> = open.iter().map(|&r| of[r]).collect();
            let lists = self.nearest_of(points, &open_of, k);
            for (row, &r) in open.iter().enumerate() {
                out[r] = Ok(first_positive_distance(
                    points,
                    points[of[r] as usize],
                    lists.row(row),
                ));
            }
        }
        out.into_iter().map(|r| r.unwrap_or(None)).collect()
    }

    /// The `k` nearest neighbours of the points `of` (indices into `points`, the points the
    /// grid was made of), as [`PointGrid::nearest`] gives them: row r holds those of `of[r]`.
    pub(crate) fn nearest_of(&self, points: &[[f64; 3]], of: &[u32], k: usize) -> Neighbours {
        // The rows queried in cell order, as in `all_nearest`.
        let rows = self.rows_in_cell_order(points, of);
        self.nearest_in_order(points, k, &rows, |r| of[r as usize])
    }

    /// The rows 0..`of`.len() ordered by the cell of their point `points[of[r]]` (then by row).
    fn rows_in_cell_order(&self, points: &[[f64; 3]], of: &[u32]) -> Vec<u32> {
        let cell = |i: u32| {
            let p = points[i as usize];
            let c = [0, 1, 2].map(|a| self.cell_of(p[a], a));
            c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
        };
        let mut keyed: Vec<(usize, u32)> = (0..of.len() as u32)
            .map(|r| (cell(of[r as usize]), r))
            .collect();
        keyed.par_sort_unstable();
        keyed.into_iter().map(|(_, r)| r).collect()
    }

    /// The `k` nearest neighbours of point `point_of(r)` in row r, for every r of `rows` (a
    /// permutation of 0..rows.len()), queried in that order so that each query starts from the
    /// radius of the one before it.
    fn nearest_in_order(
        &self,
        points: &[[f64; 3]],
        k: usize,
        rows: &[u32],
        point_of: impl Fn(u32) -> u32 + Sync,
    ) -> Neighbours {
        let n = rows.len();
        // Every answer has this length (k + 1 keys, or all points, less the point itself or the
        // farthest).
        let stride = k.min(self.len().saturating_sub(1));
        let blocks: Vec<Vec<u32>> = rows
            .par_chunks(BLOCK)
            .map(|block| {
                let mut keys = Vec::new();
                let mut hint2 = 0.0;
                let mut lists = Vec::with_capacity(block.len() * stride);
                for &r in block {
                    let i = point_of(r);
                    let row = lists.len();
                    let farthest =
                        self.nearest_into(points, i as usize, k, hint2, &mut keys, &mut lists);
                    // Never shorter (see `stride`); kept rectangular whatever happens.
                    lists.resize(row + stride, i);
                    // A little more than the neighbour's radius, so that most queries need
                    // one pass.
                    hint2 = farthest * 1.3;
                }
                lists
            })
            .collect();
        let mut list = vec![0u32; n * stride];
        if stride > 0 {
            for (block, lists) in rows.chunks(BLOCK).zip(&blocks) {
                for (&r, row) in block.iter().zip(lists.chunks_exact(stride)) {
                    let r = r as usize;
                    list[r * stride..(r + 1) * stride].copy_from_slice(row);
                }
            }
        }
        Neighbours { stride, n, list }
    }
}

/// The neighbours named in sorted `keys`, point `i` left out, at most `k`.
fn listed(keys: &[u128], i: usize, k: usize) -> impl Iterator<Item = u32> + '_ {
    keys.iter()
        .map(|&key| key as u32)
        .filter(move |&j| j as usize != i)
        .take(k)
}

/// The k nearest neighbours of every point, nearest first, in one flat array of rows of equal
/// length (one allocation instead of one per point).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub(crate) struct Neighbours {
    /// Length of every row.
    stride: usize,
    /// Number of rows (points).
    n: usize,
    /// Row i is `list[i * stride..(i + 1) * stride]`.
    list: Vec<u32>,
}

impl Neighbours {
    /// `n` empty rows.
    pub(crate) fn empty(n: usize) -> Neighbours {
        Neighbours {
            stride: 0,
            n,
            list: Vec::new(),
        }
    }

    /// Number of rows (points).
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.n
    }

    /// Length of every row.
    pub(crate) fn stride(&self) -> usize {
        self.stride
    }

    /// The neighbours of point `i`, nearest first (empty for `i` out of range).
    pub(crate) fn row(&self, i: usize) -> &[u32] {
        if i >= self.n {
            return &[];
        }
        &self.list[i * self.stride..(i + 1) * self.stride]
    }

    /// All rows, one after the other.
    pub(crate) fn flat(&self) -> &[u32] {
        &self.list
    }
}

/// The distance from `p` to the first point of `row` (indices into `points`, nearest first, as
/// [`Neighbours::row`] holds them) at a positive distance: its nearest such neighbour among the
/// row's; `None` when every one coincides with `p`.
pub(crate) fn first_positive_distance(
    points: &[[f64; 3]],
    p: [f64; 3],
    row: &[u32],
) -> Option<f64> {
    row.iter()
        .map(|&j| norm(sub(p, points[j as usize])))
        .find(|&d| d > 0.0)
}

/// Whether `points` can be bucketed: some, at most `u32::MAX`, all coordinates finite.
fn usable(points: &[[f64; 3]]) -> bool {
    let n = points.len();
    n > 0 && n <= u32::MAX as usize && points.iter().flatten().all(|x| x.is_finite())
}

/// The box the grid covers: per axis, the 1% and 99% quantiles of the coordinates (of every
/// k-th point when there are more than `most`) widened by a quarter of their distance, within
/// the points' bounding box. A legitimate object lies inside it; a few stray points far away (a
/// scan's outliers) fall outside and are kept in the cells at the grid's faces (cell
/// coordinates are clamped), which keeps the queries exact, while the cells stay sized for the
/// object: with the plain bounding box, one point 1000 sizes away made every cell hold the
/// whole object and the queries 30 times slower.
fn robust_box(points: &[[f64; 3]], most: usize) -> ([f64; 3], [f64; 3]) {
    let step = points.len().div_ceil(most.max(1)).max(1);
    let (min, max) = points
        .par_iter()
        .fold(
            || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
            |(mut lo, mut hi), p| {
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
                (lo, hi)
            },
        )
        .reduce(
            || ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
            |(l1, h1), (l2, h2)| {
                (
                    [0, 1, 2].map(|a| l1[a].min(l2[a])),
                    [0, 1, 2].map(|a| h1[a].max(h2[a])),
                )
            },
        );
    let mut lo = [0.0; 3];
    let mut hi = [0.0; 3];
    let mut coordinate: Vec<f64> = Vec::with_capacity(points.len().div_ceil(step));
    for a in 0..3 {
        coordinate.clear();
        coordinate.extend(points.iter().step_by(step).map(|p| p[a]));
        let m = coordinate.len();
        let tail = m / 100;
        let (_, &mut low, _) = coordinate.select_nth_unstable_by(tail, f64::total_cmp);
        let (_, &mut high, _) = coordinate.select_nth_unstable_by(m - 1 - tail, f64::total_cmp);
        let margin = 0.25 * (high - low);
        lo[a] = (low - margin).max(min[a]);
        hi[a] = (high + margin).min(max[a]);
    }
    (lo, hi)
}

/// A squared gap made a little smaller, so that rounding never makes it exceed the squared
/// distance of a point beyond that gap.
#[inline]
fn lower(g2: f64) -> f64 {
    g2 * (1.0 - 1e-12)
}

/// The squared distance an [`order_key`] was made of (for a non-negative distance).
fn distance_of_key(key: u128) -> f64 {
    let ordered = (key >> 32) as u64;
    f64::from_bits(ordered & !(1 << 63))
}

#[cfg(test)]
mod tests;
