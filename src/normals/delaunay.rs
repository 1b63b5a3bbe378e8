//! 3D Delaunay tetrahedralization, the first building block of the `normals` stage's crust.
//!
//! Input: points in `f64` (any finite coordinates; duplicates allowed). Output:
//! [`Tetrahedralization`]: the Delaunay tetrahedra of the points, each positively oriented, with
//! face adjacency.
//!
//! Invariants: every tetrahedron `[a, b, c, d]` has `robust::orient3d(a, b, c, d) > 0` (the
//! orientation convention of Shewchuk's predicates: `d` lies below the plane of `a, b, c` seen
//! counter-clockwise); no input point lies strictly inside the circumsphere of any tetrahedron;
//! duplicate points are skipped and mapped to their first occurrence.
//!
//! # Algorithm
//!
//! Bowyer–Watson incremental insertion (Bowyer 1981, Watson 1981) inside a large enclosing
//! tetrahedron whose four vertices are removed at the end:
//!
//! ```text
//! order the points: BRIO rounds (Amenta, Choi & Rote 2003), each round along a Hilbert curve
//! for each point p:
//!     walk from the last created tetrahedron (or, after a pole left out, the one that
//!         contained it) towards p (visibility walk, orient3d tests)
//!     grow the cavity: all tetrahedra whose circumsphere contains p (insphere tests, BFS)
//!     replace the cavity by the cone from p to its boundary faces
//! ```
//!
//! Data layout (the usual techniques of fast incremental Delaunay, e.g. Geogram's and CGAL's):
//! each tetrahedron is one 32-byte record (4 vertex ids, 4 neighbour ids with the index of the
//! shared face packed in the low 2 bits, so crossing a face never searches the neighbour);
//! points are stored in insertion order, so that nearby tetrahedra refer to nearby memory;
//! the cavity uses a reused stack and per-tetrahedron generation stamps (nothing is cleared or
//! allocated per insertion); the cone is glued through a small stamped open-addressing table
//! keyed by boundary edge; freed slots are reused by the cone; the cavity search prefetches the
//! four neighbours of each cavity tetrahedron before testing them (their records are random
//! accesses, the largest cost of the search). The walk never re-tests the face
//! it came through. A second batch of points can be inserted into an existing triangulation
//! (the crust's poles), and the faces among the first batch of several such triangulations,
//! each with its own second batch, combined into those of the union ([`faces_among_union`]).
//!
//! Predicates are Shewchuk's adaptive exact `orient3d` and `insphere` (the `robust` crate), so
//! no decision is ever wrong because of rounding; an inlined semi-static filter in front of
//! them takes the sign where Shewchuk's own first stage would have (see [`orient3d`]), so they
//! are called only for nearly degenerate configurations. Co-spherical subsets (insphere exactly zero,
//! common in scans and lattices) are decided by symbolic perturbation: each point is lifted onto
//! the paraboloid with an infinitesimal extra height that grows with its index (the
//! "simulation of simplicity" of Edelsbrunner & Mücke 1990, in the form of Devillers & Teillaud
//! 2011). The perturbed configuration is generic, so the triangulation is unique, has no flat
//! tetrahedra, and every cavity is star-shaped from the new point; insertion cannot loop or
//! crash. As a last safety net, a cavity whose cone would contain a non-positive tetrahedron is
//! rejected and the point skipped (and counted), which keeps the invariants whatever happens.
//!
//! Tetrahedra that touch the enclosing tetrahedron's vertices are dropped at the end; the faces
//! of the remaining tetrahedra that lost their neighbour are the (approximate, see below)
//! convex hull. With the enclosing vertices at 1000 times the size of the input, only hull
//! tetrahedra whose circumsphere is about that large can be missing, which changes nothing for
//! the crust.

use rayon::prelude::*;

use crate::normals::NormalsError;

/// Marks "no neighbour" in [`Tetrahedralization::neighbours`] (a convex-hull face).
pub const NO_NEIGHBOUR: u32 = u32::MAX;

/// A Delaunay tetrahedralization of a point set.
#[derive(Clone, Debug, Default)]
pub struct Tetrahedralization {
    /// Tetrahedra as indices into the input points, each positively oriented in the sense of
    /// `robust::orient3d(a, b, c, d) > 0`.
    pub tets: Vec<[u32; 4]>,
    /// `neighbours[t][i]` is the tetrahedron across the face of `t` opposite its vertex `i`, or
    /// [`NO_NEIGHBOUR`] when that face is on the convex hull.
    pub neighbours: Vec<[u32; 4]>,
    /// For each input point, the index of the point it was merged with: itself for a point that
    /// was inserted, its first exact duplicate otherwise.
    pub representative: Vec<u32>,
    /// Number of points skipped by the safety net (0 unless something unexpected happened).
    pub n_rejected: usize,
}

impl Tetrahedralization {
    /// Faces of the convex hull as `(tet, i)`: face `i` (opposite vertex `i`) of tetrahedron `tet`.
    pub fn hull_faces(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.neighbours.iter().enumerate().flat_map(|(t, n)| {
            (0..4)
                .filter(move |&i| n[i] == NO_NEIGHBOUR)
                .map(move |i| (t, i))
        })
    }
}

/// Vertices of face `i` of a tetrahedron, ordered so that they are counter-clockwise seen from
/// outside the tetrahedron (so that `orient3d(face, vertex_i) > 0`).
pub fn face_vertices(tet: [u32; 4], i: usize) -> [u32; 3] {
    // For a positive tet [a, b, c, d], orient3d(a, b, c, d) > 0; swapping two vertices flips it.
    match i {
        0 => [tet[1], tet[3], tet[2]],
        1 => [tet[0], tet[2], tet[3]],
        2 => [tet[0], tet[3], tet[1]],
        _ => [tet[0], tet[1], tet[2]],
    }
}

#[inline]
fn c3(p: &[f64; 3]) -> robust::Coord3D<f64> {
    robust::Coord3D {
        x: p[0],
        y: p[1],
        z: p[2],
    }
}

