//! `stablesurf mesh`: a model file's zero set meshed into one glTF or PLY file, the format from
//! the output's extension, written by the library's one mesh writer
//! ([`pipeline::mesh_files`]).

use anyhow::{anyhow, Context, Result};
use stablesurf::pipeline::{self, MeshFileOptions, MeshFormat, Model};
use stablesurf::{export, finish, polygonize};

use super::args::MeshArgs;
use super::config;
use super::progress::Verbosity;
use super::usage;

/// Runs `stablesurf mesh`.
pub fn mesh(args: MeshArgs, verbosity: Verbosity) -> Result<()> {
    let Some(format) = MeshFormat::from_path(&args.output) else {
        return Err(usage(format!(
            "-o {}: the mesh format comes from the extension: .glb, .gltf or .ply",
            args.output.display()
        )));
    };
    let model = config::read_model(&args.model)?;
    let params = config::polygonize_params(&args.mesh, model.mode());
    let region = match (config::region_from(args.bounds), &model) {
        (Some(b), _) => b,
        (None, Model::Detail(m)) => m.region,
        (None, Model::Global(m)) => m.bounds.ok_or_else(|| {
            anyhow!("{} has no \"box\": pass the meshing region with --bounds xmin,ymin,zmin,xmax,ymax,zmax", args.model.display())
        })?,
    };
    let mut mesh = polygonize::polygonize(model.function(), &region, &params)
        .with_context(|| format!("meshing {}", args.model.display()))?
        .mesh;
    if let Some(decimate) = config::decimate_params(&args.mesh) {
        let out = finish::decimate::decimate(&mesh, model.function(), &decimate);
        if let (Some(message), false) = (out.report.shortfall(), verbosity == Verbosity::Quiet) {
            eprintln!("stablesurf: warning: {message}");
        }
        mesh = out.mesh;
    }
    let opts = MeshFileOptions {
        gltf: export::gltf::GltfOptions {
            up: args.frame.up.map_or(export::gltf::UpAxis::Y, Into::into),
            units: args.frame.units.map(Into::into),
        },
        ply: export::ply::PlyOptions {
            encoding: if args.ascii {
                export::ply::PlyEncoding::Ascii
            } else {
                export::ply::PlyEncoding::BinaryLittleEndian
            },
            units: args.frame.units.map(Into::into),
            up: args.frame.up.map(Into::into),
            ..Default::default()
        },
        colours: None,
    };
    let name = args
        .output
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    // glTF's buffer file first, then the file that refers to it.
    for (file_name, bytes) in pipeline::mesh_files(&mesh, format, &name, &opts)? {
        config::write_file(&args.output.with_file_name(file_name), &bytes)?;
    }
    if verbosity != Verbosity::Quiet {
        let check = stablesurf::mesh::check(&mesh);
        eprintln!(
            "stablesurf: {} vertices, {} triangles, {} component(s), {} boundary edges, watertight {}",
            check.vertices, check.faces, check.components, check.boundary_edges, check.watertight
        );
    }
    Ok(())
}
