//! `stablesurf normals`: a scan's oriented normals as a binary PLY of points, and with `--mesh`
//! the crust triangulation they came from.

use anyhow::{Context, Result};
use stablesurf::{export, normals, TriangleMesh};

use super::args::NormalsArgs;
use super::config;
use super::progress::Verbosity;

/// Runs `stablesurf normals`.
pub fn normals(args: NormalsArgs, verbosity: Verbosity) -> Result<()> {
    let params = config::normals_params(&args.normals);
    let cloud = config::read_cloud(&args.input)?;
    // The cloud is given to the stage, and its result's arrays to the files: no copies.
    let result = normals::estimate_normals_owned(cloud, &params)
        .with_context(|| format!("estimating normals of {}", args.input.display()))?;
    if verbosity != Verbosity::Quiet {
        for w in &result.warnings {
            eprintln!("stablesurf: warning: {w}");
        }
        eprintln!(
            "stablesurf: {} oriented normals from {}",
            result.cloud.points.len(),
            result.source_used.as_str()
        );
    }
    let points = TriangleMesh {
        positions: result.cloud.points,
        normals: result.cloud.normals,
        triangles: Vec::new(),
    };
    let opts = export::ply::PlyOptions::default();
    export::write_atomic(&args.output, |w| export::ply::write(&points, w, &opts))?;
    if let Some(mesh_path) = &args.mesh {
        let crust = TriangleMesh {
            triangles: result.crust_triangles,
            ..points
        };
        export::write_atomic(mesh_path, |w| export::ply::write(&crust, w, &opts))?;
    }
    Ok(())
}
