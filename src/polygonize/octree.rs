//! The adaptive octree of the `polygonize` stage: which cells may hold the zero set.
//!
//! Input: an [`ImplicitFunction`], the region and the depths. Output: an [`Octree`] — the
//! surface leaves (cells whose guaranteed enclosure of f contains 0) in a fixed depth-first
//! order, and the set of subdivided cells at levels ≥ `depth` that the extraction needs to find
//! finer neighbours.
//!
//! Invariants: every leaf that may contain a zero of f is at a level ≥ `depth`; a cell is
//! discarded only when [`ImplicitFunction::bounds_on_box`] excludes 0, so no part of the zero set
//! (however thin or small) is lost to sampling; the leaf order does not depend on the thread
//! count (children are visited in a fixed order and their lists concatenated in that order).
//!
//! Refinement:
//!
//! ```text
//! cell ── bound excludes 0 ──────────────▶ discarded (f has one strict sign on it)
//!   │
//!   ├── level < depth ───────────────────▶ split into 8
//!   ├── level < fine and holds data ─────▶ split into 8 (data refinement, DataCells;
//!   │   not flat (with normals)                with normals, not where the data is flat)
//!   ├── level < cap and guard fails ─────▶ split into 8 (topology guard)
//!   └── otherwise ───────────────────────▶ surface leaf
//! ```
//!
//! With data refinement ([`DataCells`]) `depth` is the coarse level every surface leaf reaches
//! and `fine` the level the leaves holding a data point reach (with the data's normals: the
//! leaves holding data that is not flat); without it, `fine` = `depth`.
//!
//! The topology guard is the small-normal-variation condition of Plantinga & Vegter (*Isotopic
//! approximation of implicit curves and surfaces*, SGP 2004): with G the interval enclosure of ∇f
//! over the cell, the cell passes when the interval inner product ⟨G, G⟩ excludes 0, i.e.
//! ⟨∇f(p), ∇f(q)⟩ > 0 for all p, q in the cell — the normal cannot turn by 90° or more inside it,
//! so the cell cannot hold a small closed piece, a handle or a singular point.

use std::collections::HashSet;
use std::hash::BuildHasherDefault;

use rayon::prelude::*;

use super::grid::{Grid, MultiplyHasher};
use crate::cloud::Aabb;
use crate::implicit::{Enclosure, GridValues, ImplicitFunction};

/// Levels below which the children of a cell are processed in parallel (8³ = 512 tasks).
const PARALLEL_LEVELS: u32 = 3;

/// A cell of the octree: its level and integer coordinates at that level.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub(crate) struct Cell {
    /// Level (0 = the whole region).
    pub level: u32,
    /// Integer coordinates, each `< 2^level`.
    pub coords: [u32; 3],
}

/// The result of the octree construction.
#[derive(Debug, Default)]
pub(crate) struct Octree {
    /// Surface leaves in depth-first child order.
    pub leaves: Vec<Cell>,
    /// Keys ([`Grid::cell_key`]) of the subdivided cells at levels ≥ `depth`.
    pub internal: HashSet<u64, BuildHasherDefault<MultiplyHasher>>,
    /// Number of cells at levels ≥ `depth` split by the topology guard (not for the data).
    pub guard_splits: u64,
    /// Bound evaluations spent.
    pub evaluations: u64,
}

/// What one subtree contributes.
#[derive(Default)]
struct Part {
    leaves: Vec<Cell>,
    internal: Vec<Cell>,
    guard_splits: u64,
    evaluations: u64,
}

impl Part {
    fn append(&mut self, mut other: Part) {
        self.leaves.append(&mut other.leaves);
        self.internal.append(&mut other.internal);
        self.guard_splits += other.guard_splits;
        self.evaluations += other.evaluations;
    }
}

