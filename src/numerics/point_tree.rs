//! The k-d tree of points ([`PointTree`]) and the nearest-point queries built on it
//! (`PointIndex`, `nearest_point_distances`), run in a spatial order so that each query's
//! answer bounds the next one's search.
//!
//! Input: points. Output: nearest points and distances, exact.
//!
//! The crate's other point index, the point grid of `numerics`, answers the normals' fixed-size
//! neighbourhood queries over a whole cloud faster than a tree (a ball of nearly known
//! radius per point, read as contiguous runs); this tree serves every other query: the
//! nearest point to arbitrary places (mesh vertices, samples), queries of any radius, and
//! the detail fit's growing balls.
//!
//! `PointIndex`: the distances from a uniform grid of the points (`PointGrid::for_nearest`, a
//! counting sort, built in a fraction of a k-d tree's time over a scan of millions of points),
//! with the k-d tree for what the grid leaves open and for the colours' nearest points.
//! [`PointTree`] is a k-d tree (Friedman, Bentley and Finkel 1977) with median splits on the
//! widest axis, leaves of 16 points and the tight bounding box of every node: a subtree is
//! entered only when its box is closer than the best distance so far. Queries a few sample
//! spacings off the other set's surface (scan points against mesh vertices) cross many split
//! planes but few tight boxes. Ties at exactly equal distance may come back in any order.

use std::borrow::Cow;
use std::sync::OnceLock;

use rayon::prelude::*;

use crate::numerics::PointGrid;
use crate::vec3::dist2;

/// Points a leaf of [`PointTree`] holds at most.
const LEAF_POINTS: usize = 16;

/// A node of [`PointTree`]: a split (children at `index + 1` and `right`) or a leaf (`axis` =
/// [`LEAF`], its points in block `start` of [`PointTree::blocks`]).
#[derive(Clone, Copy, Debug, PartialEq)]
struct KdNode {
    /// Tight bounding box of the node's points.
    lo: [f64; 3],
    hi: [f64; 3],
    split: f64,
    axis: u32,
    right: u32,
    start: u32,
}

/// `KdNode::axis` of a leaf.
const LEAF: u32 = 3;

/// The points of one leaf, coordinate by coordinate, so that a query computes the distances to
/// all of them at once (vector lanes); the unused slots hold +∞, whose distance is never below
/// any bound.
#[derive(Clone, Copy, Debug, PartialEq)]
struct LeafBlock {
    coords: [[f64; LEAF_POINTS]; 3],
    /// Index of each point in the input slice.
    items: [u32; LEAF_POINTS],
}

impl LeafBlock {
    /// Squared distances from `q` to the block's points ([`Self::dist2_lanes`]) and the mask of
    /// those below `bound` ([`Self::below`]).
    #[inline(always)]
    fn scan(&self, q: [f64; 3], bound: f64) -> ([f64; LEAF_POINTS], u32) {
        let d = self.dist2_lanes(q);
        (d, Self::below(&d, bound))
    }

    /// Squared distances from `q` to the block's points, each summed as [`dist2`] sums it.
    #[inline(always)]
    fn dist2_lanes(&self, q: [f64; 3]) -> [f64; LEAF_POINTS] {
        let mut d = [0.0; LEAF_POINTS];
        for (l, d) in d.iter_mut().enumerate() {
            let dx = self.coords[0][l] - q[0];
            let dy = self.coords[1][l] - q[1];
            let dz = self.coords[2][l] - q[2];
            *d = dx * dx + dy * dy + dz * dz;
        }
        d
    }

    /// Bit l set where `d[l] < bound`.
    #[inline(always)]
    fn below(d: &[f64; LEAF_POINTS], bound: f64) -> u32 {
        let mut mask = 0;
        for (l, &d) in d.iter().enumerate() {
            mask |= u32::from(d < bound) << l;
        }
        mask
    }
}

/// A k-d tree over 3D points for the nearest-point queries of this module and of
/// [`crate::distance`]: median splits on the widest axis, leaves of up to `LEAF_POINTS`
/// points stored as one block each, and queries that start from a radius (typically the
/// distance of a point known to be near, the previous query's answer) so the search prunes from
/// the start. Distances are squared Euclidean, summed as `dist2` does. Among points at exactly
/// equal distance the one met first in the tree's order wins; the results are otherwise those
/// of any exact nearest-neighbour search.
#[derive(Clone, Debug)]
pub struct PointTree {
    nodes: Vec<KdNode>,
    /// The leaves' points, one block per leaf in tree order.
    blocks: Vec<LeafBlock>,
}

