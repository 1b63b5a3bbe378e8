//! The `TriangleMesh` artifact (output of `polygonize`, input of `export`) and its topology checks.
//!
//! Invariants: positions and normals have the same length; normals are unit length; every index
//! is `< positions.len()`; triangles are wound counter-clockwise seen from outside (the side
//! where the implicit function is positive).
//!
//! Checks ([`check`] → [`MeshReport`]): an edge used by one triangle is a boundary edge, by three
//! or more a non-manifold edge; a vertex whose triangles form more than one fan (joined through
//! shared edges) is a non-manifold vertex; the orientation is consistent when every interior edge
//! is traversed once in each direction; χ = V − E + F; a triangle that meets another away from
//! their shared vertices and edges is self-intersecting ([`self_intersecting_faces`], exact
//! predicates over a uniform grid). [`component_labels`] labels connected
//! components (union–find over triangle edges), and [`drop_components_far_from`] removes the
//! components that no data point comes near (`--keep data`).

mod intersect;

#[cfg(test)]
pub(crate) use intersect::intersecting_triangles;
pub use intersect::self_intersecting_faces;
pub(crate) use intersect::{intersecting_triangles_among, triangle_box, triangles_intersect};

use crate::numerics::UnionFind;
use crate::vec3::triangle_area;
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
    pub(crate) const FORMAT_VERSION: u32 = 1;
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
    /// Closed chains of boundary edges (connected pieces of the boundary edges): 0 for a
    /// closed surface, 1 for a disc-like open patch, one more per hole. Reports written before
    /// this field read as 0.
    #[serde(default)]
    pub boundary_loops: usize,
    /// Edges used by three or more triangles.
    pub non_manifold_edges: usize,
    /// Vertices whose triangles do not form a single fan (two surface sheets touching at a
    /// point).
    pub non_manifold_vertices: usize,
    /// Triangles with a repeated vertex index or an index out of range (not counted elsewhere).
    pub degenerate_faces: usize,
    /// V − E + F (2 per sphere-like closed component, 2 − 2g for genus g).
    pub euler_characteristic: i64,
    /// The total genus (handles) of a watertight mesh's components: components − χ/2; absent
    /// for an open or non-manifold mesh.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub genus: Option<i64>,
    /// Every edge shared by two triangles is traversed in opposite directions by them.
    pub orientation_consistent: bool,
    /// The mesh has triangles, no boundary edge, no non-manifold edge or vertex and no
    /// degenerate face: a closed 2-manifold.
    pub watertight: bool,
    /// Triangles that intersect another triangle of the mesh other than at the vertices and
    /// edges they share ([`self_intersecting_faces`]); 0 for an embedded surface. Not part of
    /// `watertight`. Reports written before this field read as 0.
    #[serde(default)]
    pub self_intersecting_faces: usize,
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
pub(crate) struct VertexTriangles {
    /// Row starts, `n_vertices + 1` entries.
    pub start: Vec<usize>,
    /// Triangle indices, row by row.
    pub triangles: Vec<u32>,
}

