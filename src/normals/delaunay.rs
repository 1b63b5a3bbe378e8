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
//!     walk from the last created tetrahedron towards p (visibility walk, orient3d tests)
//!     grow the cavity: all tetrahedra whose circumsphere contains p (insphere tests, BFS)
//!     replace the cavity by the cone from p to its boundary faces
//! ```
//!
//! Predicates are Shewchuk's adaptive exact `orient3d` and `insphere` (the `robust` crate), so
//! no decision is ever wrong because of rounding. Co-spherical subsets (insphere exactly zero,
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
#[inline]
pub fn orient3d(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3]) -> f64 {
    robust::orient3d(c3(a), c3(b), c3(c), c3(d))
}

/// Shewchuk's exact insphere: positive when `e` is inside the sphere of the positive tet `a..d`.
#[inline]
pub fn insphere(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3], e: &[f64; 3]) -> f64 {
    robust::insphere(c3(a), c3(b), c3(c), c3(d), c3(e))
}

/// A small deterministic generator (xorshift64*), so the insertion order and the walk never
/// depend on anything but the input.
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
        .iter()
        .map(|p| p.map(|c| (c + 0.0).to_bits()))
        .collect();
    keys.sort_unstable();
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
    check_spans_3d(points)?;
    let n = points.len();
    if n >= (u32::MAX - 8) as usize {
        return Err(NormalsError::TooManyPoints { n_points: n });
    }
    let bbox = crate::cloud::Aabb::from_points(points).ok_or(NormalsError::TooFewPoints {
        n_points: 0,
        min: 5,
    })?;
    let centre = bbox.center();
    let radius = (0.5 * bbox.diagonal()).max(f64::MIN_POSITIVE);
    // The inscribed sphere of this tetrahedron has radius k / sqrt(3) > 1000 * radius.
    let k = 2000.0 * radius;
    let mut all: Vec<[f64; 3]> = Vec::with_capacity(n + 4);
    all.extend_from_slice(points);
    for s in [
        [1.0, 1.0, 1.0],
        [1.0, -1.0, -1.0],
        [-1.0, 1.0, -1.0],
        [-1.0, -1.0, 1.0],
    ] {
        all.push([
            centre[0] + k * s[0],
            centre[1] + k * s[1],
            centre[2] + k * s[2],
        ]);
    }
    let s0 = n as u32;
    let mut first = [s0, s0 + 1, s0 + 2, s0 + 3];
    if orient3d(&all[n], &all[n + 1], &all[n + 2], &all[n + 3]) < 0.0 {
        first.swap(0, 1);
    }
    let mut b = Builder {
        points: &all,
        tets: vec![first],
        neighbours: vec![[NO_NEIGHBOUR; 4]],
        mark: vec![0],
        free: Vec::new(),
        stamp: 0,
        rng: Rng(0x2545_f491_4f6c_dd1d),
        cavity: Vec::new(),
        boundary: Vec::new(),
        pending: Vec::new(),
        created: Vec::new(),
        stack: Vec::new(),
    };

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
    let mut order: Vec<u32> = (0..n as u32)
        .filter(|&i| representative[i as usize] == i)
        .collect();
    brio_order(points, &mut order);
    let mut n_rejected = 0;
    let mut last = 0u32;
    for &v in &order {
        let t = b.locate(last, v);
        if let Some(dup) = b.tets[t as usize]
            .iter()
            .find(|&&w| all[w as usize] == all[v as usize])
        {
            representative[v as usize] = *dup;
            continue;
        }
        match b.insert(t, v) {
            Some(new_last) => last = new_last,
            None => n_rejected += 1,
        }
    }
    // Duplicates may have been mapped to a later duplicate of the same point; resolve chains
    // so that every representative is an inserted point.
    for i in 0..n {
        let mut r = representative[i];
        while representative[r as usize] != r {
            r = representative[r as usize];
        }
        representative[i] = r;
    }

    // Drop the tets that touch the enclosing vertices and the freed slots; renumber.
    let mut new_index = vec![NO_NEIGHBOUR; b.tets.len()];
    let mut tets = Vec::new();
    for (t, tet) in b.tets.iter().enumerate() {
        if tet[0] != NO_NEIGHBOUR && tet.iter().all(|&v| v < s0) {
            new_index[t] = tets.len() as u32;
            tets.push(*tet);
        }
    }
    let mut neighbours = Vec::with_capacity(tets.len());
    for (t, tet) in b.tets.iter().enumerate() {
        if new_index[t] != NO_NEIGHBOUR {
            debug_assert!(tet[0] != NO_NEIGHBOUR);
            neighbours.push(b.neighbours[t].map(|u| {
                if u == NO_NEIGHBOUR {
                    NO_NEIGHBOUR
                } else {
                    new_index[u as usize]
                }
            }));
        }
    }
    Ok(Tetrahedralization {
        tets,
        neighbours,
        representative,
        n_rejected,
    })
}

