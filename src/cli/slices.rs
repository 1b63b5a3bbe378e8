//! `stablesurf slices`: a model's signed-distance slices as OpenEXR images with PNG previews,
//! by the exact or first-order distance to a polynomial or the distance to the meshed zero set.

use std::path::PathBuf;

use anyhow::{Context, Result};
use stablesurf::distance::{self, DistanceMethod, SliceParams};
use stablesurf::pipeline::Model;
use stablesurf::{export, polygonize};

use super::args::{DistanceArg, SlicesArgs};
use super::config;
use super::progress::Verbosity;
use super::usage;

/// Runs `stablesurf slices`.
pub fn slices(args: SlicesArgs, verbosity: Verbosity) -> Result<()> {
    let model = config::read_model(&args.model)?;
    let mesh_params = config::polygonize_params(&args.mesh, model.mode());
    let distance = match (args.distance, &model) {
        (Some(DistanceArg::Mesh) | None, Model::Detail(_)) => DistanceArg::Mesh,
        (Some(other), Model::Detail(_)) => {
            return Err(usage(format!(
                "--distance {}: a detail model (.mpu) has only the mesh distance",
                if other == DistanceArg::Exact {
                    "exact"
                } else {
                    "taubin"
                }
            )))
        }
        (d, Model::Global(_)) => d.unwrap_or(DistanceArg::Exact),
    };
    // The count and resolution are within range::COUNT and range::RESOLUTION.
    let params = SliceParams {
        axis: args.axis.into(),
        count: args.count,
        resolution: args.resolution,
        method: distance.into(),
    };
    let region = match config::region_from(args.bounds) {
        Some(b) => b,
        None => model.region(),
    };
    let slices = match &model {
        Model::Global(m) if params.method != DistanceMethod::Mesh => {
            distance::slices(&m.polynomial, &region, &params)
        }
        _ => {
            let mesh = polygonize::polygonize(model.function(), &region, &mesh_params)
                .with_context(|| format!("meshing {}", args.model.display()))?
                .mesh;
            distance::slices_from_mesh(model.function(), &mesh, &region, &params)
        }
    }
    .with_context(|| format!("computing distance slices of {}", args.model.display()))?;
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("creating {}", args.output.display()))?;
    for slice in &slices {
        let stem: PathBuf = args.output.join(format!("slice_{:03}", slice.index));
        export::write_atomic(&stem.with_extension("exr"), |w| {
            export::exr::write_slice(slice, &export::exr::ExrOptions::default(), w)
        })?;
        export::write_atomic(&stem.with_extension("png"), |w| {
            export::png::write_preview(slice, w)
        })?;
    }
    if verbosity != Verbosity::Quiet {
        eprintln!(
            "stablesurf: {} slices written to {}",
            slices.len(),
            args.output.display()
        );
    }
    Ok(())
}
