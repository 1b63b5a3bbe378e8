//! Times each part of the pipeline's export stage alone (wall and CPU seconds), on the artifacts
//! of a cached run: `stablesurf run SCAN -o OUT --cache-dir DIR` first, then
//! `cargo run --release --features tools --example export_parts -- DIR [REPEATS]`. Each part runs REPEATS times
//! (default 3) on the global rayon pool (`RAYON_NUM_THREADS` sets its size); the minimum is
//! printed. With a third argument, an output folder of `stablesurf run` (for instance main's),
//! the slices are compared pixel by pixel with its EXR files. A tool, not part of the library.

#[path = "proc_time.rs"]
mod proc_time;

use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;
use stablesurf::cache::codec::decode;
use stablesurf::distance::{slices, SliceParams};
use stablesurf::export;
use stablesurf::measure::{point_to_mesh_distances, DistanceSummary};
use stablesurf::{mesh, Aabb, ImplicitModel, PointCloud, TriangleMesh};

fn entry(dir: &Path, stage: &str) -> Vec<u8> {
    let mut found: Vec<PathBuf> = Vec::new();
    for shard in std::fs::read_dir(dir.join(stage)).expect("stage folder") {
        for file in std::fs::read_dir(shard.expect("shard").path()).expect("shard folder") {
            let path = file.expect("entry").path();
            if path.extension().is_some_and(|e| e == "bin") {
                found.push(path);
            }
        }
    }
    assert_eq!(found.len(), 1, "expected one {stage} entry in the cache");
    std::fs::read(&found[0]).expect("read entry")
}

/// Compares the slices pixel by pixel with `slices/slice_NNN.exr` under `reference` (an output
/// folder of `stablesurf run`): the largest difference, and the number of pixels that differ.
fn compare(stack: &[stablesurf::distance::Slice], reference: &Path) {
    let (mut worst, mut n_diff, mut n_pixels, mut worst_rel) = (0.0f64, 0usize, 0usize, 0.0f64);
    for s in stack {
        let path = reference.join(format!("slices/slice_{:03}.exr", s.index));
        let v = stablesurf::export::exr::read_samples(&std::fs::read(&path).expect("read slice"))
            .expect("reference slice");
        assert_eq!(v.len(), s.data.len());
        for (a, b) in v.iter().zip(&s.data) {
            n_pixels += 1;
            if a.to_bits() != b.to_bits() {
                n_diff += 1;
                let d = (f64::from(*a) - f64::from(*b)).abs();
                worst = worst.max(d);
                worst_rel = worst_rel.max(d / f64::from(a.abs()).max(1e-30));
            }
        }
    }
    println!(
        "compare: {n_diff} of {n_pixels} pixels differ from {}, max abs diff {worst:e}, max rel diff {worst_rel:e}",
        reference.display()
    );
}

/// Nearest-point queries one by one (A) and with the previous answer as a radius (B), single
/// threaded, for k-d trees with leaves of 32, 16 and 8 points.
fn kd_ab(queries: &[[f64; 3]], points: &[[f64; 3]], repeats: usize) {
    macro_rules! ab {
        ($b:literal) => {{
            use kiddo::{Eytzinger, KdTree, SquaredEuclidean, VecOfArenas};
            type Tree = KdTree<f64, u32, Eytzinger, VecOfArenas<f64, u32, 3, $b>, 3, $b>;
            let tree = time(concat!("build B=", $b), 1, || {
                Tree::new_from_slice(points).expect("tree")
            });
            for _ in 0..repeats {
                let a = time(concat!("one B=", $b), 1, || {
                    queries
                        .iter()
                        .map(|q| {
                            tree.query(q)
                                .nearest_one::<SquaredEuclidean<f64>>()
                                .execute()
                                .distance
                        })
                        .sum::<f64>()
                });
                let b = time(concat!("hinted B=", $b), 1, || {
                    let mut hint: Option<[f64; 3]> = None;
                    queries
                        .iter()
                        .map(|q| {
                            let d2 = |h: [f64; 3]| {
                                (q[0] - h[0]).powi(2)
                                    + (q[1] - h[1]).powi(2)
                                    + (q[2] - h[2]).powi(2)
                            };
                            let n = match hint {
                                Some(h) => {
                                    let found = tree
                                        .query(q)
                                        .nearest_n::<SquaredEuclidean<f64>>(
                                            std::num::NonZero::<usize>::MIN,
                                        )
                                        .within(d2(h) * (1.0 + 1e-9))
                                        .execute();
                                    (found[0].distance, found[0].item)
                                }
                                None => {
                                    let n = tree
                                        .query(q)
                                        .nearest_one::<SquaredEuclidean<f64>>()
                                        .execute();
                                    (n.distance, n.item)
                                }
                            };
                            hint = Some(points[n.1 as usize]);
                            n.0
                        })
                        .sum::<f64>()
                });
                assert_eq!(a, b);
            }
        }};
    }
    ab!(32);
    ab!(16);
    ab!(8);
}

