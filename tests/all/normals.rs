//! Integration tests of the `normals` stage: the Delaunay tetrahedralization's invariants on
//! random, lattice (co-spherical) and duplicated input; normal accuracy and outward orientation on
//! analytic shapes (sphere, torus, a genus-2 "eight") with and without noise; sign agreement with
//! the original meshes of real scans; clear errors on degenerate input.

use stablesurf::normals::{estimate_normals, NormalSource, NormalsError, NormalsParams};
use stablesurf::testing::{face_vertices, insphere, orient3d, tetrahedralize, NO_NEIGHBOUR};
use stablesurf::PointCloud;

use crate::fixtures::{quaternion_rotation, shared, Rng};

// ---------------------------------------------------------------- helpers

fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let l = dot(&a, &a).sqrt();
    [a[0] / l, a[1] / l, a[2] / l]
}

/// Points on a surface with their true unit outward normals.
struct Sample {
    points: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    size: f64,
}

fn sphere(n: usize, seed: u64) -> Sample {
    let mut rng = Rng(seed);
    let mut points = Vec::new();
    let mut normals = Vec::new();
    while points.len() < n {
        let v = [rng.gauss(), rng.gauss(), rng.gauss()];
        if dot(&v, &v) < 1e-6 {
            continue;
        }
        let u = unit(v);
        points.push([1.0 + u[0], 2.0 + u[1], -0.5 + u[2]]);
        normals.push(u);
    }
    Sample {
        points,
        normals,
        size: 2.0,
    }
}

fn torus(n: usize, seed: u64) -> Sample {
    let (big, small) = (1.0, 0.4);
    let mut rng = Rng(seed);
    let mut points = Vec::new();
    let mut normals = Vec::new();
    while points.len() < n {
        let phi = std::f64::consts::TAU * rng.uniform();
        let theta = std::f64::consts::TAU * rng.uniform();
        // Area element ∝ (R + r cos θ): accept with that probability.
        if rng.uniform() * (big + small) > big + small * theta.cos() {
            continue;
        }
        let nrm = [
            phi.cos() * theta.cos(),
            phi.sin() * theta.cos(),
            theta.sin(),
        ];
        let rho = big + small * theta.cos();
        points.push([rho * phi.cos(), rho * phi.sin(), small * theta.sin()]);
        normals.push(nrm);
    }
    Sample {
        points,
        normals,
        size: 2.0 * (big + small),
    }
}

/// A genus-2 "eight": two tori (R = 0.65, r = 0.35) side by side, centres 1.6 apart, joined by a
/// smooth union of their signed distances, f = −ln(e^(−k·d₁) + e^(−k·d₂))/k with k = 16.
fn eight(n: usize, seed: u64) -> Sample {
    let (big, small, offset, k) = (0.65, 0.35, 0.8, 16.0);
    // Signed distance to a torus centred at (cx, 0, 0) and its gradient.
    let torus_sdf = |p: [f64; 3], cx: f64| {
        let (x, y, z) = (p[0] - cx, p[1], p[2]);
        let rho = (x * x + y * y).sqrt().max(1e-12);
        let q = rho - big;
        let len = (q * q + z * z).sqrt().max(1e-12);
        (len - small, [q / len * x / rho, q / len * y / rho, z / len])
    };
    let field = |p: [f64; 3]| {
        let (d1, g1) = torus_sdf(p, -offset);
        let (d2, g2) = torus_sdf(p, offset);
        let m = d1.min(d2);
        let (e1, e2) = ((-k * (d1 - m)).exp(), (-k * (d2 - m)).exp());
        let f = m - (e1 + e2).ln() / k;
        let (w1, w2) = (e1 / (e1 + e2), e2 / (e1 + e2));
        (
            f,
            [
                w1 * g1[0] + w2 * g2[0],
                w1 * g1[1] + w2 * g2[1],
                w1 * g1[2] + w2 * g2[2],
            ],
        )
    };
    let mut rng = Rng(seed);
    let mut points = Vec::new();
    let mut normals = Vec::new();
    // Uniform points in a thin shell around the surface (density ∝ area), then projected.
    let shell = 0.004;
    while points.len() < n {
        let mut p = [
            3.8 * rng.uniform() - 1.9,
            2.2 * rng.uniform() - 1.1,
            0.8 * rng.uniform() - 0.4,
        ];
        let (f0, g0) = field(p);
        let gl = dot(&g0, &g0).sqrt();
        if gl < 1e-9 || f0.abs() / gl > shell {
            continue;
        }
        for _ in 0..20 {
            let (f, g) = field(p);
            let s = f / dot(&g, &g);
            p = [p[0] - s * g[0], p[1] - s * g[1], p[2] - s * g[2]];
        }
        let (f, g) = field(p);
        if f.abs() > 1e-12 {
            continue;
        }
        points.push(p);
        normals.push(unit(g));
    }
    Sample {
        points,
        normals,
        size: 2.0 * (offset + big + small),
    }
}

