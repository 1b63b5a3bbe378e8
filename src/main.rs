//! The `stablesurf` binary: parse the command line, call the library, map errors to exit codes.
//!
//! Exit codes: 0 success, 1 runtime error (bad input, failed fit, unwritable output), 2 usage
//! error. stdout carries only machine-readable output (`--json`); everything else goes to stderr.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::str::FromStr;
use std::time::Duration;

mod cli;

use anyhow::{anyhow, Context, Result};
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};

use crate::cli::{Cli, CommandArgs};
use stablesurf::cache::Cache;
use stablesurf::pipeline::{
    self, Keep, Observer, OutputFormat, PipelineConfig, ScanSource, StageRecord,
};
use stablesurf::trim::{TrimMode, TrimParams};
use stablesurf::{export, fit, import, normals, polygonize, Aabb, TriangleMesh};

/// A command line that parsed but makes no sense (exit code 2).
#[derive(Debug)]
struct UsageError(String);

impl std::fmt::Display for UsageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for UsageError {}

fn usage(msg: impl Into<String>) -> anyhow::Error {
    anyhow::Error::new(UsageError(msg.into()))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match real_main(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            if err.chain().any(|e| {
                e.downcast_ref::<std::io::Error>()
                    .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            }) {
                return ExitCode::SUCCESS;
            }
            eprintln!("stablesurf: error: {err:#}");
            if err.downcast_ref::<UsageError>().is_some() {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}

fn real_main(cli: Cli) -> Result<()> {
    // Every numeric flag was checked against its range (`cli::THREADS`, `cli::DEGREE`, …)
    // while the command line was parsed: out of range is clap's usage error, before any work.
    if let Some(n) = cli.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .with_context(|| format!("setting up the thread pool of -j {n}"))?;
    }
    let verbosity = if cli.quiet {
        Verbosity::Quiet
    } else if cli.verbose > 0 {
        Verbosity::Verbose
    } else {
        Verbosity::Normal
    };
    match cli.command {
        CommandArgs::Run(args) => cmd_run(args, verbosity),
        CommandArgs::Normals(args) => cmd_normals(args, verbosity),
        CommandArgs::Fit(args) => cmd_fit(args, verbosity),
        CommandArgs::Moments(args) => cmd_moments(args, verbosity),
        CommandArgs::Frame(args) => cmd_frame(args),
        CommandArgs::Mesh(args) => cmd_mesh(args, verbosity),
        CommandArgs::Slices(args) => cmd_slices(args, verbosity),
        CommandArgs::Render(args) => cmd_render(args),
        CommandArgs::Info(args) => cmd_info(args),
        CommandArgs::Cache(args) => cmd_cache(args),
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Verbosity {
    Quiet,
    Normal,
    Verbose,
}

/// Progress on stderr: a spinner per stage on a terminal, one line per stage with `-v`.
struct StderrObserver {
    verbosity: Verbosity,
    bar: Option<ProgressBar>,
}

impl StderrObserver {
    fn new(verbosity: Verbosity) -> Self {
        StderrObserver {
            verbosity,
            bar: None,
        }
    }
}

impl Observer for StderrObserver {
    fn stage_started(&mut self, stage: &'static str) {
        let on_terminal =
            std::io::stderr().is_terminal() && std::env::var_os("TERM").is_none_or(|t| t != "dumb");
        if self.verbosity != Verbosity::Quiet && on_terminal {
            let bar = ProgressBar::new_spinner();
            if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} {elapsed}") {
                bar.set_style(style);
            }
            bar.set_message(stage);
            bar.enable_steady_tick(Duration::from_millis(100));
            self.bar = Some(bar);
        }
    }

    fn stage_finished(&mut self, record: &StageRecord) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
        if self.verbosity == Verbosity::Verbose {
            eprintln!(
                "stablesurf: {:<10} {:<7} {:>8.3}s  {}",
                record.stage, record.cache, record.seconds, record.figures
            );
        }
    }

    fn warning(&mut self, message: &str) {
        if self.verbosity != Verbosity::Quiet {
            eprintln!("stablesurf: warning: {message}");
        }
    }

    fn note(&mut self, message: &str) {
        if self.verbosity != Verbosity::Quiet {
            eprintln!("stablesurf: note: {message}");
        }
    }
}