/// Shewchuk's exact orientation: positive when `d` lies below the plane of `a, b, c`.
///
/// A semi-static filter decides first (the usual first stage of fast exact predicates, e.g.
/// CGAL's static filters): the determinant is evaluated exactly as Shewchuk's first stage
/// evaluates it, and its sign is taken when it exceeds his error bound with the permanent
/// replaced by an upper bound from the largest coordinate differences (the permanent is a sum
/// of 6 products of one x, one y and one z difference). Whenever the filter decides, Shewchuk's
/// first stage would have returned this same value; otherwise his full adaptive predicate runs.
#[inline(always)]
pub fn orient3d(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3]) -> f64 {
    let adx = a[0] - d[0];
    let bdx = b[0] - d[0];
    let cdx = c[0] - d[0];
    let ady = a[1] - d[1];
    let bdy = b[1] - d[1];
    let cdy = c[1] - d[1];
    let adz = a[2] - d[2];
    let bdz = b[2] - d[2];
    let cdz = c[2] - d[2];
    let det = adz * (bdx * cdy - cdx * bdy)
        + bdz * (cdx * ady - adx * cdy)
        + cdz * (adx * bdy - bdx * ady);
    let mx = adx.abs().max(bdx.abs()).max(cdx.abs());
    let my = ady.abs().max(bdy.abs()).max(cdy.abs());
    let mz = adz.abs().max(bdz.abs()).max(cdz.abs());
    let bound = O3D_SEMI_STATIC * (mx * my * mz);
    if bound > SEMI_STATIC_MIN && (det > bound || -det > bound) {
        return det;
    }
    orient3d_exact(a, b, c, d)
}

/// Shewchuk's error bound coefficient for orient3d's first stage, (7 + 56ε)ε with ε = 2⁻⁵³.
const O3D_ERRBOUND_A: f64 = (7.0 + 56.0 * f64::EPSILON / 2.0) * f64::EPSILON / 2.0;
/// [`O3D_ERRBOUND_A`] times the 6 products of the permanent, with a margin of 10⁻⁴ for the
/// rounding of both the permanent and this bound.
const O3D_SEMI_STATIC: f64 = O3D_ERRBOUND_A * 6.0 * 1.0001;
/// Shewchuk's error bound coefficient for insphere's first stage, (16 + 224ε)ε.
const ISP_ERRBOUND_A: f64 = (16.0 + 224.0 * f64::EPSILON / 2.0) * f64::EPSILON / 2.0;
/// [`ISP_ERRBOUND_A`] times the 24 products (x·y·z·lift) of the permanent, with a margin.
const ISP_SEMI_STATIC: f64 = ISP_ERRBOUND_A * 24.0 * 1.0001;
/// Below this the filter's bound may have lost accuracy to underflow: the exact predicate
/// decides.
const SEMI_STATIC_MIN: f64 = 1e-200;

#[inline(never)]
fn orient3d_exact(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3]) -> f64 {
    robust::orient3d(c3(a), c3(b), c3(c), c3(d))
}

/// Shewchuk's exact insphere: positive when `e` is inside the sphere of the positive tet `a..d`.
///
/// Filtered as [`orient3d`] is: the determinant is evaluated as Shewchuk's first stage
/// evaluates it, and its bound uses the permanent's upper bound 24·mx·my·mz·(mx² + my² + mz²)
/// (4 lifted terms of 6 products each) from the largest coordinate differences.
#[inline(always)]
pub fn insphere(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3], e: &[f64; 3]) -> f64 {
    let aex = a[0] - e[0];
    let bex = b[0] - e[0];
    let cex = c[0] - e[0];
    let dex = d[0] - e[0];
    let aey = a[1] - e[1];
    let bey = b[1] - e[1];
    let cey = c[1] - e[1];
    let dey = d[1] - e[1];
    let aez = a[2] - e[2];
    let bez = b[2] - e[2];
    let cez = c[2] - e[2];
    let dez = d[2] - e[2];
    let ab = aex * bey - bex * aey;
    let bc = bex * cey - cex * bey;
    let cd = cex * dey - dex * cey;
    let da = dex * aey - aex * dey;
    let ac = aex * cey - cex * aey;
    let bd = bex * dey - dex * bey;
    let abc = aez * bc - bez * ac + cez * ab;
    let bcd = bez * cd - cez * bd + dez * bc;
    let cda = cez * da + dez * ac + aez * cd;
    let dab = dez * ab + aez * bd + bez * da;
    let alift = aex * aex + aey * aey + aez * aez;
    let blift = bex * bex + bey * bey + bez * bez;
    let clift = cex * cex + cey * cey + cez * cez;
    let dlift = dex * dex + dey * dey + dez * dez;
    let det = (dlift * abc - clift * dab) + (blift * cda - alift * bcd);
    let mx = aex.abs().max(bex.abs()).max(cex.abs()).max(dex.abs());
    let my = aey.abs().max(bey.abs()).max(cey.abs()).max(dey.abs());
    let mz = aez.abs().max(bez.abs()).max(cez.abs()).max(dez.abs());
    let bound = ISP_SEMI_STATIC * (mx * my * mz) * (mx * mx + my * my + mz * mz);
    if bound > SEMI_STATIC_MIN && (det > bound || -det > bound) {
        return det;
    }
    insphere_exact(a, b, c, d, e)
}

#[inline(never)]
fn insphere_exact(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3], e: &[f64; 3]) -> f64 {
    robust::insphere(c3(a), c3(b), c3(c), c3(d), c3(e))
}