fn with_noise(s: &Sample, fraction: f64, seed: u64) -> Sample {
    let mut rng = Rng(seed);
    let sigma = fraction * s.size;
    let points = s
        .points
        .iter()
        .map(|p| {
            [
                p[0] + sigma * rng.gauss(),
                p[1] + sigma * rng.gauss(),
                p[2] + sigma * rng.gauss(),
            ]
        })
        .collect();
    Sample {
        points,
        normals: s.normals.clone(),
        size: s.size,
    }
}

/// (mean angular error in degrees, fraction of outward normals).
fn score(truth: &[[f64; 3]], got: &[[f64; 3]]) -> (f64, f64) {
    let mut sum = 0.0;
    let mut outward = 0;
    for (t, g) in truth.iter().zip(got) {
        let c = dot(t, g);
        assert!(
            (dot(g, g) - 1.0).abs() < 1e-9,
            "normal {g:?} is not unit length"
        );
        sum += c.abs().min(1.0).acos().to_degrees();
        if c > 0.0 {
            outward += 1;
        }
    }
    (
        sum / truth.len() as f64,
        outward as f64 / truth.len() as f64,
    )
}

fn run(points: &[[f64; 3]], source: NormalSource) -> stablesurf::normals::Normals {
    let cloud = PointCloud {
        points: points.to_vec(),
        ..Default::default()
    };
    let params = NormalsParams {
        source,
        ..Default::default()
    };
    estimate_normals(&cloud, &params).expect("normals")
}

// ---------------------------------------------------------------- Delaunay

/// Checks orientation, adjacency and the empty-circumsphere property against all points.
fn check_delaunay(points: &[[f64; 3]]) -> usize {
    let dt = tetrahedralize(points).expect("tetrahedralization");
    assert_eq!(dt.n_rejected, 0);
    for (t, tet) in dt.tets.iter().enumerate() {
        let q = tet.map(|v| points[v as usize]);
        assert!(
            orient3d(&q[0], &q[1], &q[2], &q[3]) > 0.0,
            "tet {t} is not positively oriented"
        );
        for (i, &u) in dt.neighbours[t].iter().enumerate() {
            if u == NO_NEIGHBOUR {
                continue;
            }
            let back = dt.neighbours[u as usize]
                .iter()
                .position(|&x| x as usize == t);
            let j = back.expect("adjacency is symmetric");
            let mut f = face_vertices(*tet, i).to_vec();
            let mut g = face_vertices(dt.tets[u as usize], j).to_vec();
            f.sort_unstable();
            g.sort_unstable();
            assert_eq!(f, g, "neighbours share the face");
        }
        for (k, p) in points.iter().enumerate() {
            if tet.contains(&(k as u32)) || dt.representative[k] as usize != k {
                continue;
            }
            assert!(
                insphere(&q[0], &q[1], &q[2], &q[3], p) <= 0.0,
                "point {k} inside the circumsphere of tet {t}"
            );
        }
    }
    // Hull faces point away from the opposite vertex.
    for (t, i) in dt.hull_faces() {
        let f = face_vertices(dt.tets[t], i).map(|v| points[v as usize]);
        let opposite = points[dt.tets[t][i] as usize];
        assert!(orient3d(&f[0], &f[1], &f[2], &opposite) > 0.0);
    }
    dt.tets.len()
}

fn volume(points: &[[f64; 3]], tets: &[[u32; 4]]) -> f64 {
    tets.iter()
        .map(|t| {
            let [a, b, c, d] = t.map(|v| points[v as usize]);
            let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
            let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
            let w = [d[0] - a[0], d[1] - a[1], d[2] - a[2]];
            (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0])
                + u[2] * (v[0] * w[1] - v[1] * w[0]))
                .abs()
                / 6.0
        })
        .sum()
}

