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
    let mut edges: Vec<(u32, u32, u8)> = Vec::new();
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if a != b && (a as usize) < n && (b as usize) < n {
                edges.push((a.min(b), a.max(b), 0));
            }
        }
    }
    let penalty = if triangles.is_empty() { 0 } else { 1 };
    for (i, list) in knn.iter().enumerate() {
        for &j in list {
            if j as usize != i && (j as usize) < n {
                edges.push(((i as u32).min(j), (i as u32).max(j), penalty));
            }
        }
    }
    // Sorted by (a, b, penalty): a counting sort by a, then each point's short list sorted by
    // (b, penalty). The order of the tuples is total, so this is the order a full sort gives.
    let mut bucket = vec![0usize; n + 1];
    for e in &edges {
        bucket[e.0 as usize + 1] += 1;
    }
    for i in 0..n {
        bucket[i + 1] += bucket[i];
    }
    let mut fill = bucket.clone();
    let mut rest = vec![(0u32, 0u8); edges.len()];
    for e in &edges {
        rest[fill[e.0 as usize]] = (e.1, e.2);
        fill[e.0 as usize] += 1;
    }
    edges.clear();
    for a in 0..n {
        let row = &mut rest[bucket[a]..bucket[a + 1]];
        row.sort_unstable();
        edges.extend(row.iter().map(|&(b, p)| (a as u32, b, p)));
    }
    // Keep the smallest penalty of each pair.
    edges.dedup_by(|a, b| a.0 == b.0 && a.1 == b.1);
    let mut count = vec![0usize; n + 1];
    for e in &edges {
        count[e.0 as usize + 1] += 1;
        count[e.1 as usize + 1] += 1;
    }
    for i in 0..n {
        count[i + 1] += count[i];
    }
    let mut fill = count.clone();
    let mut entries = vec![(0u32, 0.0); count[n]];
    for e in &edges {
        entries[fill[e.0 as usize]] = (e.1, f64::from(e.2));
        fill[e.0 as usize] += 1;
        entries[fill[e.1 as usize]] = (e.0, f64::from(e.2));
        fill[e.1 as usize] += 1;
    }
    Graph {
        start: count,
        entries,
    }
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
    // sequence, hence the tree, is the same as with every push.
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
