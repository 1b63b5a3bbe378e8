//! Self-intersections of a mesh: which triangles cross another, decided exactly (orientation
//! predicates), with a broad phase of boxes on a grid.
//!
//! Input: a [`TriangleMesh`]. Output: per-triangle flags and counts.

use super::*;

/// Exact orientation of `d` against the plane of `a, b, c` (Shewchuk's adaptive predicate behind
/// a semi-static filter, [`crate::numerics::predicates::orient3d`]; its sign is exact).
#[inline(always)]
fn orient3d(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3]) -> f64 {
    crate::numerics::predicates::orient3d(a, b, c, d)
}

/// The sign of a number as −1, 0 or 1.
#[inline]
fn sign(x: f64) -> i8 {
    if x > 0.0 {
        1
    } else if x < 0.0 {
        -1
    } else {
        0
    }
}

/// Exact 2-D orientation of `a, b, c` projected along axis `drop` (the coordinate left out).
#[inline]
fn orient2d(drop: usize, a: &[f64; 3], b: &[f64; 3], c: &[f64; 3]) -> i8 {
    let (i, j) = ((drop + 1) % 3, (drop + 2) % 3);
    let p = |q: &[f64; 3]| robust::Coord { x: q[i], y: q[j] };
    sign(robust::orient2d(p(a), p(b), p(c)))
}

/// An axis along which the triangle `a, b, c` projects to a non-degenerate triangle (the one
/// with the largest projected area), or `None` when the three points are collinear (exactly).
fn projection_axis(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3]) -> Option<usize> {
    let mut best = None;
    let mut best_area = 0.0;
    for drop in 0..3 {
        let (i, j) = ((drop + 1) % 3, (drop + 2) % 3);
        let p = |q: &[f64; 3]| robust::Coord { x: q[i], y: q[j] };
        let area = robust::orient2d(p(a), p(b), p(c)).abs();
        if area > best_area {
            best_area = area;
            best = Some(drop);
        }
    }
    best
}

/// Whether the closed segments `pq` and `rs`, coplanar and projected along `drop`, meet.
fn segments_meet_2d(drop: usize, p: &[f64; 3], q: &[f64; 3], r: &[f64; 3], s: &[f64; 3]) -> bool {
    let (o1, o2) = (orient2d(drop, p, q, r), orient2d(drop, p, q, s));
    let (o3, o4) = (orient2d(drop, r, s, p), orient2d(drop, r, s, q));
    if o1 == 0 && o2 == 0 {
        // Collinear: the projected intervals overlap on some axis of the projection plane (a
        // collinear pair of non-point segments overlaps exactly when it does along both axes).
        let (i, j) = ((drop + 1) % 3, (drop + 2) % 3);
        return [i, j]
            .iter()
            .all(|&a| p[a].min(q[a]) <= r[a].max(s[a]) && r[a].min(s[a]) <= p[a].max(q[a]));
    }
    o1 * o2 <= 0 && o3 * o4 <= 0
}

/// Whether the point `p`, in the plane of the triangle `t` (projected along `drop`), lies in the
/// closed triangle.
fn point_in_triangle_2d(drop: usize, p: &[f64; 3], t: [&[f64; 3]; 3]) -> bool {
    let o = [
        orient2d(drop, t[0], t[1], p),
        orient2d(drop, t[1], t[2], p),
        orient2d(drop, t[2], t[0], p),
    ];
    !(o.contains(&1) && o.contains(&-1))
}

