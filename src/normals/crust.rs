//! The crust triangulation and crust normals of the `normals` stage (paper sections 5.1, 5.2).
//!
//! Input: distinct points sampled from a surface. Output: [`Crust`] (the crust triangles, with
//! arbitrary winding, as indices into the points) and, from [`crust_normals`], one unit outward
//! normal per point.
//!
//! # Algorithm (Amenta, Bern & Kamvysselis, "A new Voronoi-based surface reconstruction
//! algorithm", SIGGRAPH 1998)
//!
//! ```text
//! Delaunay(P)            its tetrahedra's circumcentres are the Voronoi vertices
//! pole p⁺ of sample s    the farthest Voronoi vertex of s's cell; on the convex hull the cell is
//!                        unbounded and the pole vector is the outward hull normal instead
//! pole p⁻ of sample s    the farthest Voronoi vertex v of s's cell with (v − s)·(p⁺ − s) < 0
//! Delaunay(P ∪ poles)    the poles approximate the medial axis, so the Delaunay faces
//!                        among samples only are those near the surface
//! crust                  the faces of Delaunay(P ∪ poles) whose three vertices are samples
//! ```
//!
//! Delaunay(P ∪ poles) is never built whole. The poles (each position once) are cut into two
//! slabs along the longest axis, each slab is inserted into its own copy of Delaunay(P) in
//! parallel, and the faces among samples of the union are decided from the two copies' faces
//! and the apexes of their tetrahedra ([`faces_among_union`]: a face's Voronoi edge loses a
//! prefix or a suffix to each pole, so the union's remaining edge is the intersection of the
//! parts'). The result is the list that inserting every pole into one triangulation gives
//! (the triangulation is unique under the symbolic perturbation, so neither the order nor the
//! cut matters); a unit test in `delaunay.rs` checks it on a degenerate lattice. The
//! k-nearest-neighbour plane fits run beside all this on the other core.
//!
//! Most poles cannot change the crust, and those are not inserted (on the bunny, 45k of 70k).
//! Let f be a face of Delaunay(P) and [c₁, c₂] its dual Voronoi edge (the centres of the empty
//! balls through f's vertices; the segment is finite because of the enclosing vertices). A pole
//! v removes the part of [c₁, c₂] where the ball centred there contains v; that part is the
//! segment's intersection with a half-space, so it contains c₁ or c₂ whenever it is not empty.
//! f is a crust face exactly when the poles together do not remove all of [c₁, c₂]. While the
//! poles are inserted one by one, a face that is still there has as its current Voronoi edge the
//! part not yet removed, whose end points are the circumcentres of its two current
//! tetrahedra; so a new pole that removes anything more of it conflicts with (has in its
//! Bowyer–Watson cavity) a tetrahedron with f as a face. A pole whose cavity holds no
//! tetrahedron with three sample vertices therefore removes nothing that the earlier poles did
//! not, and leaving it out changes neither the crust nor, for any crust face, the remaining part
//! of its Voronoi edge, hence nor its two tetrahedra (by induction over the insertion order).
//! The symbolic perturbation makes the configuration generic, so the argument holds as stated.
//!
//! Poles farther than twice the bounding-box diagonal from the box centre are left out of the
//! second tetrahedralization: they lie outside the convex hull of the samples, where they only
//! remove hull faces that the crust may keep anyway, and they would spoil the spatial sort.
//!
//! The raw crust is not a manifold: four nearly co-circular samples make a flat "sliver"
//! tetrahedron in both tetrahedralizations, and all four of its faces are crust triangles. ABK
//! remove them with a normal filter and a manifold extraction; for normals that is unnecessary,
//! since all those faces are nearly tangent to the surface.
//!
//! Normals (paper section 5.2): around each sample, a planar fan of crust triangles (its link is
//! one cycle, or one path at a boundary) is walked in order so that every triangle is wound the
//! same way (the right-hand rule of the paper's figure 3a); a non-planar fan (slivers) has its
//! triangle normals aligned with the pole vector instead. The aligned normals are summed with the
//! weights of Max (1999), exact for samples of a sphere, and normalised. A fan is ill-structured
//! when it is empty, when a triangle is more than `max_fan_angle_deg` from the result, when the
//! result is more than that from the pole vector's line, or when the data is noisy at the scale
//! of the fan (the adaptive plane fit of [`crate::normals::pca`] had to grow its neighbourhood);
//! such points get that plane fit. Signs are then fixed by [`crate::normals::orient`].

