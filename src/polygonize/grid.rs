//! The integer lattice of the `polygonize` stage: cell and point coordinates, and their place in
//! the region.
//!
//! Input: the region box, `depth` and the cap. Output: exact integer names for every point the
//! extraction samples (cell corners, face centres, cell centres) and their input coordinates.
//!
//! Invariants: the lattice has 2^(cap+1) steps per axis, so every cell of level ≤ cap has an even
//! side in lattice steps and its centre and face centres are lattice points; a lattice point maps
//! to the same input-space point every time (one formula), so two cells that share a point see
//! exactly the same f value and sign there.

use std::hash::Hasher;

use crate::cloud::Aabb;

use super::octree::Cell;

/// Bits per axis in a packed lattice point (the lattice has at most 2^17 steps per axis).
const POINT_BITS: u32 = 18;

/// The lattice over the region.
///
/// The octree's root is a cube of 2^depth level-`depth` cells per axis, each of the region's
/// longest side / 2^depth; along a shorter axis only the first n_a = ⌈side_a / cell⌉ cells are
/// inside, and they are shrunk (by less than 2×) so that they end exactly on the region's face.
/// Cells of level < `depth` may straddle that face and are clipped to it; cells of level ≥
/// `depth` are wholly inside or wholly outside.
#[derive(Clone, Debug)]
pub(crate) struct Grid {
    /// Level every surface leaf reaches.
    pub depth: u32,
    /// Deepest level (topology guard cap), ≤ [`Grid::MAX_CAP`].
    pub cap: u32,
    /// The region's smallest corner.
    origin: [f64; 3],
    /// Input-space length of one lattice step along each axis.
    step: [f64; 3],
    /// Lattice steps from the region's smallest to its largest corner along each axis.
    extent: [u64; 3],
}

impl Grid {
    /// Largest supported cap.
    pub(crate) const MAX_CAP: u32 = 16;

    /// The lattice for `region`, refined to `depth` with the guard capped at `cap`.
    pub(crate) fn new(region: Aabb, depth: u32, cap: u32) -> Grid {
        debug_assert!(depth <= cap && cap <= Grid::MAX_CAP);
        let sides = [0, 1, 2].map(|a| region.max[a] - region.min[a]);
        let longest = sides.iter().copied().fold(0.0, f64::max);
        let cells_per_axis = f64::from(1u32 << depth);
        let cell = longest / cells_per_axis;
        let depth_side = 1u64 << (cap + 1 - depth);
        let extent = sides.map(|s| {
            // The 1e-9 keeps a side that is a whole number of cells from rounding up.
            let n = (s / cell * (1.0 - 1e-9)).ceil().clamp(1.0, cells_per_axis);
            n as u64 * depth_side
        });
        let step = [0, 1, 2].map(|a| sides[a] / extent[a] as f64);
        Grid {
            depth,
            cap,
            origin: region.min,
            step,
            extent,
        }
    }

    /// Side of a level-`level` cell in lattice steps.
    pub(crate) fn cell_side(&self, level: u32) -> u64 {
        1 << (self.cap + 1 - level)
    }

    /// Smallest lattice corner of `cell`.
    pub(crate) fn cell_min(&self, cell: Cell) -> [u64; 3] {
        let side = self.cell_side(cell.level);
        cell.coords.map(|c| u64::from(c) * side)
    }

    /// Input-space coordinates of the lattice point `l`.
    #[inline]
    pub(crate) fn point(&self, l: [u64; 3]) -> [f64; 3] {
        [
            self.origin[0] + l[0] as f64 * self.step[0],
            self.origin[1] + l[1] as f64 * self.step[1],
            self.origin[2] + l[2] as f64 * self.step[2],
        ]
    }

    /// Whether `cell` lies wholly outside the region.
    pub(crate) fn is_outside(&self, cell: Cell) -> bool {
        let min = self.cell_min(cell);
        (0..3).any(|a| min[a] >= self.extent[a])
    }

    /// The closed box of `cell`, clipped to the region, in input coordinates (its corners are
    /// exactly [`Grid::point`]s).
    pub(crate) fn cell_box(&self, cell: Cell) -> Aabb {
        let min = self.cell_min(cell);
        let side = self.cell_side(cell.level);
        let max = [0, 1, 2].map(|a| (min[a] + side).min(self.extent[a]));
        Aabb {
            min: self.point(min),
            max: self.point(max),
        }
    }