/// Asks the processor to bring the cache line of `r` in: a hint, with no effect on results.
#[inline(always)]
fn prefetch<T>(r: Option<&T>) {
    #[cfg(target_arch = "x86_64")]
    if let Some(r) = r {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        // SAFETY: SSE is part of the x86_64 baseline, and a prefetch never faults nor changes
        // memory: it is only a hint, valid for any address.
        unsafe { _mm_prefetch::<_MM_HINT_T0>((r as *const T).cast::<i8>()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = r;
}

/// A small deterministic generator (xorshift64*), so the insertion order and the walk never
/// depend on anything but the input.
#[derive(Clone)]
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
}

/// Checks that the points span 3D space; returns the error that says what is wrong otherwise.
pub(crate) fn check_spans_3d(points: &[[f64; 3]]) -> Result<(), NormalsError> {
    if let Some(index) = points.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(NormalsError::NonFinitePoint { index });
    }
    let distinct = count_distinct(points);
    if distinct < 5 {
        return Err(NormalsError::TooFewPoints {
            n_points: distinct,
            min: 5,
        });
    }
    let p0 = points[0];
    let Some(p1) = points.iter().find(|p| **p != p0).copied() else {
        return Err(NormalsError::Collinear);
    };
    let collinear = |p: &[f64; 3]| {
        let xy = robust::orient2d(
            robust::Coord { x: p0[0], y: p0[1] },
            robust::Coord { x: p1[0], y: p1[1] },
            robust::Coord { x: p[0], y: p[1] },
        );
        let yz = robust::orient2d(
            robust::Coord { x: p0[1], y: p0[2] },
            robust::Coord { x: p1[1], y: p1[2] },
            robust::Coord { x: p[1], y: p[2] },
        );
        let zx = robust::orient2d(
            robust::Coord { x: p0[2], y: p0[0] },
            robust::Coord { x: p1[2], y: p1[0] },
            robust::Coord { x: p[2], y: p[0] },
        );
        xy == 0.0 && yz == 0.0 && zx == 0.0
    };
    let Some(p2) = points.iter().find(|p| !collinear(p)).copied() else {
        return Err(NormalsError::Collinear);
    };
    if points.iter().all(|p| orient3d(&p0, &p1, &p2, p) == 0.0) {
        return Err(NormalsError::Coplanar);
    }
    Ok(())
}

fn count_distinct(points: &[[f64; 3]]) -> usize {
    let mut keys: Vec<[u64; 3]> = points
        .par_iter()
        .map(|p| p.map(|c| (c + 0.0).to_bits()))
        .collect();
    keys.par_sort_unstable();
    keys.dedup();
    keys.len()
}

/// Hilbert index of a point quantised to 2^bits cells per axis (Skilling 2004, "Programming the
/// Hilbert curve": axes to transposed index, then bit interleaving).
fn hilbert_index(mut x: [u32; 3], bits: u32) -> u64 {
    let m = 1u32 << (bits - 1);
    let mut q = m;
    while q > 1 {
        let p = q - 1;
        for i in 0..3 {
            if x[i] & q != 0 {
                x[0] ^= p;
            } else {
                let t = (x[0] ^ x[i]) & p;
                x[0] ^= t;
                x[i] ^= t;
            }
        }
        q >>= 1;
    }
    for i in 1..3 {
        x[i] ^= x[i - 1];
    }
    let mut t = 0;
    q = m;
    while q > 1 {
        if x[2] & q != 0 {
            t ^= q - 1;
        }
        q >>= 1;
    }
    for v in &mut x {
        *v ^= t;
    }
    let mut key = 0u64;
    for b in (0..bits).rev() {
        for v in &x {
            key = (key << 1) | u64::from((v >> b) & 1);
        }
    }
    key
}

/// Insertion order: a deterministic shuffle cut into rounds of doubling size (BRIO), each
/// round sorted along a Hilbert curve so that consecutive points are close.
fn brio_order(points: &[[f64; 3]], ids: &mut [u32]) {
    const BITS: u32 = 16;
    let Some(bbox) = crate::cloud::Aabb::from_points(points) else {
        return;
    };
    let scale = (0..3)
        .map(|a| bbox.max[a] - bbox.min[a])
        .fold(0.0f64, f64::max)
        .max(f64::MIN_POSITIVE);
    let cells = f64::from((1u32 << BITS) - 1);
    let key = |i: u32| {
        let p = points[i as usize];
        let q =
            [0, 1, 2].map(|a| (((p[a] - bbox.min[a]) / scale) * cells).clamp(0.0, cells) as u32);
        hilbert_index(q, BITS)
    };
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for i in (1..ids.len()).rev() {
        let j = (rng.next() % (i as u64 + 1)) as usize;
        ids.swap(i, j);
    }
    let mut end = ids.len();
    while end > 0 {
        let start = if end > 64 { end / 2 } else { 0 };
        ids[start..end].sort_by_cached_key(|&i| (key(i), i));
        end = start;
    }
}

/// Builds the Delaunay tetrahedralization of `points`.
///
/// # Errors
/// Fewer than 5 distinct points, a non-finite coordinate, or all points on a line or a plane.
///
/// ```
/// use stablesurf::normals::delaunay::tetrahedralize;
/// let cube: Vec<[f64; 3]> = (0..8)
///     .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64])
///     .collect();
/// let mut points = cube.clone();
/// points.push([0.5, 0.5, 0.5]);
/// let dt = tetrahedralize(&points).unwrap();
/// assert_eq!(dt.tets.len(), 12); // the centre coned to the 12 triangles of the cube's faces
/// ```
pub fn tetrahedralize(points: &[[f64; 3]]) -> Result<Tetrahedralization, NormalsError> {
    tetrahedralize_timed(points, &mut Vec::new())
}

/// [`tetrahedralize`], appending the wall time of its phases (checks, sort, insertion,
/// compaction) to `times`.
fn tetrahedralize_timed(
    points: &[[f64; 3]],
    times: &mut Vec<(&'static str, std::time::Duration)>,
) -> Result<Tetrahedralization, NormalsError> {
    let mut clock = std::time::Instant::now();
    let mut lap = |name: &'static str, times: &mut Vec<(&'static str, std::time::Duration)>| {
        let now = std::time::Instant::now();
        times.push((name, now - clock));
        clock = now;
    };
    check_spans_3d(points)?;
    let n = points.len();
    let mut delaunay = Delaunay::enclosing(points)?;
    // Exact duplicates are merged with their first occurrence before insertion.
    let mut representative: Vec<u32> = (0..n as u32).collect();
    let key = |i: u32| points[i as usize].map(|c| (c + 0.0).to_bits());
    let mut sorted: Vec<u32> = (0..n as u32).collect();
    sorted.sort_unstable_by_key(|&i| (key(i), i));
    for w in 1..sorted.len() {
        if key(sorted[w]) == key(sorted[w - 1]) {
            representative[sorted[w] as usize] = representative[sorted[w - 1] as usize];
        }
    }
    let ids: Vec<u32> = (0..n as u32)
        .filter(|&i| representative[i as usize] == i)
        .collect();
    lap("delaunay: checks + dedup", times);
    delaunay.insert(points, ids, 0, &mut representative, Keep::All, times);
    let dt = delaunay.extract(representative);
    lap("delaunay: compaction", times);
    Ok(dt)
}

/// A tetrahedron record: vertices (internal ids) and neighbours. `n[i]` is the tetrahedron
/// across the face opposite `v[i]` shifted left by two, with the index of the shared face in
/// that neighbour in the low two bits, or [`NO_NEIGHBOUR`]. A free slot has
/// `v[0] == NO_NEIGHBOUR`. Vertices and neighbours share one 32-byte record, so visiting a
/// tetrahedron touches one cache line.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
struct Tet {
    v: [u32; 4],
    n: [u32; 4],
}

/// A face of the cavity's boundary: the cone tetrahedron's vertices (the cavity tetrahedron's
/// with the new point at `i`), and the packed outside neighbour.
#[derive(Clone, Copy)]
struct BoundaryFace {
    verts: [u32; 4],
    i: u32,
    outside: u32,
}

/// An entry of the cone-gluing hash table: an edge key, the insertion stamp that wrote it,
/// and the packed (tet, face) waiting for its twin ([`NO_NEIGHBOUR`] once glued).
#[derive(Clone, Copy, Default)]
struct EdgeSlot {
    key: u64,
    stamp: u32,
    face: u32,
}

/// Which points of a batch [`Delaunay::insert`] inserts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Keep {
    /// Every point.
    All,
    /// Only the points whose cavity holds a tetrahedron with a face among the first `limit`
    /// points inserted (the crust's samples); the others are left out (see
    /// [`crate::normals::crust`] for why that changes no such face).
    IfCavityHasFaceBelow(u32),
}

