//! Extraction of the `polygonize` stage: marching tetrahedra on a conforming tetrahedralization
//! of the octree's surface leaves, and placement of the mesh vertices on the zero set.
//!
//! Input: the [`Octree`] and the function. Output: triangles named by the lattice edges they
//! cross (phase 1), then one vertex per crossed edge, on the zero set (phase 2).
//!
//! Invariants: every lattice point has one sign (f ≥ 0 counts as outside), computed from one
//! formula, so neighbouring cells agree on it; the tetrahedra of neighbouring leaves meet face to
//! face (below), so each crossed tetrahedron edge is shared by exactly the triangles around it and
//! the surface is a closed 2-manifold away from the region's boundary; each triangle is wound
//! counter-clockwise seen from its positive (outside) side.
//!
//! # Why the mesh is watertight and manifold
//!
//! Marching tetrahedra computes the zero set of the piecewise-linear interpolant of the vertex
//! signs over a tetrahedral complex. When no sample is exactly a root of the interpolant (our
//! sign convention makes every sample strictly positive or strictly negative), that zero set is a
//! 2-manifold, closed wherever the complex has no boundary (Bloomenthal, *Polygonization of
//! implicit surfaces*, CAGD 1988; Doi & Koide, *An efficient method of triangulating
//! equi-valued surfaces by using tetrahedral cells*, IEICE 1991). The only requirement is that
//! the tetrahedra form a *complex*: two tetrahedra meet in a common face, edge, vertex or not at
//! all. Neighbouring octree leaves of different sizes break that unless their shared faces are
//! triangulated the same way from both sides, which is done here:
//!
//! * Every leaf face is tiled by *elementary squares*: the face itself when the neighbour across
//!   it is not subdivided at this level, otherwise the faces of the neighbour's descendants that
//!   lie on it. Both sides of a face find the same squares.
//! * The boundary of an elementary square holds its 4 corners and every leaf corner lying on its
//!   sides (the *hanging points*, found by looking at the 4 cells around each side); both sides
//!   and every other square along that side find the same points.
//! * A square with no hanging point is split along its min-to-max diagonal; one with hanging
//!   points is fanned from its centre.
//! * A leaf whose 18 face and edge neighbours are not subdivided ("regular", every leaf when the
//!   topology guard split nothing) is cut into the 6 Kuhn (Freudenthal) tetrahedra around its
//!   min-to-max diagonal, which cut each of its faces along the min-to-max diagonal too. Any other
//!   leaf is cut into tetrahedra joining its centre to the triangles of its face tiling.
//!
//! ```text
//!   regular leaf: 6 Kuhn tetrahedra      transition leaf: cone from the centre
//!   +-------+                            +---+---+      (face next to finer
//!   |     / |    every face split         | \ | / |       cells, fanned from
//!   |   /   |    along min→max            +---o---+       its centre)
//!   | /     |                            | / | \ |
//!   +-------+                            +---+---+
//! ```
//!
//! Leaves the octree discarded need no tetrahedra: f has one strict sign on their closed box, so
//! no crossed edge lies on their faces, and a surface leaf next to one cannot leave a gap there.
//!
//! Each mesh vertex is the root of f on its lattice edge, found by the Illinois variant of
//! regula falsi, then Newton steps x ← x − f∇f/|∇f|² until |f|/|∇f| is below the projection
//! tolerance; its normal is ∇f/|∇f|.

use std::collections::hash_map::Entry;
use std::collections::HashMap;
use std::hash::BuildHasherDefault;

use rayon::prelude::*;

use super::grid::{pack, unpack, Grid, MultiplyHasher};
use super::octree::{Cell, Octree};
use crate::implicit::ImplicitFunction;
use crate::vec3::norm;

/// A lattice edge: the packed keys of its two ends, smaller one in the high half.
pub(crate) type EdgeKey = u128;

/// Leaves per parallel task (fixed, so the work split never depends on the thread count). Each
/// task evaluates the lattice points of its leaves once, so points on the border between two
/// tasks are evaluated twice: larger tasks evaluate fewer border points, and this size still
/// gives the threads enough tasks to balance.
const LEAVES_PER_TASK: usize = 2048;

