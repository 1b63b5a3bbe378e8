//! Stage `export`: artifacts → files (glTF, PLY, OpenEXR slices, PNG previews, model.json).
//!
//! Input: a [`TriangleMesh`], the distance slices of
//! [`distance::slices`](crate::distance::slices), or an [`ImplicitModel`](crate::ImplicitModel).
//! Output: bytes. The stage function is [`export()`] (in `stage.rs`: the model and its mesh →
//! every output file of `run`, with [`ExportParams`]); it calls one writer per format:
//!
//! - [`gltf`]: glTF 2.0 (`.glb`, or `.gltf` + `.bin`) for Blender and other viewers;
//! - [`ply`]: PLY with normals and a per-vertex `quality` for MeshLab;
//! - [`exr`]: one float32 OpenEXR image per distance slice, with its geometry in the header;
//! - [`png`]: a colour preview of a distance slice with the zero contour drawn;
//! - `model.json` and `model.mpu`, the polynomial and the detail model, are written by
//!   [`Model::file`](crate::model::Model::file): their formats live with the model, in
//!   [`crate::model::json`] and [`crate::model::mpu`];
//! - [`vdb`]: `volume.vdb`, the narrow-band signed-distance level set for OpenVDB and Blender;
//! - [`npy`]: `volume.npy` and `volume.json`, the dense signed-distance grid for NumPy;
//! - [`units`]: the input's length unit (`--units`), which glTF is scaled by and the others
//!   record.
//!
//! Every writer takes `&mut impl Write`; choosing a file is the caller's job. Files are written
//! atomically with [`write_atomic`]: a temporary file in the same directory, renamed into place,
//! so an interrupted or failed write never leaves a partial file. Invariant: every writer's bytes
//! depend only on its input and options (no timestamps, no hash-map order, fixed float
//! formatting), so outputs can be hashed and compared.

pub mod exr;
pub mod gltf;
pub mod npy;
pub mod ply;
pub mod png;
mod stage;
pub mod units;
pub mod vdb;

pub use stage::{export, ExportParams, ExportReport, OutputFile, OutputFormat};
pub(crate) use stage::{export_mesh, model_slices, slices_from_model, STAGE_VERSION};

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use crate::mesh::TriangleMesh;

/// Largest `f32` rounding error of a coordinate, as a fraction of the mesh's bounding-box
/// diagonal, that float positions may carry; past it positions are written as `double` (PLY) or relative
/// to a node translation (glTF). At 1e-7
/// no mesh from a scan near the origin changes, while a 50 m LiDAR tile at UTM northings
/// (4,000 km, where `f32` steps are 0.25 m) is written in doubles.
pub(crate) const DOUBLE_PRECISION_RATIO: f64 = 1e-7;

/// Whether `positions` need `double` PLY properties: half an `f32` step at the largest
/// coordinate magnitude exceeds [`DOUBLE_PRECISION_RATIO`] of the bounding-box diagonal.
pub(crate) fn needs_double(positions: &[[f64; 3]]) -> bool {
    far_off_centre(positions).is_some()
}

/// The centre of the bounding box of `positions` when they [`needs_double`], else `None`: the
/// origin glTF writes far-off positions relative to.
pub(crate) fn far_off_centre(positions: &[[f64; 3]]) -> Option<[f64; 3]> {
    let b = crate::cloud::Aabb::from_points(positions)?;
    let diagonal = b.diagonal();
    if diagonal.is_nan() || diagonal <= 0.0 {
        return None;
    }
    let largest = (0..3).fold(0.0f64, |m, a| m.max(b.min[a].abs()).max(b.max[a].abs()));
    // The spacing of f32 values just below `largest`: 2^(exponent − 23).
    let step = (largest as f32).max(f32::MIN_POSITIVE);
    let half_step = 0.5 * f64::from(f32::from_bits(step.to_bits() + 1) - step);
    (half_step > DOUBLE_PRECISION_RATIO * diagonal).then(|| b.center())
}

