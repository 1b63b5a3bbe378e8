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

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use crate::normals::vec3::{dot, norm, scale, sub};

/// Symmetric neighbour graph in compressed rows: `(neighbour, penalty)` per entry.
struct Graph {
    start: Vec<usize>,
    entries: Vec<(u32, f64)>,
}

fn build_graph(n: usize, triangles: &[[u32; 3]], knn: &[Vec<u32>]) -> Graph {
    let knn_penalty = u32::from(!triangles.is_empty());
    // Who names whom: the triangles at each point, and the points whose k-nearest lists hold
    // it, in compressed rows.
    let (tri_start, tri_rows) = rows_by_point(
        n,
        triangles.iter().enumerate().flat_map(|(t, tri)| {
            tri.iter()
                .filter(|&&v| (v as usize) < n)
                .map(move |&v| (v, t as u32))
        }),
    );
    let (named_start, named_by) = rows_by_point(
        n,
        knn.iter().enumerate().flat_map(|(i, list)| {
            list.iter()
                .filter(move |&&j| j as usize != i && (j as usize) < n)
                .map(move |&j| (j, i as u32))
        }),
    );
    // Each point's row: its crust neighbours (penalty 0), its k nearest and the points that
    // count it among theirs (penalty 1 when there is a crust), each neighbour once with its
    // smallest penalty. The rows are independent, so they are built in parallel; the order
    // inside a row does not matter to the spanning tree (see `orient_consistently`).
    // Per block of points: the entries of its rows, and each row's length.
    type Block = (Vec<(u32, f64)>, Vec<usize>);
    const BLOCK: usize = 4096;
    let rows: Vec<Block> = (0..n.div_ceil(BLOCK))
        .into_par_iter()
        .map(|b| {
            let block = b * BLOCK..((b + 1) * BLOCK).min(n);
            let mut entries = Vec::new();
            let mut lengths = Vec::with_capacity(block.len());
            let mut row: Vec<(u32, u32)> = Vec::new();
            for v in block {
                row.clear();
                for &t in &tri_rows[tri_start[v]..tri_start[v + 1]] {
                    let tri = triangles[t as usize];
                    for k in 0..3 {
                        let (a, b) = (tri[k] as usize, tri[(k + 1) % 3] as usize);
                        if a == b || a >= n || b >= n {
                            continue;
                        }
                        if a == v {
                            row.push((b as u32, 0));
                        } else if b == v {
                            row.push((a as u32, 0));
                        }
                    }
                }
                for &j in knn[v]
                    .iter()
                    .chain(&named_by[named_start[v]..named_start[v + 1]])
                {
                    if j as usize != v && (j as usize) < n {
                        row.push((j, knn_penalty));
                    }
                }
                row.sort_unstable();
                row.dedup_by_key(|e| e.0);
                entries.extend(row.iter().map(|&(j, p)| (j, f64::from(p))));
                lengths.push(row.len());
            }
            (entries, lengths)
        })
        .collect();
    let mut start = Vec::with_capacity(n + 1);
    start.push(0);
    let mut entries = Vec::with_capacity(rows.iter().map(|r| r.0.len()).sum());
    for (block, lengths) in rows {
        for length in lengths {
            start.push(start.last().copied().unwrap_or(0) + length);
        }
        entries.extend(block);
    }
    Graph { start, entries }
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

impl Graph {
    fn neighbours(&self, i: usize) -> &[(u32, f64)] {
        &self.entries[self.start[i]..self.start[i + 1]]
    }
}

/// Makes the signs of `normals` consistent along a minimum spanning tree of the neighbour graph.
/// Returns the connected pieces as a label per point.
pub fn orient_consistently(
    points: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    triangles: &[[u32; 3]],
    knn: &[Vec<u32>],
) -> Vec<u32> {
    let n = points.len();
    let graph = build_graph(n, triangles, knn);
    // Edge weights do not depend on the signs (|nᵢ·nⱼ|), so they are computed up front, in
    // parallel, with the same arithmetic as at the time of the push. Non-negative f64 order
    // equals the order of their bit patterns.
    let weights: Vec<u64> = (0..n)
        .into_par_iter()
        .flat_map_iter(|i| {
            let normals = &*normals;
            graph.neighbours(i).iter().map(move |&(j, penalty)| {
                let w = penalty + 1.0 - dot(&normals[i], &normals[j as usize]).abs().min(1.0);
                w.max(0.0).to_bits()
            })
        })
        .collect();
    let mut label = vec![u32::MAX; n];
    // The smallest (weight, from) pushed so far for each point: a push that does not improve
    // on it would only be popped after that one and skipped, so it is left out. The popped
    // sequence, hence the tree, is the same as with every push. Whether a neighbour j of the
    // popped point is pushed depends on j's entry alone, and the heap orders by (weight, j,
    // from), all distinct: the order of a row's entries changes nothing.
    let mut best: Vec<(u64, u32)> = vec![(u64::MAX, u32::MAX); n];
    let mut heap: BinaryHeap<Reverse<(u64, u32, u32)>> = BinaryHeap::new();
    let mut n_pieces = 0u32;
    for root in 0..n {
        if label[root] != u32::MAX {
            continue;
        }
        heap.clear();
        heap.push(Reverse((0, root as u32, root as u32)));
        while let Some(Reverse((_, to, from))) = heap.pop() {
            let to = to as usize;
            if label[to] != u32::MAX {
                continue;
            }
            label[to] = n_pieces;
            if dot(&normals[to], &normals[from as usize]) < 0.0 {
                normals[to] = scale(&normals[to], -1.0);
            }
            let row = graph.start[to]..graph.start[to + 1];
            for (&(j, _), &w) in graph.entries[row.clone()].iter().zip(&weights[row]) {
                let candidate = (w, to as u32);
                if label[j as usize] == u32::MAX && candidate < best[j as usize] {
                    best[j as usize] = candidate;
                    heap.push(Reverse((w, j, to as u32)));
                }
            }
        }
        n_pieces += 1;
    }
    label
}

/// Turns each connected piece (`label` from [`orient_consistently`]) outward by the
/// farthest-points vote. Returns the number of pieces flipped.
pub fn orient_outward_pieces(
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
pub fn orient_outward(
    points: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    triangles: &[[u32; 3]],
    knn: &[Vec<u32>],
) {
    let label = orient_consistently(points, normals, triangles, knn);
    orient_outward_pieces(points, normals, &label);
}
