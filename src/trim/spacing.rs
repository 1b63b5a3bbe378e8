//! Step 1 of the trim: the local spacing of the data at the points that need it, the median over
//! a point and its k nearest neighbours of each one's distance to its nearest non-coincident
//! neighbour.
//!
//! Input: the data points, their bucket grid and the points wanted. Output: one spacing per
//! wanted point, in input units.

use rayon::prelude::*;

use crate::numerics::PointGrid;

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
    // The first neighbour at a positive distance among the k nearest (sorted by distance) is
    // at the smallest positive distance unless k or more other points coincide with the point
    // (then 0).
    let nearest: Vec<f64> = grid
        .nearest_positive_of(points, &around, k)
        .into_iter()
        .map(|d| d.unwrap_or(0.0))
        .collect();
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
