//! Exact nearest-point distances on a uniform grid of buckets, for the mesh → data queries of
//! `measure` (the PLY's vertex quality, the accuracy by area).
//!
//! Input: finite points (up to `u32::MAX`). Output: for a query point, the smallest squared
//! distance to any of them, summed as `measure::dist2` sums it (((dx² + dy²) + dz²)), so that
//! its square root is bit for bit the distance a k-d tree over the same points gives; or
//! `None` when the answer is farther than the few rings of cells a query searches (the caller
//! then asks its k-d tree).
//!
//! Why: a k-d tree over millions of scan points takes longer to build (a median split per
//! level) than the few hundred thousand queries of an export take to answer. The grid is a
//! counting sort (O(N)): the points sorted by cell, cells numbered x fastest, so that a run of
//! cells along x is one run of points. A query scans its own cell, then rings of cells around
//! it (Chebyshev distance 1, 2, …), each row of a ring trimmed to the cells that can hold a
//! point closer than the best so far, and stops once every cell outside the rings scanned is
//! at least as far as that best. Cell bounds are widened by a slack far above the rounding of
//! the cell coordinates, so pruning never drops a point that could be nearer.
//!
//! The grid spans the 1% and 99% quantiles of each coordinate (widened by a quarter of their
//! distance, within the bounding box); points outside (a scan's stray outliers) are kept in
//! the cells at the grid's faces, whose outer bounds are then unbounded. [`NearestGrid::new`]
//! declines point sets so clustered that a query would scan many points per cell.

use rayon::prelude::*;

/// Cells per point at most (the cell size is chosen for about this many cells over the box):
/// on the 3M-point torus, 1 and 2 took the same time, 4 and 8 a little more (more memory).
const CELLS_PER_POINT: usize = 2;

/// Rings of cells a query searches at most before it gives up (answer `None`): 9³ cells, so
/// that a query far from every point wastes little before the caller's k-d tree answers it.
const MAX_RING: usize = 4;

/// Largest mean number of points sharing a point's cell (Σ count² / N) the grid accepts;
/// beyond it the points are too clustered for cells of one size.
const MAX_OCCUPANCY: f64 = 256.0;

/// Points sampled per axis for the quantiles of the grid's box.
const BOX_SAMPLES: usize = 1 << 16;

/// The points bucketed in a uniform grid (see the module docs).
#[derive(Clone, Debug)]
pub(crate) struct NearestGrid {
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
    /// Per axis, the widening of every cell bound (a safe margin over the rounding of the cell
    /// coordinates).
    slack: [f64; 3],
}

