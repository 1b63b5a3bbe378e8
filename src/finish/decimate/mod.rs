//! Decimation of a meshed zero set: edge collapses, cheapest first, down to a triangle budget
//! (`--target-triangles`), keeping the mesh watertight, manifold, of the same genus and free of
//! crossings.
//!
//! Input: a [`TriangleMesh`] (closed or open, 2-manifold, consistently wound, no triangle
//! crossing another; what `polygonize` and the trim make), the model's
//! [`ImplicitFunction`] it was meshed from, and [`DecimateParams`]. Output: [`Decimated`], the
//! mesh with at most `target_triangles` triangles when some sequence of legal collapses gets
//! there, else the smallest one the collapses reach, and a [`DecimateReport`] that says which.
//!
//! Invariants: a mesh already within the budget comes back unchanged (the same vertices and
//! triangles, so the same file bytes); the output's topology is the input's (components, Euler
//! characteristic, boundary loops), its winding is consistent, no boundary vertex moves; no
//! triangle crosses another when none did in the input; every moved vertex lies on the model's
//! zero set within 10⁻⁷ of the mesh's diagonal (or is an input vertex); the result is the same
//! bytes for any number of threads (the collapses run in one sequential, totally ordered pass).
//!
//! # Algorithm
//!
//! ```text
//! quadrics (area-weighted planes, Garland & Heckbert 1997) ─ heap of edges by quadric error
//!   └─ pop cheapest ─ place: quadric optimum → Newton onto f = 0 (or an end of the edge)
//!        └─ legal?  link condition · no fold, flip or sliver · no crossing (exact, local grid)
//!             └─ collapse, push the new vertex's edges; repeat until the budget or no edge left
//! ```
//!
//! 1. **Cost.** Each vertex carries the sum of the quadrics of the planes of its triangles,
//!    weighted by their area; an edge's cost is the error x ᵀQx of the best new position x for
//!    Q = Q_a + Q_b. The heap is ordered by (cost, a, b), a total order, so ties never depend on
//!    anything but the mesh.
//! 2. **Placement.** The quadric's minimiser (regularised towards the edge's midpoint, so that
//!    a flat or cylindrical patch still has one) is a point of the planes, off a curved surface;
//!    it is moved onto the model's zero set by Newton steps along ∇f (x ← x − f∇f/|∇f|²), and
//!    its normal is ∇f/|∇f| there, as the polygonizer places its vertices. When the steps do
//!    not converge near the edge, or an end of the edge is cheaper, the new vertex is that end
//!    (a half-edge collapse, whose position is already on the mesh). An edge with one end on
//!    the mesh's boundary collapses onto that end only; one with both ends on it never.
//!    Projection costs evaluations, so the heap holds the optimum's error first (a lower bound
//!    of every placement's error) and an edge is placed only when it comes to the top; if its
//!    placed cost then exceeds the next edge's, it goes back with that cost (lazy evaluation,
//!    the order stays exact).
//! 3. **Legality.** A collapse is refused when (a) the *link condition* fails: a and b have a
//!    common neighbour other than the two opposite vertices w₁, w₂ of the edge's triangles, or
//!    the edge w₁w₂ is in both links (a tetrahedron) — exactly the collapses that keep a closed
//!    2-manifold's topology (Dey, Edelsbrunner, Guha & Nekhayev 1999; the polygonizer's own
//!    sweep uses the same condition for its half-edge collapses); (b) a moved triangle's normal
//!    turns by more than the polygonizer's limit (about 40°), or faces away from the model's
//!    normal at one of its corners (a fold), or its shape (mean ratio) falls below
//!    `MIN_QUALITY` and below what the worst triangle around the edge had; (c) a new triangle
//!    meets another triangle of the mesh other than at their shared vertices and edges,
//!    decided by the exact test of `crate::mesh::triangles_intersect` against every triangle
//!    whose box meets the new fan's, found in a hierarchical spatial hash (each triangle in the
//!    cell of its box's lowest corner, at the level whose cells are at least as large as the
//!    box); the hash only finds candidates, so the decision is exact whatever its cells.
//! 4. **End.** The pass stops once the mesh holds at most the budget. When the heap runs dry
//!    first, every edge is pushed again (a refused edge may have become legal since) and the
//!    pass repeats, until a whole pass collapses nothing: the mesh is then as small as legal
//!    collapses make it, and [`DecimateReport::reached`] is false.

mod hash;

