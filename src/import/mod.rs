//! Stage `import`: scan file bytes → [`PointCloud`].
//!
//! Input: the bytes of a scan file and its path (the path only names the file in errors and gives
//! the extension). Output: a [`Scan`] (the format and a [`PointCloud`] exactly as stored, NaN
//! coordinates kept) from [`read_scan_bytes`], or a validated [`PointCloud`] from
//! [`import_bytes`], which the pipeline uses.
//!
//! Invariants of a validated cloud: at least one point, every coordinate finite, every triangle
//! index `< points.len()`, `normals`, `colours` and `intensity` (when present) hold one entry
//! per point, and `scans` (when present) count every point. Points are never merged, reordered
//! or rescaled, except that STL corners are welded by exact position (an STL file stores every
//! triangle corner separately), and points that a format marks as having no position (a PCD's
//! NaN points, an E57's invalid ones) are dropped with a notice.
//!
//! # Formats and how they are chosen
//!
//! ```text
//! bytes ──▶ starts with "ply\n"?            ─▶ ply.rs  (ascii, binary LE, binary BE)
//!       ──▶ starts with "LASF"?             ─▶ las.rs  (LAS, LAZ)
//!       ──▶ starts with "ASTM-E57"?         ─▶ e57.rs  (every scan, moved by its pose)
//!       ──▶ a "# .PCD" or VERSION/FIELDS line? ─▶ pcd.rs  (ascii, binary)
//!       ──▶ 84 + 50·n == len (n at byte 80)? ─▶ stl.rs  binary (even if it starts with "solid")
//!       ──▶ starts with "solid" + "facet"?   ─▶ stl.rs  ascii
//!       ──▶ extension .obj .stl .ply .las .laz .e57 .pcd .xyz .pts .txt .csv
//!       ──▶ no known extension: text whose lines start with `v ` is OBJ, numeric text is XYZ
//! ```
//!
//! The binary STL size rule comes first because many binary STL files start their 80-byte header
//! with the word `solid` too. Text never satisfies it by chance: the four bytes at offset 80 of a
//! text file read as a triangle count of at least 0x09090909, which needs a file of gigabytes.
//!
//! Every reader is hand-written over the byte slice, so each error can name the line, face or
//! point at fault, and malformed input is an [`ImportError`], never a panic. Polygons are
//! fan-triangulated: (v0, v1, v2), (v0, v2, v3), …; a face with fewer than three corners is an
//! error in every format (no file in the shared test data has one, and in a binary PLY a face of
//! 0 corners is the usual sign that the vertex count is wrong and the face bytes are read out of
//! place).
//!
//! # Believe the bytes, not the header
//!
//! A reader accepts a file only when its bytes and its declarations agree: a binary PLY body must
//! be exactly as long as the header's counts make it (no byte short, no byte over, not even a
//! trailing newline, since the format has no terminator), an ascii STL facet has exactly three
//! corners and nothing but another `solid` follows an `endsolid`, an OBJ corner has at most
//! three slash fields and its texture and normal indices exist, and a text file in which no point
//! parses is an [`ImportError::NoPointFound`] that says what the file looks like (NUL bytes, or
//! its first non-blank line), not an empty cloud.
//!
//! What a reader reads but does not keep is named in [`Scan::notices`] (for example the extra
//! columns of a 5-column point list, or a PLY's `confidence` property), and
//! `stablesurf info` prints them from [`ScanInfo::notices`].

pub mod conf;
mod e57;
mod las;
mod obj;
mod pcd;
mod ply;
pub(crate) mod range;
mod stl;
mod xyz;

use std::collections::HashSet;
use std::path::Path;

use serde::Serialize;

use crate::cloud::{Aabb, PointCloud, ScanOrigin};

