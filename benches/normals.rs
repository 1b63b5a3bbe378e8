//! Criterion benchmarks of the `normals` stage: crust normals of the 36k-point Stanford bunny
//! (faces dropped) and of 10k, 50k and 200k random samples of a torus (time versus N), plus the
//! Delaunay tetrahedralization alone.
//!
//! Run: `cargo bench --bench normals`. The bunny case is skipped when ../shared/data is absent.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use stablesurf::normals::delaunay::tetrahedralize;
use stablesurf::normals::{estimate_normals, NormalSource, NormalsParams};
use stablesurf::PointCloud;

fn torus(n: usize) -> Vec<[f64; 3]> {
    // A low-discrepancy (golden-ratio) sampling, area-weighted by rejection on θ.
    let (big, small) = (1.0, 0.4);
    let mut points = Vec::with_capacity(n);
    let mut k = 0u64;
    while points.len() < n {
        k += 1;
        let u = (k as f64 * 0.754_877_666_246_692_7).fract();
        let v = (k as f64 * 0.569_840_290_998_053_3).fract();
        let w = (k as f64 * 0.618_033_988_749_894_8).fract();
        let (phi, theta) = (std::f64::consts::TAU * u, std::f64::consts::TAU * v);
        if w * (big + small) > big + small * theta.cos() {
            continue;
        }
        let rho = big + small * theta.cos();
        points.push([rho * phi.cos(), rho * phi.sin(), small * theta.sin()]);
    }
    points
}

/// x y z of the ASCII bunny (the first three numbers of each vertex line).
fn bunny() -> Option<Vec<[f64; 3]>> {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/bunny_zipper.ply");
    let text = std::fs::read_to_string(path).ok()?;
    let (header, body) = text.split_once("end_header\n")?;
    let n: usize = header.lines().find_map(|l| l.strip_prefix("element vertex "))?.trim().parse().ok()?;
    body.lines()
        .take(n)
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().take(3).filter_map(|x| x.parse().ok()).collect();
            (v.len() == 3).then(|| [v[0], v[1], v[2]])
        })
        .collect()
}

fn crust_params() -> NormalsParams {
    NormalsParams { source: NormalSource::Crust, ..Default::default() }
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("normals");
    group.sample_size(10);
    if let Some(points) = bunny() {
        let cloud = PointCloud { points, ..Default::default() };
        group.bench_function("crust/bunny_35947", |b| b.iter(|| estimate_normals(black_box(&cloud), &crust_params()).unwrap()));
    } else {
        eprintln!("bunny_zipper.ply not found: skipping the bunny bench");
    }
    for n in [10_000, 50_000, 200_000] {
        let cloud = PointCloud { points: torus(n), ..Default::default() };
        group.bench_with_input(BenchmarkId::new("crust/torus", n), &cloud, |b, cloud| {
            b.iter(|| estimate_normals(black_box(cloud), &crust_params()).unwrap())
        });
        group.bench_with_input(BenchmarkId::new("delaunay/torus", n), &cloud.points, |b, points| {
            b.iter(|| tetrahedralize(black_box(points)).unwrap())
        });
        let pca = NormalsParams { source: NormalSource::Pca, ..Default::default() };
        group.bench_with_input(BenchmarkId::new("pca/torus", n), &cloud, |b, cloud| {
            b.iter(|| estimate_normals(black_box(cloud), &pca).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
