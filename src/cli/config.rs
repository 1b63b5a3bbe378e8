//! From parsed arguments to the library's parameters, and the few file reads and writes every
//! command shares. The per-mode defaults are the library's ([`PipelineConfig::for_mode`]): a
//! flag here only overrides them.

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};
use stablesurf::cache::Cache;
use stablesurf::distance::volume::VoxelSize;
use stablesurf::distance::{Axis, DistanceMethod};
use stablesurf::export::{self, gltf::UpAxis, units::LengthUnit};
use stablesurf::finish::decimate::DecimateParams;
use stablesurf::fit::{self, FitMethod, KappaRule};
use stablesurf::normals::{NormalSource, NormalsParams};
use stablesurf::pipeline::{Keep, Mode, Model, OutputFormat, PipelineConfig, Setting};
use stablesurf::polygonize::{PolygonizeParams, REFINE_SAGITTA};
use stablesurf::render::View;
use stablesurf::trim::TrimParams;
use stablesurf::{import, Aabb, PointCloud};

use super::args::{
    AxisArg, CacheOpts, DetailOpts, DistanceArg, FitOpts, FormatArg, KappaRuleArg, KeepArg,
    MeshOpts, MethodArg, ModeArg, NormalsOpts, RunArgs, SourceArg, TrimArg, UnitsArg, UpArg,
    ViewArg,
};
use super::usage;

/// `From<Arg> for Value` for each command-line enum and the library enum it stands for, variant
/// by variant (the two always have the same variants).
macro_rules! same_variants {
    ($($arg:ident => $value:ident { $($variant:ident),+ })+) => {
        $(impl From<$arg> for $value {
            fn from(arg: $arg) -> $value {
                match arg {
                    $($arg::$variant => $value::$variant,)+
                }
            }
        })+
    };
}

same_variants! {
    ModeArg => Mode { Global, Detail }
    SourceArg => NormalSource { Auto, Crust, Pca, Mesh, Input }
    MethodArg => FitMethod { ThreeLrr, ThreeL, Ls }
    KappaRuleArg => KappaRule { Stable, Paper }
    FormatArg => OutputFormat { Glb, Gltf, Ply, Exr, Png, Json, Vdb, Npy }
    ViewArg => View { Iso, Front, Top, Side }
    UnitsArg => LengthUnit { Mm, Cm, M, In, Ft }
    UpArg => UpAxis { Y, Z }
    AxisArg => Axis { X, Y, Z }
    DistanceArg => DistanceMethod { Taubin, Exact, Mesh }
    KeepArg => Keep { All, Data }
}

/// The cache `--cache-dir`/`--no-cache`/`--cache-max-size` ask for.
pub fn open_cache(opts: &CacheOpts) -> Result<Cache> {
    if opts.no_cache {
        return Ok(Cache::disabled());
    }
    match opts
        .cache_dir
        .clone()
        .or_else(stablesurf::cache::default_dir)
    {
        Some(dir) => Ok(Cache::at(dir).with_max_size(
            opts.cache_max_size
                .unwrap_or(stablesurf::cache::lru::DEFAULT_MAX_SIZE),
        )),
        None => Err(usage(
            "no cache directory: set HOME or XDG_CACHE_HOME, pass --cache-dir, or use --no-cache",
        )),
    }
}

/// Normals-stage parameters: the source and the viewpoint, the rest the library's defaults.
pub fn normals_params(opts: &NormalsOpts) -> NormalsParams {
    NormalsParams {
        source: opts.source.into(),
        viewpoint: opts.viewpoint,
        ..Default::default()
    }
}

/// Fit-stage parameters. An odd degree with automatic κ is a usage error: its zero set is
/// never bounded.
pub fn fit_params(opts: &FitOpts) -> Result<fit::FitParams> {
    let method = FitMethod::from(opts.method);
    let kappa = opts.kappa.value;
    // --degree, --kappa and --epsilon are within range::DEGREE, range::KAPPA and range::EPSILON.
    if opts.degree % 2 == 1 && kappa == fit::Kappa::Auto && method == FitMethod::ThreeLrr {
        return Err(usage(format!(
            "--degree {} is odd: automatic κ needs an even degree (an odd-degree zero set is never bounded); use an even degree or give --kappa a number",
            opts.degree
        )));
    }
    Ok(fit::FitParams {
        degree: opts.degree,
        method,
        kappa,
        kappa_rule: opts.kappa_rule.into(),
        epsilon: opts.epsilon,
        ..Default::default()
    })
}