use hash::SpatialHash;
use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap};
use std::hash::BuildHasherDefault;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::implicit::ImplicitFunction;
use crate::mesh::{triangle_box, triangles_intersect, TriangleMesh};
use crate::polygonize::simplify::{shape, MAX_NORMAL_TURN_COS};
use crate::vec3::{cross, dot, norm, sub};

/// Version of the decimation's algorithm: part of the finish stage's key when it decimates.
/// If you change anything that changes its output for the same input and params, bump it.
pub(crate) const VERSION: u32 = 1;

/// Smallest squared mean ratio (see the polygonizer's shape measure) a collapse may leave
/// unless the triangles around the edge were already worse: mean ratio 0.2, a triangle of
/// about 7° at its smallest corner.
pub(crate) const MIN_QUALITY: f64 = 0.04;

/// Newton steps allowed when placing a new vertex on the zero set.
const NEWTON_STEPS: usize = 12;

/// Projection tolerance: |f|/|∇f| at a moved vertex, as a fraction of the mesh's diagonal (the
/// polygonizer's).
const PROJECTION_TOLERANCE: f64 = 1e-7;

/// Levels of the spatial hash (cells double in size from one level to the next).
const HASH_LEVELS: usize = 40;

/// Parameters of the decimation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DecimateParams {
    /// Largest number of triangles of the result (`--target-triangles`), at least 1.
    pub target_triangles: usize,
}

/// What the decimation did, for the report.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct DecimateReport {
    /// The budget asked for.
    pub target_triangles: usize,
    /// Triangles before.
    pub triangles_before: usize,
    /// Triangles after.
    pub triangles_after: usize,
    /// Vertices before.
    pub vertices_before: usize,
    /// Vertices after.
    pub vertices_after: usize,
    /// Edge collapses made.
    pub collapses: usize,
    /// Whether the result is within the budget. False when no further collapse was legal (the
    /// link condition, a fold or sliver, or a crossing refused every remaining edge; a closed
    /// mesh cannot go below a tetrahedron's 4 triangles, and an open one keeps its boundary).
    pub reached: bool,
}

/// The decimated mesh and what was done.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Decimated {
    /// The mesh: surviving vertices in their input order, then triangles in their input order.
    pub mesh: TriangleMesh,
    /// Counts and whether the budget was reached.
    pub report: DecimateReport,
}

impl DecimateReport {
    /// The message a command prints when the budget was not reached, or `None`.
    pub fn shortfall(&self) -> Option<String> {
        let r = self;
        (!r.reached).then(|| {
            format!(
                "--target-triangles {}: the decimation stopped at {} triangles (from {}): no further edge collapse keeps the mesh manifold, of the same genus, unfolded and free of crossings{}",
                r.target_triangles,
                r.triangles_after,
                r.triangles_before,
                if r.triangles_after > r.target_triangles { "; pass a larger budget to make this exact" } else { "" },
            )
        })
    }
}

/// Decimates `mesh`, meshed from `function`'s zero set, to at most
/// `params.target_triangles` triangles by legal edge collapses (see the module docs).
///
/// Vertices the collapses cannot safely touch are kept where they are: those on the boundary
/// (an edge of one triangle), on a non-manifold edge or vertex, on a degenerate triangle or at
/// a non-finite position. A mesh with an index out of range comes back unchanged, with
/// `reached` false.
///
/// ```
/// use stablesurf::finish::decimate::{decimate, DecimateParams};
/// use stablesurf::polygonize::{polygonize, PolygonizeParams};
/// use stablesurf::{Aabb, ImplicitPolynomial};
/// let mut coefficients = vec![0.0; 10];
/// coefficients[0] = -1.0;
/// for l in [4, 7, 9] {
///     coefficients[l] = 1.0;
/// }
/// let sphere = ImplicitPolynomial { degree: 2, coefficients, center: [0.0; 3], scale: 1.0 };
/// let region = Aabb { min: [-1.5; 3], max: [1.5; 3] };
/// let mesh = polygonize(&sphere, &region, &PolygonizeParams { depth: 4, ..Default::default() })?.mesh;
/// let out = decimate(&mesh, &sphere, &DecimateParams { target_triangles: 200 });
/// assert!(out.report.reached && out.mesh.triangles.len() <= 200);
/// let check = stablesurf::mesh::check(&out.mesh);
/// assert!(check.watertight && check.euler_characteristic == 2);
/// assert_eq!(check.self_intersecting_faces, 0);
/// # Ok::<(), stablesurf::polygonize::PolygonizeError>(())
/// ```
pub fn decimate<F: ImplicitFunction + ?Sized>(
    mesh: &TriangleMesh,
    function: &F,
    params: &DecimateParams,
) -> Decimated {
    let target = params.target_triangles;
    let report = DecimateReport {
        target_triangles: target,
        triangles_before: mesh.triangles.len(),
        triangles_after: mesh.triangles.len(),
        vertices_before: mesh.positions.len(),
        vertices_after: mesh.positions.len(),
        collapses: 0,
        reached: mesh.triangles.len() <= target,
    };
    let n = mesh.positions.len();
    let in_range = mesh
        .triangles
        .iter()
        .all(|t| t.iter().all(|&v| (v as usize) < n))
        && mesh.normals.len() == n;
    if report.reached || !in_range {
        return Decimated {
            mesh: mesh.clone(),
            report,
        };
    }
    let mut state = State::new(mesh, function);
    let collapses = state.run(target);
    let out = state.compact();
    Decimated {
        report: DecimateReport {
            triangles_after: out.triangles.len(),
            vertices_after: out.positions.len(),
            collapses,
            reached: out.triangles.len() <= target,
            ..report
        },
        mesh: out,
    }
}

