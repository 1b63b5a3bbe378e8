//! Integration tests of the `polygonize` stage and the mesh checks on exact polynomials of known
//! topology: watertightness, manifoldness, components, Euler characteristic, Hausdorff distance
//! to the true surface, projection residual, adaptivity and determinism across thread counts.

use std::collections::HashMap;

use stablesurf::mesh::{
    check, component_labels, drop_components_far_from, MeshReport, TriangleMesh,
};
use stablesurf::polygonize::{
    polygonize, polygonize_with_data, ImplicitFunction, PolygonizeError, PolygonizeParams,
    Polygonized, Simplification,
};
use stablesurf::testing::shapes;
use stablesurf::{Aabb, ImplicitPolynomial};

fn boxed(min: [f64; 3], max: [f64; 3]) -> Aabb {
    Aabb { min, max }
}

fn run(f: &ImplicitPolynomial, region: &Aabb, depth: u32) -> Polygonized {
    let params = PolygonizeParams {
        depth,
        ..PolygonizeParams::default()
    };
    polygonize(f, region, &params).expect("valid input")
}

/// The longest side of a finest (level `depth`) cell.
fn finest_cell(region: &Aabb, depth: u32) -> f64 {
    (0..3)
        .map(|a| region.max[a] - region.min[a])
        .fold(0.0, f64::max)
        / f64::from(1u32 << depth)
}

fn assert_closed(report: &MeshReport, components: usize, euler: i64) {
    assert!(report.watertight, "{report:?}");
    assert!(report.orientation_consistent, "{report:?}");
    assert_eq!(report.boundary_edges, 0, "{report:?}");
    assert_eq!(report.non_manifold_edges, 0, "{report:?}");
    assert_eq!(report.non_manifold_vertices, 0, "{report:?}");
    assert_eq!(report.components, components, "{report:?}");
    assert_eq!(report.euler_characteristic, euler, "{report:?}");
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// Largest distance from the mesh (vertices, edge midpoints, centroids) to the surface, with
/// `distance` the exact (or first-order) distance to the true surface.
fn mesh_to_surface(mesh: &TriangleMesh, distance: impl Fn([f64; 3]) -> f64) -> f64 {
    let mut worst: f64 = 0.0;
    for t in &mesh.triangles {
        let p = t.map(|i| mesh.positions[i as usize]);
        let centroid = [0, 1, 2].map(|a| (p[0][a] + p[1][a] + p[2][a]) / 3.0);
        worst = worst.max(distance(centroid).abs());
        for (i, j) in [(0, 1), (1, 2), (2, 0)] {
            worst = worst.max(distance(p[i]).abs());
            worst = worst.max(distance([0, 1, 2].map(|a| 0.5 * (p[i][a] + p[j][a]))).abs());
        }
    }
    worst
}

/// First-order distance |f|/|∇f|.
fn first_order(f: &ImplicitPolynomial) -> impl Fn([f64; 3]) -> f64 + '_ {
    |p| {
        let (v, g) = f.value_gradient(p);
        v.abs() / norm(g)
    }
}

/// Points on the true surface inside `region`: grid points within about one `spacing` of it,
/// projected by Newton steps along the gradient.
fn surface_samples(f: &ImplicitPolynomial, region: &Aabb, spacing: f64) -> Vec<[f64; 3]> {
    let counts = [0, 1, 2].map(|a| ((region.max[a] - region.min[a]) / spacing).ceil() as usize);
    let mut out = Vec::new();
    for i in 0..=counts[0] {
        for j in 0..=counts[1] {
            for k in 0..=counts[2] {
                // Offset from the lattice so the samples fall between the mesher's grid points.
                let start =
                    [0, 1, 2].map(|a| region.min[a] + ([i, j, k][a] as f64 + 0.37) * spacing);
                let (v, g) = f.value_gradient(start);
                if v.abs() / norm(g) > spacing {
                    continue;
                }
                let mut x = start;
                let mut converged = false;
                for _ in 0..30 {
                    let (v, g) = f.value_gradient(x);
                    let g2 = dot(g, g);
                    if g2 == 0.0 {
                        break;
                    }
                    if v.abs() / g2.sqrt() < 1e-13 {
                        converged = true;
                        break;
                    }
                    x = [0, 1, 2].map(|a| x[a] - v * g[a] / g2);
                }
                if converged && norm(sub(x, start)) < 2.0 * spacing && region.contains(x) {
                    out.push(x);
                }
            }
        }
    }
    out
}