/// Errors of the import stage. Each message names the file, the problem and what to change.
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
    /// The file has no bytes at all.
    #[error("{path}: the file is empty; export the scan again")]
    Empty {
        /// The file.
        path: String,
    },
    /// The file is a `.conf` registration (scans and their poses), not a scan.
    #[error(
        "{path}: a .conf registration lists scans and their poses, not points; give it to `stablesurf \
         run`, `fit`, `normals` or `moments`, which read its scans and merge them, or give one of its scans"
    )]
    Registration {
        /// The file.
        path: String,
    },
    /// Neither the content nor the extension tells the format.
    #[error(
        "{path}: unknown scan format: no ply, stl, las, e57 or pcd signature and the extension \
         is not one of .ply .obj .stl .las .laz .e57 .pcd .xyz .pts .txt .csv; rename the file with the extension of \
         its format"
    )]
    UnknownFormat {
        /// The file.
        path: String,
    },
    /// The file ends before the data its header or structure announces.
    #[error("{path}: the file is truncated: {detail}; export it again or fix the header counts")]
    Truncated {
        /// The file.
        path: String,
        /// What was being read when the bytes ran out.
        detail: String,
    },
    /// A header count disagrees with the data that follows it.
    #[error(
        "{path}: the header declares {declared} {what} but the file holds {found}; \
         fix the count in the header"
    )]
    HeaderCountMismatch {
        /// The file.
        path: String,
        /// What is counted, e.g. "`vertex` entries" or "triangles".
        what: String,
        /// The count the header states.
        declared: u64,
        /// The count the data supports.
        found: u64,
    },
    /// A PLY header line is not valid.
    #[error("{path}:{line}: bad ply header: {message}")]
    BadHeader {
        /// The file.
        path: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong and what is expected.
        message: String,
    },
    /// The PLY `vertex` element lacks a coordinate, or an element has an unusable layout.
    #[error("{path}: {message}")]
    BadLayout {
        /// The file.
        path: String,
        /// What is wrong and what is expected.
        message: String,
    },
    /// A text line cannot be parsed.
    #[error("{path}:{line}: {message}")]
    Malformed {
        /// The file.
        path: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong and what is expected.
        message: String,
    },
    /// A face refers to a vertex that does not exist.
    #[error(
        "{path}{at}: face {face} refers to vertex {index}, but the file has {n_points} vertices \
         (0-based indices 0..{n_points}); fix or remove that face",
        at = line_suffix(.line)
    )]
    IndexOutOfRange {
        /// The file.
        path: String,
        /// 1-based line of the face, for text formats that know it.
        line: Option<usize>,
        /// 0-based number of the face in file order (before triangulation).
        face: usize,
        /// The offending index, 0-based (OBJ's 1-based and negative indices are converted).
        index: i64,
        /// Number of vertices in the file.
        n_points: usize,
    },
    /// A point has a NaN or infinite coordinate.
    #[error(
        "{path}: point {point} (0-based) has a non-finite coordinate ({x}, {y}, {z}); \
         remove that point or give it finite coordinates"
    )]
    NonFinite {
        /// The file.
        path: String,
        /// 0-based index of the point.
        point: usize,
        /// Its x coordinate.
        x: f64,
        /// Its y coordinate.
        y: f64,
        /// Its z coordinate.
        z: f64,
    },
    /// The file is valid but holds no point.
    #[error("{path}: the file holds no points; give a scan with at least one vertex")]
    NoPoints {
        /// The file.
        path: String,
    },
    /// A text file (XYZ or OBJ) in which no point parses: it is probably not the format its
    /// extension says.
    #[error("{path}: no point found: {detail}")]
    NoPointFound {
        /// The file.
        path: String,
        /// What the file looks like and what to change.
        detail: String,
    },
    /// A binary PLY body that does not fit the layout its header declares.
    #[error("{path}: byte {offset} of the file (`{element}` entry {entry}): {message}")]
    BadBinary {
        /// The file.
        path: String,
        /// The element being read.
        element: String,
        /// 0-based entry of that element.
        entry: u64,
        /// Byte offset in the file (header included) where the entry starts.
        offset: u64,
        /// What is wrong and what to change.
        message: String,
    },
    /// The normals do not match the points one to one.
    #[error(
        "{path}: the file has {normals} normals for {points} points; give one normal per point \
         or none"
    )]
    NormalCountMismatch {
        /// The file.
        path: String,
        /// Number of normals.
        normals: usize,
        /// Number of points.
        points: usize,
    },
}

