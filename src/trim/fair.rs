//! Step 6 of the trim: the surface the model closes over a hole of the scan is faired.
//!
//! Input: the kept triangles, their vertices' positions and normals, and which vertices are
//! free (far from every data point, on kept unsupported surface). Output: the positions and
//! normals with the free vertices moved, and how many moved. Invariants: a vertex that is not
//! free, or lies on the mesh's boundary or on an edge with other than two triangles, keeps its
//! exact position and normal; no triangle that touches a moved vertex crosses another (the
//! exact test of [`crate::mesh`]), so a mesh without self-intersections stays without;
//! deterministic (one sequential solve).
//!
//! Why: over a hole the blend of local fits continues the fits of the hole's rim, and their
//! quadrics bulge the patch out past the rim (the bunny's open base). The free vertices move to
//! the membrane the rest spans: each at the mean of its neighbours (the discrete Laplace
//! equation with uniform weights, the others fixed; Liepa, *Filling holes in meshes*, SGP 2003,
//! fairs its fills with the same operator). Moves that would make triangles cross are undone,
//! vertex by vertex, until none do.

use crate::mesh::{intersecting_triangles_among, triangle_box, TriangleMesh, VertexTriangles};
use crate::vec3;

/// The membrane's solve stops when the residual is below this share of the right-hand side...
const MEMBRANE_TOLERANCE: f64 = 1e-10;

/// ... or after this many conjugate-gradient steps (a patch n edges across needs about n).
const MEMBRANE_ITERATIONS: usize = 2000;