fn open_cache(opts: &cli::CacheOpts) -> Result<Cache> {
    if opts.no_cache {
        return Ok(Cache::disabled());
    }
    match opts
        .cache_dir
        .clone()
        .or_else(stablesurf::cache::default_dir)
    {
        Some(dir) => Ok(Cache::at(dir)),
        None => Err(usage(
            "no cache directory: set HOME or XDG_CACHE_HOME, pass --cache-dir, or use --no-cache",
        )),
    }
}

/// `--trim`: auto trims in detail mode (a blend extrapolates past the data) and keeps a
/// polynomial's zero set whole (it is the model).
fn trim_params(arg: Option<cli::TrimArg>, mode: pipeline::Mode) -> TrimParams {
    match (arg.unwrap_or(cli::TrimArg::Auto), mode) {
        (cli::TrimArg::Off, _) | (cli::TrimArg::Auto, pipeline::Mode::Global) => TrimParams::off(),
        (cli::TrimArg::Auto, pipeline::Mode::Detail) => TrimParams::default(),
        (cli::TrimArg::Factor(support_factor), _) => TrimParams {
            support_factor,
            ..TrimParams::default()
        },
    }
}

fn outlier_params(keep: bool) -> stablesurf::outliers::OutlierParams {
    stablesurf::outliers::OutlierParams {
        keep,
        ..Default::default()
    }
}

fn normals_params(opts: &cli::NormalsOpts) -> Result<normals::NormalsParams> {
    let source = normals::NormalSource::from_str(&opts.source)
        .map_err(|e| usage(format!("--normals: {e}")))?;
    Ok(normals::NormalsParams {
        source,
        viewpoint: opts.viewpoint,
        ..Default::default()
    })
}

fn fit_params(opts: &cli::FitOpts) -> Result<fit::FitParams> {
    let method =
        fit::FitMethod::from_str(&opts.method).map_err(|e| usage(format!("--method: {e}")))?;
    let kappa = fit::Kappa::from_str(&opts.kappa).map_err(|e| usage(format!("--kappa: {e}")))?;
    let kappa_rule = fit::KappaRule::from_str(&opts.kappa_rule)
        .map_err(|e| usage(format!("--kappa-rule: {e}")))?;
    // --degree, --kappa and --epsilon are within cli::DEGREE, cli::KAPPA and cli::EPSILON.
    if opts.degree % 2 == 1 && kappa == fit::Kappa::Auto && method == fit::FitMethod::ThreeLrr {
        return Err(usage(format!(
            "--degree {} is odd: automatic κ needs an even degree (an odd-degree zero set is never bounded); use an even degree or give --kappa a number",
            opts.degree
        )));
    }
    Ok(fit::FitParams {
        degree: opts.degree,
        method,
        kappa,
        kappa_rule,
        epsilon: opts.epsilon,
        ..Default::default()
    })
}

/// Detail-fit parameters (`--local-degree` and `--tolerance` are within cli::LOCAL_DEGREE and
/// cli::TOLERANCE).
fn detail_params(opts: &cli::DetailOpts) -> Result<stablesurf::detail::DetailParams> {
    let defaults = stablesurf::detail::DetailParams::default();
    Ok(stablesurf::detail::DetailParams {
        degree: opts.local_degree,
        tolerance: opts.tolerance,
        finest_tolerance: opts.tolerance.min(1e-3),
        ..defaults
    })
}

/// Meshing parameters for a model of `mode`: depth 7 by default (`PolygonizeParams`'s). Every
/// mesh vertex is projected onto the zero set, so a finer mesh only flattens the facets between
/// them: on the ten scans of ../shared/data a global (polynomial) model meshed at depth 8 has 4×
/// the triangles of depth 7, the same topology (watertight, components, Euler characteristic)
/// and a mean point-to-mesh distance within 4.6e-6 of the diagonal of depth 7's (README). A
/// detail model is meshed without the topology guard, whose gradient test the blend's loose
/// gradient enclosure cannot pass (it would refine nearly everywhere).
fn polygonize_params(
    opts: &cli::MeshOpts,
    mode: pipeline::Mode,
) -> Result<polygonize::PolygonizeParams> {
    let defaults = polygonize::PolygonizeParams::default();
    let (depth, guard_levels) = match mode {
        pipeline::Mode::Global => (opts.depth.unwrap_or(defaults.depth), defaults.guard_levels),
        pipeline::Mode::Detail => (opts.depth.unwrap_or(defaults.depth), 0),
    };
    // `--depth` is within cli::DEPTH; the default is the library's.
    Ok(polygonize::PolygonizeParams {
        depth,
        guard_levels,
        ..Default::default()
    })
}

