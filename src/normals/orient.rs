//! Global orientation of the `normals` stage: consistent signs, then outward, per connected piece.
//!
//! Input: distinct points, unit normals with arbitrary signs, the crust triangles (may be empty)
//! and the k-nearest-neighbour lists. Output: the same normals, some negated, so that neighbours
//! agree and every piece points out of the object.
//!
//! # Algorithm
//!
//! The paper (section 5.2) aligns normals by propagation: take a reference normal, flip each
//! neighbour whose dot product with it is negative (with an angle margin), and repeat from each
//! aligned point. The order matters: propagating across a sharp fold or between two close sheets
//! flips whole regions. Following Hoppe et al. (1992, "Surface reconstruction from unorganized
//! points"), propagation runs along a minimum spanning tree of the neighbour graph weighted by
//! 1 − |nᵢ·nⱼ|, so that it always crosses the most parallel pairs first and the unreliable
//! (nearly perpendicular) pairs last, if at all. Crust edges are preferred over k-nearest-neighbour
//! edges (the latter get a penalty of 1), because k-nearest neighbours may lie on the other side
//! of a thin part while crust edges follow the surface.
//!
//! Outward: for any centre c, the point of a closed surface farthest from c has its outward normal
//! along p − c. Each connected piece's farthest points from its centroid (the farthest 2%, at
//! least 8) vote with n·(p − c)/|p − c|; a negative sum flips the piece.

use rayon::prelude::*;

use crate::normals::vec3::{dot, norm, scale, sub};
use crate::numerics::{Neighbours, PointGrid};

/// Points per block of graph rows.
const BLOCK: usize = 4096;

/// Symmetric neighbour graph in compressed rows, in blocks of [`BLOCK`] rows (built in parallel
/// and kept as built, without a copy into one array). Points are numbered in the sweep order of
/// [`orient_consistently`]. A row holds each neighbour once, crust neighbours first: an entry's
/// weight in the spanning tree, penalty + 1 − |nᵢ·nⱼ|, is computed where the tree needs it
/// ([`Graph::weight`]) instead of stored (4 bytes an entry instead of 12).
struct Graph {
    blocks: Vec<GraphBlock>,
    /// The penalty of a row's entries after its crust neighbours: 1 when there is a crust.
    knn_penalty: u32,
}

struct GraphBlock {
    /// `start[r]..start[r + 1]` are the entries of the block's row r.
    start: Vec<u32>,
    /// `start[r]..crust_end[r]` are the row's entries of penalty 0 (its crust neighbours, or
    /// all of them when there is no crust), the rest its other k-nearest ones (penalty
    /// [`Graph::knn_penalty`]).
    crust_end: Vec<u32>,
    /// The neighbour of each entry.
    neighbour: Vec<u32>,
}

impl Graph {
    /// The neighbours of point `u`'s row, and how many of them (the first) are crust
    /// neighbours.
    fn row(&self, u: usize) -> (&[u32], usize) {
        let block = &self.blocks[u / BLOCK];
        let r = u % BLOCK;
        let (start, crust_end) = (block.start[r] as usize, block.crust_end[r] as usize);
        (
            &block.neighbour[start..block.start[r + 1] as usize],
            crust_end - start,
        )
    }

    /// The weight of the edge between points with unit normals `a` and `b`, that is
    /// penalty + 1 − |a·b| (at least 0), as its bits: for non-negative values their order is
    /// the numbers'. It does not depend on the signs (|a·b| has the same bits either way
    /// round), so flipping normals while the tree grows leaves it unchanged.
    #[inline]
    fn weight(penalty: u32, a: &[f64; 3], b: &[f64; 3]) -> u64 {
        let w = f64::from(penalty) + 1.0 - dot(a, b).abs().min(1.0);
        w.max(0.0).to_bits()
    }
}

