//! Step 5 of the trim: the short boundary loops closed by ear clipping in the loop's Newell
//! plane, when the projected loop is simple, no new edge exists already and no new triangle
//! meets the mesh (the exact test of [`crate::mesh`]).
//!
//! Input: the vertex positions and the kept triangles. Output: the triangles with the closing
//! ones appended, and the counts of loops closed and triangles added.

use crate::mesh::{self, TriangleMesh};
use crate::vec3::{cross, dot, norm, sub};

/// Most vertices of a loop [`fill_holes`] closes.
const FILL_MAX_VERTICES: usize = 512;

/// Step 5: closes the boundary loops of `triangles` no longer than `max_perimeter`; returns
/// the number of loops closed and of triangles added.
pub(super) fn fill_holes(
    positions: &[[f64; 3]],
    triangles: &mut Vec<[u32; 3]>,
    max_perimeter: f64,
) -> (usize, usize) {
    if max_perimeter <= 0.0 {
        return (0, 0);
    }
    let boundary = mesh::boundary_edges(triangles);
    if boundary.is_empty() {
        return (0, 0);
    }
    // Each boundary vertex of a manifold mesh starts exactly one boundary edge.
    let mut next: std::collections::BTreeMap<u32, u32> = std::collections::BTreeMap::new();
    for &[a, b] in &boundary {
        if next.insert(a, b).is_some() {
            // Not manifold at a: no loop is well defined; close nothing.
            return (0, 0);
        }
    }
    let mut existing: std::collections::HashSet<(u32, u32)> = triangles
        .iter()
        .flat_map(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
        .collect();
    let mut visited: std::collections::BTreeSet<u32> = std::collections::BTreeSet::new();
    let mut fills: Vec<Vec<[u32; 3]>> = Vec::new();
    for &[start, _] in &boundary {
        if visited.contains(&start) {
            continue;
        }
        let mut lp = vec![start];
        visited.insert(start);
        let mut v = start;
        let mut closed = false;
        while let Some(&w) = next.get(&v) {
            if w == start {
                closed = true;
                break;
            }
            if !visited.insert(w) || lp.len() > FILL_MAX_VERTICES {
                break;
            }
            lp.push(w);
            v = w;
        }
        // Mark the rest of a loop that was too long, so it is not traced again.
        let mut w = v;
        while let Some(&x) = next.get(&w) {
            if !visited.insert(x) {
                break;
            }
            w = x;
        }
        if !closed || lp.len() < 3 {
            continue;
        }
        let perimeter: f64 = (0..lp.len())
            .map(|i| {
                norm(sub(
                    positions[lp[(i + 1) % lp.len()] as usize],
                    positions[lp[i] as usize],
                ))
            })
            .sum();
        if perimeter > max_perimeter {
            continue;
        }
        // The fill runs against the boundary's direction, so its edges pair with the mesh's.
        lp.reverse();
        if let Some(tris) = ear_clip(positions, &lp, &existing) {
            for t in &tris {
                for k in 0..3 {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    existing.insert((a.min(b), a.max(b)));
                }
            }
            fills.push(tris);
        }
    }
    if fills.is_empty() {
        return (0, 0);
    }
    // Fills that meet the mesh (or another fill) are taken back.
    let base = triangles.len();
    let mut all = triangles.clone();
    let mut owner = Vec::new();
    for (f, tris) in fills.iter().enumerate() {
        all.extend_from_slice(tris);
        owner.extend(std::iter::repeat_n(f, tris.len()));
    }
    let active: Vec<bool> = (0..all.len()).map(|i| i >= base).collect();
    let probe = TriangleMesh {
        positions: positions.to_vec(),
        normals: Vec::new(),
        triangles: all,
    };
    let hits = mesh::intersecting_triangles_among(&probe, Some(&active));
    let mut bad = vec![false; fills.len()];
    for (i, &h) in hits.iter().enumerate().skip(base) {
        if h {
            bad[owner[i - base]] = true;
        }
    }
    let (mut loops, mut added) = (0, 0);
    for (f, tris) in fills.into_iter().enumerate() {
        if !bad[f] {
            loops += 1;
            added += tris.len();
            triangles.extend(tris);
        }
    }
    (loops, added)
}

/// Ear clipping of the loop `lp` (vertex indices, in the order its fill triangles run) in the
/// plane of its Newell normal; `None` when the projected loop is not a simple polygon or an ear
/// would add an edge that `existing` already holds.
fn ear_clip(
    positions: &[[f64; 3]],
    lp: &[u32],
    existing: &std::collections::HashSet<(u32, u32)>,
) -> Option<Vec<[u32; 3]>> {
    let m = lp.len();
    let p = |i: usize| positions[lp[i] as usize];
    let mut normal = [0.0; 3];
    for i in 0..m {
        let (a, b) = (p(i), p((i + 1) % m));
        normal[0] += (a[1] - b[1]) * (a[2] + b[2]);
        normal[1] += (a[2] - b[2]) * (a[0] + b[0]);
        normal[2] += (a[0] - b[0]) * (a[1] + b[1]);
    }
    let len = norm(normal);
    if len.is_nan() || len <= 0.0 {
        return None;
    }
    let nz = normal.map(|c| c / len);
    let helper = if nz[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let u = {
        let c = cross(helper, nz);
        let l = norm(c);
        c.map(|x| x / l)
    };
    let v = cross(nz, u);
    let flat: Vec<[f64; 2]> = (0..m).map(|i| [dot(p(i), u), dot(p(i), v)]).collect();
    let orient = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
        (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    };
    // A simple polygon: no two edges that are not neighbours meet.
    let meet = |a: [f64; 2], b: [f64; 2], c: [f64; 2], d: [f64; 2]| {
        let (d1, d2) = (orient(a, b, c), orient(a, b, d));
        let (d3, d4) = (orient(c, d, a), orient(c, d, b));
        d1 * d2 <= 0.0 && d3 * d4 <= 0.0
    };
    for i in 0..m {
        for j in i + 2..m {
            if i == 0 && j == m - 1 {
                continue;
            }
            if meet(flat[i], flat[(i + 1) % m], flat[j], flat[(j + 1) % m]) {
                return None;
            }
        }
    }
    let mut ring: Vec<usize> = (0..m).collect();
    let mut out = Vec::with_capacity(m - 2);
    while ring.len() > 3 {
        let r = ring.len();
        let mut clipped = false;
        for k in 0..r {
            let (ia, ib, ic) = (ring[(k + r - 1) % r], ring[k], ring[(k + 1) % r]);
            let (a, b, c) = (flat[ia], flat[ib], flat[ic]);
            if orient(a, b, c) <= 0.0 {
                continue;
            }
            let inside = ring.iter().any(|&j| {
                j != ia
                    && j != ib
                    && j != ic
                    && orient(a, b, flat[j]) >= 0.0
                    && orient(b, c, flat[j]) >= 0.0
                    && orient(c, a, flat[j]) >= 0.0
            });
            let (x, y) = (lp[ia], lp[ic]);
            if inside || existing.contains(&(x.min(y), x.max(y))) {
                continue;
            }
            out.push([lp[ia], lp[ib], lp[ic]]);
            ring.remove(k);
            clipped = true;
            break;
        }
        if !clipped {
            return None;
        }
    }
    out.push([lp[ring[0]], lp[ring[1]], lp[ring[2]]]);
    Some(out)
}
