//! Offset bias of the detail mode on analytic shapes with exact normals: a sphere (radius 2,
//! centre (1, 2, 3)) and a torus (R = 2, r = 0.6), 20k points each by default, fitted with
//! `fit_detail` and the default `DetailParams`, meshed by `polygonize` (guard levels 0).
//!
//! Usage: `cargo run --release --features tools --example detail_bias -- [--points N] [--depth D]
//! [--epsilon E] [--kappa K] [--tolerance T] [--gradient|--three-levels] [--no-aux]
//! [--fit-chords] [--chord-share S]` (`--gradient`: the local fits' gradient rows ∇Q = n instead
//! of the 3L rows at ±ε, the default; `--fit-chords`: the meshing's fitted chords, as `run` does
//! in detail mode, with their default share, a quarter; `--chord-share S`: the chords with the
//! share S in (0, 1] of their least-squares move, 1 for the whole move).
//! Prints, per shape: cells, fit time, vertices, the mean and rms signed radial (sphere) / tube
//! (torus) error of the mesh vertices, and the mean over the mesh's area (each triangle's three
//! edge midpoints, weighted by its area), as fractions of the diagonal of the points' bounding
//! box (positive: outside the truth).

use std::time::Instant;

use stablesurf::detail::{fit_detail, AuxiliaryPoints, DetailParams, LocalConstraints};
use stablesurf::polygonize::{polygonize, PolygonizeParams};
use stablesurf::OrientedCloud;

/// A shape's exact signed distance (positive outside).
type SignedDistance = Box<dyn Fn([f64; 3]) -> f64>;

const GOLDEN: f64 = 2.399_963_229_728_653; // π(3 − √5)

/// `n` points of a Fibonacci sphere (unit directions).
fn fibonacci(n: usize) -> Vec<[f64; 3]> {
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let t = GOLDEN * i as f64;
            [r * t.cos(), r * t.sin(), z]
        })
        .collect()
}

fn sphere(n: usize) -> (OrientedCloud, SignedDistance) {
    let c = [1.0, 2.0, 3.0];
    let normals = fibonacci(n);
    let points = normals
        .iter()
        .map(|u| [0, 1, 2].map(|a| c[a] + 2.0 * u[a]))
        .collect();
    let sd = move |p: [f64; 3]| {
        let d = [0, 1, 2].map(|a| p[a] - c[a]);
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 2.0
    };
    (
        OrientedCloud {
            points,
            normals,
            weights: None,
        },
        Box::new(sd),
    )
}

fn torus(n: usize) -> (OrientedCloud, SignedDistance) {
    let (big, small) = (2.0, 0.6);
    // A 2D golden-ratio lattice on (u, v), with v drawn area-uniformly (density ∝ R + r cos v).
    let mut points = Vec::with_capacity(n);
    let mut normals = Vec::with_capacity(n);
    let phi = 0.5 * (1.0 + 5f64.sqrt());
    for i in 0..n {
        let u = std::f64::consts::TAU * (i as f64 + 0.5) / n as f64;
        let w = (i as f64 / phi).fract();
        // Invert the cdf of v: (v + (r/R) sin v)/(2π) = w, by Newton.
        let target = std::f64::consts::TAU * w;
        let mut v = target;
        for _ in 0..30 {
            let f = v + small / big * v.sin() - target;
            v -= f / (1.0 + small / big * v.cos());
        }
        let nv = [v.cos() * u.cos(), v.cos() * u.sin(), v.sin()];
        let rho = big + small * v.cos();
        points.push([rho * u.cos(), rho * u.sin(), small * v.sin()]);
        normals.push(nv);
    }
    let sd = move |p: [f64; 3]| {
        let rho = (p[0] * p[0] + p[1] * p[1]).sqrt();
        ((rho - big).powi(2) + p[2] * p[2]).sqrt() - small
    };
    (
        OrientedCloud {
            points,
            normals,
            weights: None,
        },
        Box::new(sd),
    )
}

fn main() -> anyhow::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut params = DetailParams::default();
    let mut n = 20_000;
    let mut depth = 7;
    let mut fit_chords = false;
    let mut chord_share = stablesurf::polygonize::CHORD_SHARE;
    while !args.is_empty() {
        let a = args.remove(0);
        match a.as_str() {
            "--gradient" => {
                params.constraints = LocalConstraints::Gradient;
                continue;
            }
            "--three-levels" => {
                params.constraints = LocalConstraints::ThreeLevels;
                continue;
            }
            "--no-aux" => {
                params.auxiliary = AuxiliaryPoints::None;
                continue;
            }
            "--fit-chords" => {
                fit_chords = true;
                continue;
            }
            _ => {}
        }
        if args.is_empty() {
            anyhow::bail!("{a} needs a value");
        }
        let v = args.remove(0);
        match a.as_str() {
            "--points" => n = v.parse()?,
            "--depth" => depth = v.parse()?,
            "--epsilon" => params.epsilon = v.parse()?,
            "--kappa" => params.kappa = v.parse()?,
            "--tolerance" => params.tolerance = v.parse()?,
            "--chord-share" => {
                chord_share = v.parse()?;
                fit_chords = true;
            }
            _ => anyhow::bail!("unknown flag {a}"),
        }
    }
    let mesh_params = PolygonizeParams {
        depth,
        guard_levels: 0,
        fit_chords,
        chord_share,
        ..PolygonizeParams::default()
    };
    println!(
        "shape\tpoints\tcells\tfit_s\tvertices\tmean_rel\trms_rel\tmax_abs_rel\tarea_mean_rel"
    );
    for (name, (cloud, sd)) in [("sphere", sphere(n)), ("torus", torus(n))] {
        let lo = (0..3).map(|a| cloud.points.iter().map(|p| p[a]).fold(f64::MAX, f64::min));
        let hi = (0..3).map(|a| cloud.points.iter().map(|p| p[a]).fold(f64::MIN, f64::max));
        let diagonal = lo
            .zip(hi)
            .map(|(l, h)| (h - l) * (h - l))
            .sum::<f64>()
            .sqrt();
        let t = Instant::now();
        let model = fit_detail(&cloud, &params)?;
        let fit_s = t.elapsed().as_secs_f64();
        let mesh = polygonize(&model, &model.region, &mesh_params)?.mesh;
        let errors: Vec<f64> = mesh.positions.iter().map(|&p| sd(p)).collect();
        let k = errors.len().max(1) as f64;
        let mean = errors.iter().sum::<f64>() / k;
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / k).sqrt();
        let worst = errors.iter().fold(0.0f64, |m, e| m.max(e.abs()));
        // The edge-midpoint rule on each triangle (exact for quadratics), weighted by area.
        let area_mean = stablesurf::measure::area_mean(&mesh, &sd);
        println!(
            "{name}\t{}\t{}\t{fit_s:.2}\t{}\t{:+.3e}\t{:.3e}\t{:.3e}\t{:+.3e}",
            cloud.points.len(),
            model.cells.len(),
            mesh.positions.len(),
            mean / diagonal,
            rms / diagonal,
            worst / diagonal,
            area_mean / diagonal
        );
    }
    Ok(())
}