impl PointTree {
    /// Indexes `points` (at most `u32::MAX` of them); `None` when there are none or too many.
    pub fn new(points: &[[f64; 3]]) -> Option<PointTree> {
        if points.is_empty() || points.len() > u32::MAX as usize {
            return None;
        }
        Some(PointTree::build(points))
    }

    /// [`PointTree::new`] for a count already checked (1 to `u32::MAX` points).
    fn build(points: &[[f64; 3]]) -> PointTree {
        // The points are reordered in place (contiguous, so the splits read memory in order).
        let mut entries: Vec<([f64; 3], u32)> = points
            .iter()
            .enumerate()
            .map(|(i, &p)| (p, i as u32))
            .collect();
        let (nodes, blocks) = build_subtree(&mut entries);
        PointTree { nodes, blocks }
    }

    /// The point of `q`'s nearest neighbour and its squared distance, among the points closer
    /// than √`radius2`; `None` when there is none.
    pub(crate) fn nearest_within(&self, q: [f64; 3], radius2: f64) -> Option<(f64, usize)> {
        let mut best = (radius2, u32::MAX);
        self.search_one(0, q, &mut best);
        (best.1 != u32::MAX).then_some((best.0, best.1 as usize))
    }

    /// The nearest point to `q`: squared distance and index.
    pub fn nearest(&self, q: [f64; 3]) -> (f64, usize) {
        self.nearest_within(q, f64::INFINITY)
            .unwrap_or((f64::INFINITY, 0))
    }

    fn search_one(&self, node: usize, q: [f64; 3], best: &mut (f64, u32)) {
        let n = &self.nodes[node];
        if n.axis == LEAF {
            let block = &self.blocks[n.start as usize];
            // The points in order, each against the best so far (which only falls).
            let (d, mut mask) = block.scan(q, best.0);
            while mask != 0 {
                let l = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                if d[l] < best.0 {
                    *best = (d[l], block.items[l]);
                }
            }
            return;
        }
        let (near, far) = self.children(node, n, q);
        if box_dist2(q, &self.nodes[near]) < best.0 {
            self.search_one(near, q, best);
        }
        if box_dist2(q, &self.nodes[far]) < best.0 {
            self.search_one(far, q, best);
        }
    }

    /// The child of split `n` (at `node`) on `q`'s side, then the other one.
    #[inline]
    fn children(&self, node: usize, n: &KdNode, q: [f64; 3]) -> (usize, usize) {
        if q[n.axis as usize] < n.split {
            (node + 1, n.right as usize)
        } else {
            (n.right as usize, node + 1)
        }
    }

    /// The up to `out.len()` nearest points to `q` closer than √`radius2`, nearest first, as
    /// (squared distance, index) into `out`; returns how many were found.
    pub(crate) fn nearest_n_within(
        &self,
        q: [f64; 3],
        radius2: f64,
        out: &mut [(f64, u32)],
    ) -> usize {
        let mut len = 0;
        if !out.is_empty() {
            self.search_n(0, q, radius2, out, &mut len);
        }
        len
    }

    fn search_n(
        &self,
        node: usize,
        q: [f64; 3],
        radius2: f64,
        out: &mut [(f64, u32)],
        len: &mut usize,
    ) {
        let k = out.len();
        let n = &self.nodes[node];
        if n.axis == LEAF {
            let block = &self.blocks[n.start as usize];
            // The points in order, each against the bound of the moment (which only falls).
            let (d, mut mask) = block.scan(q, if *len == k { out[k - 1].0 } else { radius2 });
            while mask != 0 {
                let l = mask.trailing_zeros() as usize;
                mask &= mask - 1;
                let d = d[l];
                let bound = if *len == k { out[k - 1].0 } else { radius2 };
                if d < bound {
                    insert_nearest(out, len, d, block.items[l]);
                }
            }
            return;
        }
        let (near, far) = self.children(node, n, q);
        for child in [near, far] {
            let bound = if *len == k { out[k - 1].0 } else { radius2 };
            if box_dist2(q, &self.nodes[child]) < bound {
                self.search_n(child, q, radius2, out, len);
            }
        }
    }
}