/// The graph over points renumbered by `rank` (`perm` its inverse), triangles and k-nearest
/// lists in the input's numbering. The lists are consumed: they are renumbered into the sweep
/// order and dropped, so only one copy is held.
fn build_graph(
    n: usize,
    perm: &[u32],
    rank: &[u32],
    triangles: &[[u32; 3]],
    knn: Neighbours,
) -> Graph {
    let knn_penalty = u32::from(!triangles.is_empty());
    // The triangles at each point (input numbering), in compressed rows.
    let (tri_start, tri_rows) = rows_by_point(
        n,
        triangles.iter().enumerate().flat_map(|(t, tri)| {
            tri.iter()
                .filter(|&&v| (v as usize) < n)
                .map(move |&v| (v, t as u32))
        }),
    );
    // The k-nearest lists in the sweep order, renumbered (u32::MAX for an entry out of range),
    // and the points whose lists name each point. Both read and write near the sweep index,
    // so they stay in cache however the input is ordered.
    let stride = knn.stride();
    let mut near = vec![u32::MAX; n * stride];
    near.par_chunks_mut(stride.max(1))
        .enumerate()
        .for_each(|(u, row)| {
            for (slot, &j) in row.iter_mut().zip(knn.row(perm[u] as usize)) {
                if (j as usize) < n {
                    *slot = rank[j as usize];
                }
            }
        });
    drop(knn);
    let (named_start, named_by) = named_by(n, stride, &near);
    let near = |u: usize| {
        near[u * stride..(u + 1) * stride]
            .iter()
            .copied()
            .filter(|&j| (j as usize) < n)
    };
    // Each point's row: its crust neighbours (penalty 0), then the others among its k nearest
    // and the points that count it among theirs (penalty 1 when there is a crust), each
    // neighbour once. The rows are independent, so they are built in parallel; the order
    // inside a row does not matter to the spanning tree (see `orient_consistently`).
    let blocks: Vec<GraphBlock> = (0..n.div_ceil(BLOCK))
        .into_par_iter()
        .map(|b| {
            let block = b * BLOCK..((b + 1) * BLOCK).min(n);
            let mut start = Vec::with_capacity(block.len() + 1);
            let mut crust_end = Vec::with_capacity(block.len());
            start.push(0u32);
            let mut neighbour = Vec::new();
            // Entries as neighbour << 1 | penalty: sorting the numbers orders by neighbour,
            // then penalty.
            let mut row: Vec<u64> = Vec::new();
            for u in block {
                row.clear();
                let v = perm[u] as usize;
                for &t in &tri_rows[tri_start[v]..tri_start[v + 1]] {
                    let tri = triangles[t as usize];
                    for k in 0..3 {
                        let (a, b) = (tri[k] as usize, tri[(k + 1) % 3] as usize);
                        if a == b || a >= n || b >= n {
                            continue;
                        }
                        if a == v {
                            row.push(u64::from(rank[b]) << 1);
                        } else if b == v {
                            row.push(u64::from(rank[a]) << 1);
                        }
                    }
                }
                for j in near(u).chain(named_by[named_start[u]..named_start[u + 1]].iter().copied())
                {
                    if j as usize != u {
                        row.push(u64::from(j) << 1 | u64::from(knn_penalty));
                    }
                }
                // Each neighbour once, with its smallest penalty; crust neighbours first.
                row.sort_unstable();
                row.dedup_by_key(|e| *e >> 1);
                neighbour.extend(
                    row.iter()
                        .filter(|&&e| e & 1 == 0)
                        .map(|&e| (e >> 1) as u32),
                );
                crust_end.push(neighbour.len() as u32);
                neighbour.extend(
                    row.iter()
                        .filter(|&&e| e & 1 != 0)
                        .map(|&e| (e >> 1) as u32),
                );
                start.push(neighbour.len() as u32);
            }
            neighbour.shrink_to_fit();
            GraphBlock {
                start,
                crust_end,
                neighbour,
            }
        })
        .collect();
    Graph {
        blocks,
        knn_penalty,
    }
}

