//! The command line as clap parses it: the subcommands' argument structs and the typed values
//! of their flags (closed choices as `ValueEnum`s, numbers checked against their
//! [`range`](super::range) constants). Nothing here calls the library; `cli::config` turns these
//! values into the library's parameters.
//!
//! Input: `std::env::args`. Output: a [`Cli`]. A value clap refuses (an unknown choice, a number
//! out of range) is a usage error, exit code 2, before any work.

use std::ffi::OsStr;
use std::marker::PhantomData;
use std::path::PathBuf;

use clap::builder::{EnumValueParser, PossibleValue, TypedValueParser};
use clap::{Args, Parser, Subcommand, ValueEnum};
use stablesurf::fit;

use super::range::{
    number, BOUNDS_MAX_ABS, COUNT, DEGREE, DEPTH, EPSILON, FIT_STRIDE, KAPPA, LOCAL_DEGREE,
    RESOLUTION, SIZE, SLICE_COUNT, SLICE_RESOLUTION, SMOOTH, TARGET_TRIANGLES, THREADS, TOLERANCE,
    TRIM, VIEWPOINT, VOXEL_SIZE,
};

/// stablesurf: stable algebraic surfaces from 3D scans (Sahin & Unel 2008).
///
/// Imports a scan, estimates outward normals, fits an implicit polynomial with 3L and
/// Euclidean-invariant ridge regression, meshes its zero set with an adaptive octree and writes
/// glTF, PLY, OpenEXR distance slices and the polynomial itself.
#[derive(Debug, Parser)]
#[command(name = "stablesurf", version, about, long_about = None, propagate_version = true)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub command: CommandArgs,
    /// Print nothing but errors on stderr.
    #[arg(short, long, global = true, conflicts_with = "verbose")]
    pub quiet: bool,
    /// Print one line per stage (cache hit or miss, seconds, key figures); repeat for more.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(short = 'j', long, global = true, value_name = "N",
          help = THREADS.help("Worker threads (default: all cores). Results do not depend on it"),
          allow_negative_numbers = true, value_parser = THREADS.whole::<usize>())]
    pub threads: Option<usize>,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum CommandArgs {
    /// Scan to outputs in one command: import, normals, fit, mesh, export.
    Run(RunArgs),
    /// Estimate oriented normals and write them as a binary PLY.
    Normals(NormalsArgs),
    /// Fit an implicit polynomial and write the model file.
    Fit(FitArgs),
    /// Write one chunk's fit statistics (one pass of the moments protocol) for `fit --from-moments`.
    Moments(MomentsArgs),
    /// Merge pass-1 or pass-2 moments files into the next pass's --center or --frame value.
    Frame(FrameArgs),
    /// Mesh a model file's zero set.
    Mesh(MeshArgs),
    /// Write signed-distance slices (OpenEXR) and PNG previews of a model.
    Slices(SlicesArgs),
    /// Render a shaded picture of a mesh.
    Render(RenderArgs),
    /// Show what a scan, model or mesh file holds.
    Info(InfoArgs),
    /// Inspect or clear the stage cache.
    Cache(CacheArgs),
}

/// Options of the normals stage.
#[derive(Debug, Args, Clone)]
pub struct NormalsOpts {
    /// Where normals come from: auto (file normals, else mesh faces, else crust up to 200,000
    /// points and pca beyond), crust
    /// (Voronoi/Delaunay crust, paper section 5), pca (k-nearest-neighbour planes), mesh (the
    /// file's faces), input (the file's normals).
    #[arg(long = "normals", value_name = "SOURCE", default_value = "auto",
          value_parser = Trimmed::<SourceArg>::default(), ignore_case = true,
          hide_possible_values = true)]
    pub source: SourceArg,
    /// The sensor's position in input coordinates: every normal, whatever its source, is turned
    /// to face it. For several scans, each scan's own coordinates.
    #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true, value_parser = parse_viewpoint,
          help = viewpoint_help())]
    pub viewpoint: Option<[f64; 3]>,
}

