//! The `stablesurf.mpu` model file: a detail-mode [`MpuModel`] (multi-level partition of unity
//! of local polynomials), written and read.
//!
//! Input: an [`MpuModel`] (write) or the file's bytes (read). Output: the bytes, or the model with
//! its evaluation index rebuilt. Invariant: `read_mpu(write_mpu(m)) == m` and rewriting a read
//! model gives byte-identical output (every number is stored as its exact little-endian f64).
//!
//! Layout (binary, little-endian):
//!
//! ```text
//! magic      16 bytes  "stablesurf.mpu\0\0"
//! version    u32       1
//! region     6 × f64   min xyz, max xyz (meshing box, input coordinates)
//! root       6 × f64   the octree's root cube
//! diagonal   f64       data diagonal (f where no ball reaches)
//! n_cells    u64
//! per cell:  centre 3 × f64, radius f64, fit radius f64, level u32, grown u8,
//!            degree u32, poly centre 3 × f64, poly scale f64,
//!            (d+1)(d+2)(d+3)/6 × f64 coefficients (paper's monomial order)
//! diag_len   u64, then that many bytes of JSON (the fit's DetailDiagnostics)
//! ```
//!
//! The local polynomial of a cell is Q(p) = Σ a_α q^α with q = (p − poly centre)/poly scale; the
//! blend and weights are described in [`crate::detail`].

use std::io::Write;
use std::path::Path;

use super::ModelError;
use crate::cloud::Aabb;
use crate::detail::{DetailDiagnostics, MpuCell, MpuModel};
use crate::poly::{n_coefficients, ImplicitPolynomial};

/// The file's first 16 bytes.
pub(crate) const MAGIC: &[u8; 16] = b"stablesurf.mpu\0\0";

/// The layout version this code writes and reads.
pub(crate) const VERSION: u32 = 1;

/// Highest local degree a file may hold.
const MAX_DEGREE: u32 = 4;

/// Whether `bytes` start like a `stablesurf.mpu` file (any version).
///
/// ```
/// assert!(stablesurf::model::mpu::is_mpu(b"stablesurf.mpu\0\0\x01\0\0\0"));
/// assert!(!stablesurf::model::mpu::is_mpu(b"{\"format\": \"stablesurf.implicit-polynomial\"}"));
/// ```
pub fn is_mpu(bytes: &[u8]) -> bool {
    bytes.starts_with(MAGIC)
}

/// Writes `model` in the `stablesurf.mpu` format.
///
/// # Errors
/// [`ModelError::Write`] when the stream fails.
pub fn write_mpu(model: &MpuModel, out: &mut impl Write) -> Result<(), ModelError> {
    out.write_all(&mpu_bytes(model)?).map_err(ModelError::Write)
}

/// The bytes [`write_mpu`] writes, in one buffer of their exact size (a detail model of the bunny
/// is 13 MB: growing or copying it again costs more than encoding it).
///
/// # Errors
/// [`ModelError::Format`] when the diagnostics cannot be encoded.
pub(crate) fn mpu_bytes(model: &MpuModel) -> Result<Vec<u8>, ModelError> {
    let diagnostics = serde_json::to_vec(&model.diagnostics)
        .map_err(|e| ModelError::Format(format!("cannot encode the diagnostics: {e}")))?;
    let cells: usize = model
        .cells
        .iter()
        .map(|c| 3 * 8 + 8 + 8 + 4 + 1 + 4 + 3 * 8 + 8 + 8 * c.poly.coefficients.len())
        .sum();
    let mut buf: Vec<u8> = Vec::with_capacity(16 + 4 + 13 * 8 + 8 + cells + 8 + diagnostics.len());
    buf.extend_from_slice(MAGIC);
    buf.extend_from_slice(&VERSION.to_le_bytes());
    for b in [&model.region, &model.root] {
        for v in b.min.iter().chain(&b.max) {
            buf.extend_from_slice(&v.to_le_bytes());
        }
    }
    buf.extend_from_slice(&model.diagonal.to_le_bytes());
    buf.extend_from_slice(&(model.cells.len() as u64).to_le_bytes());
    for c in &model.cells {
        for v in c.center {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        buf.extend_from_slice(&c.radius.to_le_bytes());
        buf.extend_from_slice(&c.fit_radius.to_le_bytes());
        buf.extend_from_slice(&c.level.to_le_bytes());
        buf.push(u8::from(c.grown));
        buf.extend_from_slice(&c.poly.degree.to_le_bytes());
        for v in c.poly.center {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        buf.extend_from_slice(&c.poly.scale.to_le_bytes());
        for v in &c.poly.coefficients {
            buf.extend_from_slice(&v.to_le_bytes());
        }
    }
    buf.extend_from_slice(&(diagnostics.len() as u64).to_le_bytes());
    buf.extend_from_slice(&diagnostics);
    debug_assert_eq!(buf.len(), buf.capacity());
    Ok(buf)
}

/// A cursor over the file's bytes that reports truncation with the path.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
    path: &'a Path,
}

impl Reader<'_> {
    fn bad(&self, what: &str) -> ModelError {
        ModelError::Format(format!(
            "{} is not a valid stablesurf.mpu file: {what} (at byte {}); rewrite it with `stablesurf fit --mode detail`",
            self.path.display(),
            self.at
        ))
    }

    fn take(&mut self, n: usize) -> Result<&[u8], ModelError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        match end {
            Some(end) => {
                let s = &self.bytes[self.at..end];
                self.at = end;
                Ok(s)
            }
            None => Err(self.bad("the file is truncated")),
        }
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], ModelError> {
        let s = self.take(N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    fn f64(&mut self) -> Result<f64, ModelError> {
        let v = f64::from_le_bytes(self.array()?);
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.bad("a number is not finite"))
        }
    }

    fn u32(&mut self) -> Result<u32, ModelError> {
        Ok(u32::from_le_bytes(self.array()?))
    }

    fn u64(&mut self) -> Result<u64, ModelError> {
        Ok(u64::from_le_bytes(self.array()?))
    }

    fn point(&mut self) -> Result<[f64; 3], ModelError> {
        Ok([self.f64()?, self.f64()?, self.f64()?])
    }

    fn aabb(&mut self) -> Result<Aabb, ModelError> {
        let min = self.point()?;
        let max = self.point()?;
        if (0..3).any(|a| min[a] > max[a]) {
            return Err(self.bad("a box has min > max"));
        }
        Ok(Aabb { min, max })
    }
}

