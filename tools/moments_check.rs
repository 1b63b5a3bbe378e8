//! Tool: checks the moments protocol at scale. Writes a torus (R = 1, r = 0.4, about (3, −2, 5))
//! of N points with outward normals as one binary PLY and as K chunk PLYs, runs the three
//! `stablesurf moments` passes on every chunk and `stablesurf fit --from-moments`, runs
//! `stablesurf fit` on the whole file, and prints the largest relative coefficient difference
//! and the times of each step.
//!
//! Usage: `cargo run --release --features tools --example moments_check -- OUT_DIR [--points N] [--chunks K]
//! [--degree D] [--kappa K] [--write-only]` (defaults: 8,000,000 points, 8 chunks, degree 8,
//! κ = 1e-3). `--write-only` only writes the chunk files `chunk-K.ply` (and `whole.ply`), for
//! other drivers such as `tools/distributed/fit_dask.py`. The `stablesurf` binary is the one
//! built beside this example (`target/release/stablesurf`); build it first.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

fn main() {
    if let Err(e) = real_main() {
        eprintln!("moments_check: error: {e}");
        std::process::exit(1);
    }
}

struct Opts {
    out: PathBuf,
    points: usize,
    chunks: usize,
    degree: u32,
    kappa: String,
    write_only: bool,
}

fn parse() -> Result<Opts, String> {
    let mut args = std::env::args().skip(1);
    let mut o = Opts {
        out: PathBuf::new(),
        points: 8_000_000,
        chunks: 8,
        degree: 8,
        kappa: "1e-3".to_string(),
        write_only: false,
    };
    let mut out = None;
    while let Some(a) = args.next() {
        let mut value = |name: &str| args.next().ok_or(format!("{name} needs a value"));
        match a.as_str() {
            "--points" => {
                o.points = value("--points")?
                    .parse()
                    .map_err(|e| format!("--points: {e}"))?
            }
            "--chunks" => {
                o.chunks = value("--chunks")?
                    .parse()
                    .map_err(|e| format!("--chunks: {e}"))?
            }
            "--degree" => {
                o.degree = value("--degree")?
                    .parse()
                    .map_err(|e| format!("--degree: {e}"))?
            }
            "--kappa" => o.kappa = value("--kappa")?,
            "--write-only" => o.write_only = true,
            other if out.is_none() && !other.starts_with('-') => out = Some(PathBuf::from(other)),
            other => return Err(format!("unknown argument {other:?}")),
        }
    }
    o.out = out.ok_or("usage: moments_check OUT_DIR [--points N] [--chunks K] [--degree D] [--kappa K] [--write-only]")?;
    if o.chunks == 0 || o.points < o.chunks {
        return Err("--chunks must be at least 1 and at most --points".into());
    }
    Ok(o)
}

/// Point i of the torus with its outward normal (a fixed quasi-random sequence).
fn torus_point(i: usize) -> [f32; 6] {
    let u = (i as f64 * 0.618_033_988_749_894_9).fract() * std::f64::consts::TAU;
    let v = (i as f64 * 0.754_877_666_246_692_7).fract() * std::f64::consts::TAU;
    let (big, small) = (1.0, 0.4);
    let n = [v.cos() * u.cos(), v.cos() * u.sin(), v.sin()];
    let p = [
        3.0 + (big + small * v.cos()) * u.cos(),
        -2.0 + (big + small * v.cos()) * u.sin(),
        5.0 + small * v.sin(),
    ];
    [
        p[0] as f32,
        p[1] as f32,
        p[2] as f32,
        n[0] as f32,
        n[1] as f32,
        n[2] as f32,
    ]
}

fn write_ply(path: &Path, range: std::ops::Range<usize>) -> Result<(), String> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\ncomment torus, tools/moments_check.rs\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\nend_header\n",
        range.len()
    )
    .into_bytes();
    out.reserve(range.len() * 24);
    for i in range {
        for v in torus_point(i) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(path, out).map_err(|e| format!("writing {}: {e}", path.display()))
}

fn stablesurf() -> PathBuf {
    let exe = std::env::current_exe().unwrap_or_default();
    let dir = exe
        .parent()
        .and_then(Path::parent)
        .unwrap_or(Path::new("."));
    dir.join("stablesurf")
}

