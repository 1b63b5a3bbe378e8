//! The `TriangleMesh` artifact (output of `polygonize`, input of `export`) and its topology checks.
//!
//! Invariants: positions and normals have the same length; normals are unit length; every index
//! is `< positions.len()`; triangles are wound counter-clockwise seen from outside (the side
//! where the implicit function is positive).
//!
//! Checks ([`check`] → [`MeshReport`]): an edge used by one triangle is a boundary edge, by three
//! or more a non-manifold edge; a vertex whose triangles form more than one fan (joined through
//! shared edges) is a non-manifold vertex; the orientation is consistent when every interior edge
//! is traversed once in each direction; χ = V − E + F. [`component_labels`] labels connected
//! components (union–find over triangle edges), and [`drop_components_far_from`] removes the
//! components that no data point comes near (`--keep data`).

use serde::{Deserialize, Serialize};

/// A triangle mesh in input coordinates.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TriangleMesh {
    /// Vertex positions in input coordinates and units.
    pub positions: Vec<[f64; 3]>,
    /// Unit-length outward vertex normals, one per position.
    pub normals: Vec<[f64; 3]>,
    /// Triangles as indices into `positions`, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

impl TriangleMesh {
    /// Version of this artifact's layout; bump it whenever a field changes.
    pub const FORMAT_VERSION: u32 = 1;
}

/// Topology and size of a mesh, as [`check`] measures it.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MeshReport {
    /// Number of vertices (`positions.len()`).
    pub vertices: usize,
    /// Number of triangles.
    pub faces: usize,
    /// Number of undirected edges.
    pub edges: usize,
    /// Number of connected components (vertices joined by triangle edges; an unreferenced vertex
    /// is a component of its own).
    pub components: usize,
    /// Edges used by exactly one triangle: the mesh's boundary (where the zero set leaves the
    /// meshing region).
    pub boundary_edges: usize,
    /// Edges used by three or more triangles.
    pub non_manifold_edges: usize,
    /// Vertices whose triangles do not form a single fan (two surface sheets touching at a
    /// point).
    pub non_manifold_vertices: usize,
    /// Triangles with a repeated vertex index or an index out of range (not counted elsewhere).
    pub degenerate_faces: usize,
    /// V − E + F (2 per sphere-like closed component, 2 − 2g for genus g).
    pub euler_characteristic: i64,
    /// Every edge shared by two triangles is traversed in opposite directions by them.
    pub orientation_consistent: bool,
    /// The mesh has triangles, no boundary edge, no non-manifold edge or vertex and no
    /// degenerate face: a closed 2-manifold.
    pub watertight: bool,
}

/// Valid triangles (indices in range and distinct).
fn valid_triangles(mesh: &TriangleMesh) -> impl Iterator<Item = [u32; 3]> + '_ {
    let n = mesh.positions.len();
    mesh.triangles.iter().copied().filter(move |t| {
        t.iter().all(|&i| (i as usize) < n) && t[0] != t[1] && t[1] != t[2] && t[0] != t[2]
    })
}

/// The triangles around each vertex, in compressed rows: the triangles of vertex `v` are
/// `triangles[start[v]..start[v + 1]]` (indices into the input triangle list, in its order).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct VertexTriangles {
    /// Row starts, `n_vertices + 1` entries.
    pub start: Vec<usize>,
    /// Triangle indices, row by row.
    pub triangles: Vec<u32>,
}