impl VertexTriangles {
    /// Builds the rows for `n_vertices` vertices; every index in `triangles` must be below it.
    pub(crate) fn new(n_vertices: usize, triangles: &[[u32; 3]]) -> VertexTriangles {
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
    pub(crate) fn of(&self, v: usize) -> &[u32] {
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
    // The smaller index is always the root, so labels follow vertex order.
    let mut sets = UnionFind::new(n);
    for t in valid_triangles(mesh) {
        for (a, b) in [(t[0], t[1]), (t[1], t[2])] {
            sets.union(a, b);
        }
    }
    let mut labels = vec![u32::MAX; n];
    let mut root_label = vec![u32::MAX; n];
    let mut count = 0u32;
    for (i, label) in labels.iter_mut().enumerate() {
        let root = sets.find(i as u32) as usize;
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
/// assert_eq!(r.genus, Some(0));
/// // One face less: open, and no genus.
/// let open = TriangleMesh { triangles: mesh.triangles[..3].to_vec(), ..mesh };
/// assert_eq!(check(&open).genus, None);
/// ```
pub fn check(mesh: &TriangleMesh) -> MeshReport {
    check_with(mesh, false)
}

/// [`check`], without the exact crossing test when `known_embedded`: the caller vouches that no
/// triangle of `mesh` crosses another, because [`intersecting_triangles`] found none on it or on
/// a mesh it came from by removing triangles and adding ones tested against the rest (as
/// [`crate::polygonize::Polygonized::embedded`] says of a polygonized mesh, and the component
/// filter and the trim keep). `self_intersecting_faces` is then 0.
pub(crate) fn check_with(mesh: &TriangleMesh, known_embedded: bool) -> MeshReport {
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
    let mut fans = UnionFind::default();
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
        fans.reset(around.len());
        for pair in spokes.windows(2) {
            if pair[0].0 == pair[1].0 {
                fans.union(pair[0].1 as u32, pair[1].1 as u32);
            }
        }
        let n_fans = (0..around.len() as u32)
            .filter(|&i| fans.find(i) == i)
            .count();
        if n_fans > 1 {
            non_manifold_vertices += 1;
        }
    }

    let (components, _) = component_labels(mesh);
    let boundary_loops = if boundary_edges == 0 {
        0
    } else {
        boundary_pieces(n, &triangles)
    };
    let euler_characteristic = n as i64 - n_edges as i64 + triangles.len() as i64;
    let watertight = !triangles.is_empty()
        && boundary_edges == 0
        && non_manifold_edges == 0
        && non_manifold_vertices == 0
        && degenerate_faces == 0;
    // Each closed component of genus g adds 2 − 2g to the characteristic.
    let handles = 2 * components as i64 - euler_characteristic;
    MeshReport {
        vertices: n,
        faces: mesh.triangles.len(),
        edges: n_edges,
        components,
        boundary_edges,
        boundary_loops,
        non_manifold_edges,
        non_manifold_vertices,
        degenerate_faces,
        euler_characteristic,
        genus: (watertight && handles >= 0 && handles % 2 == 0).then_some(handles / 2),
        orientation_consistent,
        watertight,
        self_intersecting_faces: if known_embedded {
            0
        } else {
            self_intersecting_faces(mesh)
        },
    }
}

/// Every use of an edge by `triangles`, as (the edge's key, the index of the triangle that uses
/// it), sorted by key (a radix sort; the uses of one edge are adjacent, in triangle order). The
/// key of the edge between vertices a and b is `edge_key(a, b, n)` with `n` the second value
/// returned: one more than the largest vertex index.
fn edge_uses(triangles: &[[u32; 3]]) -> (Vec<(u64, u32)>, u64) {
    let n = triangles
        .iter()
        .flatten()
        .max()
        .map_or(0, |&m| u64::from(m) + 1);
    let mut uses: Vec<(u64, u32)> = triangles
        .iter()
        .enumerate()
        .flat_map(|(t, tri)| (0..3).map(move |k| (edge_key(tri[k], tri[(k + 1) % 3], n), t as u32)))
        .collect();
    crate::numerics::sort_pairs_by_key(&mut uses);
    (uses, n)
}

/// The key of the undirected edge between vertices `a` and `b` below `n`: min · n + max (it
/// fits: n ≤ 2³²).
#[inline]
fn edge_key(a: u32, b: u32, n: u64) -> u64 {
    u64::from(a.min(b)) * n + u64::from(a.max(b))
}

/// The boundary edges of `triangles` (edges used once), each as it runs in its triangle
/// (a → b), sorted.
pub(crate) fn boundary_edges(triangles: &[[u32; 3]]) -> Vec<[u32; 2]> {
    let (uses, n) = edge_uses(triangles);
    let mut out: Vec<[u32; 2]> = uses
        .chunk_by(|x, y| x.0 == y.0)
        .filter(|uses| uses.len() == 1)
        .filter_map(|uses| {
            // Used once, so its triangle holds it once: one of its sides has the key.
            let (key, t) = uses[0];
            let tri = triangles[t as usize];
            (0..3)
                .map(|k| [tri[k], tri[(k + 1) % 3]])
                .find(|&[a, b]| edge_key(a, b, n) == key)
        })
        .collect();
    out.sort_unstable();
    out
}

/// The number of boundary loops of `mesh` (as [`check`] counts them): connected pieces of its
/// boundary edges, 0 for a closed surface.
pub(crate) fn boundary_loops(mesh: &TriangleMesh) -> usize {
    let triangles: Vec<[u32; 3]> = valid_triangles(mesh).collect();
    boundary_pieces(mesh.positions.len(), &triangles)
}

/// Connected pieces of the boundary edges of `triangles` (vertices below `n_vertices`): the
/// number of boundary loops of a manifold mesh.
fn boundary_pieces(n_vertices: usize, triangles: &[[u32; 3]]) -> usize {
    let edges = boundary_edges(triangles);
    let mut sets = UnionFind::new(n_vertices);
    let mut pieces = 0usize;
    let mut on_boundary = vec![false; n_vertices];
    for &[a, b] in &edges {
        for v in [a, b] {
            if !on_boundary[v as usize] {
                on_boundary[v as usize] = true;
                pieces += 1;
            }
        }
        if sets.union(a, b) {
            pieces -= 1;
        }
    }
    pieces
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
    let distances = crate::numerics::point_tree::nearest_point_distances(&mesh.positions, points)
        .unwrap_or_else(|| vec![f64::INFINITY; mesh.positions.len()]);
    drop_components_by_distance(mesh, &distances, max_distance)
}

/// [`drop_components_far_from`] given each vertex's distance to the nearest data point
/// (`vertex_distances`, one per vertex; NaN counts as far): a component is kept when one of its
/// vertices lies within `max_distance`.
pub(crate) fn drop_components_by_distance(
    mesh: &TriangleMesh,
    vertex_distances: &[f64],
    max_distance: f64,
) -> (TriangleMesh, usize) {
    let (n_components, labels) = component_labels(mesh);
    let mut keep = vec![false; n_components];
    for (&label, &d) in labels.iter().zip(vertex_distances) {
        if d <= max_distance {
            keep[label as usize] = true;
        }
    }
    let dropped = keep.iter().filter(|&&k| !k).count();
    (keep_components(mesh, &labels, &keep), dropped)
}

/// The vertices and triangles of `mesh` whose component (`labels`, per vertex) is marked in
/// `keep`, in their original order.
fn keep_components(mesh: &TriangleMesh, labels: &[u32], keep: &[bool]) -> TriangleMesh {
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
    out
}

/// The area of each of the `n_components` components of `mesh` (`labels`, per vertex, as
/// [`component_labels`] gives them), summed over its valid triangles in mesh order.
fn component_areas(mesh: &TriangleMesh, labels: &[u32], n_components: usize) -> Vec<f64> {
    let mut area = vec![0.0; n_components];
    for t in valid_triangles(mesh) {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        area[labels[t[0] as usize] as usize] += triangle_area(a, b, c);
    }
    area
}

/// Drops the closed components of `mesh` whose area is below `max_fraction` of the largest
/// component's and that lie inside another, larger component (by the parity of a ray's
/// crossings from one of their vertices), and returns the rest with the number dropped. These
/// are the small bubbles an implicit fit leaves inside thin parts (a duck's beak: seven, each
/// under 0.13% of the area); a scanner never sees an object's inside, and a void of a
/// mesh's own is rarely that small. Kept vertices and triangles stay in their order.
pub(crate) fn drop_small_nested_components(
    mesh: &TriangleMesh,
    max_fraction: f64,
) -> (TriangleMesh, usize) {
    let (n_components, labels) = component_labels(mesh);
    if n_components < 2 {
        return (mesh.clone(), 0);
    }
    // Only closed meshes have an inside: every edge used by exactly two triangles, or nothing
    // is dropped.
    let triangles: Vec<[u32; 3]> = valid_triangles(mesh).collect();
    if !edge_uses(&triangles)
        .0
        .chunk_by(|x, y| x.0 == y.0)
        .all(|uses| uses.len() == 2)
    {
        return (mesh.clone(), 0);
    }
    let area = component_areas(mesh, &labels, n_components);
    let mut tris_of: Vec<Vec<[u32; 3]>> = vec![Vec::new(); n_components];
    for t in triangles {
        tris_of[labels[t[0] as usize] as usize].push(t);
    }
    let largest = area.iter().copied().fold(0.0, f64::max);
    let mut keep = vec![true; n_components];
    let first_vertex: Vec<Option<u32>> = (0..n_components)
        .map(|c| tris_of[c].first().map(|t| t[0]))
        .collect();
    for c in 0..n_components {
        if area[c] >= max_fraction * largest || area[c].is_nan() {
            continue;
        }
        let Some(v) = first_vertex[c] else { continue };
        let p = mesh.positions[v as usize];
        keep[c] = !(0..n_components)
            .filter(|&o| o != c && area[o] > area[c])
            .any(|o| ray_parity_inside(p, &tris_of[o], &mesh.positions));
    }
    let dropped = keep.iter().filter(|&&k| !k).count();
    if dropped == 0 {
        return (mesh.clone(), 0);
    }
    (keep_components(mesh, &labels, &keep), dropped)
}

/// Drops the components of `mesh` whose area is below `max_fraction` of the largest
/// component's and whose bounding box holds fewer than `min_points` of `points`, and returns the
/// rest with the number dropped. These are the small pieces the blend grows around a stray point
/// or two beside the surface (too few points for a local fit to stand on); a small part the
/// data samples keeps its points. Kept vertices and triangles stay in their order. Cost: one
/// pass over `points` per small component, stopped at `min_points`.
pub(crate) fn drop_small_unsupported_components(
    mesh: &TriangleMesh,
    points: &[[f64; 3]],
    max_fraction: f64,
    min_points: usize,
) -> (TriangleMesh, usize) {
    let (n_components, labels) = component_labels(mesh);
    if n_components < 2 {
        return (mesh.clone(), 0);
    }
    let area = component_areas(mesh, &labels, n_components);
    let largest = area.iter().copied().fold(0.0, f64::max);
    let mut boxes = vec![([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]); n_components];
    for (p, &label) in mesh.positions.iter().zip(&labels) {
        let (lo, hi) = &mut boxes[label as usize];
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let mut keep = vec![true; n_components];
    for c in 0..n_components {
        // A NaN area is never small.
        if area[c] >= max_fraction * largest || area[c].is_nan() {
            continue;
        }
        let (lo, hi) = boxes[c];
        let inside = points
            .iter()
            .filter(|p| (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]))
            .take(min_points)
            .count();
        keep[c] = inside >= min_points;
    }
    let dropped = keep.iter().filter(|&&k| !k).count();
    if dropped == 0 {
        return (mesh.clone(), 0);
    }
    (keep_components(mesh, &labels, &keep), dropped)
}

/// Whether `p` is inside the closed surface `triangles` by the parity of the crossings of a ray
/// from `p` in a fixed direction chosen off the axes (a ray through an edge or a vertex is
/// unlikely; such a point is then misjudged, which only keeps or drops one small bubble).
fn ray_parity_inside(p: [f64; 3], triangles: &[[u32; 3]], positions: &[[f64; 3]]) -> bool {
    let dir = [0.577_215_664_9, 0.312_761_431_7, 0.759_134_847_2];
    let mut crossings = 0usize;
    for t in triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        // Möller–Trumbore.
        let e1 = [0, 1, 2].map(|k| b[k] - a[k]);
        let e2 = [0, 1, 2].map(|k| c[k] - a[k]);
        let h = [
            dir[1] * e2[2] - dir[2] * e2[1],
            dir[2] * e2[0] - dir[0] * e2[2],
            dir[0] * e2[1] - dir[1] * e2[0],
        ];
        let det = e1[0] * h[0] + e1[1] * h[1] + e1[2] * h[2];
        if det.abs() < 1e-300 {
            continue;
        }
        let f = 1.0 / det;
        let s = [0, 1, 2].map(|k| p[k] - a[k]);
        let u = f * (s[0] * h[0] + s[1] * h[1] + s[2] * h[2]);
        if !(0.0..=1.0).contains(&u) {
            continue;
        }
        let q = [
            s[1] * e1[2] - s[2] * e1[1],
            s[2] * e1[0] - s[0] * e1[2],
            s[0] * e1[1] - s[1] * e1[0],
        ];
        let v = f * (dir[0] * q[0] + dir[1] * q[1] + dir[2] * q[2]);
        if v < 0.0 || u + v > 1.0 {
            continue;
        }
        let t_hit = f * (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]);
        if t_hit > 0.0 {
            crossings += 1;
        }
    }
    crossings % 2 == 1
}

/// The triangles on each undirected edge, in compressed rows over the sorted edges.
pub(crate) struct EdgeMap {
    /// For each triangle, the index of each of its three edges (edge k runs from corner k to
    /// corner k + 1).
    of_triangle: Vec<[u32; 3]>,
    /// `start[e]..start[e + 1]` are edge e's triangles in `triangles`.
    start: Vec<u32>,
    triangles: Vec<u32>,
    /// Each edge's ends, lower index first.
    ends: Vec<[u32; 2]>,
}

impl EdgeMap {
    /// The edges of `tris`, numbered in the order of their (lower, higher) vertex indices.
    pub(crate) fn new(tris: &[[u32; 3]]) -> EdgeMap {
        use rayon::prelude::*;
        let mut uses: Vec<(u32, u32, u32, u8)> = tris
            .iter()
            .enumerate()
            .flat_map(|(ti, t)| {
                (0..3).map(move |k| {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    (a.min(b), a.max(b), ti as u32, k as u8)
                })
            })
            .collect();
        uses.par_sort_unstable();
        let mut of_triangle = vec![[0u32; 3]; tris.len()];
        let mut start = Vec::new();
        let mut triangles = Vec::with_capacity(uses.len());
        let mut ends = Vec::new();
        let mut e = 0u32;
        for (i, u) in uses.iter().enumerate() {
            if i == 0 || (uses[i - 1].0, uses[i - 1].1) != (u.0, u.1) {
                if i > 0 {
                    e += 1;
                }
                start.push(i as u32);
                ends.push([u.0, u.1]);
            }
            of_triangle[u.2 as usize][u.3 as usize] = e;
            triangles.push(u.2);
        }
        start.push(uses.len() as u32);
        EdgeMap {
            of_triangle,
            start,
            triangles,
            ends,
        }
    }