/// Inserts `(d, item)` among the first `*len` entries of `out` (nearest first), keeping the
/// `out.len()` nearest (`*len` grows until `out` is full); a tie goes after the entries already
/// held. The caller has checked `d` against its bound (the last entry's when `out` is full).
#[inline]
pub(crate) fn insert_nearest(out: &mut [(f64, u32)], len: &mut usize, d: f64, item: u32) {
    let k = out.len();
    let mut at = (*len).min(k - 1);
    if *len < k {
        *len += 1;
    }
    while at > 0 && out[at - 1].0 > d {
        out[at] = out[at - 1];
        at -= 1;
    }
    out[at] = (d, item);
}

/// Squared distance from `q` to the bounding box of `n`, summed as [`dist2`] sums: never more
/// than the squared distance to any point of the box as [`dist2`] rounds it (each term is a
/// rounded difference no larger than the point's), so a box at or beyond a bound holds no
/// point within it.
#[inline]
fn box_dist2(q: [f64; 3], n: &KdNode) -> f64 {
    let gap = |a: usize| {
        if q[a] < n.lo[a] {
            n.lo[a] - q[a]
        } else if q[a] > n.hi[a] {
            q[a] - n.hi[a]
        } else {
            0.0
        }
    };
    gap(0).powi(2) + gap(1).powi(2) + gap(2).powi(2)
}

/// Subtrees of more points than this are built in parallel by [`build_subtree`].
const PARALLEL_SUBTREE: usize = 1 << 16;

/// The nodes and leaf blocks of the tree over `entries`, laid out exactly as [`build_node`] lays
/// them out. Both arrays are sized once ([`tree_size`]: the shape depends on the count alone)
/// and the two halves of a large subtree fill their parts of them in parallel, so the tree does
/// not depend on the thread count and no part is copied twice.
fn build_subtree(entries: &mut [([f64; 3], u32)]) -> (Vec<KdNode>, Vec<LeafBlock>) {
    let (n_nodes, n_blocks) = tree_size(entries.len());
    let empty_node = KdNode {
        lo: [0.0; 3],
        hi: [0.0; 3],
        split: 0.0,
        axis: LEAF,
        right: 0,
        start: 0,
    };
    let empty_block = LeafBlock {
        coords: [[f64::INFINITY; LEAF_POINTS]; 3],
        items: [u32::MAX; LEAF_POINTS],
    };
    let mut nodes = vec![empty_node; n_nodes];
    let mut blocks = vec![empty_block; n_blocks];
    build_into(entries, &mut nodes, &mut blocks, 0, 0);
    (nodes, blocks)
}

/// How many nodes and leaf blocks the tree over `n` points has.
fn tree_size(n: usize) -> (usize, usize) {
    fn size(n: usize, memo: &mut Vec<(usize, (usize, usize))>) -> (usize, usize) {
        if n <= LEAF_POINTS {
            return (1, 1);
        }
        if let Some(&(_, s)) = memo.iter().find(|(m, _)| *m == n) {
            return s;
        }
        let (a, b) = (size(n / 2, memo), size(n - n / 2, memo));
        let s = (1 + a.0 + b.0, a.1 + b.1);
        memo.push((n, s));
        s
    }
    // Each level has at most two distinct counts, so the memo stays short.
    size(n, &mut Vec::new())
}

