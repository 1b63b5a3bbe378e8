//! Unit tests of `mesh`.

use super::*;

fn mesh(positions: Vec<[f64; 3]>, triangles: Vec<[u32; 3]>) -> TriangleMesh {
    let normals = vec![[0.0, 0.0, 1.0]; positions.len()];
    TriangleMesh {
        positions,
        normals,
        triangles,
    }
}

/// The self-intersecting faces of the mesh of `triangles` over `positions`.
fn crossings(positions: &[[f64; 3]], triangles: &[[u32; 3]]) -> usize {
    self_intersecting_faces(&mesh(positions.to_vec(), triangles.to_vec()))
}

fn sphere(center: [f64; 3], radius: f64, rings: u32, sectors: u32) -> TriangleMesh {
    lat_long_sphere(center, radius, rings, sectors)
}

fn merge(a: &TriangleMesh, b: &TriangleMesh) -> TriangleMesh {
    let mut out = a.clone();
    let offset = a.positions.len() as u32;
    out.positions.extend(&b.positions);
    out.normals.extend(&b.normals);
    out.triangles
        .extend(b.triangles.iter().map(|t| t.map(|i| i + offset)));
    out
}

#[test]
fn two_crossing_triangles_count_two() {
    let m = mesh(
        vec![
            [0.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            [0.0, 2.0, 0.0],
            [0.5, 0.5, -1.0],
            [0.5, 0.5, 1.0],
            [3.0, 3.0, 0.0],
        ],
        vec![[0, 1, 2], [3, 4, 5]],
    );
    assert_eq!(self_intersecting_faces(&m), 2);
    assert_eq!(check(&m).self_intersecting_faces, 2);
    // Moved apart: 0; touching at a corner (no shared index): counted.
    let mut apart = m.clone();
    apart.positions[3] = [5.0, 5.0, -1.0];
    apart.positions[4] = [5.0, 5.0, 1.0];
    assert_eq!(self_intersecting_faces(&apart), 0);
    let mut touching = m.clone();
    touching.positions[3] = [2.0, 0.0, 0.0];
    touching.positions[4] = [3.0, 0.0, 1.0];
    touching.positions[5] = [3.0, 0.0, -1.0];
    assert_eq!(self_intersecting_faces(&touching), 2);
}

#[test]
fn closed_meshes_count_zero() {
    let tetra = mesh(
        vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ],
        vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
    );
    assert_eq!(check(&tetra).self_intersecting_faces, 0);
    let corners: Vec<[f64; 3]> = (0..8)
        .map(|i| {
            [
                f64::from(i & 1),
                f64::from((i >> 1) & 1),
                f64::from((i >> 2) & 1),
            ]
        })
        .collect();
    let cube = mesh(
        corners,
        vec![
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ],
    );
    let r = check(&cube);
    assert!(r.watertight);
    assert_eq!(r.self_intersecting_faces, 0);
    let ball = sphere([0.1, -0.2, 0.3], 1.3, 24, 48);
    let r = check(&ball);
    assert!(r.watertight);
    assert_eq!(r.self_intersecting_faces, 0);
}

#[test]
fn interpenetrating_spheres_count_only_along_the_intersection() {
    let a = sphere([0.0, 0.0, 0.0], 1.0, 20, 40);
    let b = sphere([1.2, 0.1, 0.05], 1.0, 20, 40);
    let both = merge(&a, &b);
    let flags = intersecting_triangles(&both);
    let count = flags.iter().filter(|&&f| f).count();
    assert!(count > 0);
    // Every flagged triangle has corners on both sides of (near) the other sphere.
    let edge = 0.2;
    for (ti, t) in both.triangles.iter().enumerate() {
        if !flags[ti] {
            continue;
        }
        let other = if ti < a.triangles.len() {
            [1.2, 0.1, 0.05]
        } else {
            [0.0, 0.0, 0.0]
        };
        let d = t.map(|i| {
            let p = both.positions[i as usize];
            (0..3)
                .map(|k| (p[k] - other[k]).powi(2))
                .sum::<f64>()
                .sqrt()
        });
        let near = d.iter().any(|&x| (x - 1.0).abs() < edge);
        assert!(
            near,
            "triangle {ti} flagged far from the intersection: {d:?}"
        );
    }
    // The same count on one thread and on several.
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| intersecting_triangles(&both));
    let three = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap()
        .install(|| intersecting_triangles(&both));
    assert_eq!(one, flags);
    assert_eq!(three, flags);
    // Apart: none.
    let c = sphere([2.5, 0.0, 0.0], 1.0, 20, 40);
    assert_eq!(self_intersecting_faces(&merge(&a, &c)), 0);
}

