//! The pipeline: import → normals → fit → polygonize, chained through the stage cache, then
//! the exports. This is what `stablesurf run` calls.
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

use serde::Serialize;

use crate::cache::{self, Artifact, Cache, Key, OutputFiles};
use crate::cloud::{Aabb, OrientedCloud, PointCloud};
use crate::detail::{self, DetailParams, MpuModel};
use crate::export::{self, ExportError};
use crate::fit::{self, FitParams};
use crate::import;
use crate::measure::{self, Accuracy};
use crate::mesh::{self, MeshReport, TriangleMesh};
use crate::normals::{self, NormalsParams};
use crate::outliers::{self, OutlierParams};
use crate::outputs::OutputSet;
use crate::poly::ImplicitModel;
use crate::polygonize::{self, ImplicitFunction, PolygonizeParams};
use crate::trim::{self, TrimParams, TrimReport};

/// The small real scan built into the binary: "Spot" the cow by Keenan Crane (CC0 1.0),
/// 2,930 vertices, 5,856 triangles.
pub const SAMPLE_SCAN: &[u8] = include_bytes!("sample/spot.obj");
/// The name the sample scan is reported under.
pub const SAMPLE_NAME: &str = "spot.obj (built-in sample, Keenan Crane, CC0)";

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
    /// Trimming the mesh to its data failed.
    #[error("trimming the mesh failed")]
    Trim(#[from] trim::TrimError),
    /// Writing an output failed.
    #[error("writing outputs failed")]
    Export(#[from] ExportError),
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

/// Which model the pipeline fits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum Mode {
    /// One polynomial (the paper's compact, invariant descriptor).
    #[default]
    Global,
    /// A multi-level partition of unity of local fits.
    Detail,
}

/// The fitted model of a run: one polynomial, or the detail mode's blend of local fits.
#[derive(Clone, Debug)]
pub enum Model {
    /// `--mode global`.
    Global(ImplicitModel),
    /// `--mode detail`.
    Detail(MpuModel),
}

impl Model {
    /// The mode that makes this kind of model.
    pub fn mode(&self) -> Mode {
        match self {
            Model::Global(_) => Mode::Global,
            Model::Detail(_) => Mode::Detail,
        }
    }

    /// Reads a model file of either kind from its bytes: a `stablesurf.mpu` file (detail) by its
    /// magic, else `model.json` (global). `path` names the file in errors.
    ///
    /// # Errors
    /// [`ExportError`] when the bytes are not a valid model file of the kind they look like.
    ///
    /// ```
    /// use std::path::Path;
    /// use stablesurf::pipeline::Model;
    /// let err = Model::from_bytes(b"{}", Path::new("m.json")).unwrap_err();
    /// assert!(err.to_string().contains("m.json"));
    /// ```
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Model, ExportError> {
        Ok(if export::mpu::is_mpu(bytes) {
            Model::Detail(export::mpu::read_mpu(bytes, path)?)
        } else {
            Model::Global(export::model::read_model(bytes, path)?)
        })
    }

    /// The model as a function to mesh and sign distances with.
    pub fn function(&self) -> &dyn ImplicitFunction {
        match self {
            Model::Global(m) => &m.polynomial,
            Model::Detail(m) => m,
        }
    }

    /// The region the model is meshed in (input coordinates).
    pub fn region(&self) -> Aabb {
        match self {
            Model::Global(m) => meshing_region(m),
            Model::Detail(m) => m.region,
        }
    }

    /// The model's settings and diagnostics, for `report.json`.
    pub fn report(&self) -> serde_json::Value {
        match self {
            Model::Global(m) => {
                serde_json::json!({ "mode": "global", "fit": m.fit, "diagnostics": m.diagnostics })
            }
            Model::Detail(m) => serde_json::json!({
                "mode": "detail",
                "diagnostics": m.diagnostics,
            }),
        }
    }

    /// The model file's name and bytes: `model.json` (global) or `model.mpu` (detail).
    ///
    /// # Errors
    /// [`ExportError`] from the writer.
    pub fn file(&self) -> Result<(&'static str, Vec<u8>), ExportError> {
        let mut bytes = Vec::new();
        match self {
            Model::Global(m) => {
                export::model::write_model(m, &mut bytes)?;
                Ok(("model.json", bytes))
            }
            Model::Detail(m) => {
                export::mpu::write_mpu(m, &mut bytes)?;
                Ok(("model.mpu", bytes))
            }
        }
    }
}

/// An output file kind of `run`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum OutputFormat {
    /// `mesh.glb`.
    Glb,
    /// `mesh.gltf` + `mesh.bin`.
    Gltf,
    /// `mesh.ply` (binary, with normals and per-vertex quality).
    Ply,
    /// `slices/slice_NNN.exr` signed-distance slices.
    Exr,
    /// `preview.png` (a shaded render of the mesh) and `slices/slice_NNN.png` previews.
    Png,
    /// The model file (`model.json`, or `model.mpu` in detail mode) and `report.json`.
    Json,
}

impl std::str::FromStr for OutputFormat {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s.trim() {
            "glb" => OutputFormat::Glb,
            "gltf" => OutputFormat::Gltf,
            "ply" => OutputFormat::Ply,
            "exr" => OutputFormat::Exr,
            "png" => OutputFormat::Png,
            "json" => OutputFormat::Json,
            other => {
                return Err(format!(
                    "unknown output format '{other}' (choose from glb, gltf, ply, exr, png, json)"
                ))
            }
        })
    }
}

