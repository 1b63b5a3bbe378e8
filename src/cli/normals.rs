//! `stablesurf normals`: a scan's oriented normals as a binary PLY of points, and with `--mesh`
//! the crust triangulation they came from. A `.conf` registration, or several files of one
//! object, gives every view's normals, each estimated in its own frame and then moved by its
//! pose into the common frame (as `run` merges them), in view order.

use anyhow::{Context, Result};
use stablesurf::cloud::OrientedCloud;
use stablesurf::merge::{self, Pose};
use stablesurf::normals::NormalsParams;
use stablesurf::pipeline::ScanSource;
use stablesurf::{export, normals, TriangleMesh};

use super::args::NormalsArgs;
use super::config;
use super::progress::Verbosity;

/// Runs `stablesurf normals`.
pub fn normals(args: NormalsArgs, verbosity: Verbosity) -> Result<()> {
    let params = config::normals_params(&args.normals);
    let source = ScanSource::from_inputs(&args.input);
    let views = source.views()?;
    let several = views.is_some();
    let (points, crust) = match views {
        None => one_scan(&args.input[0], &params, verbosity, false)?,
        Some(views) => {
            let mut oriented: Vec<(OrientedCloud, Pose)> = Vec::with_capacity(views.len());
            let mut crust = Vec::new();
            let mut before = 0;
            for view in &views {
                let (cloud, triangles) = one_scan(&view.path, &params, verbosity, true)?;
                let offset = u32::try_from(before).with_context(|| {
                    format!(
                        "{}: the views hold more than 2^32 points together; give fewer views",
                        source.name()
                    )
                })?;
                crust.extend(triangles.iter().map(|t| t.map(|i| i + offset)));
                before += cloud.points.len();
                oriented.push((cloud, view.pose));
            }
            let refs: Vec<(&OrientedCloud, Pose)> = oriented.iter().map(|(c, p)| (c, *p)).collect();
            (merge::merge_views(&refs), crust)
        }
    };
    if verbosity != Verbosity::Quiet && several {
        eprintln!(
            "stablesurf: {} oriented normals in the common frame of {}",
            points.points.len(),
            source.name()
        );
    }
    let points = TriangleMesh {
        positions: points.points,
        normals: points.normals,
        triangles: Vec::new(),
    };
    let opts = export::ply::PlyOptions::default();
    export::write_atomic(&args.output, |w| export::ply::write(&points, w, &opts))?;
    if let Some(mesh_path) = &args.mesh {
        let crust = TriangleMesh {
            triangles: crust,
            ..points
        };
        export::write_atomic(mesh_path, |w| export::ply::write(&crust, w, &opts))?;
    }
    Ok(())
}

/// One scan's oriented normals (in its own frame) and the crust triangles they came from; its
/// messages name the file when it is one `view` of several.
fn one_scan(
    path: &std::path::Path,
    params: &NormalsParams,
    verbosity: Verbosity,
    view: bool,
) -> Result<(OrientedCloud, Vec<[u32; 3]>)> {
    let cloud = config::read_cloud(path)?;
    // The cloud is given to the stage, and its result's arrays to the files: no copies.
    let result = normals::estimate_normals_owned(cloud, params)
        .with_context(|| format!("estimating normals of {}", path.display()))?;
    if verbosity != Verbosity::Quiet {
        let of = if view {
            format!("{}: ", path.display())
        } else {
            String::new()
        };
        for w in &result.warnings {
            eprintln!("stablesurf: warning: {of}{w}");
        }
        eprintln!(
            "stablesurf: {of}{} oriented normals from {}",
            result.cloud.points.len(),
            result.source_used.as_str()
        );
    }
    Ok((result.cloud, result.crust_triangles))
}