fn gltf_options(up: cli::UpArg) -> export::gltf::GltfOptions {
    let up = match up {
        cli::UpArg::Y => export::gltf::UpAxis::Y,
        cli::UpArg::Z => export::gltf::UpAxis::Z,
    };
    export::gltf::GltfOptions { up }
}

fn region_from(bounds: Option<[f64; 6]>) -> Option<Aabb> {
    bounds.map(|v| Aabb {
        min: [v[0], v[1], v[2]],
        max: [v[3], v[4], v[5]],
    })
}

fn parse_mode(mode: &str) -> Result<pipeline::Mode> {
    match mode {
        "global" => Ok(pipeline::Mode::Global),
        "detail" => Ok(pipeline::Mode::Detail),
        other => Err(usage(format!(
            "--mode must be global or detail, got '{other}'"
        ))),
    }
}

fn cmd_run(args: cli::RunArgs, verbosity: Verbosity) -> Result<()> {
    let mode = parse_mode(args.mode())?;
    let formats = args
        .formats
        .iter()
        .map(|f| OutputFormat::from_str(f).map_err(|e| usage(format!("--formats: {e}"))))
        .collect::<Result<Vec<_>>>()?;
    if mode == pipeline::Mode::Detail
        && matches!(
            args.slices.slice_distance,
            Some(cli::DistanceArg::Exact | cli::DistanceArg::Taubin)
        )
    {
        return Err(usage(
            "--slice-distance exact and taubin need a polynomial: use --slice-distance mesh with --mode detail",
        ));
    }
    let config = PipelineConfig {
        mode,
        outliers: outlier_params(args.keep_outliers),
        normals: normals_params(&args.normals)?,
        fit: fit_params(&args.fit)?,
        detail: detail_params(&args.detail)?,
        polygonize: polygonize_params(&args.mesh, mode)?,
        // Detail mode leaves out pieces the data does not support (a blend can close a blob in
        // empty space); a polynomial's pieces are part of the model.
        keep: match (args.keep, mode) {
            (Some(cli::KeepArg::All), _) | (None, pipeline::Mode::Global) => Keep::All,
            (Some(cli::KeepArg::Data), _) | (None, pipeline::Mode::Detail) => Keep::Data,
        },
        trim: trim_params(args.trim, mode),
        gltf: gltf_options(args.up),
        slices: slice_params(
            cli::AxisArg::Z,
            args.slices.slice_count,
            args.slices.slice_resolution,
            args.slices.slice_distance.unwrap_or(match mode {
                pipeline::Mode::Global => cli::DistanceArg::Exact,
                pipeline::Mode::Detail => cli::DistanceArg::Mesh,
            }),
        )?,
        formats,
    };
    let cache = open_cache(&args.cache)?;
    let source = ScanSource::from_inputs(&args.input);
    if args.input.len() > 1 {
        if let Some(conf) = args.input.iter().find(|p| import::conf::is_conf(p)) {
            return Err(usage(format!(
                "{} is a registration file: give it alone, or give the scans without it",
                conf.display()
            )));
        }
    }
    if verbosity != Verbosity::Quiet {
        let input = source.name();
        let model = match mode {
            pipeline::Mode::Global => format!(
                "degree {}, method {}, kappa {}, rule {}, epsilon {}",
                args.fit.degree,
                args.fit.method,
                args.fit.kappa,
                args.fit.kappa_rule,
                args.fit.epsilon
            ),
            pipeline::Mode::Detail => format!(
                "local degree {}, tolerance {}",
                args.detail.local_degree, args.detail.tolerance
            ),
        };
        eprintln!(
            "stablesurf: run {input} -> {} (mode {}{}, normals {}, {model}, depth {}, keep {}, trim {}, slices {} x {}^2 {}, cache {})",
            args.output.display(),
            args.mode(),
            if args.mode_given() {
                ""
            } else {
                " by default; --mode global fits one polynomial"
            },
            args.normals.source,
            config.polygonize.depth,
            match config.keep {
                Keep::All => "all",
                Keep::Data => "data",
            },
            match config.trim.mode {
                TrimMode::Off => "off".to_string(),
                TrimMode::Support => format!("support factor {}", config.trim.support_factor),
            },
            config.slices.count,
            config.slices.resolution,
            config.slices.method.name(),
            cache.root().map_or("off".to_string(), |r| r.display().to_string()),
        );
    }
    let mut observer = StderrObserver::new(verbosity);
    let report = pipeline::run(&source, &args.output, &config, &cache, &mut observer)
        .with_context(|| {
            format!(
                "running the pipeline on {}",
                match source {
                    ScanSource::Sample => "the built-in sample".into(),
                    _ => source.name(),
                }
            )
        })?;
    if verbosity != Verbosity::Quiet {
        let bounded = match mode {
            pipeline::Mode::Global => format!(
                ", bounded {}",
                report
                    .fit
                    .get("diagnostics")
                    .and_then(|d| d.get("bounded"))
                    .map_or("unknown".into(), |b| b.to_string())
            ),
            pipeline::Mode::Detail => String::new(),
        };
        let t = &report.trim;
        let trimmed = if t.removed_triangles > 0 || t.holes_filled > 0 {
            format!(
                ", trimmed {} triangles ({:.1}% of the area) where no data supports the surface, {} hole(s) closed",
                t.removed_triangles,
                100.0 * t.removed_area_share,
                t.holes_filled
            )
        } else {
            String::new()
        };
        eprintln!(
            "stablesurf: done in {:.2}s: {} vertices, {} triangles, {} component(s), watertight {}, boundary loops {}, self-intersecting faces {}{bounded}{trimmed}, {}; outputs in {}",
            report.seconds,
            report.mesh.vertices,
            report.mesh.faces,
            report.mesh.components,
            report.mesh.watertight,
            report.mesh.boundary_loops,
            report.mesh.self_intersecting_faces,
            report.accuracy.describe(),
            args.output.display()
        );
    }
    if args.json {
        let mut out = std::io::stdout().lock();
        serde_json::to_writer_pretty(&mut out, &report)?;
        writeln!(out)?;
    }
    Ok(())
}

