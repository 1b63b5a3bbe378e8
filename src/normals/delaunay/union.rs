//! Faces among a first batch of points, within one triangulation and across several: each
//! triangulation's faces among its first points with the apexes of their two tetrahedra
//! ([`FaceApexes`]), and the faces of the Delaunay tetrahedralization of the union of several
//! point sets that share those first points, decided from those lists alone
//! ([`faces_among_union`], the crust's second triangulation).
//!
//! Input: triangulations ([`Delaunay`]) that share their first points. Output: faces as caller
//! indices, sorted and wound as one triangulation of the union would give them.

use rayon::prelude::*;

#[cfg(test)]
use super::insert::Tet;
use super::insert::{Delaunay, ENCLOSING_KEY};
use super::perturbation::inside;
use super::{face_vertices, NO_NEIGHBOUR};

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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::normals::delaunay::order::Rng;
    use crate::normals::delaunay::Keep;

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