/// A mesh file format: `run`'s `mesh.glb`, `mesh.gltf` and `mesh.ply`, and the `-o` of
/// `stablesurf mesh`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    /// Binary glTF, one file.
    Glb,
    /// glTF JSON and the binary buffer it refers to, `<stem>.bin` beside it.
    Gltf,
    /// PLY ([`export::ply`]).
    Ply,
}

impl MeshFormat {
    /// The format a file name's extension names, in any case: `.glb`, `.gltf` or `.ply`.
    ///
    /// ```
    /// use std::path::Path;
    /// use stablesurf::pipeline::MeshFormat;
    /// assert_eq!(MeshFormat::from_path(Path::new("out/a.GLB")), Some(MeshFormat::Glb));
    /// assert_eq!(MeshFormat::from_path(Path::new("a.obj")), None);
    /// ```
    pub fn from_path(path: &Path) -> Option<MeshFormat> {
        let extension = path.extension()?.to_string_lossy().to_ascii_lowercase();
        match extension.as_str() {
            "glb" => Some(MeshFormat::Glb),
            "gltf" => Some(MeshFormat::Gltf),
            "ply" => Some(MeshFormat::Ply),
            _ => None,
        }
    }
}

/// How [`mesh_files`] writes a mesh: the glTF options for glTF, the PLY options for PLY.
#[derive(Clone, Copy, Debug, Default)]
pub struct MeshFileOptions<'a> {
    /// Options of the glTF writers.
    pub gltf: export::gltf::GltfOptions,
    /// Options of the PLY writer (encoding, per-vertex quality).
    pub ply: export::ply::PlyOptions<'a>,
}

/// The files of `mesh` in `format`, named after `name` (a file name such as `mesh.glb`), as
/// (file name, bytes): `name` alone, or for glTF the buffer `<stem of name>.bin` first and
/// then `name`, which refers to the buffer by that file name. The one mesh writer of `run` and
/// `stablesurf mesh`; the caller puts the files where they belong.
///
/// # Errors
/// [`ExportError`] from the writer (an empty or invalid mesh, a glTF over its size limit).
///
/// ```
/// use stablesurf::pipeline::{mesh_files, MeshFileOptions, MeshFormat};
/// use stablesurf::TriangleMesh;
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 3],
///     triangles: vec![[0, 1, 2]],
/// };
/// let opts = MeshFileOptions::default();
/// let files = mesh_files(&mesh, MeshFormat::Gltf, "a.gltf", &opts).unwrap();
/// let names: Vec<&str> = files.iter().map(|(name, _)| name.as_str()).collect();
/// assert_eq!(names, ["a.bin", "a.gltf"]);
/// ```
pub fn mesh_files(
    mesh: &TriangleMesh,
    format: MeshFormat,
    name: &str,
    opts: &MeshFileOptions<'_>,
) -> Result<Vec<(String, Vec<u8>)>, ExportError> {
    let mut bytes = Vec::new();
    match format {
        MeshFormat::Glb => export::gltf::write_glb(mesh, &mut bytes, &opts.gltf)?,
        MeshFormat::Gltf => {
            let bin_name = Path::new(name)
                .with_extension("bin")
                .to_string_lossy()
                .into_owned();
            let mut bin = Vec::new();
            export::gltf::write_gltf(mesh, &mut bytes, &mut bin, &bin_name, &opts.gltf)?;
            return Ok(vec![(bin_name, bin), (name.to_string(), bytes)]);
        }
        MeshFormat::Ply => export::ply::write(mesh, &mut bytes, &opts.ply)?,
    }
    Ok(vec![(name.to_string(), bytes)])
}

/// Everything that decides what `run` computes and writes.
#[derive(Clone, Debug)]
pub struct PipelineConfig {
    /// Global or detail model.
    pub mode: Mode,
    /// Which points are left out as outliers before the normals ([`outliers`]).
    pub outliers: OutlierParams,
    /// Normals stage parameters.
    pub normals: NormalsParams,
    /// Fit stage parameters (global mode).
    pub fit: FitParams,
    /// Detail fit parameters (detail mode).
    pub detail: DetailParams,
    /// Polygonize stage parameters (see [`PipelineConfig::for_mode`]).
    pub polygonize: PolygonizeParams,
    /// Which zero-set components the mesh keeps (see [`PipelineConfig::for_mode`]).
    pub keep: Keep,
    /// Trim stage parameters (see [`PipelineConfig::for_mode`]).
    pub trim: TrimParams,
    /// Distance slice parameters: 16 slices of 128² along z, by default exact distances in
    /// global mode and the distance to the mesh in detail mode, which has only that one (see
    /// [`PipelineConfig::for_mode`]).
    pub slices: crate::distance::SliceParams,
    /// glTF options.
    pub gltf: export::gltf::GltfOptions,
    /// Which files to write.
    pub formats: Vec<OutputFormat>,
}

/// Which zero-set components the mesh keeps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum Keep {
    /// Every component.
    #[default]
    All,
    /// Only components with a data point within 2% of the data's diagonal, and no small closed
    /// piece inside another ([`mesh::drop_small_nested_components`]).
    Data,
}

