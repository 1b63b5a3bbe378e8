//! Step 1 of the trim: the local spacing of the data at the points that need it, the median over
//! a point and its k nearest neighbours of each one's distance to its nearest non-coincident
//! neighbour.
//!
//! Input: the data points, their bucket grid and the points wanted. Output: one spacing per
//! wanted point, in input units.

use rayon::prelude::*;

use crate::numerics::PointGrid;
use crate::vec3::{norm, sub};

/// The local spacing (step 1 of the module docs) at each of the points `wanted` (indices into
/// `points`, sorted, distinct), in their order.
pub(super) fn local_spacing(
    grid: &PointGrid,
    points: &[[f64; 3]],
    k: usize,
    wanted: &[u32],
) -> Vec<f64> {
    let k = k.min(points.len().saturating_sub(1));
    if k == 0 {
        return vec![0.0; wanted.len()];
    }
    let neighbours = grid.nearest_of(points, wanted, k);
    // Each point's distance to its nearest neighbour at a positive distance (0 when all its k
    // neighbours coincide with it), for the wanted points and their neighbours.
    let mut around: Vec<u32> = wanted
        .iter()
        .copied()
        .chain(neighbours.flat().iter().copied())
        .collect();
    around.sort_unstable();
    around.dedup();
    let dist = |i: usize, j: u32| norm(sub(points[i], points[j as usize]));
    // The first neighbour at a positive distance among the k nearest (sorted by distance) is
    // at the smallest positive distance, so the nearest neighbour alone answers unless it
    // coincides with the point; only those points ask for all k (the same values, at a
    // fraction of the cost: most of `around` is the wanted points' neighbours).
    let first = grid.nearest_of(points, &around, 1);
    let mut nearest: Vec<f64> = around
        .par_iter()
        .enumerate()
        .map(|(r, &i)| first.row(r).first().map_or(0.0, |&j| dist(i as usize, j)))
        .collect();
    if k > 1 {
        let coincident: Vec<u32> = (0..around.len() as u32)
            .filter(|&r| nearest[r as usize] == 0.0)
            .collect();
        let of: Vec<u32> = coincident.iter().map(|&r| around[r as usize]).collect();
        let all = grid.nearest_of(points, &of, k);
        for (row, &r) in coincident.iter().enumerate() {
            let i = around[r as usize] as usize;
            nearest[r as usize] = all
                .row(row)
                .iter()
                .map(|&j| dist(i, j))
                .find(|&d| d > 0.0)
                .unwrap_or(0.0);
        }
    }
    let nearest_of = |j: u32| nearest[around.binary_search(&j).unwrap_or(0)];
    wanted
        .par_iter()
        .enumerate()
        .map(|(r, &i)| {
            let mut values: Vec<f64> = std::iter::once(nearest_of(i))
                .chain(neighbours.row(r).iter().map(|&j| nearest_of(j)))
                .collect();
            values.sort_unstable_by(f64::total_cmp);
            values[values.len() / 2]
        })
        .collect()
}