/// How the collapses may treat a vertex.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// Its link is one closed cycle: it may move or go.
    Interior,
    /// Its link is one path (a manifold boundary vertex): an interior neighbour may collapse
    /// onto it; it never moves.
    Boundary,
    /// Anything else (non-manifold, degenerate, non-finite): never touched.
    Frozen,
}

/// A symmetric 4×4 quadric [A b; bᵀ c] as (a00 a01 a02 a11 a12 a22, b0 b1 b2, c), in
/// coordinates relative to the mesh's centre.
type Quadric = [f64; 10];

/// The quadric of the plane u·x + d = 0 (u a unit normal): the squared distance to it.
fn plane_quadric(u: [f64; 3], d: f64) -> Quadric {
    [
        u[0] * u[0],
        u[0] * u[1],
        u[0] * u[2],
        u[1] * u[1],
        u[1] * u[2],
        u[2] * u[2],
        u[0] * d,
        u[1] * d,
        u[2] * d,
        d * d,
    ]
}

fn add(q: &Quadric, r: &Quadric) -> Quadric {
    std::array::from_fn(|i| q[i] + r[i])
}

/// xᵀAx + 2bᵀx + c, never below 0.
fn error(q: &Quadric, x: [f64; 3]) -> f64 {
    let [a00, a01, a02, a11, a12, a22, b0, b1, b2, c] = *q;
    let ax = [
        a00 * x[0] + a01 * x[1] + a02 * x[2],
        a01 * x[0] + a11 * x[1] + a12 * x[2],
        a02 * x[0] + a12 * x[1] + a22 * x[2],
    ];
    (dot(x, ax) + 2.0 * (b0 * x[0] + b1 * x[1] + b2 * x[2]) + c).max(0.0)
}

/// The minimiser of xᵀQx + λ|x − m|² with λ a thousandth of A's mean eigenvalue: Q's own
/// minimiser where Q is well conditioned, the point nearest `m` among its near-minimisers on
/// a flat or cylindrical patch. `None` when the system is singular or not finite.
fn optimum(q: &Quadric, m: [f64; 3]) -> Option<[f64; 3]> {
    let [a00, a01, a02, a11, a12, a22, b0, b1, b2, _] = *q;
    let lambda = 1e-3 * (a00 + a11 + a22) / 3.0;
    let (a00, a11, a22) = (a00 + lambda, a11 + lambda, a22 + lambda);
    let r = [
        -b0 + lambda * m[0],
        -b1 + lambda * m[1],
        -b2 + lambda * m[2],
    ];
    let c00 = a11 * a22 - a12 * a12;
    let c01 = a02 * a12 - a01 * a22;
    let c02 = a01 * a12 - a02 * a11;
    let det = a00 * c00 + a01 * c01 + a02 * c02;
    if !(det.is_finite() && det > 0.0) {
        return None;
    }
    let c11 = a00 * a22 - a02 * a02;
    let c12 = a01 * a02 - a00 * a12;
    let c22 = a00 * a11 - a01 * a01;
    let x = [
        (c00 * r[0] + c01 * r[1] + c02 * r[2]) / det,
        (c01 * r[0] + c11 * r[1] + c12 * r[2]) / det,
        (c02 * r[0] + c12 * r[1] + c22 * r[2]) / det,
    ];
    x.iter().all(|c| c.is_finite()).then_some(x)
}

/// A heap entry: an edge and the cost it was pushed with. `placed` entries carry the cost of
/// their placement, the others a lower bound of it.
#[derive(Clone, Copy, Debug)]
struct Entry {
    cost: f64,
    a: u32,
    b: u32,
    stamp_a: u32,
    stamp_b: u32,
    placed: bool,
}

