//! Tool: reproduces the experiments of Sahin & Unel (2008), section 7, and writes
//! `docs/paper-experiments.md` (tables, a statement of which claims hold) with picture grids
//! like the paper's figures 4–10 (`docs/img/paper-*.png`).
//!
//! Inputs: the six synthetic shapes of `stablesurf::testing::study` (sphere, torus, eight, heart,
//! cube, twisted object; exact normals) and the real models of `../shared/data` that are present
//! (normals from the file, else its faces, else the crust — the pipeline's `auto` source), each
//! reduced to `--points` points (default 3000, a deterministic stride for the real models).
//! Variants: clean; Gaussian noise of variance 0.0025 per coordinate in normalized units (the
//! normals are kept, as in the paper's noise tests); 15% of the points cut away (the largest
//! x + 0.3y + 0.2z). Methods: plain least squares (`ls`), 3L (κ = 0), and 3LRR with κ chosen by
//! the paper's rule (smallest grid κ with a positive leading form) and by stablesurf's default
//! `stable` rule; degrees 4, 6, 8; ε 0.05 and 0.01 (ε does not apply to `ls`).
//!
//! Per fit: κ, leading form positive on the unit sphere, zero-set components in the normalized
//! box [−4, 4]³ and whether one touches its boundary (both from `study::assess`, a sign-change
//! grid of spacing 0.1), the judge's verdict, mean and max first-order distance |f|/|∇f| of the
//! data to the zero set relative to the bounding-box diagonal, and the condition number of
//! MᵀM + κD.
//!
//! Usage: `tools/paper_experiments [--quick] [--out DIR] [--points N]`
//! (= `cargo run --release --features tools --example paper_experiments -- …`). `--quick` runs the torus at
//! degree 6 only (for CI) and writes into `target/paper-experiments-quick` unless `--out` is
//! given. Deterministic: fixed seeds, no timing in the document except the total wall time.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use image::{Rgb, RgbImage};
use rayon::prelude::*;
use stablesurf::fit::{fit, FitMethod, FitParams, Kappa, KappaRule};
use stablesurf::normals::{estimate_normals, NormalsParams};
use stablesurf::polygonize::{polygonize, PolygonizeParams};
use stablesurf::render::{render, RenderParams, View};
use stablesurf::testing::study::{assess, cut_away, sample, Assessment, Lcg, Shape, Variant};
use stablesurf::{Aabb, ImplicitPolynomial, OrientedCloud};

/// Real models tried (skipped when absent), with the paper's closest object in brackets.
const REAL_MODELS: [&str; 4] = [
    "duck.ply",
    "patella_vhf_left.ply",
    "bunny_zipper.ply",
    "max_planck.obj",
];

const DEGREES: [u32; 3] = [4, 6, 8];
const EPSILONS: [f64; 2] = [0.05, 0.01];
const SEED: u64 = 2008;
/// Tile size of the methods grid; the robustness grid uses `TILE_SMALL`.
const TILE: u32 = 128;
const TILE_SMALL: u32 = 96;

/// One way of fitting.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Method {
    Ls,
    ThreeL,
    Paper,
    Stable,
}

impl Method {
    const ALL: [Method; 4] = [Method::Ls, Method::ThreeL, Method::Paper, Method::Stable];

    fn name(self) -> &'static str {
        match self {
            Method::Ls => "LS",
            Method::ThreeL => "3L",
            Method::Paper => "3LRR paper κ",
            Method::Stable => "3LRR stable κ",
        }
    }

    fn params(self, degree: u32, epsilon: f64) -> FitParams {
        let base = FitParams {
            degree,
            epsilon,
            ..FitParams::default()
        };
        match self {
            Method::Ls => FitParams {
                method: FitMethod::Ls,
                ..base
            },
            Method::ThreeL => FitParams {
                method: FitMethod::ThreeL,
                kappa: Kappa::Fixed(0.0),
                ..base
            },
            Method::Paper => FitParams {
                kappa_rule: KappaRule::Paper,
                ..base
            },
            Method::Stable => FitParams {
                kappa_rule: KappaRule::Stable,
                ..base
            },
        }
    }
}

/// One input: a name and its three variants.
struct Input {
    name: String,
    synthetic: bool,
    clouds: Vec<(Variant, OrientedCloud)>,
}

/// The result of one fit.
#[derive(Clone, Debug)]
struct Row {
    input: String,
    synthetic: bool,
    variant: Variant,
    degree: u32,
    epsilon: Option<f64>,
    method: Method,
    outcome: Result<Outcome, String>,
}

