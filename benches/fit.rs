//! Criterion benches of the `fit` stage: a bunny-size cloud (36k points) at degrees 4, 8, 12 and
//! 1M points at degree 8 (synthetic heart samples with exact normals), fixed κ = 1e-3, plus the
//! automatic-κ fit of the bunny-size cloud at degree 8. Peak resident memory (VmHWM) is printed
//! at the end.

use criterion::{criterion_group, Criterion};
use stablesurf::fit::{fit, FitParams, Kappa};
use stablesurf::testing::study::{sample, Shape, Variant};
use stablesurf::OrientedCloud;

#[path = "../tools/proc_time.rs"]
mod proc_time;
use proc_time::cpu_seconds;

/// Repeats a sample with small deterministic jitter to reach `n` points.
fn cloud_of(n: usize) -> OrientedCloud {
    let base = sample(Shape::Heart, Variant::Clean, 36_000.min(n), 1);
    let mut cloud = OrientedCloud::default();
    let mut k = 0usize;
    while cloud.points.len() < n {
        let i = k % base.points.len();
        let jitter = 1e-4 * ((k / base.points.len()) as f64);
        let p = base.points[i];
        cloud.points.push([p[0] + jitter, p[1] - jitter, p[2]]);
        cloud.normals.push(base.normals[i]);
        k += 1;
    }
    cloud
}

fn bench_fit(c: &mut Criterion) {
    let bunny = cloud_of(36_000);
    let mut group = c.benchmark_group("fit");
    group.sample_size(10);
    for degree in [4, 8, 12] {
        let params = FitParams {
            degree,
            kappa: Kappa::Fixed(1e-3),
            ..FitParams::default()
        };
        group.bench_function(format!("points=36k/degree={degree}/kappa=1e-3"), |b| {
            b.iter(|| fit(&bunny, &params).unwrap())
        });
    }
    let auto = FitParams {
        degree: 8,
        ..FitParams::default()
    };
    group.bench_function("points=36k/degree=8/kappa=auto", |b| {
        b.iter(|| fit(&bunny, &auto).unwrap())
    });
    let million = cloud_of(1_000_000);
    let params = FitParams {
        degree: 8,
        kappa: Kappa::Fixed(1e-3),
        ..FitParams::default()
    };
    group.bench_function("points=1M/degree=8/kappa=1e-3", |b| {
        b.iter(|| fit(&million, &params).unwrap())
    });
    group.finish();
}

criterion_group!(benches, bench_fit);

/// `FIT_PHASES=1 cargo bench --bench fit`: wall time of the phases of the 1M-point fit.
fn phases() {
    let million = cloud_of(1_000_000);
    let params = FitParams {
        degree: 8,
        kappa: Kappa::Fixed(1e-3),
        ..FitParams::default()
    };
    for _ in 0..3 {
        let t = std::time::Instant::now();
        let cpu0 = cpu_seconds();
        let summary = stablesurf::fit::system_summary(&million, 8, 0.05).unwrap();
        let t_system = t.elapsed();
        let cpu_system = cpu_seconds() - cpu0;
        let cpu0 = cpu_seconds();
        let t = std::time::Instant::now();
        let model = fit(&million, &params).unwrap();
        let t_fit = t.elapsed();
        let cpu_fit = cpu_seconds() - cpu0;
        let t = std::time::Instant::now();
        let mut values = vec![0.0; million.points.len()];
        let mut gradients = vec![[0.0; 3]; million.points.len()];
        model
            .polynomial
            .eval_gradient_many(&million.points, &mut values, &mut gradients);
        let t_eval = t.elapsed();
        eprintln!(
            "1M points, degree 8: normalization + moments {t_system:.3?} ({cpu_system:.2} CPU-s), whole fit {t_fit:.3?} ({cpu_fit:.2} CPU-s), value+gradient at all points (1 thread) {t_eval:.3?} (beta0 {})",
            summary.beta[0]
        );
    }
}

fn main() {
    if std::env::var_os("FIT_PHASES").is_some() {
        phases();
        return;
    }
    benches();
    Criterion::default().configure_from_args().final_summary();
    if let Ok(status) = std::fs::read_to_string("/proc/self/status") {
        for line in status
            .lines()
            .filter(|l| l.starts_with("VmHWM") || l.starts_with("VmRSS"))
        {
            eprintln!("{line}");
        }
    }
}
