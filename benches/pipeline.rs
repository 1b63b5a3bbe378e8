//! End-to-end benchmark: import → normals → fit → polygonize → checks with a cold (disabled)
//! cache, on the Stanford bunny from ../shared/data when present, else on the built-in sample.
//! Prints the per-stage breakdown of one run before the criterion measurement. Cases: global mode
//! without files, global with glb+ply+json, and detail mode with every output (the defaults of
//! `stablesurf run --mode detail`, `PipelineConfig::for_mode`: depth 7, no topology guard, the
//! pieces near the data kept and trimmed, mesh-distance slices).
//!
//! Run: `cargo bench --bench pipeline`.

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use stablesurf::cache::Cache;
use stablesurf::export::ExportParams;
use stablesurf::pipeline::{self, Mode, OutputFormat, PipelineConfig, ScanSource, Silent};

fn source() -> (ScanSource, &'static str) {
    let bunny = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/bunny_zipper.ply");
    if bunny.exists() {
        (ScanSource::File(bunny), "bunny")
    } else {
        (ScanSource::Sample, "sample")
    }
}

fn bench(c: &mut Criterion) {
    let (source, name) = source();
    let out = tempfile::tempdir().unwrap();
    let global = PipelineConfig::for_mode(Mode::Global);
    let detail = PipelineConfig::for_mode(Mode::Detail);
    for (label, config) in [
        (
            "no files",
            PipelineConfig {
                export: ExportParams {
                    formats: vec![],
                    ..global.export.clone()
                },
                ..global.clone()
            },
        ),
        (
            "glb+ply+json",
            PipelineConfig {
                export: ExportParams {
                    formats: vec![OutputFormat::Glb, OutputFormat::Ply, OutputFormat::Json],
                    ..global.export.clone()
                },
                ..global.clone()
            },
        ),
        ("detail, all outputs", detail),
    ] {
        let report = pipeline::run(
            &source,
            out.path(),
            &config,
            &Cache::disabled(),
            &mut Silent,
        )
        .unwrap();
        eprintln!("{name}, {label}: {:.3} s in all", report.seconds);
        for s in &report.stages {
            eprintln!("  {:<10} {:>8.3} s  {}", s.stage, s.seconds, s.figures);
        }
        let mut group = c.benchmark_group("pipeline");
        group.sample_size(10);
        group.bench_function(format!("{name}/cold/{label}"), |b| {
            b.iter(|| {
                pipeline::run(
                    &source,
                    out.path(),
                    &config,
                    &Cache::disabled(),
                    &mut Silent,
                )
                .unwrap()
            })
        });
        group.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
