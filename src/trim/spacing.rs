//! Step 1 of the trim: the local spacing of the data at the points that need it, the median over
//! a point and its k nearest neighbours of each one's distance to its nearest non-coincident
//! neighbour.
//!
//! Input: the data points, their bucket grid and the points wanted. Output: one spacing per
//! wanted point, in input units.

use rayon::prelude::*;

use crate::numerics::point_grid::first_positive_distance;
use crate::numerics::PointGrid;

/// The local spacing at each of the points `at` (indices into `points`, in any order, repeats
/// allowed), in their order: [`local_spacing`] once per distinct point.
pub(super) fn spacing_at(
    grid: &PointGrid,
    points: &[[f64; 3]],
    k: usize,
    at: impl Iterator<Item = usize> + Clone,
) -> Vec<f64> {
    let mut wanted: Vec<u32> = at.clone().map(|j| j as u32).collect();
    wanted.sort_unstable();
    wanted.dedup();
    let spacing = local_spacing(grid, points, k, &wanted);
    at.map(|j| spacing[wanted.binary_search(&(j as u32)).unwrap_or(0)])
        .collect()
}

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
    // neighbours coincide with it), for the wanted points and their neighbours. A wanted
    // point's is the first entry of its own row at a positive distance (the rows are sorted by
    // distance, the same sums as the search's); the other points are searched for it.
    let own: Vec<f64> = wanted
        .par_iter()
        .enumerate()
        .map(|(r, &i)| {
            first_positive_distance(points, points[i as usize], neighbours.row(r)).unwrap_or(0.0)
        })
        .collect();
    let mut others: Vec<u32> = neighbours
        .flat()
        .iter()
        .copied()
        .filter(|j| wanted.binary_search(j).is_err())
        .collect();
    others.sort_unstable();
    others.dedup();
    let others_nearest: Vec<f64> = grid
        .nearest_positive_of(points, &others, k)
        .into_iter()
        .map(|d| d.unwrap_or(0.0))
        .collect();
    let nearest_of = |j: u32| match wanted.binary_search(&j) {
        Ok(r) => own[r],
        Err(_) => others_nearest[others.binary_search(&j).unwrap_or(0)],
    };
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
