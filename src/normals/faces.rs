//! The `mesh` and `input` normal sources of the `normals` stage.
//!
//! Input: distinct points and either the file's triangles (remapped to the distinct points) or
//! the file's per-point normals. Output: one unit outward normal per point and warnings.
//!
//! `mesh`: the triangles' windings are made consistent by a breadth-first walk over edges shared
//! by exactly two triangles (a neighbour that runs along the shared edge in the same direction
//! is flipped), each connected patch is turned so that its signed volume, measured from its
//! centroid, is positive (outward for a closed surface), and each vertex gets the sum of its
//! triangles' unnormalised right-hand normals (area weighting). Vertices with no usable triangle
//! get a plane fit, signed like the average of their neighbours' normals.
//!
//! `input`: the file's normals are normalised (zero or non-finite ones are replaced by plane
//! fits); if more than 1% of the nearest-neighbour pairs on one sheet (offset within 60° of both
//! tangent planes), checked on a sample of at most 50,000 points, disagree in sign they are
//! re-oriented by [`crate::normals::orient`] and each connected piece is turned outward;
//! otherwise they are kept and only a whole cloud whose normals point in is turned.

use std::borrow::Cow;
use std::collections::VecDeque;

use rayon::prelude::*;

use crate::measure::every_kth;
use crate::normals::vec3::{add, dot, normalized, scale, sub, triangle_normal};
use crate::normals::{orient, pca, NormalsError, NormalsParams};

/// Unit outward normals from the mesh's faces. Returns the normals, the usable triangles wound
/// outward, and warnings.
///
/// # Errors
/// [`NormalsError::NoMeshFaces`] when there is no triangle.
pub(crate) fn mesh_normals(
    points: &[[f64; 3]],
    triangles: &[[u32; 3]],
    params: &NormalsParams,
) -> Result<MeshNormals, NormalsError> {
    let n = points.len();
    let mut tris: Vec<[u32; 3]> = triangles
        .iter()
        .filter(|t| {
            t[0] != t[1] && t[1] != t[2] && t[0] != t[2] && t.iter().all(|&v| (v as usize) < n)
        })
        .copied()
        .collect();
    if tris.is_empty() {
        return Err(NormalsError::NoMeshFaces);
    }
    let mut warnings = Vec::new();
    // Directed edges (a < b key, triangle, whether the triangle runs a → b).
    let mut edges: Vec<(u32, u32, u32, bool)> = Vec::with_capacity(3 * tris.len());
    for (t, tri) in tris.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            edges.push((a.min(b), a.max(b), t as u32, a < b));
        }
    }
    // The entries are distinct (a triangle has no two edges on the same pair of vertices), so
    // any sort gives this one order.
    edges.par_sort_unstable();
    // Manifold adjacency: (neighbour triangle, same direction along the shared edge), at most
    // one per edge of a triangle, in the order of the sorted edges.
    let mut adjacency: Vec<([(u32, bool); 3], u8)> = vec![([(0, false); 3], 0); tris.len()];
    let mut link = |t: u32, u: u32, same: bool| {
        let (list, len) = &mut adjacency[t as usize];
        list[usize::from(*len)] = (u, same);
        *len += 1;
    };
    let mut s = 0;
    while s < edges.len() {
        let mut e = s + 1;
        while e < edges.len() && edges[e].0 == edges[s].0 && edges[e].1 == edges[s].1 {
            e += 1;
        }
        if e - s == 2 {
            let (x, y) = (edges[s], edges[s + 1]);
            let same = x.3 == y.3;
            link(x.2, y.2, same);
            link(y.2, x.2, same);
        }
        s = e;
    }
    let mut flip = vec![false; tris.len()];
    let mut patch = vec![u32::MAX; tris.len()];
    let mut n_patches = 0u32;
    let mut n_conflicts = 0usize;
    let mut queue = VecDeque::new();
    for seed in 0..tris.len() {
        if patch[seed] != u32::MAX {
            continue;
        }
        patch[seed] = n_patches;
        queue.push_back(seed as u32);
        while let Some(t) = queue.pop_front() {
            let (list, len) = &adjacency[t as usize];
            for &(u, same) in &list[..usize::from(*len)] {
                // Consistent neighbours traverse the shared edge in opposite directions.
                let want = flip[t as usize] ^ same;
                if patch[u as usize] == u32::MAX {
                    patch[u as usize] = n_patches;
                    flip[u as usize] = want;
                    queue.push_back(u);
                } else if flip[u as usize] != want {
                    n_conflicts += 1;
                }
            }
        }
        n_patches += 1;
    }
    for (t, tri) in tris.iter_mut().enumerate() {
        if flip[t] {
            tri.swap(1, 2);
        }
    }
    // Outward per patch: positive signed volume measured from the patch's centroid.
    let mut centroid = vec![[0.0; 3]; n_patches as usize];
    let mut count = vec![0.0; n_patches as usize];
    for (t, tri) in tris.iter().enumerate() {
        let p = patch[t] as usize;
        for &v in tri {
            centroid[p] = add(&centroid[p], &points[v as usize]);
            count[p] += 1.0;
        }
    }
    for p in 0..centroid.len() {
        centroid[p] = scale(&centroid[p], 1.0 / count[p]);
    }
    let mut volume = vec![0.0; n_patches as usize];
    for (t, tri) in tris.iter().enumerate() {
        let p = patch[t] as usize;
        let c = centroid[p];
        let [a, b, d] = tri.map(|v| sub(&points[v as usize], &c));
        volume[p] += dot(&a, &crate::normals::vec3::cross(&b, &d));
    }
    for (t, tri) in tris.iter_mut().enumerate() {
        if volume[patch[t] as usize] < 0.0 {
            tri.swap(1, 2);
        }
    }
    if n_conflicts > 0 {
        warnings.push(format!(
            "the mesh is not orientable or has inconsistent faces ({} edge conflicts); some normals may point inward",
            n_conflicts / 2
        ));
    }
    let (normals, more) = wound_normals(points, &tris, params);
    warnings.extend(more);
    Ok(MeshNormals {
        normals,
        triangles: tris,
        warnings,
    })
}