#[test]
fn delaunay_of_random_points_is_valid() {
    let mut rng = Rng(7);
    let points: Vec<[f64; 3]> = (0..400)
        .map(|_| [rng.uniform(), rng.uniform(), rng.uniform()])
        .collect();
    let n_tets = check_delaunay(&points);
    assert!(n_tets > 400);
}

#[test]
fn delaunay_of_a_cubic_lattice_is_valid_and_fills_the_box() {
    // Every unit cube of a lattice has 8 co-spherical corners: the hardest degenerate input.
    let m = 6;
    let mut points = Vec::new();
    for i in 0..m {
        for j in 0..m {
            for k in 0..m {
                points.push([i as f64 * 0.5, j as f64 * 0.5, k as f64 * 0.5]);
            }
        }
    }
    check_delaunay(&points);
    let dt = tetrahedralize(&points).unwrap();
    let side = 0.5 * (m - 1) as f64;
    assert!((volume(&points, &dt.tets) - side * side * side).abs() < 1e-9);
}

#[test]
fn delaunay_of_a_sphere_with_duplicates_is_valid() {
    // Exactly co-spherical (up to rounding) points, each present twice, plus a grid on a sphere.
    let s = sphere(300, 3);
    let mut points = s.points.clone();
    points.extend_from_slice(&s.points[..100]);
    for i in 0..8 {
        for j in 0..8 {
            let (a, b) = (i as f64 * 0.7, j as f64 * 0.4);
            points.push([a.cos() * b.sin(), a.sin() * b.sin(), b.cos()]);
        }
    }
    check_delaunay(&points);
    let dt = tetrahedralize(&points).unwrap();
    for k in 300..400 {
        assert_eq!(dt.representative[k] as usize, k - 300);
    }
}

#[test]
fn delaunay_of_points_on_two_planes_is_valid() {
    // Two parallel grids: many coplanar and co-spherical subsets.
    let mut points = Vec::new();
    for i in 0..10 {
        for j in 0..10 {
            points.push([i as f64, j as f64, 0.0]);
            points.push([i as f64 + 0.5, j as f64, 1.0]);
        }
    }
    check_delaunay(&points);
}

// ---------------------------------------------------------------- bad input

#[test]
fn degenerate_clouds_give_clear_errors() {
    let params = NormalsParams {
        source: NormalSource::Crust,
        ..Default::default()
    };
    let few = PointCloud {
        points: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        ..Default::default()
    };
    assert!(matches!(
        estimate_normals(&few, &params),
        Err(NormalsError::TooFewPoints { .. })
    ));
    let dups = PointCloud {
        points: vec![[1.0, 2.0, 3.0]; 50],
        ..Default::default()
    };
    assert!(matches!(
        estimate_normals(&dups, &params),
        Err(NormalsError::TooFewPoints { .. })
    ));
    let line = PointCloud {
        points: (0..20)
            .map(|i| [i as f64, 2.0 * i as f64, -(i as f64)])
            .collect(),
        ..Default::default()
    };
    assert!(matches!(
        estimate_normals(&line, &params),
        Err(NormalsError::Collinear)
    ));
    let plane = PointCloud {
        points: (0..100)
            .map(|i| {
                [
                    (i % 10) as f64,
                    (i / 10) as f64,
                    0.5 * (i % 10) as f64 + 3.0,
                ]
            })
            .collect(),
        ..Default::default()
    };
    assert!(matches!(
        estimate_normals(&plane, &params),
        Err(NormalsError::Coplanar)
    ));
    let nan = PointCloud {
        points: vec![
            [0.0; 3],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, f64::NAN],
            [0.0, 0.0, 1.0],
            [1.0; 3],
        ],
        ..Default::default()
    };
    assert!(matches!(
        estimate_normals(&nan, &params),
        Err(NormalsError::NonFinitePoint { index: 2 })
    ));
    for source in [NormalSource::Pca, NormalSource::Auto] {
        let p = NormalsParams {
            source,
            ..Default::default()
        };
        assert!(estimate_normals(&plane, &p).is_err());
    }
    let p = NormalsParams {
        source: NormalSource::Input,
        ..Default::default()
    };
    let s = PointCloud {
        points: sphere(50, 1).points,
        ..Default::default()
    };
    assert!(matches!(
        estimate_normals(&s, &p),
        Err(NormalsError::NoInputNormals)
    ));
    let p = NormalsParams {
        source: NormalSource::Mesh,
        ..Default::default()
    };
    assert!(matches!(
        estimate_normals(&s, &p),
        Err(NormalsError::NoMeshFaces)
    ));
    let message = estimate_normals(&plane, &params).unwrap_err().to_string();
    assert!(message.contains("plane"), "{message}");
}