impl VertexTriangles {
    /// Builds the rows for `n_vertices` vertices; every index in `triangles` must be below it.
    ///
    /// ```
    /// let around = stablesurf::mesh::VertexTriangles::new(4, &[[0, 1, 2], [0, 2, 3]]);
    /// assert_eq!(around.of(0), &[0, 1]);
    /// assert_eq!(around.of(3), &[1]);
    /// ```
    pub fn new(n_vertices: usize, triangles: &[[u32; 3]]) -> VertexTriangles {
        let mut start = vec![0usize; n_vertices + 1];
        for t in triangles {
            for &v in t {
                start[v as usize + 1] += 1;
            }
        }
        for i in 0..n_vertices {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut rows = vec![0u32; start[n_vertices]];
        for (ti, t) in triangles.iter().enumerate() {
            for &v in t {
                rows[fill[v as usize]] = ti as u32;
                fill[v as usize] += 1;
            }
        }
        VertexTriangles {
            start,
            triangles: rows,
        }
    }

    /// The indices of the triangles around vertex `v`.
    pub fn of(&self, v: usize) -> &[u32] {
        &self.triangles[self.start[v]..self.start[v + 1]]
    }
}

/// Connected components of the mesh: their number and one label per vertex, numbered in order
/// of each component's smallest vertex index. Vertices are joined by the edges of valid
/// triangles; an unreferenced vertex forms a component of its own.
///
/// ```
/// use stablesurf::mesh::{component_labels, TriangleMesh};
/// let mesh = TriangleMesh {
///     positions: vec![[0.0; 3]; 6],
///     normals: vec![[0.0, 0.0, 1.0]; 6],
///     triangles: vec![[0, 1, 2], [3, 4, 5]],
/// };
/// assert_eq!(component_labels(&mesh), (2, vec![0, 0, 0, 1, 1, 1]));
/// ```
pub fn component_labels(mesh: &TriangleMesh) -> (usize, Vec<u32>) {
    let n = mesh.positions.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn find(parent: &mut [u32], mut i: u32) -> u32 {
        while parent[i as usize] != i {
            let grand = parent[parent[i as usize] as usize];
            parent[i as usize] = grand;
            i = grand;
        }
        i
    }
    for t in valid_triangles(mesh) {
        for (a, b) in [(t[0], t[1]), (t[1], t[2])] {
            let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
            if ra != rb {
                // Keep the smaller index as root so labels follow vertex order.
                let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
                parent[hi as usize] = lo;
            }
        }
    }
    let mut labels = vec![u32::MAX; n];
    let mut root_label = vec![u32::MAX; n];
    let mut count = 0u32;
    for (i, label) in labels.iter_mut().enumerate() {
        let root = find(&mut parent, i as u32) as usize;
        if root_label[root] == u32::MAX {
            root_label[root] = count;
            count += 1;
        }
        *label = root_label[root];
    }
    (count as usize, labels)
}

/// Measures a mesh's topology: components, boundary and non-manifold edges, non-manifold
/// vertices, Euler characteristic and orientation consistency.
///
/// ```
/// use stablesurf::mesh::{check, TriangleMesh};
/// // A tetrahedron wound consistently: closed, χ = 2.
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 4],
///     triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
/// };
/// let r = check(&mesh);
/// assert!(r.watertight && r.orientation_consistent);
/// assert_eq!((r.euler_characteristic, r.components, r.boundary_edges), (2, 1, 0));
/// ```
pub fn check(mesh: &TriangleMesh) -> MeshReport {
    let n = mesh.positions.len();
    let triangles: Vec<[u32; 3]> = valid_triangles(mesh).collect();
    let degenerate_faces = mesh.triangles.len() - triangles.len();
    // Edges and non-manifold vertices, vertex by vertex from the triangles around it (no hash
    // map): the edge vw with v < w is counted at v, from the triangles around v that hold w.
    // The triangles around a vertex group into fans joined by the edges through it; more than
    // one fan means sheets touching at a point.
    let mut offsets = vec![0usize; n + 1];
    for t in &triangles {
        for &v in t {
            offsets[v as usize + 1] += 1;
        }
    }
    for i in 0..n {
        offsets[i + 1] += offsets[i];
    }
    let mut incident = vec![0u32; offsets[n]];
    let mut fill = offsets.clone();
    for (ti, t) in triangles.iter().enumerate() {
        for &v in t {
            incident[fill[v as usize]] = ti as u32;
            fill[v as usize] += 1;
        }
    }
    let mut non_manifold_vertices = 0;
    let mut n_edges = 0usize;
    let mut boundary_edges = 0;
    let mut non_manifold_edges = 0;
    let mut orientation_consistent = true;
    let mut parent: Vec<usize> = Vec::new();
    // (w, slot of the triangle around v, whether w follows v in that triangle's winding).
    let mut spokes: Vec<(u32, usize, bool)> = Vec::new();
    for v in 0..n {
        let around = &incident[offsets[v]..offsets[v + 1]];
        spokes.clear();
        for (slot, &ti) in around.iter().enumerate() {
            let t = triangles[ti as usize];
            for k in 0..3 {
                let w = t[k];
                if w as usize != v {
                    spokes.push((w, slot, t[(k + 2) % 3] as usize == v));
                }
            }
        }
        spokes.sort_unstable();
        // Edges vw with v < w: their uses, and the uses in the direction v → w.
        let mut g = 0;
        while g < spokes.len() {
            let w = spokes[g].0;
            let mut end = g;
            let mut forward = 0;
            while end < spokes.len() && spokes[end].0 == w {
                forward += u32::from(spokes[end].2);
                end += 1;
            }
            if w as usize > v {
                n_edges += 1;
                match end - g {
                    1 => boundary_edges += 1,
                    2 => orientation_consistent &= forward == 1,
                    _ => non_manifold_edges += 1,
                }
            }
            g = end;
        }
        if around.len() < 2 {
            continue;
        }
        parent.clear();
        parent.extend(0..around.len());
        fn root(parent: &mut [usize], mut i: usize) -> usize {
            while parent[i] != i {
                parent[i] = parent[parent[i]];
                i = parent[i];
            }
            i
        }
        for pair in spokes.windows(2) {
            if pair[0].0 == pair[1].0 {
                let (a, b) = (root(&mut parent, pair[0].1), root(&mut parent, pair[1].1));
                parent[a.max(b)] = a.min(b);
            }
        }
        let fans = (0..around.len())
            .filter(|&i| root(&mut parent, i) == i)
            .count();
        if fans > 1 {
            non_manifold_vertices += 1;
        }
    }

    let (components, _) = component_labels(mesh);
    MeshReport {
        vertices: n,
        faces: mesh.triangles.len(),
        edges: n_edges,
        components,
        boundary_edges,
        non_manifold_edges,
        non_manifold_vertices,
        degenerate_faces,
        euler_characteristic: n as i64 - n_edges as i64 + triangles.len() as i64,
        orientation_consistent,
        watertight: !triangles.is_empty()
            && boundary_edges == 0
            && non_manifold_edges == 0
            && non_manifold_vertices == 0
            && degenerate_faces == 0,
    }
}