use rayon::prelude::*;

use crate::cloud::Aabb;
use crate::mesh::VertexTriangles;
use crate::normals::delaunay::{
    check_spans_3d, face_vertices, faces_among_union, Delaunay, Keep, KeyedPoints, NO_NEIGHBOUR,
};
use crate::normals::vec3::{add, cross, dot, norm, normalized, scale, sub, triangle_normal};
use crate::normals::{orient, pca, NormalsError, NormalsParams};

/// The crust of a point set.
#[derive(Clone, Debug, Default)]
pub struct Crust {
    /// Crust triangles as indices into the points (winding arbitrary).
    pub triangles: Vec<[u32; 3]>,
    /// For each point: the unit pole vector (towards the first pole, or the outward hull normal
    /// on the convex hull), or `None` when the point has no Voronoi cell (skipped as a duplicate).
    pub pole_vectors: Vec<Option<[f64; 3]>>,
    /// For each point: whether it is a vertex of the convex hull.
    pub on_hull: Vec<bool>,
    /// Number of poles (within two box diagonals) offered to the second tetrahedralization.
    pub n_poles: usize,
    /// Number of those left out because they could not change the crust (summed over the
    /// slabs, each of which decides it for its own poles).
    pub n_poles_redundant: usize,
}

/// The indices of `poles` in two halves along the longest axis of their bounding box, cut at
/// their median coordinate: spatially compact sets, so that each set's insertions stay local
/// (three or four slabs cost more in all than they gained, on the bunny: each slab's poles
/// see the unrefined space beyond its borders). A pole equal to another (five co-spherical samples
/// give two tetrahedra the same circumcentre) is left out but for the one with the smallest
/// index, so the vertex that stands for a position never depends on the insertion order.
/// Deterministic; the crust does not depend on the cut.
fn pole_slabs(poles: &[[f64; 3]]) -> [Vec<u32>; 2] {
    let Some(bbox) = Aabb::from_points(poles) else {
        return [Vec::new(), Vec::new()];
    };
    let extent = [0, 1, 2].map(|a| bbox.max[a] - bbox.min[a]);
    let axis = (0..3).fold(0, |best, a| if extent[a] > extent[best] { a } else { best });
    let axes = [axis, (axis + 1) % 3, (axis + 2) % 3];
    let mut ids: Vec<u32> = (0..poles.len() as u32).collect();
    ids.par_sort_unstable_by(|&i, &j| {
        let (p, q) = (&poles[i as usize], &poles[j as usize]);
        axes.iter()
            .fold(std::cmp::Ordering::Equal, |o, &a| {
                o.then(p[a].total_cmp(&q[a]))
            })
            .then(i.cmp(&j))
    });
    ids.dedup_by(|later, kept| poles[*later as usize] == poles[*kept as usize]);
    let second = ids.split_off(ids.len() / 2);
    [ids, second]
}

/// Circumcentre of a tetrahedron (not finite for a flat one).
fn circumcentre(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3]) -> [f64; 3] {
    let ba = sub(b, a);
    let ca = sub(c, a);
    let da = sub(d, a);
    let lb = dot(&ba, &ba);
    let lc = dot(&ca, &ca);
    let ld = dot(&da, &da);
    let cd = cross(&ca, &da);
    let db = cross(&da, &ba);
    let bc = cross(&ba, &ca);
    let det = dot(&ba, &cd);
    let s = 0.5 / det;
    let off = scale(
        &add(&add(&scale(&cd, lb), &scale(&db, lc)), &scale(&bc, ld)),
        s,
    );
    add(a, &off)
}