impl ImportError {
    /// An [`ImportError::Malformed`] for line `line` of the file `path`.
    pub(crate) fn malformed(path: &str, line: usize, message: String) -> ImportError {
        ImportError::Malformed {
            path: path.to_owned(),
            line,
            message,
        }
    }
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
    /// ASPRS LAS.
    Las,
    /// LAS compressed with LASzip.
    Laz,
    /// ASTM E57 (one or more registered scans).
    E57,
    /// Point Cloud Library PCD, ascii body.
    PcdAscii,
    /// Point Cloud Library PCD, binary body.
    PcdBinary,
}

impl ScanFormat {
    /// The format's name as `stablesurf info` prints it.
    ///
    /// ```
    /// use stablesurf::import::ScanFormat;
    /// assert_eq!(ScanFormat::PlyBinaryLe.as_str(), "ply-binary-le");
    /// assert_eq!(ScanFormat::StlAscii.as_str(), "stl-ascii");
    /// ```
    pub fn as_str(self) -> &'static str {
        match self {
            ScanFormat::PlyAscii => "ply-ascii",
            ScanFormat::PlyBinaryLe => "ply-binary-le",
            ScanFormat::PlyBinaryBe => "ply-binary-be",
            ScanFormat::Obj => "obj",
            ScanFormat::StlAscii => "stl-ascii",
            ScanFormat::StlBinary => "stl-binary",
            ScanFormat::Xyz => "xyz",
            ScanFormat::Las => "las",
            ScanFormat::Laz => "laz",
            ScanFormat::E57 => "e57",
            ScanFormat::PcdAscii => "pcd-ascii",
            ScanFormat::PcdBinary => "pcd-binary",
        }
    }
}

impl std::fmt::Display for ScanFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A parsed scan before validation: it may still hold NaN coordinates.
#[derive(Clone, Debug)]
pub struct Scan {
    /// The format the bytes were in.
    pub format: ScanFormat,
    /// What the file holds.
    pub cloud: PointCloud,
    /// What the reader read but did not keep, one sentence each (e.g. "columns 4 to 5 of each
    /// line (intensity, quality) are not read: the cloud keeps x y z only").
    /// Empty when the cloud holds everything the file does. A caller should print them.
    pub notices: Vec<String>,
    /// What triangulating the file's range grid did, when it has one (see `range`).
    pub range_grid: Option<range::RangeGridInfo>,
}

/// What `stablesurf info` prints about a scan.
#[derive(Clone, Debug, Serialize)]
pub struct ScanInfo {
    /// Format name, e.g. "ply-binary-le" (see [`ScanFormat::as_str`]).
    pub format: String,
    /// Number of points as stored (STL corners welded).
    pub points: usize,
    /// Number of triangles after fan triangulation.
    pub triangles: usize,
    /// Whether the file stores normals.
    pub has_normals: bool,
    /// Whether the cloud keeps a colour per point (see [`PointCloud::colours`]).
    pub has_colours: bool,
    /// Whether the cloud keeps an intensity per point (see [`PointCloud::intensity`]).
    pub has_intensity: bool,
    /// The registered scans of a multi-scan file (E57): each scanner's position and point count.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scans: Option<Vec<ScanOrigin>>,
    /// Bounding box of the finite points (NaN, printed as JSON `null`, when there is none).
    pub bbox_min: [f64; 3],
    /// Bounding box of the finite points (NaN, printed as JSON `null`, when there is none).
    pub bbox_max: [f64; 3],
    /// Number of finite points whose position repeats an earlier point exactly.
    pub duplicate_points: usize,
    /// Number of points with a NaN or infinite coordinate.
    pub nan_points: usize,
    /// What the reader read but did not keep (see [`Scan::notices`]).
    pub notices: Vec<String>,
    /// The range grid's size, what its triangulation kept and cut, and the sensor (only for a
    /// file with a range grid).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub range_grid: Option<range::RangeGridInfo>,
}

/// `:LINE` after a path when the line is known.
fn line_suffix(line: &Option<usize>) -> String {
    line.map(|l| format!(":{l}")).unwrap_or_default()
}

