//! The insertion order of the Delaunay tetrahedralization: a deterministic shuffle cut into BRIO
//! rounds, each sorted along a Hilbert curve, and the small generator behind the shuffle and the
//! walk.
//!
//! Input: the points and the ids to insert. Output: the ids reordered; the order depends on
//! nothing but the input.

/// A small deterministic generator (xorshift64*), so the insertion order and the walk never
/// depend on anything but the input.
#[derive(Clone)]
pub(super) struct Rng(pub(super) u64);

impl Rng {
    pub(super) fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
}

/// Hilbert index of a point quantised to 2^bits cells per axis (Skilling 2004, "Programming the
/// Hilbert curve": axes to transposed index, then bit interleaving).
fn hilbert_index(mut x: [u32; 3], bits: u32) -> u64 {
    let m = 1u32 << (bits - 1);
    let mut q = m;
    while q > 1 {
        let p = q - 1;
        for i in 0..3 {
            if x[i] & q != 0 {
                x[0] ^= p;
            } else {
                let t = (x[0] ^ x[i]) & p;
                x[0] ^= t;
                x[i] ^= t;
            }
        }
        q >>= 1;
    }
    for i in 1..3 {
        x[i] ^= x[i - 1];
    }
    let mut t = 0;
    q = m;
    while q > 1 {
        if x[2] & q != 0 {
            t ^= q - 1;
        }
        q >>= 1;
    }
    for v in &mut x {
        *v ^= t;
    }
    let mut key = 0u64;
    for b in (0..bits).rev() {
        for v in &x {
            key = (key << 1) | u64::from((v >> b) & 1);
        }
    }
    key
}

/// Insertion order: a deterministic shuffle cut into rounds of doubling size (BRIO), each
/// round sorted along a Hilbert curve so that consecutive points are close.
pub(super) fn brio_order(points: &[[f64; 3]], ids: &mut [u32]) {
    const BITS: u32 = 16;
    let Some(bbox) = crate::cloud::Aabb::from_points(points) else {
        return;
    };
    let scale = (0..3)
        .map(|a| bbox.max[a] - bbox.min[a])
        .fold(0.0f64, f64::max)
        .max(f64::MIN_POSITIVE);
    let cells = f64::from((1u32 << BITS) - 1);
    let key = |i: u32| {
        let p = points[i as usize];
        let q =
            [0, 1, 2].map(|a| (((p[a] - bbox.min[a]) / scale) * cells).clamp(0.0, cells) as u32);
        hilbert_index(q, BITS)
    };
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for i in (1..ids.len()).rev() {
        let j = (rng.next() % (i as u64 + 1)) as usize;
        ids.swap(i, j);
    }
    let mut end = ids.len();
    while end > 0 {
        let start = if end > 64 { end / 2 } else { 0 };
        ids[start..end].sort_by_cached_key(|&i| (key(i), i));
        end = start;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hilbert_index_is_a_bijection_on_a_small_grid() {
        let mut keys: Vec<u64> = (0..512u32)
            .map(|i| hilbert_index([i & 7, (i >> 3) & 7, i >> 6], 3))
            .collect();
        keys.sort_unstable();
        keys.dedup();
        assert_eq!(keys.len(), 512);
        assert!(keys.iter().all(|&k| k < 512));
    }

    #[test]
    fn hilbert_neighbours_in_order_are_adjacent_cells() {
        let mut cells: Vec<(u64, [u32; 3])> = (0..512u32)
            .map(|i| {
                let c = [i & 7, (i >> 3) & 7, i >> 6];
                (hilbert_index(c, 3), c)
            })
            .collect();
        cells.sort_unstable();
        for w in cells.windows(2) {
            let d: u32 = (0..3).map(|a| w[0].1[a].abs_diff(w[1].1[a])).sum();
            assert_eq!(d, 1, "consecutive Hilbert cells {:?} {:?}", w[0], w[1]);
        }
    }
}