/// What happened to one point in [`Delaunay::insert_one`].
enum Outcome {
    Inserted,
    /// Left out by the safety net.
    Rejected,
    /// Left out by [`Keep::IfCavityHasFaceBelow`].
    Redundant,
}

/// Incremental Bowyer–Watson state, kept between insertions so that a second batch of points
/// (the crust's poles) can be added to the triangulation of the first.
///
/// Internally, points are stored in insertion order (internal id 0–3: the enclosing
/// tetrahedron), so that the vertices of nearby tetrahedra are close in memory; `orig` maps an
/// internal id back to the caller's index, which is also the symbolic perturbation's priority.
#[derive(Clone)]
pub(crate) struct Delaunay {
    pts: Vec<[f64; 3]>,
    orig: Vec<u32>,
    tets: Vec<Tet>,
    /// `mark[t] == stamp`: tet `t` is in the current cavity; `mark[t] == stamp + 1`: tet `t` was
    /// tested and is not. Stamps grow by two per insertion, so nothing is ever cleared.
    mark: Vec<u32>,
    free: Vec<u32>,
    stamp: u32,
    rng: Rng,
    last: u32,
    cavity: Vec<u32>,
    boundary: Vec<BoundaryFace>,
    stack: Vec<u32>,
    table: Vec<EdgeSlot>,
    n_rejected: usize,
    pub(crate) n_redundant: usize,
}

/// Priority of enclosing vertex `i` in the symbolic perturbation (above every real point).
const ENCLOSING_KEY: u32 = u32::MAX - 4;

/// Whether `p` (caller index `key`) is strictly inside the perturbed circumsphere of the
/// positive tet `q` (caller indices `keys`): the exact insphere sign, and for an exactly
/// co-spherical configuration the symbolic perturbation ([`perturbed_inside`]). The same
/// decision the insertion makes, so it can be asked of points in different triangulations.
fn inside(q: &[[f64; 3]; 4], keys: [u32; 4], p: &[f64; 3], key: u32) -> bool {
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
fn perturbed_inside(q: &[[f64; 3]; 4], keys: [u32; 4], p: &[f64; 3], key: u32) -> bool {
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

/// A vertex of a triangulation by caller index, with its position.
#[derive(Clone, Copy, Debug)]
struct Apex {
    key: u32,
    point: [f64; 3],
}

/// A face among the first points of a triangulation ([`Delaunay::face_apexes`]): its vertices
/// in increasing caller index `[a, b, c]`, and the caller indices of the opposite vertices of
/// its two tetrahedra, on the side where `orient3d(a, b, c, ·) > 0` (`plus`) and on the other
/// (`minus`). Twenty bytes, so that the lists of hundreds of thousands of faces sort and merge
/// in cache-sized strides; the positions are looked up in [`KeyedPoints`] when needed.
#[derive(Clone, Copy, Debug)]
pub(crate) struct FaceApexes {
    key: [u32; 3],
    plus: u32,
    minus: u32,
}

/// The positions of a triangulation's vertices by caller index: `first` (indices below its
/// length), the points inserted after them (`extra`, index `first.len() + j`), and the
/// enclosing tetrahedron's vertices ([`Delaunay::enclosing_points`]).
pub(crate) struct KeyedPoints<'a> {
    pub first: &'a [[f64; 3]],
    pub extra: &'a [[f64; 3]],
    pub enclosing: [[f64; 3]; 4],
}

impl KeyedPoints<'_> {
    fn apex(&self, key: u32) -> Apex {
        let k = key as usize;
        let point = if key >= ENCLOSING_KEY {
            self.enclosing[(key - ENCLOSING_KEY) as usize]
        } else if k < self.first.len() {
            self.first[k]
        } else {
            self.extra[k - self.first.len()]
        };
        Apex { key, point }
    }
}

