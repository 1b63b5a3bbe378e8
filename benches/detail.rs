//! Detail mode benchmark: the Stanford bunny's detail fit + meshing (depth 7, no
//! topology-guard levels), with its Chamfer distance, and the growth with the number of points
//! (35k, 140k, 1M points sampled on the bunny's triangles), printed once before the criterion
//! measurement: wall time, CPU time (all threads, the steadier figure on a shared machine) and
//! the process's peak resident memory so far.
//!
//! Run: `cargo bench --bench detail`. Skips with a notice when ../shared/data is absent.

use std::path::Path;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion};
use stablesurf::detail::{chamfer_distance, fit_detail, DetailParams};
use stablesurf::normals::{estimate_normals, NormalSource, NormalsParams};
use stablesurf::pipeline::{Mode, PipelineConfig};
use stablesurf::polygonize::{polygonize, PolygonizeParams};
use stablesurf::OrientedCloud;

#[path = "../tools/proc_time.rs"]
mod proc_time;
use proc_time::cpu_seconds;

/// The meshing of `stablesurf run --mode detail` (depth 7, no topology-guard levels).
fn mesh_params() -> PolygonizeParams {
    PipelineConfig::for_mode(Mode::Detail).polygonize
}

/// Peak resident memory of the process so far, MB.
fn peak_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|v| v.parse::<f64>().ok())
        })
        .map_or(0.0, |kb| kb / 1024.0)
}

/// The bunny with normals from its faces, and its triangles.
fn bunny() -> Option<(OrientedCloud, Vec<[u32; 3]>)> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/bunny_zipper.ply");
    let bytes = std::fs::read(&path).ok()?;
    let cloud = stablesurf::import::import_bytes(&bytes, &path).ok()?;
    let params = NormalsParams {
        source: NormalSource::Mesh,
        ..Default::default()
    };
    let normals = estimate_normals(&cloud, &params).ok()?;
    Some((normals.cloud, cloud.triangles))
}

/// `n` points: the vertices, then points spread over the triangles in a fixed low-discrepancy
/// pattern, with interpolated vertex normals.
fn upsample(cloud: &OrientedCloud, triangles: &[[u32; 3]], n: usize) -> OrientedCloud {
    let mut out = cloud.clone();
    let mut k = 0usize;
    while out.points.len() < n && !triangles.is_empty() {
        let t = triangles[k % triangles.len()];
        let round = (k / triangles.len()) as f64;
        // An R2 sequence folded into the triangle.
        let (mut u, mut v) = (
            (0.5 + (round + 1.0) * 0.754_877_666) % 1.0,
            (0.5 + (round + 1.0) * 0.569_840_291) % 1.0,
        );
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        let w = 1.0 - u - v;
        let [a, b, c] = t.map(|i| i as usize);
        let p = [0, 1, 2]
            .map(|x| w * cloud.points[a][x] + u * cloud.points[b][x] + v * cloud.points[c][x]);
        let nv = [0, 1, 2]
            .map(|x| w * cloud.normals[a][x] + u * cloud.normals[b][x] + v * cloud.normals[c][x]);
        let len = (nv[0] * nv[0] + nv[1] * nv[1] + nv[2] * nv[2]).sqrt();
        if len > 1e-9 {
            out.points.push(p);
            out.normals.push(nv.map(|x| x / len));
        }
        k += 1;
    }
    out
}

fn bench(c: &mut Criterion) {
    let Some((cloud, triangles)) = bunny() else {
        eprintln!("skipping: ../shared/data/bunny_zipper.ply is absent");
        return;
    };
    let params = DetailParams::default();
    let meshing = mesh_params();
    for n in [cloud.points.len(), 140_000, 1_000_000] {
        let input = upsample(&cloud, &triangles, n);
        let (t0, c0) = (Instant::now(), cpu_seconds());
        let model = fit_detail(&input, &params).unwrap();
        let (t1, c1) = (Instant::now(), cpu_seconds());
        let out = polygonize(&model, &model.region, &meshing).unwrap();
        let (t2, c2) = (Instant::now(), cpu_seconds());
        let report = stablesurf::mesh::check(&out.mesh);
        let chamfer = chamfer_distance(&cloud.points, &out.mesh).unwrap_or_default();
        eprintln!(
            "{} points: fit {:.2} s wall / {:.2} s cpu, mesh {:.2} s wall / {:.2} s cpu, {} cells, {} faces, {} components, watertight {}, Chamfer to the bunny's vertices {:.3e} of the diagonal, peak RSS {:.0} MB",
            input.points.len(),
            (t1 - t0).as_secs_f64(),
            c1 - c0,
            (t2 - t1).as_secs_f64(),
            c2 - c1,
            model.cells.len(),
            report.faces,
            report.components,
            report.watertight,
            chamfer.symmetric / model.diagonal,
            peak_mb(),
        );
    }
    let mut group = c.benchmark_group("detail");
    group.sample_size(10);
    group.bench_function("bunny35k/fit+mesh depth 7", |b| {
        b.iter(|| {
            let model = fit_detail(&cloud, &params).unwrap();
            polygonize(&model, &model.region, &meshing).unwrap()
        })
    });
    group.bench_function("bunny35k/fit", |b| {
        b.iter(|| fit_detail(&cloud, &params).unwrap())
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