/// Computes the crust of distinct `points`.
///
/// # Errors
/// Fewer than 5 distinct points, a non-finite coordinate, or all points on a line or a plane.
///
/// ```
/// use stablesurf::testing::crust;
/// // The 6 vertices of an octahedron: its crust is its 8 faces.
/// let pts = [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]];
/// let c = crust(&pts).unwrap();
/// assert_eq!(c.triangles.len(), 8);
/// ```
pub fn crust(points: &[[f64; 3]]) -> Result<Crust, NormalsError> {
    let mut times = Vec::new();
    let crust = crust_timed(points, &mut times);
    log_phases("crust", &times);
    crust
}

/// Logs the wall time of each phase at the `debug` level, in phase order (a profiling aid:
/// `-vv` on the command line, or a logger of the benches).
fn log_phases(what: &str, times: &[(&'static str, std::time::Duration)]) {
    for (phase, time) in times {
        log::debug!("{what} phase {phase}: {:.1} ms", time.as_secs_f64() * 1e3);
    }
}

/// Wall-clock laps of the phases, for [`crust_timed`] and [`crust_normals_timed`].
struct Laps(std::time::Instant);

impl Laps {
    fn lap(&mut self, name: &'static str, times: &mut Vec<(&'static str, std::time::Duration)>) {
        let now = std::time::Instant::now();
        times.push((name, now - self.0));
        self.0 = now;
    }
}

/// [`crust`], appending the wall time of its phases to `times`.
fn crust_timed(
    points: &[[f64; 3]],
    times: &mut Vec<(&'static str, std::time::Duration)>,
) -> Result<Crust, NormalsError> {
    let n = points.len();
    check_spans_3d(points)?;
    let mut laps = Laps(std::time::Instant::now());
    // The poles are inserted into copies of the Delaunay tetrahedralization of the samples, so
    // the samples are inserted once. The enclosing tetrahedron (1000 times the samples' size)
    // contains the poles kept (within two box diagonals).
    let mut delaunay = Delaunay::enclosing(points)?;
    let mut representative: Vec<u32> = (0..n as u32).collect();
    delaunay.insert(
        points,
        (0..n as u32).collect(),
        0,
        &mut representative,
        Keep::All,
        times,
    );
    laps.lap("delaunay: insertion total", times);
    let dt = delaunay.extract(representative);
    laps.lap("delaunay: compaction", times);
    let centres: Vec<[f64; 3]> = dt
        .tets
        .par_iter()
        .map(|t| {
            circumcentre(
                &points[t[0] as usize],
                &points[t[1] as usize],
                &points[t[2] as usize],
                &points[t[3] as usize],
            )
        })
        .collect();

    // Convex hull: outward normals of hull faces, summed per vertex (area-weighted).
    let mut hull_normal = vec![[0.0; 3]; n];
    let mut on_hull = vec![false; n];
    for (t, i) in dt.hull_faces() {
        let f = face_vertices(dt.tets[t], i);
        let nrm = triangle_normal(
            &points[f[0] as usize],
            &points[f[1] as usize],
            &points[f[2] as usize],
        );
        for v in f {
            on_hull[v as usize] = true;
            hull_normal[v as usize] = add(&hull_normal[v as usize], &nrm);
        }
    }

    // First pole: the farthest Voronoi vertex (circumcentre of an incident tet).
    let mut first: Vec<(f64, u32)> = vec![(-1.0, NO_NEIGHBOUR); n];
    for (t, tet) in dt.tets.iter().enumerate() {
        let c = centres[t];
        if !c.iter().all(|x| x.is_finite()) {
            continue;
        }
        for &v in tet {
            let d = norm(&sub(&c, &points[v as usize]));
            if d > first[v as usize].0 {
                first[v as usize] = (d, t as u32);
            }
        }
    }
    let pole_vectors: Vec<Option<[f64; 3]>> = (0..n)
        .map(|v| {
            if on_hull[v] {
                normalized(&hull_normal[v])
            } else if first[v].1 != NO_NEIGHBOUR {
                normalized(&sub(&centres[first[v].1 as usize], &points[v]))
            } else {
                None
            }
        })
        .collect();
    // Second pole: the farthest Voronoi vertex on the other side.
    let mut second: Vec<(f64, u32)> = vec![(-1.0, NO_NEIGHBOUR); n];
    for (t, tet) in dt.tets.iter().enumerate() {
        let c = centres[t];
        if !c.iter().all(|x| x.is_finite()) {
            continue;
        }
        for &v in tet {
            let Some(pv) = pole_vectors[v as usize] else {
                continue;
            };
            let r = sub(&c, &points[v as usize]);
            if dot(&r, &pv) < 0.0 {
                let d = norm(&r);
                if d > second[v as usize].0 {
                    second[v as usize] = (d, t as u32);
                }
            }
        }
    }

    // The poles (each Voronoi vertex once), without the far ones.
    let bbox = Aabb::from_points(points).ok_or(NormalsError::TooFewPoints {
        n_points: 0,
        min: 5,
    })?;
    let centre = bbox.center();
    let limit = 2.0 * bbox.diagonal();
    let mut is_pole = vec![false; dt.tets.len()];
    for v in 0..n {
        if !on_hull[v] && first[v].1 != NO_NEIGHBOUR {
            is_pole[first[v].1 as usize] = true;
        }
        if second[v].1 != NO_NEIGHBOUR {
            is_pole[second[v].1 as usize] = true;
        }
    }
    let poles: Vec<[f64; 3]> = is_pole
        .iter()
        .zip(&centres)
        .filter(|&(&p, c)| p && norm(&sub(c, &centre)) <= limit)
        .map(|(_, c)| *c)
        .collect();
    let n_poles = poles.len();
    laps.lap("poles", times);
    // The poles in two slabs along the longest axis of their box, each inserted into its own
    // copy of Delaunay(P), in parallel; the crust faces of the union are then decided from the
    // copies' faces alone (`faces_among_union`, which says why that is exact).
    let parts: Vec<_> = pole_slabs(&poles)
        .into_par_iter()
        .map(|ids| {
            let mut copy = delaunay.clone();
            let mut part_times = Vec::new();
            let mut representative: Vec<u32> = (0..(n + n_poles) as u32).collect();
            copy.insert(
                &poles,
                ids,
                n as u32,
                &mut representative,
                Keep::IfCavityHasFaceBelow(n as u32),
                &mut part_times,
            );
            let faces = copy.face_apexes(n as u32);
            (faces, copy.n_redundant, part_times)
        })
        .collect();
    let keyed = KeyedPoints {
        first: points,
        extra: &poles,
        enclosing: delaunay.enclosing_points(),
    };
    drop(delaunay);
    let mut n_poles_redundant = 0;
    let mut lists = Vec::with_capacity(parts.len());
    for (faces, redundant, part_times) in parts {
        n_poles_redundant += redundant;
        times.extend(part_times);
        lists.push(faces);
    }
    laps.lap("(second delaunay)", times);
    let triangles = faces_among_union(&lists, &keyed);
    laps.lap("face extraction", times);
    Ok(Crust {
        triangles,
        pole_vectors,
        on_hull,
        n_poles,
        n_poles_redundant,
    })
}

/// Normal of the fan of crust triangles `tris` around sample `p`, or `None` when the fan is
/// ill-structured.
///
/// A planar fan (link = one cycle, or one path at a boundary) is walked in order, which winds
/// every triangle the same way (the right-hand rule). The raw crust also holds all four faces of
/// the flat "sliver" tetrahedra that four nearly co-circular samples make; such a fan is not
/// planar but its triangles are all nearly tangent, so they are aligned with the pole vector
/// instead. Each triangle (p, a, b) contributes (a − p) × (b − p) / (|a − p|² |b − p|²), the
/// weights of Max (1999, "Weights for computing vertex normals from facet normals"), exact for
/// samples of a sphere. The fan is rejected when a triangle's aligned normal is more than the
/// angle whose cosine is `cos_max` away from the result.
fn fan_normal(
    points: &[[f64; 3]],
    p: u32,
    tris: &[[u32; 3]],
    pole: Option<[f64; 3]>,
    cos_max: f64,
) -> Option<[f64; 3]> {
    if tris.is_empty() {
        return None;
    }
    let o = &points[p as usize];
    let weighted = |a: u32, b: u32| {
        let ea = sub(&points[a as usize], o);
        let eb = sub(&points[b as usize], o);
        let w = dot(&ea, &ea) * dot(&eb, &eb);
        if w > 0.0 {
            scale(&cross(&ea, &eb), 1.0 / w)
        } else {
            [0.0; 3]
        }
    };
    // Link edges a → b from each triangle (p, a, b) in its own winding.
    let link: Vec<(u32, u32)> = tris
        .iter()
        .map(|t| {
            let k = t.iter().position(|&v| v == p).unwrap_or(0);
            (t[(k + 1) % 3], t[(k + 2) % 3])
        })
        .collect();
    let normals: Vec<[f64; 3]> = match ordered_ring(&link) {
        Some(ring) => ring.windows(2).map(|w| weighted(w[0], w[1])).collect(),
        None => {
            let reference = match pole {
                Some(v) => v,
                None => link
                    .iter()
                    .map(|&(a, b)| weighted(a, b))
                    .max_by(|x, y| norm(x).total_cmp(&norm(y)))?,
            };
            link.iter()
                .map(|&(a, b)| {
                    let nrm = weighted(a, b);
                    if dot(&nrm, &reference) < 0.0 {
                        scale(&nrm, -1.0)
                    } else {
                        nrm
                    }
                })
                .collect()
        }
    };
    let sum = normals.iter().fold([0.0; 3], |acc, x| add(&acc, x));
    let unit = normalized(&sum)?;
    for nrm in &normals {
        let l = norm(nrm);
        if l > 0.0 && dot(nrm, &unit) < cos_max * l {
            return None;
        }
    }
    if let Some(v) = pole
        && dot(&v, &unit).abs() < cos_max
    {
        return None;
    }
    Some(unit)
}

/// The link vertices in order when the link edges form one cycle (first vertex repeated at the
/// end) or one path; `None` otherwise.
fn ordered_ring(link: &[(u32, u32)]) -> Option<Vec<u32>> {
    let mut verts: Vec<(u32, u32)> = Vec::with_capacity(2 * link.len());
    for &(a, b) in link {
        for v in [a, b] {
            match verts.iter_mut().find(|x| x.0 == v) {
                Some(x) => x.1 += 1,
                None => verts.push((v, 1)),
            }
        }
    }
    if verts.iter().any(|x| x.1 > 2) {
        return None;
    }
    let ends: Vec<u32> = verts.iter().filter(|x| x.1 == 1).map(|x| x.0).collect();
    let is_cycle = ends.is_empty();
    if !(is_cycle && link.len() >= 3 || ends.len() == 2 && link.len() >= 2) {
        return None;
    }
    let mut used = vec![false; link.len()];
    let mut ring = vec![if is_cycle { link[0].0 } else { ends[0] }];
    let mut cur = ring[0];
    for _ in 0..link.len() {
        let next = (0..link.len()).find(|&e| !used[e] && (link[e].0 == cur || link[e].1 == cur))?;
        used[next] = true;
        cur = if link[next].0 == cur {
            link[next].1
        } else {
            link[next].0
        };
        ring.push(cur);
    }
    if is_cycle && cur != ring[0] {
        return None;
    }
    Some(ring)
}

/// Crust normals and what the stage reports about them.
#[derive(Clone, Debug, Default)]
pub struct CrustNormals {
    /// One unit outward normal per point.
    pub normals: Vec<[f64; 3]>,
    /// The crust triangles (indices into the points).
    pub triangles: Vec<[u32; 3]>,
    /// Number of points whose fan was ill-structured (plane fit used).
    pub n_plane_fits: usize,
    /// Messages for the user.
    pub warnings: Vec<String>,
}

/// Unit outward normals of distinct `points` from their crust (paper section 5.2).
///
/// # Errors
/// Fewer than 5 distinct points, a non-finite coordinate, or all points on a line or a plane.
pub fn crust_normals(
    points: &[[f64; 3]],
    params: &NormalsParams,
) -> Result<CrustNormals, NormalsError> {
    let mut times = Vec::new();
    let normals = crust_normals_timed(points, params, &mut times);
    log_phases("crust normals", &times);
    normals
}

/// [`crust_normals`], appending the wall time of its phases to `times`.
fn crust_normals_timed(
    points: &[[f64; 3]],
    params: &NormalsParams,
    times: &mut Vec<(&'static str, std::time::Duration)>,
) -> Result<CrustNormals, NormalsError> {
    let n = points.len();
    // The plane fits do not depend on the crust: they run on the other core while the
    // (sequential) tetrahedralizations run. Each side is deterministic on its own.
    let (c, (knn, fits, noisy, fit_time)) = rayon::join(
        || crust_timed(points, times),
        || {
            let clock = std::time::Instant::now();
            let (index, knn) = pca::knn_with_index(points, params.k_neighbours);
            let (fits, noisy) =
                pca::adaptive_normals(points, index.as_ref(), &knn, params.max_k_neighbours);
            (knn, fits, noisy, clock.elapsed())
        },
    );
    let c = c?;
    times.push(("(knn + plane fits, concurrent)", fit_time));
    let mut laps = Laps(std::time::Instant::now());
    // Incident triangles per point, in compressed rows.
    let around = VertexTriangles::new(n, &c.triangles);
    let incident: Vec<[u32; 3]> = around
        .triangles
        .iter()
        .map(|&t| c.triangles[t as usize])
        .collect();
    let cos_max = params.max_fan_angle_deg.to_radians().cos();
    let fans: Vec<Option<[f64; 3]>> = (0..n)
        .into_par_iter()
        .map(|v| {
            fan_normal(
                points,
                v as u32,
                &incident[around.start[v]..around.start[v + 1]],
                c.pole_vectors[v],
                cos_max,
            )
        })
        .collect();
    laps.lap("fans", times);
    let mut n_plane_fits = 0;
    let mut n_noisy = 0;
    let mut normals: Vec<[f64; 3]> = Vec::with_capacity(n);
    for v in 0..n {
        match fans[v] {
            Some(f) if !noisy[v] => normals.push(f),
            _ => {
                n_plane_fits += 1;
                n_noisy += usize::from(noisy[v]);
                normals.push(fits[v]);
            }
        }
    }
    orient::orient_outward(points, &mut normals, &c.triangles, knn);
    laps.lap("orientation", times);
    let mut warnings = Vec::new();
    if n_plane_fits > 0 {
        warnings.push(format!(
            "crust fan ill-structured at {n_plane_fits} of {n} points ({n_noisy} of them noisy); used pca plane fits there"
        ));
    }
    Ok(CrustNormals {
        normals,
        triangles: c.triangles,
        n_plane_fits,
        warnings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn circumcentre_is_equidistant() {
        let q = [
            [0.1, 0.2, 0.3],
            [1.3, 0.1, -0.2],
            [0.4, 1.7, 0.2],
            [0.3, 0.5, 1.9],
        ];
        let c = circumcentre(&q[0], &q[1], &q[2], &q[3]);
        let r0 = norm(&sub(&c, &q[0]));
        for p in &q[1..] {
            assert!((norm(&sub(&c, p)) - r0).abs() < 1e-12);
        }
    }

    #[test]
    fn sphere_crust_is_a_closed_triangulation() {
        // Points of a Fibonacci sphere are all on the convex hull: the crust is the hull, 2n − 4
        // triangles, every vertex in a planar fan.
        let n = 500;
        let points = crate::normals::test_support::fibonacci_sphere(n);
        let c = crust(&points).unwrap();
        assert_eq!(c.triangles.len(), 2 * n - 4);
        assert!(c.on_hull.iter().all(|&h| h));
        for (p, v) in points.iter().zip(&c.pole_vectors) {
            assert!(
                dot(p, &v.unwrap()) > 0.99,
                "the pole vector of a hull point is the outward normal"
            );
        }
    }
}
