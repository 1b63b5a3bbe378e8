//! Steps 2–4 of the trim: the unsupported triangles joined by edges into regions and which of
//! them go (those that reach the boundary or hold a large share of the area, and then the deep
//! enclosed ones), then the extra fans at a vertex and the small islands.
//!
//! Input: the mesh, its edge map, the triangles' areas and the unsupported triangles' depths.
//! Output: the removed triangles, marked in place, and the counts the report gives.

use crate::mesh::{EdgeMap, TriangleMesh, VertexTriangles};
use crate::numerics::UnionFind;

/// How far an unsupported triangle's centroid lies from the data; for a region, the largest of
/// each over its triangles (taken separately: one triangle may give the spacings, another the
/// distance).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Depth {
    /// In local spacings of the nearest data point.
    pub(super) spacings: f64,
    /// In input units.
    pub(super) distance: f64,
}

/// Step 3: which triangles to remove, and how many unsupported regions are kept. Whether a
/// region opens the mesh is decided over the whole mesh: an opening in one piece lets deep
/// enclosed regions go in every piece.
pub(super) fn unsupported_regions(
    mesh: &TriangleMesh,
    edges: &EdgeMap,
    unsupported: &[Option<Depth>],
    areas: &[f64],
    keep_area: f64,
    keep_depth: Depth,
) -> (Vec<bool>, usize) {
    let n = mesh.triangles.len();
    let mut removed = vec![false; n];
    let mut seen = vec![false; n];
    let mut kept_regions = 0;
    let mut opened = false;
    // Enclosed regions that are deep: removed only when the mesh is opened anyway.
    let mut deep_regions: Vec<Vec<u32>> = Vec::new();
    let mut stack = Vec::new();
    let mut region = Vec::new();
    for first in 0..n {
        if unsupported[first].is_none() || seen[first] {
            continue;
        }
        seen[first] = true;
        stack.push(first as u32);
        region.clear();
        let mut area = 0.0;
        let mut depth = Depth::default();
        let mut reaches_boundary = false;
        while let Some(t) = stack.pop() {
            region.push(t);
            area += areas[t as usize];
            if let Some(d) = unsupported[t as usize] {
                depth.spacings = depth.spacings.max(d.spacings);
                depth.distance = depth.distance.max(d.distance);
            }
            for &e in &edges.of_triangle(t as usize) {
                let on = edges.triangles_of(e);
                if on.len() == 1 {
                    reaches_boundary = true;
                }
                for &u in on {
                    if unsupported[u as usize].is_some() && !seen[u as usize] {
                        seen[u as usize] = true;
                        stack.push(u);
                    }
                }
            }
        }
        let deep = depth.spacings > keep_depth.spacings && depth.distance > keep_depth.distance;
        if reaches_boundary || area > keep_area {
            opened = true;
            for &t in &region {
                removed[t as usize] = true;
            }
        } else if deep {
            deep_regions.push(region.clone());
        } else {
            kept_regions += 1;
        }
    }
    if opened {
        for t in deep_regions.iter().flatten() {
            removed[*t as usize] = true;
        }
    } else {
        kept_regions += deep_regions.len();
    }
    (removed, kept_regions)
}

/// Step 4, fans: at every vertex whose kept triangles form more than one fan, removes all
/// fans but the one of largest area (ties: the one with the smallest triangle index), until no
/// such vertex is left.
pub(super) fn remove_extra_fans(
    mesh: &TriangleMesh,
    around: &VertexTriangles,
    areas: &[f64],
    removed: &mut [bool],
) {
    let n = mesh.positions.len();
    // The vertices to look at: those of removed triangles (only they can have lost a fan's
    // link); a removal adds its triangles' vertices again.
    let mut queue: Vec<u32> = Vec::new();
    let mut queued = vec![false; n];
    for (t, &r) in mesh.triangles.iter().zip(removed.iter()) {
        if r {
            for &v in t {
                if !queued[v as usize] {
                    queued[v as usize] = true;
                    queue.push(v);
                }
            }
        }
    }
    queue.sort_unstable();
    let mut head = 0;
    let mut local: Vec<u32> = Vec::new();
    let mut sets = UnionFind::default();
    while head < queue.len() {
        let v = queue[head];
        head += 1;
        queued[v as usize] = false;
        local.clear();
        local.extend(
            around
                .of(v as usize)
                .iter()
                .copied()
                .filter(|&t| !removed[t as usize]),
        );
        if local.len() < 2 {
            continue;
        }
        sets.reset(local.len());
        // Two triangles around v are in one fan when they share an edge through v.
        for i in 0..local.len() {
            let ti = mesh.triangles[local[i] as usize];
            for (j, &other) in local.iter().enumerate().skip(i + 1) {
                let tj = mesh.triangles[other as usize];
                let shared = ti.iter().filter(|&&w| w != v && tj.contains(&w)).count();
                if shared > 0 {
                    sets.union(i as u32, j as u32);
                }
            }
        }
        let roots: Vec<usize> = (0..local.len() as u32)
            .map(|i| sets.find(i) as usize)
            .collect();
        let mut fans: Vec<usize> = roots.clone();
        fans.sort_unstable();
        fans.dedup();
        if fans.len() < 2 {
            continue;
        }
        let fan_area = |r: usize| -> f64 {
            (0..local.len())
                .filter(|&i| roots[i] == r)
                .map(|i| areas[local[i] as usize])
                .sum()
        };
        // The fan roots are in order of their smallest slot, and slots follow triangle order.
        let mut best = fans[0];
        let mut best_area = fan_area(best);
        for &r in &fans[1..] {
            let a = fan_area(r);
            if a > best_area {
                (best, best_area) = (r, a);
            }
        }
        for i in 0..local.len() {
            if roots[i] != best {
                let t = local[i] as usize;
                removed[t] = true;
                for &w in &mesh.triangles[t] {
                    if !queued[w as usize] {
                        queued[w as usize] = true;
                        queue.push(w);
                    }
                }
            }
        }
    }
}

/// Step 4, islands: removes the edge-connected pieces of kept triangles with less than
/// `share` of the kept area; returns how many.
pub(super) fn remove_islands(
    mesh: &TriangleMesh,
    edges: &EdgeMap,
    areas: &[f64],
    share: f64,
    removed: &mut [bool],
) -> usize {
    let n = mesh.triangles.len();
    let mut label = vec![u32::MAX; n];
    let mut piece_area: Vec<f64> = Vec::new();
    let mut stack = Vec::new();
    for first in 0..n {
        if removed[first] || label[first] != u32::MAX {
            continue;
        }
        let id = piece_area.len() as u32;
        let mut area = 0.0;
        label[first] = id;
        stack.push(first as u32);
        while let Some(t) = stack.pop() {
            area += areas[t as usize];
            for &e in &edges.of_triangle(t as usize) {
                for &u in edges.triangles_of(e) {
                    if !removed[u as usize] && label[u as usize] == u32::MAX {
                        label[u as usize] = id;
                        stack.push(u);
                    }
                }
            }
        }
        piece_area.push(area);
    }
    let total: f64 = piece_area.iter().sum();
    let small: Vec<bool> = piece_area.iter().map(|&a| a < share * total).collect();
    for t in 0..n {
        if !removed[t] && small[label[t] as usize] {
            removed[t] = true;
        }
    }
    small.iter().filter(|&&s| s).count()
}