#[test]
fn shared_edge_counts_only_a_coplanar_fold() {
    let p = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.3, 1.0, 0.0],
        [0.6, 0.8, 0.0],
        [0.5, -1.0, 0.0],
        [0.5, 1.0, 0.5],
    ];
    // Folded back onto each other in one plane.
    assert_eq!(crossings(&p, &[[0, 1, 2], [1, 0, 3]]), 2);
    // Flat, opposite sides: fine; bent along the edge: fine.
    assert_eq!(crossings(&p, &[[0, 1, 2], [1, 0, 4]]), 0);
    assert_eq!(crossings(&p, &[[0, 1, 2], [1, 0, 5]]), 0);
    // A duplicated face.
    assert_eq!(crossings(&p, &[[0, 1, 2], [2, 1, 0]]), 2);
}

#[test]
fn shared_vertex_counts_only_beyond_it() {
    let p = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [-1.0, 0.0, 0.5],
        [0.0, -1.0, 0.5],
        [1.0, 1.0, -0.5],
        [1.0, 1.0, 0.5],
        [0.5, 0.2, 0.0],
        [0.2, 0.5, 0.0],
    ];
    // Touching only at the shared vertex (other triangle away, or standing on it).
    assert_eq!(crossings(&p, &[[0, 1, 2], [0, 3, 4]]), 0);
    // Piercing through the first triangle from the shared corner.
    assert_eq!(crossings(&p, &[[0, 1, 2], [0, 5, 6]]), 2);
    // Coplanar, overlapping inside the corner.
    assert_eq!(crossings(&p, &[[0, 1, 2], [0, 7, 8]]), 2);
    // Coplanar, only the corner point in common.
    let q = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
    ];
    assert_eq!(crossings(&q, &[[0, 1, 2], [0, 3, 4]]), 0);
    // Coplanar, sharing a direction along an edge: overlap along a segment counts.
    let mut r = q;
    r[3] = [0.5, 0.0, 0.0];
    r[4] = [0.5, -1.0, 0.0];
    assert_eq!(crossings(&r, &[[0, 1, 2], [0, 3, 4]]), 2);
}

#[test]
fn old_reports_parse_without_the_field() {
    let mut value = serde_json::to_value(MeshReport::default()).unwrap();
    value
        .as_object_mut()
        .unwrap()
        .remove("self_intersecting_faces");
    let r: MeshReport = serde_json::from_value(value).unwrap();
    assert_eq!(r.self_intersecting_faces, 0);
}

#[test]
fn boundary_edges_are_the_edges_used_once_as_they_run() {
    // A sphere with triangles removed (holes), a fold (an edge used three times), a
    // degenerate triangle (an edge used twice by one triangle) and a lone triangle; more
    // than the radix sort's threshold of uses.
    let sphere = lat_long_sphere([0.0; 3], 1.0, 40, 60);
    let mut triangles: Vec<[u32; 3]> = sphere
        .triangles
        .iter()
        .enumerate()
        .filter(|(i, _)| i % 97 != 5)
        .map(|(_, &t)| t)
        .collect();
    let [a, b, _] = triangles[100];
    triangles.push([a, b, 7]);
    triangles.push([3, 9, 3]);
    triangles.push([5000, 5001, 5002]);
    assert!(3 * triangles.len() > 4096);
    // The reference: every use, sorted by comparison.
    let mut uses: Vec<([u32; 2], [u32; 2])> = triangles
        .iter()
        .flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3])))
        .map(|(a, b)| ([a.min(b), a.max(b)], [a, b]))
        .collect();
    uses.sort_unstable();
    let mut expected: Vec<[u32; 2]> = uses
        .chunk_by(|x, y| x.0 == y.0)
        .filter(|u| u.len() == 1)
        .map(|u| u[0].1)
        .collect();
    expected.sort_unstable();
    assert!(expected.len() > 100 && expected.contains(&[5000, 5001]));
    assert_eq!(boundary_edges(&triangles), expected);
    assert!(boundary_edges(&sphere.triangles).is_empty());
    assert!(boundary_edges(&[]).is_empty());
}
