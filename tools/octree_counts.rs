//! Adaptivity and mesh quality of the `polygonize` stage: function evaluations, surface cells,
//! triangles and triangle shape at depths 6–9 for exact models, with the growth factor per level
//! (about 4× for a surface, 8× would mean the octree refines the volume).
//!
//! Run: `cargo run --release --features tools --example octree_counts` for the exact models, or
//! `cargo run --release --features tools --example octree_counts -- MODEL.json [DEPTH] [none]` for one model file
//! (its box is the region; `none` skips the edge collapses), which prints the time (best of 3), the mesh checks and the triangle shape
//! statistics (minimum angle, radius ratio 2r/R: 1 for an equilateral triangle, 0 for a sliver).

use std::path::Path;

use stablesurf::polygonize::{polygonize, ImplicitFunction, PolygonizeParams, Simplification};
use stablesurf::testing::shapes;
use stablesurf::{Aabb, ImplicitPolynomial, TriangleMesh};

fn fail(message: String) -> ! {
    eprintln!("octree_counts: error: {message}");
    std::process::exit(1);
}

/// Minimum angle (degrees) and radius ratio 2r/R of each non-degenerate triangle.
fn shapes_of(mesh: &TriangleMesh) -> (Vec<f64>, Vec<f64>) {
    let mut angles = Vec::with_capacity(mesh.triangles.len());
    let mut ratios = Vec::with_capacity(mesh.triangles.len());
    for t in &mesh.triangles {
        let p = t.map(|i| mesh.positions[i as usize]);
        let len = |a: usize, b: usize| {
            (0..3)
                .map(|k| (p[a][k] - p[b][k]).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let (a, b, c) = (len(1, 2), len(2, 0), len(0, 1));
        let s = 0.5 * (a + b + c);
        let area2 = s * (s - a) * (s - b) * (s - c);
        let area = area2.max(0.0).sqrt();
        // r = area / s, R = abc / (4 area): 2r/R = 8 area² / (s a b c).
        ratios.push(if a * b * c > 0.0 {
            8.0 * area * area / (s * a * b * c)
        } else {
            0.0
        });
        let angle = |opposite: f64, x: f64, y: f64| {
            ((x * x + y * y - opposite * opposite) / (2.0 * x * y))
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        };
        let min = angle(a, b, c).min(angle(b, c, a)).min(angle(c, a, b));
        angles.push(if min.is_finite() { min } else { 0.0 });
    }
    (angles, ratios)
}

fn print_quality(mesh: &TriangleMesh) {
    let (mut angles, mut ratios) = shapes_of(mesh);
    let n = angles.len().max(1) as f64;
    angles.sort_by(f64::total_cmp);
    ratios.sort_by(f64::total_cmp);
    let quantile = |v: &[f64], q: f64| v.get(((v.len() as f64 - 1.0) * q) as usize).copied();
    let below = |v: &[f64], x: f64| v.iter().filter(|&&a| a < x).count() as f64 / n * 100.0;
    println!(
        "min angle: min {:.2}°, 1% {:.2}°, median {:.2}°, mean {:.2}°; below 10° {:.1}%, below 20° {:.1}%",
        quantile(&angles, 0.0).unwrap_or(0.0),
        quantile(&angles, 0.01).unwrap_or(0.0),
        quantile(&angles, 0.5).unwrap_or(0.0),
        angles.iter().sum::<f64>() / n,
        below(&angles, 10.0),
        below(&angles, 20.0)
    );
    println!(
        "radius ratio 2r/R: min {:.3}, 1% {:.3}, median {:.3}, mean {:.3}; below 0.1 {:.1}%",
        quantile(&ratios, 0.0).unwrap_or(0.0),
        quantile(&ratios, 0.01).unwrap_or(0.0),
        quantile(&ratios, 0.5).unwrap_or(0.0),
        ratios.iter().sum::<f64>() / n,
        below(&ratios, 0.1)
    );
}

fn model_file(path: &str, depth: u32, simplification: Simplification) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| fail(format!("reading {path}: {e}")));
    let model = stablesurf::model::json::read_model(&bytes, Path::new(path))
        .unwrap_or_else(|e| fail(e.to_string()));
    let region = model
        .bounds
        .unwrap_or_else(|| fail(format!("{path} has no box")));
    let params = PolygonizeParams {
        depth,
        simplification,
        ..PolygonizeParams::default()
    };
    let mut best = f64::INFINITY;
    let mut result = None;
    for _ in 0..3 {
        let start = std::time::Instant::now();
        let out =
            polygonize(&model.polynomial, &region, &params).unwrap_or_else(|e| fail(e.to_string()));
        best = best.min(start.elapsed().as_secs_f64());
        result = Some(out);
    }
    let Some(out) = result else { return };
    let report = stablesurf::mesh::check(&out.mesh);
    println!(
        "{path} depth {depth}: {:.3} s (best of 3), {} vertices, {} triangles, {} cells, {} evaluations, max level {}",
        best,
        out.mesh.positions.len(),
        out.mesh.triangles.len(),
        out.cells,
        out.evaluations,
        out.max_level
    );
    println!(
        "checks: watertight {}, boundary edges {}, non-manifold edges {} vertices {}, orientation consistent {}, components {}, euler {}, max |f|/|∇f| / diagonal {:.2e}",
        report.watertight,
        report.boundary_edges,
        report.non_manifold_edges,
        report.non_manifold_vertices,
        report.orientation_consistent,
        report.components,
        report.euler_characteristic,
        out.max_projection_residual
    );
    let worst = out
        .mesh
        .positions
        .iter()
        .map(|&p| {
            let (v, g) = model.polynomial.value_gradient(p);
            v.abs() / g.iter().map(|c| c * c).sum::<f64>().sqrt()
        })
        .fold(0.0, f64::max);
    println!("vertex |f|/|∇f| max {worst:.2e} (input units)");
    print_quality(&out.mesh);
}

