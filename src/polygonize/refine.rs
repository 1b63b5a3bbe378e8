//! Step 7 of the `polygonize` stage ([`super::PolygonizeParams::refine`], `--refine`): the
//! edges whose chord strays far from the curved surface are split at their midpoint, projected
//! onto the zero set.
//!
//! Input: the mesh of step 4 (its vertices on the zero set, with their normals) and the
//! largest sagitta kept, in input units. Output: [`Refined`], the new vertices (appended after
//! the old ones, in the order of their edges) with the edge each splits, and the new triangles.
//!
//! Which edges: an edge of length h whose end normals differ by |n_a − n_b| (about the angle θ
//! they make) spans an arc of the surface whose sagitta is h·θ/8 (exact for a circular arc); the
//! edges where that exceeds the threshold are split. A triangle with two split edges has its
//! third split too (repeated until none has two), so every triangle is either kept, split in two
//! through its one split edge, or split in four through the midpoints of its three: the refined
//! mesh is conforming, every edge is split from both sides or from neither, so it stays a
//! 2-manifold with the same boundary, topology and winding.
//!
//! Where: each new vertex starts at its edge's midpoint and moves to the zero set by the Newton
//! steps of step 4 (at most half the edge length each); an edge on the mesh's boundary (the
//! region's faces), or one whose steps do not converge, keeps its midpoint.
//!
//! Why: marching tetrahedra at depth 7 puts vertices on the zero set, but its flat facets lie
//! off the curved surface between them by up to the sagitta of their edges; where the points are
//! denser than the cells, they sample those facets' interiors, and a depth-8 mesh costs 4× the
//! octree and extraction work (docs/defaults.md, "Refined edges"). Splitting the curved edges
//! once halves their sagitta's length scale for one projection per new vertex.
//!
//! Step 5 then treats a new vertex like any other: its first positions are its chord position
//! and its projection; its last fallback is the midpoint of its edge's two ends wherever they
//! are, where the pieces of a split triangle lie in its plane, so the refined mesh with every
//! vertex at its last fallback is the unrefined one, embedded as that one is.

use rayon::prelude::*;

use super::extract::{newton, PlacedVertex};
use super::ImplicitFunction;
use crate::mesh::{EdgeMap, TriangleMesh};
use crate::vec3::{norm, sub};

/// The refinement of a mesh (see the module docs).
pub(crate) struct Refined {
    /// The new vertices, in the order of their edges (sorted by their ends' indices).
    pub vertices: Vec<PlacedVertex>,
    /// The ends of the edge each new vertex splits.
    pub parents: Vec<[u32; 2]>,
    /// The refined triangles: the old vertices keep their indices, the new ones follow.
    pub triangles: Vec<[u32; 3]>,
}