/// Runs the binary; returns its stdout.
fn run(args: &[&str]) -> Result<String, String> {
    let out = Command::new(stablesurf())
        .args(["-q"])
        .args(args)
        .output()
        .map_err(|e| format!("running {}: {e}", stablesurf().display()))?;
    if !out.status.success() {
        return Err(format!(
            "stablesurf {} failed: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok(String::from_utf8_lossy(&out.stdout).trim().to_string())
}

fn coefficients(path: &Path) -> Result<Vec<f64>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let json: serde_json::Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    json["coefficients"]
        .as_array()
        .ok_or("no coefficients")?
        .iter()
        .map(|v| v.as_f64().ok_or_else(|| "not a number".to_string()))
        .collect()
}

fn real_main() -> Result<(), String> {
    let o = parse()?;
    std::fs::create_dir_all(&o.out).map_err(|e| format!("{}: {e}", o.out.display()))?;
    let t = Instant::now();
    let whole = o.out.join("whole.ply");
    write_ply(&whole, 0..o.points)?;
    let mut chunks = Vec::new();
    for k in 0..o.chunks {
        let lo = o.points * k / o.chunks;
        let hi = o.points * (k + 1) / o.chunks;
        let path = o.out.join(format!("chunk-{k}.ply"));
        write_ply(&path, lo..hi)?;
        chunks.push(path.display().to_string());
    }
    println!(
        "wrote {} points as whole.ply and {} chunks in {:.1} s",
        o.points,
        o.chunks,
        t.elapsed().as_secs_f64()
    );
    if o.write_only {
        return Ok(());
    }
    let degree = o.degree.to_string();
    let fit_flags = [
        "--degree",
        degree.as_str(),
        "--kappa",
        o.kappa.as_str(),
        "--normals",
        "input",
    ];
    let part = |pass: usize, k: usize| {
        o.out
            .join(format!("pass{pass}-{k}.moments"))
            .display()
            .to_string()
    };
    let mut times = Vec::new();
    let mut arg = String::new();
    for pass in 1..=3 {
        let t = Instant::now();
        for (k, chunk) in chunks.iter().enumerate() {
            let out = part(pass, k);
            let mut args = vec!["moments", chunk.as_str(), "-o", out.as_str()];
            args.extend_from_slice(&fit_flags);
            match pass {
                2 => args.extend(["--center", arg.as_str()]),
                3 => args.extend(["--frame", arg.as_str()]),
                _ => {}
            }
            run(&args)?;
        }
        let elapsed = t.elapsed().as_secs_f64();
        if pass < 3 {
            let parts: Vec<String> = (0..o.chunks).map(|k| part(pass, k)).collect();
            let mut args = vec!["frame"];
            args.extend(parts.iter().map(String::as_str));
            arg = run(&args)?;
        }
        times.push(elapsed);
    }
    let t = Instant::now();
    let merged = o.out.join("from-moments.json").display().to_string();
    let parts: Vec<String> = (0..o.chunks).map(|k| part(3, k)).collect();
    let mut args = vec!["fit", "-o", merged.as_str()];
    args.extend_from_slice(&fit_flags);
    args.push("--from-moments");
    args.extend(parts.iter().map(String::as_str));
    run(&args)?;
    let merge_time = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let whole_model = o.out.join("whole.json").display().to_string();
    let whole_str = whole.display().to_string();
    let mut args = vec![
        "fit",
        whole_str.as_str(),
        "-o",
        whole_model.as_str(),
        "--keep-outliers",
    ];
    args.extend_from_slice(&fit_flags);
    run(&args)?;
    let whole_time = t.elapsed().as_secs_f64();
    let a = coefficients(Path::new(&merged))?;
    let b = coefficients(Path::new(&whole_model))?;
    let scale = b.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let diff = a
        .iter()
        .zip(&b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
        / scale;
    println!(
        "moments passes over {} chunks (sequential): center {:.2} s, scale {:.2} s, system {:.2} s; fit --from-moments {:.2} s",
        o.chunks, times[0], times[1], times[2], merge_time
    );
    println!("fit on the whole file: {whole_time:.2} s");
    println!(
        "max relative coefficient difference: {diff:.2e} (degree {}, kappa {})",
        o.degree, o.kappa
    );
    if diff > 1e-9 {
        return Err(format!("difference {diff:e} above 1e-9"));
    }
    Ok(())
}
