//! `stablesurf fit`: a scan's model file (`model.json`, or `.mpu` with `--mode detail`) without
//! meshing, or with `--from-moments` one polynomial from the moments files of a scan given in
//! chunks ([`super::moments`]).

use anyhow::{anyhow, Context, Result};
use stablesurf::cache::Cache;
use stablesurf::fit as fit_stage;
use stablesurf::pipeline::{self, Model, PipelineConfig, ScanSource};

use super::args::{spelling, FitArgs, ModeArg};
use super::config;
use super::moments::{merge_error, read_moments};
use super::progress::{StderrObserver, Verbosity};
use super::usage;

/// Runs `stablesurf fit`.
pub fn fit(args: FitArgs, verbosity: Verbosity) -> Result<()> {
    let Some(input) = args.input.clone() else {
        return fit_from_moments(args, verbosity);
    };
    let mut config = PipelineConfig::for_mode(args.mode.into());
    config.outliers.keep = args.keep_outliers;
    config.normals = config::normals_params(&args.normals);
    config.fit = config::fit_params(&args.fit)?;
    config::set_detail(&mut config, &args.detail);
    let mut observer = StderrObserver::new(verbosity);
    let (model, _, _) = pipeline::fit_model(
        &ScanSource::from_inputs(std::slice::from_ref(&input)),
        &config,
        &Cache::disabled(),
        &mut observer,
    )
    .with_context(|| format!("fitting {}", input.display()))?;
    config::write_model(&model, &args.output)?;
    if verbosity != Verbosity::Quiet {
        match &model {
            Model::Global(model) => {
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
            Model::Detail(model) => {
                let d = &model.diagnostics;
                eprintln!(
                    "stablesurf: detail fit, {} cells ({} grown), depth {}, mean |f|/|grad f| {:.2e} of the diagonal",
                    d.cells, d.grown_cells, d.depth_reached, d.mean_residual
                );
            }
        }
    }
    if args.json {
        config::print_json(&model.report())?;
    }
    Ok(())
}

/// `stablesurf fit --from-moments`.
fn fit_from_moments(args: FitArgs, verbosity: Verbosity) -> Result<()> {
    if args.mode != ModeArg::Global {
        return Err(usage(format!(
            "--from-moments fits one global polynomial, not --mode {}: drop --mode",
            spelling(&args.mode)
        )));
    }
    let params = config::fit_params(&args.fit)?;
    let parts = args
        .from_moments
        .iter()
        .map(|p| read_moments(p))
        .collect::<Result<Vec<_>>>()?;
    let merged =
        fit_stage::moments::merge_system(&parts).map_err(|e| merge_error(e, &args.from_moments))?;
    let model = fit_stage::fit_from_moments(&merged, &params).map_err(|e| {
        let first = args
            .from_moments
            .first()
            .map(|p| p.display().to_string())
            .unwrap_or_default();
        match e {
            fit_stage::FitError::NeedsPoints { .. } => usage(format!("--from-moments: {e}")),
            fit_stage::FitError::MomentsMismatch { .. } => anyhow!("{first}: {e}"),
            e => anyhow!(e).context(format!("fitting from {} moments files", parts.len())),
        }
    })?;
    let model = Model::Global(model);
    config::write_model(&model, &args.output)?;
    if let (Model::Global(m), true) = (&model, verbosity != Verbosity::Quiet)
        && let (Some(f), Some(d)) = (&m.fit, &m.diagnostics)
    {
        eprintln!(
            "stablesurf: degree {} {} fit from {} points, kappa {:e} ({}), bounded {}",
            m.polynomial.degree, f.method, f.n_points, f.kappa, f.kappa_rule, d.bounded
        );
    }
    if args.json {
        config::print_json(&model.report())?;
    }
    Ok(())
}