/// Fills `nodes` and `blocks` (exactly the subtree's size) with the subtree over `entries`,
/// whose first node and block have the indices `node_base` and `block_base` in the tree.
fn build_into(
    entries: &mut [([f64; 3], u32)],
    nodes: &mut [KdNode],
    blocks: &mut [LeafBlock],
    node_base: usize,
    block_base: usize,
) {
    if entries.len() <= PARALLEL_SUBTREE {
        let mut local_nodes = Vec::with_capacity(nodes.len());
        let mut local_blocks = Vec::with_capacity(blocks.len());
        build_node(entries, &mut local_nodes, &mut local_blocks);
        for (dst, node) in nodes.iter_mut().zip(local_nodes) {
            *dst = node;
            if node.axis != LEAF {
                dst.right += node_base as u32;
            }
            dst.start += block_base as u32;
        }
        blocks.copy_from_slice(&local_blocks);
        return;
    }
    let (lo, hi) = tight_box(entries);
    let (axis, split, mid) = median_split(entries, lo, hi);
    let (left_nodes_n, left_blocks_n) = tree_size(mid);
    nodes[0] = KdNode {
        lo,
        hi,
        split,
        axis: axis as u32,
        right: (node_base + 1 + left_nodes_n) as u32,
        start: block_base as u32,
    };
    let (left, right) = entries.split_at_mut(mid);
    let (left_nodes, right_nodes) = nodes[1..].split_at_mut(left_nodes_n);
    let (left_blocks, right_blocks) = blocks.split_at_mut(left_blocks_n);
    rayon::join(
        || build_into(left, left_nodes, left_blocks, node_base + 1, block_base),
        || {
            build_into(
                right,
                right_nodes,
                right_blocks,
                node_base + 1 + left_nodes_n,
                block_base + left_blocks_n,
            )
        },
    );
}