#[test]
fn lattice_and_duplicates_get_outward_normals() {
    // The surface of a cube lattice (co-spherical and co-planar everywhere), duplicated.
    let m = 9;
    let mut points = Vec::new();
    for i in 0..m {
        for j in 0..m {
            for k in 0..m {
                if [i, j, k].iter().any(|&c| c == 0 || c == m - 1) {
                    points.push([i as f64, j as f64, k as f64]);
                }
            }
        }
    }
    let n = points.len();
    points.extend_from_slice(&points.clone()[..50]);
    let out = run(&points, NormalSource::Crust);
    assert_eq!(out.cloud.points, points);
    let c = (m - 1) as f64 / 2.0;
    for (k, (p, nrm)) in out.cloud.points.iter().zip(&out.cloud.normals).enumerate() {
        let radial = [p[0] - c, p[1] - c, p[2] - c];
        assert!(
            dot(nrm, &radial) > 0.0,
            "point {k} normal {nrm:?} points inward"
        );
        if k >= n {
            assert_eq!(
                *nrm,
                out.cloud.normals[k - n],
                "a duplicate gets its twin's normal"
            );
        }
    }
    // Face centres (away from edges) have the exact face normal.
    let centre_face = points.iter().position(|p| *p == [c, c, 0.0]).unwrap();
    assert!(dot(&out.cloud.normals[centre_face], &[0.0, 0.0, -1.0]) > 0.999);
}

// ---------------------------------------------------------------- analytic shapes

fn check_clean(s: &Sample, name: &str) {
    let out = run(&s.points, NormalSource::Crust);
    assert_eq!(out.source_used, NormalSource::Crust);
    let (mean, outward) = score(&s.normals, &out.cloud.normals);
    println!(
        "{name}: {} points, mean error {mean:.3}°, outward {:.4}, {} crust triangles, {:?}",
        s.points.len(),
        outward,
        out.crust_triangles.len(),
        out.warnings
    );
    assert!(mean < 2.0, "{name}: mean angular error {mean}° ≥ 2°");
    assert_eq!(outward, 1.0, "{name}: not every normal points outward");
}

fn check_noisy(s: &Sample, name: &str, source: NormalSource) {
    let noisy = with_noise(s, 0.01, 99);
    let out = run(&noisy.points, source);
    let (mean, outward) = score(&s.normals, &out.cloud.normals);
    println!(
        "{name} noisy ({source}): mean error {mean:.3}°, outward {outward:.4}, {:?}",
        out.warnings
    );
    assert!(
        mean < 10.0,
        "{name} noisy: mean angular error {mean}° ≥ 10°"
    );
    assert!(outward >= 0.99, "{name} noisy: only {outward} outward");
}

#[test]
fn sphere_clean() {
    check_clean(&sphere(2000, 11), "sphere 2k");
    check_clean(&sphere(20000, 12), "sphere 20k");
}

#[test]
fn torus_clean() {
    check_clean(&torus(5000, 21), "torus 5k");
    check_clean(&torus(30000, 22), "torus 30k");
}

#[test]
fn eight_clean() {
    check_clean(&eight(20000, 31), "eight 20k");
}

#[test]
fn sphere_noisy() {
    check_noisy(&sphere(10000, 13), "sphere 10k", NormalSource::Crust);
    check_noisy(&sphere(10000, 14), "sphere 10k", NormalSource::Pca);
}

#[test]
fn torus_noisy() {
    check_noisy(&torus(20000, 23), "torus 20k", NormalSource::Crust);
}

#[test]
fn eight_noisy() {
    check_noisy(&eight(20000, 32), "eight 20k", NormalSource::Crust);
}

#[test]
fn pca_clean_shapes() {
    for (s, name) in [(sphere(5000, 41), "sphere"), (torus(10000, 42), "torus")] {
        let out = run(&s.points, NormalSource::Pca);
        let (mean, outward) = score(&s.normals, &out.cloud.normals);
        println!("{name} pca: mean {mean:.3}°, outward {outward}");
        assert!(mean < 3.0, "{name} pca: mean error {mean}°");
        assert_eq!(outward, 1.0);
    }
}

/// A torus as a (u, v) grid mesh, each triangle wound at random, with the true normals.
/// Points, true normals and triangles of a mesh.
type Mesh = (Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<[u32; 3]>);