fn read_cloud(path: &Path) -> Result<stablesurf::PointCloud> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(import::import_bytes(&bytes, path)?)
}

fn cmd_normals(args: cli::NormalsArgs, verbosity: Verbosity) -> Result<()> {
    let params = normals_params(&args.normals)?;
    let cloud = read_cloud(&args.input)?;
    let result = normals::estimate_normals(&cloud, &params)
        .with_context(|| format!("estimating normals of {}", args.input.display()))?;
    if verbosity != Verbosity::Quiet {
        for w in &result.warnings {
            eprintln!("stablesurf: warning: {w}");
        }
        eprintln!(
            "stablesurf: {} oriented normals from {}",
            result.cloud.points.len(),
            result.source_used.as_str()
        );
    }
    let points = TriangleMesh {
        positions: result.cloud.points.clone(),
        normals: result.cloud.normals.clone(),
        triangles: Vec::new(),
    };
    let opts = export::ply::PlyOptions::default();
    export::write_atomic(&args.output, |w| export::ply::write(&points, w, &opts))?;
    if let Some(mesh_path) = &args.mesh {
        let crust = TriangleMesh {
            triangles: result.crust_triangles.clone(),
            ..points
        };
        export::write_atomic(mesh_path, |w| export::ply::write(&crust, w, &opts))?;
    }
    Ok(())
}

