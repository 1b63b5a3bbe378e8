//! `stablesurf info`: what a scan, mesh, model or `.conf` registration file holds, as aligned
//! text or one JSON object on stdout.

use std::io::Write;

use anyhow::{Context, Result};
use stablesurf::fit::moments::PartialMoments;
use stablesurf::pipeline::Model;
use stablesurf::{export, import, Aabb};

use super::args::InfoArgs;

/// Runs `stablesurf info`.
pub fn info(args: InfoArgs) -> Result<()> {
    let bytes =
        std::fs::read(&args.file).with_context(|| format!("reading {}", args.file.display()))?;
    let looks_like_json = bytes.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'{');
    let named = |what: &str| format!("reading {} as {what}", args.file.display());
    let value = if bytes.starts_with(b"glTF") || (looks_like_json && is_gltf_json(&bytes)) {
        export::gltf::read_info(&bytes).with_context(|| named("glTF"))?
    } else if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        export::exr::read_info(&bytes).with_context(|| named("OpenEXR"))?
    } else if bytes.starts_with(&[0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0]) {
        export::vdb::read_info(&bytes).with_context(|| named("OpenVDB"))?
    } else if bytes.starts_with(b"\x93NUMPY") {
        export::npy::read_info(&bytes).with_context(|| named("NumPy .npy"))?
    } else if bytes.starts_with(b"SSMOMENT") {
        moments_info(&bytes).with_context(|| named("a moments file"))?
    } else if import::conf::is_conf(&args.file) {
        conf_info(&bytes, &args.file)?
    } else if looks_like_json || stablesurf::model::mpu::is_mpu(&bytes) {
        match Model::from_bytes(&bytes, &args.file)? {
            Model::Detail(model) => serde_json::json!({
                "format": "stablesurf.mpu",
                "cells": model.cells.len(),
                "box": model.region,
                "diagonal": model.diagonal,
                "diagnostics": model.diagnostics,
            }),
            Model::Global(model) => serde_json::json!({
                "format": "stablesurf.implicit-polynomial",
                "degree": model.polynomial.degree,
                "coefficients": model.polynomial.coefficients.len(),
                "center": model.polynomial.center,
                "scale": model.polynomial.scale,
                "box": model.bounds,
                "fit": model.fit,
                "diagnostics": model.diagnostics,
            }),
        }
    } else {
        let scan = import::read_scan_bytes(&bytes, &args.file)?;
        let mut value = serde_json::to_value(import::scan_info(&scan))?;
        value["noise"] = noise_json(&scan.cloud.points);
        value
    };
    let mut out = std::io::stdout().lock();
    if args.json {
        serde_json::to_writer(&mut out, &value)?;
        writeln!(out)?;
    } else if let serde_json::Value::Object(map) = &value {
        for (k, v) in map {
            writeln!(out, "{k:<18} {v}")?;
        }
    }
    Ok(())
}

/// The measured noise of `points` ([`stablesurf::estimate_noise`]) as `run`'s report gives
/// it: σ in input units and over the box's diagonal, the 10% and 90% quantiles of the local
/// estimates, σ over the median spacing; null when it cannot be measured.
fn noise_json(points: &[[f64; 3]]) -> serde_json::Value {
    let finite: Vec<[f64; 3]> = points
        .iter()
        .filter(|p| p.iter().all(|c| c.is_finite()))
        .copied()
        .collect();
    let diagonal = Aabb::from_points(&finite).map_or(0.0, |b| b.diagonal());
    match stablesurf::estimate_noise(&finite) {
        Some(n) if diagonal > 0.0 => serde_json::json!({
            "sigma": n.sigma,
            "sigma_per_diagonal": n.sigma / diagonal,
            "sigma_low": n.sigma_low,
            "sigma_high": n.sigma_high,
            "sigma_per_spacing": n.relative_to_spacing(),
        }),
        _ => serde_json::Value::Null,
    }
}

/// What a `.conf` registration holds: each scan's file, point count and pose, and the box of
/// all their finite points moved into the common frame (what `run` merges).
fn conf_info(bytes: &[u8], path: &std::path::Path) -> Result<serde_json::Value> {
    let views = import::conf::read_conf(bytes, path)?;
    let mut scans = Vec::with_capacity(views.len());
    let mut moved = Vec::new();
    for view in &views {
        let scan_bytes = std::fs::read(&view.path).with_context(|| {
            format!(
                "reading {}, a scan of {}",
                view.path.display(),
                path.display()
            )
        })?;
        let scan = import::read_scan_bytes(&scan_bytes, &view.path)?;
        moved.extend(view.pose.apply_all(&scan.cloud.points));
        scans.push(serde_json::json!({
            "file": view.path.display().to_string(),
            "format": scan.format.as_str(),
            "points": scan.cloud.points.len(),
            "translation": view.pose.translation,
            "rotation": view.pose.rotation,
        }));
    }
    // The box of the finite points; NaN, printed as JSON null, when there is none (as a scan's).
    let bbox = Aabb::from_points(&moved);
    let (min, max) = (
        bbox.map_or([f64::NAN; 3], |b| b.min),
        bbox.map_or([f64::NAN; 3], |b| b.max),
    );
    Ok(serde_json::json!({
        "format": "conf",
        "views": views.len(),
        "points": moved.len(),
        "noise": noise_json(&moved),
        "bbox_min": min,
        "bbox_max": max,
        "scans": scans,
    }))
}

/// Whether JSON text is a glTF asset (it has an `asset` object) rather than a model file.
fn is_gltf_json(bytes: &[u8]) -> bool {
    /// The one member every glTF asset has.
    #[derive(serde::Deserialize)]
    struct Gltf {
        #[allow(dead_code)]
        asset: serde_json::Map<String, serde_json::Value>,
    }
    serde_json::from_slice::<Gltf>(bytes).is_ok()
}

/// What a `stablesurf moments` file holds: its pass, point count and, for the moments of the
/// fit itself, the degree, ε and frame.
fn moments_info(bytes: &[u8]) -> Result<serde_json::Value> {
    Ok(match PartialMoments::from_bytes(bytes)? {
        PartialMoments::Center {
            n_points, bounds, ..
        } => serde_json::json!({
            "format": "stablesurf.moments",
            "pass": "center",
            "points": n_points,
            "box": bounds,
        }),
        PartialMoments::Scale {
            n_points, center, ..
        } => serde_json::json!({
            "format": "stablesurf.moments",
            "pass": "scale",
            "points": n_points,
            "center": center,
        }),
        PartialMoments::System(s) => serde_json::json!({
            "format": "stablesurf.moments",
            "pass": "system",
            "points": s.n_points,
            "degree": s.degree,
            "epsilon": s.epsilon,
            "center": s.frame.center,
            "scale": s.frame.scale,
            "box": s.bounds,
        }),
    })
}