/// The file's name as errors print it.
fn display_path(path: &Path) -> String {
    path.display().to_string()
}

/// The extensions (lowercase, without the dot) of the scan formats the readers know: a file
/// with one of them is read as that format when its content carries no signature. A batch run
/// of a folder runs the files with these extensions and skips the others.
pub const SCAN_EXTENSIONS: [&str; 11] = [
    "ply", "obj", "stl", "las", "laz", "e57", "pcd", "xyz", "pts", "txt", "csv",
];

/// Whether `path`'s extension is one of [`SCAN_EXTENSIONS`], in any case.
///
/// ```
/// use std::path::Path;
/// use stablesurf::import::has_scan_extension;
/// assert!(has_scan_extension(Path::new("data/bunny.PLY")));
/// assert!(!has_scan_extension(Path::new("data/SOURCES.md")));
/// assert!(!has_scan_extension(Path::new("data/bun.conf")));
/// ```
pub fn has_scan_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| SCAN_EXTENSIONS.iter().any(|k| e.eq_ignore_ascii_case(k)))
}

/// Reads and parses a scan file (no validation: NaN coordinates are kept).
///
/// # Errors
/// [`ImportError::Io`] when the file cannot be read, else as [`read_scan_bytes`].
pub fn read_scan(path: &Path) -> Result<Scan, ImportError> {
    let bytes = std::fs::read(path).map_err(|source| ImportError::Io {
        path: display_path(path),
        source,
    })?;
    read_scan_bytes(&bytes, path)
}

/// Parses scan bytes; `path` names the file in errors and gives the extension.
///
/// The format is chosen by content where possible (see the module docs), else by extension.
/// Coordinates are kept as stored, NaN included; face indices are checked against the vertex
/// count because a triangle must index a point.
///
/// ```
/// use std::path::Path;
/// use stablesurf::import::{read_scan_bytes, ScanFormat};
/// let scan = read_scan_bytes(b"0 0 0\n1 0 0\nnan 1 0\n", Path::new("pts.xyz")).unwrap();
/// assert_eq!(scan.format, ScanFormat::Xyz);
/// assert_eq!(scan.cloud.points.len(), 3);
/// assert!(scan.cloud.points[2][0].is_nan());
/// ```
///
/// # Errors
/// Empty, truncated or malformed content, an unknown format, or a face index out of range.
pub fn read_scan_bytes(bytes: &[u8], path: &Path) -> Result<Scan, ImportError> {
    let name = display_path(path);
    if bytes.is_empty() {
        return Err(ImportError::Empty { path: name });
    }
    let Some(detected) = detect_format(bytes, path) else {
        return Err(if conf::is_conf(path) {
            ImportError::Registration { path: name }
        } else {
            ImportError::UnknownFormat { path: name }
        });
    };
    read_detected(bytes, &name, detected)
}

/// Parses scan bytes with the reader of `format`, whatever the content and extension say (for
/// files whose extension lies). Any PLY variant selects the PLY reader, which takes the encoding
/// from the header; the STL variants select the binary or the ascii reader.
///
/// ```
/// use std::path::Path;
/// use stablesurf::import::{read_scan_bytes_as, ScanFormat};
/// let scan = read_scan_bytes_as(b"v 0 0 0\n", Path::new("scan.dat"), ScanFormat::Obj).unwrap();
/// assert_eq!(scan.cloud.points, vec![[0.0, 0.0, 0.0]]);
/// ```
///
/// # Errors
/// As [`read_scan_bytes`], except [`ImportError::UnknownFormat`].
pub fn read_scan_bytes_as(
    bytes: &[u8],
    path: &Path,
    format: ScanFormat,
) -> Result<Scan, ImportError> {
    let name = display_path(path);
    if bytes.is_empty() {
        return Err(ImportError::Empty { path: name });
    }
    let detected = match format {
        ScanFormat::PlyAscii | ScanFormat::PlyBinaryLe | ScanFormat::PlyBinaryBe => Detected::Ply,
        ScanFormat::Obj => Detected::Obj,
        ScanFormat::StlAscii => Detected::StlAscii,
        ScanFormat::StlBinary => Detected::StlBinary,
        ScanFormat::Xyz => Detected::Xyz,
        ScanFormat::Las | ScanFormat::Laz => Detected::Las,
        ScanFormat::E57 => Detected::E57,
        ScanFormat::PcdAscii | ScanFormat::PcdBinary => Detected::Pcd,
    };
    read_detected(bytes, &name, detected)
}

