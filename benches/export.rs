//! Export throughput: writing a 1M-triangle mesh as .glb and as binary PLY, computing
//! distance slices, and the report's exact self-intersection count.
//!
//! The mesh is a closed torus grid of 1000 × 500 vertices (500 000 vertices, 1 000 000
//! triangles), written to an in-memory buffer, so the figures are encoding cost without disk.
//! The slices are 4 slices of 128 × 128 pixels (65 536 distances) of a degree-4 torus
//! polynomial, by each distance method (`mesh` measures against the torus polygonized at depth
//! 7, as the detail mode does). The pipeline's export stage on the bunny is measured end to end
//! with `stablesurf run … -v` (see the final report of the export-speed branch).
//! Run: `cargo bench --bench export`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use stablesurf::cloud::Aabb;
use stablesurf::distance::{slices, slices_from_mesh, DistanceMethod, SliceParams};
use stablesurf::export::gltf::{write_glb, GltfOptions};
use stablesurf::export::ply::{self, PlyEncoding, PlyOptions};
use stablesurf::mesh::self_intersecting_faces;
use stablesurf::poly::{monomial_index, n_coefficients};
use stablesurf::{ImplicitPolynomial, TriangleMesh};

fn torus_mesh(n_u: usize, n_v: usize) -> TriangleMesh {
    let (big, small) = (1.0, 0.3);
    let mut mesh = TriangleMesh::default();
    for i in 0..n_u {
        let u = i as f64 / n_u as f64 * std::f64::consts::TAU;
        for j in 0..n_v {
            let v = j as f64 / n_v as f64 * std::f64::consts::TAU;
            let rho = big + small * v.cos();
            mesh.positions
                .push([rho * u.cos(), rho * u.sin(), small * v.sin()]);
            mesh.normals
                .push([v.cos() * u.cos(), v.cos() * u.sin(), v.sin()]);
        }
    }
    let id = |i: usize, j: usize| ((i % n_u) * n_v + (j % n_v)) as u32;
    for i in 0..n_u {
        for j in 0..n_v {
            mesh.triangles
                .push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            mesh.triangles
                .push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    mesh
}

fn bench_export(c: &mut Criterion) {
    let mesh = torus_mesh(1000, 500);
    let n_triangles = mesh.triangles.len();
    let quality: Vec<f32> = (0..mesh.positions.len()).map(|i| i as f32 * 1e-6).collect();
    let mut group = c.benchmark_group("export");
    group.sample_size(10);
    group.throughput(Throughput::Elements(n_triangles as u64));
    let mut buf = Vec::with_capacity(64 << 20);
    group.bench_function(format!("glb/tris={n_triangles}"), |b| {
        b.iter(|| {
            buf.clear();
            write_glb(black_box(&mesh), &mut buf, &GltfOptions::default()).unwrap();
            black_box(buf.len())
        })
    });
    group.bench_function(format!("ply_binary/tris={n_triangles}"), |b| {
        b.iter(|| {
            buf.clear();
            ply::write(black_box(&mesh), &mut buf, &PlyOptions::default()).unwrap();
            black_box(buf.len())
        })
    });
    group.bench_function(format!("ply_binary_quality/tris={n_triangles}"), |b| {
        let opts = PlyOptions {
            encoding: PlyEncoding::BinaryLittleEndian,
            quality: Some(&quality),
            units: None,
            colours: None,
            up: None,
        };
        b.iter(|| {
            buf.clear();
            ply::write(black_box(&mesh), &mut buf, &opts).unwrap();
            black_box(buf.len())
        })
    });
    group.finish();
}

/// (x² + y² + z² + R² − r²)² − 4R²(x² + y²) with R = 1, r = 0.4.
fn torus_polynomial() -> ImplicitPolynomial {
    let (big, small) = (1.0f64, 0.4f64);
    let k = big * big - small * small;
    let mut c = vec![0.0; n_coefficients(4)];
    let terms: [([u32; 3], f64); 10] = [
        ([4, 0, 0], 1.0),
        ([0, 4, 0], 1.0),
        ([0, 0, 4], 1.0),
        ([2, 2, 0], 2.0),
        ([2, 0, 2], 2.0),
        ([0, 2, 2], 2.0),
        ([2, 0, 0], 2.0 * k - 4.0 * big * big),
        ([0, 2, 0], 2.0 * k - 4.0 * big * big),
        ([0, 0, 2], 2.0 * k),
        ([0, 0, 0], k * k),
    ];
    for (e, a) in terms {
        c[monomial_index(e)] += a;
    }
    ImplicitPolynomial {
        degree: 4,
        coefficients: c,
        center: [0.0; 3],
        scale: 1.0,
    }
}

/// The box around [`torus_polynomial`]'s zero set that the slices and the meshing cover.
const TORUS_REGION: Aabb = Aabb {
    min: [-1.6, -1.6, -0.6],
    max: [1.6, 1.6, 0.6],
};

/// [`torus_polynomial`] polygonized over [`TORUS_REGION`] at `depth`.
fn polygonized_torus(depth: u32) -> TriangleMesh {
    stablesurf::polygonize::polygonize(
        &torus_polynomial(),
        &TORUS_REGION,
        &stablesurf::polygonize::PolygonizeParams {
            depth,
            ..Default::default()
        },
    )
    .unwrap()
    .mesh
}

fn bench_slices(c: &mut Criterion) {
    let poly = torus_polynomial();
    let region = TORUS_REGION;
    let mut group = c.benchmark_group("slices");
    group.sample_size(10);
    group.throughput(Throughput::Elements(4 * 128 * 128));
    for method in [DistanceMethod::Taubin, DistanceMethod::Exact] {
        let params = SliceParams {
            count: 4,
            resolution: 128,
            method,
            ..Default::default()
        };
        group.bench_function(format!("{}/px=65536", method.name()), |b| {
            b.iter(|| slices(black_box(&poly), &region, &params).unwrap())
        });
    }
    let mesh = polygonized_torus(7);
    let params = SliceParams {
        count: 4,
        resolution: 128,
        method: DistanceMethod::Mesh,
        ..Default::default()
    };
    group.bench_function("mesh/px=65536", |b| {
        b.iter(|| slices_from_mesh(black_box(&poly), &mesh, &region, &params).unwrap())
    });
    group.finish();
}

/// The report's exact self-intersection count on the torus polygonized at depth 8 (450,814
/// triangles).
fn bench_mesh_check(c: &mut Criterion) {
    let mesh = polygonized_torus(8);
    let n_triangles = mesh.triangles.len();
    let mut group = c.benchmark_group("mesh_check");
    group.sample_size(10);
    group.throughput(Throughput::Elements(n_triangles as u64));
    group.bench_function(format!("self_intersections/tris={n_triangles}"), |b| {
        b.iter(|| self_intersecting_faces(black_box(&mesh)))
    });
    group.finish();
}

criterion_group!(benches, bench_export, bench_slices, bench_mesh_check);
criterion_main!(benches);
