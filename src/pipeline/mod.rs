//! The pipeline: import → normals → fit (or detail) → polygonize → finish → export, each stage's free
//! function called through the stage cache. This is what `stablesurf run` calls.
//!
//! Input: a scan (file or the built-in sample), a [`PipelineConfig`] and a [`Cache`].
//! Output: files in the output directory and a [`RunReport`].
//!
//! Each stage's key chains the key of its input artifact (see [`crate::cache`]), so changing
//! only the meshing depth reuses import, normals and fit. The output folder is checked before
//! any work, every output is computed before the first file is written, and the files move into
//! place as one set ([`crate::outputs`]), so a failed or killed run leaves the folder as it was.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::cache::{self, Artifact, Cache, Key, OutputFiles};
use crate::cloud::{OrientedCloud, PointCloud};
use crate::detail;
use crate::export::{self, ExportError, ExportReport};
use crate::finish::{self, FinishError, FinishReport, Finished};
use crate::fit;
use crate::import;
use crate::normals;
use crate::outliers::{self, OutlierParams};
use crate::outputs::OutputSet;
use crate::polygonize;

mod config;
mod reconstruct;
mod records;

pub use crate::export::{mesh_files, MeshFileOptions, MeshFormat, OutputFormat};
pub use crate::finish::Keep;
pub use crate::model::{meshing_region, Mode, Model, ModelReport};
pub(crate) use config::ResolvedConfig;
pub use config::{smoothing, PipelineConfig, Setting, DENSE_TOLERANCE};
pub use reconstruct::{reconstruct, Reconstruction};
use records::{mesh_figures, run_report, EntryMeta, StageReport};
pub use records::{
    DetailReport, FitReport, ImportReport, MergeReport, NoiseReport, NormalsReport,
    PolygonizeReport, RunReport, StageFigures, StageRecord, WriteReport,
};

/// The small real scan built into the binary: "Spot" the cow by Keenan Crane (CC0 1.0),
/// 2,930 vertices, 5,856 triangles.
pub(crate) const SAMPLE_SCAN: &[u8] = include_bytes!("../sample/spot.obj");
/// The name the sample scan is reported under.
pub(crate) const SAMPLE_NAME: &str = "spot.obj (built-in sample, Keenan Crane, CC0)";