fn cmd_fit(args: cli::FitArgs, verbosity: Verbosity) -> Result<()> {
    let Some(input) = args.input.clone() else {
        return cmd_fit_from_moments(args, verbosity);
    };
    let config = PipelineConfig {
        mode: parse_mode(&args.mode)?,
        outliers: outlier_params(args.keep_outliers),
        normals: normals_params(&args.normals)?,
        fit: fit_params(&args.fit)?,
        detail: detail_params(&args.detail)?,
        ..Default::default()
    };
    let mut observer = StderrObserver::new(verbosity);
    let (model, _, _) = pipeline::fit_model(
        &ScanSource::File(input.clone()),
        &config,
        &Cache::disabled(),
        &mut observer,
    )
    .with_context(|| format!("fitting {}", input.display()))?;
    let (_, bytes) = model.file()?;
    export::write_atomic(&args.output, |w| {
        w.write_all(&bytes).map_err(export::ExportError::Write)
    })?;
    if verbosity != Verbosity::Quiet {
        match &model {
            pipeline::Model::Global(model) => {
                if let (Some(f), Some(d)) = (&model.fit, &model.diagnostics) {
                    eprintln!(
                        "stablesurf: degree {} {} fit, kappa {:e} ({}), bounded {}, mean distance {:.2e} of the diagonal",
                        model.polynomial.degree, f.method, f.kappa, f.kappa_rule, d.bounded, d.mean_distance_relative
                    );
                    for w in &d.warnings {
                        eprintln!("stablesurf: warning: {w}");
                    }
                }
            }
            pipeline::Model::Detail(model) => {
                let d = &model.diagnostics;
                eprintln!(
                    "stablesurf: detail fit, {} cells ({} grown), depth {}, mean |f|/|grad f| {:.2e} of the diagonal",
                    d.cells, d.grown_cells, d.depth_reached, d.mean_residual
                );
            }
        }
    }
    if args.json {
        let mut out = std::io::stdout().lock();
        serde_json::to_writer_pretty(&mut out, &model.report())?;
        writeln!(out)?;
    }
    Ok(())
}

/// Reads a moments file; errors name it.
fn read_moments(path: &Path) -> Result<fit::moments::PartialMoments> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    fit::moments::PartialMoments::from_bytes(&bytes)
        .with_context(|| format!("reading {}", path.display()))
}

/// A merge error, naming the offending file when the error points at one.
fn merge_error(err: fit::moments::MomentsError, parts: &[PathBuf]) -> anyhow::Error {
    let named = match &err {
        fit::moments::MomentsError::Mismatch { index, .. } => parts.get(*index),
        _ => None,
    };
    match named {
        Some(path) => anyhow!("{}: {err}", path.display()),
        None => anyhow!("merging {} moments files: {err}", parts.len()),
    }
}

/// `stablesurf moments`: one pass of the moments protocol over one chunk.
fn cmd_moments(args: cli::MomentsArgs, verbosity: Verbosity) -> Result<()> {
    let fit = fit_params(&args.fit)?;
    let config = PipelineConfig {
        // Outlier removal needs all the points: a chunk is used as it is.
        outliers: outlier_params(true),
        normals: normals_params(&args.normals)?,
        ..Default::default()
    };
    let pass = match (args.center, args.frame) {
        (_, Some(f)) => fit::moments::MomentsPass::System {
            frame: fit::moments::Frame {
                center: [f[0], f[1], f[2]],
                scale: f[3],
            },
            degree: fit.degree,
            epsilon: fit.epsilon,
        },
        (Some(center), None) => fit::moments::MomentsPass::Scale { center },
        (None, None) => fit::moments::MomentsPass::Center,
    };
    let mut observer = StderrObserver::new(verbosity);
    let cloud = pipeline::oriented_cloud(
        &ScanSource::File(args.input.clone()),
        &config,
        &Cache::disabled(),
        &mut observer,
    )
    .with_context(|| format!("reading {}", args.input.display()))?;
    let part = fit::moments::moments(&cloud, &pass)
        .with_context(|| format!("moments of {}", args.input.display()))?;
    let bytes = part.to_bytes();
    export::write_atomic(&args.output, |w| {
        w.write_all(&bytes).map_err(export::ExportError::Write)
    })?;
    Ok(())
}

/// `stablesurf frame`: merges pass-1 or pass-2 files and prints the next pass's argument.
fn cmd_frame(args: cli::FrameArgs) -> Result<()> {
    let parts = args
        .parts
        .iter()
        .map(|p| read_moments(p))
        .collect::<Result<Vec<_>>>()?;
    let merged = fit::moments::merge_frame(&parts).map_err(|e| merge_error(e, &args.parts))?;
    let mut out = std::io::stdout().lock();
    writeln!(out, "{}", merged.argument())?;
    Ok(())
}