/// Edges per parallel task in vertex placement.
const EDGES_PER_TASK: usize = 1024;

/// The 6 permutations of the axes: each gives one Kuhn tetrahedron.
const KUHN: [[usize; 3]; 6] = [
    [0, 1, 2],
    [0, 2, 1],
    [1, 0, 2],
    [1, 2, 0],
    [2, 0, 1],
    [2, 1, 0],
];

/// The triangles of all surface leaves: the crossed edges (sorted, unique) that become the mesh
/// vertices, f at their two ends (smaller key first), the triangles as indices into them (in
/// leaf order), and the evaluations spent.
#[allow(clippy::type_complexity)]
pub(crate) fn triangulate<F: ImplicitFunction + ?Sized>(
    function: &F,
    grid: &Grid,
    octree: &Octree,
) -> (Vec<EdgeKey>, Vec<[f64; 2]>, Vec<[u32; 3]>, u64) {
    // Each task names its crossed edges once (local indices), so the global sort below handles
    // each edge about once per task that sees it rather than once per triangle corner.
    let parts: Vec<(Vec<EdgeKey>, Vec<[f64; 2]>, Vec<[u32; 3]>, u64)> = octree
        .leaves
        .par_chunks(LEAVES_PER_TASK)
        .map(|chunk| {
            let mut ctx = LeafContext {
                function,
                grid,
                octree,
                // Sized for the usual counts per leaf (about 2 new lattice points, 3 new
                // crossed edges and 6 triangles), so the tables rarely grow.
                triangles: Vec::with_capacity(8 * chunk.len()),
                evaluations: 0,
                values: PointValues::with_capacity_and_hasher(
                    4 * chunk.len(),
                    BuildHasherDefault::default(),
                ),
            };
            for &leaf in chunk {
                ctx.leaf(leaf);
            }
            let mut local: HashMap<EdgeKey, u32, BuildHasherDefault<MultiplyHasher>> =
                HashMap::with_capacity_and_hasher(4 * chunk.len(), BuildHasherDefault::default());
            let mut edges = Vec::with_capacity(4 * chunk.len());
            let triangles = ctx
                .triangles
                .iter()
                .map(|tri| {
                    tri.map(|key| {
                        *local.entry(key).or_insert_with(|| {
                            edges.push(key);
                            (edges.len() - 1) as u32
                        })
                    })
                })
                .collect();
            // Every end of a crossed edge was evaluated in this task.
            let ends = edges
                .iter()
                .map(|&key| {
                    let value = |k: u64| ctx.values.get(&k).copied().unwrap_or(f64::NAN);
                    [value((key >> 64) as u64), value(key as u64)]
                })
                .collect();
            (edges, ends, triangles, ctx.evaluations)
        })
        .collect();
    let mut edges: Vec<EdgeKey> = Vec::with_capacity(parts.iter().map(|p| p.0.len()).sum());
    for part in &parts {
        edges.extend_from_slice(&part.0);
    }
    edges.par_sort_unstable();
    edges.dedup();
    let remapped: Vec<(Vec<u32>, Vec<[u32; 3]>)> = parts
        .par_iter()
        .map(|(local_edges, _, triangles, _)| {
            let global: Vec<u32> = local_edges
                .iter()
                .map(|key| edges.binary_search(key).unwrap_or(0) as u32)
                .collect();
            let triangles = triangles
                .iter()
                .map(|t| t.map(|i| global[i as usize]))
                .collect();
            (global, triangles)
        })
        .collect();
    // Tasks that share an edge computed the same end values (one formula per lattice point).
    // The two gathers below are sequential; each runs on its own core.
    let (end_values, triangles) = rayon::join(
        || {
            let mut end_values = vec![[f64::NAN; 2]; edges.len()];
            for ((global, _), part) in remapped.iter().zip(&parts) {
                for (&g, &ends) in global.iter().zip(&part.1) {
                    end_values[g as usize] = ends;
                }
            }
            end_values
        },
        || {
            let mut triangles = Vec::with_capacity(remapped.iter().map(|(_, t)| t.len()).sum());
            for (_, part) in &remapped {
                triangles.extend_from_slice(part);
            }
            triangles
        },
    );
    let evaluations = parts.iter().map(|p| p.3).sum();
    (edges, end_values, triangles, evaluations)
}