/// Distance from `p` to the triangle (a, b, c) (Ericson, *Real-Time Collision Detection*, 5.1.5).
fn point_triangle_distance(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return norm(ap);
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return norm(bp);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return norm(sub(p, [0, 1, 2].map(|k| a[k] + v * ab[k])));
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return norm(cp);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return norm(sub(p, [0, 1, 2].map(|k| a[k] + w * ac[k])));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return norm(sub(p, [0, 1, 2].map(|k| b[k] + w * (c[k] - b[k]))));
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    norm(sub(p, [0, 1, 2].map(|k| a[k] + ab[k] * v + ac[k] * w)))
}

/// Largest distance from the surface samples to the mesh (triangles within two `cell`s).
fn surface_to_mesh(samples: &[[f64; 3]], mesh: &TriangleMesh, cell: f64) -> f64 {
    let key = |p: [f64; 3]| p.map(|c| (c / cell).floor() as i64);
    let mut buckets: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
    for (ti, t) in mesh.triangles.iter().enumerate() {
        buckets
            .entry(key(mesh.positions[t[0] as usize]))
            .or_default()
            .push(ti);
    }
    let mut worst: f64 = 0.0;
    for &s in samples {
        let k = key(s);
        let mut best = f64::INFINITY;
        for dx in -2..=2 {
            for dy in -2..=2 {
                for dz in -2..=2 {
                    for &ti in buckets
                        .get(&[k[0] + dx, k[1] + dy, k[2] + dz])
                        .into_iter()
                        .flatten()
                    {
                        let t = mesh.triangles[ti].map(|i| mesh.positions[i as usize]);
                        best = best.min(point_triangle_distance(s, t[0], t[1], t[2]));
                    }
                }
            }
        }
        worst = worst.max(best);
    }
    worst
}

/// Checks the Hausdorff distance both ways (sampled) against one finest cell, the projection
/// residual and unit normals.
fn assert_accurate(
    f: &ImplicitPolynomial,
    region: &Aabb,
    depth: u32,
    out: &Polygonized,
    distance: impl Fn([f64; 3]) -> f64,
) {
    let cell = finest_cell(region, depth);
    let forward = mesh_to_surface(&out.mesh, distance);
    assert!(forward < cell, "mesh → surface {forward} ≥ cell {cell}");
    let samples = surface_samples(f, region, cell);
    assert!(samples.len() > 100, "only {} samples", samples.len());
    let backward = surface_to_mesh(&samples, &out.mesh, cell);
    assert!(backward < cell, "surface → mesh {backward} ≥ cell {cell}");
    // Projection: |f|/|∇f| below 1e-6 of the region's diagonal at every vertex.
    let diagonal = region.diagonal();
    assert!(
        out.max_projection_residual < 1e-6,
        "{}",
        out.max_projection_residual
    );
    for (p, n) in out.mesh.positions.iter().zip(&out.mesh.normals) {
        let (v, g) = f.value_gradient(*p);
        assert!(v.abs() / norm(g) < 1e-6 * diagonal, "vertex {p:?}");
        assert!((norm(*n) - 1.0).abs() < 1e-12);
        // Outward: the normal agrees with the gradient.
        assert!(dot(*n, g) > 0.0);
    }
}

#[test]
fn sphere_with_center_and_scale() {
    // The unit sphere in normalized coordinates: radius 2 around (1, 2, 3) in input coordinates.
    let mut f = shapes::sphere(1.0);
    f.center = [1.0, 2.0, 3.0];
    f.scale = 2.0;
    let region = boxed([-1.5, -0.5, 0.5], [3.5, 4.5, 5.5]);
    let depth = 6;
    let out = run(&f, &region, depth);
    assert_closed(&check(&out.mesh), 1, 2);
    assert_eq!(out.max_level, depth);
    assert_accurate(&f, &region, depth, &out, |p| {
        norm(sub(p, [1.0, 2.0, 3.0])) - 2.0
    });
}

