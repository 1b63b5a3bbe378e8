//! Noisy, unoriented points: the noise is measured, the default run averages it instead of
//! following it, and the mesh keeps the true topology.
//!
//! The inputs are analytic shapes (a sphere of radius 1, a torus of radii 1 and 0.4) sampled
//! without normals and moved by isotropic Gaussian noise of a share of their diagonal, so the
//! truth is known exactly: the distance of the mesh to the true surface, and its Euler
//! characteristic. The same points with `--smooth 0` (the data taken as exact) are the
//! reference the smoothing must beat.

use std::fmt::Write as _;

use stablesurf::pipeline::{reconstruct, Mode, PipelineConfig, Reconstruction, ScanSource, Silent};
use stablesurf::testing::study::{sample, Lcg, Shape, Variant};
use stablesurf::{Aabb, PointCloud};

use crate::fixtures::{bin, read_report, run_ok, stderr_of};

/// `n` points of `shape` without normals, moved by Gaussian noise of `share` of their box's
/// diagonal in each coordinate; also returns that σ.
fn noisy(shape: Shape, n: usize, share: f64, seed: u64) -> (PointCloud, f64) {
    let clean = sample(shape, Variant::Clean, n, seed).points;
    let sigma = share * Aabb::from_points(&clean).unwrap().diagonal();
    let mut rng = Lcg::new(seed + 1);
    let points = clean
        .iter()
        .map(|p| p.map(|c| c + sigma * rng.normal()))
        .collect();
    (
        PointCloud {
            points,
            ..Default::default()
        },
        sigma,
    )
}

/// The default run (detail mode) on `cloud` at `--smooth smooth`.
fn run(cloud: &PointCloud, smooth: f64) -> Reconstruction {
    let mut config = PipelineConfig::for_mode(Mode::Detail);
    config.smooth = smooth;
    reconstruct(
        &ScanSource::Cloud(Box::new(cloud.clone())),
        &config,
        &mut Silent,
    )
    .unwrap()
}

/// The mean, over the mesh's vertices, of their distance to the true surface.
fn mean_distance(out: &Reconstruction, distance: impl Fn([f64; 3]) -> f64) -> f64 {
    let v = &out.mesh.positions;
    v.iter().map(|&p| distance(p)).sum::<f64>() / v.len() as f64
}

fn sphere_distance(p: [f64; 3]) -> f64 {
    ((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 1.0).abs()
}

fn torus_distance(p: [f64; 3]) -> f64 {
    let rho = (p[0] * p[0] + p[1] * p[1]).sqrt();
    (((rho - 1.0).powi(2) + p[2] * p[2]).sqrt() - 0.4).abs()
}

#[test]
fn noisy_unoriented_shapes_are_measured_averaged_and_keep_their_topology() {
    // 20,000 points, σ = 0.5% of the diagonal: about 0.7 of the spacing on the sphere, 0.5 on
    // the torus (measured below).
    for (shape, euler, distance) in [
        (Shape::Sphere, 2, sphere_distance as fn([f64; 3]) -> f64),
        (Shape::Torus, 0, torus_distance),
    ] {
        let (cloud, sigma) = noisy(shape, 20_000, 0.005, 7);
        let smooth = run(&cloud, 1.0);
        let exact = run(&cloud, 0.0);
        let noise = smooth.report.noise.unwrap();
        // The noise figure within 15% of the σ added (the issue asks for a factor 1.5).
        let ratio = noise.sigma / sigma;
        assert!(
            (0.85..=1.15).contains(&ratio),
            "{shape:?}: {noise:?}, σ {sigma}"
        );
        assert!(noise.smoothed_per_diagonal > 0.0, "{shape:?}: {noise:?}");
        assert_eq!(exact.report.noise.unwrap().smoothed_per_diagonal, 0.0);
        let mesh = &smooth.report.mesh;
        assert!(
            mesh.watertight && mesh.components == 1,
            "{shape:?}: {mesh:?}"
        );
        assert_eq!(mesh.euler_characteristic, euler, "{shape:?}: {mesh:?}");
        assert_eq!(mesh.self_intersecting_faces, 0, "{shape:?}: {mesh:?}");
        // Averaged: within a third of σ of the true surface on average, and less than half the
        // distance of the mesh that follows the noise.
        let (d_smooth, d_exact) = (
            mean_distance(&smooth, distance),
            mean_distance(&exact, distance),
        );
        assert!(
            d_smooth < sigma / 3.0 && d_smooth < 0.5 * d_exact,
            "{shape:?}: mean distance {d_smooth} smoothed, {d_exact} exact, σ {sigma}"
        );
    }
}

#[test]
fn clean_points_are_not_smoothed() {
    // The same sphere without noise: the noise measured is a sliver of the spacing, and the
    // run is the exact fit's, to the byte.
    let clean = PointCloud {
        points: sample(Shape::Sphere, Variant::Clean, 20_000, 7).points,
        ..Default::default()
    };
    let auto = run(&clean, 1.0);
    let noise = auto.report.noise.unwrap();
    assert!(noise.sigma_per_spacing < 0.05, "{noise:?}");
    assert_eq!(noise.smoothed_per_diagonal, 0.0);
    let exact = run(&clean, 0.0);
    assert_eq!(auto.mesh.positions, exact.mesh.positions);
    assert_eq!(auto.mesh.triangles, exact.mesh.triangles);
}

#[test]
fn the_command_line_reports_the_noise_and_checks_smooth() {
    // 5,000 points of the unit sphere without normals, moved along their radius by noise of
    // 0.03 (about 0.6 of their spacing), as an XYZ file.
    let dir = tempfile::tempdir().unwrap();
    let mut rng = Lcg::new(4);
    let mut text = String::new();
    for p in sample(Shape::Sphere, Variant::Clean, 5_000, 4).points {
        let s = 1.0 + 0.03 * rng.normal();
        writeln!(text, "{} {} {}", p[0] * s, p[1] * s, p[2] * s).unwrap();
    }
    let input = dir.path().join("noisy.xyz");
    std::fs::write(&input, text).unwrap();
    // `info`: the same estimate as a run's report, within 15% of the noise added.
    let out = bin().args(["info", "--json"]).arg(&input).output().unwrap();
    assert!(out.status.success(), "{}", stderr_of(&out));
    let info: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let sigma = info["noise"]["sigma"].as_f64().unwrap();
    assert!((sigma / 0.03 - 1.0).abs() < 0.15, "{info}");
    assert!(
        info["noise"]["sigma_per_spacing"].as_f64().unwrap() > 0.5,
        "{info}"
    );
    // `run`: the summary line gives the noise and what was averaged, report.json the same σ.
    let run = run_ok(&input, &dir.path().join("out"), &["--formats", "ply,json"]);
    let summary = stderr_of(&run);
    assert!(
        summary.contains("averaged at") && summary.contains("(genus 0)"),
        "{summary}"
    );
    let report = read_report(&dir.path().join("out"));
    assert_eq!(report["noise"]["sigma"].as_f64().unwrap(), sigma);
    assert_eq!(report["mesh"]["genus"], 0);
    // A factor out of range is a usage error, before any work and without output.
    let bad = bin()
        .arg("run")
        .arg(&input)
        .arg("-o")
        .arg(dir.path().join("bad"))
        .args(["--smooth", "11"])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
    assert!(stderr_of(&bad).contains("--smooth"), "{}", stderr_of(&bad));
    assert!(!dir.path().join("bad").exists());
}