/// Runs the reader of `detected` on the bytes.
fn read_detected(bytes: &[u8], name: &str, detected: Detected) -> Result<Scan, ImportError> {
    let mut notices = Vec::new();
    let mut range_grid = None;
    let (format, cloud) = match detected {
        Detected::Ply => {
            let (format, cloud, grid) = ply::read(bytes, name, &mut notices)?;
            range_grid = grid;
            (format, cloud)
        }
        Detected::StlBinary => (ScanFormat::StlBinary, stl::read_binary(bytes, name)?),
        Detected::StlAscii => (ScanFormat::StlAscii, stl::read_ascii(bytes, name)?),
        Detected::Obj => (ScanFormat::Obj, obj::read(bytes, name, &mut notices)?),
        Detected::Xyz => (ScanFormat::Xyz, xyz::read(bytes, name, &mut notices)?),
        Detected::Las => guarded(name, "las", || las::read(bytes, name, &mut notices))?,
        Detected::E57 => (
            ScanFormat::E57,
            guarded(name, "e57", || e57::read(bytes, name, &mut notices))?,
        ),
        Detected::Pcd => match pcd::read(bytes, name, &mut notices)? {
            (true, cloud) => (ScanFormat::PcdBinary, cloud),
            (false, cloud) => (ScanFormat::PcdAscii, cloud),
        },
    };
    Ok(Scan {
        format,
        cloud,
        notices,
        range_grid,
    })
}

thread_local! {
    /// Set while [`guarded`] runs a third-party reader: its panics are errors, not messages.
    static QUIET_PANICS: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

/// Runs a reader built on a third-party crate (las/laz, e57), turning a panic on malformed bytes
/// (the laz decompressor indexes out of range on some corrupt files) into an
/// [`ImportError::BadLayout`] that names the file. The panic hook installed here stays silent
/// for such panics only, on the thread that runs the reader, and hands every other panic to the
/// hook that was there before.
fn guarded<T>(
    path: &str,
    what: &str,
    read: impl FnOnce() -> Result<T, ImportError>,
) -> Result<T, ImportError> {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !QUIET_PANICS.with(std::cell::Cell::get) {
                previous(info);
            }
        }));
    });
    QUIET_PANICS.with(|q| q.set(true));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(read));
    QUIET_PANICS.with(|q| q.set(false));
    result.unwrap_or_else(|payload| {
        let cause = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_default();
        Err(ImportError::BadLayout {
            path: path.to_owned(),
            message: format!(
                "the {what} reader failed on malformed data ({cause}): the file is corrupt; \
                 export the scan again"
            ),
        })
    })
}

/// Parses and validates scan bytes (finite coordinates, at least one point, indices in range,
/// one normal per point when there are normals).
///
/// ```
/// use std::path::Path;
/// use stablesurf::import::{import_bytes, ImportError};
/// let cloud = import_bytes(b"0 0 0 0 0 1\n1 0 0 0 0 1\n", Path::new("a.xyz")).unwrap();
/// assert_eq!(cloud.normals.unwrap().len(), 2);
/// let err = import_bytes(b"0 0 0\ninf 0 0\n", Path::new("b.xyz")).unwrap_err();
/// assert!(matches!(err, ImportError::NonFinite { point: 1, .. }));
/// ```
///
/// # Errors
/// Those of [`read_scan_bytes`], plus [`ImportError::NoPoints`], [`ImportError::NonFinite`],
/// [`ImportError::IndexOutOfRange`] and [`ImportError::NormalCountMismatch`].
pub fn import_bytes(bytes: &[u8], path: &Path) -> Result<PointCloud, ImportError> {
    Ok(import_scan_bytes(bytes, path)?.cloud)
}

