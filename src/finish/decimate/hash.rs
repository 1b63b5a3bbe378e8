//! The decimation's spatial hash: the triangles by the cell of their box, for the collapses'
//! tests of their new triangles against the ones nearby.

use super::*;

/// The triangles by the cell of their box's lowest corner, at the level whose cells are at
/// least as large as the box (see the module docs, step 3).
pub(super) struct SpatialHash {
    origin: [f64; 3],
    base: f64,
    levels: Vec<HashMap<u64, Vec<u32>, FixedState>>,
    counts: Vec<usize>,
    /// (level, cell) of each registered triangle; level `u8::MAX` when not registered.
    slot: Vec<(u8, u64)>,
}

impl SpatialHash {
    pub(super) fn new(origin: [f64; 3], base: f64, n_triangles: usize) -> SpatialHash {
        SpatialHash {
            origin,
            base,
            levels: (0..HASH_LEVELS).map(|_| HashMap::default()).collect(),
            counts: vec![0; HASH_LEVELS],
            slot: vec![(u8::MAX, 0); n_triangles],
        }
    }

    fn cell_size(&self, level: usize) -> f64 {
        self.base * 2f64.powi(level as i32)
    }

    fn coordinate(&self, x: f64, axis: usize, size: f64) -> i64 {
        (((x - self.origin[axis]) / size).floor() as i64).clamp(-(1 << 20), (1 << 20) - 1)
    }

    fn key(cell: [i64; 3]) -> u64 {
        let part = |c: i64| ((c + (1 << 20)) as u64) & ((1 << 21) - 1);
        (part(cell[0]) << 42) | (part(cell[1]) << 21) | part(cell[2])
    }

    pub(super) fn insert(&mut self, t: u32, lo: [f64; 3], hi: [f64; 3]) {
        let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        let mut level = 0;
        while level + 1 < HASH_LEVELS && self.cell_size(level) < extent {
            level += 1;
        }
        let size = self.cell_size(level);
        let cell = [0, 1, 2].map(|a| self.coordinate(lo[a], a, size));
        let key = Self::key(cell);
        self.levels[level].entry(key).or_default().push(t);
        self.counts[level] += 1;
        self.slot[t as usize] = (level as u8, key);
    }

    pub(super) fn remove(&mut self, t: u32) {
        let (level, key) = self.slot[t as usize];
        if level == u8::MAX {
            return;
        }
        let level = level as usize;
        if let Some(list) = self.levels[level].get_mut(&key) {
            if let Some(i) = list.iter().position(|&s| s == t) {
                list.swap_remove(i);
                self.counts[level] -= 1;
            }
            if list.is_empty() {
                self.levels[level].remove(&key);
            }
        }
        self.slot[t as usize] = (u8::MAX, 0);
    }

    /// Every registered triangle whose box may meet the box `lo..hi` (a superset), into `out`.
    pub(super) fn query(&self, lo: [f64; 3], hi: [f64; 3], out: &mut Vec<u32>) {
        out.clear();
        for level in 0..HASH_LEVELS {
            if self.counts[level] == 0 {
                continue;
            }
            let size = self.cell_size(level);
            // A triangle of this level starts at most one cell below the box.
            let from = [0, 1, 2].map(|a| self.coordinate(lo[a] - size, a, size));
            let to = [0, 1, 2].map(|a| self.coordinate(hi[a], a, size));
            let cells: f64 = (0..3).map(|a| (to[a] - from[a] + 1) as f64).product();
            let map = &self.levels[level];
            if cells > map.len() as f64 {
                for (&key, list) in map {
                    let c = [42, 21, 0].map(|s| ((key >> s) & ((1 << 21) - 1)) as i64 - (1 << 20));
                    if (0..3).all(|a| from[a] <= c[a] && c[a] <= to[a]) {
                        out.extend_from_slice(list);
                    }
                }
                continue;
            }
            for x in from[0]..=to[0] {
                for y in from[1]..=to[1] {
                    for z in from[2]..=to[2] {
                        if let Some(list) = map.get(&Self::key([x, y, z])) {
                            out.extend_from_slice(list);
                        }
                    }
                }
            }
        }
    }
}
