//! Step 1 of the trim: the local spacing of the data at the points that need it, the median over
//! a point and its k nearest neighbours of each one's distance to its nearest non-coincident
//! neighbour.
//!
//! Input: the data points, their bucket grid and the points wanted. Output: one spacing per
//! wanted point, in input units, and on request its reach (the distance to its k-th nearest
//! neighbour, step 6's measure of a hole's depth).

use rayon::prelude::*;

use crate::numerics::point_grid::first_positive_distance;
use crate::numerics::PointGrid;
use crate::vec3::{norm, sub};

/// The local spacing at each of the points `at` (indices into `points`, in any order, repeats
/// allowed), in their order: [`local_spacing`] once per distinct point.
pub(super) fn spacing_at(
    grid: &PointGrid,
    points: &[[f64; 3]],
    k: usize,
    at: impl Iterator<Item = usize> + Clone,
) -> Vec<f64> {
    spacing_and_reach_at(grid, points, k, at)
        .into_iter()
        .map(|(s, _)| s)
        .collect()
}

/// As [`spacing_at`], each with the point's *reach*: its distance to its k-th nearest
/// neighbour. The reach is the steadier measure of the density on randomly placed samples,
/// where nearest-neighbour distances scatter widely (a median of 9 of them can be a fraction
/// of the typical one), so a depth in reaches tells a hole from a gap between samples: points
/// spread at random with that density put about 4k of them in a disk of radius 2 reaches, and
/// none with probability about e^(−4k) (e^(−32) for k = 8).
pub(super) fn spacing_and_reach_at(
    grid: &PointGrid,
    points: &[[f64; 3]],
    k: usize,
    at: impl Iterator<Item = usize> + Clone,
) -> Vec<(f64, f64)> {
    // The distinct points in their first-seen order, and each one's row in that list.
    let mut row_of = vec![u32::MAX; points.len()];
    let mut wanted: Vec<u32> = Vec::new();
    for j in at.clone() {
        if row_of[j] == u32::MAX {
            row_of[j] = wanted.len() as u32;
            wanted.push(j as u32);
        }
    }
    let spacing = local_spacing(grid, points, k, &wanted);
    at.map(|j| spacing[row_of[j] as usize]).collect()
}

/// The local spacing (step 1 of the module docs) and the reach (see [`spacing_and_reach_at`])
/// at each of the points `wanted` (indices into `points`, distinct, in any order), in their order.
pub(super) fn local_spacing(
    grid: &PointGrid,
    points: &[[f64; 3]],
    k: usize,
    wanted: &[u32],
) -> Vec<(f64, f64)> {
    let k = k.min(points.len().saturating_sub(1));
    if k == 0 {
        return vec![(0.0, 0.0); wanted.len()];
    }
    let neighbours = grid.nearest_of(points, wanted, k);
    // Each point's distance to its nearest neighbour at a positive distance (0 when all its k
    // neighbours coincide with it), for the wanted points and their neighbours, in a table by
    // point (NaN: not needed). A wanted point's is the first entry of its own row at a positive
    // distance (the rows are sorted by distance, the same sums as the search's); the other
    // points are searched for it.
    let own: Vec<f64> = wanted
        .par_iter()
        .enumerate()
        .map(|(r, &i)| {
            first_positive_distance(points, points[i as usize], neighbours.row(r)).unwrap_or(0.0)
        })
        .collect();
    let mut nearest = vec![f64::NAN; points.len()];
    for (&i, &d) in wanted.iter().zip(&own) {
        nearest[i as usize] = d;
    }
    drop(own);
    // The neighbours not wanted, each once (marked by an infinite entry until searched).
    let mut others: Vec<u32> = Vec::new();
    for &j in neighbours.flat() {
        if nearest[j as usize].is_nan() {
            nearest[j as usize] = f64::INFINITY;
            others.push(j);
        }
    }
    for (&j, d) in others
        .iter()
        .zip(grid.nearest_positive_of(points, &others, k))
    {
        nearest[j as usize] = d.unwrap_or(0.0);
    }
    wanted
        .par_iter()
        .enumerate()
        .map_init(Vec::new, |values, (r, &i)| {
            let row = neighbours.row(r);
            values.clear();
            values.push(nearest[i as usize]);
            values.extend(row.iter().map(|&j| nearest[j as usize]));
            values.sort_unstable_by(f64::total_cmp);
            let reach = row
                .last()
                .map_or(0.0, |&j| norm(sub(points[i as usize], points[j as usize])));
            (values[values.len() / 2], reach)
        })
        .collect()
}