/// Errors of the export stage.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// Writing failed.
    #[error("cannot write {path}: {source}; {hint}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
        /// What to do about it.
        hint: &'static str,
    },
    /// A writer failed for a format-specific reason.
    #[error("{0}")]
    Format(String),
    /// The output stream of a writer failed (the caller knows which file it was).
    #[error("write failed: {0}")]
    Write(#[source] std::io::Error),
    /// The mesh cannot be written as it is (empty, non-finite coordinates, zero normals, an
    /// index out of range). The message says which element is at fault; fix the stage that
    /// produced the mesh or the meshing parameters.
    #[error("mesh cannot be exported: {0}")]
    InvalidMesh(String),
    /// The output would exceed a limit of its format; write a smaller mesh (a lower meshing
    /// depth) or choose another format.
    #[error("{what} would be {bytes} bytes, over the format's limit of {limit} bytes; lower the meshing depth or write .ply")]
    TooLarge {
        /// What would be too large.
        what: String,
        /// Its size.
        bytes: u64,
        /// The format's limit.
        limit: u64,
    },
    /// A model file could not be written (see [`crate::model::ModelError`]).
    #[error(transparent)]
    Model(#[from] crate::model::ModelError),
    /// A distance slice cannot be written (its data does not match its resolution).
    #[error("slice cannot be exported: {0}")]
    InvalidSlice(String),
    /// Computing the distance slices failed (see [`crate::distance::DistanceError`]).
    #[error("distance slices failed")]
    Distance(#[from] crate::distance::DistanceError),
    /// The slices asked for do not exist for this model (an `exact` or `taubin` distance of a
    /// detail model); the message names the setting to use instead.
    #[error("{0}")]
    Unsupported(String),
}

/// Writes a file atomically: `write` fills a temporary file in the same directory, which is
/// flushed, synced and renamed to `path` only when `write` succeeds. On any error the temporary
/// file is removed and `path` is untouched.
///
/// # Errors
/// The directory is not writable, or `write` fails.
pub fn write_atomic<F>(path: &Path, write: F) -> Result<(), ExportError>
where
    F: FnOnce(&mut BufWriter<&mut File>) -> Result<(), ExportError>,
{
    let io_err = |source: std::io::Error| ExportError::Io {
        hint: crate::files::io_hint(&source),
        path: path.display().to_string(),
        source,
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let file_name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    remove_stale_temporaries(dir, |name| name == file_name);
    let tmp_path = dir.join(format!(".{file_name}.tmp{}", std::process::id()));
    let result = (|| {
        let mut file = File::create(&tmp_path).map_err(io_err)?;
        {
            let mut w = BufWriter::new(&mut file);
            write(&mut w)?;
            w.flush().map_err(io_err)?;
        }
        file.sync_all().map_err(io_err)?;
        std::fs::rename(&tmp_path, path).map_err(io_err)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp_path);
    }
    result
}

/// Removes the temporaries `.NAME.tmp<pid>` that [`write_atomic`] left in `dir` for the names
/// `NAME` that `names` accepts, when the process `pid` is gone (a killed run's debris). Never
/// fails: what cannot be read or removed stays.
pub(crate) fn remove_stale_temporaries(dir: &Path, names: impl Fn(&str) -> bool) {
    crate::files::remove_debris(dir, |name| {
        let (file, pid) = name.strip_prefix('.')?.rsplit_once(".tmp")?;
        let digits = !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit());
        (digits && names(file)).then(|| pid.parse().ok())?
    });
}

/// A mesh file format: `run`'s `mesh.glb`, `mesh.gltf` and `mesh.ply`, and the `-o` of
/// `stablesurf mesh`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    /// Binary glTF, one file.
    Glb,
    /// glTF JSON and the binary buffer it refers to, `<stem>.bin` beside it.
    Gltf,
    /// PLY ([`ply`]).
    Ply,
}

impl MeshFormat {
    /// The format a file name's extension names, in any case: `.glb`, `.gltf` or `.ply`.
    ///
    /// ```
    /// use std::path::Path;
    /// use stablesurf::export::MeshFormat;
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
    pub gltf: gltf::GltfOptions,
    /// Options of the PLY writer (encoding, per-vertex quality).
    pub ply: ply::PlyOptions<'a>,
    /// One 8-bit sRGB colour per vertex for every format (PLY `red green blue`, glTF
    /// `COLOR_0`), or `None`; for PLY, `ply.colours` wins when both are given.
    pub colours: Option<&'a [[u8; 3]]>,
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
/// use stablesurf::export::{mesh_files, MeshFileOptions, MeshFormat};
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
        MeshFormat::Glb => gltf::write_glb_coloured(mesh, opts.colours, &mut bytes, &opts.gltf)?,
        MeshFormat::Gltf => {
            let bin_name = Path::new(name)
                .with_extension("bin")
                .to_string_lossy()
                .into_owned();
            let mut bin = Vec::new();
            gltf::write_gltf_coloured(
                mesh,
                opts.colours,
                &mut bytes,
                &mut bin,
                &bin_name,
                &opts.gltf,
            )?;
            return Ok(vec![(bin_name, bin), (name.to_string(), bytes)]);
        }
        MeshFormat::Ply => {
            let ply_opts = ply::PlyOptions {
                colours: opts.ply.colours.or(opts.colours),
                ..opts.ply
            };
            ply::write(mesh, &mut bytes, &ply_opts)?
        }
    }
    Ok(vec![(name.to_string(), bytes)])
}