/// Options of the fit stage.
#[derive(Debug, Args, Clone)]
pub struct FitOpts {
    /// Polynomial degree (even for automatic κ).
    #[arg(long, default_value_t = 8, value_name = "N",
          help = DEGREE.help("Polynomial degree, even for automatic κ"),
          allow_negative_numbers = true, value_parser = DEGREE.whole::<u32>())]
    pub degree: u32,
    /// Ridge weight κ: `auto` or a number.
    #[arg(long, default_value = "auto",
          help = KAPPA.help("Ridge weight κ: auto, or a number"),
          allow_negative_numbers = true, value_parser = parse_kappa)]
    pub kappa: KappaArg,
    /// Rule for automatic κ: `stable` (default, checks the zero set) or `paper` (section 6.3).
    #[arg(long, value_name = "RULE", value_enum, default_value_t = KappaRuleArg::Stable,
          ignore_case = true, hide_possible_values = true)]
    pub kappa_rule: KappaRuleArg,
    /// Layer offset ε in normalized units (paper: 0.01 to 0.05).
    #[arg(long, default_value_t = 0.05, value_name = "E",
          help = EPSILON.help("Layer offset ε in normalized units (paper: 0.01 to 0.05)"),
          allow_negative_numbers = true, value_parser = EPSILON.real())]
    pub epsilon: f64,
    /// Fitting method: 3lrr (3L + ridge regression), 3l (κ = 0) or ls (plain least squares).
    #[arg(long, value_enum, default_value_t = MethodArg::ThreeLrr, ignore_case = true,
          hide_possible_values = true)]
    pub method: MethodArg,
}

/// Options of the detail fit (`--mode detail`).
#[derive(Debug, Args, Clone)]
pub struct DetailOpts {
    /// Degree of the local fits in detail mode.
    #[arg(long, default_value_t = 2, value_name = "N",
          help = LOCAL_DEGREE.help("Degree of the local fits in detail mode"),
          allow_negative_numbers = true, value_parser = LOCAL_DEGREE.whole::<u32>())]
    pub local_degree: u32,
    /// Detail mode: split a cell while its fit is farther than this from its points (fraction
    /// of the bounding-box diagonal). Default: the library's, cut to 0.27× by `run` on points much
    /// finer than the mesh's cells.
    #[arg(long, value_name = "T", help = tolerance_help(),
          allow_negative_numbers = true, value_parser = TOLERANCE.real())]
    pub tolerance: Option<f64>,
    /// Detail mode: fit every N-th point along a Z-order curve (a spatially even subset).
    /// Default: 1; `run`: the points per occupied cell of the mesh's finest level over 6.
    #[arg(long, value_name = "N",
          help = FIT_STRIDE.help("Detail mode: fit every N-th point along a Z-order curve (a spatially even subset) [default: 1; `run`: the mean points per occupied cell of the mesh's finest level / 6, rounded down]"),
          allow_negative_numbers = true, value_parser = FIT_STRIDE.whole::<u32>())]
    pub fit_stride: Option<u32>,
    /// Detail mode: average noise of this many times the measured noise instead of following
    /// it (0: fit the points as exact).
    #[arg(long, value_name = "S", default_value_t = 1.0,
          help = SMOOTH.help("Detail mode: a factor on the measured noise of the points that the local fits average instead of following it (report.json's noise; 0 fits the points as exact, 2 smooths twice as much; points that scatter by less than half their spacing are fitted as exact)"),
          allow_negative_numbers = true, value_parser = SMOOTH.real())]
    pub smooth: f64,
}

/// Options of the polygonize stage.
#[derive(Debug, Args, Clone)]
pub struct MeshOpts {
    /// Octree depth near the surface: finest cell = longest side of the box / 2^depth
    /// [default: 7].
    #[arg(long, value_name = "D",
          help = depth_help(),
          allow_negative_numbers = true, value_parser = DEPTH.whole::<u32>())]
    pub depth: Option<u32>,
    /// Decimate the mesh by edge collapses (quadric error, new vertices on the model's
    /// surface) to at most N triangles, keeping it watertight, manifold, of the same genus and
    /// free of self-intersections; after the component filter and the trim. When no legal
    /// collapse is left above N, the smallest mesh reached is written with a warning.
    #[arg(long, value_name = "N",
          help = TARGET_TRIANGLES.help("Decimate the mesh to at most N triangles by edge collapses that keep it watertight, manifold, of the same genus and free of self-intersections (after --keep and --trim; a warning says when no legal collapse gets there)"),
          allow_negative_numbers = true, value_parser = TARGET_TRIANGLES.whole::<usize>())]
    pub target_triangles: Option<usize>,
    /// Move the vertices off the zero set by a quarter of the facets' chord error, so the mesh
    /// lies less under the surface where it curves: a smaller mean distance to the surface at
    /// the same triangles, with the vertices slightly off it (within 1e-5 of the diagonal on
    /// average on a 20,000-point sphere or torus). The default for a detail model; a global
    /// model keeps its vertices on the polynomial's zero set.
    #[arg(long, overrides_with = "no_fit_chords")]
    pub fit_chords: bool,
    /// Keep every vertex on the model's zero set (the default for a global model).
    #[arg(long, overrides_with = "fit_chords")]
    pub no_fit_chords: bool,
    /// Split the mesh's curved edges at their midpoint on the surface: the edges whose arc
    /// strays from the chord by more than 1.5% of the finest cells' side and, with data points,
    /// by more than their median distance from the model, so the facets follow the surface
    /// where it curves, for up to 4x the triangles there. `run` in detail mode does it by
    /// default where the points are a level or more finer than the mesh.
    #[arg(long, overrides_with = "no_refine")]
    pub refine: bool,
    /// Never split the mesh's edges (the default for a global model, and for points no finer
    /// than the mesh).
    #[arg(long, overrides_with = "refine")]
    pub no_refine: bool,
}