/// An elementary square on a leaf face.
#[derive(Clone, Copy, Debug)]
struct Square {
    /// Normal axis of the face.
    axis: usize,
    /// Smallest lattice corner.
    min: [u64; 3],
    /// Side in lattice steps.
    side: u64,
    /// Octree level of the cell whose face this is.
    level: u32,
}

struct LeafContext<'a, F: ?Sized> {
    function: &'a F,
    grid: &'a Grid,
    octree: &'a Octree,
    triangles: Vec<[EdgeKey; 3]>,
    evaluations: u64,
    /// Values at the lattice points seen in this task (neighbouring leaves share corners).
    values: PointValues,
}

impl<F: ImplicitFunction + ?Sized> LeafContext<'_, F> {
    fn is_internal(&self, level: u32, coords: [i64; 3]) -> bool {
        if self.octree.internal.is_empty() || level < self.grid.depth || level >= self.grid.cap {
            return false;
        }
        if !self.grid.in_range(level, coords) {
            return false;
        }
        let cell = Cell {
            level,
            coords: coords.map(|c| c as u32),
        };
        self.octree.internal.contains(&self.grid.cell_key(cell))
    }

    /// f at a lattice point, computed once per task.
    fn value(&mut self, l: [u64; 3]) -> f64 {
        // One probe of the table whether or not the point is new.
        match self.values.entry(pack(l)) {
            Entry::Occupied(known) => *known.get(),
            Entry::Vacant(slot) => {
                self.evaluations += 1;
                *slot.insert(self.function.value(self.grid.point(l)))
            }
        }
    }

    fn leaf(&mut self, leaf: Cell) {
        if self.is_regular(leaf) {
            self.regular_leaf(leaf);
        } else {
            self.transition_leaf(leaf);
        }
    }

    /// No face or edge neighbour at the leaf's level is subdivided.
    fn is_regular(&self, leaf: Cell) -> bool {
        if self.octree.internal.is_empty() {
            return true;
        }
        let c = leaf.coords.map(i64::from);
        for dz in -1..=1i64 {
            for dy in -1..=1i64 {
                for dx in -1..=1i64 {
                    let nonzero = [dx, dy, dz].iter().filter(|&&d| d != 0).count();
                    if (nonzero == 1 || nonzero == 2)
                        && self.is_internal(leaf.level, [c[0] + dx, c[1] + dy, c[2] + dz])
                    {
                        return false;
                    }
                }
            }
        }
        true
    }

    fn regular_leaf(&mut self, leaf: Cell) {
        let min = self.grid.cell_min(leaf);
        let side = self.grid.cell_side(leaf.level);
        let corner = |bits: usize| [0, 1, 2].map(|a| min[a] + side * ((bits >> a) & 1) as u64);
        let mut values = [0.0; 8];
        for (bits, v) in values.iter_mut().enumerate() {
            *v = self.value(corner(bits));
        }
        if values.iter().all(|&v| v >= 0.0) || values.iter().all(|&v| v < 0.0) {
            return;
        }
        for perm in KUHN {
            let b1 = 1 << perm[0];
            let b2 = b1 | 1 << perm[1];
            let ids = [0, b1, b2, 7];
            march(ids.map(corner), ids.map(|i| values[i]), &mut self.triangles);
        }
    }

    fn transition_leaf(&mut self, leaf: Cell) {
        let min = self.grid.cell_min(leaf);
        let side = self.grid.cell_side(leaf.level);
        let center = min.map(|c| c + side / 2);
        let mut squares = Vec::new();
        for axis in 0..3 {
            for upper in [false, true] {
                let mut neighbour = leaf.coords.map(i64::from);
                neighbour[axis] += if upper { 1 } else { -1 };
                let plane = min[axis] + if upper { side } else { 0 };
                self.tile(leaf.level, neighbour, axis, upper, plane, &mut squares);
            }
        }
        let mut boundary = Vec::new();
        for square in squares {
            boundary.clear();
            self.square_boundary(square, &mut boundary);
            if boundary.len() == 4 {
                self.tetrahedron([center, boundary[0], boundary[1], boundary[2]]);
                self.tetrahedron([center, boundary[0], boundary[2], boundary[3]]);
            } else {
                let (u, v) = other_axes(square.axis);
                let mut middle = square.min;
                middle[u] += square.side / 2;
                middle[v] += square.side / 2;
                for i in 0..boundary.len() {
                    let next = boundary[(i + 1) % boundary.len()];
                    self.tetrahedron([center, middle, boundary[i], next]);
                }
            }
        }
    }

    fn tetrahedron(&mut self, points: [[u64; 3]; 4]) {
        let mut values = [0.0; 4];
        for (v, p) in values.iter_mut().zip(points) {
            *v = self.value(p);
        }
        march(points, values, &mut self.triangles);
    }

    /// Elementary squares on the plane between a leaf and the cell `coords` at `level` across it
    /// (`upper`: the cell lies on the leaf's +axis side).
    fn tile(
        &self,
        level: u32,
        coords: [i64; 3],
        axis: usize,
        upper: bool,
        plane: u64,
        out: &mut Vec<Square>,
    ) {
        if !self.is_internal(level, coords) {
            let side = self.grid.cell_side(level);
            let mut min = coords.map(|c| c.max(0) as u64 * side);
            min[axis] = plane;
            out.push(Square {
                axis,
                min,
                side,
                level,
            });
            return;
        }
        let (u, v) = other_axes(axis);
        for bits in 0..4 {
            let mut child = coords.map(|c| 2 * c);
            child[axis] += if upper { 0 } else { 1 };
            child[u] += bits & 1;
            child[v] += (bits >> 1) & 1;
            self.tile(level + 1, child, axis, upper, plane, out);
        }
    }

    /// The square's boundary points in cyclic order: corners and hanging points.
    fn square_boundary(&self, square: Square, out: &mut Vec<[u64; 3]>) {
        let (u, v) = other_axes(square.axis);
        let s = square.side;
        let at = |du: u64, dv: u64| {
            let mut p = square.min;
            p[u] += du;
            p[v] += dv;
            p
        };
        let mut side_points = Vec::new();
        // Four sides: along u at v = 0, along v at u = s, back along u at v = s, back along v.
        for (start, axis, reverse) in [
            (at(0, 0), u, false),
            (at(s, 0), v, false),
            (at(0, s), u, true),
            (at(0, 0), v, true),
        ] {
            side_points.clear();
            self.edge_points(square.level, start, axis, &mut side_points);
            let first = if reverse {
                let mut end = start;
                end[axis] += s;
                end
            } else {
                start
            };
            out.push(first);
            if reverse {
                out.extend(side_points.iter().rev());
            } else {
                out.extend(side_points.iter());
            }
        }
    }

    /// Leaf corners strictly inside the side of a level-`level` cell that starts at `start` and
    /// runs along `axis`, in increasing order.
    fn edge_points(&self, level: u32, start: [u64; 3], axis: usize, out: &mut Vec<[u64; 3]>) {
        if level >= self.grid.cap {
            return;
        }
        let side = self.grid.cell_side(level);
        let (p1, p2) = other_axes(axis);
        let base = start.map(|c| (c / side) as i64);
        let mut any = false;
        for bits in 0..4 {
            let mut c = base;
            c[p1] -= bits & 1;
            c[p2] -= (bits >> 1) & 1;
            if self.is_internal(level, c) {
                any = true;
                break;
            }
        }
        if !any {
            return;
        }
        let half = side / 2;
        let mut middle = start;
        middle[axis] += half;
        self.edge_points(level + 1, start, axis, out);
        out.push(middle);
        self.edge_points(level + 1, middle, axis, out);
    }
}