    /// A unique key for a cell (level and coordinates).
    pub(crate) fn cell_key(&self, cell: Cell) -> u64 {
        u64::from(cell.level) << 48
            | u64::from(cell.coords[0])
            | u64::from(cell.coords[1]) << 16
            | u64::from(cell.coords[2]) << 32
    }

    /// The level-`level` cell that holds the input-space point `p` (a point on a face between
    /// two cells goes to the upper one), `None` when `p` lies outside the region or is not
    /// finite.
    pub(crate) fn cell_of(&self, p: [f64; 3], level: u32) -> Option<Cell> {
        let side = self.cell_side(level);
        let mut coords = [0u32; 3];
        for a in 0..3 {
            let l = (p[a] - self.origin[a]) / self.step[a];
            if !(l >= 0.0 && l <= self.extent[a] as f64) {
                return None;
            }
            // A point on the region's upper face belongs to the last cell inside.
            let last = (self.extent[a] - 1) / side;
            coords[a] = ((l / side as f64).floor() as u64).min(last) as u32;
        }
        Some(Cell { level, coords })
    }

    /// Whether integer coordinates at `level` name a cell inside the region.
    pub(crate) fn in_range(&self, level: u32, coords: [i64; 3]) -> bool {
        coords.iter().all(|&c| c >= 0 && c < 1i64 << level)
    }
}

/// Packs a lattice point into one integer (ordered by z, then y, then x).
pub(crate) fn pack(l: [u64; 3]) -> u64 {
    l[0] | l[1] << POINT_BITS | l[2] << (2 * POINT_BITS)
}

/// Inverse of [`pack`].
pub(crate) fn unpack(key: u64) -> [u64; 3] {
    let mask = (1u64 << POINT_BITS) - 1;
    [
        key & mask,
        (key >> POINT_BITS) & mask,
        key >> (2 * POINT_BITS),
    ]
}

/// Fibonacci hashing of integer keys (`u64`, `u128`): the keys here are distinct lattice
/// points, cells or edges, so no protection against adversarial keys is needed.
#[derive(Default)]
pub(crate) struct MultiplyHasher(u64);

impl Hasher for MultiplyHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        }
    }

    fn write_u64(&mut self, key: u64) {
        self.0 = (self.0 ^ key)
            .wrapping_mul(0x9e37_79b9_7f4a_7c15)
            .rotate_left(29);
    }

    fn write_u128(&mut self, key: u128) {
        self.write_u64(key as u64);
        self.write_u64((key >> 64) as u64);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pack_round_trips() {
        for l in [[0, 0, 0], [1 << 17, 5, 1 << 17], [3, 1 << 16, 7]] {
            assert_eq!(unpack(pack(l)), l);
        }
    }

    #[test]
    fn cell_box_corners_are_lattice_points() {
        // Longest side 4 along y: level-2 cells of side 1; x has 2 of them, z one (shrunk to 0.5).
        let region = Aabb {
            min: [-1.0, 0.0, 2.0],
            max: [1.0, 4.0, 2.5],
        };
        let g = Grid::new(region, 2, 4);
        let root = g.cell_box(Cell {
            level: 0,
            coords: [0, 0, 0],
        });
        assert_eq!(root, region);
        let b = g.cell_box(Cell {
            level: 2,
            coords: [1, 3, 0],
        });
        assert_eq!(
            b,
            Aabb {
                min: [0.0, 3.0, 2.0],
                max: [1.0, 4.0, 2.5]
            }
        );
        assert!(g.is_outside(Cell {
            level: 2,
            coords: [2, 0, 0]
        }));
        assert!(g.is_outside(Cell {
            level: 2,
            coords: [0, 0, 1]
        }));
        assert!(!g.is_outside(Cell {
            level: 1,
            coords: [0, 1, 0]
        }));
        // A level-4 cell below the depth keeps its shrunk z side: 0.5 / 4.
        let c = g.cell_box(Cell {
            level: 4,
            coords: [0, 0, 3],
        });
        assert!((c.max[2] - c.min[2] - 0.125).abs() < 1e-15);
    }
}
