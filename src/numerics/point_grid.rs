//! Exact k-nearest-neighbour queries on a uniform grid of buckets, for the plane fits of the
//! `normals` stage and the local sample spacings of `trim`.
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
//! but the answer. Measured on the 36k-point bunny, one thread, against the `kiddo` k-d tree
//! used before: the 16 nearest of every point 76 → 45 ms; the adaptive plane fits with their
//! 128-nearest queries (and the one-pass moments of `pca`) 325 → 275 ms.
//!
//! Method of a query for the k nearest of point i: every point in the ball of radius r around
//! it (the cells overlapping the ball's bounding cube, each point's squared distance compared
//! with r²) is collected; if at least k + 1 were found (i itself among them), the k + 1
//! smallest by (distance, index) are the answer, since every point outside the ball is farther
//! than each of them; else r is grown and the query repeated. The starting r is a hint (the
//! caller's, or the previous answer's k-th distance in the same block of nearby points), so it
//! changes the speed, never the result.
//!
//! Distances are squared Euclidean summed as ((dx² + dy²) + dz²), the same operations as the
//! `kiddo` crate's, so the order of non-tied neighbours is the one it gave.

use rayon::prelude::*;

use crate::vec3::sub;

/// Largest number of cells the grid may have, per point (the cell size grows to keep it).
const CELLS_PER_POINT: usize = 2;

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
    /// Buckets `points`; `None` when there are none, more than `u32::MAX`, or a non-finite
    /// coordinate.
    pub(crate) fn new(points: &[[f64; 3]]) -> Option<PointGrid> {
        let n = points.len();
        if n == 0 || n > u32::MAX as usize || points.iter().flatten().any(|x| !x.is_finite()) {
            return None;
        }
        let (lo, hi) = robust_box(points);
        let extent = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let longest = extent.iter().fold(0.0f64, |m, &e| m.max(e));
        if !longest.is_finite() {
            return None;
        }
        // The volume per point (a flat axis counts as one cell thick): about one point per cell
        // in a cloud that fills its box, a few per occupied cell on a scanned surface.
        let floor = if longest > 0.0 { longest * 1e-6 } else { 1.0 };
        let volume: f64 = extent.iter().map(|&e| e.max(floor)).product();
        let mut cell = (volume / n as f64).cbrt().max(floor);
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
        Some(PointGrid {
            origin: lo,
            cell,
            dims,
            start,
            sorted,
            items,
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
        let farthest = self.nearest_keys(points, i, k, hint2, keys);
        (listed(keys, i, k).collect(), farthest)
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

    /// The `k` nearest neighbours of the points `of` (indices into `points`, the points the
    /// grid was made of), as [`PointGrid::nearest`] gives them: row r holds those of `of[r]`.
    pub(crate) fn nearest_of(&self, points: &[[f64; 3]], of: &[u32], k: usize) -> Neighbours {
        // The rows queried in cell order, as in `all_nearest`.
        let cell = |i: u32| {
            let p = points[i as usize];
            let c = [0, 1, 2].map(|a| self.cell_of(p[a], a));
            c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
        };
        let mut keyed: Vec<(usize, u32)> = (0..of.len() as u32)
            .map(|r| (cell(of[r as usize]), r))
            .collect();
        keyed.par_sort_unstable();
        let rows: Vec<u32> = keyed.into_iter().map(|(_, r)| r).collect();
        self.nearest_in_order(points, k, &rows, |r| of[r as usize])
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

/// The box the grid covers: per axis, the 1% and 99% quantiles of the coordinates widened by a
/// quarter of their distance, within the points' bounding box. A legitimate object lies inside
/// it; a few stray points far away (a scan's outliers) fall outside and are kept in the cells
/// at the grid's faces (cell coordinates are clamped), which keeps the queries exact, while
/// the cells stay sized for the object: with the plain bounding box, one point 1000 sizes
/// away made every cell hold the whole object and the queries 30 times slower.
fn robust_box(points: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let n = points.len();
    let tail = n / 100;
    let mut lo = [0.0; 3];
    let mut hi = [0.0; 3];
    let mut coordinate: Vec<f64> = Vec::with_capacity(n);
    for a in 0..3 {
        coordinate.clear();
        coordinate.extend(points.iter().map(|p| p[a]));
        let (min, max) = coordinate
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
                (l.min(x), h.max(x))
            });
        let (_, &mut low, _) = coordinate.select_nth_unstable_by(tail, f64::total_cmp);
        let (_, &mut high, _) = coordinate.select_nth_unstable_by(n - 1 - tail, f64::total_cmp);
        let margin = 0.25 * (high - low);
        lo[a] = (low - margin).max(min);
        hi[a] = (high + margin).min(max);
    }
    (lo, hi)
}

/// The squared distance an [`order_key`] was made of (for a non-negative distance).
fn distance_of_key(key: u128) -> f64 {
    let ordered = (key >> 32) as u64;
    f64::from_bits(ordered & !(1 << 63))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The k nearest by brute force: all (distance, index) keys sorted.
    fn brute(points: &[[f64; 3]], i: usize, k: usize) -> Vec<u32> {
        let mut keys: Vec<u128> = points
            .iter()
            .enumerate()
            .map(|(j, p)| {
                let d = sub(*p, points[i]);
                order_key(d[0] * d[0] + d[1] * d[1] + d[2] * d[2], j as u32)
            })
            .collect();
        keys.sort_unstable();
        keys.into_iter()
            .map(|key| key as u32)
            .filter(|&j| j as usize != i)
            .take(k)
            .collect()
    }

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn nearest_is_exact_on_surfaces_clouds_lattices_and_outliers() {
        let mut seed = 7;
        let mut sphere: Vec<[f64; 3]> = (0..1500)
            .map(|_| {
                let (u, v) = (lcg(&mut seed), lcg(&mut seed));
                let z = 2.0 * u - 1.0;
                let r = (1.0 - z * z).sqrt();
                let a = std::f64::consts::TAU * v;
                [r * a.cos(), r * a.sin(), z]
            })
            .collect();
        // A far outlier and a dense clump: cells far from uniform.
        sphere.push([40.0, -3.0, 7.0]);
        for t in 0..50 {
            sphere.push([0.2 + 1e-4 * t as f64, 0.1, 0.97]);
        }
        let cloud: Vec<[f64; 3]> = (0..1000)
            .map(|_| [lcg(&mut seed), 2.0 * lcg(&mut seed), 0.5 * lcg(&mut seed)])
            .collect();
        // A lattice: many exactly equal distances, so the ties decide.
        let lattice: Vec<[f64; 3]> = (0..729)
            .map(|i| [(i % 9) as f64, (i / 9 % 9) as f64, (i / 81) as f64])
            .collect();
        // A plane (one axis flat) and a line.
        let plane: Vec<[f64; 3]> = (0..400)
            .map(|i| [(i % 20) as f64 * 0.1, (i / 20) as f64 * 0.1, 3.0])
            .collect();
        let line: Vec<[f64; 3]> = (0..100).map(|i| [i as f64, 0.0, 0.0]).collect();
        for points in [&sphere, &cloud, &lattice, &plane, &line] {
            let grid = PointGrid::new(points).unwrap();
            for k in [1, 16, 128] {
                let all = grid.all_nearest(points, k);
                let mut keys = Vec::new();
                // Every 7th point, and the last 60 (the outliers and the clump).
                let checked = (0..points.len())
                    .step_by(7)
                    .chain(points.len().saturating_sub(60)..points.len());
                for i in checked {
                    let expected = brute(points, i, k);
                    assert_eq!(all.row(i), expected, "all_nearest, point {i}, k {k}");
                    for hint2 in [1e-12, 0.3, 1e9] {
                        let (list, _) = grid.nearest(points, i, k, hint2, &mut keys);
                        assert_eq!(list, expected, "point {i}, k {k}, hint {hint2}");
                    }
                }
            }
        }
    }

    #[test]
    fn order_key_orders_as_total_cmp_then_index() {
        let values = [
            0.0,
            -0.0,
            1e-300,
            0.5,
            0.5,
            2.0,
            f64::INFINITY,
            -1.0,
            f64::NAN,
        ];
        let pairs: Vec<(f64, u32)> = values
            .iter()
            .enumerate()
            .flat_map(|(i, &d)| [(d, i as u32), (d, 100 - i as u32)])
            .collect();
        for a in &pairs {
            for b in &pairs {
                let expected = a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
                assert_eq!(order_key(a.0, a.1).cmp(&order_key(b.0, b.1)), expected);
            }
        }
    }

    #[test]
    fn fewer_points_than_asked_gives_all_of_them() {
        let points = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]];
        let grid = PointGrid::new(&points).unwrap();
        let (list, _) = grid.nearest(&points, 0, 16, 0.0, &mut Vec::new());
        assert_eq!(list, vec![1, 2]);
        let one = [[5.0, 5.0, 5.0]];
        let grid = PointGrid::new(&one).unwrap();
        let all = grid.all_nearest(&one, 4);
        assert_eq!((all.len(), all.stride(), all.row(0)), (1, 0, &[][..]));
        let all = PointGrid::new(&points).unwrap().all_nearest(&points, 16);
        assert_eq!((all.len(), all.stride()), (3, 2));
        assert_eq!(
            [all.row(0), all.row(1), all.row(2)],
            [[1, 2], [0, 2], [0, 1]]
        );
        assert!(PointGrid::new(&[]).is_none());
        assert!(PointGrid::new(&[[f64::NAN, 0.0, 0.0]]).is_none());
    }
}