/// The cells between the grid's `depth` and a finer level that hold a data point: the octree
/// splits them down to `fine`, so the mesh has the fine resolution where the data is and the
/// coarse one between far-apart points. With the data's normals, a cell where the data is flat
/// (see [`DataCells::new`]) is not split either: a plane needs no fine cells.
pub(crate) struct DataCells {
    /// Level the leaves holding a data point reach (> the grid's `depth`).
    pub fine: u32,
    /// Keys ([`Grid::cell_key`]) of the cells of levels `depth..fine` that hold a data point
    /// (and, with normals, are not flat), with all their ancestors down to `depth`.
    keys: HashSet<u64, BuildHasherDefault<MultiplyHasher>>,
}

/// A cell counts as flat when its data and that of its 26 neighbours (at its level) number at
/// least this many points...
const FLAT_MIN_POINTS: u32 = 8;

/// ... and the mean of their unit normals is at least this long: 1 − |mean| ≈ ⟨θ²⟩/2 for small
/// angles θ to the mean direction, so this asks an RMS angle of about 1.1°. Over such a cell
/// of side H the surface departs from its tangent plane by about H·θ, against the curvature
/// error of the fine cells the coarse one replaces. On the synthetic shapes of the benchmark
/// (20,000 points, exact normals, detail mode) the cube's faces are flat at the coarse level,
/// while the sphere, the torus, the eight and the twisted shape give the same mesh as without
/// the test, and the heart the same but for 22 of its 57,279 vertices.
const FLAT_MEAN_LENGTH: f64 = 0.9998;

/// A cell's data: the sum of its unit normals and its point count.
type NormalSum = ([f64; 3], u32);

impl DataCells {
    /// The cells of levels `grid.depth..fine` that hold one of `points` (points outside the
    /// region are ignored), with their ancestors. With `normals` (one unit normal per point),
    /// a cell's data is *flat* when the points in its 3×3×3 block of cells number at least
    /// [`FLAT_MIN_POINTS`] and their mean normal is at least [`FLAT_MEAN_LENGTH`] long, and
    /// *curved* when they are as many but their mean is shorter; a curved cell is split with
    /// its ancestors, a flat one only when one of its descendants is curved, and a cell with
    /// fewer points in its block when its parent is split. So planar parts of a scan are
    /// meshed with large triangles while its curved parts and its edges get the fine level.
    /// Deterministic: a set, whatever the thread count (the sums run in a fixed order).
    pub(crate) fn new(
        grid: &Grid,
        points: &[[f64; 3]],
        normals: Option<&[[f64; 3]]>,
        fine: u32,
    ) -> DataCells {
        debug_assert!(grid.depth < fine && fine <= grid.cap);
        debug_assert!(normals.is_none_or(|n| n.len() == points.len()));
        let mut keys: HashSet<u64, BuildHasherDefault<MultiplyHasher>> =
            HashSet::with_hasher(BuildHasherDefault::default());
        let Some(normals) = normals else {
            // The level fine − 1 cells first, then their ancestors.
            let mut cells: Vec<Cell> = points
                .par_iter()
                .filter_map(|&p| grid.cell_of(p, fine - 1))
                .collect();
            cells.par_sort_unstable();
            cells.dedup();
            keys.reserve(2 * cells.len());
            for cell in cells {
                insert_with_ancestors(grid, &mut keys, cell);
            }
            return DataCells { fine, keys };
        };
        // Level fine − 1: each cell's normal sum, the points taken in (cell, index) order.
        let mut located: Vec<(Cell, u32)> = points
            .par_iter()
            .enumerate()
            .filter_map(|(i, &p)| grid.cell_of(p, fine - 1).map(|c| (c, i as u32)))
            .collect();
        located.par_sort_unstable();
        let mut sums = add_up(
            located
                .into_iter()
                .map(|(c, i)| (c, (normals[i as usize], 1))),
        );
        keys.reserve(2 * sums.len());
        // Each level's cells with data and what their blocks say, finest first.
        let mut levels: Vec<Vec<(Cell, Flatness)>> = Vec::new();
        for level in (grid.depth..fine).rev() {
            let at_level: std::collections::HashMap<[u32; 3], NormalSum> =
                sums.iter().map(|&(c, s)| (c.coords, s)).collect();
            levels.push(
                sums.iter()
                    .map(|&(c, _)| (c, block_flatness(&at_level, c.coords)))
                    .collect(),
            );
            if level > grid.depth {
                // The parents' sums, each of its children's in cell order (a stable sort).
                let mut parents: Vec<(Cell, NormalSum)> =
                    sums.iter().map(|&(c, s)| (parent(c), s)).collect();
                parents.sort_by_key(|&(c, _)| c);
                sums = add_up(parents.into_iter());
            }
        }
        // A cell whose data is not flat is split, and so are its ancestors.
        for &(cell, flatness) in levels.iter().flatten() {
            if flatness == Flatness::Curved {
                insert_with_ancestors(grid, &mut keys, cell);
            }
        }
        // A cell with too few points to tell is split when its parent is (or at the coarse
        // level), as it would be without normals: coarsest first.
        for &(cell, flatness) in levels.iter().rev().flatten() {
            if flatness == Flatness::Unknown
                && (cell.level == grid.depth || keys.contains(&grid.cell_key(parent(cell))))
            {
                keys.insert(grid.cell_key(cell));
            }
        }
        DataCells { fine, keys }
    }

