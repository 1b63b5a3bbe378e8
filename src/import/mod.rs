//! Stage `import`: scan file bytes → [`PointCloud`].
//!
//! (Skeleton: the import helper replaces this file; the public signatures below are the contract
//! the CLI and pipeline use.)

use std::path::Path;

use serde::Serialize;

use crate::cloud::PointCloud;

/// Errors of the import stage.
#[derive(Debug, thiserror::Error)]
pub enum ImportError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// Not built yet.
    #[error("{path}: import is not built yet")]
    NotBuilt {
        /// The file.
        path: String,
    },
}

/// The on-disk format of a scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScanFormat {
    /// PLY, ascii.
    PlyAscii,
    /// PLY, binary little-endian.
    PlyBinaryLe,
    /// PLY, binary big-endian.
    PlyBinaryBe,
    /// Wavefront OBJ.
    Obj,
    /// STL, ascii.
    StlAscii,
    /// STL, binary.
    StlBinary,
    /// XYZ point list (also .pts, .txt, .csv).
    Xyz,
}

/// A parsed scan before validation: it may still hold NaN coordinates.
#[derive(Clone, Debug)]
pub struct Scan {
    /// The format the bytes were in.
    pub format: ScanFormat,
    /// What the file holds.
    pub cloud: PointCloud,
}

/// What `stablesurf info` prints about a scan.
#[derive(Clone, Debug, Serialize)]
pub struct ScanInfo {
    /// Format name, e.g. "ply-binary-le".
    pub format: String,
    /// Number of points as stored.
    pub points: usize,
    /// Number of triangles after fan triangulation.
    pub triangles: usize,
    /// Whether the file stores normals.
    pub has_normals: bool,
    /// Bounding box of the finite points.
    pub bbox_min: [f64; 3],
    /// Bounding box of the finite points.
    pub bbox_max: [f64; 3],
    /// Number of points whose position repeats an earlier point exactly.
    pub duplicate_points: usize,
    /// Number of points with a NaN or infinite coordinate.
    pub nan_points: usize,
}

/// Parses scan bytes; `path` names the file in errors and gives the extension.
///
/// # Errors
/// Malformed or unsupported content.
pub fn read_scan_bytes(_bytes: &[u8], path: &Path) -> Result<Scan, ImportError> {
    Err(ImportError::NotBuilt { path: path.display().to_string() })
}

/// Parses and validates scan bytes (finite coordinates, at least one point, indices in range).
///
/// # Errors
/// Malformed content or invalid data.
pub fn import_bytes(bytes: &[u8], path: &Path) -> Result<PointCloud, ImportError> {
    Ok(read_scan_bytes(bytes, path)?.cloud)
}

/// Summarizes a parsed scan for `stablesurf info`.
pub fn scan_info(scan: &Scan) -> ScanInfo {
    ScanInfo {
        format: String::new(),
        points: scan.cloud.points.len(),
        triangles: 0,
        has_normals: false,
        bbox_min: [0.0; 3],
        bbox_max: [0.0; 3],
        duplicate_points: 0,
        nan_points: 0,
    }
}