/// `--mode`: which model to fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModeArg {
    /// One polynomial.
    Global,
    /// Local fits blended.
    Detail,
}

/// `--normals`: where the normals come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SourceArg {
    /// The file's normals, else its faces, else the crust (pca beyond 200,000 points).
    Auto,
    /// The Voronoi/Delaunay crust.
    Crust,
    /// k-nearest-neighbour planes.
    Pca,
    /// The file's faces.
    Mesh,
    /// The file's normals.
    Input,
}

/// `--method`: how the polynomial is fitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// 3L with ridge regression.
    #[value(name = "3lrr")]
    ThreeLrr,
    /// 3L alone (κ = 0).
    #[value(name = "3l")]
    ThreeL,
    /// Plain least squares.
    Ls,
}

/// `--kappa-rule`: how automatic κ is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum KappaRuleArg {
    /// The stricter rule that checks the zero set.
    Stable,
    /// The paper's rule (section 6.3).
    Paper,
}

/// `--kappa`: `auto` (any case) or a number in [`KAPPA`], with the text as typed (trimmed) for
/// the run's summary line.
#[derive(Debug, Clone, PartialEq)]
pub struct KappaArg {
    /// The value as typed, without surrounding spaces.
    pub text: String,
    /// The value.
    pub value: fit::Kappa,
}

impl std::fmt::Display for KappaArg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.text)
    }
}

/// `--formats`: one output kind of `run`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum FormatArg {
    /// mesh.glb.
    Glb,
    /// mesh.gltf and mesh.bin.
    Gltf,
    /// mesh.ply.
    Ply,
    /// OpenEXR distance slices.
    Exr,
    /// preview.png and the slices' PNG previews.
    Png,
    /// The model file and report.json.
    Json,
    /// volume.vdb: the narrow-band signed-distance level set (OpenVDB, Blender).
    Vdb,
    /// volume.npy and volume.json: the dense signed-distance grid (NumPy) and its transform.
    Npy,
}

/// `render --view`: the camera direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ViewArg {
    /// From the front-right, a little above.
    Iso,
    /// From the front.
    Front,
    /// From above.
    Top,
    /// From the right (+x).
    Side,
}

/// The spelling of a choice on the command line (`3lrr`, `detail`).
pub fn spelling<E: ValueEnum>(value: &E) -> String {
    value
        .to_possible_value()
        .map(|v| v.get_name().to_string())
        .unwrap_or_default()
}

/// A value parser for the choice `E` that ignores spaces around the value (`--formats "glb,
/// ply"`), as these flags always have; clap's enum parser does the rest (case, errors, help).
#[derive(Clone, Copy, Debug)]
struct Trimmed<E>(PhantomData<E>);

impl<E> Default for Trimmed<E> {
    fn default() -> Self {
        Trimmed(PhantomData)
    }
}

impl<E: ValueEnum + Clone + Send + Sync + 'static> TypedValueParser for Trimmed<E> {
    type Value = E;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        arg: Option<&clap::Arg>,
        value: &OsStr,
    ) -> Result<E, clap::Error> {
        let value = value.to_str().map_or(value, |t| OsStr::new(t.trim()));
        EnumValueParser::<E>::new().parse_ref(cmd, arg, value)
    }

    fn possible_values(&self) -> Option<Box<dyn Iterator<Item = PossibleValue> + '_>> {
        Some(Box::new(
            E::value_variants()
                .iter()
                .filter_map(ValueEnum::to_possible_value),
        ))
    }
}

/// Which zero-set components to keep.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum KeepArg {
    /// Every component.
    All,
    /// Components with a data point nearby.
    Data,
}