/// [`import_bytes`] that keeps the format and the reader's [`Scan::notices`], for callers that
/// print what the file held but the cloud does not.
///
/// ```
/// use std::path::Path;
/// use stablesurf::import::import_scan_bytes;
/// let scan = import_scan_bytes(b"0 0 0 7 255\n", Path::new("a.txt")).unwrap();
/// assert_eq!(scan.cloud.points.len(), 1);
/// assert!(scan.notices[0].contains("columns 4 to 5"), "{:?}", scan.notices);
/// ```
///
/// # Errors
/// As [`import_bytes`].
pub fn import_scan_bytes(bytes: &[u8], path: &Path) -> Result<Scan, ImportError> {
    let scan = read_scan_bytes(bytes, path)?;
    validate(&scan.cloud, &display_path(path))?;
    Ok(scan)
}

/// Checks the invariants of a validated [`PointCloud`] (see the module docs) on a cloud built
/// in memory rather than read from a file; `name` stands for the file's path in the messages.
///
/// ```
/// use stablesurf::import::{validate_cloud, ImportError};
/// use stablesurf::PointCloud;
/// let mut cloud = PointCloud { points: vec![[0.0, 0.0, 0.0]], ..Default::default() };
/// assert!(validate_cloud(&cloud, "points").is_ok());
/// cloud.triangles = vec![[0, 0, 1]];
/// let err = validate_cloud(&cloud, "points").unwrap_err();
/// assert!(matches!(err, ImportError::IndexOutOfRange { index: 1, .. }));
/// ```
///
/// # Errors
/// [`ImportError::NoPoints`], [`ImportError::NonFinite`], [`ImportError::IndexOutOfRange`],
/// [`ImportError::NormalCountMismatch`], or [`ImportError::BadLayout`] when the colours,
/// intensities or scans do not count one per point.
pub fn validate_cloud(cloud: &PointCloud, name: &str) -> Result<(), ImportError> {
    validate(cloud, name)
}

/// Checks the invariants of a validated [`PointCloud`] (see the module docs).
fn validate(cloud: &PointCloud, path: &str) -> Result<(), ImportError> {
    if cloud.points.is_empty() {
        return Err(ImportError::NoPoints {
            path: path.to_owned(),
        });
    }
    if let Some((point, p)) = cloud
        .points
        .iter()
        .enumerate()
        .find(|(_, p)| !p.iter().all(|c| c.is_finite()))
    {
        return Err(ImportError::NonFinite {
            path: path.to_owned(),
            point,
            x: p[0],
            y: p[1],
            z: p[2],
        });
    }
    let n_points = cloud.points.len();
    for (face, triangle) in cloud.triangles.iter().enumerate() {
        if let Some(&index) = triangle.iter().find(|&&i| i as usize >= n_points) {
            // The readers already check per file face; this catches clouds built elsewhere, where
            // only the triangle number is known.
            return Err(ImportError::IndexOutOfRange {
                path: path.to_owned(),
                line: None,
                face,
                index: i64::from(index),
                n_points,
            });
        }
    }
    if let Some(normals) = &cloud.normals
        && normals.len() != n_points
    {
        return Err(ImportError::NormalCountMismatch {
            path: path.to_owned(),
            normals: normals.len(),
            points: n_points,
        });
    }
    // The readers make these one per point; this catches clouds built elsewhere.
    let per_point = [
        ("colours", cloud.colours.as_ref().map(Vec::len)),
        ("intensities", cloud.intensity.as_ref().map(Vec::len)),
        (
            "points in its scans",
            cloud
                .scans
                .as_ref()
                .map(|s| s.iter().map(|s| s.n_points).sum()),
        ),
    ];
    for (what, n) in per_point {
        if let Some(n) = n.filter(|&n| n != n_points) {
            return Err(ImportError::BadLayout {
                path: path.to_owned(),
                message: format!(
                    "the cloud has {n} {what} for {n_points} points; give one per point"
                ),
            });
        }
    }
    Ok(())
}

