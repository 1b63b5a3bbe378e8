//! Stage `export`: artifacts → files (glTF, PLY, OpenEXR slices, PNG previews, model.json).
//!
//! Input: a [`TriangleMesh`](crate::TriangleMesh), the distance slices of
//! [`distance::slices`](crate::distance::slices), or an [`ImplicitModel`](crate::ImplicitModel).
//! Output: bytes in one format per module:
//!
//! - [`gltf`]: glTF 2.0 (`.glb`, or `.gltf` + `.bin`) for Blender and other viewers;
//! - [`ply`]: PLY with normals and a per-vertex `quality` for MeshLab;
//! - [`exr`]: one float32 OpenEXR image per distance slice, with its geometry in the header;
//! - [`png`]: a colour preview of a distance slice with the zero contour drawn;
//! - [`model`]: `model.json`, the polynomial and its fit record, and its reader.
//!
//! Every writer takes `&mut impl Write`; choosing a file is the caller's job. Files are written
//! atomically with [`write_atomic`]: a temporary file in the same directory, renamed into place,
//! so an interrupted or failed write never leaves a partial file. Invariant: every writer's bytes
//! depend only on its input and options (no timestamps, no hash-map order, fixed float
//! formatting), so outputs can be hashed and compared.

pub mod exr;
pub mod gltf;
pub mod model;
pub mod mpu;
pub mod ply;
pub mod png;

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

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
    /// A model file could not be read: bad JSON, a missing field, or values that do not
    /// describe a polynomial (wrong coefficient count, non-finite numbers, scale ≤ 0).
    #[error("cannot read model {path}: {reason}")]
    Model {
        /// The file.
        path: String,
        /// What is wrong and what to change.
        reason: String,
    },
    /// A model cannot be written as JSON (a non-finite number, which JSON cannot hold).
    #[error("cannot write model: {0}")]
    ModelValue(String),
    /// A distance slice cannot be written (its data does not match its resolution).
    #[error("slice cannot be exported: {0}")]
    InvalidSlice(String),
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