/// Unit normals from triangles whose winding already says which side is out (a range grid's
/// triangles face the scanner): each vertex gets the sum of its triangles' unnormalised
/// right-hand normals (area weighting); vertices with no usable triangle get a plane fit signed
/// like their neighbours. Returns the normals and warnings.
pub(crate) fn wound_normals(
    points: &[[f64; 3]],
    tris: &[[u32; 3]],
    params: &NormalsParams,
) -> (Vec<[f64; 3]>, Vec<String>) {
    let n = points.len();
    let mut warnings = Vec::new();
    let mut sums = vec![[0.0; 3]; n];
    for tri in tris {
        let nrm = triangle_normal(
            &points[tri[0] as usize],
            &points[tri[1] as usize],
            &points[tri[2] as usize],
        );
        for &v in tri {
            sums[v as usize] = add(&sums[v as usize], &nrm);
        }
    }
    let mut normals: Vec<Option<[f64; 3]>> = sums.iter().map(normalized).collect();
    let missing = normals.iter().filter(|x| x.is_none()).count();
    if missing > 0 {
        warnings.push(format!(
            "{missing} points belong to no usable face; used pca plane fits there"
        ));
        fill_missing(points, &mut normals, params);
    }
    (
        normals
            .into_iter()
            .map(|x| x.unwrap_or([0.0, 0.0, 1.0]))
            .collect(),
        warnings,
    )
}

/// What [`mesh_normals`] gives.
pub(crate) struct MeshNormals {
    /// One unit outward normal per point.
    pub normals: Vec<[f64; 3]>,
    /// The usable triangles, wound so that their right-hand normals point outward.
    pub triangles: Vec<[u32; 3]>,
    /// Messages for the user.
    pub warnings: Vec<String>,
}

/// Most surface samples [`surface_samples`] adds, as a multiple of the number of points.
const MAX_SAMPLES_PER_POINT: usize = 4;