/// A map from packed lattice points to f, hashed by one multiplication (the keys are distinct
/// integers; no protection against adversarial keys is needed).
type PointValues = HashMap<u64, f64, BuildHasherDefault<MultiplyHasher>>;

/// The two axes other than `axis`, in increasing order.
fn other_axes(axis: usize) -> (usize, usize) {
    match axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    }
}

/// The key of the edge between two lattice points.
fn edge_key(a: [u64; 3], b: [u64; 3]) -> EdgeKey {
    let (ka, kb) = (pack(a), pack(b));
    let (lo, hi) = if ka < kb { (ka, kb) } else { (kb, ka) };
    (u128::from(lo) << 64) | u128::from(hi)
}

/// Marching tetrahedra on one tetrahedron: appends 0, 1 or 2 triangles, wound so that their
/// normal points to the positive side.
fn march(points: [[u64; 3]; 4], values: [f64; 4], out: &mut Vec<[EdgeKey; 3]>) {
    let positive = values.map(|v| v >= 0.0);
    let n_positive = positive.iter().filter(|&&p| p).count();
    match n_positive {
        1 | 3 => {
            let lone = (0..4)
                .position(|i| positive[i] == (n_positive == 1))
                .unwrap_or(0);
            let others: Vec<usize> = (0..4).filter(|&i| i != lone).collect();
            let reference = if n_positive == 1 { lone } else { others[0] };
            let tri = [0, 1, 2].map(|t| (lone, others[t]));
            emit(&points, tri, reference, out);
        }
        2 => {
            let pos: Vec<usize> = (0..4).filter(|&i| positive[i]).collect();
            let neg: Vec<usize> = (0..4).filter(|&i| !positive[i]).collect();
            let quad = [
                (pos[0], neg[0]),
                (pos[0], neg[1]),
                (pos[1], neg[1]),
                (pos[1], neg[0]),
            ];
            emit(&points, [quad[0], quad[1], quad[2]], pos[0], out);
            emit(&points, [quad[0], quad[2], quad[3]], pos[0], out);
        }
        _ => {}
    }
}