/// The faces among the first points (caller indices below the `limit` given to
/// [`Delaunay::face_apexes`], positions `points.first`) of the Delaunay tetrahedralization of the
/// union of the point sets of several triangulations that all contain those first points, from
/// their [`FaceApexes`] lists alone; the same list, wound and sorted the same way, as
/// [`Delaunay::faces_among`] on one triangulation of the union would give.
///
/// Why it holds: the centres of the balls through a face's three vertices form a line; a point
/// on the plus side is strictly inside the ball for the centres beyond some position along it,
/// a point on the minus side for those before some position, and the face is a Delaunay face
/// exactly when some centre has an empty ball, i.e. when the plus side's first position comes
/// after the minus side's last. In each triangulation the face's two tetrahedra have as
/// apexes the plus point with the first position and the minus point with the last among its
/// points; over the union, the plus apex is the earliest of the triangulations' plus apexes
/// (one point precedes another when it is strictly inside the sphere through the face and the
/// other), the minus apex the latest, and the face survives when the minus apex is outside the
/// sphere through the face and the plus apex. Every comparison is the insertion's own perturbed
/// insphere test, so the union's faces are decided exactly as inserting all the points into
/// one triangulation would. A face missing from any triangulation is not a Delaunay face of the
/// union (an empty ball for the union is empty for each part).
pub(crate) fn faces_among_union(parts: &[Vec<FaceApexes>], points: &KeyedPoints) -> Vec<[u32; 3]> {
    let Some((first, rest)) = parts.split_first() else {
        return Vec::new();
    };
    // Merge walk over the sorted lists: the faces in every part, as one index per part.
    let k = parts.len();
    let mut matched: Vec<u32> = Vec::with_capacity(first.len() * k);
    let mut cursors = vec![0usize; rest.len()];
    'faces: for (i, face) in first.iter().enumerate() {
        for (c, part) in cursors.iter_mut().zip(rest) {
            while *c < part.len() && part[*c].key < face.key {
                *c += 1;
            }
            if *c == part.len() || part[*c].key != face.key {
                continue 'faces;
            }
        }
        matched.push(i as u32);
        matched.extend(cursors.iter().map(|&c| c as u32));
    }
    let mut faces: Vec<[u32; 3]> = matched
        .par_chunks(k)
        .filter_map(|indices| {
            union_face(
                points,
                indices
                    .iter()
                    .zip(parts)
                    .map(|(&i, part)| &part[i as usize]),
            )
        })
        .collect();
    faces.sort_unstable();
    faces
}

/// One face of [`faces_among_union`]: its records in the parts (at least one, all with the same
/// key); the face as [`Delaunay::faces_among`] winds it, or None when it is not a face of the
/// union or not one of the kept faces (both its tetrahedra touch the enclosing vertices).
fn union_face<'a>(
    points: &KeyedPoints,
    mut records: impl Iterator<Item = &'a FaceApexes>,
) -> Option<[u32; 3]> {
    let first = records.next()?;
    let [ka, kb, kc] = first.key;
    let [a, b, c] = first.key.map(|v| points.first[v as usize]);
    // The positive tetrahedra of the face with a plus apex and with a minus apex.
    let plus_tet = |x: Apex| ([a, b, c, x.point], [ka, kb, kc, x.key]);
    let minus_tet = |x: Apex| ([a, c, b, x.point], [ka, kc, kb, x.key]);
    let precedes = |tet: ([[f64; 3]; 4], [u32; 4]), x: Apex| inside(&tet.0, tet.1, &x.point, x.key);
    let (mut plus, mut minus) = (points.apex(first.plus), points.apex(first.minus));
    for r in records {
        if r.plus != plus.key {
            let other = points.apex(r.plus);
            if precedes(plus_tet(plus), other) {
                plus = other;
            }
        }
        if r.minus != minus.key {
            let other = points.apex(r.minus);
            if precedes(minus_tet(minus), other) {
                minus = other;
            }
        }
    }
    if precedes(plus_tet(plus), minus) {
        return None;
    }
    // Wound for the tetrahedron whose apex has the smaller caller index, as `faces_among`
    // does; the enclosing vertices have the largest ones.
    if plus.key.min(minus.key) >= ENCLOSING_KEY {
        return None;
    }
    Some(if plus.key < minus.key {
        [ka, kb, kc]
    } else {
        [ka, kc, kb]
    })
}

impl Delaunay {
    /// An empty triangulation inside a tetrahedron 1000 times the size of `points` (their
    /// bounding box), which also contains anything within a few box diagonals of them.
    pub(crate) fn enclosing(points: &[[f64; 3]]) -> Result<Delaunay, NormalsError> {
        // Packed neighbours leave 30 bits for tet ids; a triangulation has about 6.5 n tets.
        if points.len() >= 1 << 26 {
            return Err(NormalsError::TooManyPoints {
                n_points: points.len(),
            });
        }
        let bbox = crate::cloud::Aabb::from_points(points).ok_or(NormalsError::TooFewPoints {
            n_points: 0,
            min: 5,
        })?;
        let centre = bbox.center();
        let radius = (0.5 * bbox.diagonal()).max(f64::MIN_POSITIVE);
        // The inscribed sphere of this tetrahedron has radius k / sqrt(3) > 1000 * radius.
        let k = 2000.0 * radius;
        let pts: Vec<[f64; 3]> = [
            [1.0, 1.0, 1.0],
            [1.0, -1.0, -1.0],
            [-1.0, 1.0, -1.0],
            [-1.0, -1.0, 1.0],
        ]
        .iter()
        .map(|s| [0, 1, 2].map(|a| centre[a] + k * s[a]))
        .collect();
        let mut v = [0, 1, 2, 3];
        if orient3d(&pts[0], &pts[1], &pts[2], &pts[3]) < 0.0 {
            v.swap(0, 1);
        }
        Ok(Delaunay {
            pts,
            orig: (0..4).map(|i| ENCLOSING_KEY + i).collect(),
            tets: vec![Tet {
                v,
                n: [NO_NEIGHBOUR; 4],
            }],
            mark: vec![0],
            free: Vec::new(),
            stamp: 0,
            rng: Rng(0x2545_f491_4f6c_dd1d),
            last: 0,
            cavity: Vec::new(),
            boundary: Vec::new(),
            stack: Vec::new(),
            table: Vec::new(),
            n_rejected: 0,
            n_redundant: 0,
        })
    }