/// For each of the `n` points, the points whose rows of `near` (rows of `stride`, entries
/// `n` and above ignored) name it, in increasing order, in compressed rows (a counting sort):
/// row starts and points.
fn named_by(n: usize, stride: usize, near: &[u32]) -> (Vec<usize>, Vec<u32>) {
    let mut start = vec![0usize; n + 1];
    for &j in near {
        if (j as usize) < n {
            start[j as usize + 1] += 1;
        }
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut by = vec![0u32; start[n]];
    for (i, list) in near.chunks_exact(stride.max(1)).enumerate() {
        for &j in list {
            if (j as usize) < n {
                by[fill[j as usize]] = i as u32;
                fill[j as usize] += 1;
            }
        }
    }
    (start, by)
}

/// The values of `pairs` (point, value) grouped by point (each point below `n`) in compressed
/// rows, in the pairs' order within a row (a counting sort): row starts and values.
fn rows_by_point(n: usize, pairs: impl Iterator<Item = (u32, u32)>) -> (Vec<usize>, Vec<u32>) {
    let pairs: Vec<(u32, u32)> = pairs.collect();
    let mut start = vec![0usize; n + 1];
    for &(v, _) in &pairs {
        start[v as usize + 1] += 1;
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut rows = vec![0u32; pairs.len()];
    for &(v, x) in &pairs {
        rows[fill[v as usize]] = x;
        fill[v as usize] += 1;
    }
    (start, rows)
}

/// Not in the frontier (see [`Frontier`]).
const OUTSIDE: u32 = u32::MAX;

/// The points next to the growing tree, in a 4-ary min-heap by (weight, input index) with each
/// point's heap position: one entry per point, lowered in place when a shorter edge reaches it
/// (Prim's algorithm with decrease-key). Entries are (weight bits, input index, sweep index).
struct Frontier {
    heap: Vec<(u64, u32, u32)>,
    /// Each point's index in `heap` (by sweep index), or [`OUTSIDE`].
    position: Vec<u32>,
}

impl Frontier {
    fn new(n: usize) -> Frontier {
        Frontier {
            heap: Vec::new(),
            position: vec![OUTSIDE; n],
        }
    }

    /// The weight at which point `u` (sweep index) waits in the frontier, if it does.
    fn weight_of(&self, u: usize) -> Option<u64> {
        let at = self.position[u];
        (at != OUTSIDE).then(|| self.heap[at as usize].0)
    }

    /// Adds point `u` (input index `id`) at weight `w`, or lowers it to `w` (never raises it).
    fn offer(&mut self, u: u32, id: u32, w: u64) {
        let at = match self.position[u as usize] {
            OUTSIDE => {
                self.heap.push((w, id, u));
                self.heap.len() - 1
            }
            at => {
                let at = at as usize;
                self.heap[at].0 = self.heap[at].0.min(w);
                at
            }
        };
        self.sift_up(at);
    }

    /// Removes and returns the least entry's sweep index.
    fn pop(&mut self) -> Option<u32> {
        let last = self.heap.pop()?;
        let top = if self.heap.is_empty() {
            last
        } else {
            let top = std::mem::replace(&mut self.heap[0], last);
            self.sift_down(0);
            top
        };
        self.position[top.2 as usize] = OUTSIDE;
        Some(top.2)
    }

    fn sift_up(&mut self, mut at: usize) {
        let entry = self.heap[at];
        while at > 0 {
            let parent = (at - 1) / 4;
            let above = self.heap[parent];
            if above <= entry {
                break;
            }
            self.place(at, above);
            at = parent;
        }
        self.place(at, entry);
    }

    fn sift_down(&mut self, mut at: usize) {
        let entry = self.heap[at];
        let len = self.heap.len();
        loop {
            let first = 4 * at + 1;
            if first >= len {
                break;
            }
            let mut child = first;
            for c in first + 1..(first + 4).min(len) {
                if self.heap[c] < self.heap[child] {
                    child = c;
                }
            }
            let below = self.heap[child];
            if below >= entry {
                break;
            }
            self.place(at, below);
            at = child;
        }
        self.place(at, entry);
    }

    /// Puts `entry` at heap index `at` and records that position.
    #[inline(always)]
    fn place(&mut self, at: usize, entry: (u64, u32, u32)) {
        self.heap[at] = entry;
        self.position[entry.2 as usize] = at as u32;
    }
}

/// Makes the signs of `normals` consistent along a minimum spanning tree of the neighbour graph
/// (the crust `triangles` and the k-nearest lists `knn`, which it consumes to renumber them in
/// place of a copy). Returns the connected pieces as a label per point.
pub(crate) fn orient_consistently(
    points: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    triangles: &[[u32; 3]],
    knn: Neighbours,
) -> Vec<u32> {
    let n = points.len().min(normals.len());
    // The work runs on the points renumbered in the grid's cell order (`perm[u]` is the input
    // index of sweep index u, `rank` the inverse), so that the tree's front, which advances
    // across the surface, reads nearby memory; every choice below still compares input
    // indices, so the tree does not depend on the numbering.
    let perm: Vec<u32> = match PointGrid::new(&points[..n]) {
        Some(grid) => grid.order().to_vec(),
        None => (0..n as u32).collect(),
    };
    let mut rank = vec![0u32; n];
    for (u, &v) in perm.iter().enumerate() {
        rank[v as usize] = u as u32;
    }
    let mut local: Vec<[f64; 3]> = perm.par_iter().map(|&v| normals[v as usize]).collect();
    let graph = build_graph(n, &perm, &rank, triangles, knn);
    // Prim's algorithm from the lowest unlabelled point (input index): the next point to join
    // is always the frontier's least (weight, point), through `from`, the tree point of its
    // least (weight, from) edge to the tree (an offer replaces the standing one only when its
    // (weight, from) is smaller). This is the tree of the lazy form with a heap of
    // (weight, point, from) entries that skips points already in the tree: a waiting point's
    // least entry is its least (weight, from), so both pop the same sequence. Whether an offer
    // replaces depends on that point's entry alone, and the order is by (weight, point), all
    // distinct: the order of a row's entries changes nothing.
    let mut label = vec![u32::MAX; n];
    let mut from = vec![u32::MAX; n];
    let mut frontier = Frontier::new(n);
    let mut n_pieces = 0u32;
    for (root, &r) in rank.iter().enumerate() {
        let r = r as usize;
        if label[r] != u32::MAX {
            continue;
        }
        frontier.offer(r as u32, root as u32, 0);
        from[r] = r as u32;
        while let Some(to) = frontier.pop() {
            let to = to as usize;
            label[to] = n_pieces;
            let parent = from[to] as usize;
            if dot(&local[to], &local[parent]) < 0.0 {
                local[to] = scale(&local[to], -1.0);
            }
            let id = perm[to];
            let (neighbours, n_crust) = graph.row(to);
            for (e, &j) in neighbours.iter().enumerate() {
                let j = j as usize;
                if label[j] != u32::MAX {
                    continue;
                }
                let penalty = if e < n_crust { 0 } else { graph.knn_penalty };
                let w = Graph::weight(penalty, &local[to], &local[j]);
                let better = match frontier.weight_of(j) {
                    None => true,
                    Some(standing) => (w, id) < (standing, perm[from[j] as usize]),
                };
                if better {
                    from[j] = to as u32;
                    frontier.offer(j as u32, perm[j], w);
                }
            }
        }
        n_pieces += 1;
    }
    let mut out = vec![0u32; n];
    for (u, &v) in perm.iter().enumerate() {
        normals[v as usize] = local[u];
        out[v as usize] = label[u];
    }
    out
}

/// Turns each connected piece (`label` from [`orient_consistently`]) outward by the
/// farthest-points vote. Returns the number of pieces flipped.
pub(crate) fn orient_outward_pieces(
    points: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    label: &[u32],
) -> usize {
    let n_pieces = label.iter().copied().max().map_or(0, |m| m as usize + 1);
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); n_pieces];
    for (i, &l) in label.iter().enumerate() {
        members[l as usize].push(i as u32);
    }
    let mut flipped = 0;
    for piece in &members {
        let count = piece.len() as f64;
        let mut centre = [0.0; 3];
        for &i in piece {
            for a in 0..3 {
                centre[a] += points[i as usize][a] / count;
            }
        }
        let mut by_distance: Vec<(f64, u32)> = piece
            .iter()
            .map(|&i| (norm(&sub(&points[i as usize], &centre)), i))
            .collect();
        // Only the voters are sorted: the order is total (indices are distinct), so they come
        // out as a full sort would order them.
        let order = |a: &(f64, u32), b: &(f64, u32)| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1));
        let voters = (piece.len() / 50).max(8).min(piece.len());
        if voters > 0 && voters < by_distance.len() {
            by_distance.select_nth_unstable_by(voters - 1, order);
        }
        by_distance[..voters].sort_unstable_by(order);
        let vote: f64 = by_distance[..voters]
            .iter()
            .filter(|(d, _)| *d > 0.0)
            .map(|&(d, i)| dot(&normals[i as usize], &sub(&points[i as usize], &centre)) / d)
            .sum();
        if vote < 0.0 {
            for &i in piece {
                normals[i as usize] = scale(&normals[i as usize], -1.0);
            }
            flipped += 1;
        }
    }
    flipped
}

