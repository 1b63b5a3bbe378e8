//! Noisy data: the signs of the normals checked against the empty space around the points,
//! before the detail fit (see [`super::DetailParams::noise`]).
//!
//! Input: the points, their unit normals and the noise σ (input units). Output: the normals
//! with some signs flipped, and how many.
//!
//! Why: where a part is only a few σ thick (a beak, a thin limb), the plane fits behind noisy
//! normals span both of its sides, and the propagation of their signs (a spanning tree over
//! neighbours) crosses from one side to the other: a whole patch at the part's tip comes out
//! pointing inward, consistently enough that no local test sees it. Its 3L rows and its
//! auxiliary rows then ask for "inside" beyond the tip, and the local quadrics carry that out
//! into empty space: a tube of inside that runs from the tip to the meshing box, cut open
//! there (and trimmed open near the data), with handles where it meets the part. The fit's
//! other safeguards (the robust refit, the second fit along the first blend's gradient) follow
//! the patch, since its normals agree among themselves.
//!
//! Method: the space around a closed object is connected to the far field, the space inside it
//! is not. On a lattice of cells σ wide (coarser when the points' box would need more than
//! [`MAX_CELLS`]), the cells within a barrier radius of a point form a barrier: [`BARRIER`]·σ,
//! or the [`sampling_gap`] where the samples lie farther apart than that, so that the barrier
//! has no holes. The free cells that a flood from the lattice's border reaches are the
//! exterior. Along each point's normal line, out to the barrier radius and [`REACH`]·σ more
//! either way, the first exterior cell is sought; a normal whose own side reaches no exterior
//! cell, or reaches one farther than the opposite side does, is flipped to point to the nearer
//! exterior. A line that reaches no exterior cell on its other side (deep in a thick part, or
//! along a tangent) is left alone.
//!
//! Where the points do not enclose anything (a single view, a scan with an unseen side, holes
//! wider than the barrier), the flood reaches the free cells on both sides of the points and
//! no normal is turned: enclosed free cells under [`ENCLOSED_SHARE`] of the barrier's say so.
//! Across a part thinner than a few σ, a point the
//! noise moved past the part's middle is oriented by the side it lies nearer (a share
//! Φ(−t/2σ) of the points where the part is t thick), and a gap narrower than about twice the
//! barrier radius (a groove, a tunnel) is closed by the barrier, so that the normals facing
//! into it may turn: both below the scale the noise lets the fit resolve.
//!
//! Deterministic: the lattice and the flood are sequential, the per-point search is a
//! parallel map of independent values.

use std::collections::VecDeque;

use rayon::prelude::*;

use crate::numerics::point_tree::PointTree;

/// Cells within this many σ of a data point are barrier.
pub(crate) const BARRIER: f64 = 2.0;

/// How far along each normal line, either way, the exterior is sought: the barrier's radius
/// and this many σ more (past the barrier on the near side of a point up to 3σ off its
/// surface, and across a part a few σ thick).
pub(crate) const REACH: f64 = 8.0;

/// Most lattice cells (one byte each); above, the cells are made wider than σ.
pub(crate) const MAX_CELLS: f64 = 16_777_216.0;

/// The enclosed volume, as a share of the barrier's, below which the points are taken to
/// enclose nothing (an open scan, whose few enclosed cells are pockets in its noisy barrier).
pub(crate) const ENCLOSED_SHARE: f64 = 0.01;

const FREE: u8 = 0;
const WALL: u8 = 1;
const OUTSIDE: u8 = 2;

/// The neighbour whose distance [`sampling_gap`] measures.
pub(crate) const GAP_NEIGHBOURS: usize = 16;