#[test]
fn torus_is_genus_one() {
    let (major, minor) = (1.0, 0.4);
    let f = shapes::torus(major, minor);
    let region = boxed([-1.6, -1.6, -0.6], [1.6, 1.6, 0.6]);
    let depth = 6;
    let out = run(&f, &region, depth);
    assert_closed(&check(&out.mesh), 1, 0);
    assert_accurate(&f, &region, depth, &out, |p| {
        let ring = (p[0] * p[0] + p[1] * p[1]).sqrt() - major;
        (ring * ring + p[2] * p[2]).sqrt() - minor
    });
}

#[test]
fn two_holed_surface_is_genus_two() {
    let mut f = shapes::genus_two();
    // A non-trivial normalization: the surface moves by (0.5, 0, 0) and grows 1.5×.
    f.center = [0.5, 0.0, 0.0];
    f.scale = 1.5;
    let region = boxed([-1.3, -1.05, -0.3], [2.3, 1.05, 0.3]);
    let depth = 7;
    let out = run(&f, &region, depth);
    assert_closed(&check(&out.mesh), 1, -2);
    assert_accurate(&f, &region, depth, &out, first_order(&f));
}

#[test]
fn two_spheres_are_two_components() {
    let f = shapes::two_spheres(1.0, 0.6);
    let region = boxed([-1.8, -0.8, -0.8], [1.8, 0.8, 0.8]);
    let depth = 6;
    let out = run(&f, &region, depth);
    let report = check(&out.mesh);
    assert_closed(&report, 2, 4);
    assert_accurate(&f, &region, depth, &out, |p| {
        let a = norm(sub(p, [1.0, 0.0, 0.0])) - 0.6;
        let b = norm(sub(p, [-1.0, 0.0, 0.0])) - 0.6;
        if a.abs() < b.abs() {
            a
        } else {
            b
        }
    });
    // Labels split the vertices by sphere.
    let (n, labels) = component_labels(&out.mesh);
    assert_eq!(n, 2);
    for (p, &l) in out.mesh.positions.iter().zip(&labels) {
        assert_eq!(
            l == labels[0],
            (p[0] > 0.0) == (out.mesh.positions[0][0] > 0.0)
        );
    }
    // Keeping only the component near a data point drops the other sphere.
    let (kept, dropped) = drop_components_far_from(&out.mesh, &[[1.6, 0.0, 0.0]], 0.1);
    assert_eq!(dropped, 1);
    assert_closed(&check(&kept), 1, 2);
    assert!(kept.positions.iter().all(|p| p[0] > 0.0));
    let (all, none_dropped) =
        drop_components_far_from(&out.mesh, &[[1.6, 0.0, 0.0], [-0.4, 0.0, 0.0]], 0.1);
    assert_eq!(
        (none_dropped, all.triangles.len()),
        (0, out.mesh.triangles.len())
    );
}

#[test]
fn identical_output_with_one_and_two_threads() {
    let f = shapes::genus_two();
    let region = boxed([-1.2, -0.7, -0.2], [1.2, 0.7, 0.2]);
    let params = PolygonizeParams {
        depth: 6,
        guard_levels: 3,
        ..PolygonizeParams::default()
    };
    let in_pool = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("thread pool")
            .install(|| polygonize(&f, &region, &params).expect("valid input"))
    };
    let (one, two) = (in_pool(1), in_pool(2));
    let bits = |m: &TriangleMesh| -> Vec<u64> {
        m.positions
            .iter()
            .chain(&m.normals)
            .flatten()
            .map(|c| c.to_bits())
            .collect()
    };
    assert!(!one.mesh.triangles.is_empty());
    assert_eq!(bits(&one.mesh), bits(&two.mesh));
    assert_eq!(one.mesh.triangles, two.mesh.triangles);
    assert_eq!(one.evaluations, two.evaluations);
}

#[test]
fn evaluations_grow_like_the_surface_not_the_volume() {
    let f = shapes::torus(1.0, 0.4);
    let region = boxed([-1.6, -1.6, -1.6], [1.6, 1.6, 1.6]);
    let counts: Vec<u64> = (5..=7).map(|d| run(&f, &region, d).evaluations).collect();
    for pair in counts.windows(2) {
        let ratio = pair[1] as f64 / pair[0] as f64;
        assert!(ratio > 2.5 && ratio < 5.5, "counts {counts:?}");
    }
}