    /// Inserts `points[i]` for each `i` in `ids` (in BRIO order), as caller index
    /// `first + i`. A point equal to a vertex already there is not inserted:
    /// `representative[first + i]` is set to that vertex's caller index.
    pub(crate) fn insert(
        &mut self,
        points: &[[f64; 3]],
        mut ids: Vec<u32>,
        first: u32,
        representative: &mut [u32],
        rule: Keep,
        times: &mut Vec<(&'static str, std::time::Duration)>,
    ) {
        let clock = std::time::Instant::now();
        brio_order(points, &mut ids);
        let now = std::time::Instant::now();
        times.push(("delaunay: brio sort", now - clock));
        self.pts.reserve(ids.len());
        self.orig.reserve(ids.len());
        let expected = self.tets.len() + 7 * ids.len();
        self.tets.reserve(expected.saturating_sub(self.tets.len()));
        self.mark.reserve(expected.saturating_sub(self.mark.len()));
        for &i in &ids {
            let p = points[i as usize];
            let v = self.pts.len() as u32;
            self.pts.push(p);
            self.orig.push(first + i);
            let t = self.locate(self.last, &p);
            let tv = self.tets[t as usize].v;
            if let Some(&dup) = tv.iter().find(|&&w| self.pts[w as usize] == p) {
                representative[(first + i) as usize] = self.orig[dup as usize];
                continue;
            }
            match self.insert_one(t, v, rule) {
                Outcome::Inserted => {}
                Outcome::Rejected => self.n_rejected += 1,
                Outcome::Redundant => {
                    // Nothing changed, and `t` contains this point: the next point, close to
                    // it in the insertion order, is found faster from here than from the last
                    // point inserted.
                    self.n_redundant += 1;
                    self.last = t;
                }
            }
        }
        times.push(("delaunay: insertion", now.elapsed()));
    }

    /// The tetrahedra not touching the enclosing vertices, renumbered, with caller indices.
    /// `representative` chains (a duplicate of a duplicate) are resolved.
    pub(crate) fn extract(&self, mut representative: Vec<u32>) -> Tetrahedralization {
        for i in 0..representative.len() {
            let mut r = representative[i];
            while representative[r as usize] != r {
                r = representative[r as usize];
            }
            representative[i] = r;
        }
        let mut new_index = vec![NO_NEIGHBOUR; self.tets.len()];
        let mut tets = Vec::with_capacity(self.tets.len());
        for (t, tet) in self.tets.iter().enumerate() {
            if tet.v[0] != NO_NEIGHBOUR && tet.v.iter().all(|&v| v >= 4) {
                new_index[t] = tets.len() as u32;
                tets.push(tet.v.map(|v| self.orig[v as usize]));
            }
        }
        let mut neighbours = Vec::with_capacity(tets.len());
        for (t, tet) in self.tets.iter().enumerate() {
            if new_index[t] != NO_NEIGHBOUR {
                neighbours.push(tet.n.map(|u| {
                    if u == NO_NEIGHBOUR {
                        NO_NEIGHBOUR
                    } else {
                        new_index[(u >> 2) as usize]
                    }
                }));
            }
        }
        Tetrahedralization {
            tets,
            neighbours,
            representative,
            n_rejected: self.n_rejected,
        }
    }

    /// The faces whose three vertices have caller indices below `limit`, each once, sorted.
    /// (The crust uses [`faces_among_union`]; this is its reference in the tests.)
    /// The result depends only on the triangulation, not on how its tetrahedra are stored: a
    /// face is wound as [`face_vertices`] winds it for the adjacent kept tetrahedron whose
    /// opposite vertex has the smaller caller index, and rotated to start at its smallest index.
    #[cfg(test)]
    pub(crate) fn faces_among(&self, limit: u32) -> Vec<[u32; 3]> {
        let kept = |t: &Tet| t.v[0] != NO_NEIGHBOUR && t.v.iter().all(|&v| v >= 4);
        let mut faces = Vec::new();
        for tet in &self.tets {
            if !kept(tet) {
                continue;
            }
            let ids = tet.v.map(|v| self.orig[v as usize]);
            if ids.iter().filter(|&&v| v < limit).count() < 3 {
                continue;
            }
            for i in 0..4 {
                let u = tet.n[i];
                if u != NO_NEIGHBOUR {
                    let other = &self.tets[(u >> 2) as usize];
                    if kept(other) && self.orig[other.v[(u & 3) as usize] as usize] < ids[i] {
                        continue;
                    }
                }
                let f = face_vertices(ids, i);
                if f.iter().all(|&v| v < limit) {
                    let k = (0..3).min_by_key(|&k| f[k]).unwrap_or(0);
                    faces.push([f[k], f[(k + 1) % 3], f[(k + 2) % 3]]);
                }
            }
        }
        faces.sort_unstable();
        faces
    }

    /// The faces whose three vertices have caller indices below `limit`, with the apexes of
    /// their two tetrahedra, sorted by their vertices: a part for [`faces_among_union`].
    pub(crate) fn face_apexes(&self, limit: u32) -> Vec<FaceApexes> {
        let mut faces: Vec<FaceApexes> = self
            .tets
            .par_chunks(4096)
            .flat_map_iter(|block| {
                block.iter().flat_map(move |tet| {
                    let ids = tet.v.map(|v| {
                        if v == NO_NEIGHBOUR {
                            u32::MAX
                        } else {
                            self.orig[v as usize]
                        }
                    });
                    let live = tet.v[0] != NO_NEIGHBOUR;
                    (0..4).filter_map(move |i| {
                        let u = tet.n[i];
                        if !live || u == NO_NEIGHBOUR {
                            return None;
                        }
                        // Each face once, from the tetrahedron on its plus side.
                        let f = face_vertices(ids, i);
                        if f.iter().any(|&v| v >= limit) {
                            return None;
                        }
                        let k = (0..3).min_by_key(|&k| f[k]).unwrap_or(0);
                        let (x, y) = (f[(k + 1) % 3], f[(k + 2) % 3]);
                        if x > y {
                            return None;
                        }
                        let other = self.tets[(u >> 2) as usize].v[(u & 3) as usize];
                        Some(FaceApexes {
                            key: [f[k], x, y],
                            plus: ids[i],
                            minus: self.orig[other as usize],
                        })
                    })
                })
            })
            .collect();
        faces.par_sort_unstable_by_key(|f| f.key);
        faces
    }

    /// The positions of the enclosing tetrahedron's vertices (caller indices `ENCLOSING_KEY`
    /// and the three after it).
    pub(crate) fn enclosing_points(&self) -> [[f64; 3]; 4] {
        [0, 1, 2, 3].map(|v| self.pts[v])
    }

    #[inline]
    fn p(&self, v: u32) -> [f64; 3] {
        self.pts[v as usize]
    }

    /// Visibility walk from tet `start` to a tet whose closure contains `p`. The face the walk
    /// came through is not tested again (`p` is known to be on its inner side).
    fn locate(&mut self, start: u32, p: &[f64; 3]) -> u32 {
        let mut t = start;
        let mut came = 4usize;
        let mut steps = 0usize;
        'walk: loop {
            steps += 1;
            if steps > 4 * self.tets.len() + 64 {
                // Cannot happen with exact predicates on a valid triangulation; scan as a fallback.
                return self.locate_by_scan(p).unwrap_or(start);
            }
            let tet = self.tets[t as usize];
            let q = tet.v.map(|w| self.p(w));
            let r = (self.rng.next() & 3) as usize;
            for k in 0..4 {
                let i = (r + k) & 3;
                if i == came {
                    continue;
                }
                let mut f = q;
                f[i] = *p;
                if orient3d(&f[0], &f[1], &f[2], &f[3]) < 0.0 {
                    let u = tet.n[i];
                    if u == NO_NEIGHBOUR {
                        // Outside the enclosing tetrahedron: cannot happen, all points are inside.
                        return t;
                    }
                    t = u >> 2;
                    came = (u & 3) as usize;
                    continue 'walk;
                }
            }
            return t;
        }
    }