/// Drops the connected components of `mesh` that have no point of `points` within
/// `max_distance` of one of their vertices (the paper's "extra surface pieces" away from the
/// data), and returns the remaining mesh with the number of components dropped. Kept vertices and
/// triangles stay in their original order. Distance is measured to vertices, so choose
/// `max_distance` at least about one mesh cell.
///
/// ```
/// use stablesurf::mesh::{drop_components_far_from, TriangleMesh};
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0],
///                     [9.0, 0.0, 0.0], [10.0, 0.0, 0.0], [9.0, 1.0, 0.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 6],
///     triangles: vec![[0, 1, 2], [3, 4, 5]],
/// };
/// let (kept, dropped) = drop_components_far_from(&mesh, &[[0.1, 0.1, 0.0]], 0.5);
/// assert_eq!(dropped, 1);
/// assert_eq!(kept.triangles, vec![[0, 1, 2]]);
/// ```
pub fn drop_components_far_from(
    mesh: &TriangleMesh,
    points: &[[f64; 3]],
    max_distance: f64,
) -> (TriangleMesh, usize) {
    use rayon::prelude::*;
    let (n_components, labels) = component_labels(mesh);
    // Hash the vertices into cubes of side max_distance; a point's near vertices lie in the 27
    // cubes around it.
    let cell = if max_distance > 0.0 && max_distance.is_finite() {
        max_distance
    } else {
        1.0
    };
    let key = |p: [f64; 3]| p.map(|c| (c / cell).floor() as i64);
    let mut buckets: std::collections::HashMap<[i64; 3], Vec<u32>> =
        std::collections::HashMap::new();
    for (i, &p) in mesh.positions.iter().enumerate() {
        if p.iter().all(|c| c.is_finite()) {
            buckets.entry(key(p)).or_default().push(i as u32);
        }
    }
    let r2 = max_distance * max_distance;
    let near: Vec<Vec<u32>> = points
        .par_chunks(4096)
        .map(|chunk| {
            let mut found = Vec::new();
            for &q in chunk {
                if !q.iter().all(|c| c.is_finite()) {
                    continue;
                }
                let k = key(q);
                for d in 0..27 {
                    let offset = [d % 3 - 1, (d / 3) % 3 - 1, d / 9 - 1];
                    let kk = [0, 1, 2].map(|a| k[a] + offset[a]);
                    for &i in buckets.get(&kk).into_iter().flatten() {
                        let p = mesh.positions[i as usize];
                        let d2: f64 = (0..3).map(|a| (p[a] - q[a]).powi(2)).sum();
                        if d2 <= r2 {
                            found.push(labels[i as usize]);
                        }
                    }
                }
            }
            found.sort_unstable();
            found.dedup();
            found
        })
        .collect();
    let mut keep = vec![false; n_components];
    for label in near.into_iter().flatten() {
        keep[label as usize] = true;
    }
    let mut new_index = vec![u32::MAX; mesh.positions.len()];
    let mut out = TriangleMesh::default();
    for (i, &label) in labels.iter().enumerate() {
        if keep[label as usize] {
            new_index[i] = out.positions.len() as u32;
            out.positions.push(mesh.positions[i]);
            if let Some(&n) = mesh.normals.get(i) {
                out.normals.push(n);
            }
        }
    }
    for t in &mesh.triangles {
        let mapped = t.map(|i| new_index.get(i as usize).copied().unwrap_or(u32::MAX));
        if mapped.iter().all(|&i| i != u32::MAX) {
            out.triangles.push(mapped);
        }
    }
    let dropped = keep.iter().filter(|&&k| !k).count();
    (out, dropped)
}