impl PipelineConfig {
    /// The defaults of a `mode` run, the ones `stablesurf run --mode MODE` starts from: every
    /// stage's `…Params::default()`, 16 distance slices of 128² along z, every output format,
    /// and per mode:
    ///
    /// | mode   | topology guard | components kept     | trim         | slice distance |
    /// |--------|----------------|---------------------|--------------|----------------|
    /// | global | 3 levels       | all (the model's)   | off          | exact          |
    /// | detail | none           | data ([`Keep::Data`]) | on (support) | mesh           |
    ///
    /// A polynomial's zero set is the model, so all of it is kept. A detail model's blend
    /// extrapolates past the data (it can close a blob in empty space), so the pieces and the
    /// parts of the surface the data does not support are left out; its loose gradient
    /// enclosure cannot pass the topology guard's test (it would refine nearly everywhere), and
    /// only the distance to the mesh is defined for it.
    ///
    /// ```
    /// use stablesurf::distance::DistanceMethod;
    /// use stablesurf::pipeline::{Keep, Mode, PipelineConfig};
    /// let detail = PipelineConfig::for_mode(Mode::Detail);
    /// assert_eq!(detail.mode, Mode::Detail);
    /// assert_eq!(detail.keep, Keep::Data);
    /// assert_eq!(detail.slices.method, DistanceMethod::Mesh);
    /// assert_eq!(PipelineConfig::for_mode(Mode::Global).polygonize.guard_levels, 3);
    /// ```
    pub fn for_mode(mode: Mode) -> PipelineConfig {
        let global = PipelineConfig {
            mode: Mode::Global,
            outliers: OutlierParams::default(),
            normals: NormalsParams::default(),
            fit: FitParams::default(),
            detail: DetailParams::default(),
            polygonize: PolygonizeParams::default(),
            keep: Keep::All,
            trim: TrimParams::off(),
            slices: crate::distance::SliceParams {
                resolution: 128,
                method: crate::distance::DistanceMethod::Exact,
                ..Default::default()
            },
            gltf: Default::default(),
            formats: vec![
                OutputFormat::Glb,
                OutputFormat::Ply,
                OutputFormat::Exr,
                OutputFormat::Png,
                OutputFormat::Json,
            ],
        };
        match mode {
            Mode::Global => global,
            Mode::Detail => PipelineConfig {
                mode: Mode::Detail,
                polygonize: PolygonizeParams {
                    guard_levels: 0,
                    ..global.polygonize
                },
                keep: Keep::Data,
                trim: TrimParams::default(),
                slices: crate::distance::SliceParams {
                    method: crate::distance::DistanceMethod::Mesh,
                    ..global.slices
                },
                ..global
            },
        }
    }
}

impl Default for PipelineConfig {
    /// The defaults of the default mode ([`Mode::Global`]): `PipelineConfig::for_mode(Mode::default())`.
    fn default() -> Self {
        PipelineConfig::for_mode(Mode::default())
    }
}

/// Where the scan comes from.
#[derive(Clone, Debug)]
pub enum ScanSource {
    /// A file.
    File(PathBuf),
    /// The built-in sample ([`SAMPLE_SCAN`]).
    Sample,
    /// A Stanford `.conf` registration file: its scans, each oriented in its own frame, moved
    /// by their poses and merged ([`crate::merge`]).
    Conf(PathBuf),
    /// Several scans of one object, already in one frame (identity poses), each oriented on its
    /// own and then merged.
    Files(Vec<PathBuf>),
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
        }
    }
}

/// One stage's line in the report.
#[derive(Clone, Debug, Serialize)]
pub struct StageRecord {
    /// Stage name.
    pub stage: &'static str,
    /// "hit", "miss" or "corrupt" (recomputed), or "none" for uncached stages.
    pub cache: &'static str,
    /// Wall time in seconds.
    pub seconds: f64,
    /// Cache key (hex), when cached.
    pub key: Option<String>,
    /// Key figures of the stage's output.
    pub figures: serde_json::Value,
}

/// What the run produced and measured (written as `report.json`).
#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    /// The scan (file path or sample name).
    pub input: String,
    /// One record per stage, in order.
    pub stages: Vec<StageRecord>,
    /// The fitted model's settings and diagnostics.
    pub fit: serde_json::Value,
    /// What the trim stage removed and closed.
    pub trim: TrimReport,
    /// Mesh topology checks.
    pub mesh: MeshReport,
    /// Two-sided distances between the input points and the mesh, absolute and relative to the
    /// data's diagonal: data → mesh, mesh → data by area, and the share of the mesh's area far
    /// from every data point.
    pub accuracy: Accuracy,
    /// Files written, relative to the output directory.
    pub outputs: Vec<String>,
    /// Every warning the run printed.
    pub warnings: Vec<String>,
    /// Total wall time in seconds.
    pub seconds: f64,
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
const IMPORT_VERSION: u32 = 2;
/// Merging the views of a `.conf` or of several files.
const MERGE_VERSION: u32 = 1;
/// The outlier filter is not cached (it is a linear pass), but its output's key chains
/// through it when it leaves points out.
const OUTLIERS_VERSION: u32 = 1;
const NORMALS_VERSION: u32 = 4;
const FIT_VERSION: u32 = 2;
const POLYGONIZE_VERSION: u32 = 2;
const EXPORT_VERSION: u32 = 5;

/// With `Keep::Data`, closed pieces inside another piece and smaller than this share of the
/// largest piece's area are left out ([`mesh::drop_small_nested_components`]).
const NESTED_AREA_FRACTION: f64 = 0.01;