    /// Whether `cell` (of a level in `depth..fine`) is split for the data: it holds a data
    /// point (with normals: as [`DataCells::new`] says).
    fn holds(&self, grid: &Grid, cell: Cell) -> bool {
        cell.level < self.fine && self.keys.contains(&grid.cell_key(cell))
    }
}

/// The parent of `cell` (level ≥ 1).
fn parent(cell: Cell) -> Cell {
    Cell {
        level: cell.level - 1,
        coords: cell.coords.map(|c| c / 2),
    }
}

/// The sums of `items` (sorted by cell) per cell, in that order.
fn add_up(items: impl Iterator<Item = (Cell, NormalSum)>) -> Vec<(Cell, NormalSum)> {
    let mut sums: Vec<(Cell, NormalSum)> = Vec::new();
    for (cell, (n, k)) in items {
        match sums.last_mut() {
            Some((c, (s, count))) if *c == cell => {
                for a in 0..3 {
                    s[a] += n[a];
                }
                *count += k;
            }
            _ => sums.push((cell, (n, k))),
        }
    }
    sums
}

/// Adds `cell` and its ancestors down to the grid's `depth` to `keys`.
fn insert_with_ancestors(
    grid: &Grid,
    keys: &mut HashSet<u64, BuildHasherDefault<MultiplyHasher>>,
    mut cell: Cell,
) {
    // An ancestor already in the set has all of its own ancestors there too.
    while cell.level >= grid.depth && keys.insert(grid.cell_key(cell)) && cell.level > 0 {
        cell = parent(cell);
    }
}

/// What the normals of a cell's block of cells say.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Flatness {
    /// Enough points, nearly one normal.
    Flat,
    /// Enough points, not one normal.
    Curved,
    /// Fewer than [`FLAT_MIN_POINTS`].
    Unknown,
}

/// What the data of the 3×3×3 block of cells around `coords` (cells of one level, by
/// coordinates) says (see [`DataCells::new`]). The block's sums are added in a fixed order.
fn block_flatness(
    sums: &std::collections::HashMap<[u32; 3], NormalSum>,
    coords: [u32; 3],
) -> Flatness {
    let mut total = [0.0f64; 3];
    let mut count = 0u32;
    for dz in -1i32..=1 {
        for dy in -1i32..=1 {
            for dx in -1i32..=1 {
                let step = [dx, dy, dz];
                let at = [0, 1, 2].map(|a| coords[a].checked_add_signed(step[a]));
                if let [Some(x), Some(y), Some(z)] = at
                    && let Some((s, k)) = sums.get(&[x, y, z])
                {
                    for a in 0..3 {
                        total[a] += s[a];
                    }
                    count += k;
                }
            }
        }
    }
    let length2 = total[0] * total[0] + total[1] * total[1] + total[2] * total[2];
    let n = f64::from(count);
    if count < FLAT_MIN_POINTS {
        Flatness::Unknown
    } else if length2 >= (FLAT_MEAN_LENGTH * n) * (FLAT_MEAN_LENGTH * n) {
        Flatness::Flat
    } else {
        Flatness::Curved
    }
}