fn torus_mesh(nu: usize, nv: usize) -> Mesh {
    let (big, small) = (1.0, 0.4);
    let mut points = Vec::new();
    let mut normals = Vec::new();
    for i in 0..nu {
        for j in 0..nv {
            let phi = std::f64::consts::TAU * i as f64 / nu as f64;
            let theta = std::f64::consts::TAU * j as f64 / nv as f64;
            let rho = big + small * theta.cos();
            points.push([rho * phi.cos(), rho * phi.sin(), small * theta.sin()]);
            normals.push([
                phi.cos() * theta.cos(),
                phi.sin() * theta.cos(),
                theta.sin(),
            ]);
        }
    }
    let id = |i: usize, j: usize| ((i % nu) * nv + (j % nv)) as u32;
    let mut rng = Rng(5);
    let mut triangles = Vec::new();
    for i in 0..nu {
        for j in 0..nv {
            for t in [
                [id(i, j), id(i + 1, j), id(i + 1, j + 1)],
                [id(i, j), id(i + 1, j + 1), id(i, j + 1)],
            ] {
                triangles.push(if rng.uniform() < 0.5 {
                    [t[0], t[2], t[1]]
                } else {
                    t
                });
            }
        }
    }
    (points, normals, triangles)
}

#[test]
fn mesh_and_input_sources_orient_outward() {
    let (points, truth, triangles) = torus_mesh(120, 48);
    let cloud = PointCloud {
        points: points.clone(),
        normals: None,
        triangles,
        range: None,
        ..Default::default()
    };
    let out = estimate_normals(&cloud, &NormalsParams::default()).unwrap();
    assert_eq!(out.source_used, NormalSource::Mesh);
    let (mean, outward) = score(&truth, &out.cloud.normals);
    println!(
        "torus mesh: mean {mean:.3}°, outward {outward}, {:?}",
        out.warnings
    );
    assert!(mean < 1.0);
    assert_eq!(outward, 1.0);

    let s = torus(4000, 51);
    let inward: Vec<[f64; 3]> = s
        .normals
        .iter()
        .map(|n| [-3.0 * n[0], -3.0 * n[1], -3.0 * n[2]])
        .collect();
    let cloud = PointCloud {
        points: s.points.clone(),
        normals: Some(inward),
        triangles: Vec::new(),
        range: None,
        ..Default::default()
    };
    let out = estimate_normals(&cloud, &NormalsParams::default()).unwrap();
    assert_eq!(out.source_used, NormalSource::Input);
    let (mean, outward) = score(&s.normals, &out.cloud.normals);
    assert!(mean < 1e-6);
    assert_eq!(outward, 1.0);
    assert!(!out.warnings.is_empty());
}

#[test]
fn normals_do_not_depend_on_thread_count() {
    let s = torus(3000, 61);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let a = one.install(|| run(&s.points, NormalSource::Crust));
    let b = run(&s.points, NormalSource::Crust);
    assert_eq!(a.cloud, b.cloud);
    assert_eq!(a.crust_triangles, b.crust_triangles);
}

// ---------------------------------------------------------------- real data

/// A minimal reader for the test files' PLY layouts (x y z first, then a face list of
/// `uchar count, int indices`), binary little endian or ASCII.
fn read_ply(path: &std::path::Path) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
    let bytes = std::fs::read(path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    let mut n_vertices = 0;
    let mut n_faces = 0;
    let mut vertex_props = 0;
    let mut in_vertex = false;
    for line in header.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["element", "vertex", n] => {
                n_vertices = n.parse().unwrap();
                in_vertex = true;
            }
            ["element", "face", n] => {
                n_faces = n.parse().unwrap();
                in_vertex = false;
            }
            ["property", _, _] if in_vertex => vertex_props += 1,
            _ => {}
        }
    }
    let mut points = Vec::with_capacity(n_vertices);
    let mut faces = Vec::with_capacity(n_faces);
    if header.contains("binary_little_endian") {
        assert_eq!(vertex_props, 3);
        let mut at = end;
        let f32_at = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as f64;
        for _ in 0..n_vertices {
            points.push([f32_at(at), f32_at(at + 4), f32_at(at + 8)]);
            at += 12;
        }
        let i32_at = |at: usize| i32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as u32;
        for _ in 0..n_faces {
            let count = bytes[at] as usize;
            let idx: Vec<u32> = (0..count).map(|k| i32_at(at + 1 + 4 * k)).collect();
            at += 1 + 4 * count;
            for k in 1..count - 1 {
                faces.push([idx[0], idx[k], idx[k + 1]]);
            }
        }
    } else {
        let body = std::str::from_utf8(&bytes[end..]).unwrap();
        let mut lines = body.lines();
        for _ in 0..n_vertices {
            let v: Vec<f64> = lines
                .next()
                .unwrap()
                .split_whitespace()
                .map(|x| x.parse().unwrap())
                .collect();
            points.push([v[0], v[1], v[2]]);
        }
        for _ in 0..n_faces {
            let v: Vec<u32> = lines
                .next()
                .unwrap()
                .split_whitespace()
                .map(|x| x.parse().unwrap())
                .collect();
            for k in 2..v[0] as usize {
                faces.push([v[1], v[k], v[k + 1]]);
            }
        }
    }
    (points, faces)
}