impl PartialEq for Entry {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Entry {
    /// The cheapest edge is the greatest (`BinaryHeap` is a max-heap); ties by the vertices.
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .cost
            .total_cmp(&self.cost)
            .then(other.a.cmp(&self.a))
            .then(other.b.cmp(&self.b))
            .then(other.placed.cmp(&self.placed))
    }
}

/// A candidate position of the merged vertex: where, its normal, and its cost.
#[derive(Clone, Copy, Debug)]
struct Placement {
    position: [f64; 3],
    normal: [f64; 3],
    cost: f64,
}

/// A fixed hasher for the spatial hash (its answers are sets, so any hasher gives the same
/// result; a fixed one keeps the run times reproducible too).
type FixedState = BuildHasherDefault<std::collections::hash_map::DefaultHasher>;

/// The mesh being decimated.
struct State<'f, F: ImplicitFunction + ?Sized> {
    function: &'f F,
    /// Positions relative to `center` are used for the quadrics.
    center: [f64; 3],
    positions: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    triangles: Vec<[u32; 3]>,
    alive: Vec<bool>,
    live_triangles: usize,
    around: Vec<Vec<u32>>,
    kind: Vec<Kind>,
    removed: Vec<bool>,
    stamp: Vec<u32>,
    quadrics: Vec<Quadric>,
    hash: SpatialHash,
    tolerance: f64,
    heap: BinaryHeap<Entry>,
    // Scratch buffers.
    mark: Vec<u32>,
    mark_stamp: u32,
    candidates: Vec<u32>,
}