/// The median, over at most about 4096 evenly strided points, of the distance from a point
/// to its [`GAP_NEIGHBOURS`]-th nearest neighbour. On a surface sampled at random with
/// density ρ, that distance is about √(16/(πρ)), while the widest empty disk among n samples
/// has a radius of about √(ln n/(πρ)), smaller for n below e¹⁶: balls of this radius around
/// the points close the sampling's gaps.
pub(crate) fn sampling_gap(points: &[[f64; 3]], tree: &PointTree) -> f64 {
    let stride = (points.len() / 4096).max(1);
    let mut found: Vec<f64> = points
        .par_iter()
        .step_by(stride)
        .filter_map(|&p| {
            let mut near = [(0.0, 0u32); GAP_NEIGHBOURS + 1];
            let k = tree.nearest_n_within(p, f64::INFINITY, &mut near);
            (k == near.len()).then(|| near[k - 1].0.sqrt())
        })
        .collect();
    if found.is_empty() {
        return 0.0;
    }
    found.sort_unstable_by(f64::total_cmp);
    found[found.len() / 2]
}

/// Flips the normals that point away from the nearer exterior along their line (see the
/// module docs); returns how many. The barrier's radius is [`BARRIER`]·σ or `gap` (the
/// [`sampling_gap`]), whichever is larger. Nothing changes when `sigma` is not positive and
/// finite or there are no points.
pub(crate) fn orient_by_exterior(
    points: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    sigma: f64,
    gap: f64,
) -> usize {
    if !(sigma > 0.0 && sigma.is_finite()) || points.is_empty() {
        return 0;
    }
    let barrier = (BARRIER * sigma).max(if gap.is_finite() { gap } else { 0.0 });
    let Some(lattice) = Lattice::new(points, sigma, barrier) else {
        return 0;
    };
    // Points that enclose no volume (an open scan: its unseen side joins inside to outside)
    // give no inside to tell from the outside, and a rule by the nearer side would turn the
    // normals of the points the noise moved to the inner half of the barrier: nothing changes.
    let (walls, enclosed) = lattice.counts();
    if (enclosed as f64) < ENCLOSED_SHARE * walls as f64 {
        return 0;
    }
    let reach = barrier + REACH * sigma;
    // Half a cell per step: no cell is skipped along the line.
    let step = 0.5 * lattice.cell;
    let steps = (reach / step).ceil() as usize;
    let flips: Vec<bool> = points
        .par_iter()
        .zip(normals.par_iter())
        .map(|(p, n)| {
            let first = |sign: f64| {
                (1..=steps).find(|&k| {
                    let t = sign * step * k as f64;
                    lattice.state([p[0] + t * n[0], p[1] + t * n[1], p[2] + t * n[2]]) == OUTSIDE
                })
            };
            match (first(1.0), first(-1.0)) {
                (_, None) => false,
                (None, Some(_)) => true,
                (Some(own), Some(other)) => other < own,
            }
        })
        .collect();
    let mut flipped = 0;
    for (n, flip) in normals.iter_mut().zip(flips) {
        if flip {
            *n = n.map(|c| -c);
            flipped += 1;
        }
    }
    flipped
}

/// The barrier and the flooded exterior on a regular lattice over the points' box, padded
/// so that its border lies beyond the barrier and the reach.
struct Lattice {
    origin: [f64; 3],
    cell: f64,
    dims: [usize; 3],
    state: Vec<u8>,
}

impl Lattice {
    fn new(points: &[[f64; 3]], sigma: f64, barrier: f64) -> Option<Lattice> {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let pad = 2.0 * barrier + REACH * sigma;
        let extent = [0, 1, 2].map(|a| hi[a] - lo[a] + 2.0 * pad);
        if extent.iter().any(|e| !e.is_finite()) {
            return None;
        }
        let volume: f64 = extent.iter().product();
        let cell = sigma.max((volume / MAX_CELLS).cbrt());
        // Two more cells per side: the border row is free of barrier.
        let dims = extent.map(|e| (e / cell).ceil() as usize + 4);
        let origin = [0, 1, 2].map(|a| lo[a] - pad - 2.0 * cell);
        let mut lattice = Lattice {
            origin,
            cell,
            dims,
            state: vec![FREE; dims[0] * dims[1] * dims[2]],
        };
        lattice.build_barrier(points, barrier);
        lattice.flood();
        Some(lattice)
    }