/// Area-weighted vertex normals of a mesh in its own winding.
fn mesh_vertex_normals(points: &[[f64; 3]], faces: &[[u32; 3]]) -> Vec<[f64; 3]> {
    let mut sums = vec![[0.0; 3]; points.len()];
    for f in faces {
        let [a, b, c] = f.map(|v| points[v as usize]);
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        for &k in f {
            for a in 0..3 {
                sums[k as usize][a] += n[a];
            }
        }
    }
    sums
}

#[test]
fn real_scans_agree_with_their_meshes() {
    for (file, min_agree) in [
        ("duck.ply", 0.99),
        ("patella_vhf_left.ply", 0.99),
        ("fertility.ply", 0.99),
        ("bunny_zipper.ply", 0.99),
    ] {
        let Some(path) = shared(&format!("data/{file}"), "the mesh sign check") else {
            continue;
        };
        let (points, faces) = read_ply(&path);
        let mut reference = mesh_vertex_normals(&points, &faces);
        // The sign of the enclosed volume says whether the file winds its faces outward.
        // Measured from the centroid so that holes (the bunny's base) change it little.
        let n = points.len() as f64;
        let centre = [0, 1, 2].map(|a| points.iter().map(|p| p[a]).sum::<f64>() / n);
        let signed_volume: f64 = faces
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|v| {
                    let p = points[v as usize];
                    [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]]
                });
                a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0])
            })
            .sum();
        if signed_volume < 0.0 {
            println!(
                "{file}: faces wound inward (signed volume {:e}); reference normals negated",
                signed_volume / 6.0
            );
            reference
                .iter_mut()
                .for_each(|r| *r = [-r[0], -r[1], -r[2]]);
        }
        let out = run(&points, NormalSource::Crust);
        let mut counted = 0;
        let mut agree = 0;
        for (r, n) in reference.iter().zip(&out.cloud.normals) {
            if dot(r, r) == 0.0 {
                continue; // a vertex without faces has no reference normal
            }
            counted += 1;
            if dot(r, n) > 0.0 {
                agree += 1;
            }
        }
        let fraction = agree as f64 / counted as f64;
        println!(
            "{file}: {} points, sign agreement {fraction:.4}, {:?}",
            points.len(),
            out.warnings
        );
        assert!(
            fraction >= min_agree,
            "{file}: only {fraction} of the normals agree with the mesh"
        );
    }
}

/// The six faces of the box [0, a] × [0, b] × [0, c], each sampled on an n × n grid (cell
/// centres), with exact outward normals.
fn box_surface(size: [f64; 3], n: usize) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut points = Vec::new();
    let mut normals = Vec::new();
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in [0.0, 1.0] {
            for i in 0..n {
                for j in 0..n {
                    let mut p = [0.0; 3];
                    p[axis] = side * size[axis];
                    p[u] = (i as f64 + 0.5) / n as f64 * size[u];
                    p[v] = (j as f64 + 0.5) / n as f64 * size[v];
                    let mut nrm = [0.0; 3];
                    nrm[axis] = if side == 0.0 { -1.0 } else { 1.0 };
                    points.push(p);
                    normals.push(nrm);
                }
            }
        }
    }
    (points, normals)
}