    fn locate_by_scan(&self, p: &[f64; 3]) -> Option<u32> {
        (0..self.tets.len() as u32).find(|&t| {
            let tet = self.tets[t as usize];
            tet.v[0] != NO_NEIGHBOUR
                && (0..4).all(|i| {
                    let mut q = tet.v.map(|w| self.p(w));
                    q[i] = *p;
                    orient3d(&q[0], &q[1], &q[2], &q[3]) >= 0.0
                })
        })
    }

    /// Whether point `v` is in conflict with tet `t` (strictly inside its perturbed circumsphere).
    #[inline]
    fn conflict(&self, t: u32, v: u32) -> bool {
        let tet = self.tets[t as usize].v;
        let q = tet.map(|w| self.p(w));
        let p = self.p(v);
        let s = insphere(&q[0], &q[1], &q[2], &q[3], &p);
        if s != 0.0 {
            return s > 0.0;
        }
        // The decision of `inside`, written out so that the caller indices are looked up only
        // on this rare co-spherical path, not before every test of the cavity search.
        perturbed_inside(
            &q,
            tet.map(|w| self.orig[w as usize]),
            &p,
            self.orig[v as usize],
        )
    }

    fn alloc(&mut self) -> u32 {
        match self.free.pop() {
            Some(s) => s,
            None => {
                self.tets.push(Tet {
                    v: [NO_NEIGHBOUR; 4],
                    n: [NO_NEIGHBOUR; 4],
                });
                self.mark.push(0);
                (self.tets.len() - 1) as u32
            }
        }
    }