    /// The barrier's cells and the free cells the flood did not reach (enclosed).
    fn counts(&self) -> (usize, usize) {
        let walls = self.state.iter().filter(|&&s| s == WALL).count();
        let enclosed = self.state.iter().filter(|&&s| s == FREE).count();
        (walls, enclosed)
    }

    fn index(&self, c: [usize; 3]) -> usize {
        (c[0] * self.dims[1] + c[1]) * self.dims[2] + c[2]
    }

    /// The cell holding `q` (clamped to the lattice).
    fn cell_of(&self, q: [f64; 3]) -> [usize; 3] {
        [0, 1, 2].map(|a| {
            let x = ((q[a] - self.origin[a]) / self.cell).floor();
            if x.is_nan() || x < 0.0 {
                0
            } else {
                (x as usize).min(self.dims[a] - 1)
            }
        })
    }

    fn state(&self, q: [f64; 3]) -> u8 {
        self.state[self.index(self.cell_of(q))]
    }

    /// Every cell whose centre lies within `radius` of a point, and the cell holding it.
    fn build_barrier(&mut self, points: &[[f64; 3]], radius: f64) {
        let reach = (radius / self.cell).ceil() as isize + 1;
        let r2 = radius * radius;
        for p in points {
            let c = self.cell_of(*p);
            let i = self.index(c);
            self.state[i] = WALL;
            for dx in -reach..=reach {
                for dy in -reach..=reach {
                    for dz in -reach..=reach {
                        let n = [dx, dy, dz];
                        let Some(m) = [0, 1, 2].iter().try_fold([0usize; 3], |mut m, &a| {
                            let v = c[a] as isize + n[a];
                            (v >= 0 && (v as usize) < self.dims[a]).then(|| {
                                m[a] = v as usize;
                                m
                            })
                        }) else {
                            continue;
                        };
                        let centre =
                            [0, 1, 2].map(|a| self.origin[a] + (m[a] as f64 + 0.5) * self.cell);
                        let d2: f64 = (0..3).map(|a| (centre[a] - p[a]).powi(2)).sum();
                        if d2 <= r2 {
                            let j = self.index(m);
                            self.state[j] = WALL;
                        }
                    }
                }
            }
        }
    }