/// `--up`: the input's up axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum UpArg {
    /// The input is Y-up: glTF unchanged, PLY turned by (x, y, z) ↦ (x, −z, y).
    Y,
    /// The input is Z-up: glTF turned by (x, y, z) ↦ (x, z, −y), PLY unchanged.
    Z,
}

/// `--units`: the unit of the input coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum UnitsArg {
    /// Millimetres.
    Mm,
    /// Centimetres.
    Cm,
    /// Metres.
    M,
    /// Inches.
    In,
    /// Feet.
    Ft,
}

/// Cache options.
#[derive(Debug, Args, Clone)]
pub struct CacheOpts {
    /// Cache directory (default: $XDG_CACHE_HOME/stablesurf or ~/.cache/stablesurf).
    #[arg(long, value_name = "DIR")]
    pub cache_dir: Option<PathBuf>,
    /// Do not read or write the cache.
    #[arg(long)]
    pub no_cache: bool,
    /// Size limit of the cache (e.g. 5G, 500MB, 2GiB): after each run the least recently used
    /// entries go until the rest fit [default: 5G].
    #[arg(long, value_name = "SIZE", env = "STABLESURF_CACHE_MAX_SIZE",
          value_parser = parse_cache_size)]
    pub cache_max_size: Option<u64>,
}

/// Parses a `--cache-max-size`.
fn parse_cache_size(text: &str) -> Result<u64, String> {
    stablesurf::cache::lru::parse_size(text)
}

/// `stablesurf run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Scan file (PLY, OBJ, STL, XYZ/PTS, LAS/LAZ, E57, PCD); a Stanford .conf registration
    /// file (its scans, moved by their poses); or several scans of one object in one frame. Each
    /// scan gets its normals in its own frame before the merge. Without any, a small built-in
    /// sample scan is used. A folder (given alone) is a batch: every scan file directly in it
    /// (by extension; subfolders and other files are skipped with a notice) runs on its own into
    /// OUT_DIR/<file stem>/, as with --batch.
    pub input: Vec<PathBuf>,
    /// Run each INPUT on its own instead of merging them as views of one object: each into
    /// OUT_DIR/<file stem>/, exactly as `run INPUT -o OUT_DIR/<file stem>` would. Inputs whose
    /// stems collide get their file name instead (a.ply/, a.obj/), and a name still taken gets
    /// -2, -3, … in input order. One failed input does not stop the others; the command then
    /// exits 1 naming each. A table of the results goes to stdout (JSON with --json) and to
    /// OUT_DIR/summary.csv.
    #[arg(long)]
    pub batch: bool,
    /// Output directory (created if missing).
    #[arg(short, long, value_name = "OUT_DIR")]
    pub output: PathBuf,
    /// detail (the default): local fits blended, a mesh close to the scan; global: one
    /// polynomial, the paper's compact descriptor of the coarse shape.
    #[arg(long, value_name = "MODE", value_enum, hide_possible_values = true)]
    pub mode: Option<ModeArg>,
    /// Outputs to write, comma-separated: glb, gltf, ply, exr, png, json, vdb (volume.vdb, a
    /// narrow-band signed-distance level set for Blender and OpenVDB), npy (volume.npy, the
    /// dense signed-distance grid, with volume.json giving its transform).
    #[arg(long, value_delimiter = ',', default_value = "glb,ply,exr,png,json",
          value_parser = Trimmed::<FormatArg>::default(), hide_possible_values = true)]
    pub formats: Vec<FormatArg>,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub frame: FrameOpts,
    /// Which zero-set components to keep: data (drop pieces with no data point within 2% of the
    /// diagonal, and small pieces with fewer than 15 data points in their box; the default in
    /// detail mode) or all (the default in global mode).
    #[arg(long, value_enum)]
    pub keep: Option<KeepArg>,
    /// Keep points far outside the bulk of the data, and on a cloud without normals or faces the
    /// small groups of points apart from the surface (left out by default, with a warning).
    #[arg(long)]
    pub keep_outliers: bool,
    /// Trim the mesh to the surface the data supports: auto (on in detail mode, off in global
    /// mode), off, or a support factor (how many local sample spacings from the data a
    /// triangle may lie).
    #[arg(long, value_name = "auto|off|FACTOR",
          help = trim_help(),
          allow_negative_numbers = true, value_parser = parse_trim)]
    pub trim: Option<TrimArg>,
    /// Voxel edge of the vdb and npy volumes, input units [default: the meshing box's longest
    /// side / 256]. The vdb keeps the voxels within 3 voxels of the surface; with --units its
    /// transform and values are in metres and it is turned like the glb, so both overlap in
    /// Blender; the npy stays in input units and coordinates.
    #[arg(long, value_name = "SIZE",
          help = VOXEL_SIZE.help("Voxel edge of the vdb and npy volumes, input units [default: the meshing box's longest side / 256]. The vdb keeps the voxels within 3 voxels of the surface; with --units its transform and values are in metres and it is turned like the glb (--up), so both overlap in Blender; the npy stays in input units and coordinates"),
          allow_negative_numbers = true, value_parser = VOXEL_SIZE.real())]
    pub voxel_size: Option<f64>,
    /// Print the stage summary as JSON on stdout (a batch: the summary table as JSON).
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub normals: NormalsOpts,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub fit: FitOpts,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub detail: DetailOpts,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub mesh: MeshOpts,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub slices: SliceOpts,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub cache: CacheOpts,
}

