//! Tool: writes the synthetic inputs of `tools/bench_peers` as binary little-endian PLY point
//! clouds with exact unit normals (`float x y z nx ny nz`).
//!
//! Shapes are those of `stablesurf::testing::study` (sphere, torus, eight, heart, cube, twisted),
//! sampled clean with `study::sample` (seed 2008), plus a 1,000,000-point torus (`torus_1m.ply`).
//!
//! Usage: `cargo run --release --features tools --example bench_peers_inputs -- OUT_DIR [--quick] [--points N]
//! [--big N]`; `--quick` writes only the torus (and no big sample). Defaults: 20000 points per
//! shape, 1000000 for the big torus (0 skips it).

use std::io::Write;
use std::path::PathBuf;

use stablesurf::testing::study::{sample, Shape, Variant};
use stablesurf::OrientedCloud;

fn write_ply(path: &PathBuf, cloud: &OrientedCloud) -> std::io::Result<()> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment stablesurf tools/bench_peers_inputs.rs, exact normals\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\nend_header\n",
        cloud.points.len()
    )
    .into_bytes();
    out.reserve(cloud.points.len() * 24);
    for (p, n) in cloud.points.iter().zip(&cloud.normals) {
        for v in p.iter().chain(n.iter()) {
            out.extend_from_slice(&(*v as f32).to_le_bytes());
        }
    }
    let mut f = std::fs::File::create(path)?;
    f.write_all(&out)
}

fn main() {
    let mut args = std::env::args().skip(1);
    let mut out_dir = None;
    let mut quick = false;
    let mut points = 20_000usize;
    let mut big = 1_000_000usize;
    while let Some(a) = args.next() {
        match a.as_str() {
            "--quick" => quick = true,
            "--points" => points = args.next().and_then(|v| v.parse().ok()).unwrap_or(points),
            "--big" => big = args.next().and_then(|v| v.parse().ok()).unwrap_or(big),
            other => out_dir = Some(PathBuf::from(other)),
        }
    }
    let Some(out_dir) = out_dir else {
        eprintln!("usage: bench_peers_inputs OUT_DIR [--quick] [--points N] [--big N]");
        std::process::exit(2);
    };
    if let Err(e) = std::fs::create_dir_all(&out_dir) {
        eprintln!(
            "bench_peers_inputs: cannot create {}: {e}",
            out_dir.display()
        );
        std::process::exit(1);
    }
    let shapes: Vec<Shape> = if quick {
        vec![Shape::Torus]
    } else {
        Shape::ALL.to_vec()
    };
    let mut jobs: Vec<(String, Shape, usize)> = shapes
        .iter()
        .map(|s| (s.name().to_string(), *s, points))
        .collect();
    if !quick && big > 0 {
        jobs.push(("torus_1m".into(), Shape::Torus, big));
    }
    for (name, shape, n) in jobs {
        let path = out_dir.join(format!("{name}.ply"));
        let cloud = sample(shape, Variant::Clean, n, 2008);
        if let Err(e) = write_ply(&path, &cloud) {
            eprintln!("bench_peers_inputs: cannot write {}: {e}", path.display());
            std::process::exit(1);
        }
        println!("{}", path.display());
    }
}