/// Points on the faces of a mesh whose triangles are large against its typical edge (the
/// median edge length h), each with its face's outward normal: a triangle gets
/// max(⌊area/a₀⌋, ⌊longest edge/h⌋) − 1 points, a₀ = √3/4·h² the area of an equilateral
/// triangle of side h, placed by the plastic-number (R2) sequence folded into the triangle, at
/// most [`MAX_SAMPLES_PER_POINT`] × the points in all (the counts are scaled down to fit). A
/// model's flat faces are often a few long triangles with no vertex inside (the fandisk's
/// back, the fertility's base): their vertices alone leave those faces as holes in the data,
/// which the fit must then bridge. `triangles` must be wound outward ([`mesh_normals`]).
/// Deterministic: the samples follow the order of the triangles.
pub(crate) fn surface_samples(
    points: &[[f64; 3]],
    triangles: &[[u32; 3]],
) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut lengths: Vec<f64> = triangles
        .iter()
        .flat_map(|t| {
            (0..3).map(move |k| {
                crate::normals::vec3::norm(&sub(
                    &points[t[(k + 1) % 3] as usize],
                    &points[t[k] as usize],
                ))
            })
        })
        .filter(|l| *l > 0.0 && l.is_finite())
        .collect();
    if lengths.is_empty() {
        return (Vec::new(), Vec::new());
    }
    let mid = lengths.len() / 2;
    let (_, &mut h, _) = lengths.select_nth_unstable_by(mid, f64::total_cmp);
    let a0 = 3f64.sqrt() / 4.0 * h * h;
    let counts: Vec<usize> = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| points[v as usize]);
            let area = 0.5 * crate::normals::vec3::norm(&triangle_normal(&a, &b, &c));
            let longest = [sub(&b, &a), sub(&c, &b), sub(&a, &c)]
                .iter()
                .map(crate::normals::vec3::norm)
                .fold(0.0, f64::max);
            let m = (area / a0).floor().max((longest / h).floor());
            if m.is_finite() && m >= 2.0 {
                m as usize - 1
            } else {
                0
            }
        })
        .collect();
    let total: usize = counts.iter().sum();
    let budget = MAX_SAMPLES_PER_POINT * points.len();
    let shrink = if total > budget {
        budget as f64 / total as f64
    } else {
        1.0
    };
    // R2: the additive recurrence of the plastic number g, g³ = g + 1.
    let g = 1.324_717_957_244_746_f64;
    let (a1, a2) = (1.0 / g, 1.0 / (g * g));
    let mut out_points = Vec::new();
    let mut out_normals = Vec::new();
    for (t, &count) in triangles.iter().zip(&counts) {
        let m = (count as f64 * shrink).floor() as usize;
        if m == 0 {
            continue;
        }
        let [a, b, c] = t.map(|v| points[v as usize]);
        let Some(nrm) = normalized(&triangle_normal(&a, &b, &c)) else {
            continue;
        };
        let (ab, ac) = (sub(&b, &a), sub(&c, &a));
        for i in 1..=m {
            let mut u = (0.5 + a1 * i as f64).fract();
            let mut v = (0.5 + a2 * i as f64).fract();
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            out_points.push(add(&a, &add(&scale(&ab, u), &scale(&ac, v))));
            out_normals.push(nrm);
        }
    }
    (out_points, out_normals)
}

