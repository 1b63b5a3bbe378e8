//! Stage `export`: artifacts → files (glTF, PLY, OpenEXR slices, PNG previews, model.json).
//!
//! Every writer takes `&mut impl Write`; choosing a file is the caller's job. Files are written
//! atomically with [`write_atomic`]: a temporary file in the same directory, renamed into place,
//! so an interrupted or failed write never leaves a partial file.
//!
//! (Skeleton: the export helper fills the format modules.)

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

/// Errors of the export stage.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// Writing failed.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// A writer failed for a format-specific reason.
    #[error("{0}")]
    Format(String),
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
    let io_err = |source| ExportError::Io { path: path.display().to_string(), source };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let file_name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
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
