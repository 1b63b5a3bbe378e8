//! Compares two folders of distance slices (`slice_NNN.exr`, as `stablesurf slices` or `run`
//! writes them) pixel by pixel: how many values differ, by how many float32 steps at most
//! (away from the surface), the largest absolute difference, and that difference relative to
//! the largest |value| (about the region's size). Used to check that a change to the slice
//! computation keeps the distances.
//!
//! ```text
//! cargo run --release --features tools --example slice_diff -- DIR_A DIR_B
//! ```

use std::path::{Path, PathBuf};

fn samples(path: &Path) -> Vec<f32> {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    stablesurf::export::exr::read_samples(&bytes)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn exr_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "exr"))
        .collect();
    files.sort();
    files
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [a, b] = args.as_slice() else {
        eprintln!("usage: slice_diff DIR_A DIR_B");
        std::process::exit(2);
    };
    let (fa, fb) = (exr_files(Path::new(a)), exr_files(Path::new(b)));
    assert_eq!(fa.len(), fb.len(), "different numbers of slices");
    let mut stacks = Vec::with_capacity(fa.len());
    for (pa, pb) in fa.iter().zip(&fb) {
        let (va, vb) = (samples(pa), samples(pb));
        assert_eq!(va.len(), vb.len(), "{}: different sizes", pa.display());
        stacks.push((va, vb));
    }
    let max_value = stacks
        .iter()
        .flat_map(|(va, _)| va)
        .fold(0f64, |m, v| m.max(f64::from(v.abs())));
    let (mut pixels, mut differ, mut max_abs) = (0usize, 0usize, 0f64);
    // The largest difference in float32 steps (units in the last place) between values of one
    // sign, among values above 1e-3 of the largest |value| (nearer the surface a step is far
    // below the distances' own tolerance); a sign change counts as `u32::MAX`.
    let mut max_ulps = 0u32;
    for (va, vb) in &stacks {
        for (x, y) in va.iter().zip(vb) {
            pixels += 1;
            if x.to_bits() != y.to_bits() {
                differ += 1;
                max_abs = max_abs.max((f64::from(*x) - f64::from(*y)).abs());
                let ulps = if x.is_sign_negative() == y.is_sign_negative() {
                    x.to_bits().abs_diff(y.to_bits())
                } else {
                    u32::MAX
                };
                if f64::from(x.abs()) >= 1e-3 * max_value {
                    max_ulps = max_ulps.max(ulps);
                }
            }
        }
    }
    println!(
        "{} slices, {pixels} pixels: {differ} differ (by at most {max_ulps} float32 steps where |value| ≥ 1e-3 of the largest); largest difference {max_abs:.3e} ({:.3e} of the largest |value| {max_value:.3e})",
        fa.len(),
        max_abs / max_value.max(f64::MIN_POSITIVE)
    );
}