/// Moves the `free` vertices of `triangles` (see the module docs); returns how many moved.
pub(super) fn fair(
    positions: &mut [[f64; 3]],
    normals: &mut [[f64; 3]],
    triangles: &[[u32; 3]],
    free: &[bool],
) -> usize {
    let n = positions.len();
    if !free.iter().any(|&f| f) {
        return 0;
    }
    // Vertices on an edge that does not join exactly two triangles stay where they are (the
    // edges at a free vertex: every triangle on such an edge touches that vertex).
    let mut edges: Vec<(u32, u32)> = triangles
        .iter()
        .filter(|t| t.iter().any(|&v| free[v as usize]))
        .flat_map(|t| (0..3).map(move |k| (t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3]))))
        .collect();
    edges.sort_unstable();
    let mut pinned = vec![false; n];
    for run in edges.chunk_by(|a, b| a == b) {
        if run.len() != 2 {
            pinned[run[0].0 as usize] = true;
            pinned[run[0].1 as usize] = true;
        }
    }
    let movable: Vec<u32> = (0..n as u32)
        .filter(|&v| free[v as usize] && !pinned[v as usize])
        .collect();
    if movable.is_empty() {
        return 0;
    }
    let around = VertexTriangles::new(n, triangles);
    let original: Vec<[f64; 3]> = movable.iter().map(|&v| positions[v as usize]).collect();
    // The membrane: every movable vertex at the mean of its neighbours, the others fixed. Each
    // neighbour is counted once per triangle they share (twice for an interior edge), which
    // weighs them all alike: A x = b with A = diag(count) − (movable neighbours), b = the sum
    // of the fixed neighbours, symmetric positive definite as every patch touches a fixed
    // vertex (the caller frees only such patches). One system per coordinate, by conjugate
    // gradients from the current positions.
    let mut slot = vec![u32::MAX; n];
    for (i, &v) in movable.iter().enumerate() {
        slot[v as usize] = i as u32;
    }
    let m = movable.len();
    let mut offsets = Vec::with_capacity(m + 1);
    let mut columns: Vec<u32> = Vec::new();
    let mut diagonal = vec![0.0; m];
    let mut rhs = vec![[0.0; 3]; m];
    offsets.push(0);
    for (i, &v) in movable.iter().enumerate() {
        for &t in around.of(v as usize) {
            for w in triangles[t as usize] {
                if w == v {
                    continue;
                }
                diagonal[i] += 1.0;
                match slot[w as usize] {
                    u32::MAX => {
                        let p = positions[w as usize];
                        for a in 0..3 {
                            rhs[i][a] += p[a];
                        }
                    }
                    j => columns.push(j),
                }
            }
        }
        offsets.push(columns.len());
    }
    let apply = |x: &[f64], out: &mut [f64]| {
        for i in 0..m {
            let mut s = diagonal[i] * x[i];
            for &j in &columns[offsets[i]..offsets[i + 1]] {
                s -= x[j as usize];
            }
            out[i] = s;
        }
    };
    let dot = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(a, b)| a * b).sum::<f64>();
    for a in 0..3 {
        let mut x: Vec<f64> = original.iter().map(|p| p[a]).collect();
        let b: Vec<f64> = rhs.iter().map(|r| r[a]).collect();
        let mut q = vec![0.0; m];
        apply(&x, &mut q);
        let mut r: Vec<f64> = b.iter().zip(&q).map(|(b, q)| b - q).collect();
        let mut d = r.clone();
        let mut rr = dot(&r, &r);
        let stop = MEMBRANE_TOLERANCE * MEMBRANE_TOLERANCE * dot(&b, &b);
        for _ in 0..MEMBRANE_ITERATIONS.min(2 * m + 10) {
            if rr <= stop {
                break;
            }
            apply(&d, &mut q);
            let alpha = rr / dot(&d, &q);
            if !alpha.is_finite() {
                break;
            }
            for i in 0..m {
                x[i] += alpha * d[i];
                r[i] -= alpha * q[i];
            }
            let next = dot(&r, &r);
            let beta = next / rr;
            rr = next;
            for i in 0..m {
                d[i] = r[i] + beta * d[i];
            }
        }
        if x.iter().all(|c| c.is_finite()) {
            for (&v, &c) in movable.iter().zip(&x) {
                positions[v as usize][a] = c;
            }
        }
    }
    // Undo the moves of the vertices of crossing triangles until none cross.
    let mut moved = vec![false; n];
    for &v in &movable {
        moved[v as usize] = true;
    }
    // Only the triangles whose boxes meet the box of the moved ones, at their new or their
    // old positions (any mix the undoing below leaves), can cross them.
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for t in triangles
        .iter()
        .filter(|t| t.iter().any(|&v| moved[v as usize]))
    {
        for &v in t {
            let old = match slot[v as usize] {
                u32::MAX => positions[v as usize],
                i => original[i as usize],
            };
            for p in [positions[v as usize], old] {
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
        }
    }
    let near: Vec<[u32; 3]> = triangles
        .iter()
        .filter(|t| {
            let (l, h) = triangle_box(t, positions);
            (0..3).all(|a| l[a] <= hi[a] && h[a] >= lo[a])
        })
        .copied()
        .collect();
    let mut mesh = TriangleMesh {
        positions: positions.to_vec(),
        normals: Vec::new(),
        triangles: near,
    };
    loop {
        let active: Vec<bool> = mesh
            .triangles
            .iter()
            .map(|t| t.iter().any(|&v| moved[v as usize]))
            .collect();
        let crossing = intersecting_triangles_among(&mesh, Some(&active));
        let mut undone = false;
        for (t, _) in mesh.triangles.iter().zip(&crossing).filter(|&(_, &c)| c) {
            for &v in t {
                if moved[v as usize] {
                    moved[v as usize] = false;
                    undone = true;
                }
            }
        }
        if !undone {
            break;
        }
        for (&v, &p) in movable.iter().zip(&original) {
            if !moved[v as usize] {
                mesh.positions[v as usize] = p;
            }
        }
    }
    for (&v, &p) in movable.iter().zip(&original) {
        if !moved[v as usize] {
            positions[v as usize] = p;
        }
    }
    // A moved vertex's normal: the area-weighted mean of its triangles' (counter-clockwise
    // seen from outside, so outward).
    let mut count = 0;
    for &v in &movable {
        if !moved[v as usize] {
            continue;
        }
        count += 1;
        let mut sum = [0.0; 3];
        for &t in around.of(v as usize) {
            let [a, b, c] = triangles[t as usize].map(|i| positions[i as usize]);
            let face = vec3::cross(vec3::sub(b, a), vec3::sub(c, a));
            for k in 0..3 {
                sum[k] += face[k];
            }
        }
        let length = vec3::norm(sum);
        if length > 0.0
            && length.is_finite()
            && let Some(slot) = normals.get_mut(v as usize)
        {
            *slot = sum.map(|c| c / length);
        }
    }
    count
}