/// Sets `config`'s detail fit from `opts`: `--local-degree` (within range::LOCAL_DEGREE),
/// `--smooth`, and `--tolerance` and `--fit-stride` as fixed settings, kept over the ones the
/// data's resolution would choose ([`PipelineConfig::tolerance`], [`PipelineConfig::fit_stride`]).
/// A tolerance splits the finest cells down to it or 1e-3, whichever is smaller
/// ([`DetailParams::with_tolerance`]).
pub fn set_detail(config: &mut PipelineConfig, opts: &DetailOpts) {
    config.detail.degree = opts.local_degree;
    if let Some(t) = opts.tolerance {
        config.tolerance = Setting::Fixed(t);
    }
    if let Some(k) = opts.fit_stride {
        config.fit_stride = Setting::Fixed(k);
    }
    config.smooth = opts.smooth;
}

/// Meshing parameters for a model of `mode`: the mode's defaults
/// ([`PipelineConfig::for_mode`]) with `--depth` (within range::DEPTH) and `--fit-chords` or
/// `--no-fit-chords` when given. A global model's mesh vertices are projected onto the zero
/// set, so a finer mesh only flattens the facets between them: on the ten scans of
/// ../shared/data a global (polynomial) model meshed at depth 8 has 4× the triangles of depth
/// 7, the same topology (watertight, components, Euler characteristic) and a mean
/// point-to-mesh distance within 4.6e-6 of the diagonal of depth 7's (docs/defaults.md).
pub fn polygonize_params(opts: &MeshOpts, mode: Mode) -> PolygonizeParams {
    let defaults = PipelineConfig::for_mode(mode).polygonize;
    PolygonizeParams {
        depth: opts.depth.unwrap_or(defaults.depth),
        fit_chords: match (opts.fit_chords, opts.no_fit_chords) {
            (true, _) => true,
            (_, true) => false,
            _ => defaults.fit_chords,
        },
        refine: match (opts.refine, opts.no_refine) {
            (true, _) => Some(REFINE_SAGITTA),
            (_, true) => None,
            _ => defaults.refine,
        },
        ..defaults
    }
}

/// The decimation `--target-triangles` asks for (within range::TARGET_TRIANGLES), or none.
pub fn decimate_params(opts: &MeshOpts) -> Option<DecimateParams> {
    opts.target_triangles
        .map(|target_triangles| DecimateParams { target_triangles })
}

/// The configuration of `stablesurf run`: the mode's defaults, then every flag given.
pub fn run_config(args: &RunArgs) -> Result<PipelineConfig> {
    let mode = Mode::from(args.mode());
    let mut config = PipelineConfig::for_mode(mode);
    config.outliers.keep = args.keep_outliers;
    config.normals = normals_params(&args.normals);
    config.fit = fit_params(&args.fit)?;
    set_detail(&mut config, &args.detail);
    config.polygonize = polygonize_params(&args.mesh, mode);
    if let Some(depth) = args.mesh.depth {
        config.depth = Setting::Fixed(depth);
    }
    if args.mesh.refine || args.mesh.no_refine {
        config.refine = Setting::Fixed(config.polygonize.refine);
    }
    let finish = &mut config.finish;
    finish.decimate = decimate_params(&args.mesh);
    if let Some(keep) = args.keep {
        finish.keep = keep.into();
    }
    match args.trim {
        None | Some(TrimArg::Auto) => {}
        Some(TrimArg::Off) => finish.trim = TrimParams::off(),
        Some(TrimArg::Factor(support_factor)) => {
            finish.trim = TrimParams {
                support_factor,
                ..TrimParams::default()
            }
        }
    }
    let export = &mut config.export;
    export.gltf.up = args.frame.up.map_or(UpAxis::Y, Into::into);
    export.ply_up = args.frame.up.map(Into::into);
    export.units = args.frame.units.map(Into::into);
    // The count and resolution are within range::SLICE_COUNT and range::SLICE_RESOLUTION.
    export.slices.count = args.slices.slice_count;
    export.slices.resolution = args.slices.slice_resolution;
    if let Some(distance) = args.slices.slice_distance {
        export.slices.method = distance.into();
    }
    export.formats = args.formats.iter().map(|&f| f.into()).collect();
    if let Some(h) = args.voxel_size {
        export.volume.voxel_size = VoxelSize::Size(h);
    }
    Ok(config)
}

/// `--bounds` as a box.
pub fn region_from(bounds: Option<[f64; 6]>) -> Option<Aabb> {
    bounds.map(|v| Aabb {
        min: [v[0], v[1], v[2]],
        max: [v[3], v[4], v[5]],
    })
}

/// Reads a scan or mesh file; errors name it.
pub fn read_cloud(path: &Path) -> Result<PointCloud> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(import::import_bytes(&bytes, path)?)
}

/// Reads a model file of either kind ([`Model::from_bytes`]); errors name it.
pub fn read_model(path: &Path) -> Result<Model> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(Model::from_bytes(&bytes, path)?)
}