/// Summarizes a parsed scan for `stablesurf info`.
///
/// ```
/// use std::path::Path;
/// use stablesurf::import::{read_scan_bytes, scan_info};
/// let scan = read_scan_bytes(b"0 0 0\n1 2 3\n0 0 0\nnan 0 0\n", Path::new("a.xyz")).unwrap();
/// let info = scan_info(&scan);
/// assert_eq!(info.format, "xyz");
/// assert_eq!((info.points, info.duplicate_points, info.nan_points), (4, 1, 1));
/// assert_eq!(info.bbox_max, [1.0, 2.0, 3.0]);
/// ```
pub fn scan_info(scan: &Scan) -> ScanInfo {
    let cloud = &scan.cloud;
    let bbox = Aabb::from_points(&cloud.points);
    let mut seen = HashSet::with_capacity(cloud.points.len());
    let mut duplicate_points = 0;
    let mut nan_points = 0;
    for p in &cloud.points {
        if p.iter().all(|c| c.is_finite()) {
            if !seen.insert(position_key(*p)) {
                duplicate_points += 1;
            }
        } else {
            nan_points += 1;
        }
    }
    ScanInfo {
        format: scan.format.as_str().to_owned(),
        points: cloud.points.len(),
        triangles: cloud.triangles.len(),
        has_normals: cloud.normals.is_some(),
        has_colours: cloud.colours.is_some(),
        has_intensity: cloud.intensity.is_some(),
        scans: cloud.scans.clone(),
        bbox_min: bbox.map_or([f64::NAN; 3], |b| b.min),
        bbox_max: bbox.map_or([f64::NAN; 3], |b| b.max),
        duplicate_points,
        nan_points,
        notices: scan.notices.clone(),
        range_grid: scan.range_grid.clone(),
    }
}

/// A hashable key for an exact position: the coordinate bits, with -0.0 folded onto 0.0 so the
/// key agrees with `==` on finite values.
pub(crate) fn position_key(p: [f64; 3]) -> [u64; 3] {
    p.map(|c| (c + 0.0).to_bits())
}

/// Appends the fan triangulation of `polygon` (indices already 0-based) to `triangles`.
/// Polygons with fewer than three corners add nothing.
#[inline]
pub(crate) fn push_fan(triangles: &mut Vec<[u32; 3]>, polygon: &[u32]) {
    if let Some((&first, rest)) = polygon.split_first() {
        for pair in rest.windows(2) {
            triangles.push([first, pair[0], pair[1]]);
        }
    }
}

/// Which reader the bytes go to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Detected {
    Ply,
    StlBinary,
    StlAscii,
    Obj,
    Xyz,
    Las,
    E57,
    Pcd,
}

/// Chooses the reader: content signatures first, then the extension, then a look at the text.
fn detect_format(bytes: &[u8], path: &Path) -> Option<Detected> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        return Some(Detected::Ply);
    }
    if bytes.starts_with(b"LASF") {
        return Some(Detected::Las);
    }
    if bytes.starts_with(b"ASTM-E57") {
        return Some(Detected::E57);
    }
    if pcd::looks_like_pcd(bytes) {
        return Some(Detected::Pcd);
    }
    if stl::is_binary_size(bytes) {
        return Some(Detected::StlBinary);
    }
    if stl::looks_ascii(bytes) {
        return Some(Detected::StlAscii);
    }
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("ply") => return Some(Detected::Ply),
        Some("obj") => return Some(Detected::Obj),
        // Neither signature matched, so the binary reader reports the size mismatch.
        Some("stl") => return Some(Detected::StlBinary),
        Some("xyz" | "pts" | "txt" | "csv") => return Some(Detected::Xyz),
        // No signature, so the las reader reports what the file starts with.
        Some("las" | "laz") => return Some(Detected::Las),
        Some("pcd") => return Some(Detected::Pcd),
        Some("e57") => return Some(Detected::E57),
        _ => {}
    }
    sniff_text(bytes)
}

