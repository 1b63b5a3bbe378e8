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
pub fn check_with(mesh: &TriangleMesh, known_embedded: bool) -> MeshReport {
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
pub fn boundary_edges(triangles: &[[u32; 3]]) -> Vec<[u32; 2]> {
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
///
/// ```
/// use stablesurf::mesh::{drop_small_nested_components, TriangleMesh};
/// // A big tetrahedron and a small one inside it.
/// let tet = |s: f64, o: f64| vec![[o, o, o], [o + s, o, o], [o, o + s, o], [o, o, o + s]];
/// let mut positions = tet(10.0, 0.0);
/// positions.extend(tet(0.5, 1.0));
/// let faces = |b: u32| [[b, b + 2, b + 1], [b, b + 1, b + 3], [b, b + 3, b + 2], [b + 1, b + 2, b + 3]];
/// let mut triangles = faces(0).to_vec();
/// triangles.extend(faces(4));
/// let mesh = TriangleMesh { normals: vec![[0.0, 0.0, 1.0]; 8], positions, triangles };
/// let (kept, dropped) = drop_small_nested_components(&mesh, 0.01);
/// assert_eq!((dropped, kept.triangles.len()), (1, 4));
/// ```
pub fn drop_small_nested_components(
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
///
/// ```
/// use stablesurf::mesh::{drop_small_unsupported_components, TriangleMesh};
/// // A big triangle over many points, a tiny one beside a single point.
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0],
///                     [20.0, 0.0, 0.0], [20.1, 0.0, 0.0], [20.0, 0.1, 0.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 6],
///     triangles: vec![[0, 1, 2], [3, 4, 5]],
/// };
/// let mut points: Vec<[f64; 3]> = (0..100).map(|i| [(i % 10) as f64 * 0.5, (i / 10) as f64 * 0.5, 0.0]).collect();
/// points.push([20.05, 0.02, 0.0]);
/// let (kept, dropped) = drop_small_unsupported_components(&mesh, &points, 0.01, 15);
/// assert_eq!((dropped, kept.triangles.clone()), (1, vec![[0, 1, 2]]));
/// ```
pub fn drop_small_unsupported_components(
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

// ---------------------------------------------------------------------------------------------
// Self-intersections.

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
///
/// ```
/// use stablesurf::mesh::triangles_intersect;
/// let p = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0],
///          [0.5, 0.5, -1.0], [0.5, 0.5, 1.0], [-3.0, -3.0, 0.0]];
/// assert!(triangles_intersect([0, 1, 2], [3, 4, 5], &p));
/// assert!(!triangles_intersect([0, 1, 2], [0, 4, 5], &p));
/// ```
pub fn triangles_intersect(s: [u32; 3], t: [u32; 3], positions: &[[f64; 3]]) -> bool {
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
/// vertices and edges they share (see [`triangles_intersect`] for what counts exactly).
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
pub fn intersecting_triangles(mesh: &TriangleMesh) -> Vec<bool> {
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
mod tests {
    use super::*;

    fn mesh(positions: Vec<[f64; 3]>, triangles: Vec<[u32; 3]>) -> TriangleMesh {
        let normals = vec![[0.0, 0.0, 1.0]; positions.len()];
        TriangleMesh {
            positions,
            normals,
            triangles,
        }
    }

    /// The self-intersecting faces of the mesh of `triangles` over `positions`.
    fn crossings(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> usize {
        self_intersecting_faces(&mesh(positions.to_vec(), triangles.to_vec()))
    }

    fn sphere(center: [f64; 3], radius: f64, rings: u32, sectors: u32) -> TriangleMesh {
        lat_long_sphere(center, radius, rings, sectors)
    }

    fn merge(a: &TriangleMesh, b: &TriangleMesh) -> TriangleMesh {
        let mut out = a.clone();
        let offset = a.positions.len() as u32;
        out.positions.extend(&b.positions);
        out.normals.extend(&b.normals);
        out.triangles
            .extend(b.triangles.iter().map(|t| t.map(|i| i + offset)));
        out
    }

    #[test]
    fn two_crossing_triangles_count_two() {
        let m = mesh(
            vec![
                [0.0, 0.0, 0.0],
                [2.0, 0.0, 0.0],
                [0.0, 2.0, 0.0],
                [0.5, 0.5, -1.0],
                [0.5, 0.5, 1.0],
                [3.0, 3.0, 0.0],
            ],
            vec![[0, 1, 2], [3, 4, 5]],
        );
        assert_eq!(self_intersecting_faces(&m), 2);
        assert_eq!(check(&m).self_intersecting_faces, 2);
        // Moved apart: 0; touching at a corner (no shared index): counted.
        let mut apart = m.clone();
        apart.positions[3] = [5.0, 5.0, -1.0];
        apart.positions[4] = [5.0, 5.0, 1.0];
        assert_eq!(self_intersecting_faces(&apart), 0);
        let mut touching = m.clone();
        touching.positions[3] = [2.0, 0.0, 0.0];
        touching.positions[4] = [3.0, 0.0, 1.0];
        touching.positions[5] = [3.0, 0.0, -1.0];
        assert_eq!(self_intersecting_faces(&touching), 2);
    }

    #[test]
    fn closed_meshes_count_zero() {
        let tetra = mesh(
            vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
            ],
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        );
        assert_eq!(check(&tetra).self_intersecting_faces, 0);
        let corners: Vec<[f64; 3]> = (0..8)
            .map(|i| {
                [
                    f64::from(i & 1),
                    f64::from((i >> 1) & 1),
                    f64::from((i >> 2) & 1),
                ]
            })
            .collect();
        let cube = mesh(
            corners,
            vec![
                [0, 2, 1],
                [1, 2, 3],
                [4, 5, 6],
                [5, 7, 6],
                [0, 1, 4],
                [1, 5, 4],
                [2, 6, 3],
                [3, 6, 7],
                [0, 4, 2],
                [2, 4, 6],
                [1, 3, 5],
                [3, 7, 5],
            ],
        );
        let r = check(&cube);
        assert!(r.watertight);
        assert_eq!(r.self_intersecting_faces, 0);
        let ball = sphere([0.1, -0.2, 0.3], 1.3, 24, 48);
        let r = check(&ball);
        assert!(r.watertight);
        assert_eq!(r.self_intersecting_faces, 0);
    }

    #[test]
    fn interpenetrating_spheres_count_only_along_the_intersection() {
        let a = sphere([0.0, 0.0, 0.0], 1.0, 20, 40);
        let b = sphere([1.2, 0.1, 0.05], 1.0, 20, 40);
        let both = merge(&a, &b);
        let flags = intersecting_triangles(&both);
        let count = flags.iter().filter(|&&f| f).count();
        assert!(count > 0);
        // Every flagged triangle has corners on both sides of (near) the other sphere.
        let edge = 0.2;
        for (ti, t) in both.triangles.iter().enumerate() {
            if !flags[ti] {
                continue;
            }
            let other = if ti < a.triangles.len() {
                [1.2, 0.1, 0.05]
            } else {
                [0.0, 0.0, 0.0]
            };
            let d = t.map(|i| {
                let p = both.positions[i as usize];
                (0..3)
                    .map(|k| (p[k] - other[k]).powi(2))
                    .sum::<f64>()
                    .sqrt()
            });
            let near = d.iter().any(|&x| (x - 1.0).abs() < edge);
            assert!(
                near,
                "triangle {ti} flagged far from the intersection: {d:?}"
            );
        }
        // The same count on one thread and on several.
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| intersecting_triangles(&both));
        let three = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap()
            .install(|| intersecting_triangles(&both));
        assert_eq!(one, flags);
        assert_eq!(three, flags);
        // Apart: none.
        let c = sphere([2.5, 0.0, 0.0], 1.0, 20, 40);
        assert_eq!(self_intersecting_faces(&merge(&a, &c)), 0);
    }

    #[test]
    fn shared_edge_counts_only_a_coplanar_fold() {
        let p = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.3, 1.0, 0.0],
            [0.6, 0.8, 0.0],
            [0.5, -1.0, 0.0],
            [0.5, 1.0, 0.5],
        ];
        // Folded back onto each other in one plane.
        assert_eq!(crossings(&p, &[[0, 1, 2], [1, 0, 3]]), 2);
        // Flat, opposite sides: fine; bent along the edge: fine.
        assert_eq!(crossings(&p, &[[0, 1, 2], [1, 0, 4]]), 0);
        assert_eq!(crossings(&p, &[[0, 1, 2], [1, 0, 5]]), 0);
        // A duplicated face.
        assert_eq!(crossings(&p, &[[0, 1, 2], [2, 1, 0]]), 2);
    }

    #[test]
    fn shared_vertex_counts_only_beyond_it() {
        let p = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [-1.0, 0.0, 0.5],
            [0.0, -1.0, 0.5],
            [1.0, 1.0, -0.5],
            [1.0, 1.0, 0.5],
            [0.5, 0.2, 0.0],
            [0.2, 0.5, 0.0],
        ];
        // Touching only at the shared vertex (other triangle away, or standing on it).
        assert_eq!(crossings(&p, &[[0, 1, 2], [0, 3, 4]]), 0);
        // Piercing through the first triangle from the shared corner.
        assert_eq!(crossings(&p, &[[0, 1, 2], [0, 5, 6]]), 2);
        // Coplanar, overlapping inside the corner.
        assert_eq!(crossings(&p, &[[0, 1, 2], [0, 7, 8]]), 2);
        // Coplanar, only the corner point in common.
        let q = vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
        ];
        assert_eq!(crossings(&q, &[[0, 1, 2], [0, 3, 4]]), 0);
        // Coplanar, sharing a direction along an edge: overlap along a segment counts.
        let mut r = q;
        r[3] = [0.5, 0.0, 0.0];
        r[4] = [0.5, -1.0, 0.0];
        assert_eq!(crossings(&r, &[[0, 1, 2], [0, 3, 4]]), 2);
    }

    #[test]
    fn old_reports_parse_without_the_field() {
        let mut value = serde_json::to_value(MeshReport::default()).unwrap();
        value
            .as_object_mut()
            .unwrap()
            .remove("self_intersecting_faces");
        let r: MeshReport = serde_json::from_value(value).unwrap();
        assert_eq!(r.self_intersecting_faces, 0);
    }

    #[test]
    fn boundary_edges_are_the_edges_used_once_as_they_run() {
        // A sphere with triangles removed (holes), a fold (an edge used three times), a
        // degenerate triangle (an edge used twice by one triangle) and a lone triangle; more
        // than the radix sort's threshold of uses.
        let sphere = lat_long_sphere([0.0; 3], 1.0, 40, 60);
        let mut triangles: Vec<[u32; 3]> = sphere
            .triangles
            .iter()
            .enumerate()
            .filter(|(i, _)| i % 97 != 5)
            .map(|(_, &t)| t)
            .collect();
        let [a, b, _] = triangles[100];
        triangles.push([a, b, 7]);
        triangles.push([3, 9, 3]);
        triangles.push([5000, 5001, 5002]);
        assert!(3 * triangles.len() > 4096);
        // The reference: every use, sorted by comparison.
        let mut uses: Vec<([u32; 2], [u32; 2])> = triangles
            .iter()
            .flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3])))
            .map(|(a, b)| ([a.min(b), a.max(b)], [a, b]))
            .collect();
        uses.sort_unstable();
        let mut expected: Vec<[u32; 2]> = uses
            .chunk_by(|x, y| x.0 == y.0)
            .filter(|u| u.len() == 1)
            .map(|u| u[0].1)
            .collect();
        expected.sort_unstable();
        assert!(expected.len() > 100 && expected.contains(&[5000, 5001]));
        assert_eq!(boundary_edges(&triangles), expected);
        assert!(boundary_edges(&sphere.triangles).is_empty());
        assert!(boundary_edges(&[]).is_empty());
    }
}
