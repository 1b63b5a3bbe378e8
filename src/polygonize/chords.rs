//! Step 6 of the `polygonize` stage (`--fit-chords`): the mesh is moved off the zero set by a
//! share of its chord error, towards the position where it straddles the surface instead of
//! lying under it.
//!
//! Input: the mesh of step 4, its vertices projected onto the zero set, with their normals, and
//! the share s of the least-squares move ([`super::PolygonizeParams::chord_share`]). Output:
//! the positions of its vertices, each interior vertex moved along its normal by −(s/4)(L·n),
//! where L is the umbrella vector (the mean of its neighbours minus the vertex), the move
//! capped at [`MAX_MOVE`] × the vertex's mean edge length; vertices on the region's boundary
//! stay.
//!
//! Why: a flat triangle whose corners lie on a surface of curvature κ lies under it, by
//! κ·h²/8 on average for an equilateral triangle of side h (the linear interpolation error of
//! the quadratic κ·r²/2 averaged over the triangle), while the neighbours of a vertex of a
//! regular mesh lie κ·h²/2 under its tangent plane: moving every vertex out by a quarter of
//! the umbrella vector's normal part (s = 1) makes the mean signed distance between the facets
//! and the surface zero, the least-squares counterpart of the interpolating mesh at the same
//! triangles. It puts the vertices outside by about as much as the interpolating facets lie
//! inside, and a surface's vertices are what most checks measure. The stage's default therefore
//! takes a quarter of that move ([`super::CHORD_SHARE`]): the facets' mean signed error falls
//! by a quarter, the distance to the points keeps part of the least-squares gain, and the
//! vertices stay on the surface to within a small share of the diagonal (docs/defaults.md,
//! "Fitted chords"). Points far denser than the mesh sample the facets' interiors, and there
//! detail mode's `run` takes the whole move.
//!
//! Guarantees: the triangles, and so the topology and winding, are unchanged. The positions are
//! a function of the mesh alone. They are the first positions step 5 of the stage tests for
//! crossings: the vertices of a triangle that crosses another go back to the zero set (and on
//! to step 5's own fallbacks), so the fitted mesh is as free of crossings as the interpolating
//! one, for one exact test of the whole mesh.

use crate::mesh::TriangleMesh;
use crate::vec3::{dot, sub};

/// The share of the umbrella vector's normal part a vertex moves by for the least-squares
/// facets (share 1).
const LEAST_SQUARES: f64 = 0.25;

/// The largest move, in mean edge lengths of the vertex (a crease or a corner, where the
/// umbrella vector is long and the quadratic model does not hold).
const MAX_MOVE: f64 = 0.05;