/// Guesses OBJ or XYZ from the first meaningful lines of a file with no known extension.
fn sniff_text(bytes: &[u8]) -> Option<Detected> {
    let head = &bytes[..bytes.len().min(4096)];
    // Binary data (NUL bytes or invalid UTF-8 away from the cut) is no text format.
    if head.contains(&0) {
        return None;
    }
    let text = match std::str::from_utf8(head) {
        Ok(t) => t,
        Err(e) if e.error_len().is_none() => std::str::from_utf8(&head[..e.valid_up_to()]).ok()?,
        Err(_) => return None,
    };
    for line in text.lines().map(str::trim).filter(|l| !l.is_empty()) {
        if line.starts_with('#') {
            continue;
        }
        let first = line.split_ascii_whitespace().next().unwrap_or("");
        if matches!(
            first,
            "v" | "vn" | "vt" | "f" | "o" | "g" | "mtllib" | "usemtl" | "s"
        ) {
            return Some(Detected::Obj);
        }
        let numeric = line
            .split(|c: char| c.is_ascii_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
            .all(|t| t.parse::<f64>().is_ok());
        return numeric.then_some(Detected::Xyz);
    }
    None
}

/// A cursor over the lines of a text file that keeps 1-based line numbers for error messages.
pub(crate) struct Lines<'a> {
    rest: &'a [u8],
    line: usize,
}

impl<'a> Lines<'a> {
    /// Lines of `bytes`, the first numbered `first_line`.
    pub(crate) fn new(bytes: &'a [u8], first_line: usize) -> Lines<'a> {
        Lines {
            rest: bytes,
            line: first_line.saturating_sub(1),
        }
    }

    /// The next line without its `\n` or `\r\n`, with its number, or `None` at the end.
    /// Invalid UTF-8 is reported as a [`ImportError::Malformed`] line.
    pub(crate) fn next_line(
        &mut self,
        path: &str,
    ) -> Option<Result<(usize, &'a str), ImportError>> {
        if self.rest.is_empty() {
            return None;
        }
        let end = self.rest.iter().position(|&b| b == b'\n');
        let (raw, rest) = match end {
            Some(i) => (&self.rest[..i], &self.rest[i + 1..]),
            None => (self.rest, &self.rest[self.rest.len()..]),
        };
        self.rest = rest;
        self.line += 1;
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        Some(match std::str::from_utf8(raw) {
            Ok(text) => Ok((self.line, text)),
            Err(_) => Err(ImportError::Malformed {
                path: path.to_owned(),
                line: self.line,
                message: "the line is not text (invalid utf-8): the file is binary or corrupt"
                    .to_owned(),
            }),
        })
    }
}

/// The error for a text file holding a NUL byte (`what` names the format), or `None`.
/// No text format has NUL bytes; a file with one is binary or zero-filled.
pub(crate) fn nul_byte(bytes: &[u8], path: &str, what: &str) -> Option<ImportError> {
    let at = bytes.iter().position(|&b| b == 0)?;
    let line = 1 + bytes[..at].iter().filter(|&&b| b == b'\n').count();
    let all = bytes.iter().all(|&b| b == 0);
    Some(ImportError::Malformed {
        path: path.to_owned(),
        line,
        message: format!(
            "the file holds NUL bytes (the first at byte {at}{}): it looks binary, not {what} \
             text; give the scan in its own format, with that format's extension",
            if all { "; every byte is 0" } else { "" }
        ),
    })
}

/// The first non-blank line of a text file (comments included) and its number, shortened to
/// 60 characters, as errors quote it: `` line 3: `hello world` ``.
pub(crate) fn first_line_quoted(bytes: &[u8]) -> Option<String> {
    let mut lines = Lines::new(bytes, 1);
    while let Some(Ok((number, text))) = lines.next_line("") {
        let text = text.trim();
        if !text.is_empty() {
            let short: String = text.chars().take(60).collect();
            let more = if short.len() < text.len() { "…" } else { "" };
            return Some(format!("line {number}: `{short}{more}`"));
        }
    }
    None
}

/// Parses one coordinate token (accepts `nan`, `inf`, `1.`, `.5`, exponents).
pub(crate) fn parse_f64(token: &str) -> Option<f64> {
    token.parse::<f64>().ok()
}

#[cfg(test)]
mod tests;
