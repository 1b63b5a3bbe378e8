//! Golden cases: each folder of `golden/` holds a small input (or names the built-in sample),
//! `params.json`, and `expected.txt` with the report's key figures at fixed precision. One
//! `check(case)` runs the pipeline and compares: counts and flags exactly, floats to a stated
//! relative tolerance. `UPDATE_GOLDEN=1 cargo test --test all golden` rewrites the expected files.

use std::fs;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use stablesurf::cache::Cache;
use stablesurf::export::ExportParams;
use stablesurf::pipeline::{self, OutputFormat, PipelineConfig, ScanSource, Setting, Silent};
use stablesurf::{fit, normals};

/// Relative tolerance for floating-point figures (they are computed deterministically; the
/// slack absorbs last-digit differences of libm between machines).
const REL_TOL: f64 = 1e-6;

fn golden_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("golden")
}

fn summary(case: &Path) -> String {
    let params: serde_json::Value =
        serde_json::from_slice(&fs::read(case.join("params.json")).unwrap()).unwrap();
    let source = if params["input"] == "sample" {
        ScanSource::Sample
    } else {
        let input = fs::read_dir(case)
            .unwrap()
            .map(|e| e.unwrap().path())
            .find(|p| p.file_stem().is_some_and(|s| s == "input"))
            .expect("input.* in the case folder");
        ScanSource::File(input)
    };
    let config = PipelineConfig {
        normals: normals::NormalsParams {
            source: normals::NormalSource::from_str(params["normals"].as_str().unwrap()).unwrap(),
            ..Default::default()
        },
        fit: fit::FitParams {
            degree: params["degree"].as_u64().unwrap() as u32,
            epsilon: params["epsilon"].as_f64().unwrap(),
            kappa: fit::Kappa::from_str(params["kappa"].as_str().unwrap()).unwrap(),
            ..Default::default()
        },
        depth: Setting::Fixed(params["depth"].as_u64().unwrap() as u32),
        export: ExportParams {
            formats: vec![OutputFormat::Json],
            ..Default::default()
        },
        ..Default::default()
    };
    let out = tempfile::tempdir().unwrap();
    let report = pipeline::run(
        &source,
        out.path(),
        &config,
        &Cache::disabled(),
        &mut Silent,
    )
    .unwrap_or_else(|e| panic!("{}: {e:#}", case.display()));
    let model: serde_json::Value =
        serde_json::from_slice(&fs::read(out.path().join("model.json")).unwrap()).unwrap();
    let coefficients: Vec<f64> = model["coefficients"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let fit = report.fit.to_json();
    let d = &fit["diagnostics"];
    let f = &fit["fit"];
    let figure = |v: &serde_json::Value| format!("{:.9e}", v.as_f64().unwrap_or(f64::NAN));
    let mut s = String::new();
    let mut line = |k: &str, v: String| s.push_str(&format!("{k} {v}\n"));
    line(
        "points",
        report.stages[0].figures.to_json()["points"].to_string(),
    );
    line(
        "normals",
        report.stages[1].figures.to_json()["source"].to_string(),
    );
    line("degree", model["degree"].to_string());
    line("kappa", figure(&f["kappa"]));
    line("bounded", d["bounded"].to_string());
    line(
        "leading_form_min_relative",
        figure(&d["leading_form_min_relative"]),
    );
    line(
        "coefficients_abs_sum",
        format!("{:.9e}", coefficients.iter().map(|c| c.abs()).sum::<f64>()),
    );
    line("coefficient_0", format!("{:.9e}", coefficients[0]));
    line(
        "fit_mean_distance_relative",
        figure(&d["mean_distance_relative"]),
    );
    line("mesh_vertices", report.mesh.vertices.to_string());
    line("mesh_faces", report.mesh.faces.to_string());
    line("components", report.mesh.components.to_string());
    line("boundary_edges", report.mesh.boundary_edges.to_string());
    line(
        "non_manifold_edges",
        report.mesh.non_manifold_edges.to_string(),
    );
    line(
        "euler_characteristic",
        report.mesh.euler_characteristic.to_string(),
    );
    line("watertight", report.mesh.watertight.to_string());
    line(
        "mesh_mean_distance_relative",
        format!("{:.9e}", report.accuracy.data_to_mesh.mean_relative),
    );
    s
}

fn same(expected: &str, actual: &str) -> bool {
    match (expected.parse::<f64>(), actual.parse::<f64>()) {
        (Ok(e), Ok(a)) if expected.contains('e') => {
            (e - a).abs() <= REL_TOL * e.abs().max(a.abs()) || (e.is_nan() && a.is_nan())
        }
        _ => expected == actual,
    }
}

fn check(case: &Path) -> Vec<String> {
    let actual = summary(case);
    let expected_path = case.join("expected.txt");
    if std::env::var_os("UPDATE_GOLDEN").is_some() {
        fs::write(&expected_path, &actual).unwrap();
        return Vec::new();
    }
    let expected = fs::read_to_string(&expected_path).unwrap_or_else(|_| {
        panic!(
            "{} missing: run UPDATE_GOLDEN=1 cargo test --test all golden",
            expected_path.display()
        )
    });
    let mut problems = Vec::new();
    let parse = |text: &str| -> Vec<(String, String)> {
        text.lines()
            .filter_map(|l| {
                l.split_once(' ')
                    .map(|(k, v)| (k.to_string(), v.to_string()))
            })
            .collect()
    };
    let (e, a) = (parse(&expected), parse(&actual));
    if e.iter().map(|p| &p.0).ne(a.iter().map(|p| &p.0)) {
        problems.push(format!(
            "{}: keys differ:\n{expected}\nvs\n{actual}",
            case.display()
        ));
        return problems;
    }
    for ((k, ev), (_, av)) in e.iter().zip(&a) {
        if !same(ev, av) {
            problems.push(format!("{}: {k}: expected {ev}, got {av}", case.display()));
        }
    }
    problems
}

#[test]
fn golden_cases() {
    let mut cases: Vec<PathBuf> = fs::read_dir(golden_dir())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.join("params.json").exists())
        .collect();
    cases.sort();
    assert!(cases.len() >= 3, "golden cases missing");
    let problems: Vec<String> = cases.iter().flat_map(|c| check(c)).collect();
    assert!(
        problems.is_empty(),
        "golden mismatches:\n{}",
        problems.join("\n")
    );
}