impl RunArgs {
    /// The mode asked for, or the default (detail).
    pub fn mode(&self) -> ModeArg {
        self.mode.unwrap_or(ModeArg::Detail)
    }
}

/// `stablesurf normals`.
#[derive(Debug, Args)]
pub struct NormalsArgs {
    /// Scan file; or a `.conf` registration, or several scans of one object in one frame: each
    /// view's normals are estimated in its own frame, then moved by its pose and merged.
    #[arg(required = true)]
    pub input: Vec<PathBuf>,
    /// Output PLY (binary, points with normals).
    #[arg(short, long, value_name = "OUT.ply")]
    pub output: PathBuf,
    /// Also write the crust triangulation (points and triangles) to this PLY.
    #[arg(long, value_name = "CRUST.ply")]
    pub mesh: Option<PathBuf>,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub normals: NormalsOpts,
}

/// `stablesurf moments`.
#[derive(Debug, Args)]
pub struct MomentsArgs {
    /// Chunk of the scan (any scan format, or a `.conf` of several; normals from the file or the
    /// normals stage).
    pub input: PathBuf,
    /// Output moments file.
    #[arg(short, long, value_name = "PART.moments")]
    pub output: PathBuf,
    /// Pass 2: the centroid printed by `stablesurf frame` over the pass-1 files.
    #[arg(long, value_name = "CX,CY,CZ", allow_hyphen_values = true,
          value_parser = parse_center, conflicts_with = "frame")]
    pub center: Option<[f64; 3]>,
    /// Pass 3: the frame printed by `stablesurf frame` over the pass-2 files. Without --center
    /// or --frame, pass 1 (counts and sums) is written.
    #[arg(long, value_name = "CX,CY,CZ,S", allow_hyphen_values = true, value_parser = parse_frame)]
    pub frame: Option<[f64; 4]>,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub normals: NormalsOpts,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub fit: FitOpts,
}

/// `stablesurf frame`.
#[derive(Debug, Args)]
pub struct FrameArgs {
    /// Pass-1 files (prints CX,CY,CZ for --center) or pass-2 files (prints CX,CY,CZ,S for
    /// --frame).
    #[arg(required = true, value_name = "PART")]
    pub parts: Vec<PathBuf>,
}

/// `stablesurf fit`.
#[derive(Debug, Args)]
pub struct FitArgs {
    /// Scan file, or a `.conf` registration of several scans (merged as `run` merges them).
    #[arg(required_unless_present = "from_moments")]
    pub input: Option<PathBuf>,
    /// Fit from pass-3 moments files (`stablesurf moments --frame`) instead of a scan: needs a
    /// fixed --kappa or --kappa-rule paper, and the --degree and --epsilon of the moments.
    #[arg(long, value_name = "PART", num_args = 1.., conflicts_with = "input")]
    pub from_moments: Vec<PathBuf>,
    /// Output model file.
    #[arg(short, long, value_name = "MODEL.json")]
    pub output: PathBuf,
    /// Print the model's diagnostics as JSON on stdout.
    #[arg(long)]
    pub json: bool,
    /// global: one polynomial, written as model.json; detail: local fits blended, written as a
    /// stablesurf.mpu file.
    #[arg(long, value_enum, default_value_t = ModeArg::Global, hide_possible_values = true)]
    pub mode: ModeArg,
    /// Keep points far outside the bulk of the data, and on a cloud without normals or faces the
    /// small groups of points apart from the surface (left out by default, with a warning).
    #[arg(long)]
    pub keep_outliers: bool,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub normals: NormalsOpts,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub fit: FitOpts,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub detail: DetailOpts,
}