/// Appends the triangle through the tetrahedron edges `tri`, wound so that its normal points
/// towards the positive vertex `reference`. The winding is decided on the edge midpoints in exact
/// integer arithmetic: that plane separates the positive from the negative vertices, and the map
/// from lattice to input coordinates scales each axis by a positive factor, which keeps the
/// orientation.
fn emit(
    points: &[[u64; 3]; 4],
    tri: [(usize, usize); 3],
    reference: usize,
    out: &mut Vec<[EdgeKey; 3]>,
) {
    let doubled = |(i, j): (usize, usize)| [0, 1, 2].map(|a| (points[i][a] + points[j][a]) as i64);
    let m = tri.map(doubled);
    let d1 = [0, 1, 2].map(|a| m[1][a] - m[0][a]);
    let d2 = [0, 1, 2].map(|a| m[2][a] - m[0][a]);
    let normal = [
        d1[1] * d2[2] - d1[2] * d2[1],
        d1[2] * d2[0] - d1[0] * d2[2],
        d1[0] * d2[1] - d1[1] * d2[0],
    ];
    let r = points[reference].map(|c| 2 * c as i64);
    let side: i64 = (0..3).map(|a| normal[a] * (r[a] - m[0][a])).sum();
    debug_assert!(side != 0, "degenerate tetrahedron");
    let keys = tri.map(|(i, j)| edge_key(points[i], points[j]));
    if side > 0 {
        out.push(keys);
    } else {
        out.push([keys[0], keys[2], keys[1]]);
    }
}

/// For each crossed edge: the root of the linear interpolant of its end values (no evaluation)
/// and its cell size (the edge's longest extent along one axis, input units).
pub(crate) fn approximate_vertices(
    grid: &Grid,
    edges: &[EdgeKey],
    end_values: &[[f64; 2]],
) -> (Vec<[f64; 3]>, Vec<f64>) {
    edges
        .par_iter()
        .zip(end_values)
        .map(|(&key, &[fa, fb])| {
            let (la, lb) = (unpack((key >> 64) as u64), unpack(key as u64));
            let (a, b) = (grid.point(la), grid.point(lb));
            let s = if fa == fb {
                0.5
            } else {
                (fa / (fa - fb)).clamp(0.0, 1.0)
            };
            let p = [0, 1, 2].map(|k| a[k] + s * (b[k] - a[k]));
            let size = (0..3).map(|k| (b[k] - a[k]).abs()).fold(0.0, f64::max);
            (p, size)
        })
        .unzip()
}