/// The degree-8 genus-two surface and the box it is meshed in.
fn genus_two() -> (ImplicitPolynomial, Aabb) {
    let region = Aabb {
        min: [-1.2, -0.7, -0.2],
        max: [1.2, 0.7, 0.2],
    };
    (shapes::genus_two(), region)
}

/// The degree-8 linked tori and the box they are meshed in.
fn linked_tori() -> (ImplicitPolynomial, Aabb) {
    let region = Aabb {
        min: [-1.4, -1.4, -1.4],
        max: [2.4, 1.4, 1.4],
    };
    (shapes::linked_tori(), region)
}

/// `octree_counts genus_two|linked_tori [DEPTH] [RUNS]`: times `RUNS` polygonizations of one
/// exact degree-8 model (for profiling and CPU-time comparisons) and prints its counts.
fn exact_model(name: &str, depth: u32, runs: usize) {
    let (f, region) = if name == "genus_two" {
        genus_two()
    } else {
        linked_tori()
    };
    let params = PolygonizeParams {
        depth,
        ..PolygonizeParams::default()
    };
    let mut times = Vec::new();
    let mut result = None;
    for _ in 0..runs.max(1) {
        let start = std::time::Instant::now();
        let out = polygonize(&f, &region, &params).unwrap_or_else(|e| fail(e.to_string()));
        times.push(start.elapsed().as_secs_f64());
        result = Some(out);
    }
    let Some(out) = result else { return };
    times.sort_by(f64::total_cmp);
    // A hash of the mesh's bytes, to tell whether a change altered the output.
    let mut bytes = Vec::new();
    for (p, n) in out.mesh.positions.iter().zip(&out.mesh.normals) {
        for c in p.iter().chain(n) {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
    }
    for t in &out.mesh.triangles {
        for i in t {
            bytes.extend_from_slice(&i.to_le_bytes());
        }
    }
    println!("mesh hash {}", blake3::hash(&bytes).to_hex());
    let report = stablesurf::mesh::check(&out.mesh);
    println!(
        "{name} depth {depth}: min {:.3} s, median {:.3} s over {} runs; {} vertices, {} triangles, {} cells, {} evaluations, guard splits {}, watertight {}, euler {}, components {}, max |f|/|∇f| / diagonal {:.2e}",
        times[0],
        times[times.len() / 2],
        times.len(),
        out.mesh.positions.len(),
        out.mesh.triangles.len(),
        out.cells,
        out.evaluations,
        out.guard_splits,
        report.watertight,
        report.euler_characteristic,
        report.components,
        out.max_projection_residual
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if let Some(name) = args
        .first()
        .filter(|a| a.as_str() == "genus_two" || a.as_str() == "linked_tori")
    {
        let depth = args.get(1).and_then(|d| d.parse().ok()).unwrap_or(8);
        let runs: usize = args.get(2).and_then(|d| d.parse().ok()).unwrap_or(5);
        exact_model(name, depth, runs);
        return;
    }
    if let Some(path) = args.first() {
        let depth = args
            .get(1)
            .map(|d| d.parse().unwrap_or_else(|_| fail(format!("bad depth {d}"))))
            .unwrap_or(8);
        let simplification = match args.get(2).map(String::as_str) {
            Some("none") => Simplification::None,
            _ => Simplification::EdgeCollapse,
        };
        model_file(path, depth, simplification);
        return;
    }
    let ((genus, genus_region), (tori, tori_region)) = (genus_two(), linked_tori());
    let cases: [(&str, ImplicitPolynomial, Aabb); 3] = [
        (
            "torus (deg 4)",
            shapes::torus(1.0, 0.4),
            Aabb {
                min: [-1.6; 3],
                max: [1.6; 3],
            },
        ),
        ("genus two (deg 8)", genus, genus_region),
        ("linked tori (deg 8)", tori, tori_region),
    ];
    println!(
        "{:<22} {:>5} {:>12} {:>7} {:>10} {:>10} {:>7} {:>9}",
        "model", "depth", "evaluations", "ratio", "cells", "triangles", "level", "seconds"
    );
    for (name, f, region) in &cases {
        let mut previous: Option<u64> = None;
        for depth in 6..=9 {
            let params = PolygonizeParams {
                depth,
                ..PolygonizeParams::default()
            };
            let start = std::time::Instant::now();
            let out = polygonize(f, region, &params).unwrap_or_else(|e| fail(e.to_string()));
            let seconds = start.elapsed().as_secs_f64();
            let ratio = previous.map_or(String::from("-"), |p| {
                format!("{:.2}", out.evaluations as f64 / p as f64)
            });
            println!(
                "{:<22} {:>5} {:>12} {:>7} {:>10} {:>10} {:>7} {:>9.3}",
                name,
                depth,
                out.evaluations,
                ratio,
                out.cells,
                out.mesh.triangles.len(),
                out.max_level,
                seconds
            );
            if depth == 8 {
                print_quality(&out.mesh);
            }
            previous = Some(out.evaluations);
        }
    }
}