/// Whether the closed segment `pq` meets the closed, non-degenerate triangle `t` whose
/// projection axis is `drop`.
fn segment_meets_triangle(p: &[f64; 3], q: &[f64; 3], t: [&[f64; 3]; 3], drop: usize) -> bool {
    let op = sign(orient3d(t[0], t[1], t[2], p));
    let oq = sign(orient3d(t[0], t[1], t[2], q));
    if op * oq > 0 {
        return false;
    }
    if op == 0 && oq == 0 {
        // In the triangle's plane.
        return point_in_triangle_2d(drop, p, t)
            || point_in_triangle_2d(drop, q, t)
            || (0..3).any(|k| segments_meet_2d(drop, p, q, t[k], t[(k + 1) % 3]));
    }
    // The segment crosses the plane at one point: inside the closed triangle when the line pq
    // passes on no two strictly different sides of its edges.
    let s = [
        sign(orient3d(p, q, t[0], t[1])),
        sign(orient3d(p, q, t[1], t[2])),
        sign(orient3d(p, q, t[2], t[0])),
    ];
    !(s.contains(&1) && s.contains(&-1))
}

/// Whether the ray from `v` through `a` (both in the plane of the triangle `v, c, d`, projected
/// along `drop`) enters the closed triangle beyond `v`: the direction lies in its corner at `v`.
fn ray_in_corner(drop: usize, v: &[f64; 3], a: &[f64; 3], c: &[f64; 3], d: &[f64; 3]) -> bool {
    let s = orient2d(drop, v, c, d);
    orient2d(drop, v, c, a) * s >= 0 && orient2d(drop, v, a, d) * s >= 0 && a != v
}

/// Whether the triangles `s` and `t` (vertex indices into `positions`) intersect anywhere other
/// than at the vertices and edges they share by index, decided exactly (Shewchuk's `orient3d`
/// and `orient2d` from the `robust` crate, so every sign is exact in f64).
///
/// What counts: with no shared vertex, any common point (touching included); with one shared
/// vertex, any common point other than it (an edge of one meeting the other away from it, or
/// the two overlapping in a common plane); with a shared edge, only a coplanar fold (the third
/// vertices strictly on the same side of the edge), since two triangles in different planes
/// through an edge meet only on it; with all three shared (a duplicate face), always. A
/// zero-area triangle (exactly collinear corners) or one with a repeated index is never counted.
pub(crate) fn triangles_intersect(s: [u32; 3], t: [u32; 3], positions: &[[f64; 3]]) -> bool {
    let n = positions.len() as u32;
    if s.iter().chain(&t).any(|&i| i >= n) {
        return false;
    }
    let axis = |t: [u32; 3]| {
        let p = t.map(|i| &positions[i as usize]);
        if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
            None
        } else {
            projection_axis(p[0], p[1], p[2])
        }
    };
    match (axis(s), axis(t)) {
        (Some(ds), Some(dt)) => intersect_with_axes(s, t, ds, dt, positions),
        _ => false,
    }
}