    /// The number of edges.
    pub(crate) fn len(&self) -> usize {
        self.start.len() - 1
    }

    /// The indices of triangle `t`'s edges (edge k runs from corner k to corner k + 1).
    pub(crate) fn of_triangle(&self, t: usize) -> [u32; 3] {
        self.of_triangle[t]
    }

    /// The ends of edge `e`, lower index first.
    pub(crate) fn ends(&self, e: u32) -> [u32; 2] {
        self.ends[e as usize]
    }

    /// The triangles on edge `e`, in triangle order.
    pub(crate) fn triangles_of(&self, e: u32) -> &[u32] {
        &self.triangles[self.start[e as usize] as usize..self.start[e as usize + 1] as usize]
    }
}

/// A closed latitude–longitude sphere with `rings` bands and `sectors` wedges, wound outwards,
/// with radial unit normals: a test mesh for the mesh checks and the decimation.
#[cfg(test)]
pub(crate) fn lat_long_sphere(
    center: [f64; 3],
    radius: f64,
    rings: u32,
    sectors: u32,
) -> TriangleMesh {
    let mut normals = vec![[0.0, 0.0, 1.0]];
    for r in 1..rings {
        let theta = std::f64::consts::PI * f64::from(r) / f64::from(rings);
        for s in 0..sectors {
            let phi = 2.0 * std::f64::consts::PI * f64::from(s) / f64::from(sectors);
            normals.push([
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            ]);
        }
    }
    normals.push([0.0, 0.0, -1.0]);
    let positions = normals
        .iter()
        .map(|n| std::array::from_fn(|a| center[a] + radius * n[a]))
        .collect();
    let south = normals.len() as u32 - 1;
    let at = |r: u32, s: u32| 1 + (r - 1) * sectors + s % sectors;
    let mut triangles = Vec::new();
    for s in 0..sectors {
        triangles.push([0, at(1, s), at(1, s + 1)]);
        triangles.push([south, at(rings - 1, s + 1), at(rings - 1, s)]);
    }
    for r in 1..rings - 1 {
        for s in 0..sectors {
            triangles.push([at(r, s), at(r + 1, s), at(r + 1, s + 1)]);
            triangles.push([at(r, s), at(r + 1, s + 1), at(r, s + 1)]);
        }
    }
    TriangleMesh {
        positions,
        normals,
        triangles,
    }
}

/// The unit square [0, 1]² at z = 0 as two triangles facing +z: a fixture of the tests.
#[cfg(test)]
pub(crate) fn unit_square() -> TriangleMesh {
    TriangleMesh {
        positions: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ],
        normals: vec![[0.0, 0.0, 1.0]; 4],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
    }
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn vertex_triangles_new() {
        let around = crate::mesh::VertexTriangles::new(4, &[[0, 1, 2], [0, 2, 3]]);
        assert_eq!(around.of(0), &[0, 1]);
        assert_eq!(around.of(3), &[1]);
    }