/// The coordinates' up axis and unit (`run`, `mesh`).
#[derive(Debug, Args)]
pub struct FrameOpts {
    /// The up axis of the input's (or model's) coordinates, y or z: every mesh file is written
    /// upright for its format (glTF +Y up, PLY +Z up as Blender and CloudCompare import it).
    /// Without it a PLY keeps the input's coordinates (to lie on the scan in MeshLab) and glTF
    /// takes them as Y-up.
    #[arg(long, value_enum)]
    pub up: Option<UpArg>,
    /// Unit of the input's (or model's) coordinates: a glTF is written in metres (glTF's unit,
    /// so Blender shows the true size); the PLY (and run's OpenEXR slices and report.json)
    /// record the unit; without it coordinates are written unchanged.
    #[arg(
        long,
        value_enum,
        value_name = "mm|cm|m|in|ft",
        hide_possible_values = true
    )]
    pub units: Option<UnitsArg>,
}

/// `stablesurf mesh`.
#[derive(Debug, Args)]
pub struct MeshArgs {
    /// Model file (model.json or model.mpu).
    pub model: PathBuf,
    /// Output mesh: .glb, .gltf or .ply (format from the extension).
    #[arg(short, long, value_name = "OUT")]
    pub output: PathBuf,
    /// Meshing region in input coordinates: xmin,ymin,zmin,xmax,ymax,zmax (overrides the model's box).
    #[arg(long, value_name = "XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX", allow_hyphen_values = true, value_parser = parse_bounds,
          help = bounds_help("Meshing region in input coordinates (overrides the model's box)"))]
    pub bounds: Option<[f64; 6]>,
    /// Write a text PLY instead of binary.
    #[arg(long)]
    pub ascii: bool,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub frame: FrameOpts,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub mesh: MeshOpts,
}

/// Slice axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum AxisArg {
    /// Slices perpendicular to x.
    X,
    /// Slices perpendicular to y.
    Y,
    /// Slices perpendicular to z.
    Z,
}

/// Distance method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum DistanceArg {
    /// First-order distance f/|∇f| (fast, accurate near the surface only).
    Taubin,
    /// Distance to the zero set by closest-point search and Newton projection.
    Exact,
    /// Distance to the meshed zero set (meshed at --depth), signed by the model.
    Mesh,
}

/// Options of the distance slices `run` writes.
#[derive(Debug, Args, Clone)]
pub struct SliceOpts {
    /// Number of distance slices across the box (along z).
    #[arg(long, default_value_t = 16, value_name = "K",
          help = SLICE_COUNT.help("Number of distance slices across the box (along z)"),
          allow_negative_numbers = true, value_parser = SLICE_COUNT.whole::<usize>())]
    pub slice_count: usize,
    /// Pixels per side of each distance slice (`stablesurf slices` makes finer ones).
    #[arg(long, default_value_t = 128, value_name = "R",
          help = SLICE_RESOLUTION.help("Pixels per side of each distance slice (`stablesurf slices` makes finer ones)"),
          allow_negative_numbers = true, value_parser = SLICE_RESOLUTION.whole::<usize>())]
    pub slice_resolution: usize,
    /// Distance method of the slices [default: exact for --mode global, mesh for --mode detail].
    #[arg(long, value_enum)]
    pub slice_distance: Option<DistanceArg>,
}

/// `stablesurf slices`.
#[derive(Debug, Args)]
pub struct SlicesArgs {
    /// Model file (model.json or model.mpu).
    pub model: PathBuf,
    /// Output directory.
    #[arg(short, long, value_name = "DIR")]
    pub output: PathBuf,
    /// Slice axis.
    #[arg(long, value_enum, default_value_t = AxisArg::Z)]
    pub axis: AxisArg,
    /// Number of slices across the model's box.
    #[arg(long, default_value_t = 16, value_name = "K",
          help = COUNT.help("Number of slices across the model's box"),
          allow_negative_numbers = true, value_parser = COUNT.whole::<usize>())]
    pub count: usize,
    /// Pixels per side of each slice.
    #[arg(long, default_value_t = 256, value_name = "R",
          help = RESOLUTION.help("Pixels per side of each slice"),
          allow_negative_numbers = true, value_parser = RESOLUTION.whole::<usize>())]
    pub resolution: usize,
    /// Distance method [default: exact for model.json, mesh for model.mpu].
    #[arg(long, value_enum)]
    pub distance: Option<DistanceArg>,
    /// Region in input coordinates: xmin,ymin,zmin,xmax,ymax,zmax (overrides the model's box).
    #[arg(long, value_name = "XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX", allow_hyphen_values = true, value_parser = parse_bounds,
          help = bounds_help("Region in input coordinates (overrides the model's box)"))]
    pub bounds: Option<[f64; 6]>,
    #[command(flatten)]
    #[allow(missing_docs)]
    pub mesh: MeshOpts,
}