#[test]
fn surface_leaving_the_region_is_cut_with_boundary_edges() {
    // The upper half of the unit sphere: a disk (χ = 1) whose rim lies on the plane z = 0.
    let f = shapes::sphere(1.0);
    let region = boxed([-1.5, -1.5, 0.0], [1.5, 1.5, 1.5]);
    let out = run(&f, &region, 5);
    let report = check(&out.mesh);
    assert!(report.boundary_edges > 0 && !report.watertight);
    assert_eq!(report.non_manifold_edges + report.non_manifold_vertices, 0);
    assert!(report.orientation_consistent);
    assert_eq!((report.components, report.euler_characteristic), (1, 1));
    // Every boundary edge lies on the cut plane.
    let mut uses: HashMap<(u32, u32), u32> = HashMap::new();
    for t in &out.mesh.triangles {
        for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
            *uses.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    for ((a, b), n) in uses {
        if n == 1 {
            let (pa, pb) = (
                out.mesh.positions[a as usize],
                out.mesh.positions[b as usize],
            );
            assert!(pa[2].abs() < 1e-9 && pb[2].abs() < 1e-9, "{pa:?} {pb:?}");
        }
    }
}

#[test]
fn topology_guard_finds_a_component_smaller_than_a_cell() {
    // A sphere of radius 0.03 far from the lattice points of a depth-4 grid (cells 0.125).
    let mut f = shapes::sphere(1.0);
    f.center = [0.31, -0.19, 0.44];
    f.scale = 0.03;
    let region = boxed([-1.0; 3], [1.0; 3]);
    let guarded = polygonize(
        &f,
        &region,
        &PolygonizeParams {
            depth: 4,
            guard_levels: 3,
            ..PolygonizeParams::default()
        },
    )
    .expect("valid input");
    assert!(guarded.guard_splits > 0 && guarded.max_level > 4);
    assert_closed(&check(&guarded.mesh), 1, 2);
    // Without the guard the corners of the depth-4 cell all lie outside: nothing is meshed.
    let unguarded = polygonize(
        &f,
        &region,
        &PolygonizeParams {
            depth: 4,
            guard_levels: 0,
            ..PolygonizeParams::default()
        },
    )
    .expect("valid input");
    assert!(unguarded.mesh.triangles.is_empty());
}

#[test]
fn mixed_levels_stay_manifold_around_a_singular_point() {
    // The double cone x² + y² − z² = 0 has a singular apex: the guard refines around it to the
    // cap, and leaves of four levels meet. The mesh must stay a consistently wound manifold.
    let mut coefficients = vec![0.0; 10];
    coefficients[4] = 1.0;
    coefficients[7] = 1.0;
    coefficients[9] = -1.0;
    let cone = ImplicitPolynomial {
        degree: 2,
        coefficients,
        center: [0.01, 0.02, 0.03],
        scale: 1.0,
    };
    let region = boxed([-1.0; 3], [1.0; 3]);
    let out = polygonize(
        &cone,
        &region,
        &PolygonizeParams {
            depth: 4,
            guard_levels: 3,
            ..PolygonizeParams::default()
        },
    )
    .expect("valid input");
    assert_eq!(out.max_level, 7);
    let report = check(&out.mesh);
    assert_eq!(report.non_manifold_edges, 0, "{report:?}");
    assert_eq!(report.non_manifold_vertices, 0, "{report:?}");
    assert!(report.orientation_consistent, "{report:?}");
    assert!(report.boundary_edges > 0);
}

#[test]
fn linked_tori_have_two_genus_one_components() {
    let f = shapes::linked_tori();
    let region = boxed([-1.4, -1.4, -1.4], [2.4, 1.4, 1.4]);
    let out = run(&f, &region, 6);
    assert_closed(&check(&out.mesh), 2, 0);
}

#[test]
fn bad_input_is_an_error() {
    let f = shapes::sphere(1.0);
    let flat = boxed([0.0, 0.0, 0.0], [1.0, 1.0, 0.0]);
    assert!(polygonize(&f, &flat, &PolygonizeParams::default()).is_err());
    let region = boxed([-1.0; 3], [1.0; 3]);
    for params in [
        PolygonizeParams {
            depth: 0,
            guard_levels: 0,
            ..PolygonizeParams::default()
        },
        PolygonizeParams {
            depth: 15,
            guard_levels: 2,
            ..PolygonizeParams::default()
        },
    ] {
        assert!(polygonize(&f, &region, &params).is_err());
    }
    let mut broken = f.clone();
    broken.coefficients.pop();
    assert!(polygonize(&broken, &region, &PolygonizeParams::default()).is_err());
    let mut broken = f;
    broken.scale = 0.0;
    assert!(polygonize(&broken, &region, &PolygonizeParams::default()).is_err());
}

#[test]
fn empty_zero_set_gives_an_empty_mesh() {
    let f = shapes::sphere(1.0);
    let region = boxed([3.0; 3], [4.0; 3]);
    let out = run(&f, &region, 6);
    assert!(out.mesh.positions.is_empty() && out.mesh.triangles.is_empty());
    assert_eq!(out.evaluations, 1);
}

/// Squared mean ratio 12|n|²/(Σ lᵢ²)² of each triangle (1 equilateral, 0 degenerate).
fn shape_qualities(mesh: &TriangleMesh) -> Vec<f64> {
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let (ab, ac, bc) = (sub(b, a), sub(c, a), sub(c, b));
            let n = [
                ab[1] * ac[2] - ab[2] * ac[1],
                ab[2] * ac[0] - ab[0] * ac[2],
                ab[0] * ac[1] - ab[1] * ac[0],
            ];
            let l = dot(ab, ab) + dot(ac, ac) + dot(bc, bc);
            12.0 * dot(n, n) / (l * l)
        })
        .collect()
}