/// `stablesurf fit --from-moments`.
fn cmd_fit_from_moments(args: cli::FitArgs, verbosity: Verbosity) -> Result<()> {
    if args.mode != "global" {
        return Err(usage(format!(
            "--from-moments fits one global polynomial, not --mode {}: drop --mode",
            args.mode
        )));
    }
    let params = fit_params(&args.fit)?;
    let parts = args
        .from_moments
        .iter()
        .map(|p| read_moments(p))
        .collect::<Result<Vec<_>>>()?;
    let merged =
        fit::moments::merge_system(&parts).map_err(|e| merge_error(e, &args.from_moments))?;
    let model = fit::fit_from_moments(&merged, &params).map_err(|e| {
        let first = args
            .from_moments
            .first()
            .map(|p| p.display().to_string())
            .unwrap_or_default();
        match e {
            fit::FitError::NeedsPoints { .. } => usage(format!("--from-moments: {e}")),
            fit::FitError::MomentsMismatch { .. } => anyhow!("{first}: {e}"),
            e => anyhow!(e).context(format!("fitting from {} moments files", parts.len())),
        }
    })?;
    let model = pipeline::Model::Global(model);
    let (_, bytes) = model.file()?;
    export::write_atomic(&args.output, |w| {
        w.write_all(&bytes).map_err(export::ExportError::Write)
    })?;
    if let (pipeline::Model::Global(m), true) = (&model, verbosity != Verbosity::Quiet) {
        if let (Some(f), Some(d)) = (&m.fit, &m.diagnostics) {
            eprintln!(
                "stablesurf: degree {} {} fit from {} points, kappa {:e} ({}), bounded {}",
                m.polynomial.degree, f.method, f.n_points, f.kappa, f.kappa_rule, d.bounded
            );
        }
    }
    if args.json {
        let mut out = std::io::stdout().lock();
        serde_json::to_writer_pretty(&mut out, &model.report())?;
        writeln!(out)?;
    }
    Ok(())
}

/// Reads a model file of either kind (a `stablesurf.mpu` file by its magic, else model.json).
fn read_any_model(path: &Path) -> Result<pipeline::Model> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(if export::mpu::is_mpu(&bytes) {
        pipeline::Model::Detail(export::mpu::read_mpu(&bytes, path)?)
    } else {
        pipeline::Model::Global(export::model::read_model(&bytes, path)?)
    })
}

fn cmd_mesh(args: cli::MeshArgs, verbosity: Verbosity) -> Result<()> {
    let ext = extension(&args.output);
    if !matches!(ext.as_str(), "glb" | "gltf" | "ply") {
        return Err(usage(format!(
            "-o {}: the mesh format comes from the extension: .glb, .gltf or .ply",
            args.output.display()
        )));
    }
    let model = read_any_model(&args.model)?;
    let params = polygonize_params(&args.mesh, model.mode())?;
    let region = match (region_from(args.bounds), &model) {
        (Some(b), _) => b,
        (None, pipeline::Model::Detail(m)) => m.region,
        (None, pipeline::Model::Global(m)) => m.bounds.ok_or_else(|| {
            anyhow!("{} has no \"box\": pass the meshing region with --bounds xmin,ymin,zmin,xmax,ymax,zmax", args.model.display())
        })?,
    };
    let out = polygonize::polygonize(model.function(), &region, &params)
        .with_context(|| format!("meshing {}", args.model.display()))?;
    let mesh = out.mesh;
    write_mesh(&mesh, &args.output, args.ascii, args.up)?;
    if verbosity != Verbosity::Quiet {
        let check = stablesurf::mesh::check(&mesh);
        eprintln!(
            "stablesurf: {} vertices, {} triangles, {} component(s), {} boundary edges, watertight {}",
            check.vertices, check.faces, check.components, check.boundary_edges, check.watertight
        );
    }
    Ok(())
}

fn extension(path: &Path) -> String {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default()
}

