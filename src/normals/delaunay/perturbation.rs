//! The symbolic perturbation of the Delaunay tetrahedralization: an exactly co-spherical
//! configuration (insphere exactly zero) is decided as if each point were lifted onto the
//! paraboloid by an infinitesimal amount growing with its caller index.
//!
//! Input: a positive tetrahedron and a point, with their caller indices. Output: whether the
//! point is strictly inside the perturbed circumsphere; the exact predicates come from
//! [`crate::numerics::predicates`].

use crate::numerics::predicates::{insphere, orient3d};

/// Whether `p` (caller index `key`) is strictly inside the perturbed circumsphere of the
/// positive tet `q` (caller indices `keys`): the exact insphere sign, and for an exactly
/// co-spherical configuration the symbolic perturbation ([`perturbed_inside`]). The same
/// decision the insertion makes, so it can be asked of points in different triangulations.
pub(super) fn inside(q: &[[f64; 3]; 4], keys: [u32; 4], p: &[f64; 3], key: u32) -> bool {
    let s = insphere(&q[0], &q[1], &q[2], &q[3], p);
    if s != 0.0 {
        return s > 0.0;
    }
    perturbed_inside(q, keys, p, key)
}

/// The symbolic perturbation for an exactly co-spherical configuration: the point with the
/// largest caller index is lifted most. Lifting the new point `p` (caller index `key`) puts it
/// outside; lifting tet vertex j (caller index `keys[j]`) moves the sphere towards the side of
/// the opposite face where vertex j is, so p is inside when it is on that side.
#[cold]
pub(super) fn perturbed_inside(q: &[[f64; 3]; 4], keys: [u32; 4], p: &[f64; 3], key: u32) -> bool {
    let mut order = [0usize, 1, 2, 3, 4].map(|j| (if j == 4 { key } else { keys[j] }, j));
    order.sort_unstable_by_key(|x| std::cmp::Reverse(x.0));
    for (_, j) in order {
        if j == 4 {
            return false;
        }
        let mut r = *q;
        r[j] = *p;
        let o = orient3d(&r[0], &r[1], &r[2], &r[3]);
        if o != 0.0 {
            return o > 0.0;
        }
    }
    false
}