impl<'f, F: ImplicitFunction + ?Sized> State<'f, F> {
    fn new(mesh: &TriangleMesh, function: &'f F) -> Self {
        let n = mesh.positions.len();
        let positions = mesh.positions.clone();
        let triangles = mesh.triangles.clone();
        let mut around: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (t, tri) in triangles.iter().enumerate() {
            for &v in tri {
                if !around[v as usize].contains(&(t as u32)) {
                    around[v as usize].push(t as u32);
                }
            }
        }
        let finite = |p: &[f64; 3]| p.iter().all(|c| c.is_finite());
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in positions.iter().filter(|p| finite(p)) {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let center = [0, 1, 2].map(|a| {
            if lo[a] <= hi[a] {
                0.5 * (lo[a] + hi[a])
            } else {
                0.0
            }
        });
        let diagonal = if lo[0] <= hi[0] {
            norm(sub(hi, lo))
        } else {
            0.0
        };
        let mut kind: Vec<Kind> = (0..n as u32)
            .into_par_iter()
            .map(|v| classify(v, &around[v as usize], &triangles, &positions))
            .collect();
        // Vertices of a degenerate or non-finite triangle stay where they are.
        for tri in &triangles {
            let bad = tri[0] == tri[1]
                || tri[1] == tri[2]
                || tri[0] == tri[2]
                || tri.iter().any(|&v| !finite(&positions[v as usize]));
            if bad {
                for &v in tri {
                    kind[v as usize] = Kind::Frozen;
                }
            }
        }
        let quadrics: Vec<Quadric> = (0..n)
            .into_par_iter()
            .map(|v| {
                let mut q = [0.0; 10];
                for &t in &around[v] {
                    let [a, b, c] =
                        triangles[t as usize].map(|x| sub(positions[x as usize], center));
                    let n2 = cross(sub(b, a), sub(c, a));
                    let len = norm(n2);
                    if !(len > 0.0 && len.is_finite()) {
                        continue;
                    }
                    let area = 0.5 * len;
                    let u = n2.map(|x| x / len);
                    let d = -dot(u, a);
                    for (qi, pi) in q.iter_mut().zip(plane_quadric(u, d)) {
                        *qi += area * pi;
                    }
                }
                q
            })
            .collect();
        // The spatial hash's smallest cells: the mean box extent of the triangles.
        let mut extent_sum = 0.0;
        let boxes: Vec<([f64; 3], [f64; 3])> = triangles
            .iter()
            .map(|t| triangle_box(t, &positions))
            .collect();
        for (l, h) in &boxes {
            extent_sum += (0..3).map(|a| h[a] - l[a]).fold(0.0, f64::max);
        }
        let base = (extent_sum / triangles.len().max(1) as f64).max(diagonal * 1e-9);
        let base = if base.is_finite() && base > 0.0 {
            base
        } else {
            1.0
        };
        let mut hash = SpatialHash::new(
            lo.map(|x| if x.is_finite() { x } else { 0.0 }),
            base,
            triangles.len(),
        );
        for (t, (l, h)) in boxes.iter().enumerate() {
            if l.iter().chain(h).all(|c| c.is_finite()) {
                hash.insert(t as u32, *l, *h);
            }
        }
        State {
            function,
            center,
            normals: mesh.normals.clone(),
            alive: vec![true; triangles.len()],
            live_triangles: triangles.len(),
            triangles,
            around,
            kind,
            removed: vec![false; n],
            stamp: vec![0; n],
            quadrics,
            hash,
            tolerance: PROJECTION_TOLERANCE * diagonal,
            heap: BinaryHeap::new(),
            mark: vec![0; n],
            mark_stamp: 0,
            candidates: Vec::new(),
            positions,
        }
    }

    /// Whether the edge a–b may collapse at all (by the kinds of its ends).
    fn collapsible(&self, a: u32, b: u32) -> bool {
        use Kind::*;
        matches!(
            (self.kind[a as usize], self.kind[b as usize]),
            (Interior, Interior) | (Interior, Boundary) | (Boundary, Interior)
        )
    }

    /// The cheap lower bound of the edge's cost: the quadric error at its optimum, or at the
    /// boundary end it must collapse onto.
    fn lower_bound(&self, a: u32, b: u32) -> f64 {
        let q = add(&self.quadrics[a as usize], &self.quadrics[b as usize]);
        let (pa, pb) = (self.local(a), self.local(b));
        match (self.kind[a as usize], self.kind[b as usize]) {
            (Kind::Boundary, _) => error(&q, pa),
            (_, Kind::Boundary) => error(&q, pb),
            _ => {
                let m = [0, 1, 2].map(|k| 0.5 * (pa[k] + pb[k]));
                let x = optimum(&q, m).unwrap_or(m);
                error(&q, x).min(error(&q, pa)).min(error(&q, pb))
            }
        }
    }

    fn local(&self, v: u32) -> [f64; 3] {
        sub(self.positions[v as usize], self.center)
    }

    fn push(&mut self, a: u32, b: u32) {
        let (a, b) = (a.min(b), a.max(b));
        if !self.collapsible(a, b) {
            return;
        }
        let cost = self.lower_bound(a, b);
        self.heap.push(Entry {
            cost,
            a,
            b,
            stamp_a: self.stamp[a as usize],
            stamp_b: self.stamp[b as usize],
            placed: false,
        });
    }

    /// Pushes every edge of the live mesh once (a < b), in vertex order.
    fn push_all(&mut self) {
        let edges: Vec<(u32, u32)> = (0..self.positions.len() as u32)
            .into_par_iter()
            .flat_map_iter(|a| {
                let mut out: Vec<u32> = Vec::new();
                if !self.removed[a as usize] {
                    for &t in &self.around[a as usize] {
                        for x in self.triangles[t as usize] {
                            if x > a {
                                out.push(x);
                            }
                        }
                    }
                }
                out.sort_unstable();
                out.dedup();
                out.into_iter().map(move |b| (a, b))
            })
            .filter(|&(a, b)| self.collapsible(a, b))
            .collect();
        let entries: Vec<Entry> = edges
            .par_iter()
            .map(|&(a, b)| Entry {
                cost: self.lower_bound(a, b),
                a,
                b,
                stamp_a: self.stamp[a as usize],
                stamp_b: self.stamp[b as usize],
                placed: false,
            })
            .collect();
        self.heap.extend(entries);
    }

    /// Newton steps from `x` (input coordinates) onto f = 0; the point and the unit gradient
    /// there, or `None` when they do not converge within `reach` of `x`.
    fn project(&self, x: [f64; 3], reach: f64) -> Option<([f64; 3], [f64; 3])> {
        let start = x;
        let mut x = x;
        for _ in 0..NEWTON_STEPS {
            let (f, g) = self.function.value_gradient(x);
            let g2 = dot(g, g);
            if !(g2 > 0.0 && g2.is_finite() && f.is_finite()) {
                return None;
            }
            let step = f / g2;
            let moved = [0, 1, 2].map(|k| x[k] - step * g[k]);
            if norm(sub(moved, start)) > reach {
                return None;
            }
            let length = step.abs() * g2.sqrt();
            x = moved;
            if length <= self.tolerance {
                // The normal at the point reached.
                let (_, g) = self.function.value_gradient(x);
                let g_norm = norm(g);
                return (g_norm > 0.0 && g_norm.is_finite()).then(|| (x, g.map(|c| c / g_norm)));
            }
        }
        None
    }

    /// The placements of the merged vertex of a–b, cheapest first.
    fn placements(&self, a: u32, b: u32) -> Vec<Placement> {
        let q = add(&self.quadrics[a as usize], &self.quadrics[b as usize]);
        let end = |v: u32| Placement {
            position: self.positions[v as usize],
            normal: self.normals[v as usize],
            cost: error(&q, self.local(v)),
        };
        let mut out = Vec::with_capacity(3);
        match (self.kind[a as usize], self.kind[b as usize]) {
            (Kind::Boundary, _) => out.push(end(a)),
            (_, Kind::Boundary) => out.push(end(b)),
            _ => {
                let (pa, pb) = (self.local(a), self.local(b));
                let m = [0, 1, 2].map(|k| 0.5 * (pa[k] + pb[k]));
                let length = norm(sub(pa, pb));
                let x = optimum(&q, m)
                    .filter(|x| norm(sub(*x, m)) <= length)
                    .unwrap_or(m);
                let start = [0, 1, 2].map(|k| x[k] + self.center[k]);
                if let Some((p, normal)) = self.project(start, length) {
                    let local = sub(p, self.center);
                    if norm(sub(local, m)) <= length {
                        out.push(Placement {
                            position: p,
                            normal,
                            cost: error(&q, local),
                        });
                    }
                }
                out.push(end(a));
                out.push(end(b));
            }
        }
        out.sort_by(|x, y| x.cost.total_cmp(&y.cost));
        out
    }

    /// Whether collapsing a–b into `keep` at `place` is legal (module docs, step 3).
    fn legal(&mut self, a: u32, b: u32, keep: u32, place: &Placement) -> bool {
        let gone = if keep == a { b } else { a };
        // The edge's two triangles and their opposite vertices.
        let mut shared = [u32::MAX; 2];
        let mut n_shared = 0;
        for &t in &self.around[a as usize] {
            if self.triangles[t as usize].contains(&b) {
                if n_shared == 2 {
                    return false;
                }
                shared[n_shared] = t;
                n_shared += 1;
            }
        }
        if n_shared != 2 {
            return false;
        }
        let opposite = shared.map(|t| {
            let tri = self.triangles[t as usize];
            tri.into_iter()
                .find(|&x| x != a && x != b)
                .unwrap_or(u32::MAX)
        });
        if opposite[0] == opposite[1] {
            return false;
        }
        // (a) Link condition: the common neighbours are exactly w₁, w₂ ...
        self.mark_stamp = self.mark_stamp.wrapping_add(1);
        if self.mark_stamp == 0 {
            self.mark.fill(0);
            self.mark_stamp = 1;
        }
        let stamp = self.mark_stamp;
        for &t in &self.around[a as usize] {
            for x in self.triangles[t as usize] {
                self.mark[x as usize] = stamp;
            }
        }
        for &t in &self.around[b as usize] {
            for x in self.triangles[t as usize] {
                if x != a && x != b && self.mark[x as usize] == stamp && !opposite.contains(&x) {
                    return false;
                }
            }
        }
        // ... and w₁w₂ is not an edge of a triangle with a and of one with b (a tetrahedron).
        let has_triangle = |v: u32| {
            self.around[v as usize].iter().any(|&t| {
                let tri = self.triangles[t as usize];
                tri.contains(&opposite[0]) && tri.contains(&opposite[1])
            })
        };
        if has_triangle(a) && has_triangle(b) {
            return false;
        }
        // (b) Shapes, turns and folds of the moved triangles.
        let p = place.position;
        let mut old_worst = f64::INFINITY;
        let mut new_worst = f64::INFINITY;
        let mut fan: Vec<[u32; 3]> = Vec::with_capacity(16);
        for &v in &[a, b] {
            for &t in &self.around[v as usize] {
                let tri = self.triangles[t as usize];
                let [pa, pb, pc] = tri.map(|x| self.positions[x as usize]);
                let (old_quality, old_normal) = shape(pa, pb, pc);
                old_worst = old_worst.min(old_quality);
                if shared.contains(&t) || (v == b && tri.contains(&a)) {
                    continue;
                }
                let moved = tri.map(|x| if x == gone { keep } else { x });
                let at = |x: u32| {
                    if x == keep {
                        p
                    } else {
                        self.positions[x as usize]
                    }
                };
                let (quality, normal) = shape(at(moved[0]), at(moved[1]), at(moved[2]));
                let normal2 = dot(normal, normal);
                if !(normal2 > 0.0 && normal2.is_finite()) {
                    return false;
                }
                let old2 = dot(old_normal, old_normal);
                let turn = dot(old_normal, normal);
                if old2 > 0.0
                    && (turn <= 0.0
                        || turn * turn < MAX_NORMAL_TURN_COS * MAX_NORMAL_TURN_COS * old2 * normal2)
                {
                    return false;
                }
                for x in moved {
                    let vertex_normal = if x == keep {
                        place.normal
                    } else {
                        self.normals[x as usize]
                    };
                    if dot(vertex_normal, normal) <= 0.0 {
                        return false;
                    }
                }
                new_worst = new_worst.min(quality);
                fan.push(moved);
            }
        }
        if new_worst < MIN_QUALITY.min(old_worst) {
            return false;
        }
        // (c) No new triangle meets another: tested with the kept vertex at its new place.
        let saved = self.positions[keep as usize];
        self.positions[keep as usize] = p;
        let crossing = self.fan_crosses(&fan, a, b);
        self.positions[keep as usize] = saved;
        !crossing
    }

    /// Whether a triangle of `fan` (over the current positions) meets another one of the fan
    /// or a live triangle outside the stars of `a` and `b`, other than at shared vertices and
    /// edges.
    fn fan_crosses(&mut self, fan: &[[u32; 3]], a: u32, b: u32) -> bool {
        let boxes: Vec<([f64; 3], [f64; 3])> = fan
            .iter()
            .map(|t| triangle_box(t, &self.positions))
            .collect();
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for (l, h) in &boxes {
            for k in 0..3 {
                lo[k] = lo[k].min(l[k]);
                hi[k] = hi[k].max(h[k]);
            }
        }
        let overlap = |x: &([f64; 3], [f64; 3]), y: &([f64; 3], [f64; 3])| {
            (0..3).all(|k| x.0[k] <= y.1[k] && y.0[k] <= x.1[k])
        };
        for (i, (s, sb)) in fan.iter().zip(&boxes).enumerate() {
            for (t, tb) in fan[i + 1..].iter().zip(&boxes[i + 1..]) {
                if overlap(sb, tb) && triangles_intersect(*s, *t, &self.positions) {
                    return true;
                }
            }
        }
        let mut candidates = std::mem::take(&mut self.candidates);
        self.hash.query(lo, hi, &mut candidates);
        let mut crossing = false;
        'outer: for &t in &candidates {
            let tri = self.triangles[t as usize];
            if !self.alive[t as usize] || tri.contains(&a) || tri.contains(&b) {
                continue;
            }
            let tb = triangle_box(&tri, &self.positions);
            for (f, fb) in fan.iter().zip(&boxes) {
                if overlap(fb, &tb) && triangles_intersect(*f, tri, &self.positions) {
                    crossing = true;
                    break 'outer;
                }
            }
        }
        self.candidates = candidates;
        crossing
    }