/// Replaces `None` normals by plane fits signed like the sum of their neighbours' known normals
/// (or outward by the farthest-points vote when no neighbour has one). Only the points without
/// a normal look up their neighbours (the same k nearest that [`pca::knn`] gives them), so a
/// mesh with a few loose points costs a few queries, not one per point.
fn fill_missing(points: &[[f64; 3]], normals: &mut [Option<[f64; 3]>], params: &NormalsParams) {
    let index = pca::build_index(points);
    let missing: Vec<usize> = (0..points.len())
        .filter(|&i| normals[i].is_none())
        .collect();
    let neighbours: Vec<Vec<u32>> = missing
        .par_iter()
        .map(|&i| match &index {
            Some(index) => pca::nearest(index, points, i, params.k_neighbours),
            None => Vec::new(),
        })
        .collect();
    let mut orphans = Vec::new();
    for (&i, near) in missing.iter().zip(&neighbours) {
        let mut nrm = pca::plane_normal(points, i, near);
        let reference = near
            .iter()
            .filter_map(|&j| normals[j as usize])
            .fold([0.0; 3], |a, x| add(&a, &x));
        let r = dot(&nrm, &reference);
        if r < 0.0 {
            nrm = scale(&nrm, -1.0);
        }
        if r == 0.0 {
            orphans.push(i);
        }
        normals[i] = Some(nrm);
    }
    // No point has a known normal (every one was missing and found no signed neighbour): orient
    // them all outward together.
    if orphans.len() == points.len() {
        let knn = pca::knn(points, params.k_neighbours);
        let mut all: Vec<[f64; 3]> = normals
            .iter()
            .map(|x| x.unwrap_or([0.0, 0.0, 1.0]))
            .collect();
        orient::orient_outward(points, &mut all, &[], knn);
        for (i, a) in all.into_iter().enumerate() {
            normals[i] = Some(a);
        }
    }
}

/// Points whose neighbourhoods the sign check of given normals looks at, at most (every
/// ⌈N / this⌉-th point): the check decides whether to re-orient, and a 1% rate of conflicts
/// shows in the 200,000-odd neighbour pairs of a sample of this size as well as in all points.
const CHECK_SAMPLE: usize = 20_000;

/// Points among which the sign check looks for the sample's neighbours, and whose farthest
/// fiftieth votes on the outward side, at most (every ⌈N / this⌉-th point): a quarter of a
/// million points of a scan cover its sheets as a quarter-million-point scan does, where
/// neighbours on one sheet lie a spacing apart (pairs across a thin part are told apart by their
/// offset along the normals, not by their distance), and more only costs time: on a 3M-point
/// torus the normals stage took 0.22 CPU-s with a million and 0.08 with this (and a sample of
/// 20,000 instead of 50,000).
const CHECK_NEIGHBOURS_FROM: usize = 250_000;