impl NearestGrid {
    /// Buckets `points`; `None` when there are none, more than `u32::MAX`, a non-finite
    /// coordinate, or when they are too clustered for a uniform grid.
    pub(crate) fn new(points: &[[f64; 3]]) -> Option<NearestGrid> {
        let n = points.len();
        if n == 0 || n > u32::MAX as usize || points.iter().flatten().any(|x| !x.is_finite()) {
            return None;
        }
        let (lo, hi) = sampled_box(points);
        let extent = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let longest = extent.iter().fold(0.0f64, |m, &e| m.max(e));
        if !longest.is_finite() {
            return None;
        }
        let floor = if longest > 0.0 { longest * 1e-6 } else { 1.0 };
        let volume: f64 = extent.iter().map(|&e| e.max(floor)).product();
        let mut cell = (volume / (CELLS_PER_POINT as f64 * n as f64))
            .cbrt()
            .max(floor);
        let max_cells = CELLS_PER_POINT * n + 8;
        let dims = loop {
            let dims = extent.map(|e| (e / cell).floor() as usize + 1);
            let cells = dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d));
            match cells {
                Some(c) if c <= max_cells => break dims,
                _ => cell *= 1.25,
            }
        };
        if !cell.is_finite() || cell <= 0.0 {
            return None;
        }
        let n_cells = dims[0] * dims[1] * dims[2];
        let index = |p: &[f64; 3]| {
            let c = [0, 1, 2].map(|a| {
                let t = (p[a] - lo[a]) / cell;
                if t <= 0.0 {
                    0
                } else {
                    (t as usize).min(dims[a] - 1)
                }
            });
            c[0] + dims[0] * (c[1] + dims[1] * c[2])
        };
        let cells: Vec<u32> = points.par_iter().map(|p| index(p) as u32).collect();
        // A counting sort: the counts, their running sums (each cell's end), then the points
        // from the last, each cell's end moved down to its start as they are placed.
        let mut start = vec![0u32; n_cells + 1];
        for &c in &cells {
            start[c as usize] += 1;
        }
        let occupancy = start.iter().map(|&k| f64::from(k).powi(2)).sum::<f64>() / n as f64;
        if occupancy > MAX_OCCUPANCY {
            return None;
        }
        for c in 1..=n_cells {
            start[c] += start[c - 1];
        }
        let mut sorted = vec![[0.0; 3]; n];
        for (p, &c) in points.iter().zip(&cells).rev() {
            let slot = &mut start[c as usize];
            *slot -= 1;
            sorted[*slot as usize] = *p;
        }
        let slack = [0, 1, 2].map(|a| 1e-9 * (lo[a].abs() + hi[a].abs() + cell * dims[a] as f64));
        Some(NearestGrid {
            origin: lo,
            cell,
            dims,
            start,
            sorted,
            slack,
        })
    }

    /// The cell coordinate of `x` along `axis`, clamped to the grid.
    fn cell_of(&self, x: f64, axis: usize) -> usize {
        let t = (x - self.origin[axis]) / self.cell;
        if t <= 0.0 {
            0
        } else {
            (t as usize).min(self.dims[axis] - 1)
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
    /// `measure::dist2` sums it; `None` when it was not settled within [`MAX_RING`] rings of
    /// cells around `q`'s cell.
    pub(crate) fn nearest2(&self, q: [f64; 3]) -> Option<f64> {
        let c = [0, 1, 2].map(|a| self.cell_of(q[a], a));
        let mut best = f64::INFINITY;
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
                if outside == f64::INFINITY || lower(outside * outside) >= best {
                    return Some(best);
                }
            }
            if k > MAX_RING {
                break;
            }
            self.scan_ring(q, c, k, &mut best);
        }
        None
    }

    /// Lowers `best` to the squared distance of any point in the ring of cells at Chebyshev
    /// distance `k` from cell `c` that is closer.
    fn scan_ring(&self, q: [f64; 3], c: [usize; 3], k: usize, best: &mut f64) {
        let range = |a: usize| c[a].saturating_sub(k)..=(c[a] + k).min(self.dims[a] - 1);
        for z in range(2) {
            let gz = self.gap(q[2], 2, z);
            let gz2 = gz * gz;
            if lower(gz2) >= *best {
                continue;
            }
            let z_face = z.abs_diff(c[2]) == k;
            for y in range(1) {
                let gy = self.gap(q[1], 1, y);
                let gyz2 = gy * gy + gz2;
                if lower(gyz2) >= *best {
                    continue;
                }
                let row = self.dims[0] * (y + self.dims[1] * z);
                if z_face || y.abs_diff(c[1]) == k {
                    let (mut x0, mut x1) = (*range(0).start(), *range(0).end());
                    // Trimmed to the cells that may hold a closer point.
                    while x0 < x1 && self.cell_beyond(q[0], x0, gyz2, *best) {
                        x0 += 1;
                    }
                    while x1 > x0 && self.cell_beyond(q[0], x1, gyz2, *best) {
                        x1 -= 1;
                    }
                    if !self.cell_beyond(q[0], x0, gyz2, *best) {
                        self.scan(q, row + x0, row + x1 + 1, best);
                    }
                } else {
                    for x in [c[0].checked_sub(k), Some(c[0] + k)].into_iter().flatten() {
                        if x < self.dims[0] && !self.cell_beyond(q[0], x, gyz2, *best) {
                            self.scan(q, row + x, row + x + 1, best);
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

    /// Lowers `best` by the points of cells `from..to` (consecutive in `sorted`).
    #[inline]
    fn scan(&self, q: [f64; 3], from: usize, to: usize, best: &mut f64) {
        let (from, to) = (self.start[from] as usize, self.start[to] as usize);
        let mut b = *best;
        for p in &self.sorted[from..to] {
            let d2 = (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2);
            b = b.min(d2);
        }
        *best = b;
    }
}

/// A squared gap made a little smaller, so that rounding never makes it exceed the squared
/// distance of a point beyond that gap.
#[inline]
fn lower(g2: f64) -> f64 {
    g2 * (1.0 - 1e-12)
}

/// The box of [`NearestGrid`]: per axis, the 1% and 99% quantiles of a sample of the
/// coordinates (every k-th point, at most [`BOX_SAMPLES`]) widened by a quarter of their
/// distance, within the points' bounding box. It only sizes the cells: any box gives the same
/// answers.
fn sampled_box(points: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let step = points.len().div_ceil(BOX_SAMPLES).max(1);
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
    let mut coordinate: Vec<f64> = Vec::with_capacity(BOX_SAMPLES + 1);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measure::{dist2, PointTree};

    fn lcg(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Every query's grid answer, where it gives one, equals the k-d tree's and the brute
    /// force's bit for bit; returns how many it answered.
    fn check(points: &[[f64; 3]], queries: &[[f64; 3]]) -> usize {
        let grid = NearestGrid::new(points).expect("grid");
        let tree = PointTree::new(points).unwrap();
        let mut answered = 0;
        for q in queries {
            let brute = points
                .iter()
                .map(|p| dist2(*q, *p))
                .fold(f64::INFINITY, f64::min);
            assert_eq!(tree.nearest(*q).0.to_bits(), brute.to_bits());
            if let Some(d2) = grid.nearest2(*q) {
                assert_eq!(d2.to_bits(), brute.to_bits(), "query {q:?}");
                answered += 1;
            }
        }
        answered
    }

    #[test]
    fn nearest_matches_the_tree_on_surfaces_clouds_duplicates_and_outliers() {
        let mut seed = 11;
        let mut sphere: Vec<[f64; 3]> = (0..4000)
            .map(|_| {
                let (u, v) = (lcg(&mut seed), lcg(&mut seed));
                let z = 2.0 * u - 1.0;
                let r = (1.0 - z * z).sqrt();
                let a = std::f64::consts::TAU * v;
                [r * a.cos(), r * a.sin(), z]
            })
            .collect();
        // Far outliers on every side, clamped into the grid's face cells.
        sphere.extend([[40.0, -3.0, 7.0], [-25.0, 0.0, 0.0], [0.1, 0.2, -90.0]]);
        let mut queries: Vec<[f64; 3]> = (0..1500)
            .map(|_| [0, 1, 2].map(|_| 2.6 * lcg(&mut seed) - 1.3))
            .collect();
        // Queries on the points, far outside, beyond the outliers and next to them.
        queries.extend(sphere.iter().step_by(97).copied());
        queries.extend([
            [100.0, 100.0, 100.0],
            [-1e6, 3.0, 0.0],
            [39.0, -3.0, 7.5],
            [0.0, 0.0, -89.0],
        ]);
        let answered = check(&sphere, &queries);
        assert!(answered > queries.len() * 9 / 10, "{answered}");

        // A cloud filling its box, a lattice (many equal distances) and duplicate-heavy data.
        let cloud: Vec<[f64; 3]> = (0..3000)
            .map(|_| [lcg(&mut seed), 2.0 * lcg(&mut seed), 0.5 * lcg(&mut seed)])
            .collect();
        let lattice: Vec<[f64; 3]> = (0..1000)
            .map(|i| [(i % 10) as f64, (i / 10 % 10) as f64, (i / 100) as f64])
            .collect();
        let duplicates: Vec<[f64; 3]> = (0..3000)
            .map(|i| {
                let v = (i * 7919 % 50) as f64;
                [v * 0.1, (v * 0.37).sin(), 0.0]
            })
            .collect();
        // A plane (one axis flat) and a line.
        let plane: Vec<[f64; 3]> = (0..900)
            .map(|i| [(i % 30) as f64 * 0.1, (i / 30) as f64 * 0.1, 3.0])
            .collect();
        let line: Vec<[f64; 3]> = (0..300).map(|i| [i as f64 * 0.5, 1.0, -2.0]).collect();
        for points in [&cloud, &lattice, &duplicates, &plane, &line] {
            let queries: Vec<[f64; 3]> = (0..800)
                .map(|j| {
                    let p = points[j * 13 % points.len()];
                    let s = if j % 4 == 0 { 20.0 } else { 0.3 };
                    [0, 1, 2].map(|a| p[a] + s * (lcg(&mut seed) - 0.5))
                })
                .chain(points.iter().step_by(31).copied())
                .collect();
            let answered = check(points, &queries);
            assert!(answered > queries.len() / 2, "{answered}");
        }
        // A single point.
        assert_eq!(
            check(&[[1.0, 2.0, 3.0]], &[[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]]),
            2
        );
    }

    #[test]
    fn clustered_and_unusable_sets_are_declined() {
        // Nearly all points in one tiny clump, a few spread out: one cell would hold the clump.
        let mut seed = 5;
        let mut points: Vec<[f64; 3]> = (0..20_000)
            .map(|_| [0, 1, 2].map(|_| 1e-7 * lcg(&mut seed)))
            .collect();
        points.extend((0..4000).map(|_| [0, 1, 2].map(|_| lcg(&mut seed))));
        assert!(NearestGrid::new(&points).is_none());
        assert!(NearestGrid::new(&[]).is_none());
        assert!(NearestGrid::new(&[[f64::NAN, 0.0, 0.0]]).is_none());
    }
}