/// `stablesurf render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Mesh file (PLY, OBJ, STL).
    pub mesh: PathBuf,
    /// Output PNG.
    #[arg(short, long, value_name = "PREVIEW.png")]
    pub output: PathBuf,
    /// Image width and height in pixels.
    #[arg(long, default_value_t = 800, value_name = "PIXELS",
          help = SIZE.help("Image width and height in pixels"),
          allow_negative_numbers = true, value_parser = SIZE.whole::<u32>())]
    pub size: u32,
    /// Camera direction: iso, front, top or side.
    #[arg(long, value_enum, default_value_t = ViewArg::Iso, hide_possible_values = true)]
    pub view: ViewArg,
    /// The model's up axis (up in the picture).
    #[arg(long, value_enum, default_value_t = UpArg::Y)]
    pub up: UpArg,
}

/// `stablesurf info`.
#[derive(Debug, Args)]
pub struct InfoArgs {
    /// A scan, mesh or model file.
    pub file: PathBuf,
    /// Print one JSON object on stdout.
    #[arg(long)]
    pub json: bool,
}

/// `stablesurf cache`.
#[derive(Debug, Args)]
pub struct CacheArgs {
    /// What to do.
    #[command(subcommand)]
    pub action: CacheAction,
    /// Cache directory (default: $XDG_CACHE_HOME/stablesurf or ~/.cache/stablesurf).
    #[arg(long, value_name = "DIR", global = true)]
    pub cache_dir: Option<PathBuf>,
    /// Size limit of the cache (e.g. 5G, 500MB, 2GiB) that `info` compares its size with
    /// [default: 5G].
    #[arg(long, value_name = "SIZE", env = "STABLESURF_CACHE_MAX_SIZE", global = true,
          value_parser = parse_cache_size)]
    pub cache_max_size: Option<u64>,
}

/// Cache actions.
#[derive(Debug, Subcommand)]
pub enum CacheAction {
    /// Where the cache is, how much each stage holds, its size limit and hit rate.
    Info {
        /// Print one JSON object on stdout.
        #[arg(long)]
        json: bool,
    },
    /// Remove every entry (or only those last used before --older-than).
    Clear {
        /// Remove only the entries last used longer ago than this (e.g. 12h, 7d, 2w).
        #[arg(long, value_name = "AGE", value_parser = parse_age)]
        older_than: Option<std::time::Duration>,
    },
    /// Check every entry's checksum and identity; exit 1 if any fails.
    Verify {
        /// Print one JSON object on stdout.
        #[arg(long)]
        json: bool,
    },
}

/// Parses an `--older-than`.
fn parse_age(text: &str) -> Result<std::time::Duration, String> {
    stablesurf::cache::lru::parse_age(text)
}

/// Parses `xmin,ymin,zmin,xmax,ymax,zmax`: six finite numbers, each min below its max.
fn parse_bounds(text: &str) -> Result<[f64; 6], String> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| {
            v.trim()
                .parse::<f64>()
                .map_err(|_| format!("'{v}' is not a number"))
        })
        .collect::<Result<_, _>>()?;
    let v: [f64; 6] = values.try_into().map_err(|v: Vec<f64>| {
        format!(
            "expected 6 numbers xmin,ymin,zmin,xmax,ymax,zmax, got {}",
            v.len()
        )
    })?;
    let within = |c: &f64| c.is_finite() && c.abs() <= BOUNDS_MAX_ABS;
    if !v.iter().all(within) || (0..3).any(|a| v[a] >= v[a + 3]) {
        return Err(format!(
            "--bounds takes six numbers xmin,ymin,zmin,xmax,ymax,zmax, each from {} to {} and each min below its max, got '{text}'",
            number(-BOUNDS_MAX_ABS),
            number(BOUNDS_MAX_ABS)
        ));
    }
    Ok(v)
}

/// The help of `--depth`, whose default is the library's (`PolygonizeParams::default().depth`).
fn depth_help() -> String {
    format!(
        "{} [default: {}; `run` in detail mode: from the points' spacing, {} or {}]",
        DEPTH
            .help("Octree depth near the surface: finest cell = longest side of the box / 2^depth"),
        stablesurf::polygonize::PolygonizeParams::default().depth,
        stablesurf::polygonize::DATA_DEPTH_MIN,
        stablesurf::polygonize::DATA_DEPTH_MAX,
    )
}

