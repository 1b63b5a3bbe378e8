//! Criterion benchmarks of the `normals` stage: crust normals of the 36k-point Stanford bunny
//! (faces dropped) and of 10k, 50k and 200k random samples of a torus (time versus N), plus the
//! Delaunay tetrahedralization and the `pca` source alone.
//!
//! Run: `cargo bench --bench normals`. The bunny case is skipped when ../shared/data is absent.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use stablesurf::normals::delaunay::tetrahedralize;
use stablesurf::normals::{estimate_normals, NormalSource, NormalsParams};
use stablesurf::PointCloud;

/// Random points on a torus (R = 1, r = 0.4), uniform in area (rejection on θ), reproducible.
fn torus(n: usize) -> Vec<[f64; 3]> {
    let (big, small) = (1.0, 0.4);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut uniform = move || {
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut points = Vec::with_capacity(n);
    while points.len() < n {
        let (phi, theta) = (
            std::f64::consts::TAU * uniform(),
            std::f64::consts::TAU * uniform(),
        );
        if uniform() * (big + small) > big + small * theta.cos() {
            continue;
        }
        let rho = big + small * theta.cos();
        points.push([rho * phi.cos(), rho * phi.sin(), small * theta.sin()]);
    }
    points
}

/// x y z of the ASCII bunny (the first three numbers of each vertex line).
fn bunny() -> Option<Vec<[f64; 3]>> {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../shared/data/bunny_zipper.ply"
    );
    let text = std::fs::read_to_string(path).ok()?;
    let (header, body) = text.split_once("end_header\n")?;
    let n: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))?
        .trim()
        .parse()
        .ok()?;
    body.lines()
        .take(n)
        .map(|l| {
            let v: Vec<f64> = l
                .split_whitespace()
                .take(3)
                .filter_map(|x| x.parse().ok())
                .collect();
            (v.len() == 3).then(|| [v[0], v[1], v[2]])
        })
        .collect()
}

fn crust_params() -> NormalsParams {
    NormalsParams {
        source: NormalSource::Crust,
        ..Default::default()
    }
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("normals");
    group.sample_size(10);
    if let Some(points) = bunny() {
        let cloud = PointCloud {
            points,
            ..Default::default()
        };
        group.bench_function("crust/bunny_35947", |b| {
            b.iter(|| estimate_normals(black_box(&cloud), &crust_params()).unwrap())
        });
    } else {
        eprintln!("bunny_zipper.ply not found: skipping the bunny bench");
    }
    for n in [10_000, 50_000, 200_000] {
        let cloud = PointCloud {
            points: torus(n),
            ..Default::default()
        };
        group.bench_with_input(BenchmarkId::new("crust/torus", n), &cloud, |b, cloud| {
            b.iter(|| estimate_normals(black_box(cloud), &crust_params()).unwrap())
        });
        group.bench_with_input(
            BenchmarkId::new("delaunay/torus", n),
            &cloud.points,
            |b, points| b.iter(|| tetrahedralize(black_box(points)).unwrap()),
        );
        let pca = NormalsParams {
            source: NormalSource::Pca,
            ..Default::default()
        };
        group.bench_with_input(BenchmarkId::new("pca/torus", n), &cloud, |b, cloud| {
            b.iter(|| estimate_normals(black_box(cloud), &pca).unwrap())
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
