//! Bowyer–Watson insertion: the triangulation's state ([`Delaunay`]: packed tetrahedron records,
//! generation stamps and reused buffers), point location by a visibility walk, the cavity search
//! and the cone that replaces the cavity.
//!
//! Input: a batch of points, inserted in BRIO order into an enclosing tetrahedron or an existing
//! triangulation. Output: the triangulation, extracted as a
//! [`Tetrahedralization`](super::Tetrahedralization) without the enclosing tetrahedron's vertices.

use super::order::{brio_order, Rng};
use super::perturbation::perturbed_inside;
use super::{Tetrahedralization, NO_NEIGHBOUR};
use crate::normals::NormalsError;
use crate::numerics::predicates::{insphere, orient3d};

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

/// A tetrahedron record: vertices (internal ids) and neighbours. `n[i]` is the tetrahedron
/// across the face opposite `v[i]` shifted left by two, with the index of the shared face in
/// that neighbour in the low two bits, or [`NO_NEIGHBOUR`]. A free slot has
/// `v[0] == NO_NEIGHBOUR`. Vertices and neighbours share one 32-byte record, so visiting a
/// tetrahedron touches one cache line.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(32))]
pub(super) struct Tet {
    pub(super) v: [u32; 4],
    pub(super) n: [u32; 4],
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
    pub(super) pts: Vec<[f64; 3]>,
    pub(super) orig: Vec<u32>,
    pub(super) tets: Vec<Tet>,
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
pub(super) const ENCLOSING_KEY: u32 = u32::MAX - 4;

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
                if u != NO_NEIGHBOUR
                    && let Some(nt) = self.tets.get((u >> 2) as usize)
                {
                    prefetch(self.pts.get(nt.v[(u & 3) as usize] as usize));
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
