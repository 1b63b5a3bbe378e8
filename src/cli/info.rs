//! `stablesurf info`: what a scan, mesh or model file holds, as aligned text or one JSON object
//! on stdout.

use std::io::Write;

use anyhow::{Context, Result};
use stablesurf::import;
use stablesurf::pipeline::Model;

use super::args::InfoArgs;

/// Runs `stablesurf info`.
pub fn info(args: InfoArgs) -> Result<()> {
    let bytes =
        std::fs::read(&args.file).with_context(|| format!("reading {}", args.file.display()))?;
    let looks_like_model = bytes.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'{');
    let value = if looks_like_model || stablesurf::export::mpu::is_mpu(&bytes) {
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
        serde_json::to_value(import::scan_info(&scan))?
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