    /// Collapses a–b into `keep` at `place` (legal by [`State::legal`]).
    fn collapse(&mut self, a: u32, b: u32, keep: u32, place: &Placement) {
        let gone = if keep == a { b } else { a };
        let star_gone = std::mem::take(&mut self.around[gone as usize]);
        for &t in &star_gone {
            let tri = self.triangles[t as usize];
            self.hash.remove(t);
            if tri.contains(&keep) {
                // One of the edge's two triangles.
                self.alive[t as usize] = false;
                self.live_triangles -= 1;
                for x in tri {
                    if x != gone {
                        self.around[x as usize].retain(|&s| s != t);
                    }
                }
            } else {
                self.triangles[t as usize] = tri.map(|x| if x == gone { keep } else { x });
                self.around[keep as usize].push(t);
            }
        }
        self.removed[gone as usize] = true;
        self.positions[keep as usize] = place.position;
        self.normals[keep as usize] = place.normal;
        self.quadrics[keep as usize] = add(&self.quadrics[a as usize], &self.quadrics[b as usize]);
        self.stamp[keep as usize] = self.stamp[keep as usize].wrapping_add(1);
        self.stamp[gone as usize] = self.stamp[gone as usize].wrapping_add(1);
        // Every triangle around the kept vertex moved: register it again.
        let star = self.around[keep as usize].clone();
        let mut neighbours = Vec::with_capacity(3 * star.len());
        for &t in &star {
            self.hash.remove(t);
            let tri = self.triangles[t as usize];
            let (l, h) = triangle_box(&tri, &self.positions);
            self.hash.insert(t, l, h);
            neighbours.extend(tri.into_iter().filter(|&x| x != keep));
        }
        neighbours.sort_unstable();
        neighbours.dedup();
        for x in neighbours {
            self.push(keep, x);
        }
    }