#[test]
fn correct_input_normals_of_a_thin_plate_are_kept() {
    // A plate 2 × 2 × 0.1, sampled every 0.05: each point's 16 nearest neighbours reach across
    // to the other side, where the normals rightly point the other way, and round the sharp
    // edges. The normals are right and must come out unchanged.
    let (points, normals) = box_surface([2.0, 2.0, 0.1], 40);
    let cloud = PointCloud {
        points,
        normals: Some(normals.clone()),
        ..Default::default()
    };
    let params = NormalsParams {
        source: NormalSource::Input,
        ..Default::default()
    };
    let out = estimate_normals(&cloud, &params).unwrap();
    let changed = normals
        .iter()
        .zip(&out.cloud.normals)
        .filter(|(a, b)| dot(a, b) < 0.999)
        .count();
    assert_eq!(changed, 0, "{:?}", out.warnings);
}

#[test]
fn large_faces_get_surface_samples_with_their_normals() {
    // A box 1 × 1 × 10 of 12 triangles on its 8 corners: a model whose faces hold no vertex.
    // The median edge is √2 (the end squares' diagonals); the long faces' triangles (area 5,
    // longest edge √101) would get 6 samples each, the end squares' none; the cap of 4 samples
    // per point (32) leaves 4 each. The samples must lie on the box's faces with the faces'
    // outward normals.
    let size = [1.0, 1.0, 10.0];
    let points: Vec<[f64; 3]> = (0..8)
        .map(|i| [0, 1, 2].map(|a| ((i >> a) & 1) as f64 * size[a]))
        .collect();
    let quads = [
        [0, 2, 6, 4],
        [1, 5, 7, 3],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 1, 3, 2],
        [4, 6, 7, 5],
    ];
    let triangles: Vec<[u32; 3]> = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    let cloud = PointCloud {
        points: points.clone(),
        triangles,
        ..Default::default()
    };
    let out = estimate_normals(&cloud, &NormalsParams::default()).unwrap();
    assert_eq!(out.surface_samples, 8 * 4);
    assert_eq!(out.cloud.points.len(), 8 + out.surface_samples);
    assert_eq!(&out.cloud.points[..8], &points[..]);
    for (p, n) in out.cloud.points.iter().zip(&out.cloud.normals).skip(8) {
        // On a long face: x or y is 0 or 1 (to rounding), the normal is that face's.
        let on = (0..2)
            .find(|&a| p[a].abs() < 1e-12 || (p[a] - 1.0).abs() < 1e-12)
            .unwrap_or_else(|| panic!("{p:?} is not on a long face"));
        let mut want = [0.0; 3];
        want[on] = if p[on] < 0.5 { -1.0 } else { 1.0 };
        assert!(dot(n, &want) > 1.0 - 1e-12, "{p:?}: {n:?}");
        assert!((0..3).all(|a| (-1e-12..=size[a] + 1e-12).contains(&p[a])));
    }
    // Off: the vertices only.
    let params = NormalsParams {
        surface_samples: false,
        ..Default::default()
    };
    let out = estimate_normals(&cloud, &params).unwrap();
    assert_eq!((out.surface_samples, out.cloud.points.len()), (0, 8));
}

/// p ↦ R(q)ᵀ·p + t for the unit quaternion q = (qx, qy, qz, qw), and n ↦ R(q)ᵀ·n: the
/// convention of Stanford's `bun.conf` (see ../shared/data/SOURCES.md).
fn conf_pose(t: [f64; 3], q: [f64; 4]) -> impl Fn([f64; 3], bool) -> [f64; 3] {
    let r = quaternion_rotation(q[3], q[0], q[1], q[2]);
    move |p: [f64; 3], is_point: bool| {
        let mut out = [0, 1, 2].map(|i| (0..3).map(|k| r[k][i] * p[k]).sum::<f64>());
        if is_point {
            out = [0, 1, 2].map(|i| out[i] + t[i]);
        }
        out
    }
}

