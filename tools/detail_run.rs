//! Detail mode on scan files: import → normals (auto: the mesh's faces where present) → detail
//! fit → polygonize → checks and the symmetric Chamfer distance, one line per file.
//!
//! Usage: `cargo run --release --features tools --example detail_run -- [--depth D] [--tolerance T]
//! [--finest F] [--degree N] FILE...`. Prints, per file: points, cells, grown cells, fit and mesh
//! times, components, watertight, manifold, and Chamfer / diagonal (mean of the two directed
//! means; see `stablesurf::detail::chamfer_distance`).

use std::path::Path;
use std::time::Instant;

use stablesurf::detail::{chamfer_distance, fit_detail, DetailParams};
use stablesurf::normals::{estimate_normals, NormalsParams};
use stablesurf::polygonize::{polygonize, PolygonizeParams};

mod proc_time;
use proc_time::cpu_seconds;

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut params = DetailParams::default();
    let mut mesh_params = PolygonizeParams {
        depth: 8,
        guard_levels: 1,
        ..PolygonizeParams::default()
    };
    let mut files = Vec::new();
    while !args.is_empty() {
        let a = args.remove(0);
        let mut value = || -> anyhow::Result<String> {
            if args.is_empty() {
                anyhow::bail!("{a} needs a value");
            }
            Ok(args.remove(0))
        };
        match a.as_str() {
            "--depth" => mesh_params.depth = value()?.parse()?,
            "--guard" => mesh_params.guard_levels = value()?.parse()?,
            "--tolerance" => params.tolerance = value()?.parse()?,
            "--finest" => params.finest_tolerance = value()?.parse()?,
            "--degree" => params.degree = value()?.parse()?,
            "--max-depth" => params.max_depth = value()?.parse()?,
            "--kappa" => params.kappa = value()?.parse()?,
            _ => files.push(a),
        }
    }
    println!("file\tpoints\tnormals_s\tcells\tgrown\tdepth\tfit_s\tmesh_s\tfaces\tcomponents\twatertight\tchamfer_rel\tp2m_rel\tm2p_rel\tmax_resid_rel");
    for f in files {
        let path = Path::new(&f);
        let bytes = std::fs::read(path)?;
        let cloud = stablesurf::import::import_bytes(&bytes, path)?;
        let t = Instant::now();
        let normals = estimate_normals(&cloud, &NormalsParams::default())?;
        let t_normals = t.elapsed().as_secs_f64();
        eprintln!("normals {t_normals:.3} s");
        let oriented = normals.cloud;
        let t = Instant::now();
        let c0 = cpu_seconds();
        let model = fit_detail(&oriented, &params)?;
        let t_fit = t.elapsed().as_secs_f64();
        eprintln!(
            "fit {t_fit:.3} s, {} cells, {:?}",
            model.cells.len(),
            model.diagnostics
        );
        let c1 = cpu_seconds();
        let t = Instant::now();
        let out = polygonize(&model, &model.region, &mesh_params)?;
        let t_mesh = t.elapsed().as_secs_f64();
        let c2 = cpu_seconds();
        eprintln!(
            "cpu: fit {:.2} s, mesh {:.2} s; {} surface leaves, {} evaluations",
            c1 - c0,
            c2 - c1,
            out.cells,
            out.evaluations
        );
        let report = stablesurf::mesh::check(&out.mesh);
        let (n_components, labels) = stablesurf::mesh::component_labels(&out.mesh);
        let mut sizes = vec![0usize; n_components];
        for &l in &labels {
            if let Some(s) = sizes.get_mut(l as usize) {
                *s += 1;
            }
        }
        sizes.sort_unstable_by(|a, b| b.cmp(a));
        eprintln!(
            "boundary edges {}, non-manifold edges {}, non-manifold vertices {}, euler {}, component vertex counts {:?}",
            report.boundary_edges,
            report.non_manifold_edges,
            report.non_manifold_vertices,
            report.euler_characteristic,
            &sizes[..sizes.len().min(8)]
        );
        let c = chamfer_distance(&oriented.points, &out.mesh).unwrap_or_default();
        let d = model.diagonal;
        println!(
            "{}\t{}\t{:.2}\t{}\t{}\t{}\t{:.3}\t{:.3}\t{}\t{}\t{}\t{:.3e}\t{:.3e}\t{:.3e}\t{:.2e}",
            path.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default(),
            oriented.points.len(),
            t_normals,
            model.cells.len(),
            model.diagnostics.grown_cells,
            model.diagnostics.depth_reached,
            t_fit,
            t_mesh,
            report.faces,
            report.components,
            report.watertight,
            c.symmetric / d,
            c.points_to_mesh / d,
            c.mesh_to_points / d,
            model.diagnostics.max_residual,
        );
    }
    Ok(())
}