    #[test]
    fn drop_small_nested_components() {
        use crate::mesh::{drop_small_nested_components, TriangleMesh};
        // A big tetrahedron and a small one inside it.
        let tet = |s: f64, o: f64| vec![[o, o, o], [o + s, o, o], [o, o + s, o], [o, o, o + s]];
        let mut positions = tet(10.0, 0.0);
        positions.extend(tet(0.5, 1.0));
        let faces = |b: u32| {
            [
                [b, b + 2, b + 1],
                [b, b + 1, b + 3],
                [b, b + 3, b + 2],
                [b + 1, b + 2, b + 3],
            ]
        };
        let mut triangles = faces(0).to_vec();
        triangles.extend(faces(4));
        let mesh = TriangleMesh {
            normals: vec![[0.0, 0.0, 1.0]; 8],
            positions,
            triangles,
        };
        let (kept, dropped) = drop_small_nested_components(&mesh, 0.01);
        assert_eq!((dropped, kept.triangles.len()), (1, 4));
    }

    #[test]
    fn drop_small_unsupported_components() {
        use crate::mesh::{drop_small_unsupported_components, TriangleMesh};
        // A big triangle over many points, a tiny one beside a single point.
        let mesh = TriangleMesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [10.0, 0.0, 0.0],
                [0.0, 10.0, 0.0],
                [20.0, 0.0, 0.0],
                [20.1, 0.0, 0.0],
                [20.0, 0.1, 0.0],
            ],
            normals: vec![[0.0, 0.0, 1.0]; 6],
            triangles: vec![[0, 1, 2], [3, 4, 5]],
        };
        let mut points: Vec<[f64; 3]> = (0..100)
            .map(|i| [(i % 10) as f64 * 0.5, (i / 10) as f64 * 0.5, 0.0])
            .collect();
        points.push([20.05, 0.02, 0.0]);
        let (kept, dropped) = drop_small_unsupported_components(&mesh, &points, 0.01, 15);
        assert_eq!((dropped, kept.triangles.clone()), (1, vec![[0, 1, 2]]));
    }
}