struct Builder<'a> {
    points: &'a [[f64; 3]],
    tets: Vec<[u32; 4]>,
    neighbours: Vec<[u32; 4]>,
    /// `mark[t] == stamp`: tet `t` is in the current cavity; `mark[t] == stamp + 1`: tet `t` was
    /// tested and is not in the current cavity. One array rather than two so that a cavity test
    /// touches one cache line of marks, not two (the tets are visited in no memory order).
    mark: Vec<u32>,
    free: Vec<u32>,
    stamp: u32,
    rng: Rng,
    cavity: Vec<u32>,
    /// Boundary faces of the cavity: (cone tet vertices: the cavity tet's with the new point at
    /// `i`, position `i`, outside neighbour, index of the face of that neighbour facing the cavity).
    boundary: Vec<([u32; 4], usize, u32, usize)>,
    /// Internal faces of the cone: (edge key, tet, face index); each key occurs exactly twice.
    pending: Vec<((u32, u32), u32, u32)>,
    created: Vec<u32>,
    stack: Vec<u32>,
}

impl Builder<'_> {
    #[inline]
    fn p(&self, v: u32) -> &[f64; 3] {
        &self.points[v as usize]
    }

    /// Visibility walk from tet `start` to a tet whose closure contains point `v`.
    fn locate(&mut self, start: u32, v: u32) -> u32 {
        let p = *self.p(v);
        let mut t = start;
        let mut steps = 0usize;
        'walk: loop {
            steps += 1;
            if steps > 4 * self.tets.len() + 64 {
                // Cannot happen with exact predicates on a valid triangulation; scan as a fallback.
                return self.locate_by_scan(v).unwrap_or(start);
            }
            let tet = self.tets[t as usize];
            let r = (self.rng.next() & 3) as usize;
            for k in 0..4 {
                let i = (r + k) & 3;
                let mut q = tet.map(|w| self.p(w));
                q[i] = &p;
                if orient3d(q[0], q[1], q[2], q[3]) < 0.0 {
                    let u = self.neighbours[t as usize][i];
                    if u == NO_NEIGHBOUR {
                        // Outside the enclosing tetrahedron: cannot happen, all points are inside.
                        return t;
                    }
                    t = u;
                    continue 'walk;
                }
            }
            return t;
        }
    }

    fn locate_by_scan(&self, v: u32) -> Option<u32> {
        let p = self.p(v);
        (0..self.tets.len() as u32).find(|&t| {
            let tet = self.tets[t as usize];
            tet[0] != NO_NEIGHBOUR
                && (0..4).all(|i| {
                    let mut q = tet.map(|w| self.p(w));
                    q[i] = p;
                    orient3d(q[0], q[1], q[2], q[3]) >= 0.0
                })
        })
    }

    /// Whether point `v` is in conflict with tet `t` (strictly inside its perturbed circumsphere).
    fn conflict(&self, t: u32, v: u32) -> bool {
        let tet = self.tets[t as usize];
        let q = tet.map(|w| self.p(w));
        let p = self.p(v);
        let s = insphere(q[0], q[1], q[2], q[3], p);
        if s != 0.0 {
            return s > 0.0;
        }
        // Symbolic perturbation: the point with the largest index is lifted most. Lifting the
        // new point puts it outside; lifting tet vertex j moves the sphere towards the side of
        // the opposite face where vertex j is, so p is inside when it is on that side.
        let mut order = [
            (tet[0], 0usize),
            (tet[1], 1),
            (tet[2], 2),
            (tet[3], 3),
            (v, 4),
        ];
        order.sort_unstable_by_key(|x| std::cmp::Reverse(x.0));
        for (_, j) in order {
            if j == 4 {
                return false;
            }
            let mut r = q;
            r[j] = p;
            let o = orient3d(r[0], r[1], r[2], r[3]);
            if o != 0.0 {
                return o > 0.0;
            }
        }
        false
    }

    /// Inserts point `v` into the triangulation, starting from tet `t` that contains it.
    /// Returns a new tet, or `None` when the point was rejected.
    fn insert(&mut self, t: u32, v: u32) -> Option<u32> {
        // Stamps go up by two: `stamp` marks the cavity, `stamp + 1` the tested non-cavity tets.
        self.stamp = self.stamp.wrapping_add(2);
        if self.stamp >= u32::MAX - 1 {
            self.mark.iter_mut().for_each(|m| *m = 0);
            self.stamp = 2;
        }
        let stamp = self.stamp;
        self.cavity.clear();
        self.boundary.clear();
        self.stack.clear();
        self.mark[t as usize] = stamp;
        self.stack.push(t);
        while let Some(c) = self.stack.pop() {
            self.cavity.push(c);
            for i in 0..4 {
                let u = self.neighbours[c as usize][i];
                let is_boundary = if u == NO_NEIGHBOUR {
                    true
                } else if self.mark[u as usize] == stamp {
                    false
                } else if self.mark[u as usize] == stamp + 1 {
                    true
                } else if self.conflict(u, v) {
                    self.mark[u as usize] = stamp;
                    self.stack.push(u);
                    false
                } else {
                    self.mark[u as usize] = stamp + 1;
                    true
                };
                if is_boundary {
                    let mut verts = self.tets[c as usize];
                    verts[i] = v;
                    // The face of u that points back to c, found before anything changes.
                    let back = if u == NO_NEIGHBOUR {
                        4
                    } else {
                        self.neighbours[u as usize]
                            .iter()
                            .position(|&x| x == c)
                            .unwrap_or(4)
                    };
                    self.boundary.push((verts, i, u, back));
                }
            }
        }
        // Safety net: every cone tet must be positively oriented (a star-shaped cavity).
        for (verts, _, _, _) in &self.boundary {
            let q = verts.map(|w| self.p(w));
            if orient3d(q[0], q[1], q[2], q[3]) <= 0.0 {
                return None;
            }
        }
        // Free the cavity, create the cone.
        for &c in &self.cavity {
            self.tets[c as usize] = [NO_NEIGHBOUR; 4];
            self.free.push(c);
        }
        self.created.clear();
        self.pending.clear();
        for k in 0..self.boundary.len() {
            let (verts, i, u, back) = self.boundary[k];
            let nt = match self.free.pop() {
                Some(s) => s,
                None => {
                    self.tets.push([NO_NEIGHBOUR; 4]);
                    self.neighbours.push([NO_NEIGHBOUR; 4]);
                    self.mark.push(0);
                    (self.tets.len() - 1) as u32
                }
            };
            self.tets[nt as usize] = verts;
            self.neighbours[nt as usize] = [NO_NEIGHBOUR; 4];
            self.neighbours[nt as usize][i] = u;
            self.mark[nt as usize] = 0;
            if u != NO_NEIGHBOUR && back < 4 {
                self.neighbours[u as usize][back] = nt;
            }
            for j in 0..4 {
                if j == i {
                    continue;
                }
                // The face opposite vertex j holds v and the two face vertices other than j.
                let mut e = [0u32; 2];
                let mut m = 0;
                for (l, &w) in verts.iter().enumerate() {
                    if l != i && l != j {
                        e[m] = w;
                        m += 1;
                    }
                }
                let key = (e[0].min(e[1]), e[0].max(e[1]));
                self.pending.push((key, nt, j as u32));
            }
            self.created.push(nt);
        }
        // Glue the cone: each internal face (an edge of the cavity boundary coned to v) is
        // shared by exactly two cone tets. Sorting pairs them in O(m log m); a linear search per
        // face was O(m^2) in the cone size m and dominated large cavities.
        self.pending.sort_unstable();
        for pair in self.pending.chunks_exact(2) {
            let ((ka, ta, ja), (kb, tb, jb)) = (pair[0], pair[1]);
            debug_assert_eq!(ka, kb);
            self.neighbours[ta as usize][ja as usize] = tb;
            self.neighbours[tb as usize][jb as usize] = ta;
        }
        debug_assert!(self.pending.len().is_multiple_of(2));
        self.created.last().copied()
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
}