/// Consistent signs, then outward, in one call.
pub(crate) fn orient_outward(
    points: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    triangles: &[[u32; 3]],
    knn: Neighbours,
) {
    let label = orient_consistently(points, normals, triangles, knn);
    orient_outward_pieces(points, normals, &label);
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cmp::Reverse;
    use std::collections::{BTreeMap, BinaryHeap};

    /// The spanning-tree orientation written plainly: the symmetric k-nearest graph as a map,
    /// a lazy heap of (weight, point, from) entries, input numbering throughout.
    /// Crust edges (of `triangles`) weigh 1 less than k-nearest ones when there are triangles.
    fn reference(
        points: &[[f64; 3]],
        normals: &mut [[f64; 3]],
        triangles: &[[u32; 3]],
        knn: &Neighbours,
    ) -> Vec<u32> {
        let n = points.len();
        let mut rows: Vec<BTreeMap<u32, u64>> = vec![BTreeMap::new(); n];
        let mut link = |i: usize, j: usize, penalty: f64| {
            let w = penalty + 1.0 - dot(&normals[i], &normals[j]).abs().min(1.0);
            let w = w.max(0.0).to_bits();
            for (a, b) in [(i, j), (j, i)] {
                let entry = rows[a].entry(b as u32).or_insert(w);
                *entry = (*entry).min(w);
            }
        };
        let knn_penalty = if triangles.is_empty() { 0.0 } else { 1.0 };
        for i in 0..n {
            for &j in knn.row(i) {
                link(i, j as usize, knn_penalty);
            }
        }
        for t in triangles {
            for k in 0..3 {
                link(t[k] as usize, t[(k + 1) % 3] as usize, 0.0);
            }
        }
        let mut label = vec![u32::MAX; n];
        let mut pieces = 0;
        for root in 0..n {
            if label[root] != u32::MAX {
                continue;
            }
            let mut heap = BinaryHeap::from([Reverse((0u64, root as u32, root as u32))]);
            while let Some(Reverse((_, to, from))) = heap.pop() {
                let to = to as usize;
                if label[to] != u32::MAX {
                    continue;
                }
                label[to] = pieces;
                if dot(&normals[to], &normals[from as usize]) < 0.0 {
                    normals[to] = scale(&normals[to], -1.0);
                }
                for (&j, &w) in &rows[to] {
                    if label[j as usize] == u32::MAX {
                        heap.push(Reverse((w, j, to as u32)));
                    }
                }
            }
            pieces += 1;
        }
        label
    }

    #[test]
    fn tree_matches_the_plain_lazy_prim_with_ties_and_several_pieces() {
        // Two lattice patches (many equal distances and equal weights) far apart, the normals
        // taken from a few directions with random signs, points in a shuffled order.
        let mut seed = 11u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            seed >> 33
        };
        let mut points: Vec<[f64; 3]> = Vec::new();
        for offset in [0.0, 100.0] {
            for i in 0..20 {
                for j in 0..15 {
                    points.push([offset + i as f64, j as f64, ((i + j) % 3) as f64 * 0.5]);
                }
            }
        }
        for i in (1..points.len()).rev() {
            points.swap(i, next() as usize % (i + 1));
        }
        // a·b > 0, b·c > 0 and a·c < 0: the signs found depend on the path, so on the tree.
        let directions = [[1.0, 0.0, 0.0], [0.6, 0.8, 0.0], [-0.6, 0.8, 0.0]];
        let normals: Vec<[f64; 3]> = (0..points.len())
            .map(|_| {
                let d = directions[next() as usize % 3];
                if next() % 2 == 0 {
                    d
                } else {
                    scale(&d, -1.0)
                }
            })
            .collect();
        // Some triangles over random point triples: crust edges, preferred over k-nearest ones
        // (they need not be near: the weights are what matters).
        let triangles: Vec<[u32; 3]> = (0..120)
            .map(|_| [0; 3].map(|_| next() as u32 % points.len() as u32))
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect();
        for (k, triangles) in [(4, &[][..]), (8, &[][..]), (4, &triangles[..])] {
            let knn = PointGrid::new(&points).unwrap().all_nearest(&points, k);
            let mut expected = normals.clone();
            let expected_label = reference(&points, &mut expected, triangles, &knn);
            let mut got = normals.clone();
            let label = orient_consistently(&points, &mut got, triangles, knn);
            let case = format!("k {k}, {} triangles", triangles.len());
            assert_eq!(label, expected_label, "{case}");
            assert_eq!(got, expected, "{case}");
            if triangles.is_empty() {
                assert_eq!(label.iter().max(), Some(&1), "two pieces, {case}");
            }
        }
    }
}
