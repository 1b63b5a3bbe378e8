//! The connected pieces of the data that rule (c) of the stable κ rule compares the zero set
//! with: the components of the graph joining data points closer than 0.2 (normalized units)
//! among their 12 nearest neighbours, on a fixed-stride subset of at most 20,000 points.
//!
//! Input: the oriented cloud and the fit's normalization. Output: [`DataPieces`], the subset's
//! k-d tree ([`PointTree`], the crate's one nearest-point index) and a piece label per point, labels numbered in order of first appearance, which do
//! not depend on the thread count.

use rayon::prelude::*;

use super::{MAX_CHECK_POINTS, NEAR_DATA};
use crate::cloud::OrientedCloud;
use crate::fit::system::Normalization;
use crate::numerics::point_tree::PointTree;
use crate::numerics::UnionFind;

/// How many nearest neighbours each point is joined to (within [`NEAR_DATA`]).
const NEIGHBOURS: usize = 12;

/// The data in normalized coordinates (a fixed-stride subset), its k-d tree and its pieces.
pub(super) struct DataPieces {
    pub(super) tree: PointTree,
    /// Piece label per indexed point.
    pub(super) labels: Vec<u32>,
    pub(super) n_pieces: usize,
}

impl DataPieces {
    pub(super) fn new(cloud: &OrientedCloud, norm: &Normalization) -> Option<DataPieces> {
        let stride = cloud.points.len().div_ceil(MAX_CHECK_POINTS).max(1);
        let points: Vec<[f64; 3]> = cloud
            .points
            .iter()
            .step_by(stride)
            .map(|p| norm.apply(*p))
            .collect();
        let tree = PointTree::new(&points)?;
        let mut sets = UnionFind::new(points.len());
        // The 12 nearest neighbours within NEAR_DATA, searched in parallel (the radius bound
        // prunes the search); the union-find pass is sequential. The components do not depend
        // on the order of the unions.
        let near: Vec<Vec<u32>> = points
            .par_iter()
            .map(|p| {
                let mut nearest = [(0.0, 0_u32); NEIGHBOURS];
                // Within the radius and a hair beyond, so a neighbour at exactly NEAR_DATA joins.
                let radius2 = (NEAR_DATA * NEAR_DATA).next_up();
                let n = tree.nearest_n_within(*p, radius2, &mut nearest);
                nearest[..n].iter().map(|&(_, i)| i).collect()
            })
            .collect();
        for (i, neighbours) in near.iter().enumerate() {
            for &item in neighbours {
                sets.union(i as u32, item);
            }
        }
        let (labels, n_pieces) = compact_labels(&mut sets);
        Some(DataPieces {
            tree,
            labels,
            n_pieces,
        })
    }

    /// Distance from `q` to the nearest data point and that point's piece.
    pub(super) fn nearest(&self, q: [f64; 3]) -> (f64, u32) {
        let (d2, i) = self.tree.nearest(q);
        let label = self.labels.get(i).copied().unwrap_or(0);
        (d2.sqrt(), label)
    }
}

/// Labels 0.. in order of first appearance, and their count.
pub(super) fn compact_labels(sets: &mut UnionFind) -> (Vec<u32>, usize) {
    let mut map = std::collections::HashMap::new();
    let mut labels = Vec::with_capacity(sets.len());
    for i in 0..sets.len() as u32 {
        let root = sets.find(i);
        let next = map.len() as u32;
        labels.push(*map.entry(root).or_insert(next));
    }
    (labels, map.len())
}