/// [`triangles_intersect`] for two non-degenerate triangles with indices in range and their
/// projection axes.
fn intersect_with_axes(
    s: [u32; 3],
    t: [u32; 3],
    ds: usize,
    dt: usize,
    positions: &[[f64; 3]],
) -> bool {
    let ps = s.map(|i| &positions[i as usize]);
    let pt = t.map(|i| &positions[i as usize]);
    // Shared vertices: slot in s → slot in t.
    let mut shared: [(usize, usize); 3] = [(0, 0); 3];
    let mut k = 0;
    for (i, &a) in s.iter().enumerate() {
        if let Some(j) = t.iter().position(|&b| b == a) {
            shared[k] = (i, j);
            k += 1;
        }
    }
    let side =
        |plane: [&[f64; 3]; 3], q: &[f64; 3]| sign(orient3d(plane[0], plane[1], plane[2], q));
    match k {
        0 => {
            // Quick rejection: one triangle strictly on one side of the other's plane.
            let side_t = pt.map(|q| side(ps, q));
            if side_t[0] * side_t[1] > 0 && side_t[1] * side_t[2] > 0 {
                return false;
            }
            let side_s = ps.map(|q| side(pt, q));
            if side_s[0] * side_s[1] > 0 && side_s[1] * side_s[2] > 0 {
                return false;
            }
            // Two closed triangles meet exactly when an edge of one meets the other.
            (0..3).any(|e| segment_meets_triangle(ps[e], ps[(e + 1) % 3], pt, dt))
                || (0..3).any(|e| segment_meets_triangle(pt[e], pt[(e + 1) % 3], ps, ds))
        }
        1 => {
            let (i, j) = shared[0];
            let (i1, i2, j1, j2) = ((i + 1) % 3, (i + 2) % 3, (j + 1) % 3, (j + 2) % 3);
            let (a, b) = (ps[i1], ps[i2]);
            let (c, d) = (pt[j1], pt[j2]);
            let v = ps[i];
            // The other two corners of one triangle strictly on one side of the other's plane:
            // it meets that plane only at v.
            let (sc, sd) = (side(ps, c), side(ps, d));
            if sc * sd > 0 {
                return false;
            }
            let (sa, sb) = (side(pt, a), side(pt, b));
            if sa * sb > 0 {
                return false;
            }
            // A common point other than v ends the intersection (a convex set holding v) on an
            // edge of one triangle: the edge opposite v (which does not hold v), or an edge
            // through v lying in the other's plane and pointing into its corner at v.
            segment_meets_triangle(a, b, pt, dt)
                || segment_meets_triangle(c, d, ps, ds)
                || (sa == 0 && ray_in_corner(dt, v, a, c, d))
                || (sb == 0 && ray_in_corner(dt, v, b, c, d))
                || (sc == 0 && ray_in_corner(ds, v, c, a, b))
                || (sd == 0 && ray_in_corner(ds, v, d, a, b))
        }
        2 => {
            // The corners not on the shared edge.
            let i = (0..3).find(|&i| !t.contains(&s[i])).unwrap_or(0);
            let j = (0..3).find(|&j| !s.contains(&t[j])).unwrap_or(0);
            if side(ps, pt[j]) != 0 {
                return false;
            }
            let (u, w) = (ps[(i + 1) % 3], ps[(i + 2) % 3]);
            let o1 = orient2d(ds, u, w, ps[i]);
            let o2 = orient2d(ds, u, w, pt[j]);
            o1 * o2 > 0
        }
        _ => true,
    }
}

/// Number of triangles of `mesh` that intersect another of its triangles other than at the
/// vertices and edges they share (see `triangles_intersect` for what counts exactly).
///
/// Broad phase: the triangles' bounding boxes in a uniform grid of cubes three times the mean
/// box side, sorted by cube (a radix sort of the dense cube numbers); each pair of triangles
/// whose boxes overlap is tested once (the cubes in parallel), in the cube holding the lowest
/// corner of the boxes' overlap. The count is an integer computed from exact predicates, so it
/// is the same for any number of threads.
///
/// ```
/// use stablesurf::mesh::{self_intersecting_faces, TriangleMesh};
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0],
///                     [0.5, 0.5, -1.0], [0.5, 0.5, 1.0], [3.0, 3.0, 0.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 6],
///     triangles: vec![[0, 1, 2], [3, 4, 5]],
/// };
/// assert_eq!(self_intersecting_faces(&mesh), 2);
/// ```
pub fn self_intersecting_faces(mesh: &TriangleMesh) -> usize {
    intersecting_triangles(mesh).iter().filter(|&&x| x).count()
}

/// One flag per triangle of `mesh`: whether it intersects another (see
/// [`self_intersecting_faces`]).
pub(crate) fn intersecting_triangles(mesh: &TriangleMesh) -> Vec<bool> {
    intersecting_triangles_among(mesh, None)
}

/// A triangle in the broad phase of [`intersecting_triangles_among`]: its bounding box, the
/// grid cube of the box's lowest corner, its index, and whether its pairs are tested.
#[derive(Clone, Copy)]
struct Boxed {
    lo: [f64; 3],
    hi: [f64; 3],
    low_cube: [u32; 3],
    tri: u32,
    active: bool,
}

