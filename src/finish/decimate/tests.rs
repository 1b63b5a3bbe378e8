//! Unit tests of `finish::decimate`.

use super::*;
use crate::mesh::check;

/// A latitude–longitude sphere of radius 1, wound outwards.
fn sphere_mesh(rings: u32, sectors: u32) -> TriangleMesh {
    crate::mesh::lat_long_sphere([0.0; 3], 1.0, rings, sectors)
}

/// `mesh` (of the unit sphere) decimated to at most `target_triangles`.
fn to_budget(mesh: &TriangleMesh, target_triangles: usize) -> Decimated {
    decimate(mesh, &unit_sphere(), &DecimateParams { target_triangles })
}

fn unit_sphere() -> crate::poly::ImplicitPolynomial {
    crate::poly::ImplicitPolynomial {
        degree: 2,
        coefficients: vec![-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0],
        center: [0.0; 3],
        scale: 1.0,
    }
}

#[test]
fn classify_tells_interior_boundary_and_frozen() {
    let tris = [[0, 1, 2], [0, 2, 3], [0, 3, 1]];
    let p = [[0.0; 3]; 4];
    assert_eq!(classify(0, &[0, 1, 2], &tris, &p), Kind::Interior);
    assert_eq!(classify(0, &[0, 1], &tris, &p), Kind::Boundary);
    // Two fans at one vertex.
    let bow = [[0, 1, 2], [0, 3, 4]];
    assert_eq!(classify(0, &[0, 1], &bow, &[[0.0; 3]; 5]), Kind::Frozen);
}

#[test]
fn optimum_of_three_planes_is_their_corner() {
    let mut q = [0.0; 10];
    // Planes x = 1, y = 2, z = 3.
    for (axis, d) in [(0, 1.0), (1, 2.0), (2, 3.0)] {
        let mut u = [0.0; 3];
        u[axis] = 1.0;
        q = add(&q, &plane_quadric(u, -d));
    }
    let x = optimum(&q, [1.0, 2.0, 3.0]).unwrap();
    for (got, want) in x.iter().zip([1.0, 2.0, 3.0]) {
        assert!((got - want).abs() < 1e-12, "{x:?}");
    }
    assert!(error(&q, x) < 1e-20);
    // Far from the corner the regularisation pulls only by λ = 1e-3 of the curvature.
    let y = optimum(&q, [2.0, 2.0, 3.0]).unwrap();
    assert!((y[0] - 1.0).abs() < 2e-3, "{y:?}");
}

#[test]
fn sphere_keeps_topology_and_stays_on_the_surface() {
    let mesh = sphere_mesh(24, 48);
    let before = check(&mesh);
    assert!(before.watertight);
    let out = to_budget(&mesh, 300);
    assert!(out.report.reached, "{:?}", out.report);
    assert!(out.mesh.triangles.len() <= 300);
    let after = check(&out.mesh);
    assert!(
        after.watertight && after.orientation_consistent,
        "{after:?}"
    );
    assert_eq!(after.euler_characteristic, 2);
    assert_eq!(after.self_intersecting_faces, 0);
    for p in &out.mesh.positions {
        assert!((norm(*p) - 1.0).abs() < 1e-6, "{p:?}");
    }
}

#[test]
fn within_budget_is_unchanged() {
    let mesh = sphere_mesh(8, 16);
    let out = to_budget(&mesh, mesh.triangles.len());
    assert_eq!(out.mesh, mesh);
    assert!(out.report.reached);
    assert_eq!(out.report.collapses, 0);
}

#[test]
fn impossible_budget_stops_at_a_legal_mesh() {
    let mesh = sphere_mesh(6, 12);
    let out = to_budget(&mesh, 1);
    assert!(!out.report.reached);
    assert!(out.mesh.triangles.len() >= 4);
    let after = check(&out.mesh);
    assert!(after.watertight, "{after:?}");
    assert_eq!(after.euler_characteristic, 2);
    assert_eq!(after.self_intersecting_faces, 0);
    assert!(out.report.shortfall().is_some());
}
