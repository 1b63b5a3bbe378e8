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
//!
//! The parts: [`perturbation`] (the symbolic perturbation over the exact, filtered predicates of
//! [`crate::numerics::predicates`]), [`order`] (the BRIO/Hilbert insertion order), [`insert`] (the insertion state and the walk,
//! cavity and cone), [`union`] (faces among a first batch of points, and across
//! triangulations).

use crate::normals::NormalsError;
use crate::numerics::predicates::orient3d;

mod insert;
mod order;
mod perturbation;
mod union;

pub(crate) use insert::{Delaunay, Keep};
pub(crate) use union::{faces_among_union, KeyedPoints};

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

/// Checks that the points span 3D space; returns the error that says what is wrong otherwise.
pub(crate) fn check_spans_3d(points: &[[f64; 3]]) -> Result<(), NormalsError> {
    if let Some(index) = points.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(NormalsError::NonFinitePoint { index });
    }
    let distinct = count_distinct(points, 5);
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

/// How many distinct points `points` holds, counting up to `most`: the scan stops at the
/// `most`-th distinct point (a cloud's first few points almost always differ), so a large cloud
/// costs a few comparisons rather than a sort.
fn count_distinct(points: &[[f64; 3]], most: usize) -> usize {
    // `+ 0.0` turns -0.0 into 0.0 so that both compare equal, as they do as numbers.
    let key = |p: &[f64; 3]| p.map(|c| (c + 0.0).to_bits());
    let mut seen: Vec<[u64; 3]> = Vec::with_capacity(most);
    for p in points {
        if seen.len() >= most {
            break;
        }
        let k = key(p);
        if !seen.contains(&k) {
            seen.push(k);
        }
    }
    seen.len()
}

/// Builds the Delaunay tetrahedralization of `points`.
///
/// # Errors
/// Fewer than 5 distinct points, a non-finite coordinate, or all points on a line or a plane.
///
/// ```
/// use stablesurf::testing::tetrahedralize;
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
