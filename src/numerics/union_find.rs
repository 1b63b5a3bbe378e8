//! Disjoint sets over the indices `0..n` (union-find), the one used for connected components of
//! meshes, boundary loops, fans around a vertex and pieces of the data.
//!
//! Invariants: the root of a set is always its smallest index (a union makes the smaller root
//! the parent of the larger one), so labels derived from roots follow index order and do not
//! depend on the order of the unions. `find` halves paths as it goes.

/// Disjoint sets over `0..n`; see the module docs for the invariants.
#[derive(Clone, Debug, Default)]
pub(crate) struct UnionFind {
    parent: Vec<u32>,
}

impl UnionFind {
    /// `n` singleton sets.
    pub(crate) fn new(n: usize) -> Self {
        let mut sets = Self::default();
        sets.reset(n);
        sets
    }

    /// Makes the sets `n` singletons again, reusing the storage.
    pub(crate) fn reset(&mut self, n: usize) {
        debug_assert!(n <= u32::MAX as usize + 1);
        self.parent.clear();
        self.parent.extend(0..n as u32);
    }

    /// The number of indices, n.
    pub(crate) fn len(&self) -> usize {
        self.parent.len()
    }

    /// The root (smallest index) of the set holding `i`.
    pub(crate) fn find(&mut self, mut i: u32) -> u32 {
        while self.parent[i as usize] != i {
            let grand = self.parent[self.parent[i as usize] as usize];
            self.parent[i as usize] = grand;
            i = grand;
        }
        i
    }

    /// Joins the sets holding `a` and `b`; the smaller root becomes the root of both. Returns
    /// whether they were separate.
    pub(crate) fn union(&mut self, a: u32, b: u32) -> bool {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra == rb {
            return false;
        }
        let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
        self.parent[hi as usize] = lo;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roots_are_the_smallest_index_whatever_the_union_order() {
        let mut sets = UnionFind::new(6);
        assert!(sets.union(4, 2));
        assert!(sets.union(5, 4));
        assert!(!sets.union(2, 5));
        assert!(sets.union(3, 1));
        let roots: Vec<u32> = (0..6).map(|i| sets.find(i)).collect();
        assert_eq!(roots, [0, 1, 2, 1, 2, 2]);
        sets.reset(3);
        let roots: Vec<u32> = (0..3).map(|i| sets.find(i)).collect();
        assert_eq!(roots, [0, 1, 2]);
    }
}