#[derive(Clone, Debug)]
struct Outcome {
    kappa: f64,
    verdict: Assessment,
    mean_rel: f64,
    max_rel: f64,
    condition: f64,
    /// Automatic κ found no qualifying grid value and fell back to κ = 1e-2.
    fallback: bool,
    polynomial: ImplicitPolynomial,
}

struct Args {
    quick: bool,
    out: PathBuf,
    points: usize,
}

fn parse_args() -> Result<Args, String> {
    let mut quick = false;
    let mut out = None;
    let mut points = 3000;
    let mut it = std::env::args().skip(1);
    while let Some(a) = it.next() {
        match a.as_str() {
            "--quick" => quick = true,
            "--out" => out = Some(PathBuf::from(it.next().ok_or("--out needs a directory")?)),
            "--points" => {
                points = it
                    .next()
                    .and_then(|v| v.parse().ok())
                    .ok_or("--points needs a number")?
            }
            "-h" | "--help" => {
                return Err("usage: paper_experiments [--quick] [--out DIR] [--points N]".into())
            }
            other => {
                return Err(format!(
                    "unknown argument {other}: use --quick, --out DIR, --points N"
                ))
            }
        }
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let out = out.unwrap_or_else(|| {
        if quick {
            root.join("target/paper-experiments-quick")
        } else {
            root.join("docs")
        }
    });
    Ok(Args { quick, out, points })
}

/// Degrades a real cloud the way `study::sample` degrades the synthetic ones.
fn degrade(cloud: &OrientedCloud, variant: Variant, seed: u64) -> OrientedCloud {
    match variant {
        Variant::Clean => cloud.clone(),
        Variant::Noisy => {
            let n = cloud.points.len().max(1) as f64;
            let mut c = [0.0; 3];
            for p in &cloud.points {
                for a in 0..3 {
                    c[a] += p[a] / n;
                }
            }
            let scale = cloud
                .points
                .iter()
                .map(|p| {
                    ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt()
                })
                .sum::<f64>()
                / n;
            let sigma = 0.05 * scale;
            let mut rng = Lcg::new(seed);
            let points = cloud
                .points
                .iter()
                .map(|p| p.map(|v| v + sigma * rng.normal()))
                .collect();
            OrientedCloud {
                points,
                normals: cloud.normals.clone(),
                weights: None,
            }
        }
        Variant::Cut => cut_away(cloud),
    }
}

/// Loads a real model with the pipeline's automatic normals, reduced to about `n` points.
fn load_real(path: &Path, n: usize) -> Result<OrientedCloud, String> {
    let scan = stablesurf::import::read_scan(path).map_err(|e| e.to_string())?;
    let normals =
        estimate_normals(&scan.cloud, &NormalsParams::default()).map_err(|e| e.to_string())?;
    let cloud = normals.cloud;
    let stride = (cloud.points.len() / n.max(1)).max(1);
    let (points, normals) = cloud
        .points
        .iter()
        .zip(&cloud.normals)
        .step_by(stride)
        .map(|(p, q)| (*p, *q))
        .unzip();
    Ok(OrientedCloud {
        points,
        normals,
        weights: None,
    })
}

fn run_fit(
    cloud: &OrientedCloud,
    method: Method,
    degree: u32,
    epsilon: f64,
) -> Result<Outcome, String> {
    let model = fit(cloud, &method.params(degree, epsilon)).map_err(|e| e.to_string())?;
    let verdict = assess(&model.polynomial, cloud);
    let diag = model.diagnostics.clone().unwrap_or_default();
    Ok(Outcome {
        kappa: model.fit.as_ref().map_or(0.0, |f| f.kappa),
        verdict,
        mean_rel: diag.mean_distance_relative,
        max_rel: diag.max_distance_relative,
        condition: diag.condition_number,
        fallback: diag.kappa_fallback,
        polynomial: model.polynomial,
    })
}

/// Renders the zero set of `poly` inside the normalized box [−2.2, 2.2]³ (input coordinates),
/// with a frame: green when the judge calls the fit good, red otherwise, grey for an error.
fn tile(outcome: &Result<Outcome, String>, size: u32) -> RgbImage {
    let frame = match outcome {
        Ok(o) if o.verdict.good => Rgb([40u8, 160, 60]),
        Ok(_) => Rgb([200u8, 40, 40]),
        Err(_) => Rgb([120u8, 120, 120]),
    };
    let mut img = match outcome {
        Ok(o) => {
            let p = &o.polynomial;
            let r = 2.2 * p.scale;
            let region = Aabb {
                min: [0, 1, 2].map(|a| p.center[a] - r),
                max: [0, 1, 2].map(|a| p.center[a] + r),
            };
            let params = PolygonizeParams {
                depth: 6,
                guard_levels: 1,
                ..PolygonizeParams::default()
            };
            match polygonize(p, &region, &params) {
                Ok(out) => render(
                    &out.mesh,
                    &RenderParams {
                        size,
                        view: View::Iso,
                        ..RenderParams::default()
                    },
                ),
                Err(_) => RgbImage::from_pixel(size, size, Rgb([236, 238, 242])),
            }
        }
        Err(_) => RgbImage::from_pixel(size, size, Rgb([236, 238, 242])),
    };
    for i in 0..size {
        for t in 0..3 {
            img.put_pixel(i, t, frame);
            img.put_pixel(i, size - 1 - t, frame);
            img.put_pixel(t, i, frame);
            img.put_pixel(size - 1 - t, i, frame);
        }
    }
    img
}

/// Composes tiles (row-major, `cols` per row) into one image with a 4-pixel white gutter.
fn grid(tiles: &[RgbImage], cols: usize) -> RgbImage {
    let gap = 4u32;
    let size = tiles.first().map_or(TILE, |t| t.width());
    let rows = tiles.len().div_ceil(cols.max(1)) as u32;
    let w = cols as u32 * (size + gap) + gap;
    let h = rows * (size + gap) + gap;
    let mut img = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    for (i, t) in tiles.iter().enumerate() {
        let (c, r) = ((i % cols) as u32, (i / cols) as u32);
        image::imageops::replace(
            &mut img,
            t,
            (gap + c * (size + gap)) as i64,
            (gap + r * (size + gap)) as i64,
        );
    }
    img
}

fn fmt_e(v: f64) -> String {
    if v == 0.0 {
        "0".into()
    } else {
        format!("{v:.1e}")
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    };
    let start = Instant::now();
    let shapes: Vec<Shape> = if args.quick {
        vec![Shape::Torus]
    } else {
        Shape::ALL.to_vec()
    };
    let degrees: Vec<u32> = if args.quick {
        vec![6]
    } else {
        DEGREES.to_vec()
    };

    // Inputs.
    let mut inputs: Vec<Input> = shapes
        .iter()
        .map(|&s| Input {
            name: s.name().to_string(),
            synthetic: true,
            clouds: Variant::ALL
                .iter()
                .map(|&v| (v, sample(s, v, args.points, SEED)))
                .collect(),
        })
        .collect();
    if !args.quick {
        let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
        for (i, file) in REAL_MODELS.iter().enumerate() {
            let path = data.join(file);
            if !path.exists() {
                eprintln!("paper_experiments: {} not found, skipped", path.display());
                continue;
            }
            match load_real(&path, args.points) {
                Ok(cloud) => inputs.push(Input {
                    name: file.split('.').next().unwrap_or(file).to_string(),
                    synthetic: false,
                    clouds: Variant::ALL
                        .iter()
                        .map(|&v| (v, degrade(&cloud, v, SEED + i as u64)))
                        .collect(),
                }),
                Err(e) => eprintln!("paper_experiments: {file}: {e}; skipped"),
            }
        }
    }
    eprintln!(
        "paper_experiments: inputs ready after {:.1} s",
        start.elapsed().as_secs_f64()
    );

    // All fits (in parallel over cases; each case is deterministic).
    let mut jobs = Vec::new();
    for (ii, input) in inputs.iter().enumerate() {
        for (vi, _) in input.clouds.iter().enumerate() {
            for &degree in &degrees {
                for method in Method::ALL {
                    let eps: Vec<Option<f64>> = if method == Method::Ls {
                        vec![None]
                    } else {
                        EPSILONS.iter().map(|&e| Some(e)).collect()
                    };
                    for epsilon in eps {
                        jobs.push((ii, vi, degree, method, epsilon));
                    }
                }
            }
        }
    }
    let rows: Vec<Row> = jobs
        .par_iter()
        .with_max_len(1)
        .map(|&(ii, vi, degree, method, epsilon)| {
            let input = &inputs[ii];
            let (variant, cloud) = &input.clouds[vi];
            Row {
                input: input.name.clone(),
                synthetic: input.synthetic,
                variant: *variant,
                degree,
                epsilon,
                method,
                outcome: run_fit(cloud, method, degree, epsilon.unwrap_or(0.05)),
            }
        })
        .collect();
    let fit_secs = start.elapsed().as_secs_f64();
    eprintln!(
        "paper_experiments: {} fits done after {fit_secs:.1} s",
        rows.len()
    );

    // Picture grids.
    let img_dir = args.out.join("img");
    if let Err(e) = std::fs::create_dir_all(&img_dir) {
        eprintln!(
            "paper_experiments: cannot create {}: {e}",
            img_dir.display()
        );
        std::process::exit(1);
    }
    let find = |input: &str, variant: Variant, degree: u32, method: Method, eps: Option<f64>| {
        rows.iter().find(|r| {
            r.input == input
                && r.variant == variant
                && r.degree == degree
                && r.method == method
                && r.epsilon == eps
        })
    };
    let names: Vec<String> = inputs.iter().map(|i| i.name.clone()).collect();
    let top_degree = *degrees.last().unwrap_or(&8);
    // Figure A (paper figures 4–8): methods side by side, clean data, highest degree, ε = 0.05.
    let mut cells_a = Vec::new();
    for name in &names {
        for method in Method::ALL {
            let eps = if method == Method::Ls {
                None
            } else {
                Some(0.05)
            };
            cells_a.push(
                find(name, Variant::Clean, top_degree, method, eps).map(|r| r.outcome.clone()),
            );
        }
    }
    // Figure B (paper figures 9–10): 3LRR stable κ, every variant × degree, ε = 0.05.
    let mut cells_b = Vec::new();
    for name in &names {
        for variant in Variant::ALL {
            for &degree in &degrees {
                cells_b.push(
                    find(name, variant, degree, Method::Stable, Some(0.05))
                        .map(|r| r.outcome.clone()),
                );
            }
        }
    }
    let render_all = |cells: &[Option<Result<Outcome, String>>], size: u32| -> Vec<RgbImage> {
        cells
            .par_iter()
            .with_max_len(1)
            .map(|c| tile(&c.clone().unwrap_or_else(|| Err("missing".into())), size))
            .collect()
    };
    let tiles_a = render_all(&cells_a, TILE);
    let tiles_b = render_all(&cells_b, TILE_SMALL);
    let fig_a = img_dir.join("paper-methods.png");
    let fig_b = img_dir.join("paper-robustness.png");
    for (img, path) in [
        (grid(&tiles_a, Method::ALL.len()), &fig_a),
        (grid(&tiles_b, Variant::ALL.len() * degrees.len()), &fig_b),
    ] {
        if let Err(e) = img.save(path) {
            eprintln!("paper_experiments: cannot write {}: {e}", path.display());
            std::process::exit(1);
        }
    }
    let total_secs = start.elapsed().as_secs_f64();
    eprintln!("paper_experiments: pictures done after {total_secs:.1} s");

    let doc = document(&args, &rows, &names, &degrees, fit_secs, total_secs);
    let doc_path = args.out.join("paper-experiments.md");
    if let Err(e) = std::fs::write(&doc_path, doc) {
        eprintln!(
            "paper_experiments: cannot write {}: {e}",
            doc_path.display()
        );
        std::process::exit(1);
    }
    let csv_path = args.out.join("paper-experiments.csv");
    if let Err(e) = std::fs::write(&csv_path, csv(&rows)) {
        eprintln!(
            "paper_experiments: cannot write {}: {e}",
            csv_path.display()
        );
        std::process::exit(1);
    }
    println!("{}", doc_path.display());
}

fn csv(rows: &[Row]) -> String {
    let mut s = String::from(
        "input,variant,degree,epsilon,method,kappa,leading_form_positive,components,touches_box,good,mean_dist_rel,max_dist_rel,condition_number,kappa_fallback,error\n",
    );
    for r in rows {
        let eps = r.epsilon.map_or("-".to_string(), |e| e.to_string());
        match &r.outcome {
            Ok(o) => {
                let _ = writeln!(
                    s,
                    "{},{},{},{eps},{},{:e},{},{},{},{},{:.3e},{:.3e},{:.3e},{},",
                    r.input,
                    r.variant.name(),
                    r.degree,
                    r.method.name(),
                    o.kappa,
                    o.verdict.positive,
                    o.verdict.components,
                    o.verdict.touches_box,
                    o.verdict.good,
                    o.mean_rel,
                    o.max_rel,
                    o.condition,
                    o.fallback
                );
            }
            Err(e) => {
                let _ = writeln!(
                    s,
                    "{},{},{},{eps},{},,,,,,,,,,\"{}\"",
                    r.input,
                    r.variant.name(),
                    r.degree,
                    r.method.name(),
                    e.replace('"', "'")
                );
            }
        }
    }
    s
}

/// Counts of good fits and medians, per group.
#[derive(Default)]
struct Tally {
    good: usize,
    total: usize,
    positive: usize,
    fallback: usize,
    kappas: Vec<f64>,
    means: Vec<f64>,
    conds: Vec<f64>,
}

impl Tally {
    fn add(&mut self, r: &Row) {
        self.total += 1;
        if let Ok(o) = &r.outcome {
            self.good += o.verdict.good as usize;
            self.positive += o.verdict.positive as usize;
            self.fallback += o.fallback as usize;
            self.kappas.push(o.kappa);
            if o.mean_rel.is_finite() {
                self.means.push(o.mean_rel);
            }
            if o.condition.is_finite() {
                self.conds.push(o.condition);
            }
        }
    }
    fn cell(&self) -> String {
        if self.total == 0 {
            "-".into()
        } else {
            format!("{}/{}", self.good, self.total)
        }
    }
    fn pct(&self) -> f64 {
        100.0 * self.good as f64 / self.total.max(1) as f64
    }
}

fn tally<'a>(rows: impl Iterator<Item = &'a Row>) -> Tally {
    let mut t = Tally::default();
    for r in rows {
        t.add(r);
    }
    t
}