fn write_mesh(mesh: &TriangleMesh, path: &Path, ascii: bool, up: cli::UpArg) -> Result<()> {
    let gltf = gltf_options(up);
    match extension(path).as_str() {
        "glb" => export::write_atomic(path, |w| export::gltf::write_glb(mesh, w, &gltf))?,
        "gltf" => {
            let bin_path = path.with_extension("bin");
            let bin_uri = bin_path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let (mut json, mut bin) = (Vec::new(), Vec::new());
            export::gltf::write_gltf(mesh, &mut json, &mut bin, &bin_uri, &gltf)?;
            export::write_atomic(&bin_path, |w| {
                w.write_all(&bin).map_err(export::ExportError::Write)
            })?;
            export::write_atomic(path, |w| {
                w.write_all(&json).map_err(export::ExportError::Write)
            })?;
        }
        _ => {
            let encoding = if ascii {
                export::ply::PlyEncoding::Ascii
            } else {
                export::ply::PlyEncoding::BinaryLittleEndian
            };
            let opts = export::ply::PlyOptions {
                encoding,
                ..Default::default()
            };
            export::write_atomic(path, |w| export::ply::write(mesh, w, &opts))?;
        }
    }
    Ok(())
}

fn slice_params(
    axis: cli::AxisArg,
    count: usize,
    resolution: usize,
    distance: cli::DistanceArg,
) -> Result<stablesurf::distance::SliceParams> {
    // The count and resolution are within cli::COUNT/SLICE_COUNT and cli::RESOLUTION/
    // SLICE_RESOLUTION.
    Ok(stablesurf::distance::SliceParams {
        axis: match axis {
            cli::AxisArg::X => stablesurf::distance::Axis::X,
            cli::AxisArg::Y => stablesurf::distance::Axis::Y,
            cli::AxisArg::Z => stablesurf::distance::Axis::Z,
        },
        count,
        resolution,
        method: match distance {
            cli::DistanceArg::Taubin => stablesurf::distance::DistanceMethod::Taubin,
            cli::DistanceArg::Exact => stablesurf::distance::DistanceMethod::Exact,
            cli::DistanceArg::Mesh => stablesurf::distance::DistanceMethod::Mesh,
        },
    })
}

fn cmd_slices(args: cli::SlicesArgs, verbosity: Verbosity) -> Result<()> {
    let model = read_any_model(&args.model)?;
    let mesh_params = polygonize_params(&args.mesh, model.mode())?;
    let distance = match (args.distance, &model) {
        (Some(cli::DistanceArg::Mesh) | None, pipeline::Model::Detail(_)) => cli::DistanceArg::Mesh,
        (Some(other), pipeline::Model::Detail(_)) => {
            return Err(usage(format!(
                "--distance {}: a detail model (.mpu) has only the mesh distance",
                if other == cli::DistanceArg::Exact {
                    "exact"
                } else {
                    "taubin"
                }
            )))
        }
        (d, pipeline::Model::Global(_)) => d.unwrap_or(cli::DistanceArg::Exact),
    };
    let params = slice_params(args.axis, args.count, args.resolution, distance)?;
    let region = match region_from(args.bounds) {
        Some(b) => b,
        None => model.region(),
    };
    let slices = match &model {
        pipeline::Model::Global(m)
            if params.method != stablesurf::distance::DistanceMethod::Mesh =>
        {
            stablesurf::distance::slices(&m.polynomial, &region, &params)
        }
        _ => {
            let mesh = polygonize::polygonize(model.function(), &region, &mesh_params)
                .with_context(|| format!("meshing {}", args.model.display()))?
                .mesh;
            stablesurf::distance::slices_from_mesh(model.function(), &mesh, &region, &params)
        }
    }
    .with_context(|| format!("computing distance slices of {}", args.model.display()))?;
    std::fs::create_dir_all(&args.output)
        .with_context(|| format!("creating {}", args.output.display()))?;
    for slice in &slices {
        let stem: PathBuf = args.output.join(format!("slice_{:03}", slice.index));
        export::write_atomic(&stem.with_extension("exr"), |w| {
            export::exr::write_slice(slice, &export::exr::ExrOptions::default(), w)
        })?;
        export::write_atomic(&stem.with_extension("png"), |w| {
            export::png::write_preview(slice, w)
        })?;
    }
    if verbosity != Verbosity::Quiet {
        eprintln!(
            "stablesurf: {} slices written to {}",
            slices.len(),
            args.output.display()
        );
    }
    Ok(())
}