/// A mesh vertex on the zero set.
#[derive(Clone, Copy, Debug)]
pub(crate) struct PlacedVertex {
    pub position: [f64; 3],
    pub normal: [f64; 3],
    /// |f|/|∇f| at `position` (input units).
    pub residual: f64,
    pub evaluations: u64,
}

/// Places one vertex per edge (`edges` sorted and unique), in the same order.
pub(crate) fn place_vertices<F: ImplicitFunction + ?Sized>(
    function: &F,
    grid: &Grid,
    edges: &[EdgeKey],
    end_values: &[[f64; 2]],
    projection_tolerance: f64,
) -> Vec<PlacedVertex> {
    edges
        .par_chunks(EDGES_PER_TASK)
        .zip(end_values.par_chunks(EDGES_PER_TASK))
        .map(|(chunk, values)| {
            chunk
                .iter()
                .zip(values)
                .map(|(&key, &ends)| place_vertex(function, grid, key, ends, projection_tolerance))
                .collect::<Vec<_>>()
        })
        .collect::<Vec<_>>()
        .concat()
}

/// The vertex on the zero set for the crossed edge `key` with end values `[fa, fb]` (see the
/// module docs): the same result wherever and whenever it is computed.
pub(crate) fn place_vertex<F: ImplicitFunction + ?Sized>(
    function: &F,
    grid: &Grid,
    key: EdgeKey,
    [fa, fb]: [f64; 2],
    tolerance: f64,
) -> PlacedVertex {
    let mut evaluations = 0;
    let (neg, f_neg, pos, f_pos) = oriented_edge(grid, key, [fa, fb]);
    let direction = [0, 1, 2].map(|k| pos[k] - neg[k]);
    let length = norm(direction);
    let at = |s: f64| [0, 1, 2].map(|k| neg[k] + s * direction[k]);
    // Start from the linear interpolation of the end values, refined once; the Newton steps
    // below converge from there in one or two steps on a smooth surface. Regula falsi on the edge is the
    // fallback when they do not (a flat or turning gradient).
    let s_linear = if f_pos == 0.0 {
        1.0
    } else {
        (f_neg / (f_neg - f_pos)).clamp(0.0, 1.0)
    };
    let mut x = at(s_linear);
    if f_pos != 0.0 {
        // One more value on the edge, then the root of the parabola through the three samples
        // (inverse quadratic interpolation): its error is third order in the edge length, so the
        // first gradient evaluation below usually meets the tolerance already.
        let g_mid = function.value(x);
        evaluations += 1;
        let s_next = if g_mid == 0.0 {
            s_linear
        } else {
            let samples = [(0.0, f_neg), (s_linear, g_mid), (1.0, f_pos)];
            let mut s_root = 0.0;
            for (i, &(si, fi)) in samples.iter().enumerate() {
                let mut weight = si;
                for (j, &(_, fj)) in samples.iter().enumerate() {
                    if i != j {
                        weight *= -fj / (fi - fj);
                    }
                }
                s_root += weight;
            }
            // Keep it inside the sub-bracket that holds the sign change, else regula falsi there.
            let (lo, f_lo, hi, f_hi) = if g_mid < 0.0 {
                (s_linear, g_mid, 1.0, f_pos)
            } else {
                (0.0, f_neg, s_linear, g_mid)
            };
            if s_root > lo && s_root < hi {
                s_root
            } else {
                lo + (hi - lo) * (-f_lo / (f_hi - f_lo))
            }
        };
        if s_next.is_finite() {
            x = at(s_next.clamp(0.0, 1.0));
        }
    }
    let (vertex, spent) = newton(function, x, length, tolerance);
    evaluations += spent;
    if let Some(vertex) = vertex {
        return PlacedVertex {
            evaluations,
            ..vertex
        };
    }
    x = edge_root(
        function,
        (neg, f_neg),
        (pos, f_pos),
        tolerance,
        &mut evaluations,
    );
    // Newton steps along the gradient, each at most one edge length.
    let (mut value, mut gradient) = function.value_gradient(x);
    evaluations += 1;
    for _ in 0..8 {
        let g2 = gradient.iter().map(|g| g * g).sum::<f64>();
        if !(g2 > 0.0 && g2.is_finite()) || value.abs() <= tolerance * g2.sqrt() {
            break;
        }
        let step = [0, 1, 2].map(|k| value * gradient[k] / g2);
        if norm(step) > length {
            break;
        }
        x = [0, 1, 2].map(|k| x[k] - step[k]);
        (value, gradient) = function.value_gradient(x);
        evaluations += 1;
    }
    vertex_at(x, value, gradient, direction, evaluations)
}