/// Builds the octree of `function` over `grid`, refined down to `data.fine` near the data when
/// `data` is given.
pub(crate) fn build<F: ImplicitFunction + ?Sized>(
    function: &F,
    grid: &Grid,
    data: Option<&DataCells>,
) -> Octree {
    let root = Cell {
        level: 0,
        coords: [0, 0, 0],
    };
    let mut part = Part::default();
    visit(function, grid, data, root, None, &mut part);
    Octree {
        leaves: part.leaves,
        internal: part.internal.iter().map(|&c| grid.cell_key(c)).collect(),
        guard_splits: part.guard_splits,
        evaluations: part.evaluations,
    }
}

/// What a child learns from its parent: the parent's enclosure, and f at the child's centre
/// with its error bound when the parent's expansion provided it.
#[derive(Clone, Copy)]
struct FromParent<'a> {
    enclosure: &'a Enclosure,
    center_value: Option<(f64, f64)>,
}

/// Visits `cell`, appending what its subtree contributes to `part`; `parent` is what its parent
/// passes down (None for the root).
///
/// A child is first tested by the mean-value form with its parent's gradient enclosure G:
/// f(box) ⊂ f(c) ± Σ_a max|G_a|·h_a, widened by the error of the value at c and of a point value
/// anywhere in the box. The value at c comes from the parent's local expansion (all 8 children at
/// once, [`ImplicitFunction::enclosure_and_grid_values`]) when the model provides it, else from
/// one point value. Only a cell that survives and must be split, or whose parent's gradient
/// enclosure fails the guard, computes its own (tighter, costlier) enclosure.
fn visit<F: ImplicitFunction + ?Sized>(
    function: &F,
    grid: &Grid,
    data: Option<&DataCells>,
    cell: Cell,
    parent: Option<FromParent<'_>>,
    part: &mut Part,
) {
    if grid.is_outside(cell) {
        return;
    }
    let cell_box = grid.cell_box(cell);
    if let Some(parent) = parent {
        let (v, error) = match parent.center_value {
            Some(known) => known,
            None => {
                part.evaluations += 1;
                (
                    function.value(cell_box.center()),
                    parent.enclosure.value_error,
                )
            }
        };
        if mean_value_excludes_zero(v, error, &cell_box, parent.enclosure) {
            return;
        }
    }
    // A cell above `depth`, or near the data above `fine`, is split whenever it survives.
    let must_split = cell.level < grid.depth || data.is_some_and(|d| d.holds(grid, cell));
    // The guard runs when it may refine beyond the finest level asked for (cap > fine).
    let fine = data.map_or(grid.depth, |d| d.fine);
    let in_guard_zone = cell.level >= grid.depth && cell.level < grid.cap && grid.cap > fine;
    let passes_guard_by_parent =
        parent.is_some_and(|p| normal_variation_small(&p.enclosure.gradient));
    let leaf_without_own_enclosure = !must_split && (!in_guard_zone || passes_guard_by_parent);
    if leaf_without_own_enclosure {
        part.leaves.push(cell);
        return;
    }
    let children = children(cell);
    // A cell that must be split has its children's centre values taken from its expansion;
    // otherwise splits are rare (guard failures only).
    let (enclosure, grid_values) = if must_split {
        let (first, last) = (grid.cell_box(children[0]), grid.cell_box(children[7]));
        let (c0, c1) = (first.center(), last.center());
        let axes = [0, 1, 2].map(|a| [c0[a], c1[a]]);
        function.enclosure_and_grid_values(&cell_box, &axes)
    } else {
        (function.enclosure_on_box(&cell_box), None)
    };
    part.evaluations += 1;
    let (lo, hi) = enclosure.value;
    // Values ≥ 0 count as outside, so a cell is empty when f > 0 or f < 0 throughout.
    if lo > 0.0 || hi < 0.0 {
        return;
    }
    let split = must_split || (in_guard_zone && !normal_variation_small(&enclosure.gradient));
    if !split {
        part.leaves.push(cell);
        return;
    }
    if cell.level >= grid.depth {
        part.internal.push(cell);
        part.guard_splits += u64::from(!must_split);
    }
    let from_parent = |i: usize| FromParent {
        enclosure: &enclosure,
        center_value: grid_values.map(|g: GridValues| (g.values[i], g.error)),
    };
    if cell.level < PARALLEL_LEVELS {
        let parts: Vec<Part> = children
            .par_iter()
            .enumerate()
            .map(|(i, &child)| {
                let mut child_part = Part::default();
                visit(
                    function,
                    grid,
                    data,
                    child,
                    Some(from_parent(i)),
                    &mut child_part,
                );
                child_part
            })
            .collect();
        for p in parts {
            part.append(p);
        }
    } else {
        // Sequentially, straight into `part`: the same order as concatenating.
        for (i, &child) in children.iter().enumerate() {
            visit(function, grid, data, child, Some(from_parent(i)), part);
        }
    }
}