/// Reads a `stablesurf.mpu` file; `path` only names the file in errors.
///
/// # Errors
/// [`ModelError::Format`] naming the file and the fault: wrong magic (not an .mpu file), an
/// unsupported version, truncation, trailing bytes, a non-finite number, a radius or scale
/// ≤ 0, a degree above 4, or unreadable diagnostics.
///
/// ```
/// use std::path::Path;
/// use stablesurf::model::mpu::read_mpu;
/// let err = read_mpu(b"stablesurf.mpu\0\0\x09\0\0\0", Path::new("m.mpu")).unwrap_err();
/// assert!(err.to_string().contains("version 9"));
/// ```
pub fn read_mpu(bytes: &[u8], path: &Path) -> Result<MpuModel, ModelError> {
    let mut r = Reader { bytes, at: 0, path };
    if !is_mpu(bytes) {
        return Err(r.bad("it does not start with the stablesurf.mpu magic"));
    }
    r.at = MAGIC.len();
    let version = r.u32()?;
    if version != VERSION {
        return Err(ModelError::Format(format!(
            "{} is a stablesurf.mpu file of version {version}, this build reads version {VERSION}; refit the model with this build",
            path.display()
        )));
    }
    let region = r.aabb()?;
    let root = r.aabb()?;
    let diagonal = r.f64()?;
    if diagonal <= 0.0 {
        return Err(r.bad("the diagonal is not > 0"));
    }
    let n_cells = r.u64()?;
    // Every cell takes at least 100 bytes: reject absurd counts before allocating.
    if n_cells > (bytes.len() / 100) as u64 {
        return Err(r.bad("the cell count exceeds what the file can hold"));
    }
    let mut cells = Vec::with_capacity(n_cells as usize);
    for _ in 0..n_cells {
        let center = r.point()?;
        let radius = r.f64()?;
        let fit_radius = r.f64()?;
        let level = r.u32()?;
        let grown = match r.array::<1>()?[0] {
            0 => false,
            1 => true,
            _ => return Err(r.bad("a cell's grown flag is not 0 or 1")),
        };
        let degree = r.u32()?;
        if degree > MAX_DEGREE {
            return Err(r.bad("a cell's degree is above 4"));
        }
        let poly_center = r.point()?;
        let scale = r.f64()?;
        if radius <= 0.0 || scale <= 0.0 {
            return Err(r.bad("a cell's radius or scale is not > 0"));
        }
        let coefficients = (0..n_coefficients(degree))
            .map(|_| r.f64())
            .collect::<Result<Vec<f64>, _>>()?;
        cells.push(MpuCell {
            center,
            radius,
            fit_radius,
            level,
            grown,
            poly: ImplicitPolynomial {
                degree,
                coefficients,
                center: poly_center,
                scale,
            },
        });
    }
    let len = r.u64()?;
    let json = r.take(usize::try_from(len).unwrap_or(usize::MAX))?;
    let diagnostics: DetailDiagnostics = serde_json::from_slice(json).map_err(|e| {
        ModelError::Format(format!(
            "{} is not a valid stablesurf.mpu file: unreadable diagnostics ({e})",
            path.display()
        ))
    })?;
    if r.at != bytes.len() {
        return Err(r.bad("unexpected bytes after the end"));
    }
    Ok(MpuModel::new(region, root, diagonal, cells, diagnostics))
}