/// The ends of the crossed edge `key` with end values `[fa, fb]`, oriented from its negative
/// end (f < 0) to its positive end (f ≥ 0): (neg, f_neg, pos, f_pos).
fn oriented_edge(grid: &Grid, key: EdgeKey, [fa, fb]: [f64; 2]) -> ([f64; 3], f64, [f64; 3], f64) {
    let a = grid.point(unpack((key >> 64) as u64));
    let b = grid.point(unpack(key as u64));
    if fa < 0.0 {
        (a, fa, b, fb)
    } else {
        (b, fb, a, fa)
    }
}

/// |f|/|∇f| from f's `value` and gradient norm `g_norm` (0 on the zero set, infinite where
/// the gradient vanishes off it).
pub(super) fn residual(value: f64, g_norm: f64) -> f64 {
    if value == 0.0 {
        0.0
    } else if g_norm > 0.0 {
        value.abs() / g_norm
    } else {
        f64::INFINITY
    }
}

/// The vertex at `x`, where f has `value` and `gradient`: its normal is the gradient's
/// direction, or, at a singular point of f, the edge's `direction` (negative to positive end).
fn vertex_at(
    x: [f64; 3],
    value: f64,
    gradient: [f64; 3],
    direction: [f64; 3],
    evaluations: u64,
) -> PlacedVertex {
    let g_norm = norm(gradient);
    let normal = if g_norm > 0.0 && g_norm.is_finite() {
        gradient.map(|g| g / g_norm)
    } else {
        let length = norm(direction);
        direction.map(|d| d / length)
    };
    PlacedVertex {
        position: x,
        normal,
        residual: residual(value, g_norm),
        evaluations,
    }
}

/// The root of f on the lattice edge from `neg` (f = `f_neg` < 0) to `pos` (f = `f_pos` ≥ 0),
/// by Illinois regula falsi to `tolerance`; adds the values it spends to `evaluations`.
fn edge_root<F: ImplicitFunction + ?Sized>(
    function: &F,
    (neg, f_neg): ([f64; 3], f64),
    (pos, f_pos): ([f64; 3], f64),
    tolerance: f64,
    evaluations: &mut u64,
) -> [f64; 3] {
    if f_pos == 0.0 {
        return pos;
    }
    let direction = [0, 1, 2].map(|k| pos[k] - neg[k]);
    let length = norm(direction);
    let at = |s: f64| [0, 1, 2].map(|k| neg[k] + s * direction[k]);
    // Illinois regula falsi on s ∈ [0, 1]: g(s0) < 0 ≤ g(s1).
    let (mut s0, mut g0, mut s1, mut g1) = (0.0, f_neg, 1.0, f_pos);
    let mut last_side = 0;
    let mut s = 0.5;
    for _ in 0..64 {
        s = if g1 > g0 {
            (s0 * g1 - s1 * g0) / (g1 - g0)
        } else {
            0.5 * (s0 + s1)
        };
        if !(s > s0 && s < s1) {
            s = 0.5 * (s0 + s1);
        }
        let g = function.value(at(s));
        *evaluations += 1;
        let slope = (g1 - g0) / ((s1 - s0) * length);
        if g == 0.0 || (slope > 0.0 && g.abs() / slope < 0.1 * tolerance) {
            break;
        }
        if g < 0.0 {
            s0 = s;
            g0 = g;
            if last_side == -1 {
                g1 *= 0.5;
            }
            last_side = -1;
        } else {
            s1 = s;
            g1 = g;
            if last_side == 1 {
                g0 *= 0.5;
            }
            last_side = 1;
        }
        if (s1 - s0) * length < 0.1 * tolerance {
            break;
        }
    }
    at(s)
}