/// Unit outward normals from the file's normals `given` (one per point; their array becomes the
/// result). Returns the normals and warnings.
///
/// Zero or non-finite normals are replaced by plane fits. The signs are checked on a sample of
/// at most [`CHECK_SAMPLE`] points: a sign conflict is a pair of neighbours on one sheet (their
/// offset lies within 60° of both tangent planes) whose normals point to opposite sides.
/// Neighbours across a thin part or a sharp edge also have opposite normals, rightly: their
/// offset runs along the normals (the fandisk's and the duck's vertex normals: 1.7% and 1.8% of
/// all neighbour pairs disagree in sign, and propagating them anew broke correct normals into
/// sheets). The sample's neighbours are searched among at most [`CHECK_NEIGHBOURS_FROM`]
/// points (every k-th). Above 1% of the sampled pairs, or with any replaced normal, the normals are
/// propagated anew over the neighbour graph of all points and each connected piece is turned
/// outward; otherwise they are kept, and only the whole cloud is turned outward if its
/// normals point in, by the vote of the checked points (no graph of all points: a million
/// given normals cost one pass).
pub(crate) fn input_normals(
    points: &[[f64; 3]],
    given: Vec<[f64; 3]>,
    params: &NormalsParams,
) -> (Vec<[f64; 3]>, Vec<String>) {
    let mut warnings = Vec::new();
    let n = points.len();
    // One pass, in place: the unit normals, and the points whose given normal is unusable
    // (their slot holds +z until the plane fits below replace it).
    let mut bad: Vec<usize> = Vec::new();
    let mut normals = given;
    for (i, g) in normals.iter_mut().enumerate() {
        *g = match normalized(g).filter(|_| g.iter().all(|c| c.is_finite())) {
            Some(u) => u,
            None => {
                bad.push(i);
                [0.0, 0.0, 1.0]
            }
        };
    }
    // An index of all points only when plane fits need their neighbours.
    let index = if bad.is_empty() {
        None
    } else {
        pca::build_index(points)
    };
    let neighbours = |i: usize| match &index {
        Some(index) => pca::nearest(index, points, i, params.k_neighbours),
        None => Vec::new(),
    };
    let fits: Vec<[f64; 3]> = bad
        .par_iter()
        .map(|&i| pca::plane_normal(points, i, &neighbours(i)))
        .collect();
    for (&i, f) in bad.iter().zip(fits) {
        normals[i] = f;
    }
    let n_bad = bad.len();
    if n_bad > 0 {
        warnings.push(format!(
            "{n_bad} input normals are zero or not finite; used pca plane fits there"
        ));
    }
    // The check's points: all of them, or every k-th of a large cloud, with their own index
    // (the full one when plane fits needed it anyway).
    let (check_points, check_normals) = if n_bad > 0 {
        (Cow::Borrowed(points), Cow::Borrowed(&normals[..]))
    } else {
        (
            every_kth(points, CHECK_NEIGHBOURS_FROM),
            every_kth(&normals, CHECK_NEIGHBOURS_FROM),
        )
    };
    let check_index = match index {
        Some(index) if check_points.len() == n => Some(index),
        _ => pca::build_index(&check_points),
    };
    let m = check_points.len();
    let step = m.div_ceil(CHECK_SAMPLE).max(1);
    let sample: Vec<u32> = (0..m).step_by(step).map(|i| i as u32).collect();
    // The sample's neighbours in one batch, queried in cell order (the same lists as one query
    // each, found faster); a row is padded with its own point when the check has fewer than
    // k + 1 points, and that point is skipped below.
    let near = check_index
        .as_ref()
        .map(|index| index.nearest_of(&check_points, &sample, params.k_neighbours));
    let (pairs, disagree) = sample
        .par_iter()
        .enumerate()
        .map(|(r, &i)| {
            let i = i as usize;
            let (mut pairs, mut disagree) = (0usize, 0usize);
            let near = near.as_ref().map_or(&[][..], |near| near.row(r));
            for &j in near {
                let j = j as usize;
                if j == i {
                    continue;
                }
                let d = sub(&check_points[j], &check_points[i]);
                let reach = 0.5 * crate::normals::vec3::norm(&d);
                if dot(&check_normals[i], &d).abs() > reach
                    || dot(&check_normals[j], &d).abs() > reach
                {
                    continue;
                }
                pairs += 1;
                if dot(&check_normals[i], &check_normals[j]) < 0.0 {
                    disagree += 1;
                }
            }
            (pairs, disagree)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    drop((check_index, near));
    let flipped = if n_bad > 0 || disagree * 100 > pairs {
        drop((check_points, check_normals));
        if n_bad == 0 {
            warnings.push(format!(
                "{:.1}% of neighbouring input normals on one sheet disagree in sign; re-oriented them",
                100.0 * disagree as f64 / pairs.max(1) as f64
            ));
        }
        let knn = pca::knn(points, params.k_neighbours);
        let label = orient::orient_consistently(points, &mut normals, &[], knn);
        orient::orient_outward_pieces(points, &mut normals, &label)
    } else {
        // One piece, turned outward by the vote of the check's points: every k-th of a large
        // cloud (the farthest fiftieth of a fixed share of the points votes, on their copy),
        // else all of them, in place.
        match check_normals {
            Cow::Owned(mut voters) => {
                let flip = orient::orient_outward_pieces(&check_points, &mut voters, &vec![0; m]);
                if flip > 0 {
                    for g in &mut normals {
                        *g = scale(g, -1.0);
                    }
                }
                flip
            }
            Cow::Borrowed(_) => orient::orient_outward_pieces(points, &mut normals, &vec![0; n]),
        }
    };
    if flipped > 0 {
        warnings.push(format!(
            "input normals pointed inward on {flipped} piece(s); flipped them"
        ));
    }
    (normals, warnings)
}