    /// Marks the free cells joined to the lattice's border by faces as exterior.
    fn flood(&mut self) {
        let [nx, ny, nz] = self.dims;
        let mut queue = VecDeque::new();
        for x in 0..nx {
            for y in 0..ny {
                for z in 0..nz {
                    let border =
                        x == 0 || y == 0 || z == 0 || x == nx - 1 || y == ny - 1 || z == nz - 1;
                    let i = self.index([x, y, z]);
                    if border && self.state[i] == FREE {
                        self.state[i] = OUTSIDE;
                        queue.push_back([x, y, z]);
                    }
                }
            }
        }
        while let Some(c) = queue.pop_front() {
            for a in 0..3 {
                for up in [false, true] {
                    let mut m = c;
                    if up {
                        if c[a] + 1 >= self.dims[a] {
                            continue;
                        }
                        m[a] += 1;
                    } else {
                        if c[a] == 0 {
                            continue;
                        }
                        m[a] -= 1;
                    }
                    let j = self.index(m);
                    if self.state[j] == FREE {
                        self.state[j] = OUTSIDE;
                        queue.push_back(m);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::numerics::Lcg;

    /// A closed lens thinning to a rim a few σ thick (an ellipsoid with semi-axes 1, 1 and
    /// 0.15, sampled evenly in its parameters and moved by Gaussian noise σ = 0.0125 along its
    /// normal: 24σ thick at its middle, where it encloses a volume), with the true outward normals, except those of a
    /// patch at its rim that point inward, as the orientation of noisy plane fits leaves them
    /// at a thin part's tip. Where the plate is t thick, the share of points the noise moves
    /// past its middle is Φ(−t/2σ), about 2.3% at t = 4σ: a rule by the nearer side cannot
    /// orient those, so the correct normals are counted where the plate is at least 4σ thick.
    #[test]
    fn a_flipped_patch_at_a_thin_rim_is_turned_out_and_the_rest_stays() {
        let (a, c, sigma) = (1.0, 0.15, 0.0125);
        let mut rng = Lcg::new(11);
        let mut points = Vec::new();
        let mut normals = Vec::new();
        let mut patch = Vec::new();
        let mut thick = Vec::new();
        let (nu, nv) = (400, 60);
        for i in 0..nu {
            let phi = std::f64::consts::TAU * (i as f64 + 0.5) / nu as f64;
            for j in 0..nv {
                let theta = std::f64::consts::PI * (j as f64 + 0.5) / nv as f64;
                let (st, ct) = theta.sin_cos();
                let (sp, cp) = phi.sin_cos();
                let p = [a * st * cp, a * st * sp, c * ct];
                let g = [p[0] / (a * a), p[1] / (a * a), p[2] / (c * c)];
                let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
                let n = g.map(|x| x / len);
                let e = sigma * rng.normal();
                points.push([0, 1, 2].map(|k| p[k] + e * n[k]));
                let inward = p[0] > 0.9 && p[1].abs() < 0.3;
                normals.push(if inward { n.map(|x| -x) } else { n });
                patch.push(inward);
                thick.push(
                    2.0 * c
                        * (1.0 - (p[0] * p[0] + p[1] * p[1]) / (a * a))
                            .max(0.0)
                            .sqrt()
                        >= 4.0 * sigma,
                );
            }
        }
        let truth: Vec<[f64; 3]> = normals
            .iter()
            .zip(&patch)
            .map(|(n, &f)| if f { n.map(|x| -x) } else { *n })
            .collect();
        let tree = PointTree::new(&points).unwrap();
        let gap = sampling_gap(&points, &tree);
        assert!(gap > 0.0 && gap < 2.0 * BARRIER * sigma, "{gap}");
        let flipped = orient_by_exterior(&points, &mut normals, sigma, gap);
        let wrong = |inside: bool| {
            let (mut bad, mut all) = (0, 0);
            for (((n, t), &f), &thick) in normals.iter().zip(&truth).zip(&patch).zip(&thick) {
                if f == inside && (inside || thick) {
                    all += 1;
                    if n[0] * t[0] + n[1] * t[1] + n[2] * t[2] < 0.0 {
                        bad += 1;
                    }
                }
            }
            bad as f64 / all as f64
        };
        // Most of the patch (all of it inward before) is turned back out, up to its points in
        // the thin rim; of the correct normals where the plate is 4σ thick or more, few are
        // turned in.
        let (patch_wrong, rest_wrong) = (wrong(true), wrong(false));
        assert!(patch_wrong < 0.25, "patch {patch_wrong} flipped {flipped}");
        assert!(rest_wrong < 0.03, "rest {rest_wrong} flipped {flipped}");
        // Half of the plate (z > 0 only, open at its rim: it encloses nothing): untouched.
        let upper: Vec<usize> = (0..points.len()).filter(|&i| truth[i][2] > 0.3).collect();
        let open_points: Vec<[f64; 3]> = upper.iter().map(|&i| points[i]).collect();
        let mut open_normals: Vec<[f64; 3]> = upper.iter().map(|&i| truth[i]).collect();
        let open_truth = open_normals.clone();
        let open_tree = PointTree::new(&open_points).unwrap();
        let open_gap = sampling_gap(&open_points, &open_tree);
        assert_eq!(
            orient_by_exterior(&open_points, &mut open_normals, sigma, open_gap),
            0
        );
        assert_eq!(open_normals, open_truth);
        // Without noise, nothing to do.
        let mut same = truth.clone();
        assert_eq!(orient_by_exterior(&points, &mut same, 0.0, gap), 0);
        assert_eq!(same, truth);
    }
}