/// The positions of `mesh`'s vertices moved off the zero set by `share` of their least-squares
/// chord move (1: the least-squares facets; see the module docs); vertices on the mesh's
/// boundary, and vertices in no triangle, stay.
pub(crate) fn chord_positions(mesh: &TriangleMesh, share: f64) -> Vec<[f64; 3]> {
    let alpha = share * LEAST_SQUARES;
    let n = mesh.positions.len();
    let mut sum = vec![[0.0f64; 3]; n];
    let mut count = vec![0u32; n];
    let mut length = vec![0.0f64; n];
    // Every edge of every triangle from both ends: on a closed manifold each neighbour is
    // counted twice, which leaves the mean unchanged.
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            for (from, to) in [(a, b), (b, a)] {
                let (p, q) = (mesh.positions[from as usize], mesh.positions[to as usize]);
                let s = &mut sum[from as usize];
                for axis in 0..3 {
                    s[axis] += q[axis];
                }
                count[from as usize] += 1;
                length[from as usize] += dot(sub(q, p), sub(q, p)).sqrt();
            }
        }
    }
    let mut boundary = vec![false; n];
    for [a, b] in crate::mesh::boundary_edges(&mesh.triangles) {
        boundary[a as usize] = true;
        boundary[b as usize] = true;
    }
    let mut positions = mesh.positions.clone();
    for (v, position) in positions.iter_mut().enumerate() {
        if boundary[v] || count[v] == 0 {
            continue;
        }
        let c = f64::from(count[v]);
        let p = *position;
        let umbrella = [0, 1, 2].map(|a| sum[v][a] / c - p[a]);
        let normal = mesh.normals[v];
        let cap = MAX_MOVE * length[v] / c;
        let step = (-alpha * dot(umbrella, normal)).clamp(-cap, cap);
        if step != 0.0 && step.is_finite() {
            *position = [0, 1, 2].map(|a| p[a] + step * normal[a]);
        }
    }
    positions
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poly::ImplicitPolynomial;
    use crate::polygonize::{
        polygonize, PolygonizeError, PolygonizeParams, Polygonized, CHORD_SHARE,
    };
    use crate::Aabb;

    /// The unit sphere (a degree-2 polynomial) meshed in [−1.5, 1.5]³ with `params`.
    fn mesh_sphere(params: &PolygonizeParams) -> Result<Polygonized, PolygonizeError> {
        let mut coefficients = vec![0.0; 10];
        coefficients[0] = -1.0;
        for l in [4, 7, 9] {
            coefficients[l] = 1.0;
        }
        let sphere = ImplicitPolynomial {
            degree: 2,
            coefficients,
            center: [0.0; 3],
            scale: 1.0,
        };
        let region = Aabb {
            min: [-1.5; 3],
            max: [1.5; 3],
        };
        polygonize(&sphere, &region, params)
    }

    fn sphere_mesh(depth: u32, fit_chords: bool) -> Polygonized {
        mesh_sphere(&PolygonizeParams {
            depth,
            fit_chords,
            ..Default::default()
        })
        .unwrap()
    }

    /// Mean signed distance (r − 1) of the unit sphere's mesh over its area.
    fn mean_signed_radius_error(mesh: &TriangleMesh) -> f64 {
        crate::measure::area_mean(mesh, |p| dot(p, p).sqrt() - 1.0)
    }

    /// On the unit sphere the interpolating mesh lies under the surface by about h²/8 (mean
    /// signed error e0 over the area); the least-squares one (share 1) straddles it: its mean
    /// signed error is at least 5× smaller. The stage's default mesh ([`CHORD_SHARE`]) has
    /// (1 − CHORD_SHARE)·e0, to within 5% of |e0|; its triangles are unchanged, every vertex has
    /// moved and the mesh is embedded.
    #[test]
    fn chords_move_the_sphere_mesh_by_their_share() {
        let before = sphere_mesh(5, false);
        let after = sphere_mesh(5, true);
        assert!(before.embedded && after.embedded);
        assert_eq!(after.mesh.triangles, before.mesh.triangles);
        assert_eq!(after.evaluations, before.evaluations);
        let moved = (after.mesh.positions.iter())
            .zip(&before.mesh.positions)
            .filter(|(a, b)| a != b)
            .count();
        assert_eq!(moved, before.mesh.positions.len());
        let least_squares = TriangleMesh {
            positions: chord_positions(&before.mesh, 1.0),
            ..before.mesh.clone()
        };
        let e0 = mean_signed_radius_error(&before.mesh);
        let e1 = mean_signed_radius_error(&least_squares);
        let e = mean_signed_radius_error(&after.mesh);
        assert!(e0 < -1e-4, "interpolating mesh under the sphere: {e0}");
        assert!(e1.abs() < e0.abs() / 5.0, "before {e0}, least squares {e1}");
        assert!(
            (e - e0 * (1.0 - CHORD_SHARE)).abs() <= 0.05 * e0.abs(),
            "before {e0}, with the share {CHORD_SHARE}: {e}"
        );
        for mesh in [&after.mesh, &least_squares] {
            assert!(!crate::mesh::intersecting_triangles(mesh).iter().any(|&f| f));
        }
    }

    /// A share outside (0, 1] is refused with an error that names it; 1, the bound the dense
    /// points take, is accepted.
    #[test]
    fn a_share_out_of_range_is_an_error() {
        let with_share = |chord_share| PolygonizeParams {
            depth: 3,
            fit_chords: true,
            chord_share,
            ..Default::default()
        };
        for share in [0.0, -0.5, 1.5, f64::NAN] {
            let e = mesh_sphere(&with_share(share)).unwrap_err();
            assert!(
                matches!(e, PolygonizeError::InvalidChordShare(_)),
                "{share}: {e}"
            );
            assert!(e.to_string().contains("(0, 1]"), "{e}");
        }
        assert!(!mesh_sphere(&with_share(1.0))
            .unwrap()
            .mesh
            .triangles
            .is_empty());
    }

    /// A flat mesh does not move: a 5 × 5 grid of vertices on z = 0, whose 9 interior
    /// vertices have a zero umbrella normal part and whose 16 boundary ones are never moved.
    #[test]
    fn flat_and_boundary_vertices_stay() {
        let positions: Vec<[f64; 3]> = (0..25)
            .map(|i| [(i % 5) as f64, (i / 5) as f64, 0.0])
            .collect();
        let mut triangles = Vec::new();
        for y in 0..4u32 {
            for x in 0..4u32 {
                let v = 5 * y + x;
                triangles.push([v, v + 1, v + 6]);
                triangles.push([v, v + 6, v + 5]);
            }
        }
        let mut grid = TriangleMesh {
            normals: vec![[0.0, 0.0, 1.0]; 25],
            positions,
            triangles,
        };
        assert_eq!(chord_positions(&grid, 1.0), grid.positions);
        // Lift the centre: its neighbours lie under its tangent plane, so it rises; the
        // boundary stays.
        grid.positions[12][2] = 0.1;
        let fitted = chord_positions(&grid, 1.0);
        assert!(fitted[12][2] > 0.1);
        for v in [0, 4, 20, 24, 2, 10] {
            assert_eq!(fitted[v], grid.positions[v]);
        }
    }
}