/// [`intersecting_triangles`] testing only the pairs with at least one triangle `t` such that
/// `active[t]` (all pairs when `active` is `None`); the other triangles' flags come from those
/// pairs alone.
pub(crate) fn intersecting_triangles_among(
    mesh: &TriangleMesh,
    active: Option<&[bool]>,
) -> Vec<bool> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    let positions = &mesh.positions;
    let n = positions.len();
    let tris = &mesh.triangles;
    let usable = |t: &[u32; 3]| {
        t.iter()
            .all(|&i| (i as usize) < n && positions[i as usize].iter().all(|c| c.is_finite()))
    };
    // The box of each non-degenerate triangle.
    let boxes: Vec<Option<([f64; 3], [f64; 3])>> = tris
        .par_iter()
        .map(|t| {
            if !usable(t) || t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                return None;
            }
            Some(triangle_box(t, positions))
        })
        .collect();
    let present: Vec<&([f64; 3], [f64; 3])> = boxes.iter().flatten().collect();
    if present.len() < 2 {
        return vec![false; tris.len()];
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    let mut size = 0.0;
    for (l, h) in &present {
        for a in 0..3 {
            lo[a] = lo[a].min(l[a]);
            hi[a] = hi[a].max(h[a]);
            size += h[a] - l[a];
        }
    }
    let mean = size / (3.0 * present.len() as f64);
    let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    // Cubes of three times the mean box side (fewest pairs and entries on polygonized meshes of
    // 10⁵ triangles), at most 2^20 per axis.
    let cell = (3.0 * mean)
        .max(extent / f64::from(1u32 << 20))
        .max(f64::MIN_POSITIVE);
    // x ≥ lo[a], so truncation is the floor; monotone in x, so the cube of the larger of two
    // coordinates is the larger of their cubes.
    let cube = |x: f64, a: usize| (((x - lo[a]) / cell) as u32).min((1 << 20) - 1);
    // Cubes numbered densely (x-major), so that the keys are as short as the grid allows.
    let dims = [0, 1, 2].map(|a| u64::from(cube(hi[a], a)) + 1);
    let key =
        |c: [u32; 3]| (u64::from(c[0]) * dims[1] + u64::from(c[1])) * dims[2] + u64::from(c[2]);
    let cubes_of = |(l, h): &([f64; 3], [f64; 3])| {
        let cl = [0, 1, 2].map(|a| cube(l[a], a));
        let ch = [0, 1, 2].map(|a| cube(h[a], a));
        (cl[0]..=ch[0]).flat_map(move |x| {
            (cl[1]..=ch[1]).flat_map(move |y| (cl[2]..=ch[2]).map(move |z| key([x, y, z])))
        })
    };
    let marked = |t: usize| active.is_none_or(|a| a.get(t) == Some(&true));
    // With `active`, only the triangles sharing a cube with an active one can be in a tested
    // pair (a pair is tested in a cube both boxes overlap), so the others are left out of the
    // broad phase: a round of a repair that moved a few vertices costs about what they touch.
    let active_cubes: Option<Vec<u64>> = active.map(|_| {
        let mut keys: Vec<u64> = boxes
            .iter()
            .enumerate()
            .filter(|&(t, _)| marked(t))
            .filter_map(|(_, b)| b.as_ref())
            .flat_map(cubes_of)
            .collect();
        keys.par_sort_unstable();
        keys.dedup();
        keys
    });
    if active_cubes.as_ref().is_some_and(Vec::is_empty) {
        return vec![false; tris.len()];
    }
    let included: Vec<bool> = boxes
        .par_iter()
        .enumerate()
        .map(|(t, b)| {
            let Some(b) = b else { return false };
            match &active_cubes {
                None => true,
                Some(keys) => marked(t) || cubes_of(b).any(|k| keys.binary_search(&k).is_ok()),
            }
        })
        .collect();
    // The projection axis of each included triangle (u8::MAX: collinear, or left out).
    let axes: Vec<u8> = tris
        .par_iter()
        .zip(&included)
        .map(|(t, &inc)| {
            if !inc {
                return u8::MAX;
            }
            let p = t.map(|i| &positions[i as usize]);
            projection_axis(p[0], p[1], p[2]).map_or(u8::MAX, |a| a as u8)
        })
        .collect();
    let is_active = |t: u32| axes[t as usize] != u8::MAX && marked(t as usize);
    let flags: Vec<AtomicBool> = (0..tris.len()).map(|_| AtomicBool::new(false)).collect();
    // Each testable triangle's box and the cube of its lowest corner.
    let cells: Vec<Option<Boxed>> = boxes
        .par_iter()
        .zip(&axes)
        .enumerate()
        .map(|(ti, (b, &axis))| {
            let (l, h) = (*b)?;
            (axis != u8::MAX).then(|| Boxed {
                lo: l,
                hi: h,
                low_cube: [0, 1, 2].map(|a| cube(l[a], a)),
                tri: ti as u32,
                active: is_active(ti as u32),
            })
        })
        .collect();
    // (cube, triangle) for every cube a box overlaps, by cube, then by triangle.
    let mut entries: Vec<(u64, u32)> = Vec::new();
    for c in cells.iter().flatten() {
        entries.extend(cubes_of(&(c.lo, c.hi)).map(|k| (k, c.tri)));
    }
    crate::numerics::sort_pairs_by_key(&mut entries);
    // Group starts.
    let mut starts: Vec<usize> = (0..entries.len())
        .into_par_iter()
        .filter(|&i| i == 0 || entries[i].0 != entries[i - 1].0)
        .collect();
    starts.push(entries.len());
    starts
        .par_windows(2)
        .for_each_init(Vec::new, |group: &mut Vec<Boxed>, w| {
            let here = entries[w[0]].0;
            group.clear();
            // Every entry's triangle has a box (the entries are made from the boxes).
            group.extend(
                entries[w[0]..w[1]]
                    .iter()
                    .filter_map(|&(_, t)| cells[t as usize]),
            );
            if active.is_some() && !group.iter().any(|c| c.active) {
                return;
            }
            for (x, ci) in group.iter().enumerate() {
                for cj in &group[x + 1..] {
                    if !ci.active && !cj.active {
                        continue;
                    }
                    if (0..3).any(|a| ci.lo[a] > cj.hi[a] || cj.lo[a] > ci.hi[a]) {
                        continue;
                    }
                    // Test the pair only in the cube holding the overlap's lowest corner.
                    let corner = [0, 1, 2].map(|a| ci.low_cube[a].max(cj.low_cube[a]));
                    if key(corner) != here {
                        continue;
                    }
                    let (i, j) = (ci.tri as usize, cj.tri as usize);
                    let (ai, aj) = (axes[i] as usize, axes[j] as usize);
                    if intersect_with_axes(tris[i], tris[j], ai, aj, positions) {
                        flags[i].store(true, Ordering::Relaxed);
                        flags[j].store(true, Ordering::Relaxed);
                    }
                }
            }
        });
    flags.into_iter().map(AtomicBool::into_inner).collect()
}

/// The axis-aligned box (min, max) of triangle `t`'s corners in `positions`.
pub(crate) fn triangle_box(t: &[u32; 3], positions: &[[f64; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut lo = positions[t[0] as usize];
    let mut hi = lo;
    for &v in &t[1..] {
        let p = positions[v as usize];
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn triangles_intersect() {
        use crate::mesh::triangles_intersect;
        let p = [
            [0.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            [0.0, 2.0, 0.0],
            [0.5, 0.5, -1.0],
            [0.5, 0.5, 1.0],
            [-3.0, -3.0, 0.0],
        ];
        assert!(triangles_intersect([0, 1, 2], [3, 4, 5], &p));
        assert!(!triangles_intersect([0, 1, 2], [0, 4, 5], &p));
    }
}