/// Errors of a pipeline run: a stage's error, with the stage named.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// Reading the scan failed.
    #[error("import failed")]
    Import(#[from] import::ImportError),
    /// Normal estimation failed.
    #[error("normal estimation failed")]
    Normals(#[from] normals::NormalsError),
    /// Fitting failed.
    #[error("fit failed")]
    Fit(#[from] fit::FitError),
    /// The detail (partition of unity) fit failed.
    #[error("detail fit failed")]
    Detail(#[from] detail::DetailError),
    /// Meshing failed.
    #[error("meshing failed")]
    Polygonize(#[from] polygonize::PolygonizeError),
    /// Finishing the mesh (the trim) failed.
    #[error(transparent)]
    Finish(#[from] FinishError),
    /// Writing an output failed.
    #[error("writing outputs failed")]
    Export(#[source] ExportError),
    /// Computing the distance slices failed.
    #[error("distance slices failed")]
    Distance(#[from] crate::distance::DistanceError),
    /// The scan file could not be read.
    #[error("cannot read {path}")]
    Read {
        /// The file.
        path: String,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// The requested mode is not available.
    #[error("{0}")]
    Unsupported(String),
    /// The output files could not be written (the message names the path and what to do).
    #[error(transparent)]
    Output(#[from] crate::outputs::OutputError),
    /// The cache folder is not one the cache may use.
    #[error(transparent)]
    Cache(#[from] cache::CacheError),
}

/// The export stage's error under the stage that failed: the slices keep their own variant,
/// every writer's error is [`PipelineError::Export`].
impl From<ExportError> for PipelineError {
    fn from(e: ExportError) -> Self {
        match e {
            ExportError::Distance(e) => PipelineError::Distance(e),
            ExportError::Unsupported(message) => PipelineError::Unsupported(message),
            e => PipelineError::Export(e),
        }
    }
}

/// What the errors about an in-memory cloud ([`ScanSource::Cloud`]) call it.
pub const CLOUD_NAME: &str = "points";

/// Where the scan comes from.
#[derive(Clone, Debug)]
pub enum ScanSource {
    /// A file.
    File(PathBuf),
    /// The built-in sample (`SAMPLE_SCAN`).
    Sample,
    /// A Stanford `.conf` registration file: its scans, each oriented in its own frame, moved
    /// by their poses and merged ([`crate::merge`]).
    Conf(PathBuf),
    /// Several scans of one object, already in one frame (identity poses), each oriented on its
    /// own and then merged.
    Files(Vec<PathBuf>),
    /// A cloud already in memory (points given as arrays, or a scan read before): it takes the
    /// path of a file's cloud from the outlier filter on. Its import is the check of the
    /// cloud's invariants ([`import::validate_cloud`]), keyed by the cloud's canonical bytes.
    Cloud(Box<PointCloud>),
}

impl ScanSource {
    /// The source for the command line's inputs: none is the sample, one `.conf` its scans, one
    /// other file itself, several files views of one object.
    pub fn from_inputs(inputs: &[PathBuf]) -> ScanSource {
        match inputs {
            [] => ScanSource::Sample,
            [one] if import::conf::is_conf(one) => ScanSource::Conf(one.clone()),
            [one] => ScanSource::File(one.clone()),
            many => ScanSource::Files(many.to_vec()),
        }
    }

    /// The views of a multi-view source, poses included: a `.conf`'s scans (read from it, so
    /// a malformed `.conf` is an error naming it), or several files with identity poses; `None`
    /// for a single scan, the sample or a cloud in memory.
    ///
    /// # Errors
    /// [`PipelineError::Read`] when the `.conf` cannot be read, [`PipelineError::Import`] when
    /// it is malformed.
    pub fn views(&self) -> Result<Option<Vec<import::conf::View>>, PipelineError> {
        Ok(match self {
            ScanSource::Sample | ScanSource::File(_) | ScanSource::Cloud(_) => None,
            ScanSource::Conf(path) => Some(import::conf::read_conf(&read_bytes(path)?, path)?),
            ScanSource::Files(paths) => Some(
                paths
                    .iter()
                    .map(|p| import::conf::View {
                        path: p.clone(),
                        pose: crate::merge::Pose::IDENTITY,
                    })
                    .collect(),
            ),
        })
    }

    /// The name the report and messages give the input.
    pub fn name(&self) -> String {
        match self {
            ScanSource::Sample => SAMPLE_NAME.to_string(),
            ScanSource::File(p) | ScanSource::Conf(p) => p.display().to_string(),
            ScanSource::Files(ps) => ps
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(" "),
            ScanSource::Cloud(cloud) => format!("{CLOUD_NAME} ({} points)", cloud.points.len()),
        }
    }
}

/// Receives progress events (the CLI turns them into progress bars and `-v` lines).
pub trait Observer {
    /// A stage starts.
    fn stage_started(&mut self, _stage: &'static str) {}
    /// A stage finished.
    fn stage_finished(&mut self, _record: &StageRecord) {}
    /// Something the user should know that does not stop the run (a cache that could not be
    /// written).
    fn warning(&mut self, _message: &str) {}
    /// Something worth knowing that is no fault (columns of the scan that are not read).
    fn note(&mut self, _message: &str) {}
}

/// An observer that ignores everything.
pub struct Silent;
impl Observer for Silent {}

// Stage versions: if you change anything that changes a stage's output for the same input and
// params (algorithm, defaults, artifact layout), bump its version so old cache entries are not
// reused.
const IMPORT_VERSION: u32 = 3;
/// Merging the views of a `.conf` or of several files.
const MERGE_VERSION: u32 = 1;
/// The outlier filter is not cached (it is a linear pass), but its output's key chains
/// through it when it leaves points out.
const OUTLIERS_VERSION: u32 = 2;
const NORMALS_VERSION: u32 = 7;
const FIT_VERSION: u32 = 5;
const POLYGONIZE_VERSION: u32 = 5;
// The export stage's version is `export::STAGE_VERSION`, beside its params.

struct Ctx<'a> {
    /// The run's cache: the one asked for, or a disabled one when it cannot be written.
    cache: Cache,
    /// The misses' entries, stored beside the next stages' work.
    puts: cache::Puts,
    observer: &'a mut dyn Observer,
    stages: Vec<StageRecord>,
    /// Every warning told to the observer, for the report.
    warnings: Vec<String>,
    /// The measured noise of the fit's input points, for the report.
    noise: Option<NoiseReport>,
}

impl<'a> Ctx<'a> {
    /// Readies the cache: a folder that is not a stablesurf cache is an error; one that cannot
    /// be created or written is a warning, and the run goes on without it.
    fn new(cache: &Cache, observer: &'a mut dyn Observer) -> Result<Self, PipelineError> {
        let mut warnings = Vec::new();
        let cache = match cache.prepare() {
            Ok(()) => cache.clone(),
            Err(e @ cache::CacheError::NotACache { .. }) => return Err(e.into()),
            Err(e) => {
                warnings.push(format!("{e}; this run is not cached"));
                Cache::disabled()
            }
        };
        let mut ctx = Ctx {
            puts: cache.puts(),
            cache,
            observer,
            stages: Vec::new(),
            warnings: Vec::new(),
            noise: None,
        };
        for w in warnings {
            ctx.warn(w);
        }
        Ok(ctx)
    }

    /// Tells the observer a warning and keeps it for the report.
    fn warn(&mut self, message: String) {
        self.observer.warning(&message);
        self.warnings.push(message);
    }

    /// Waits for the cache writes. One that failed costs only the next run's time, so it is a
    /// warning: the outputs are complete either way.
    ///
    /// Then the run's lookups go into the cache's counts and the least recently used entries
    /// beyond its size limit are evicted ([`cache::lru`]); a failure there is told only when
    /// the writes did not already say the cache is failing.
    fn finish_puts(&mut self) {
        let failed = self.puts.finish();
        let told = !failed.is_empty();
        for e in failed {
            self.warn(format!(
                "{e}; this run's results are complete but were not all cached"
            ));
        }
        let count = |which: &[&str]| {
            self.stages
                .iter()
                .filter(|s| which.contains(&s.cache))
                .count() as u64
        };
        let (hits, misses) = (count(&["hit"]), count(&["miss", "corrupt"]));
        if let Err(e) = self.cache.after_run(hits, misses)
            && !told
        {
            self.warn(format!(
                "{e}; the cache's counts were not updated and its size limit not applied this run"
            ));
        }
    }

    /// Runs one cached stage: look up, else compute and store. The stage's report `R`
    /// summarizes the output for the report; on a hit the report stored in the entry is read
    /// back (an entry whose report does not read is recomputed, as a corrupt one).
    fn stage<T: Artifact, R: StageReport>(
        &mut self,
        stage: &'static str,
        version: u32,
        params: &[u8],
        input_key: &Key,
        compute: impl FnOnce() -> Result<(T, R), PipelineError>,
    ) -> Result<(T, Key, R), PipelineError> {
        self.stage_from(None, stage, version, params, input_key, compute)
    }

    /// [`Self::stage`] for a stage whose work began before this call, at `announced` (its start
    /// already told to the observer): its time counts from there.
    fn stage_from<T: Artifact, R: StageReport>(
        &mut self,
        announced: Option<Instant>,
        stage: &'static str,
        version: u32,
        params: &[u8],
        input_key: &Key,
        compute: impl FnOnce() -> Result<(T, R), PipelineError>,
    ) -> Result<(T, Key, R), PipelineError> {
        let start = announced.unwrap_or_else(|| {
            self.observer.stage_started(stage);
            Instant::now()
        });
        let key = cache::stage_key(stage, version, params, input_key);
        let (found, lookup) = self.cache.get::<T>(stage, version, &key);
        // The report is stored inside the entry, under its checksum.
        let found = found.map(|(v, meta)| (v, serde_json::from_value::<EntryMeta<R>>(meta)));
        let (value, report, lookup) = match found {
            Some((v, Ok(meta))) => (v, meta.figures, lookup),
            found => {
                let lookup = if found.is_some() {
                    cache::Lookup::Corrupt
                } else {
                    lookup
                };
                let (v, report) = compute()?;
                let meta = EntryMeta {
                    stage: stage.to_string(),
                    stage_version: version,
                    cache_format_version: cache::CACHE_FORMAT_VERSION,
                    params: serde_json::from_slice(params).unwrap_or_default(),
                    input_key: input_key.hex(),
                    seconds: start.elapsed().as_secs_f64(),
                    figures: report.clone(),
                };
                let meta = serde_json::to_value(&meta).expect("entry explanations serialize");
                self.puts.put(stage, version, &key, &v, &meta);
                (v, report, lookup)
            }
        };
        self.finish(
            stage,
            lookup.as_str(),
            start,
            Some(key),
            report.clone().into(),
        );
        Ok((value, key, report))
    }

    fn finish(
        &mut self,
        stage: &'static str,
        cache: &'static str,
        start: Instant,
        key: Option<Key>,
        figures: StageFigures,
    ) {
        let record = StageRecord {
            stage,
            cache,
            seconds: start.elapsed().as_secs_f64(),
            key: key.map(|k| k.hex()),
            figures,
        };
        self.observer.stage_finished(&record);
        self.stages.push(record);
    }
}

/// Reads a file's bytes.
fn read_bytes(path: &Path) -> Result<Vec<u8>, PipelineError> {
    std::fs::read(path).map_err(|source| PipelineError::Read {
        path: path.display().to_string(),
        source,
    })
}

/// Import, outliers and normals through the cache: the fit's input. Several views (a `.conf`,
/// or several files) are each oriented in their own frame, then merged.
fn orient_stages(
    ctx: &mut Ctx<'_>,
    source: &ScanSource,
    config: &PipelineConfig,
) -> Result<(Oriented, Key), PipelineError> {
    match source.views()? {
        Some(views) => merged_views(ctx, &views, config),
        None => match source {
            ScanSource::Cloud(cloud) => oriented_cloud_in_memory(ctx, cloud, config),
            ScanSource::File(path) => oriented_scan(ctx, read_bytes(path)?, path, config),
            _ => oriented_scan(ctx, SAMPLE_SCAN.to_vec(), Path::new("spot.obj"), config),
        },
    }
}

/// Each view imported and oriented in its own frame (through the cache), then moved by its
/// pose and merged (the `merge` stage, keyed by every view's normals key, which covers its
/// file's bytes, and every pose).
fn merged_views(
    ctx: &mut Ctx<'_>,
    views: &[import::conf::View],
    config: &PipelineConfig,
) -> Result<(Oriented, Key), PipelineError> {
    let mut oriented = Vec::with_capacity(views.len());
    let mut keys = Vec::new();
    for view in views {
        let bytes = read_bytes(&view.path)?;
        let (view_cloud, key) = oriented_scan(ctx, bytes, &view.path, config)?;
        keys.extend_from_slice(key.hex().as_bytes());
        oriented.push((view_cloud.cloud, view.pose));
    }
    let poses: Vec<crate::merge::Pose> = views.iter().map(|v| v.pose).collect();
    let (merged, key, _) = ctx.stage(
        "merge",
        MERGE_VERSION,
        &cache::params_bytes(&poses),
        &Key::of_bytes(&keys),
        || {
            let refs: Vec<(&OrientedCloud, crate::merge::Pose)> =
                oriented.iter().map(|(c, p)| (c, *p)).collect();
            let merged = crate::merge::merge_views(&refs);
            let report = MergeReport {
                views: views.len(),
                points: merged.points.len(),
                weighted: merged.weights.is_some(),
            };
            Ok((merged, report))
        },
    )?;
    let n_input = merged.points.len();
    Ok((
        Oriented {
            cloud: merged,
            n_input,
            // The views' colours are not merged.
            colours: None,
        },
        key,
    ))
}

/// One scan through import, outlier removal and normals; returns the oriented cloud and its key.
fn oriented_scan(
    ctx: &mut Ctx<'_>,
    bytes: Vec<u8>,
    path: &Path,
    config: &PipelineConfig,
) -> Result<(Oriented, Key), PipelineError> {
    let (cloud, cloud_key, report) = ctx.stage(
        "import",
        IMPORT_VERSION,
        b"",
        &Key::of_bytes(&bytes),
        || {
            let scan = import::import_scan_bytes(&bytes, path)?;
            let report = ImportReport {
                points: scan.cloud.points.len(),
                triangles: scan.cloud.triangles.len(),
                has_normals: scan.cloud.normals.is_some(),
                notices: Some(scan.notices),
            };
            Ok((scan.cloud, report))
        },
    )?;
    drop(bytes);
    // What the reader did not read (extra columns, other elements), on a hit too.
    for n in report.notices.iter().flatten() {
        ctx.observer.note(&format!("{}: {n}", path.display()));
    }
    orient(ctx, cloud, cloud_key, config)
}

/// An in-memory cloud through its import (the check of its invariants) and the rest of
/// [`oriented_scan`]'s stages.
fn oriented_cloud_in_memory(
    ctx: &mut Ctx<'_>,
    cloud: &PointCloud,
    config: &PipelineConfig,
) -> Result<(Oriented, Key), PipelineError> {
    let mut canonical = b"in-memory cloud".to_vec();
    cloud.encode_payload(&mut canonical);
    let (cloud, cloud_key, _) = ctx.stage(
        "import",
        IMPORT_VERSION,
        b"",
        &Key::of_bytes(&canonical),
        || {
            import::validate_cloud(cloud, CLOUD_NAME)?;
            let report = ImportReport {
                points: cloud.points.len(),
                triangles: cloud.triangles.len(),
                has_normals: cloud.normals.is_some(),
                notices: None,
            };
            Ok((cloud.clone(), report))
        },
    )?;
    drop(canonical);
    orient(ctx, cloud, cloud_key, config)
}

/// An imported cloud through the outlier filter and the normals stage.
fn orient(
    ctx: &mut Ctx<'_>,
    cloud: PointCloud,
    cloud_key: Key,
    config: &PipelineConfig,
) -> Result<(Oriented, Key), PipelineError> {
    let (mut cloud, cloud_key) = without_outliers(ctx, cloud, cloud_key, &config.outliers);
    let n_input = cloud.points.len();
    // The normals stage keeps the input points first and in order (duplicates too), so the
    // cloud's colours are those of the input points.
    let colours = cloud.colours.take().filter(|c| c.len() == n_input);
    let (oriented, oriented_key, report) = ctx.stage(
        "normals",
        NORMALS_VERSION,
        &cache::params_bytes(&config.normals),
        &cloud_key,
        // The cloud is given to the stage: its arrays become the oriented cloud's.
        move || {
            let normals = normals::estimate_normals_owned(cloud, &config.normals)?;
            let report = NormalsReport {
                source: normals.source_used.as_str().to_string(),
                surface_samples: normals.surface_samples,
                warnings: normals.warnings,
            };
            Ok((normals.cloud, report))
        },
    )?;
    // The stage's warnings, on a hit as on a miss.
    for w in report.warnings {
        ctx.warn(w);
    }
    Ok((
        Oriented {
            cloud: oriented,
            n_input,
            colours,
        },
        oriented_key,
    ))
}

/// Imports, estimates normals and fits: the part of the pipeline shared by `run` and `fit`.
/// Returns the oriented cloud, the model and its key, and `config` resolved for the data
/// ([`PipelineConfig::resolve`]: what the later stages run with).
fn fit_stages(
    ctx: &mut Ctx<'_>,
    source: &ScanSource,
    config: &PipelineConfig,
) -> Result<(Oriented, Model, Key, ResolvedConfig), PipelineError> {
    let (oriented, oriented_key) = orient_stages(ctx, source, config)?;
    let noise = crate::normals::estimate_noise(oriented.input_points());
    let resolved = config.resolve(
        &oriented.cloud.points,
        oriented.input_points(),
        noise.as_ref(),
    );
    ctx.noise = noise.map(|n| NoiseReport::new(n, &oriented.cloud.points, &resolved));
    let (model, model_key) = model_stages(ctx, &oriented.cloud, oriented_key, &resolved)?;
    Ok((oriented, model, model_key, resolved))
}

/// The oriented cloud and how many of its points are the input's: they come first (after
/// outlier removal, in input order), the points the normals stage adds on large faces follow.
/// The input points are what the outputs' accuracy is measured against.
struct Oriented {
    cloud: OrientedCloud,
    n_input: usize,
    /// The input points' colours (16-bit RGB), when the scan has them.
    colours: Option<Vec<[u16; 3]>>,
}

impl Oriented {
    /// The input points.
    fn input_points(&self) -> &[[f64; 3]] {
        &self.cloud.points[..self.n_input]
    }

    /// The input points' normals, while the cloud still has them.
    fn input_normals(&self) -> Option<&[[f64; 3]]> {
        self.cloud.normals.get(..self.n_input)
    }
}

/// The global fit or the detail fit of the oriented cloud.
fn model_stages(
    ctx: &mut Ctx<'_>,
    oriented: &OrientedCloud,
    oriented_key: Key,
    config: &ResolvedConfig,
) -> Result<(Model, Key), PipelineError> {
    let (model, model_key) = match config.mode {
        Mode::Global => {
            let (model, key, _) = ctx.stage(
                "fit",
                FIT_VERSION,
                &cache::params_bytes(&config.fit),
                &oriented_key,
                || {
                    let model = fit::fit(oriented, &config.fit)?;
                    let report = FitReport {
                        degree: model.polynomial.degree,
                        kappa: model.fit.as_ref().map(|f| f.kappa),
                        bounded: model.diagnostics.as_ref().map(|d| d.bounded),
                    };
                    Ok((model, report))
                },
            )?;
            // The fit's warnings (a κ that fell back, an unbounded zero set) are the model's.
            for w in model.diagnostics.iter().flat_map(|d| d.warnings.clone()) {
                ctx.warn(w);
            }
            (Model::Global(model), key)
        }
        Mode::Detail => {
            // One value for the cache key and the fit, so the key says what was fitted.
            let params = &config.detail;
            let (model, key, _) = ctx.stage(
                "detail",
                detail::STAGE_VERSION,
                &cache::params_bytes(&params),
                &oriented_key,
                || {
                    let model = detail::fit_detail(oriented, params)?;
                    let d = &model.diagnostics;
                    let report = DetailReport {
                        cells: d.cells,
                        grown_cells: d.grown_cells,
                        cubic_cells: model.cells.iter().filter(|c| c.poly.degree == 3).count(),
                        depth_reached: d.depth_reached,
                        mean_residual: d.mean_residual,
                        max_residual: d.max_residual,
                    };
                    Ok((model, report))
                },
            )?;
            (Model::Detail(model), key)
        }
    };
    Ok((model, model_key))
}

/// The cloud without the points far outside the bulk of the data ([`outliers`]), and its key;
/// the cloud as it is when none is left out. Left-out points are a warning with their count.
fn without_outliers(
    ctx: &mut Ctx<'_>,
    cloud: PointCloud,
    key: Key,
    params: &OutlierParams,
) -> (PointCloud, Key) {
    let split = outliers::remove_outliers(&cloud, params);
    if split.removed == 0 {
        drop(split);
        return (cloud, key);
    }
    let far = split.bulk_radius.map_or(String::new(), |r| {
        format!(
            " (beyond {:.3e} from the median centre, {} times the radius that holds {}% of the points, and apart from them)",
            params.far_factor * r,
            params.far_factor,
            100.0 * params.bulk_quantile
        )
    });
    let faces = if split.removed_faces > 0 {
        format!(" and the {} faces that use them", split.removed_faces)
    } else {
        String::new()
    };
    let far_count = split.removed - split.isolated;
    if far_count > 0 {
        ctx.warn(format!(
            "left out {far_count} of {} points far outside the bulk of the data{far}{faces}; pass --keep-outliers to keep them",
            cloud.points.len(),
        ));
    }
    if split.isolated > 0 {
        ctx.warn(format!(
            "left out {} of {} points in groups of at most {} apart from the rest (no other point within {} times the local spacing); pass --keep-outliers to keep them",
            split.isolated,
            cloud.points.len(),
            outliers::ISOLATED_GROUP_MAX,
            params.isolation_factor,
        ));
    }
    let params_bytes = cache::params_bytes(&serde_json::json!({
        "bulk_quantile": params.bulk_quantile,
        "far_factor": params.far_factor,
        "gap_factor": params.gap_factor,
        "isolation_factor": params.isolation_factor,
    }));
    let kept = split.cloud.into_owned();
    (
        kept,
        cache::stage_key("outliers", OUTLIERS_VERSION, &params_bytes, &key),
    )
}

/// Fits a model (import, normals, fit through the cache) without meshing: `stablesurf fit`.
///
/// # Errors
/// Any stage's error.
pub fn fit_model(
    source: &ScanSource,
    config: &PipelineConfig,
    cache: &Cache,
    observer: &mut dyn Observer,
) -> Result<(Model, OrientedCloud, Vec<StageRecord>), PipelineError> {
    let mut ctx = Ctx::new(cache, observer)?;
    let (oriented, model, _, _) = fit_stages(&mut ctx, source, config)?;
    ctx.finish_puts();
    Ok((model, oriented.cloud, ctx.stages))
}

/// The oriented points a fit would see (import, outliers unless kept, normals), without
/// fitting: the input of [`crate::fit::moments::moments`] for one chunk.
///
/// # Errors
/// Any stage's error.
pub fn oriented_cloud(
    source: &ScanSource,
    config: &PipelineConfig,
    cache: &Cache,
    observer: &mut dyn Observer,
) -> Result<OrientedCloud, PipelineError> {
    let mut ctx = Ctx::new(cache, observer)?;
    let (oriented, _) = orient_stages(&mut ctx, source, config)?;
    ctx.finish_puts();
    Ok(oriented.cloud)
}

/// Runs the whole pipeline and writes the outputs into `out_dir`.
///
/// # Errors
/// Any stage's error; the output directory or a file cannot be written.
pub fn run(
    source: &ScanSource,
    out_dir: &Path,
    config: &PipelineConfig,
    cache: &Cache,
    observer: &mut dyn Observer,
) -> Result<RunReport, PipelineError> {
    let start = Instant::now();
    // The output folder is checked (and a killed run's debris there cleared) before any work.
    let mut outputs = OutputSet::begin(out_dir)?;
    let mut ctx = Ctx::new(cache, observer)?;
    let cache = &ctx.cache.clone();
    let input_name = source.name();
    let (mut oriented, model, model_key, resolved) = fit_stages(&mut ctx, source, config)?;
    let config = &resolved;
    // From here on only the input points are needed (the accuracy is measured against them),
    // with their normals when the meshing coarsens where they are flat.
    if config.polygonize.data_levels > 0 {
        oriented.cloud.normals.truncate(oriented.n_input);
        oriented.cloud.normals.shrink_to_fit();
    } else {
        oriented.cloud.normals = Vec::new();
    }
    oriented.cloud.weights = None;
    let points = oriented.input_points();
    let normals = oriented.input_normals();
    let colours = oriented.colours.as_deref();

    let polygonize_params = cache::params_bytes(&config.polygonize);
    let export_params = &config.export;
    let export_params_bytes = cache::params_bytes(export_params);
    // The export stage's work splits in two (see [`export`]): the slice files of a polynomial
    // model need the model only, everything else needs the finished mesh. When the export stage
    // is going to run, the slice files are made beside the meshing and the finishing and then
    // beside the mesh's outputs, so both cores stay busy; the export stage then assembles the
    // parts (the same bytes as `export::export`: each part depends on the same inputs alone).
    // Its line counts from the end of the finishing.
    let finish_key = cache::stage_key(
        "finish",
        finish::STAGE_VERSION,
        &cache::params_bytes(&config.finish),
        &cache::stage_key(
            "polygonize",
            POLYGONIZE_VERSION,
            &polygonize_params,
            &model_key,
        ),
    );
    let export_key = cache::stage_key(
        "export",
        export::STAGE_VERSION,
        &export_params_bytes,
        &finish_key,
    );
    let export_runs = !cache.contains("export", &export_key);
    let early_from_model = export_runs && export::slices_from_model(&model, export_params);
    let mut early_slices = None;
    let (finished, mut early_parts, export_start) = rayon::in_place_scope(|scope| {
        if early_from_model {
            scope.spawn(|_| early_slices = export::model_slices(&model, export_params));
        }
        let finished = polygonize_stage(&mut ctx, &model, &model_key, points, normals, config)
            .and_then(|(mesh, mesh_key, polygonized)| {
                finish_stage(
                    &mut ctx,
                    &model,
                    &mesh,
                    &mesh_key,
                    polygonized.embedded,
                    points,
                    colours,
                    config,
                )
            });
        let export_start = Instant::now();
        let parts = match &finished {
            Ok((finished, ..)) if export_runs => {
                ctx.observer.stage_started("export");
                Some(export::export_mesh(&model, finished, export_params))
            }
            _ => None,
        };
        (finished, parts, export_start)
    });
    let (finished, finish_key, finish_report) = finished?;

    // Encoding every output file is one more cached stage: a rerun with the same inputs only
    // copies files out.
    let announced = early_parts.is_some().then_some(export_start);
    let (files, _, _) = ctx.stage_from(
        announced,
        "export",
        export::STAGE_VERSION,
        &export_params_bytes,
        &finish_key,
        || {
            // The parts made above, or the whole stage here when they were skipped (an export
            // entry found on disk that then failed to decode).
            let files = match early_parts.take() {
                Some(parts) => {
                    let mut files = parts?;
                    if let Some(slices) = early_slices.take() {
                        files.extend(slices?);
                    }
                    files
                }
                None => export::export(&model, &finished, export_params)?,
            };
            let report = ExportReport::of(&files);
            Ok((OutputFiles(files), report))
        },
    )?;
    drop(finished);
    let figures = mesh_figures(&mut ctx, &model, finish_report);

    // Every file is staged, then all move into place together (see [`crate::outputs`]): the
    // folder holds either this run's complete set or what it held before.
    let t = Instant::now();
    outputs.stage(&files.0)?;
    // The write line covers the wait for the cache entries still being stored.
    ctx.finish_puts();
    ctx.finish(
        "write",
        "none",
        t,
        None,
        WriteReport {
            files: files.0.len(),
        }
        .into(),
    );
    let mut names: Vec<String> = files.0.iter().map(|f| f.0.clone()).collect();
    let write_report = config.export.formats.contains(&OutputFormat::Json);
    if write_report {
        names.push("report.json".into());
    }

    let mut report = run_report(input_name, ctx, &model, config, figures, names);
    report.seconds = start.elapsed().as_secs_f64();
    if write_report {
        let bytes =
            serde_json::to_vec_pretty(&report).map_err(|e| ExportError::Format(e.to_string()))?;
        outputs.stage(&[("report.json".to_string(), bytes)])?;
    }
    outputs.commit()?;
    Ok(report)
}

/// The finish stage of the polygonized `mesh` (whose key is `mesh_key`) through the cache:
/// the mesh as written, its key and its figures. `embedded` is what the meshing proved.
#[allow(clippy::too_many_arguments)]
fn finish_stage(
    ctx: &mut Ctx<'_>,
    model: &Model,
    mesh: &crate::mesh::TriangleMesh,
    mesh_key: &Key,
    embedded: bool,
    points: &[[f64; 3]],
    colours: Option<&[[u16; 3]]>,
    config: &ResolvedConfig,
) -> Result<(Finished, Key, FinishReport), PipelineError> {
    ctx.stage(
        "finish",
        finish::STAGE_VERSION,
        &cache::params_bytes(&config.finish),
        mesh_key,
        || {
            Ok(finish::finish(
                model,
                mesh,
                embedded,
                points,
                colours,
                &config.finish,
            )?)
        },
    )
}

/// The polygonize stage of `model` through the cache: its mesh and key, at the finest depth
/// near the input `points` where their `normals` are not flat (the model's key covers both).
/// The stage's figures say whether the meshing proved the mesh embedded (`"embedded"`).
fn polygonize_stage(
    ctx: &mut Ctx<'_>,
    model: &Model,
    model_key: &Key,
    points: &[[f64; 3]],
    normals: Option<&[[f64; 3]]>,
    config: &ResolvedConfig,
) -> Result<(crate::mesh::TriangleMesh, Key, PolygonizeReport), PipelineError> {
    let region = model.region();
    ctx.stage(
        "polygonize",
        POLYGONIZE_VERSION,
        &cache::params_bytes(&config.polygonize),
        model_key,
        || {
            let out = polygonize::polygonize_with_data(
                model.function(),
                &region,
                points,
                normals,
                &config.polygonize,
            )?;
            let report = PolygonizeReport {
                depth: config.polygonize.depth,
                fit_chords: config.polygonize.fit_chords,
                chord_share: config.polygonize.chords(),
                vertices: out.mesh.positions.len(),
                triangles: out.mesh.triangles.len(),
                evaluations: out.evaluations,
                simplified: out.simplified,
                pinned_vertices: out.pinned_vertices,
                refine: config.polygonize.refine,
                refined_vertices: out.refined_vertices,
                embedded: out.embedded,
            };
            Ok((out.mesh, report))
        },
    )
}