    /// The decimation loop; returns the number of collapses.
    fn run(&mut self, target: usize) -> usize {
        let mut collapses = 0;
        loop {
            let before = collapses;
            self.push_all();
            while self.live_triangles > target {
                let Some(entry) = self.heap.pop() else { break };
                let (a, b) = (entry.a, entry.b);
                if self.removed[a as usize]
                    || self.removed[b as usize]
                    || self.stamp[a as usize] != entry.stamp_a
                    || self.stamp[b as usize] != entry.stamp_b
                {
                    continue;
                }
                let places = self.placements(a, b);
                // Lazy evaluation: an edge whose cheapest placement costs more than the next
                // edge's bound goes back with that cost and waits its turn.
                if !entry.placed
                    && let (Some(first), Some(next)) = (places.first(), self.heap.peek())
                    && first.cost > next.cost
                {
                    self.heap.push(Entry {
                        cost: first.cost,
                        placed: true,
                        ..entry
                    });
                    continue;
                }
                let keep = match (self.kind[a as usize], self.kind[b as usize]) {
                    (_, Kind::Boundary) => b,
                    _ => a,
                };
                let mut chosen = None;
                for place in &places {
                    if self.legal(a, b, keep, place) {
                        chosen = Some(*place);
                        break;
                    }
                }
                let Some(place) = chosen else { continue };
                self.collapse(a, b, keep, &place);
                collapses += 1;
            }
            self.heap.clear();
            if self.live_triangles <= target || collapses == before {
                return collapses;
            }
        }
    }