#[test]
fn edge_collapses_about_halve_the_triangles_and_keep_the_topology() {
    let f = shapes::genus_two();
    let region = boxed([-1.2, -0.7, -0.2], [1.2, 0.7, 0.2]);
    let mesh_with = |simplification| {
        polygonize(
            &f,
            &region,
            &PolygonizeParams {
                depth: 7,
                simplification,
                ..PolygonizeParams::default()
            },
        )
        .expect("valid input")
    };
    let plain = mesh_with(Simplification::None);
    let collapsed = mesh_with(Simplification::EdgeCollapse);
    assert_closed(&check(&plain.mesh), 1, -2);
    assert_closed(&check(&collapsed.mesh), 1, -2);
    let (n_plain, n_collapsed) = (plain.mesh.triangles.len(), collapsed.mesh.triangles.len());
    assert!(
        100 * n_collapsed < 55 * n_plain,
        "{n_collapsed} triangles after collapses, {n_plain} before"
    );
    // Fewer slivers (mean ratio below 0.2), in number and in share.
    let slivers = |m: &TriangleMesh| shape_qualities(m).iter().filter(|&&q| q < 0.04).count();
    let (s_plain, s_collapsed) = (slivers(&plain.mesh), slivers(&collapsed.mesh));
    assert!(
        s_collapsed * n_plain < s_plain * n_collapsed,
        "slivers {s_collapsed}/{n_collapsed} after, {s_plain}/{n_plain} before"
    );
    assert_accurate(&f, &region, 7, &collapsed, first_order(&f));
}

/// Shapes where the Newton projection pushed triangles through their neighbours before the
/// crossings were repaired (36 crossing triangles for the two-holed surface at depth 4 without the
/// guard, 36 for the torus at depth 5, 41 for the linked tori at depth 3): none now, with either
/// simplification, and the mesh stays closed.
#[test]
fn no_triangle_crosses_another() {
    use stablesurf::mesh::self_intersecting_faces;
    let cases = [
        (
            shapes::genus_two(),
            boxed([-1.1, -0.6, -0.1], [1.1, 0.6, 0.1]),
            4,
            0,
        ),
        (
            shapes::torus(1.0, 0.25),
            boxed([-1.4, -1.4, -0.4], [1.4, 1.4, 0.4]),
            5,
            3,
        ),
        (
            shapes::linked_tori(),
            boxed([-1.4, -1.4, -1.4], [2.4, 1.4, 1.4]),
            3,
            0,
        ),
    ];
    for (f, region, depth, guard_levels) in &cases {
        for simplification in [Simplification::None, Simplification::EdgeCollapse] {
            let params = PolygonizeParams {
                depth: *depth,
                guard_levels: *guard_levels,
                simplification,
                ..PolygonizeParams::default()
            };
            let out = polygonize(f, region, &params).expect("valid input");
            let report = check(&out.mesh);
            assert!(report.watertight, "depth {depth} {simplification:?}");
            assert_eq!(
                report.self_intersecting_faces, 0,
                "depth {depth} {simplification:?}"
            );
            assert_eq!(self_intersecting_faces(&out.mesh), 0);
            // What the meshing proved is what the full test finds.
            assert!(out.embedded, "depth {depth} {simplification:?}");
        }
    }
}

