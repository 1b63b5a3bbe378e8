//! Symmetric Chamfer distance between two triangle meshes, relative to the reference's bounding
//! box diagonal.
//!
//! Usage: `cargo run --release --features tools --example mesh_chamfer -- RESULT REFERENCE`. Takes two mesh files
//! (any format `import` reads); gives, on one line, the mean distance from RESULT's vertices to
//! REFERENCE's triangles, from REFERENCE's vertices to RESULT's triangles, and their mean, each
//! divided by REFERENCE's diagonal.

use std::path::Path;

use stablesurf::measure::point_to_mesh_distances;
use stablesurf::{Aabb, TriangleMesh};

fn load(path: &str) -> anyhow::Result<TriangleMesh> {
    let bytes = std::fs::read(path)?;
    let cloud = stablesurf::import::import_bytes(&bytes, Path::new(path))?;
    anyhow::ensure!(!cloud.triangles.is_empty(), "{path} has no triangles");
    Ok(TriangleMesh {
        normals: vec![[0.0; 3]; cloud.points.len()],
        positions: cloud.points,
        triangles: cloud.triangles,
    })
}

/// The vertices some triangle uses (a file's loose vertices are not part of its surface).
fn used(mesh: &TriangleMesh) -> Vec<[f64; 3]> {
    let mut on = vec![false; mesh.positions.len()];
    for &v in mesh.triangles.iter().flatten() {
        on[v as usize] = true;
    }
    (0..on.len())
        .filter(|&i| on[i])
        .map(|i| mesh.positions[i])
        .collect()
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(args.len() == 2, "usage: mesh_chamfer RESULT REFERENCE");
    let (result, reference) = (load(&args[0])?, load(&args[1])?);
    let diagonal = Aabb::from_points(&used(&reference))
        .map(|b| b.diagonal())
        .unwrap_or(1.0);
    let mean = |d: Vec<f64>| d.iter().sum::<f64>() / d.len().max(1) as f64 / diagonal;
    let a = mean(point_to_mesh_distances(&used(&result), &reference));
    let b = mean(point_to_mesh_distances(&used(&reference), &result));
    println!(
        "result->reference {a:.3e}, reference->result {b:.3e}, chamfer {:.3e} of the diagonal {diagonal:.4}",
        0.5 * (a + b)
    );
    Ok(())
}