    /// Inserts point `v` into the triangulation, starting from tet `t` that contains it.
    /// Returns false when the point was rejected by the safety net.
    fn insert_one(&mut self, t: u32, v: u32, rule: Keep) -> Outcome {
        // Stamps go up by two: `stamp` marks the cavity, `stamp + 1` the tested non-cavity tets.
        self.stamp = self.stamp.wrapping_add(2);
        if self.stamp >= u32::MAX - 1 {
            self.mark.iter_mut().for_each(|m| *m = 0);
            self.table.iter_mut().for_each(|e| e.stamp = 0);
            self.stamp = 2;
        }
        let stamp = self.stamp;
        self.cavity.clear();
        self.boundary.clear();
        self.stack.clear();
        self.mark[t as usize] = stamp;
        self.stack.push(t);
        let mut needed = true;
        let mut below = u32::MAX;
        if let Keep::IfCavityHasFaceBelow(limit) = rule {
            needed = false;
            below = limit;
        }
        while let Some(c) = self.stack.pop() {
            self.cavity.push(c);
            let tet = self.tets[c as usize];
            // The four neighbours are about to be tested: fetch their records and marks from
            // memory together rather than one miss after another.
            for &u in &tet.n {
                if u != NO_NEIGHBOUR {
                    let ut = (u >> 2) as usize;
                    prefetch(self.tets.get(ut));
                    prefetch(self.mark.get(ut));
                }
            }
            // Each neighbour's test needs its one vertex off the shared face (the other
            // three are this tetrahedron's, already in cache): once the neighbour records
            // are in, request those four points together too.
            for &u in &tet.n {
                if u != NO_NEIGHBOUR {
                    if let Some(nt) = self.tets.get((u >> 2) as usize) {
                        prefetch(self.pts.get(nt.v[(u & 3) as usize] as usize));
                    }
                }
            }
            if !needed {
                // Internal ids 4.. are in insertion order, so "caller index below the limit"
                // is "internal id in 4..4 + limit" for a first batch of `limit` points.
                let low = tet.v.iter().filter(|&&w| w >= 4 && w - 4 < below).count();
                needed = low >= 3;
            }
            for i in 0..4 {
                let u = tet.n[i];
                let outside = if u == NO_NEIGHBOUR {
                    true
                } else {
                    let ut = u >> 2;
                    let m = self.mark[ut as usize];
                    if m == stamp {
                        false
                    } else if m == stamp + 1 {
                        true
                    } else if self.conflict(ut, v) {
                        self.mark[ut as usize] = stamp;
                        self.stack.push(ut);
                        false
                    } else {
                        self.mark[ut as usize] = stamp + 1;
                        true
                    }
                };
                if outside {
                    let mut verts = tet.v;
                    verts[i] = v;
                    self.boundary.push(BoundaryFace {
                        verts,
                        i: i as u32,
                        outside: u,
                    });
                }
            }
        }
        if !needed {
            return Outcome::Redundant;
        }
        // Safety net: every cone tet must be positively oriented (a star-shaped cavity).
        for f in &self.boundary {
            let q = f.verts.map(|w| self.p(w));
            if orient3d(&q[0], &q[1], &q[2], &q[3]) <= 0.0 {
                return Outcome::Rejected;
            }
        }
        // Free the cavity, then build the cone in the freed slots (reused last in, first out).
        for k in 0..self.cavity.len() {
            let c = self.cavity[k];
            self.tets[c as usize].v[0] = NO_NEIGHBOUR;
            self.free.push(c);
        }
        // Each internal face of the cone (an edge of the cavity boundary coned to v) is shared
        // by exactly two cone tets: they find each other through a small open-addressing table
        // keyed by the edge, sized for a load factor of at most 1/2 and never cleared (entries
        // carry the insertion's stamp).
        let size = (4 * self.boundary.len()).next_power_of_two().max(16);
        if self.table.len() < size {
            self.table.resize(size, EdgeSlot::default());
        }
        let mask = size - 1;
        let mut nt = self.last;
        for k in 0..self.boundary.len() {
            let f = self.boundary[k];
            nt = self.alloc();
            let i = f.i as usize;
            let mut n = [NO_NEIGHBOUR; 4];
            n[i] = f.outside;
            if f.outside != NO_NEIGHBOUR {
                self.tets[(f.outside >> 2) as usize].n[(f.outside & 3) as usize] = (nt << 2) | f.i;
            }
            self.tets[nt as usize] = Tet { v: f.verts, n };
            self.mark[nt as usize] = 0;
            for j in 0..4 {
                if j == i {
                    continue;
                }
                // The face opposite vertex j holds v and the two face vertices other than j.
                let (a, b) = match (i, j) {
                    (0, 1) | (1, 0) => (f.verts[2], f.verts[3]),
                    (0, 2) | (2, 0) => (f.verts[1], f.verts[3]),
                    (0, 3) | (3, 0) => (f.verts[1], f.verts[2]),
                    (1, 2) | (2, 1) => (f.verts[0], f.verts[3]),
                    (1, 3) | (3, 1) => (f.verts[0], f.verts[2]),
                    _ => (f.verts[0], f.verts[1]),
                };
                let key = (u64::from(a.min(b)) << 32) | u64::from(a.max(b));
                let me = (nt << 2) | j as u32;
                let mut h = (key.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40) as usize & mask;
                loop {
                    let slot = self.table[h];
                    if slot.stamp != stamp {
                        self.table[h] = EdgeSlot {
                            key,
                            stamp,
                            face: me,
                        };
                        break;
                    }
                    if slot.key == key && slot.face != NO_NEIGHBOUR {
                        let other = slot.face;
                        self.tets[(other >> 2) as usize].n[(other & 3) as usize] = me;
                        self.tets[nt as usize].n[j] = other;
                        self.table[h].face = NO_NEIGHBOUR;
                        break;
                    }
                    h = (h + 1) & mask;
                }
            }
        }
        self.last = nt;
        Outcome::Inserted
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hilbert_index_is_a_bijection_on_a_small_grid() {
        let mut keys: Vec<u64> = (0..512u32)
            .map(|i| hilbert_index([i & 7, (i >> 3) & 7, i >> 6], 3))
            .collect();
        keys.sort_unstable();
        keys.dedup();
        assert_eq!(keys.len(), 512);
        assert!(keys.iter().all(|&k| k < 512));
    }

    #[test]
    fn hilbert_neighbours_in_order_are_adjacent_cells() {
        let mut cells: Vec<(u64, [u32; 3])> = (0..512u32)
            .map(|i| {
                let c = [i & 7, (i >> 3) & 7, i >> 6];
                (hilbert_index(c, 3), c)
            })
            .collect();
        cells.sort_unstable();
        for w in cells.windows(2) {
            let d: u32 = (0..3).map(|a| w[0].1[a].abs_diff(w[1].1[a])).sum();
            assert_eq!(d, 1, "consecutive Hilbert cells {:?} {:?}", w[0], w[1]);
        }
    }

    /// Samples on a lattice (exactly co-spherical subsets everywhere) and extra points, some on
    /// the half lattice (co-spherical with samples) and some on a sample: the faces among the
    /// samples decided from parts ([`faces_among_union`]) are those of one triangulation of
    /// all the points, wound the same way, for 1, 2 and 3 parts and both insertion rules.
    #[test]
    fn faces_of_a_union_are_those_of_one_triangulation() {
        let mut samples = Vec::new();
        for i in 0..5 {
            for j in 0..5 {
                for k in 0..3 {
                    samples.push([f64::from(i), f64::from(j), 0.75 * f64::from(k)]);
                }
            }
        }
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let mut unit = || (rng.next() >> 11) as f64 / (1u64 << 53) as f64;
        let mut extra: Vec<[f64; 3]> = (0..120)
            .map(|_| [4.4 * unit() - 0.2, 4.4 * unit() - 0.2, 1.8 * unit() - 0.15])
            .collect();
        extra
            .extend((0..4).flat_map(|i| {
                (0..4).map(move |j| [f64::from(i) + 0.5, f64::from(j) + 0.5, 0.375])
            }));
        extra.push(samples[7]);
        let (n, m) = (samples.len() as u32, extra.len() as u32);
        let mut base = Delaunay::enclosing(&samples).expect("3D samples");
        let mut representative: Vec<u32> = (0..n).collect();
        base.insert(
            &samples,
            (0..n).collect(),
            0,
            &mut representative,
            Keep::All,
            &mut Vec::new(),
        );
        let with = |d: &Delaunay, ids: Vec<u32>, rule: Keep| {
            let mut d = d.clone();
            let mut representative: Vec<u32> = (0..n + m).collect();
            d.insert(&extra, ids, n, &mut representative, rule, &mut Vec::new());
            d
        };
        let all_samples = base.faces_among(n);
        for rule in [Keep::All, Keep::IfCavityHasFaceBelow(n)] {
            let expected = with(&base, (0..m).collect(), rule).faces_among(n);
            assert!(
                expected.len() + 50 < all_samples.len(),
                "the extra points remove faces"
            );
            for k in 1..=3 {
                let parts: Vec<Vec<FaceApexes>> = (0..k)
                    .map(|p| with(&base, (0..m).filter(|i| i % k == p).collect(), rule))
                    .map(|d| d.face_apexes(n))
                    .collect();
                let points = KeyedPoints {
                    first: &samples,
                    extra: &extra,
                    enclosing: base.enclosing_points(),
                };
                assert_eq!(faces_among_union(&parts, &points), expected, "{k} parts");
            }
        }
    }
}