fn time<T>(name: &str, repeats: usize, mut f: impl FnMut() -> T) -> T {
    // PARTS=slices,ply repeats only the named parts (for profiling); the others run once.
    let repeats = match std::env::var("PARTS") {
        Ok(parts) if !parts.split(',').any(|p| p == name) => 1,
        _ => repeats,
    };
    let (mut best_wall, mut best_cpu) = (f64::INFINITY, f64::INFINITY);
    let mut out = None;
    for _ in 0..repeats {
        let (c0, t0) = (proc_time::cpu_seconds(), Instant::now());
        out = Some(f());
        best_wall = best_wall.min(t0.elapsed().as_secs_f64());
        best_cpu = best_cpu.min(proc_time::cpu_seconds() - c0);
    }
    println!("{name:<16} wall {best_wall:7.3} s   cpu {best_cpu:7.3} s");
    out.expect("at least one repeat")
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = PathBuf::from(
        args.get(1)
            .expect("usage: export_parts CACHE_DIR [REPEATS [REFERENCE_OUTPUT_DIR]]"),
    );
    let repeats: usize = args.get(2).and_then(|r| r.parse().ok()).unwrap_or(3);
    let cloud: PointCloud = decode(&entry(&dir, "import")).expect("import entry");
    let model: ImplicitModel = decode(&entry(&dir, "fit")).expect("fit entry");
    let mesh: TriangleMesh = decode(&entry(&dir, "polygonize")).expect("polygonize entry");
    let region = stablesurf::pipeline::meshing_region(&model);
    let params = SliceParams {
        resolution: 128,
        ..Default::default()
    };
    let diagonal = Aabb::from_points(&cloud.points).map_or(0.0, |b| b.diagonal());
    println!(
        "threads {}, {} points, {} triangles",
        rayon::current_num_threads(),
        cloud.points.len(),
        mesh.triangles.len()
    );
    if std::env::var_os("KD_AB").is_some() {
        kd_ab(&mesh.positions, &cloud.points, repeats);
        kd_ab(&cloud.points, &mesh.positions, repeats);
        return;
    }
    time("check", repeats, || mesh::check(&mesh));
    time("accuracy", repeats, || {
        DistanceSummary::from_distances(&point_to_mesh_distances(&cloud.points, &mesh), diagonal)
    });
    let stack = time("slices", repeats, || {
        slices(&model.polynomial, &region, &params).expect("slices")
    });
    let longest = (0..3)
        .map(|a| region.max[a] - region.min[a])
        .fold(0.0, f64::max);
    let cell = 1.5 * longest / 64.0;
    let all: Vec<f64> = stack
        .iter()
        .flat_map(|s| s.data.iter().map(|&d| f64::from(d).abs() / cell))
        .collect();
    for k in [0.5, 1.0, 2.0, 4.0, 8.0] {
        println!(
            "pixels within {k} seed cells of the surface: {:.3}",
            all.iter().filter(|&&d| d < k).count() as f64 / all.len() as f64
        );
    }
    if let Some(reference) = args.get(3) {
        compare(&stack, Path::new(reference));
    }
    time("exact setup", repeats, || {
        stablesurf::distance::ExactDistance::new(&model.polynomial, &region).expect("setup")
    });
    time("model.json", repeats, || {
        let mut b = Vec::new();
        stablesurf::model::json::write_model(&model, &mut b).expect("model");
        b
    });
    time("glb", repeats, || {
        let mut b = Vec::new();
        export::gltf::write_glb(&mesh, &mut b, &Default::default()).expect("glb");
        b
    });
    time("ply", repeats, || {
        let quality =
            export::ply::nearest_point_distances(&mesh.positions, &cloud.points).expect("quality");
        let opts = export::ply::PlyOptions {
            quality: Some(&quality),
            ..Default::default()
        };
        let mut b = Vec::new();
        export::ply::write(&mesh, &mut b, &opts).expect("ply");
        b
    });
    time("preview", repeats, || {
        let image = stablesurf::render::render(&mesh, &Default::default());
        let mut b = Vec::new();
        export::png::write_rgb(&image, &mut b).expect("png");
        b
    });
    time("slice files", repeats, || {
        stack
            .par_iter()
            .map(|s| {
                let mut exr = Vec::new();
                export::exr::write_slice(s, &Default::default(), &mut exr).expect("exr");
                let mut png = Vec::new();
                export::png::write_preview(s, &mut png).expect("png");
                (exr, png)
            })
            .collect::<Vec<_>>()
    });
}