/// The vertex for the crossed edge `key` placed on the edge itself: the root of f along it (no
/// Newton step off the edge), with the gradient's direction there as its normal (the edge's
/// direction where the gradient vanishes). Marching tetrahedra with every vertex on its own
/// lattice edge cannot self-intersect, so this is where [`super::polygonize`] puts the vertices
/// whose projection made triangles cross.
pub(crate) fn place_on_edge<F: ImplicitFunction + ?Sized>(
    function: &F,
    grid: &Grid,
    key: EdgeKey,
    [fa, fb]: [f64; 2],
    tolerance: f64,
) -> PlacedVertex {
    let (neg, f_neg, pos, f_pos) = oriented_edge(grid, key, [fa, fb]);
    let mut evaluations = 1;
    let x = edge_root(
        function,
        (neg, f_neg),
        (pos, f_pos),
        tolerance,
        &mut evaluations,
    );
    let (value, gradient) = function.value_gradient(x);
    let direction = [0, 1, 2].map(|k| pos[k] - neg[k]);
    vertex_at(x, value, gradient, direction, evaluations)
}

/// The vertex for the crossed edge `key` at the linear interpolation of its end values (the
/// position the edge collapses were judged on), with the normal of `on_edge` (the same edge's
/// root) and its own residual |f|/|∇f| there; the last fallback of [`super::polygonize`]'s
/// repair of crossings.
pub(crate) fn place_linear<F: ImplicitFunction + ?Sized>(
    function: &F,
    grid: &Grid,
    key: EdgeKey,
    [fa, fb]: [f64; 2],
    on_edge: PlacedVertex,
) -> PlacedVertex {
    let (a, b) = (
        grid.point(unpack((key >> 64) as u64)),
        grid.point(unpack(key as u64)),
    );
    let s = if fa == fb {
        0.5
    } else {
        (fa / (fa - fb)).clamp(0.0, 1.0)
    };
    let x = [0, 1, 2].map(|k| a[k] + s * (b[k] - a[k]));
    let (value, gradient) = function.value_gradient(x);
    PlacedVertex {
        position: x,
        normal: on_edge.normal,
        residual: residual(value, norm(gradient)),
        evaluations: on_edge.evaluations + 1,
    }
}

/// Newton steps from `x` along the gradient: the vertex if |f|/|∇f| ≤ `tolerance` is reached
/// within 8 steps of at most `max_step` each, and the evaluations spent.
pub(super) fn newton<F: ImplicitFunction + ?Sized>(
    function: &F,
    mut x: [f64; 3],
    max_step: f64,
    tolerance: f64,
) -> (Option<PlacedVertex>, u64) {
    for spent in 1..=8 {
        let (value, gradient) = function.value_gradient(x);
        let g_norm = norm(gradient);
        if !(g_norm > 0.0 && g_norm.is_finite()) {
            return (None, spent);
        }
        let residual = value.abs() / g_norm;
        if residual <= tolerance {
            let vertex = PlacedVertex {
                position: x,
                normal: gradient.map(|g| g / g_norm),
                residual,
                evaluations: 0,
            };
            return (Some(vertex), spent);
        }
        let step = [0, 1, 2].map(|k| value * gradient[k] / (g_norm * g_norm));
        if norm(step) > max_step {
            return (None, spent);
        }
        x = [0, 1, 2].map(|k| x[k] - step[k]);
    }
    (None, 8)
}