/// Mean length of the edges of the triangles whose centroid lies in the half-space `z > 0`
/// (`upper`) or `z < 0`.
fn mean_edge_length(mesh: &TriangleMesh, upper: bool) -> f64 {
    let (mut sum, mut count) = (0.0, 0usize);
    for t in &mesh.triangles {
        let p = t.map(|v| mesh.positions[v as usize]);
        if (p[0][2] + p[1][2] + p[2][2] > 0.0) != upper {
            continue;
        }
        for i in 0..3 {
            let (a, b) = (p[i], p[(i + 1) % 3]);
            sum += ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
            count += 1;
        }
    }
    sum / count as f64
}

#[test]
fn data_levels_keep_the_fine_level_where_the_data_is_and_a_closed_embedded_mesh() {
    let f = shapes::sphere(1.0);
    let region = boxed([-1.3; 3], [1.3; 3]);
    // Data on the upper cap only (z > 0.3), spread finer than a level-6 cell.
    let mut data = Vec::new();
    for i in 0..4000 {
        let z = 0.3 + 0.7 * (i as f64 + 0.5) / 4000.0;
        let (r, a) = ((1.0 - z * z).sqrt(), 2.399963 * i as f64);
        data.push([r * a.cos(), r * a.sin(), z]);
    }
    let params = PolygonizeParams {
        depth: 6,
        data_levels: 2,
        ..PolygonizeParams::default()
    };
    let uniform = polygonize(&f, &region, &params).expect("valid input");
    // With no data (or through `polygonize`) the data levels change nothing.
    let no_data = polygonize_with_data(&f, &region, &[], None, &params).expect("valid input");
    assert_eq!(uniform.mesh, no_data.mesh);
    let adaptive = polygonize_with_data(&f, &region, &data, None, &params).expect("valid input");
    for out in [&uniform, &adaptive] {
        let report = check(&out.mesh);
        assert_closed(&report, 1, 2);
        assert_eq!(report.self_intersecting_faces, 0);
        assert!(out.embedded);
        // Every vertex on the sphere (the projection), so the coarse part is as exact there.
        for p in &out.mesh.positions {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            assert!((r - 1.0).abs() < 1e-6, "{r}");
        }
    }
    // The upper half keeps the uniform mesh's edge lengths (within 10%); the lower half, with
    // no data, has edges about 4× as long (two levels coarser): at least 2.5× here.
    let fine = mean_edge_length(&uniform.mesh, true);
    let near = mean_edge_length(&adaptive.mesh, true);
    let far = mean_edge_length(&adaptive.mesh, false);
    assert!((near / fine - 1.0).abs() < 0.1, "{near} vs {fine}");
    assert!(far > 2.5 * fine, "{far} vs {fine}");
    assert!(adaptive.mesh.triangles.len() < uniform.mesh.triangles.len());
    // The same mesh on one thread as on several.
    let single = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| polygonize_with_data(&f, &region, &data, None, &params).expect("valid input"));
    assert_eq!(single.mesh, adaptive.mesh);
}