/// Whether the mean-value form with the parent's gradient enclosure shows that f has one strict
/// sign on `b` (a sub-box of the parent's box), given `v` ≈ f(centre of b) within `error`.
fn mean_value_excludes_zero(v: f64, error: f64, b: &Aabb, parent: &Enclosure) -> bool {
    let mut reach = 0.0;
    for a in 0..3 {
        let (lo, hi) = parent.gradient[a];
        reach += lo.abs().max(hi.abs()) * 0.5 * (b.max[a] - b.min[a]);
    }
    // The relative 1e-12 covers the rounding of this sum and of the centre; `error` covers the
    // value at the centre, the value error a point value anywhere else in the box.
    let slack = reach * (1.0 + 1e-12) + error + parent.value_error;
    if !(slack.is_finite() && v.is_finite()) {
        return false;
    }
    v - slack > 0.0 || v + slack < 0.0
}

/// The 8 children of `cell`, x fastest.
pub(crate) fn children(cell: Cell) -> [Cell; 8] {
    std::array::from_fn(|i| Cell {
        level: cell.level + 1,
        coords: [0, 1, 2].map(|a| 2 * cell.coords[a] + ((i >> a) & 1) as u32),
    })
}

/// Plantinga–Vegter's condition: the interval inner product of the gradient enclosure with
/// itself excludes 0 (it can only be positive, so: its lower end is > 0).
fn normal_variation_small(gradient: &[(f64, f64); 3]) -> bool {
    let mut lo = 0.0;
    for &(a, b) in gradient {
        if !(a.is_finite() && b.is_finite()) {
            return false;
        }
        // Lower end of the interval product [a, b]·[a, b] (two independent copies).
        lo += (a * a).min(a * b).min(b * b);
    }
    lo > 0.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn guard_condition() {
        assert!(normal_variation_small(&[
            (1.0, 2.0),
            (-0.1, 0.1),
            (0.0, 0.0)
        ]));
        assert!(!normal_variation_small(&[
            (1.0, 2.0),
            (-2.0, 2.0),
            (0.0, 0.0)
        ]));
        assert!(!normal_variation_small(&[
            (-1.0, 1.0),
            (-1.0, 1.0),
            (-1.0, 1.0)
        ]));
        assert!(!normal_variation_small(&[
            (f64::NEG_INFINITY, 1.0),
            (1.0, 1.0),
            (1.0, 1.0)
        ]));
    }

    #[test]
    fn children_tile_parent() {
        let c = children(Cell {
            level: 2,
            coords: [1, 2, 3],
        });
        assert_eq!(c[0].coords, [2, 4, 6]);
        assert_eq!(c[7].coords, [3, 5, 7]);
        assert_eq!(c[1].coords, [3, 4, 6]);
        assert!(c.iter().all(|k| k.level == 3));
    }
}