/// The help of `--tolerance`, whose default is the library's (`DetailParams::default()`).
fn tolerance_help() -> String {
    format!(
        "{} [default: {}; `run`: × {} where the points are 2 or more to a side of the mesh's cells]",
        TOLERANCE.help("Detail mode: split a cell while its fit is farther than this from its points, as a fraction of the bounding-box diagonal"),
        stablesurf::detail::DetailParams::default().tolerance,
        stablesurf::pipeline::DENSE_TOLERANCE,
    )
}

/// The help of `--viewpoint`, with its range.
fn viewpoint_help() -> String {
    VIEWPOINT.help(
        "The sensor's position X,Y,Z in input coordinates: every normal is turned to face it \
         (for several scans, in each scan's own coordinates)",
    )
}

/// Parses `x,y,z`: three numbers, each in [`VIEWPOINT`].
fn parse_viewpoint(text: &str) -> Result<[f64; 3], String> {
    let parts: Vec<&str> = text.split(',').collect();
    let bad = || {
        format!(
            "--viewpoint takes three numbers X,Y,Z, each from {}, got '{text}'",
            VIEWPOINT.describe()
        )
    };
    let [x, y, z] = parts.as_slice() else {
        return Err(bad());
    };
    let mut out = [0.0; 3];
    for (slot, part) in out.iter_mut().zip([x, y, z]) {
        *slot = VIEWPOINT.check_f64(part).map_err(|_| bad())?;
    }
    Ok(out)
}

/// The help of `--bounds`, with its limits.
fn bounds_help(what: &str) -> String {
    format!(
        "{what}: xmin,ymin,zmin,xmax,ymax,zmax, each min below its max [range: {} to {}]",
        number(-BOUNDS_MAX_ABS),
        number(BOUNDS_MAX_ABS)
    )
}

/// `--trim`'s value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TrimArg {
    /// On in detail mode, off in global mode.
    Auto,
    /// No trimming.
    Off,
    /// Trim with this support factor.
    Factor(f64),
}

fn trim_help() -> String {
    TRIM.help("Trim the mesh to the surface the data supports (detail mode's unsupported curtains and sheets go, small holes are closed): auto (on in detail mode, off in global mode), off, or a support factor, how many local sample spacings from the data a triangle may lie; default auto")
}

/// `--trim`: `auto`, `off` (any case) or a number in [`TRIM`].
fn parse_trim(text: &str) -> Result<TrimArg, String> {
    let t = text.trim();
    if t.eq_ignore_ascii_case("auto") {
        return Ok(TrimArg::Auto);
    }
    if t.eq_ignore_ascii_case("off") {
        return Ok(TrimArg::Off);
    }
    TRIM.check_f64(text).map(TrimArg::Factor).map_err(|_| {
        format!(
            "--trim takes auto, off or a number from {}, got '{text}'",
            TRIM.describe()
        )
    })
}

/// `N` comma-separated finite numbers; `form` names them in the error (`CX,CY,CZ`).
fn parse_numbers<const N: usize>(text: &str, flag: &str, form: &str) -> Result<[f64; N], String> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("{flag} takes {form}, got '{text}'"))?;
    let out: [f64; N] = values
        .try_into()
        .map_err(|_| format!("{flag} takes {N} numbers {form}, got '{text}'"))?;
    if out.iter().all(|v| v.is_finite()) {
        Ok(out)
    } else {
        Err(format!("{flag} takes finite numbers, got '{text}'"))
    }
}

fn parse_center(text: &str) -> Result<[f64; 3], String> {
    parse_numbers(text, "--center", "CX,CY,CZ")
}

fn parse_frame(text: &str) -> Result<[f64; 4], String> {
    let f = parse_numbers::<4>(text, "--frame", "CX,CY,CZ,S")?;
    if f[3] > 0.0 {
        Ok(f)
    } else {
        Err(format!(
            "--frame: the scale S must be positive, got '{text}'"
        ))
    }
}

fn parse_kappa(text: &str) -> Result<KappaArg, String> {
    let t = text.trim();
    if t.eq_ignore_ascii_case("auto") {
        return Ok(KappaArg {
            text: t.to_string(),
            value: fit::Kappa::Auto,
        });
    }
    KAPPA
        .check_f64(text)
        .map(|v| KappaArg {
            text: t.to_string(),
            value: fit::Kappa::Fixed(v),
        })
        .map_err(|_| {
            format!(
                "--kappa takes auto or a number from {}, got '{text}'",
                KAPPA.describe()
            )
        })
}

#[cfg(test)]
mod tests;
