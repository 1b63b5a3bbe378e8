//! Export throughput: writing a 1M-triangle mesh as .glb and as binary PLY.
//!
//! The mesh is a closed torus grid of 1000 × 500 vertices (500 000 vertices, 1 000 000
//! triangles), written to an in-memory buffer, so the figures are encoding cost without disk.
//! Run: `cargo bench --bench export`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use stablesurf::export::gltf::{write_glb, GltfOptions};
use stablesurf::export::ply::{self, PlyEncoding, PlyOptions};
use stablesurf::TriangleMesh;

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
        };
        b.iter(|| {
            buf.clear();
            ply::write(black_box(&mesh), &mut buf, &opts).unwrap();
            black_box(buf.len())
        })
    });
    group.finish();
}

criterion_group!(benches, bench_export);
criterion_main!(benches);