/// The tight box of `entries`' points.
fn tight_box(entries: &[([f64; 3], u32)]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for (p, _) in entries.iter() {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    (lo, hi)
}

/// Splits `entries` at the median of the box's widest axis (reordering them): the axis, the
/// split value and the index of the first entry of the right half.
fn median_split(
    entries: &mut [([f64; 3], u32)],
    lo: [f64; 3],
    hi: [f64; 3],
) -> (usize, f64, usize) {
    let axis = (0..3)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
        .unwrap_or(0);
    let mid = entries.len() / 2;
    entries.select_nth_unstable_by(mid, |a, b| a.0[axis].total_cmp(&b.0[axis]));
    (axis, entries[mid].0[axis], mid)
}

/// Builds the subtree over `entries` (points with their input indices, reordered in place) at
/// the end of `nodes`, and its leaves' blocks at the end of `blocks`.
fn build_node(
    entries: &mut [([f64; 3], u32)],
    nodes: &mut Vec<KdNode>,
    blocks: &mut Vec<LeafBlock>,
) {
    let at = nodes.len();
    let (lo, hi) = tight_box(entries);
    nodes.push(KdNode {
        lo,
        hi,
        split: 0.0,
        axis: LEAF,
        right: 0,
        start: blocks.len() as u32,
    });
    if entries.len() <= LEAF_POINTS {
        let mut block = LeafBlock {
            coords: [[f64::INFINITY; LEAF_POINTS]; 3],
            items: [u32::MAX; LEAF_POINTS],
        };
        for (l, (p, item)) in entries.iter().enumerate() {
            for (coords, &c) in block.coords.iter_mut().zip(p) {
                coords[l] = c;
            }
            block.items[l] = *item;
        }
        blocks.push(block);
        return;
    }
    let (axis, split, mid) = median_split(entries, lo, hi);
    let (left, right) = entries.split_at_mut(mid);
    build_node(left, nodes, blocks);
    let right_at = nodes.len();
    build_node(right, nodes, blocks);
    let node = &mut nodes[at];
    (node.split, node.axis, node.right) = (split, axis as u32, right_at as u32);
}

/// `query(i, hint)` for every point i of `points`, run in [`spatial_order`] in parallel chunks
/// of [`QUERY_CHUNK`]: each call gets the hint that the previous call of its chunk returned
/// (`None` first), which only bounds its search. Returns the values in input order, the same
/// whatever the thread count.
pub(crate) fn in_spatial_order<H: Copy + Send>(
    points: &[[f64; 3]],
    query: impl Fn(usize, Option<H>) -> (f64, Option<H>) + Sync,
) -> Vec<f64> {
    let order = spatial_order(points);
    let found: Vec<(u32, f64)> = order
        .par_chunks(QUERY_CHUNK)
        .flat_map_iter(|chunk| {
            let mut hint = None;
            let query = &query;
            chunk.iter().map(move |&i| {
                let (d, next) = query(i as usize, hint);
                hint = next;
                (i, d)
            })
        })
        .collect();
    let mut out = vec![0.0; points.len()];
    for (i, d) in found {
        out[i as usize] = d;
    }
    out
}

/// The indices of `points` sorted along a Z-order (Morton) curve over their bounding box, ties
/// by index: consecutive points of the order lie close together. Non-finite coordinates sort
/// as the box's minimum.
pub(crate) fn spatial_order(points: &[[f64; 3]]) -> Vec<u32> {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for a in 0..3 {
            if p[a].is_finite() {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
    }
    let scale = [0, 1, 2].map(|a| {
        let e = hi[a] - lo[a];
        if e > 0.0 {
            MORTON_MAX as f64 / e
        } else {
            0.0
        }
    });
    // Spreads the low 21 bits of v to every third bit.
    let spread = |v: u64| {
        let mut x = v & 0x1f_ffff;
        x = (x | (x << 32)) & 0x1f_0000_0000_ffff;
        x = (x | (x << 16)) & 0x1f_0000_ff00_00ff;
        x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
        x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
        (x | (x << 2)) & 0x1249_2492_4924_9249
    };
    let mut keyed: Vec<(u64, u32)> = points
        .iter()
        .enumerate()
        .map(|(i, p)| {
            // `as` saturates (NaN to 0), so every cell index is within 0 ..= 2^21 − 1.
            let cell = |a: usize| (((p[a] - lo[a]) * scale[a]) as u64).min(MORTON_MAX);
            (
                spread(cell(0)) | (spread(cell(1)) << 1) | (spread(cell(2)) << 2),
                i as u32,
            )
        })
        .collect();
    keyed.par_sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// The largest cell index of the Morton grid along each axis (2^21 cells, so three indices
/// fit in 63 bits); the box's extent maps onto 0 ..= MORTON_MAX.
const MORTON_MAX: u64 = (1 << 21) - 1;

/// Queries answered in order by one task, each search bounded by the previous answer; the
/// answers do not depend on the chunking or the thread count.
const QUERY_CHUNK: usize = 512;

/// The squared distance from `q` to the nearest point of `tree` and its index. `hint`, a point
/// of the tree near `q`, bounds the search: the nearest point is within its distance (the
/// radius is widened by 1e-9 relative so the hint itself is always inside), so the answer is
/// the same as an unbounded search's and only found sooner.
pub(crate) fn nearest_in(tree: &PointTree, q: [f64; 3], hint: Option<[f64; 3]>) -> (f64, usize) {
    if let Some(h) = hint
        && let Some(n) = tree.nearest_within(q, dist2(q, h) * (1.0 + 1e-9))
    {
        return n;
    }
    tree.nearest(q)
}

/// Distance from each of `queries` to the nearest of `points` (input units), by a
/// [`PointIndex`] of the finite points; a query with a non-finite coordinate gets NaN. Runs in
/// parallel; the result does not depend on the thread count. `None` when `points` holds no
/// finite point.
pub(crate) fn nearest_point_distances(
    queries: &[[f64; 3]],
    points: &[[f64; 3]],
) -> Option<Vec<f64>> {
    Some(PointIndex::new(points)?.distances(queries))
}

/// The finite points of a set, indexed once to answer every nearest-point query of the export
/// (the PLY's vertex quality, the mesh → data accuracy, the vertex colours).
///
/// Distances come from a uniform grid of the points (`numerics::PointGrid::for_nearest`: a
/// counting sort of the points into cells, far cheaper to build than a k-d tree over millions
/// of points); a query the grid does not settle within a few rings of cells, and every query
/// when the points are too clustered for one cell size, goes to the [`PointTree`], built the
/// first time it is needed. Both give the same distances (the minimum of the same squared
/// distances), so which one answers changes the time, never the result.
pub(crate) struct PointIndex<'a> {
    points: Cow<'a, [[f64; 3]]>,
    grid: Option<PointGrid>,
    tree: OnceLock<PointTree>,
}

impl<'a> PointIndex<'a> {
    /// Indexes the finite points of `points` (borrowed when all are finite); `None` when there
    /// is none, or more than `u32::MAX`.
    pub(crate) fn new(points: &'a [[f64; 3]]) -> Option<PointIndex<'a>> {
        let points: Cow<[[f64; 3]]> = if points.iter().all(is_finite) {
            points.into()
        } else {
            points.iter().copied().filter(is_finite).collect()
        };
        if points.is_empty() || points.len() > u32::MAX as usize {
            return None;
        }
        let grid = PointGrid::for_nearest(&points);
        let index = PointIndex {
            points,
            grid,
            tree: OnceLock::new(),
        };
        if index.grid.is_none() {
            index.tree();
        }
        Some(index)
    }

    /// The indexed (finite) points.
    pub(crate) fn points(&self) -> &[[f64; 3]] {
        &self.points
    }

    /// The k-d tree over [`PointIndex::points`] (its indices are positions in that slice),
    /// built on the first call.
    pub(crate) fn tree(&self) -> &PointTree {
        if let Some(tree) = self.tree.get() {
            return tree;
        }
        // Built outside the lock (the build runs in parallel, and a thread waiting for its
        // parallel parts may pick up another query of this index): two first calls at once may
        // both build it, the same tree, and the first one kept.
        let tree = PointTree::build(&self.points);
        self.tree.get_or_init(|| tree)
    }

    /// Distance from each of `queries` to the nearest indexed point (input units); a query
    /// with a non-finite coordinate gets NaN. Runs in parallel; the result does not depend on
    /// the thread count.
    pub(crate) fn distances(&self, queries: &[[f64; 3]]) -> Vec<f64> {
        let Some(grid) = &self.grid else {
            return self.tree_distances(queries);
        };
        // In spatial order for the cache; a query the grid leaves open gets -1 for now.
        let mut out = in_spatial_order(queries, |j, _: Option<()>| {
            let q = queries[j];
            if !is_finite(&q) {
                return (f64::NAN, None);
            }
            (grid.nearest2(q).map_or(-1.0, f64::sqrt), None)
        });
        // The queries far from every point (beyond the grid's rings), from the k-d tree.
        let open: Vec<usize> = (0..out.len()).filter(|&j| out[j] < 0.0).collect();
        if !open.is_empty() {
            let far: Vec<[f64; 3]> = open.iter().map(|&j| queries[j]).collect();
            for (j, d) in open.into_iter().zip(self.tree_distances(&far)) {
                out[j] = d;
            }
        }
        out
    }

    /// [`PointIndex::distances`] from the k-d tree alone.
    fn tree_distances(&self, queries: &[[f64; 3]]) -> Vec<f64> {
        let tree = self.tree();
        // Queried in spatial order, each query's answer bounds the next search (the distances
        // are the same as without it).
        in_spatial_order(queries, |j, hint| {
            let q = queries[j];
            if !is_finite(&q) {
                return (f64::NAN, hint);
            }
            let (d2, i) = nearest_in(tree, q, hint);
            (d2.sqrt(), Some(self.points[i]))
        })
    }
}

pub(crate) fn is_finite(p: &[f64; 3]) -> bool {
    p.iter().all(|c| c.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_parallel_tree_build_lays_out_the_serial_tree() {
        // 300,000 scattered points: four levels of parallel splits above the serial subtrees.
        let mut rng = crate::testing::study::Lcg::new(12345);
        let mut next = || rng.uniform();
        let entries: Vec<([f64; 3], u32)> = (0..300_000u32)
            .map(|i| ([next(), next() * 2.0, next() * 0.5], i))
            .collect();
        let (mut serial_nodes, mut serial_blocks) = (Vec::new(), Vec::new());
        build_node(&mut entries.clone(), &mut serial_nodes, &mut serial_blocks);
        let (nodes, blocks) = build_subtree(&mut entries.clone());
        assert!(nodes == serial_nodes && blocks == serial_blocks);
    }

    #[test]
    fn spatially_ordered_queries_match_brute_force() {
        // Queries in an interleaved order (as scans store them) and one that is not finite:
        // the answers come back in input order, equal to a brute-force search's.
        let points: Vec<[f64; 3]> = (0..500)
            .map(|i| {
                let t = i as f64 * 0.11;
                [t.sin() * 2.0, (1.3 * t).cos(), (i % 13) as f64 * 0.1]
            })
            .collect();
        let mut queries: Vec<[f64; 3]> = (0..1200)
            .map(|j| {
                let s = ((j * 7) % 1200) as f64 * 0.017;
                [
                    2.2 * s.cos(),
                    1.1 * (0.8 * s).sin(),
                    (j % 5) as f64 * 0.3 - 0.2,
                ]
            })
            .collect();
        queries[17] = [f64::NAN, 0.0, 0.0];
        let order = spatial_order(&queries);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert!(sorted.iter().enumerate().all(|(i, &j)| j as usize == i));
        let d = nearest_point_distances(&queries, &points).unwrap();
        assert!(d[17].is_nan());
        for (j, q) in queries.iter().enumerate().filter(|(j, _)| *j != 17) {
            let brute = points
                .iter()
                .map(|p| dist2(*q, *p))
                .fold(f64::INFINITY, f64::min);
            assert_eq!(d[j], brute.sqrt());
        }
    }

    #[test]
    fn index_distances_match_brute_force_near_far_and_on_clustered_points() {
        // A ring of points, and queries near it, far beyond the grid's rings (the k-d tree
        // answers those) and not finite; then a clump too dense for the grid (the tree alone).
        let ring: Vec<[f64; 3]> = (0..3000)
            .map(|i| {
                let t = i as f64 * 0.0021;
                [t.cos(), t.sin(), 0.01 * (i % 5) as f64]
            })
            .collect();
        let mut clump: Vec<[f64; 3]> = (0..3000)
            .map(|i| [1e-9 * (i % 10) as f64, 0.0, 0.0])
            .collect();
        clump.extend([[1.0, 1.0, 1.0], [-1.0, 0.0, 2.0]]);
        for points in [&ring, &clump] {
            let mut queries: Vec<[f64; 3]> = (0..400)
                .map(|j| {
                    let s = j as f64 * 0.37;
                    let r = if j % 3 == 0 { 50.0 } else { 1.05 };
                    [r * s.cos(), r * s.sin(), 0.02 * (j % 7) as f64]
                })
                .collect();
            queries.push([f64::NAN, 0.0, 0.0]);
            let index = PointIndex::new(points).unwrap();
            let d = index.distances(&queries);
            assert!(d[400].is_nan());
            for (q, d) in queries.iter().zip(&d).take(400) {
                let brute = points
                    .iter()
                    .map(|p| dist2(*q, *p))
                    .fold(f64::INFINITY, f64::min);
                assert_eq!(d.to_bits(), brute.sqrt().to_bits());
            }
            assert_eq!(index.tree().nearest(queries[1]).0.sqrt(), d[1]);
        }
        assert!(
            PointGrid::for_nearest(&ring).is_some() && PointGrid::for_nearest(&clump).is_none()
        );
    }

    #[test]
    fn point_tree_matches_brute_force() {
        // A spiral with repeated coordinates on one axis, queries inside and outside it.
        let points: Vec<[f64; 3]> = (0..700)
            .map(|i| {
                let t = i as f64 * 0.05;
                [t.cos() * (1.0 + 0.1 * t), t.sin(), (i % 7) as f64 * 0.25]
            })
            .collect();
        let tree = PointTree::new(&points).unwrap();
        for j in 0..200 {
            let s = j as f64 * 0.173;
            let q = [
                2.5 * s.sin(),
                1.7 * (0.7 * s).cos(),
                (j % 11) as f64 * 0.2 - 0.3,
            ];
            let mut brute: Vec<(f64, u32)> = points
                .iter()
                .enumerate()
                .map(|(i, p)| (dist2(q, *p), i as u32))
                .collect();
            brute.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let (d2, i) = tree.nearest(q);
            assert_eq!(d2, brute[0].0);
            assert_eq!(dist2(q, points[i]), d2);
            // A radius just above the 5th nearest distance holds exactly the 5 nearest.
            let radius2 = brute[4].0 * (1.0 + 1e-9);
            let mut out = [(0.0, 0u32); 8];
            let n = tree.nearest_n_within(q, radius2, &mut out);
            assert_eq!(n, 5);
            for (got, want) in out[..n].iter().zip(&brute) {
                assert_eq!(got.0, want.0);
            }
            let n = tree.nearest_n_within(q, f64::INFINITY, &mut out[..3]);
            assert_eq!(n, 3);
            assert!(out[..3].iter().zip(&brute).all(|(g, w)| g.0 == w.0));
            assert_eq!(tree.nearest_within(q, brute[0].0), None);
            assert_eq!(tree.nearest_within(q, radius2).map(|n| n.0), Some(d2));
        }
        assert!(PointTree::new(&[]).is_none());
    }
}

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn nearest_point_distances() {
        use crate::point_tree::nearest_point_distances;
        let d = nearest_point_distances(&[[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]], &[[0.0, 0.0, 1.0]])
            .unwrap();
        assert_eq!(d, vec![1.0, 26f64.sqrt()]);
    }
}