fn cmd_info(args: cli::InfoArgs) -> Result<()> {
    let bytes =
        std::fs::read(&args.file).with_context(|| format!("reading {}", args.file.display()))?;
    let looks_like_model = bytes.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'{');
    let value = if export::mpu::is_mpu(&bytes) {
        let model = export::mpu::read_mpu(&bytes, &args.file)?;
        serde_json::json!({
            "format": "stablesurf.mpu",
            "cells": model.cells.len(),
            "box": model.region,
            "diagonal": model.diagonal,
            "diagnostics": model.diagnostics,
        })
    } else if looks_like_model {
        let model = export::model::read_model(&bytes, &args.file)?;
        serde_json::json!({
            "format": "stablesurf.implicit-polynomial",
            "degree": model.polynomial.degree,
            "coefficients": model.polynomial.coefficients.len(),
            "center": model.polynomial.center,
            "scale": model.polynomial.scale,
            "box": model.bounds,
            "fit": model.fit,
            "diagnostics": model.diagnostics,
        })
    } else {
        let scan = import::read_scan_bytes(&bytes, &args.file)?;
        serde_json::to_value(import::scan_info(&scan))?
    };
    let mut out = std::io::stdout().lock();
    if args.json {
        serde_json::to_writer(&mut out, &value)?;
        writeln!(out)?;
    } else if let serde_json::Value::Object(map) = &value {
        for (k, v) in map {
            writeln!(out, "{k:<18} {v}")?;
        }
    }
    Ok(())
}

fn cmd_cache(args: cli::CacheArgs) -> Result<()> {
    let dir = args
        .cache_dir
        .or_else(stablesurf::cache::default_dir)
        .ok_or_else(|| {
            usage("no cache directory: set HOME or XDG_CACHE_HOME, or pass --cache-dir")
        })?;
    let cache = Cache::at(&dir);
    match args.action {
        cli::CacheAction::Info => {
            // Refuses a folder that is not a stablesurf cache (exit 1, saying why).
            let usage = cache.usage()?;
            let mut out = std::io::stdout().lock();
            writeln!(out, "cache directory: {}", dir.display())?;
            if usage.is_empty() {
                writeln!(out, "(no entries)")?;
            }
            for u in usage {
                writeln!(
                    out,
                    "{:<12} {:>6} entries {:>12.1} KiB",
                    u.stage,
                    u.entries,
                    u.bytes as f64 / 1024.0
                )?;
            }
        }
        cli::CacheAction::Clear => {
            let done = cache.clear()?;
            eprintln!(
                "stablesurf: cleared {} entries ({:.1} KiB) from {}",
                done.entries,
                done.bytes as f64 / 1024.0,
                dir.display()
            );
            if !done.foreign.is_empty() {
                let shown: Vec<String> = done
                    .foreign
                    .iter()
                    .take(5)
                    .map(|p| p.display().to_string())
                    .collect();
                eprintln!(
                    "stablesurf: left {} item(s) that the cache did not make: {}{}",
                    done.foreign.len(),
                    shown.join(", "),
                    if done.foreign.len() > 5 { ", …" } else { "" }
                );
            }
        }
    }
    Ok(())
}

fn cmd_render(args: cli::RenderArgs) -> Result<()> {
    let view = stablesurf::render::View::from_str(&args.view)
        .map_err(|e| usage(format!("--view: {e}")))?;
    // `--size` is within cli::SIZE.
    let cloud = read_cloud(&args.mesh)?;
    if cloud.triangles.is_empty() {
        return Err(anyhow!(
            "{} has no faces to render (it is a point cloud)",
            args.mesh.display()
        ));
    }
    let mesh = stablesurf::render::with_face_normals(cloud.points, cloud.triangles);
    let params = stablesurf::render::RenderParams {
        size: args.size,
        view,
        up: gltf_options(args.up).up,
        ..Default::default()
    };
    let image = stablesurf::render::render(&mesh, &params);
    export::write_atomic(&args.output, |w| export::png::write_rgb(&image, w))?;
    Ok(())
}