#[test]
fn flat_data_stays_coarse_and_curved_data_keeps_the_fine_level() {
    let params = PolygonizeParams {
        depth: 6,
        data_levels: 2,
        ..PolygonizeParams::default()
    };
    // The plane z = 0.1 (coefficients 1, x, y, z), data on it finer than a level-6 cell, with
    // its normal: flat everywhere, so the mesh stays at level 4 (edges ~4× as long).
    let plane = ImplicitPolynomial {
        degree: 1,
        coefficients: vec![-0.1, 0.0, 0.0, 1.0],
        center: [0.0; 3],
        scale: 1.0,
    };
    let region = boxed([-1.0; 3], [1.0; 3]);
    let mut data = Vec::new();
    for i in 0..100 {
        for j in 0..100 {
            data.push([-0.99 + 0.02 * i as f64, -0.99 + 0.02 * j as f64, 0.1]);
        }
    }
    let up = vec![[0.0, 0.0, 1.0]; data.len()];
    let fine = polygonize_with_data(&plane, &region, &data, None, &params).expect("valid input");
    let flat =
        polygonize_with_data(&plane, &region, &data, Some(&up), &params).expect("valid input");
    assert!(
        flat.mesh.triangles.len() * 8 < fine.mesh.triangles.len(),
        "{} vs {}",
        flat.mesh.triangles.len(),
        fine.mesh.triangles.len()
    );
    for out in [&fine, &flat] {
        let report = check(&out.mesh);
        assert!(report.orientation_consistent && report.non_manifold_edges == 0);
        assert_eq!(report.components, 1);
        assert_eq!(report.self_intersecting_faces, 0);
        for p in &out.mesh.positions {
            assert!((p[2] - 0.1).abs() < 1e-9, "{p:?}");
        }
    }

    // The unit sphere with data on it: with its exact normals nothing is flat at these levels
    // (the same mesh as without normals); with the normals of a plane declared for the upper cap,
    // the cap is meshed coarsely, and the mesh stays closed, embedded and on the sphere.
    let sphere = shapes::sphere(1.0);
    let region = boxed([-1.3; 3], [1.3; 3]);
    let data: Vec<[f64; 3]> = (0..8000)
        .map(|i| {
            let z = -1.0 + 2.0 * (i as f64 + 0.5) / 8000.0;
            let (r, a) = ((1.0 - z * z).sqrt(), 2.399963 * i as f64);
            [r * a.cos(), r * a.sin(), z]
        })
        .collect();
    let exact = data.clone();
    let declared: Vec<[f64; 3]> = data
        .iter()
        .map(|&p| if p[2] > 0.5 { [0.0, 0.0, 1.0] } else { p })
        .collect();
    let plain = polygonize_with_data(&sphere, &region, &data, None, &params).expect("valid input");
    let curved =
        polygonize_with_data(&sphere, &region, &data, Some(&exact), &params).expect("valid input");
    assert_eq!(plain.mesh, curved.mesh);
    let capped = polygonize_with_data(&sphere, &region, &data, Some(&declared), &params)
        .expect("valid input");
    let report = check(&capped.mesh);
    assert_closed(&report, 1, 2);
    assert_eq!(report.self_intersecting_faces, 0);
    assert!(capped.embedded);
    for p in &capped.mesh.positions {
        let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
        assert!((r - 1.0).abs() < 1e-6, "{r}");
    }
    // Near the pole (centroid z > 0.85, cells whose whole block holds declared normals), the
    // edges are about 4× as long (two levels coarser): at least 2.5× here.
    let polar_edge = |mesh: &TriangleMesh| {
        let (mut sum, mut count) = (0.0, 0usize);
        for t in &mesh.triangles {
            let p = t.map(|v| mesh.positions[v as usize]);
            if p[0][2] + p[1][2] + p[2][2] > 3.0 * 0.85 {
                for i in 0..3 {
                    let (a, b) = (p[i], p[(i + 1) % 3]);
                    sum += (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt();
                    count += 1;
                }
            }
        }
        sum / count as f64
    };
    let (coarse, kept) = (polar_edge(&capped.mesh), polar_edge(&plain.mesh));
    assert!(coarse > 2.5 * kept, "{coarse} vs {kept}");
    assert!(capped.mesh.triangles.len() < plain.mesh.triangles.len());

    // Normals that do not match the data in number are refused.
    let err = polygonize_with_data(&sphere, &region, &data, Some(&exact[1..]), &params);
    assert!(
        matches!(err, Err(PolygonizeError::InvalidData(_))),
        "{err:?}"
    );
}