/// Splits the edges of `mesh` (vertices on the zero set of `function`) whose sagitta estimate
/// h·|n_a − n_b|/8 exceeds `threshold` (see the module docs); new vertices are projected to
/// |f|/|∇f| ≤ `tolerance`.
pub(crate) fn refine<F: ImplicitFunction + ?Sized>(
    function: &F,
    mesh: &TriangleMesh,
    threshold: f64,
    tolerance: f64,
) -> Refined {
    let map = EdgeMap::new(&mesh.triangles);
    // An edge on the boundary has one triangle.
    let boundary = |e: usize| map.triangles_of(e as u32).len() == 1;
    let mut split: Vec<bool> = (0..map.len() as u32)
        .into_par_iter()
        .map(|e| {
            let [a, b] = map.ends(e).map(|v| v as usize);
            let length = norm(sub(mesh.positions[a], mesh.positions[b]));
            let turn = norm(sub(mesh.normals[a], mesh.normals[b]));
            length * turn / 8.0 > threshold
        })
        .collect();
    // A triangle with two split edges gets its third: pieces of two and four only.
    loop {
        let mut changed = false;
        for t in 0..mesh.triangles.len() {
            let e = map.of_triangle(t).map(|e| e as usize);
            if e.iter().filter(|&&i| split[i]).count() == 2 {
                e.iter().for_each(|&i| split[i] = true);
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let chosen: Vec<usize> = (0..map.len()).filter(|&i| split[i]).collect();
    let vertices: Vec<PlacedVertex> = chosen
        .par_iter()
        .map(|&i| {
            let [a, b] = map.ends(i as u32).map(|v| v as usize);
            let (pa, pb) = (mesh.positions[a], mesh.positions[b]);
            let mid = midpoint(pa, pb);
            if !boundary(i) {
                let (vertex, spent) = newton(function, mid, 0.5 * norm(sub(pa, pb)), tolerance);
                if let Some(vertex) = vertex {
                    return PlacedVertex {
                        evaluations: spent,
                        ..vertex
                    };
                }
                let fallback = midpoint_vertex(function, mesh, [a, b], mid);
                return PlacedVertex {
                    evaluations: fallback.evaluations + spent,
                    ..fallback
                };
            }
            midpoint_vertex(function, mesh, [a, b], mid)
        })
        .collect();
    let first = mesh.positions.len() as u32;
    let mut new_index = vec![u32::MAX; map.len()];
    for (k, &i) in chosen.iter().enumerate() {
        new_index[i] = first + k as u32;
    }
    let mut triangles = Vec::with_capacity(mesh.triangles.len() + 3 * chosen.len());
    for (i, t) in mesh.triangles.iter().enumerate() {
        // m[k] splits the edge from t[k] to t[k + 1].
        let m = map.of_triangle(i).map(|e| new_index[e as usize]);
        match m.iter().filter(|&&v| v != u32::MAX).count() {
            0 => triangles.push(*t),
            3 => {
                let [a, b, c] = *t;
                let [ab, bc, ca] = m;
                triangles.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
            }
            _ => {
                // One split edge (the closure above leaves no triangle with two).
                let k = (0..3).find(|&k| m[k] != u32::MAX).unwrap_or(0);
                let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
                triangles.extend([[a, m[k], c], [m[k], b, c]]);
            }
        }
    }
    Refined {
        vertices,
        parents: chosen.iter().map(|&i| map.ends(i as u32)).collect(),
        triangles,
    }
}

/// A new vertex left at its edge's `midpoint` (ends `a`, `b`): its residual measured there, its
/// normal the mean of its ends'.
fn midpoint_vertex<F: ImplicitFunction + ?Sized>(
    function: &F,
    mesh: &TriangleMesh,
    [a, b]: [usize; 2],
    at: [f64; 3],
) -> PlacedVertex {
    let (value, gradient) = function.value_gradient(at);
    let sum = [0, 1, 2].map(|k| mesh.normals[a][k] + mesh.normals[b][k]);
    let length = norm(sum);
    PlacedVertex {
        position: at,
        normal: if length > 0.0 {
            sum.map(|s| s / length)
        } else {
            mesh.normals[a]
        },
        residual: super::extract::residual(value, norm(gradient)),
        evaluations: 1,
    }
}

/// The midpoint of `a` and `b`.
pub(crate) fn midpoint(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|k| 0.5 * (a[k] + b[k]))
}

#[cfg(test)]
mod tests {
    use crate::mesh::{check, TriangleMesh};
    use crate::polygonize::{polygonize, PolygonizeError, PolygonizeParams, Polygonized};
    use crate::testing::shapes;
    use crate::vec3::{dot, norm};
    use crate::Aabb;

    /// `shape` meshed in the cube [−half, half]³ with `params`.
    fn mesh_of(
        shape: &crate::poly::ImplicitPolynomial,
        half: f64,
        params: &PolygonizeParams,
    ) -> Result<Polygonized, PolygonizeError> {
        let region = Aabb {
            min: [-half; 3],
            max: [half; 3],
        };
        polygonize(shape, &region, params)
    }

    /// The unit sphere meshed at depth 4 in [−1.5, 1.5]³, with step 7's share `refine`.
    fn sphere_at_depth_4(refine: Option<f64>) -> Polygonized {
        let params = PolygonizeParams {
            depth: 4,
            refine,
            ..Default::default()
        };
        mesh_of(&shapes::sphere(1.0), 1.5, &params).unwrap()
    }

    /// Mean |r − 1| of the unit sphere's mesh over its area (the facets' distance to it).
    fn mean_radius_error(mesh: &TriangleMesh) -> f64 {
        crate::measure::area_mean(mesh, |p| (dot(p, p).sqrt() - 1.0).abs())
    }

    /// The unit sphere at depth 4: with every curved edge split (a sagitta share of 0.01 of a
    /// cell; the sphere's edges turn by far more), the mesh keeps its topology (watertight,
    /// χ = 2, one component, no crossing), every new vertex lies on the sphere to 1e-7 of the
    /// region's diagonal, and the facets' mean distance to the sphere falls to at most 0.4×
    /// (halved edges: a quarter of the sagitta, plus the sagitta's spread).
    #[test]
    fn split_edges_follow_the_sphere() {
        let before = sphere_at_depth_4(None);
        let after = sphere_at_depth_4(Some(0.01));
        assert_eq!(before.refined_vertices, 0);
        let old = before.mesh.positions.len();
        assert_eq!(after.mesh.positions.len(), old + after.refined_vertices);
        assert!(after.refined_vertices > old, "{}", after.refined_vertices);
        let report = check(&after.mesh);
        assert!(report.watertight && report.orientation_consistent);
        assert_eq!(
            (report.euler_characteristic, report.components),
            (2, 1),
            "{report:?}"
        );
        assert_eq!(report.self_intersecting_faces, 0);
        assert!(after.embedded);
        assert_eq!(&after.mesh.positions[..old], &before.mesh.positions[..]);
        let diagonal = 3.0 * 3f64.sqrt();
        for p in &after.mesh.positions[old..] {
            assert!((norm(*p) - 1.0).abs() <= 1e-7 * diagonal, "{p:?}");
        }
        let (e0, e1) = (
            mean_radius_error(&before.mesh),
            mean_radius_error(&after.mesh),
        );
        assert!(e1 <= 0.4 * e0, "before {e0:.3e}, after {e1:.3e}");
    }

    /// A share so large that no edge's sagitta reaches it splits nothing: the mesh is the
    /// unrefined one, byte for byte.
    #[test]
    fn straight_enough_edges_stay() {
        let before = sphere_at_depth_4(None);
        let after = sphere_at_depth_4(Some(100.0));
        assert_eq!(after.refined_vertices, 0);
        assert_eq!(after.mesh, before.mesh);
    }

    /// With the chords' whole move and a thin torus (minor radius 1.6 cells at depth 5), the
    /// refined mesh keeps the torus's topology (χ = 0) without a crossing, and the result is
    /// the same for one thread and two.
    #[test]
    fn refined_chords_keep_a_thin_torus_embedded_and_deterministic() {
        let params = PolygonizeParams {
            depth: 5,
            fit_chords: true,
            chord_share: 1.0,
            refine: Some(0.01),
            ..Default::default()
        };
        let torus = shapes::torus(1.0, 0.15);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| mesh_of(&torus, 1.5, &params).unwrap())
        };
        let (one, two) = (run(1), run(2));
        assert_eq!(one.mesh, two.mesh);
        assert!(one.refined_vertices > 0);
        let report = check(&one.mesh);
        assert!(report.watertight, "{report:?}");
        assert_eq!(report.euler_characteristic, 0);
        assert_eq!(report.self_intersecting_faces, 0);
        assert!(one.embedded);
    }

    /// Data points 2% off the unit sphere raise the sagitta an edge must exceed to their
    /// scatter (|f|/|∇f| ≈ 0.0198 there), twice the sagitta of an edge of 1.5 cells at depth 4
    /// (0.28² / 8 ≈ 0.0099): nothing is split; on the sphere itself (scatter 0) the share
    /// alone decides, as without data.
    #[test]
    fn the_data_scatter_is_the_least_sagitta_split() {
        let params = PolygonizeParams {
            depth: 4,
            refine: Some(0.01),
            ..Default::default()
        };
        let region = Aabb {
            min: [-1.5; 3],
            max: [1.5; 3],
        };
        let sphere = shapes::sphere(1.0);
        let on: Vec<[f64; 3]> = (0..2000)
            .map(|i| {
                // A Fibonacci spiral on the sphere.
                let z = 1.0 - (2 * i + 1) as f64 / 2000.0;
                let r = (1.0 - z * z).sqrt();
                let a = i as f64 * 2.399_963_229_728_653;
                [r * a.cos(), r * a.sin(), z]
            })
            .collect();
        let off: Vec<[f64; 3]> = on.iter().map(|p| p.map(|c| 1.02 * c)).collect();
        let with = |data: &[[f64; 3]]| {
            crate::polygonize::polygonize_with_data(&sphere, &region, data, None, &params).unwrap()
        };
        let without = sphere_at_depth_4(Some(0.01));
        assert!(without.refined_vertices > 0);
        assert_eq!(with(&on).refined_vertices, without.refined_vertices);
        assert_eq!(with(&off).refined_vertices, 0);
    }

    /// A share that is not finite and positive is refused with an error that names it.
    #[test]
    fn a_share_out_of_range_is_an_error() {
        for share in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let params = PolygonizeParams {
                depth: 3,
                refine: Some(share),
                ..Default::default()
            };
            let e = mesh_of(&shapes::sphere(1.0), 1.5, &params).unwrap_err();
            assert!(matches!(e, PolygonizeError::InvalidRefine(_)), "{e}");
            assert!(e.to_string().contains("refinement"), "{e}");
        }
    }
}