struct Ctx<'a> {
    /// The run's cache: the one asked for, or a disabled one when it cannot be written.
    cache: Cache,
    /// The misses' entries, stored beside the next stages' work.
    puts: cache::Puts,
    observer: &'a mut dyn Observer,
    stages: Vec<StageRecord>,
    /// Every warning told to the observer, for the report.
    warnings: Vec<String>,
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
        };
        for w in warnings {
            ctx.warn(w);
        }
        Ok(ctx)
    }

    /// Tells the warnings in the last stage's figures (`"warnings"`), on a hit as on a miss.
    fn warn_figures(&mut self) {
        let warnings: Vec<String> = self
            .stages
            .last()
            .and_then(|s| s.figures["warnings"].as_array())
            .into_iter()
            .flatten()
            .filter_map(|w| w.as_str().map(str::to_string))
            .collect();
        for w in warnings {
            self.warn(w);
        }
    }

    /// Tells the observer a warning and keeps it for the report.
    fn warn(&mut self, message: String) {
        self.observer.warning(&message);
        self.warnings.push(message);
    }

    /// Waits for the cache writes. One that failed costs only the next run's time, so it is a
    /// warning: the outputs are complete either way.
    fn finish_puts(&mut self) {
        for e in self.puts.finish() {
            self.warn(format!(
                "{e}; this run's results are complete but were not all cached"
            ));
        }
    }

    /// Runs one cached stage: look up, else compute and store. `figures` summarizes the output
    /// for the report; on a hit the stored figures are reused.
    fn stage<T: Artifact>(
        &mut self,
        stage: &'static str,
        version: u32,
        params: &[u8],
        input_key: &Key,
        compute: impl FnOnce() -> Result<(T, serde_json::Value), PipelineError>,
    ) -> Result<(T, Key), PipelineError> {
        self.stage_from(None, stage, version, params, input_key, compute)
    }

    /// [`Self::stage`] for a stage whose work began before this call, at `announced` (its start
    /// already told to the observer): its time counts from there.
    fn stage_from<T: Artifact>(
        &mut self,
        announced: Option<Instant>,
        stage: &'static str,
        version: u32,
        params: &[u8],
        input_key: &Key,
        compute: impl FnOnce() -> Result<(T, serde_json::Value), PipelineError>,
    ) -> Result<(T, Key), PipelineError> {
        let start = announced.unwrap_or_else(|| {
            self.observer.stage_started(stage);
            Instant::now()
        });
        let key = cache::stage_key(stage, version, params, input_key);
        let (found, lookup) = self.cache.get::<T>(stage, version, &key);
        let (value, figures, lookup) = match found {
            // The figures are stored inside the entry, under its checksum.
            Some((v, meta)) => (v, meta.get("figures").cloned().unwrap_or_default(), lookup),
            None => {
                let (v, figures) = compute()?;
                let meta = serde_json::json!({
                    "stage": stage,
                    "stage_version": version,
                    "cache_format_version": cache::CACHE_FORMAT_VERSION,
                    "params": serde_json::from_slice::<serde_json::Value>(params).unwrap_or_default(),
                    "input_key": input_key.hex(),
                    "seconds": start.elapsed().as_secs_f64(),
                    "figures": figures,
                });
                self.puts.put(stage, version, &key, &v, &meta);
                (v, figures, lookup)
            }
        };
        self.finish(stage, lookup.as_str(), start, Some(key), figures);
        Ok((value, key))
    }

    fn finish(
        &mut self,
        stage: &'static str,
        cache: &'static str,
        start: Instant,
        key: Option<Key>,
        figures: serde_json::Value,
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

/// The views of a multi-view source (`None` for a single scan), poses included.
fn views_of(source: &ScanSource) -> Result<Option<Vec<import::conf::View>>, PipelineError> {
    Ok(match source {
        ScanSource::Sample | ScanSource::File(_) => None,
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

/// Import, outliers and normals through the cache: the fit's input. Several views (a `.conf`,
/// or several files) are each oriented in their own frame, then merged.
fn orient_stages(
    ctx: &mut Ctx<'_>,
    source: &ScanSource,
    config: &PipelineConfig,
) -> Result<(PointCloud, OrientedCloud, Key), PipelineError> {
    match views_of(source)? {
        Some(views) => merged_views(ctx, &views, config),
        None => {
            let (bytes, path) = match source {
                ScanSource::File(path) => (read_bytes(path)?, path.clone()),
                _ => (SAMPLE_SCAN.to_vec(), PathBuf::from("spot.obj")),
            };
            oriented_scan(ctx, bytes, &path, config)
        }
    }
}

/// Each view imported and oriented in its own frame (through the cache), then moved by its
/// pose and merged (the `merge` stage, keyed by every view's normals key, which covers its
/// file's bytes, and every pose).
fn merged_views(
    ctx: &mut Ctx<'_>,
    views: &[import::conf::View],
    config: &PipelineConfig,
) -> Result<(PointCloud, OrientedCloud, Key), PipelineError> {
    let mut oriented = Vec::with_capacity(views.len());
    let mut keys = Vec::new();
    for view in views {
        let bytes = read_bytes(&view.path)?;
        let (_, cloud, key) = oriented_scan(ctx, bytes, &view.path, config)?;
        keys.extend_from_slice(key.hex().as_bytes());
        oriented.push((cloud, view.pose));
    }
    let poses: Vec<crate::merge::Pose> = views.iter().map(|v| v.pose).collect();
    let (merged, key) = ctx.stage(
        "merge",
        MERGE_VERSION,
        &cache::params_bytes(&poses),
        &Key::of_bytes(&keys),
        || {
            let refs: Vec<(&OrientedCloud, crate::merge::Pose)> =
                oriented.iter().map(|(c, p)| (c, *p)).collect();
            let merged = crate::merge::merge_views(&refs);
            let figures = serde_json::json!({
                "views": views.len(),
                "points": merged.points.len(),
                "weighted": merged.weights.is_some(),
            });
            Ok((merged, figures))
        },
    )?;
    let cloud = PointCloud {
        points: merged.points.clone(),
        normals: Some(merged.normals.clone()),
        ..Default::default()
    };
    Ok((cloud, merged, key))
}

/// One scan through import, outlier removal and normals; returns the cloud, the oriented cloud
/// and the latter's key.
fn oriented_scan(
    ctx: &mut Ctx<'_>,
    bytes: Vec<u8>,
    path: &Path,
    config: &PipelineConfig,
) -> Result<(PointCloud, OrientedCloud, Key), PipelineError> {
    let (cloud, cloud_key) = ctx.stage(
        "import",
        IMPORT_VERSION,
        b"",
        &Key::of_bytes(&bytes),
        || {
            let scan = import::import_scan_bytes(&bytes, path)?;
            let figures = serde_json::json!({
                "points": scan.cloud.points.len(),
                "triangles": scan.cloud.triangles.len(),
                "has_normals": scan.cloud.normals.is_some(),
                "notices": scan.notices,
            });
            Ok((scan.cloud, figures))
        },
    )?;
    drop(bytes);
    // What the reader did not read (extra columns, other elements), on a hit too.
    if let Some(notices) = ctx
        .stages
        .last()
        .and_then(|s| s.figures["notices"].as_array())
    {
        let notices: Vec<String> = notices
            .iter()
            .filter_map(|n| n.as_str().map(str::to_string))
            .collect();
        for n in notices {
            ctx.observer.note(&format!("{}: {n}", path.display()));
        }
    }
    let (cloud, cloud_key) = without_outliers(ctx, cloud, cloud_key, &config.outliers);
    let (oriented, oriented_key) = ctx.stage(
        "normals",
        NORMALS_VERSION,
        &cache::params_bytes(&config.normals),
        &cloud_key,
        || {
            let normals = normals::estimate_normals(&cloud, &config.normals)?;
            let figures = serde_json::json!({
                "source": normals.source_used.as_str(),
                "surface_samples": normals.surface_samples,
                "warnings": normals.warnings,
            });
            Ok((normals.cloud, figures))
        },
    )?;
    ctx.warn_figures();
    Ok((cloud, oriented, oriented_key))
}

/// Imports, estimates normals and fits: the part of the pipeline shared by `run` and `fit`.
/// Returns the input cloud, the oriented cloud, the model and its key.
fn fit_stages(
    ctx: &mut Ctx<'_>,
    source: &ScanSource,
    config: &PipelineConfig,
) -> Result<(PointCloud, OrientedCloud, Model, Key), PipelineError> {
    let (cloud, oriented, oriented_key) = orient_stages(ctx, source, config)?;
    model_stages(ctx, cloud, oriented, oriented_key, config)
}

/// The global fit or the detail fit of the oriented cloud.
fn model_stages(
    ctx: &mut Ctx<'_>,
    cloud: PointCloud,
    oriented: OrientedCloud,
    oriented_key: Key,
    config: &PipelineConfig,
) -> Result<(PointCloud, OrientedCloud, Model, Key), PipelineError> {
    let (model, model_key) = match config.mode {
        Mode::Global => {
            let (model, key) = ctx.stage(
                "fit",
                FIT_VERSION,
                &cache::params_bytes(&config.fit),
                &oriented_key,
                || {
                    let model = fit::fit(&oriented, &config.fit)?;
                    let figures = serde_json::json!({
                        "degree": model.polynomial.degree,
                        "kappa": model.fit.as_ref().map(|f| f.kappa),
                        "bounded": model.diagnostics.as_ref().map(|d| d.bounded),
                    });
                    Ok((model, figures))
                },
            )?;
            // The fit's warnings (a κ that fell back, an unbounded zero set) are the model's.
            for w in model.diagnostics.iter().flat_map(|d| d.warnings.clone()) {
                ctx.warn(w);
            }
            (Model::Global(model), key)
        }
        Mode::Detail => {
            let (model, key) = ctx.stage(
                "detail",
                detail::STAGE_VERSION,
                &cache::params_bytes(&config.detail),
                &oriented_key,
                || {
                    let model = detail::fit_detail(&oriented, &config.detail)?;
                    let d = &model.diagnostics;
                    let figures = serde_json::json!({
                        "cells": d.cells,
                        "grown_cells": d.grown_cells,
                        "depth_reached": d.depth_reached,
                        "mean_residual": d.mean_residual,
                        "max_residual": d.max_residual,
                    });
                    Ok((model, figures))
                },
            )?;
            (Model::Detail(model), key)
        }
    };
    Ok((cloud, oriented, model, model_key))
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
    ctx.warn(format!(
        "left out {} of {} points far outside the bulk of the data{far}{faces}; pass --keep-outliers to keep them",
        split.removed,
        cloud.points.len(),
    ));
    let params_bytes = cache::params_bytes(&serde_json::json!({
        "bulk_quantile": params.bulk_quantile,
        "far_factor": params.far_factor,
        "gap_factor": params.gap_factor,
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
    let (_, oriented, model, _) = fit_stages(&mut ctx, source, config)?;
    ctx.finish_puts();
    Ok((model, oriented, ctx.stages))
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
    let (_, oriented, _) = orient_stages(&mut ctx, source, config)?;
    ctx.warn_figures();
    ctx.finish_puts();
    Ok(oriented)
}

/// The region a model is meshed in: its stored box, or the normalization sphere's cube.
pub fn meshing_region(model: &ImplicitModel) -> Aabb {
    model.bounds.unwrap_or_else(|| {
        let p = &model.polynomial;
        let r = 1.6 * p.scale;
        Aabb {
            min: [p.center[0] - r, p.center[1] - r, p.center[2] - r],
            max: [p.center[0] + r, p.center[1] + r, p.center[2] + r],
        }
    })
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
    let (cloud, _oriented, model, model_key) = fit_stages(&mut ctx, source, config)?;

    let region = model.region();
    let polygonize_params = cache::params_bytes(&config.polygonize);
    let export_params = export_params_bytes(config);
    // The export stage's work splits in two: the slice files of a polynomial model need the
    // model only, everything else needs the mesh. When the export stage is going to run, the
    // slice files are made beside the meshing and then beside the mesh's outputs, so both cores
    // stay busy; the export stage then assembles the parts (the same bytes it would compute on
    // its own: each part depends on the same inputs alone). Its line counts from the end of the
    // meshing.
    let export_key = cache::stage_key(
        "export",
        EXPORT_VERSION,
        &export_params,
        &cache::stage_key(
            "polygonize",
            POLYGONIZE_VERSION,
            &polygonize_params,
            &model_key,
        ),
    );
    let export_runs = !cache.contains("export", &export_key);
    let early_from_model = export_runs && slices_from_model(config, &model);
    let mut early_slices = None;
    let (polygonized, mut early_parts, export_start) = rayon::in_place_scope(|scope| {
        if early_from_model {
            scope.spawn(|_| early_slices = model_slice_files(config, &model, &region));
        }
        let polygonized = ctx.stage(
            "polygonize",
            POLYGONIZE_VERSION,
            &polygonize_params,
            &model_key,
            || {
                let out = polygonize::polygonize(model.function(), &region, &config.polygonize)?;
                let figures = serde_json::json!({
                    "vertices": out.mesh.positions.len(),
                    "triangles": out.mesh.triangles.len(),
                    "evaluations": out.evaluations,
                    "simplified": out.simplified,
                });
                Ok((out.mesh, figures))
            },
        );
        let export_start = Instant::now();
        let parts = match &polygonized {
            Ok((mesh, _)) if export_runs => {
                ctx.observer.stage_started("export");
                let with_slices = !early_from_model;
                Some(mesh_parts(
                    config,
                    &model,
                    mesh.clone(),
                    &cloud,
                    &region,
                    with_slices,
                ))
            }
            _ => None,
        };
        (polygonized, parts, export_start)
    });
    let (mesh, mesh_key) = polygonized?;

    // Everything after meshing (component filter, checks, accuracy, the bytes of every output
    // file) is one more cached stage: a rerun with the same inputs only copies files out.
    let announced = early_parts.is_some().then_some(export_start);
    let (files, _) = ctx.stage_from(
        announced,
        "export",
        EXPORT_VERSION,
        &export_params,
        &mesh_key,
        || {
            // Made above, or here when that was skipped (an export entry found on disk that then
            // failed to decode).
            let parts = match early_parts.take() {
                Some(parts) => parts?,
                None => {
                    let with_slices = early_slices.is_none();
                    mesh_parts(config, &model, mesh, &cloud, &region, with_slices)?
                }
            };
            let slice_files = match (early_slices.take(), parts.slices) {
                (Some(files), _) => files?,
                (None, Some(files)) => files,
                (None, None) => slice_files(config, &model, &parts.mesh, &region)?,
            };
            let mut files = parts.files;
            files.extend(slice_files);
            let figures = serde_json::json!({
                "files": files.len(),
                "bytes": files.iter().map(|f| f.1.len()).sum::<usize>(),
                "dropped_components": parts.dropped,
                "dropped_nested": parts.nested,
                "trim": parts.trim,
                "mesh": parts.report,
                "accuracy": parts.accuracy,
            });
            Ok((OutputFiles(files), figures))
        },
    )?;
    let figures = &ctx
        .stages
        .last()
        .map(|s| s.figures.clone())
        .unwrap_or_default();
    let report_mesh: MeshReport =
        serde_json::from_value(figures["mesh"].clone()).unwrap_or_default();
    let accuracy: Accuracy =
        serde_json::from_value(figures["accuracy"].clone()).unwrap_or_default();
    let trim_report: TrimReport =
        serde_json::from_value(figures["trim"].clone()).unwrap_or_default();
    // A polynomial's zero set that runs out of the meshing box is open there: not a bounded
    // surface in this mesh, whatever the fit certified.
    let dropped = figures["dropped_components"].as_u64().unwrap_or(0);
    if dropped > 0 {
        ctx.warn(format!(
            "left out {dropped} piece(s) of the surface with no data point within 2% of the diagonal; --keep all keeps them"
        ));
    }
    let nested = figures["dropped_nested"].as_u64().unwrap_or(0);
    if nested > 0 {
        ctx.warn(format!(
            "left out {nested} small closed piece(s) inside the surface (each under {}% of the largest piece's area); --keep all keeps them",
            100.0 * NESTED_AREA_FRACTION
        ));
    }
    let clipped = matches!(model, Model::Global(_)) && report_mesh.boundary_edges > 0;
    if clipped {
        ctx.warn(format!(
            "the zero set is clipped by the meshing box: the mesh is open along {} boundary edges, so it is not a bounded surface here; try another --degree or --kappa, or --mode detail",
            report_mesh.boundary_edges
        ));
    }

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
        serde_json::json!({ "files": files.0.len() }),
    );
    let mut names: Vec<String> = files.0.iter().map(|f| f.0.clone()).collect();
    let write_report = config.formats.contains(&OutputFormat::Json);
    if write_report {
        names.push("report.json".into());
    }

    let mut report = RunReport {
        input: input_name,
        stages: ctx.stages,
        fit: {
            let mut fit = model.report();
            if let (Model::Detail(_), Some(map)) = (&model, fit.as_object_mut()) {
                map.insert(
                    "params".into(),
                    serde_json::to_value(&config.detail).unwrap_or_default(),
                );
            }
            if clipped {
                fit["clipped"] = true.into();
                if let Some(d) = fit["diagnostics"].as_object_mut() {
                    d.insert("bounded".into(), false.into());
                }
            }
            fit
        },
        trim: trim_report,
        mesh: report_mesh,
        accuracy,
        outputs: names,
        warnings: ctx.warnings,
        seconds: 0.0,
    };
    report.seconds = start.elapsed().as_secs_f64();
    if write_report {
        let bytes =
            serde_json::to_vec_pretty(&report).map_err(|e| ExportError::Format(e.to_string()))?;
        outputs.stage(&[("report.json".to_string(), bytes)])?;
    }
    outputs.commit()?;
    Ok(report)
}

/// Canonical bytes of everything that decides the output files besides the mesh and model.
fn export_params_bytes(config: &PipelineConfig) -> Vec<u8> {
    let formats: Vec<String> = config.formats.iter().map(|f| format!("{f:?}")).collect();
    cache::params_bytes(&serde_json::json!({
        "formats": formats,
        "keep": format!("{:?}", config.keep),
        "trim": config.trim,
        "trim_version": trim::STAGE_VERSION,
        "up": format!("{:?}", config.gltf.up),
        "slices": {
            "axis": config.slices.axis.name(),
            "count": config.slices.count,
            "resolution": config.slices.resolution,
            "method": config.slices.method.name(),
        },
    }))
}

/// Output files as (name relative to the output directory, bytes).
type Files = Vec<(String, Vec<u8>)>;

/// What the export stage makes from the mesh: the mesh as kept (components far from the data
/// dropped when asked), its checks, the accuracy figures, the mesh's output files and, when
/// asked, the slice files.
struct MeshParts {
    mesh: TriangleMesh,
    dropped: usize,
    nested: usize,
    trim: TrimReport,
    report: MeshReport,
    accuracy: Accuracy,
    files: Files,
    slices: Option<Files>,
}

/// The export stage's mesh part: the component filter, then the checks, the accuracy, the
/// model, glTF, PLY (with its vertex quality) and preview files and, `with_slices`, the slice
/// files ([`slice_files`]: the distance to the kept mesh for a detail model), all at once. The
/// files come out in a fixed order whatever the thread count.
fn mesh_parts(
    config: &PipelineConfig,
    model: &Model,
    mut mesh: TriangleMesh,
    cloud: &PointCloud,
    region: &Aabb,
    with_slices: bool,
) -> Result<MeshParts, PipelineError> {
    let data_diagonal = Aabb::from_points(&cloud.points).map_or(0.0, |b| b.diagonal());
    let (mut dropped, mut nested) = (0, 0);
    if config.keep == Keep::Data {
        let (kept, n) = mesh::drop_components_far_from(&mesh, &cloud.points, 0.02 * data_diagonal);
        (mesh, dropped) = (kept, n);
        let (kept, n) = mesh::drop_small_nested_components(&mesh, NESTED_AREA_FRACTION);
        (mesh, nested) = (kept, n);
    }
    // The trim stage: the surface the data supports (the mesh itself when all of it is).
    let trimmed = trim::trim(&mesh, &cloud.points, &config.trim)?;
    let trim_report = trimmed.report;
    if trim_report.removed_triangles > 0 {
        mesh = trimmed.mesh;
    }
    let want = |f| config.formats.contains(&f);
    let one = |name: &str, bytes: Vec<u8>| -> Files { vec![(name.to_string(), bytes)] };
    let m = &mesh;
    let mesh_opts = MeshFileOptions {
        gltf: config.gltf,
        ..Default::default()
    };
    let json = || -> Result<Files, PipelineError> {
        if !want(OutputFormat::Json) {
            return Ok(Vec::new());
        }
        let (name, bytes) = model.file()?;
        Ok(one(name, bytes))
    };
    let glb = || -> Result<Files, PipelineError> {
        if !want(OutputFormat::Glb) {
            return Ok(Vec::new());
        }
        Ok(mesh_files(m, MeshFormat::Glb, "mesh.glb", &mesh_opts)?)
    };
    let gltf = || -> Result<Files, PipelineError> {
        if !want(OutputFormat::Gltf) {
            return Ok(Vec::new());
        }
        Ok(mesh_files(m, MeshFormat::Gltf, "mesh.gltf", &mesh_opts)?)
    };
    let ply = || -> Result<Files, PipelineError> {
        if !want(OutputFormat::Ply) {
            return Ok(Vec::new());
        }
        let quality = export::ply::nearest_point_distances(&m.positions, &cloud.points)?;
        let opts = MeshFileOptions {
            ply: export::ply::PlyOptions {
                quality: Some(&quality),
                ..Default::default()
            },
            ..mesh_opts
        };
        Ok(mesh_files(m, MeshFormat::Ply, "mesh.ply", &opts)?)
    };
    let preview = || -> Result<Files, PipelineError> {
        if !want(OutputFormat::Png) {
            return Ok(Vec::new());
        }
        let params = crate::render::RenderParams {
            up: config.gltf.up,
            ..Default::default()
        };
        let image = crate::render::render(m, &params);
        Ok(one(
            "preview.png",
            encode(&|w| export::png::write_rgb(&image, w))?,
        ))
    };
    let slices = || with_slices.then(|| slice_files(config, model, m, region));
    let (slices, ((report, accuracy), (json, ((glb, gltf), (ply, preview))))) =
        rayon::join(slices, || {
            rayon::join(
                || {
                    rayon::join(
                        || mesh::check(m),
                        || measure::accuracy(&cloud.points, m, data_diagonal),
                    )
                },
                || {
                    rayon::join(json, || {
                        rayon::join(|| rayon::join(glb, gltf), || rayon::join(ply, preview))
                    })
                },
            )
        });
    let slices = slices.transpose()?;
    let mut files = Vec::new();
    for part in [json?, glb?, gltf?, ply?, preview?] {
        files.extend(part);
    }
    Ok(MeshParts {
        mesh,
        dropped,
        nested,
        trim: trim_report,
        report,
        accuracy,
        files,
        slices,
    })
}

/// The bytes `f` writes.
fn encode(f: &dyn Fn(&mut Vec<u8>) -> Result<(), ExportError>) -> Result<Vec<u8>, PipelineError> {
    let mut bytes = Vec::new();
    f(&mut bytes)?;
    Ok(bytes)
}

/// The slice files when they can be made without the mesh (a polynomial model, a distance that
/// is not the mesh's, and slices among the formats); `None` otherwise.
fn model_slice_files(
    config: &PipelineConfig,
    model: &Model,
    region: &Aabb,
) -> Option<Result<Files, PipelineError>> {
    match model {
        Model::Global(m) if slices_from_model(config, model) => Some(
            crate::distance::slices(&m.polynomial, region, &config.slices)
                .map_err(Into::into)
                .and_then(|slices| slice_images(config, &slices)),
        ),
        _ => None,
    }
}

/// Whether the formats ask for slices (OpenEXR or their PNG previews).
fn slices_wanted(config: &PipelineConfig) -> bool {
    [OutputFormat::Exr, OutputFormat::Png]
        .iter()
        .any(|f| config.formats.contains(f))
}

/// Whether [`model_slice_files`] makes the slice files (from the model alone).
fn slices_from_model(config: &PipelineConfig, model: &Model) -> bool {
    slices_wanted(config)
        && matches!(model, Model::Global(_))
        && config.slices.method != crate::distance::DistanceMethod::Mesh
}

/// The slice files (OpenEXR and PNG, as the formats ask): from the model alone when it can
/// ([`model_slice_files`]), else from the distance to `mesh`.
fn slice_files(
    config: &PipelineConfig,
    model: &Model,
    mesh: &TriangleMesh,
    region: &Aabb,
) -> Result<Files, PipelineError> {
    if !slices_wanted(config) {
        return Ok(Vec::new());
    }
    if let Some(files) = model_slice_files(config, model, region) {
        return files;
    }
    match config.slices.method {
        crate::distance::DistanceMethod::Mesh => {
            let slices =
                crate::distance::slices_from_mesh(model.function(), mesh, region, &config.slices)?;
            slice_images(config, &slices)
        }
        method => Err(PipelineError::Unsupported(format!(
            "{} distance slices need a global (polynomial) model; use --slice-distance mesh in detail mode",
            method.name()
        ))),
    }
}

/// Encodes the slices as the formats ask, in parallel; the files come out in slice order.
fn slice_images(
    config: &PipelineConfig,
    slices: &[crate::distance::Slice],
) -> Result<Files, PipelineError> {
    use rayon::prelude::*;
    let want = |f| config.formats.contains(&f);
    let images: Vec<Files> = slices
        .par_iter()
        .map(|slice| -> Result<Files, PipelineError> {
            let mut files = Vec::new();
            if want(OutputFormat::Exr) {
                let bytes = encode(&|w| {
                    export::exr::write_slice(slice, &export::exr::ExrOptions::default(), w)
                })?;
                files.push((format!("slices/slice_{:03}.exr", slice.index), bytes));
            }
            if want(OutputFormat::Png) {
                let bytes = encode(&|w| export::png::write_preview(slice, w))?;
                files.push((format!("slices/slice_{:03}.png", slice.index), bytes));
            }
            Ok(files)
        })
        .collect::<Result<_, _>>()?;
    Ok(images.into_iter().flatten().collect())
}
