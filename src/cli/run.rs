//! `stablesurf run`: a scan (or several, or a registration file, or the built-in sample) through
//! the whole pipeline into an output folder, with a one-line summary of the settings before and
//! of the result after on stderr, and the stage summary as JSON on stdout with `--json`. A
//! folder, or several inputs with `--batch`, is a batch ([`super::batch`]): each input through
//! [`run_source`], the one path of a single run.

use std::path::Path;

use anyhow::{Context, Result};
use stablesurf::cache::Cache;
use stablesurf::import;
use stablesurf::pipeline::{self, Keep, Mode, PipelineConfig, RunReport, ScanSource};
use stablesurf::trim::TrimMode;

use super::args::{spelling, DistanceArg, RunArgs};
use super::batch;
use super::config;
use super::progress::{StderrObserver, Verbosity};
use super::usage;

/// Runs `stablesurf run`.
pub fn run(args: RunArgs, verbosity: Verbosity) -> Result<()> {
    let mode = Mode::from(args.mode());
    if mode == Mode::Detail
        && matches!(
            args.slices.slice_distance,
            Some(DistanceArg::Exact | DistanceArg::Taubin)
        )
    {
        return Err(usage(
            "--slice-distance exact and taubin need a polynomial: use --slice-distance mesh with --mode detail",
        ));
    }
    let config = config::run_config(&args)?;
    let cache = config::open_cache(&args.cache)?;
    if let Some(plan) = batch::plan(&args.input, args.batch, &args.output)? {
        return batch::run_batch(&args, &plan, &config, &cache, verbosity);
    }
    let source = ScanSource::from_inputs(&args.input);
    if args.input.len() > 1
        && let Some(conf) = args.input.iter().find(|p| import::conf::is_conf(p))
    {
        return Err(usage(format!(
                "{} is a registration file: give it alone, or give the scans without it (or add --batch to run each input on its own)",
                conf.display()
            )));
    }
    let report = run_source(&args, &source, &args.output, &config, &cache, verbosity)?;
    if args.json {
        config::print_json(&report)?;
    }
    Ok(())
}

/// One run of `source` into `output`, with its lines on stderr: a single `run`, and each input
/// of a batch.
///
/// # Errors
/// The pipeline's error, with the input named.
pub fn run_source(
    args: &RunArgs,
    source: &ScanSource,
    output: &Path,
    config: &PipelineConfig,
    cache: &Cache,
    verbosity: Verbosity,
) -> Result<RunReport> {
    let mode = config.mode;
    if verbosity != Verbosity::Quiet {
        let input = source.name();
        let model = match mode {
            Mode::Global => format!(
                "degree {}, method {}, kappa {}, rule {}, epsilon {}",
                args.fit.degree,
                spelling(&args.fit.method),
                args.fit.kappa,
                spelling(&args.fit.kappa_rule),
                args.fit.epsilon
            ),
            Mode::Detail => format!(
                "local degree {}, smooth {} x the measured noise, tolerance {}, fit stride {}",
                args.detail.local_degree,
                args.detail.smooth,
                match args.detail.tolerance {
                    Some(t) => t.to_string(),
                    None => format!(
                        "{} (x {} on dense points)",
                        config.detail.tolerance,
                        stablesurf::pipeline::DENSE_TOLERANCE
                    ),
                },
                match args.detail.fit_stride {
                    Some(k) => k.to_string(),
                    None => "from the points per mesh cell".to_string(),
                }
            ),
        };
        eprintln!(
            "stablesurf: run {input} -> {} (mode {}{}, normals {}, {model}, depth {}, keep {}, trim {}, slices {} x {}^2 {}, cache {})",
            output.display(),
            spelling(&args.mode()),
            if args.mode.is_some() {
                ""
            } else {
                " by default; --mode global fits one polynomial"
            },
            spelling(&args.normals.source),
            if config.mode == Mode::Detail && config.depth.is_auto() {
                "from the points' spacing".to_string()
            } else {
                config.depth.or_else(|| config.polygonize.depth).to_string()
            },
            match config.finish.keep {
                Keep::All => "all",
                Keep::Data => "data",
            },
            match config.finish.trim.mode {
                TrimMode::Off => "off".to_string(),
                TrimMode::Support => format!("support factor {}", config.finish.trim.support_factor),
            },
            config.export.slices.count,
            config.export.slices.resolution,
            config.export.slices.method.name(),
            cache.root().map_or("off".to_string(), |r| r.display().to_string()),
        );
    }
    let mut observer = StderrObserver::new(verbosity);
    let report =
        pipeline::run(source, output, config, cache, &mut observer).with_context(|| {
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
            Mode::Global => format!(
                ", bounded {}",
                report
                    .fit
                    .bounded()
                    .map_or("unknown".into(), |b| b.to_string())
            ),
            Mode::Detail => String::new(),
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
        let faired = if t.faired_vertices > 0 {
            format!(
                ", {} vertices faired over holes of the scan",
                t.faired_vertices
            )
        } else {
            String::new()
        };
        let noise = match report.noise {
            Some(n) if n.smoothed_per_diagonal > 0.0 => format!(
                ", noise {:.2e} of the diagonal ({:.2} x the spacing), averaged at {:.2e}",
                n.sigma_per_diagonal, n.sigma_per_spacing, n.smoothed_per_diagonal
            ),
            Some(n) => format!(
                ", noise {:.2e} of the diagonal ({:.2} x the spacing)",
                n.sigma_per_diagonal, n.sigma_per_spacing
            ),
            None => String::new(),
        };
        eprintln!(
            "stablesurf: done in {:.2}s: {} vertices, {} triangles, {} component(s), watertight {}{}, boundary loops {}, self-intersecting faces {}{bounded}{trimmed}{faired}{noise}, {}; outputs in {}",
            report.seconds,
            report.mesh.vertices,
            report.mesh.faces,
            report.mesh.components,
            report.mesh.watertight,
            report
                .mesh
                .genus
                .map_or(String::new(), |g| format!(" (genus {g})")),
            report.mesh.boundary_loops,
            report.mesh.self_intersecting_faces,
            report.accuracy.describe(),
            output.display()
        );
    }
    Ok(report)
}
