//! Criterion benchmarks of the `normals` stage: crust normals of the 36k-point Stanford bunny
//! (faces dropped) and of 10k, 50k and 200k random samples of a torus (time versus N), plus the
//! Delaunay tetrahedralization and the `pca` source alone.
//!
//! Run: `cargo bench --bench normals`. The bunny case is skipped when ../shared/data is absent.
//! `NORMALS_PHASES=1 cargo bench --bench normals` prints instead the wall time of each phase of
//! the crust normals (both tetrahedralizations, poles, faces, fans, plane fits, orientation) for
//! the bunny and the torus samples, best of three runs each (`NORMALS_PHASES_SIZES=10000,50000`
//! and `NORMALS_PHASES_RUNS=1` change the torus sizes and the number of runs).

use std::hint::black_box;

use criterion::{criterion_group, BenchmarkId, Criterion};
use stablesurf::normals::{estimate_normals, NormalSource, NormalsParams};
use stablesurf::testing::{crust_normals, tetrahedralize};
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

/// CPU time of this process (user + system, all threads) from /proc/self/stat, in clock ticks of
/// 10 ms; zero where /proc is absent. Under load it shows the work done, where wall time also
/// counts the waiting.
fn cpu_time() -> std::time::Duration {
    let ticks = std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = s.rsplit_once(')')?.1.to_string();
            let f: Vec<u64> = rest
                .split_whitespace()
                .skip(11)
                .take(2)
                .filter_map(|x| x.parse().ok())
                .collect();
            (f.len() == 2).then(|| f[0] + f[1])
        })
        .unwrap_or(0);
    std::time::Duration::from_millis(10 * ticks)
}

/// Collects the phase times that the crust normals log at the `debug` level (their messages
/// read `crust normals phase NAME: T ms`).
struct PhaseLog(std::sync::Mutex<Vec<(String, std::time::Duration)>>);

impl log::Log for PhaseLog {
    fn enabled(&self, metadata: &log::Metadata<'_>) -> bool {
        metadata.target().starts_with("stablesurf::normals")
    }

    fn log(&self, record: &log::Record<'_>) {
        let message = record.args().to_string();
        let Some(rest) = message.strip_prefix("crust normals phase ") else {
            return;
        };
        let Some((phase, ms)) = rest.rsplit_once(": ") else {
            return;
        };
        let ms: f64 = ms.trim_end_matches(" ms").parse().unwrap_or(f64::NAN);
        if let (Ok(mut times), Ok(d)) = (
            self.0.lock(),
            std::time::Duration::try_from_secs_f64(ms / 1e3),
        ) {
            times.push((phase.to_string(), d));
        }
    }

    fn flush(&self) {}
}

static PHASE_LOG: PhaseLog = PhaseLog(std::sync::Mutex::new(Vec::new()));

/// Per-phase wall times of the crust normals, best of three runs (by total time).
fn phases() {
    if log::set_logger(&PHASE_LOG).is_ok() {
        log::set_max_level(log::LevelFilter::Debug);
    }
    let mut cases: Vec<(String, Vec<[f64; 3]>)> = Vec::new();
    if let Some(points) = bunny() {
        cases.push(("bunny".into(), points));
    }
    let sizes: Vec<usize> = std::env::var("NORMALS_PHASES_SIZES")
        .ok()
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![10_000, 50_000, 200_000]);
    for n in sizes {
        cases.push((format!("torus {n}"), torus(n)));
    }
    for (name, points) in cases {
        let mut best: Option<Vec<(String, std::time::Duration)>> = None;
        let runs: usize = std::env::var("NORMALS_PHASES_RUNS")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(3);
        for _ in 0..runs {
            PHASE_LOG.0.lock().unwrap().clear();
            let start = std::time::Instant::now();
            let cpu = cpu_time();
            crust_normals(&points, &crust_params()).unwrap();
            let mut times = std::mem::take(&mut *PHASE_LOG.0.lock().unwrap());
            times.push(("CPU time (all threads)".into(), cpu_time() - cpu));
            times.push(("TOTAL".into(), start.elapsed()));
            let total = |t: &Vec<(String, std::time::Duration)>| t.last().map(|x| x.1);
            if best.as_ref().is_none_or(|b| total(&times) < total(b)) {
                best = Some(times);
            }
        }
        println!("{name} ({} points):", points.len());
        for (phase, d) in best.unwrap_or_default() {
            println!("  {phase:<28} {:>9.1} ms", d.as_secs_f64() * 1e3);
        }
    }
}

criterion_group!(benches, bench);

fn main() {
    if std::env::var_os("NORMALS_PHASES").is_some() {
        phases();
        return;
    }
    benches();
    Criterion::default().configure_from_args().final_summary();
}