/// The six registered raw scans of the bunny: their range grids' normals (`--normals auto`),
/// moved into the common frame with their `bun.conf` poses, agree in sign with the outward
/// area-weighted vertex normals of the zippered bunny (the nearest vertex) on ≥ 98% of points.
#[test]
fn range_scans_face_out_of_the_zippered_bunny() {
    let Some(scan_dir) = shared("data/bunny-scans", "the range-scan normal check") else {
        return;
    };
    let (zp, zf) = read_ply(&scan_dir.parent().unwrap().join("bunny_zipper.ply"));
    let mut reference = mesh_vertex_normals(&zp, &zf);
    let n = zp.len() as f64;
    let centre = [0, 1, 2].map(|a| zp.iter().map(|p| p[a]).sum::<f64>() / n);
    let volume: f64 = zf
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|v| {
                let p = zp[v as usize];
                [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]]
            });
            a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0])
        })
        .sum();
    if volume < 0.0 {
        reference.iter_mut().for_each(|r| *r = r.map(|c| -c));
    }
    // Only vertices that faces use have a reference normal.
    let used: Vec<usize> = (0..zp.len())
        .filter(|&i| dot(&reference[i], &reference[i]) > 0.0)
        .collect();
    let tree =
        stablesurf::point_tree::PointTree::new(&used.iter().map(|&i| zp[i]).collect::<Vec<_>>())
            .unwrap();
    let conf = std::fs::read_to_string(scan_dir.join("bun.conf")).unwrap();
    let mut scans = 0;
    for line in conf.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        if w.first() != Some(&"bmesh") {
            continue;
        }
        let v: Vec<f64> = w[2..9].iter().map(|x| x.parse().unwrap()).collect();
        let pose = conf_pose([v[0], v[1], v[2]], [v[3], v[4], v[5], v[6]]);
        let path = scan_dir.join(w[1]);
        let bytes = std::fs::read(&path).unwrap();
        let cloud = stablesurf::import::import_bytes(&bytes, &path).unwrap();
        let range = cloud.range.as_ref().expect("a range grid");
        let sensor = range.sensor.expect("a sensor estimate");
        // The Cyberware scanner sits about 1.2–1.6 m in front of the scan along +z.
        assert!(
            sensor[1].abs() < 0.3 && (1.0..1.8).contains(&sensor[2]),
            "{}: sensor {sensor:?}",
            w[1]
        );
        let out = estimate_normals(&cloud, &NormalsParams::default()).unwrap();
        assert_eq!(out.source_used, NormalSource::Mesh);
        let weights = out.cloud.weights.as_ref().expect("range confidence");
        assert!(weights.iter().all(|&x| x > 0.0 && x <= 1.0));
        let (mut agree, mut near, mut agree_near) = (0usize, 0usize, 0usize);
        for (p, nrm) in out.cloud.points.iter().zip(&out.cloud.normals) {
            let (q, m) = (pose(*p, true), pose(*nrm, false));
            let (d2, j) = tree.nearest(q);
            let ok = dot(&m, &reference[used[j]]) > 0.0;
            agree += usize::from(ok);
            // Within 2 mm of the zippered surface (its bbox diagonal is 0.25 m).
            if d2 < 2e-3 * 2e-3 {
                near += 1;
                agree_near += usize::from(ok);
            }
        }
        let total = out.cloud.points.len();
        let fraction = agree as f64 / total as f64;
        println!(
            "{}: {total} points, sign agreement {fraction:.4} (within 2 mm: {near} points, {:.4}), sensor {sensor:?}",
            w[1],
            agree_near as f64 / near.max(1) as f64
        );
        assert!(fraction >= 0.98, "{}: agreement {fraction}", w[1]);
        scans += 1;
    }
    assert_eq!(scans, 6);
}

#[test]
fn flipped_input_normals_are_found_by_the_sampled_check() {
    // 300,000 points: the sign check looks at a sample of 20,000 and their neighbours among
    // every second point. With every 20th normal flipped (5% of the points, about 10% of the
    // pairs on one sheet) the sample must see the conflicts and the normals must come out
    // consistent and outward; unflipped, they must come out unchanged; all flipped (inward),
    // the vote of the checked points must turn them all out.
    let s = sphere(300_000, 77);
    let flipped: Vec<[f64; 3]> = s
        .normals
        .iter()
        .enumerate()
        .map(|(i, n)| if i % 20 == 0 { n.map(|c| -c) } else { *n })
        .collect();
    let params = NormalsParams {
        source: NormalSource::Input,
        ..Default::default()
    };
    let inward: Vec<[f64; 3]> = s.normals.iter().map(|n| n.map(|c| -c)).collect();
    for (given, must_warn) in [(flipped, true), (s.normals.clone(), false), (inward, true)] {
        let cloud = PointCloud {
            points: s.points.clone(),
            normals: Some(given),
            ..Default::default()
        };
        let out = estimate_normals(&cloud, &params).unwrap();
        let (mean, outward) = score(&s.normals, &out.cloud.normals);
        assert_eq!(outward, 1.0, "{:?}", out.warnings);
        assert!(mean < 1e-6, "{mean}");
        assert_eq!(!out.warnings.is_empty(), must_warn, "{:?}", out.warnings);
    }
}