/// Writes `bytes` to `path` atomically.
pub fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    export::write_atomic(path, |w| {
        w.write_all(bytes).map_err(export::ExportError::Write)
    })?;
    Ok(())
}

/// Writes a model file (`model.json` or `.mpu` bytes, whatever `path` is called).
pub fn write_model(model: &Model, path: &Path) -> Result<()> {
    let (_, bytes) = model.file()?;
    write_file(path, &bytes)
}

/// Prints `value` as pretty JSON and a newline on stdout.
pub fn print_json(value: &impl serde::Serialize) -> Result<()> {
    let mut out = std::io::stdout().lock();
    serde_json::to_writer_pretty(&mut out, value)?;
    writeln!(out)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;
    use crate::cli::args::{Cli, CommandArgs};

    fn run_args(flags: &[&str]) -> RunArgs {
        let args = ["stablesurf", "run", "-o", "out"].iter().chain(flags);
        match Cli::try_parse_from(args).unwrap().command {
            CommandArgs::Run(r) => r,
            _ => panic!(),
        }
    }

    /// Without flags, `run` in either mode is the library's configuration of that mode: the
    /// flags' defaults and the library's agree.
    #[test]
    fn run_defaults_are_the_library_defaults_of_the_mode() {
        for (flags, mode) in [
            (&[][..], Mode::Detail),
            (&["--mode", "detail"][..], Mode::Detail),
            (&["--mode", "global"][..], Mode::Global),
        ] {
            let config = run_config(&run_args(flags)).unwrap();
            let library = PipelineConfig::for_mode(mode);
            assert_eq!(format!("{config:?}"), format!("{library:?}"), "{flags:?}");
        }
    }

    #[test]
    fn run_flags_override_the_mode_defaults() {
        let config = run_config(&run_args(&[
            "--trim",
            "off",
            "--keep",
            "all",
            "--slice-distance",
            "mesh",
            "--depth",
            "5",
        ]))
        .unwrap();
        assert_eq!(config.finish.trim.mode, stablesurf::trim::TrimMode::Off);
        assert_eq!(config.finish.keep, Keep::All);
        assert_eq!(config.polygonize.guard_levels, 0);
        assert_eq!(config.finish.decimate, None);
        // A depth or a tolerance asked for is fixed, not the data's to choose.
        assert_eq!(config.depth, Setting::Fixed(5));
        assert!(config.tolerance.is_auto());
        let tolerant = run_config(&run_args(&["--tolerance", "2e-4"])).unwrap();
        assert!(tolerant.depth.is_auto());
        assert_eq!(tolerant.tolerance, Setting::Fixed(2e-4));
        let strided = run_config(&run_args(&["--fit-stride", "3"])).unwrap();
        assert_eq!(strided.fit_stride, Setting::Fixed(3));
        let decimating = run_config(&run_args(&["--target-triangles", "5000"])).unwrap();
        assert_eq!(
            decimating.finish.decimate.map(|d| d.target_triangles),
            Some(5000)
        );
        let global = run_config(&run_args(&["--mode", "global", "--trim", "3"])).unwrap();
        assert_eq!(global.finish.trim.support_factor, 3.0);
        assert_eq!(global.finish.trim.mode, stablesurf::trim::TrimMode::Support);
        assert_eq!(global.export.slices.method, DistanceMethod::Exact);
        // Fitted chords: detail mode's default, not global mode's; either flag overrides it,
        // the last one given wins.
        let chords = |flags: &[&str]| run_config(&run_args(flags)).unwrap().polygonize.fit_chords;
        assert!(chords(&[]));
        assert!(!chords(&["--no-fit-chords"]));
        assert!(!chords(&["--mode", "global"]));
        assert!(chords(&["--mode", "global", "--fit-chords"]));
        assert!(!chords(&["--fit-chords", "--no-fit-chords"]));
        // Split edges: the data's to choose by default (on dense points in detail mode, resolved
        // by the pipeline), always with --refine, never with --no-refine; the last flag wins.
        let refine = |flags: &[&str]| run_config(&run_args(flags)).unwrap().refine;
        assert_eq!(refine(&[]), Setting::Auto);
        assert_eq!(refine(&["--mode", "global"]), Setting::Auto);
        assert_eq!(refine(&["--refine"]), Setting::Fixed(Some(REFINE_SAGITTA)));
        assert_eq!(refine(&["--no-refine"]), Setting::Fixed(None));
        assert_eq!(
            refine(&["--no-refine", "--refine"]),
            Setting::Fixed(Some(REFINE_SAGITTA))
        );
        assert_eq!(refine(&["--depth", "6"]), Setting::Auto);
    }
}