    /// The live mesh, vertices and triangles in their input order.
    fn compact(self) -> TriangleMesh {
        let mut used = vec![false; self.positions.len()];
        for (t, tri) in self.triangles.iter().enumerate() {
            if self.alive[t] {
                for &v in tri {
                    used[v as usize] = true;
                }
            }
        }
        // Unreferenced vertices of the input (none in a meshed zero set) are kept as they were.
        let mut index = vec![u32::MAX; self.positions.len()];
        let mut out = TriangleMesh::default();
        for v in 0..self.positions.len() {
            if !self.removed[v] || used[v] {
                index[v] = out.positions.len() as u32;
                out.positions.push(self.positions[v]);
                out.normals.push(self.normals[v]);
            }
        }
        out.triangles = self
            .triangles
            .iter()
            .zip(&self.alive)
            .filter(|&(_, &alive)| alive)
            .map(|(t, _)| t.map(|v| index[v as usize]))
            .collect();
        out
    }
}

/// The kind of vertex `v` from its triangles `star`: interior when its link edges (the edge
/// opposite v in each triangle, as wound) form one closed cycle, boundary when they form one
/// path, frozen otherwise.
fn classify(v: u32, star: &[u32], triangles: &[[u32; 3]], positions: &[[f64; 3]]) -> Kind {
    if star.is_empty() || !positions[v as usize].iter().all(|c| c.is_finite()) {
        return Kind::Frozen;
    }
    let mut edges: Vec<(u32, u32)> = Vec::with_capacity(star.len());
    for &t in star {
        let tri = triangles[t as usize];
        let Some(k) = tri.iter().position(|&x| x == v) else {
            return Kind::Frozen;
        };
        edges.push((tri[(k + 1) % 3], tri[(k + 2) % 3]));
    }
    // Each link vertex starts at most one edge and ends at most one.
    let mut starts: Vec<u32> = edges.iter().map(|e| e.0).collect();
    let mut ends: Vec<u32> = edges.iter().map(|e| e.1).collect();
    starts.sort_unstable();
    ends.sort_unstable();
    if starts.windows(2).any(|w| w[0] == w[1]) || ends.windows(2).any(|w| w[0] == w[1]) {
        return Kind::Frozen;
    }
    // Walk from a start that no edge ends at (a path's first vertex), else from any.
    let first = starts
        .iter()
        .copied()
        .find(|s| ends.binary_search(s).is_err());
    let mut current = first.unwrap_or(edges[0].0);
    let mut walked = 0;
    while let Some(&(_, next)) = edges.iter().find(|e| e.0 == current) {
        walked += 1;
        current = next;
        if walked > edges.len() || (first.is_none() && current == edges[0].0) {
            break;
        }
    }
    match (first, walked == edges.len()) {
        (None, true) if current == edges[0].0 => Kind::Interior,
        (Some(_), true) => Kind::Boundary,
        _ => Kind::Frozen,
    }
}

#[cfg(test)]
mod tests;
