//! Adaptivity of the `polygonize` octree: function evaluations, surface cells and triangles at
//! depths 6–9 for exact models, with the growth factor per level (about 4× for a surface, 8×
//! would mean the octree refines the volume).
//!
//! Run: `cargo run --release --example octree_counts`.

use stablesurf::polygonize::{polygonize, shapes, PolygonizeParams};
use stablesurf::{Aabb, ImplicitPolynomial};

fn main() {
    let cases: [(&str, ImplicitPolynomial, Aabb); 3] = [
        (
            "torus (deg 4)",
            shapes::torus(1.0, 0.4),
            Aabb { min: [-1.6; 3], max: [1.6; 3] },
        ),
        (
            "genus two (deg 8)",
            shapes::genus_two(),
            Aabb { min: [-1.2, -0.7, -0.2], max: [1.2, 0.7, 0.2] },
        ),
        (
            "linked tori (deg 8)",
            shapes::linked_tori(),
            Aabb { min: [-1.4, -1.4, -1.4], max: [2.4, 1.4, 1.4] },
        ),
    ];
    println!(
        "{:<22} {:>5} {:>12} {:>7} {:>10} {:>10} {:>7} {:>9}",
        "model", "depth", "evaluations", "ratio", "cells", "triangles", "level", "seconds"
    );
    for (name, f, region) in &cases {
        let mut previous: Option<u64> = None;
        for depth in 6..=9 {
            let params = PolygonizeParams { depth, ..PolygonizeParams::default() };
            let start = std::time::Instant::now();
            let out = match polygonize(f, region, &params) {
                Ok(out) => out,
                Err(e) => {
                    eprintln!("octree_counts: error: {e}");
                    std::process::exit(1);
                }
            };
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
            previous = Some(out.evaluations);
        }
    }
}