fn document(
    args: &Args,
    rows: &[Row],
    names: &[String],
    degrees: &[u32],
    fit_secs: f64,
    total_secs: f64,
) -> String {
    let mut d = String::new();
    let _ = writeln!(d, "# The paper's experiments, reproduced\n");
    let _ = writeln!(
        d,
        "Generated by `tools/paper_experiments{}` ({} fits, {} points per input, fits {fit_secs:.0} s, \
         total {total_secs:.0} s wall on a 2-core machine shared with other builds). Do not edit by hand.\n",
        if args.quick { " --quick" } else { "" },
        rows.len(),
        args.points
    );
    let _ = writeln!(
        d,
        "Paper: Sahin & Unel, *Stable Algebraic Surfaces for 3D Object Representation*, J Math Imaging Vis \
         32:127–137 (2008), section 7 and figures 4–10.\n\n\
         **Setup.** Synthetic shapes (`stablesurf::testing::study`): {} with exact normals{}. \
         Variants: *clean*; *noisy* (Gaussian noise of variance 0.0025 per coordinate in normalized units, \
         σ = 5% of the mean radius, normals kept — the paper's figure 10 level for the eight); *cut* (15% of \
         the points with the largest x + 0.3y + 0.2z removed — the paper's figure 9 level). Methods: LS \
         (paper section 4), 3L (κ = 0), 3LRR with κ chosen by the paper's rule (smallest κ on the grid 0, \
         1e-8 … 1 whose leading form is positive on the unit sphere) and by stablesurf's default *stable* \
         rule (positive at every larger κ, certified containment radius, no extra zero-set piece). Degrees \
         {}, ε 0.05 and 0.01 (LS has no ε).\n\n\
         **Measures.** *pos*: leading form positive on the unit sphere (the zero set is then closed and \
         bounded). *comp*: connected pieces of the zero set in the normalized box [−4, 4]³ (the data's mean \
         radius is 1), counted on a sign-change grid of spacing 0.1; *edge* when a piece reaches the box's \
         boundary (an open sheet). *good*: pos, exactly one piece, near the data, not reaching the boundary \
         (`study::assess`, independent of the fit's own checks). *mean/max*: first-order distance \
         |f|/|∇f| from the data points to the zero set, relative to the data's bounding-box diagonal. \
         *cond*: 2-norm condition number of MᵀM + κD (MᵀM for LS).\n",
        names
            .iter()
            .take_while(|n| Shape::ALL.iter().any(|s| s.name() == n.as_str()))
            .cloned()
            .collect::<Vec<_>>()
            .join(", "),
        {
            let real: Vec<&String> = names
                .iter()
                .filter(|n| !Shape::ALL.iter().any(|s| s.name() == n.as_str()))
                .collect();
            if real.is_empty() {
                String::new()
            } else {
                format!(
                    "; real models from `../shared/data`: {} (normals from the file, its faces or the crust, as \
                     `stablesurf run`; reduced to {} points by a fixed stride)",
                    real.iter().map(|s| s.as_str()).collect::<Vec<_>>().join(", "),
                    args.points
                )
            }
        },
        degrees.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")
    );

    // Summary by method × degree.
    let _ = writeln!(
        d,
        "## Summary: good fits (one closed piece near the data, nothing else in the box)\n"
    );
    let mut header = String::from("| method | inputs |");
    let mut rule = String::from("|---|---|");
    for deg in degrees {
        let _ = write!(header, " degree {deg} |");
        rule.push_str("---|");
    }
    header.push_str(
        " all | leading form positive | κ fallback | median κ | median mean dist. | median cond. |",
    );
    rule.push_str("---|---|---|---|---|---|");
    let _ = writeln!(d, "{header}\n{rule}");
    for method in Method::ALL {
        for (label, synth) in [("synthetic", true), ("real", false)] {
            let sel = |r: &&Row| r.method == method && r.synthetic == synth;
            let all = tally(rows.iter().filter(sel));
            if all.total == 0 {
                continue;
            }
            let mut line = format!("| {} | {label} |", method.name());
            for &deg in degrees {
                let t = tally(rows.iter().filter(sel).filter(|r| r.degree == deg));
                let _ = write!(line, " {} |", t.cell());
            }
            let _ = write!(
                line,
                " {} ({:.0}%) | {}/{} | {} | {} | {:.2e} | {:.1e} |",
                all.cell(),
                all.pct(),
                all.positive,
                all.total,
                all.fallback,
                fmt_e(median(all.kappas.clone())),
                median(all.means.clone()),
                median(all.conds.clone())
            );
            let _ = writeln!(d, "{line}");
        }
    }
    let _ = writeln!(d);

    // Per input × method (clean / noisy / cut).
    let _ = writeln!(
        d,
        "## Good fits per input and variant (all degrees and ε)\n"
    );
    let _ = writeln!(
        d,
        "| input | {} |",
        Method::ALL
            .iter()
            .map(|m| format!("{} clean / noisy / cut", m.name()))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    let _ = writeln!(d, "|---|{}", "---|".repeat(Method::ALL.len()));
    for name in names {
        let mut line = format!("| {name} |");
        for method in Method::ALL {
            let cells: Vec<String> = Variant::ALL
                .iter()
                .map(|&v| {
                    tally(
                        rows.iter()
                            .filter(|r| &r.input == name && r.method == method && r.variant == v),
                    )
                    .cell()
                })
                .collect();
            let _ = write!(line, " {} |", cells.join(" / "));
        }
        let _ = writeln!(d, "{line}");
    }
    let _ = writeln!(d);

    // Pictures.
    let _ = writeln!(
        d,
        "## Pictures\n\nZero sets rendered inside the normalized box [−2.2, 2.2]³ (octree depth 6); the frame is \
         green when the fit is *good*, red otherwise. Open sheets that leave the box are cut by it, as in the \
         paper's figures.\n\n\
         **Methods** (like figures 4–8): one row per input ({}), columns LS, 3L, 3LRR paper κ, 3LRR stable κ; \
         clean data, degree {}, ε = 0.05.\n\n![methods](img/paper-methods.png)\n\n\
         **Robustness** (like figures 9–10): 3LRR with the stable κ, ε = 0.05; one row per input, columns \
         clean, noisy, cut, each at degrees {}.\n\n![robustness](img/paper-robustness.png)\n",
        names.join(", "),
        degrees.last().unwrap_or(&8),
        degrees.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")
    );

    // Claims.
    let _ = writeln!(
        d,
        "## Where the paper's claims hold, and where they do not\n"
    );
    let _ = writeln!(d, "{}", claims(rows, degrees));

    // Full table.
    let _ = writeln!(
        d,
        "## Every fit\n\nAlso in `paper-experiments.csv` beside this page.\n\n<details><summary>{} rows</summary>\n",
        rows.len()
    );
    let _ = writeln!(
        d,
        "| input | variant | n | ε | method | κ | pos | comp | good | mean | max | cond |"
    );
    let _ = writeln!(d, "|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in rows {
        let eps = r.epsilon.map_or("-".to_string(), |e| e.to_string());
        match &r.outcome {
            Ok(o) => {
                let _ = writeln!(
                    d,
                    "| {} | {} | {} | {eps} | {} | {} | {} | {}{} | {} | {:.1e} | {:.1e} | {:.1e} |",
                    r.input,
                    r.variant.name(),
                    r.degree,
                    r.method.name(),
                    if r.method == Method::Ls || r.method == Method::ThreeL {
                        "-".into()
                    } else if o.fallback {
                        format!("{} (fallback)", fmt_e(o.kappa))
                    } else {
                        fmt_e(o.kappa)
                    },
                    if o.verdict.positive { "yes" } else { "no" },
                    o.verdict.components,
                    if o.verdict.touches_box { " edge" } else { "" },
                    if o.verdict.good { "good" } else { "**bad**" },
                    o.mean_rel,
                    o.max_rel,
                    o.condition
                );
            }
            Err(e) => {
                let _ = writeln!(
                    d,
                    "| {} | {} | {} | {eps} | {} | error: {} |||||||",
                    r.input,
                    r.variant.name(),
                    r.degree,
                    r.method.name(),
                    e.replace('|', "/")
                );
            }
        }
    }
    let _ = writeln!(d, "\n</details>");
    d
}

/// The plain statements, each with the numbers behind it.
fn claims(rows: &[Row], degrees: &[u32]) -> String {
    let mut s = String::new();
    let by = |m: Method| rows.iter().filter(move |r| r.method == m);
    let good_of = |it: &mut dyn Iterator<Item = &Row>| tally(it);

    // 1. LS only works on the torus (low degree).
    let ls_torus =
        good_of(&mut by(Method::Ls).filter(|r| r.input == "torus" && r.variant == Variant::Clean));
    let ls_other =
        good_of(&mut by(Method::Ls).filter(|r| r.input != "torus" && r.variant == Variant::Clean));
    let _ = writeln!(
        s,
        "1. **Least squares is unstable except on very simple shapes (figure 4).** Holds. Clean data: LS is good on \
         the torus in {} cases and on the other inputs in {} ({:.0}%).",
        ls_torus.cell(),
        ls_other.cell(),
        ls_other.pct()
    );
    // 2. 3L ok for simple shapes, fails for complex ones.
    let mut per_input = BTreeMap::new();
    for r in by(Method::ThreeL).filter(|r| r.variant == Variant::Clean) {
        per_input
            .entry(r.input.clone())
            .or_insert_with(Tally::default)
            .add(r);
    }
    let list: Vec<String> = per_input
        .iter()
        .map(|(k, t)| format!("{k} {}", t.cell()))
        .collect();
    let l3 = good_of(&mut by(Method::ThreeL));
    let _ = writeln!(
        s,
        "2. **3L alone fits simple shapes but leaves extra pieces on complex ones (figures 5–6).** Partly: 3L \
         (κ = 0) is good in {} of all cases ({:.0}%); clean data per input: {}.",
        l3.cell(),
        l3.pct(),
        list.join(", ")
    );
    // 3. RR with the paper's κ rule stabilizes everything.
    let paper = good_of(&mut by(Method::Paper));
    let stable = good_of(&mut by(Method::Stable));
    let paper_pos = paper.positive;
    let verdict = if paper.good == paper.total {
        "Holds"
    } else {
        "Does not hold in full"
    };
    let _ = writeln!(
        s,
        "3. **3LRR stabilizes every fit once the leading form is positive (sections 6.2–6.3, figures 7–8).** \
         {verdict}: the paper's rule reaches a positive leading form in {paper_pos}/{} cases, but only {} ({:.0}%) \
         are good — a bounded zero set can still carry extra closed pieces, and positivity is not monotone in κ. \
         stablesurf's stable rule gives {} ({:.0}%).",
        paper.total,
        paper.cell(),
        paper.pct(),
        stable.cell(),
        stable.pct()
    );
    for &deg in degrees {
        let p = good_of(&mut by(Method::Paper).filter(|r| r.degree == deg));
        let st = good_of(&mut by(Method::Stable).filter(|r| r.degree == deg));
        let _ = writeln!(
            s,
            "   - degree {deg}: paper rule {}, stable rule {}.",
            p.cell(),
            st.cell()
        );
    }
    let fb_inputs: BTreeMap<String, usize> = by(Method::Stable)
        .filter(|r| matches!(&r.outcome, Ok(o) if o.fallback))
        .fold(BTreeMap::new(), |mut m, r| {
            *m.entry(r.input.clone()).or_insert(0) += 1;
            m
        });
    let _ = writeln!(
        s,
        "   - Caveat on the stable rule's score: its own acceptance test (one zero-set piece near the data, nothing else) is close to this page's judge, so \"good\" is partly by construction; what it costs shows in κ (claim 4) and accuracy (claim 8). In {} of {} stable-rule fits no grid κ qualified and it fell back to κ = 1e-2, a strongly smoothed blob{}.",
        stable.fallback,
        stable.total,
        if fb_inputs.is_empty() {
            String::new()
        } else {
            format!(
                " ({})",
                fb_inputs
                    .iter()
                    .map(|(k, v)| format!("{k} {v}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        }
    );
    // 4. κ range.
    let kp = median(paper.kappas.clone());
    let ks = median(stable.kappas.clone());
    let frac_small = {
        let k = &stable.kappas;
        100.0 * k.iter().filter(|&&v| v <= 1e-4).count() as f64 / k.len().max(1) as f64
    };
    let _ = writeln!(
        s,
        "4. **κ of 1e-5 … 1e-4 is typical (section 7; 1e-4 … 1e-3 in 6.2).** Partly: the paper's rule picks a \
         median κ of {}, the stable rule {} ({frac_small:.0}% of its choices are ≤ 1e-4).",
        fmt_e(kp),
        fmt_e(ks)
    );
    // 5. Robustness to 15% missing data and noise.
    for (number, variant, what) in [
        (5, Variant::Cut, "15% missing data (figure 9)"),
        (6, Variant::Noisy, "noise of variance 0.0025 (figure 10)"),
    ] {
        let st = good_of(&mut by(Method::Stable).filter(|r| r.variant == variant));
        let p = good_of(&mut by(Method::Paper).filter(|r| r.variant == variant));
        let clean = good_of(&mut by(Method::Stable).filter(|r| r.variant == Variant::Clean));
        let mean_v = median(st.means.clone());
        let mean_c = median(clean.means.clone());
        let _ = writeln!(
            s,
            "{number}. **Robust to {what}.** {}: good fits {} with the stable rule, {} with the paper's rule; median \
             mean distance {:.2e} against {:.2e} on clean data.",
            if st.pct() >= 90.0 { "Holds with the stable rule" } else { "Partly" },
            st.cell(),
            p.cell(),
            mean_v,
            mean_c
        );
    }
    // 6. Condition number.
    let c3l = median(good_of(&mut by(Method::ThreeL)).conds);
    let cst = median(stable.conds.clone());
    let _ = writeln!(
        s,
        "7. **RR lowers the condition number (section 6).** Holds: median condition number {:.1e} for 3L, {:.1e} \
         for 3LRR (stable κ).",
        c3l, cst
    );
    // 7. Accuracy.
    let m3l = median(
        good_of(&mut by(Method::ThreeL).filter(|r| matches!(&r.outcome, Ok(o) if o.verdict.good)))
            .means,
    );
    let mst = median(
        good_of(&mut by(Method::Stable).filter(|r| matches!(&r.outcome, Ok(o) if o.verdict.good)))
            .means,
    );
    let _ = writeln!(
        s,
        "8. **RR keeps the accuracy of 3L (\"virtually unaffects the shape\").** On the cases each method fits \
         well, the median mean distance is {:.2e} for 3L and {:.2e} for 3LRR (stable κ), relative to the \
         diagonal; regularization smooths fine detail (see the real models' max distances in the table below).",
        m3l, mst
    );
    // Paired: where 3L is good, what does the stable 3LRR fit of the same case give?
    let mut ratios = Vec::new();
    for r in by(Method::ThreeL) {
        let Ok(o) = &r.outcome else { continue };
        if !o.verdict.good || o.mean_rel <= 0.0 {
            continue;
        }
        let twin = rows.iter().find(|t| {
            t.method == Method::Stable
                && t.input == r.input
                && t.variant == r.variant
                && t.degree == r.degree
                && t.epsilon == r.epsilon
        });
        if let Some(Ok(t)) = twin.map(|t| &t.outcome) {
            ratios.push(t.mean_rel / o.mean_rel);
        }
    }
    if !ratios.is_empty() {
        let _ = writeln!(
            s,
            "   - Paired over the {} cases where 3L alone is good: the stable 3LRR fit's mean distance is {:.2}× that of 3L (median; {:.0}% of pairs within 1.5×).",
            ratios.len(),
            median(ratios.clone()),
            100.0 * ratios.iter().filter(|&&q| q <= 1.5).count() as f64 / ratios.len() as f64
        );
    }
    let top = degrees.last().copied().unwrap_or(8);
    let real: Vec<String> = by(Method::Stable)
        .filter(|r| {
            !r.synthetic
                && r.variant == Variant::Clean
                && r.degree == top
                && r.epsilon == Some(0.05)
        })
        .filter_map(|r| {
            r.outcome
                .as_ref()
                .ok()
                .map(|o| format!("{} {:.1e} / {:.1e}", r.input, o.mean_rel, o.max_rel))
        })
        .collect();
    let worst_max = by(Method::Stable)
        .filter(|r| {
            !r.synthetic
                && r.variant == Variant::Clean
                && r.degree == top
                && r.epsilon == Some(0.05)
        })
        .filter_map(|r| r.outcome.as_ref().ok().map(|o| o.max_rel))
        .fold(0.0, f64::max);
    if !real.is_empty() {
        let _ = writeln!(
            s,
            "9. **Fine detail (section 7: \"globally stable and accurate fits of higher degrees … for range data \
             with fine details\").** {}: one polynomial of degree {top} keeps the coarse shape only (worst max \
             distance {:.1}% of the diagonal). Mean / max distance of the data to the stable-κ zero set, relative \
             to the diagonal (clean, ε = 0.05): {}. A max of several percent of the diagonal is a visible loss of \
             ears, beaks and faces (see the pictures); `stablesurf run --mode detail` is meant for that.",
            if worst_max > 0.02 { "Does not hold for detailed real models" } else { "Holds on these models" },
            100.0 * worst_max,
            real.join(", ")
        );
    }
    s
}
