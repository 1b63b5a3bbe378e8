//! Times the polygonize stage's polynomial kernels alone, on one thread: the cell enclosure
//! with the children's centre values (`enclosure_and_grid_values`: local Taylor expansion,
//! term ranges, grid values), the point value and the value with gradient, each on 40,000
//! pseudo-random cells (level-8 size) or points of the degree-8 linked tori's box. Prints the
//! best of five passes in ns per call and a blake3 hash of all results, so that a faster kernel
//! can be checked to give the same bits: `cargo run --release --features tools --example polygonize_kernels`.
//! A tool, not part of the library.

use std::io::Write;

use stablesurf::implicit::ImplicitFunction;
use stablesurf::testing::shapes;
use stablesurf::Aabb;

fn main() {
    let f = shapes::linked_tori();
    let n = 40_000;
    let mut boxes = Vec::with_capacity(n);
    let mut points = Vec::with_capacity(n);
    let mut s: u64 = 12345;
    let mut rnd = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let h = 3.8 / 256.0;
    for _ in 0..n {
        let c = [-1.4 + 3.8 * rnd(), -1.4 + 2.8 * rnd(), -1.4 + 2.8 * rnd()];
        boxes.push(Aabb {
            min: [c[0] - h, c[1] - h, c[2] - h],
            max: [c[0] + h, c[1] + h, c[2] + h],
        });
        points.push(c);
    }
    let mut hash = blake3::Hasher::new();
    let mut out = std::io::stdout().lock();
    for what in ["taylor", "value", "gradient"] {
        let mut best = f64::INFINITY;
        for _ in 0..5 {
            let t = std::time::Instant::now();
            let mut acc = 0.0;
            match what {
                "taylor" => {
                    for b in &boxes {
                        let axes = [0, 1, 2].map(|a| [b.min[a] + 0.5 * h, b.max[a] - 0.5 * h]);
                        let (e, g) = f.enclosure_and_grid_values(b, &axes);
                        acc += e.value.0
                            + e.value.1
                            + e.gradient[0].0
                            + e.gradient[2].1
                            + e.value_error;
                        if let Some(g) = g {
                            acc += g.values[3] + g.error;
                        }
                    }
                }
                "value" => {
                    for p in &points {
                        acc += f.value(*p);
                    }
                }
                _ => {
                    for p in &points {
                        let (v, g) = f.value_gradient(*p);
                        acc += v + g[0] + g[1] + g[2];
                    }
                }
            }
            best = best.min(t.elapsed().as_secs_f64());
            hash.update(&acc.to_le_bytes());
        }
        // Output errors (a closed pipe) end the tool quietly.
        let _ = writeln!(out, "{what:10} {:.1} ns/call", best * 1e9 / n as f64);
    }
    let _ = writeln!(out, "hash {}", hash.finalize().to_hex());
}
