//! Export stage, NumPy writer: a `DenseVolume` → `volume.npy` and its sidecar `volume.json`.
//!
//! Input: the dense signed-distance grid of `crate::distance::volume::dense`. Output: a NumPy
//! `.npy` file, format version 1.0: the magic `\x93NUMPY`, version bytes 1 0, a little-endian
//! u16 header length, the header (a Python dict literal `{'descr': '<f4', 'fortran_order':
//! False, 'shape': (nx, ny, nz), }` padded with spaces and a newline so that the data starts at
//! a multiple of 64 bytes), then nx·ny·nz little-endian float32 values in C order:
//! `volume[i, j, k]` is the signed distance at the centre of voxel (i, j, k), i along x, j along
//! y, k along z, at `origin + voxel_size · (i, j, k)` in input coordinates. Values are in input
//! units, negative inside.
//!
//! The sidecar (`sidecar`) is JSON: `format` `stablesurf.volume`, `version` 1, `data`
//! (`volume.npy`), `shape`, `axis_order`, `origin` (the centre of voxel (0, 0, 0)),
//! `voxel_size`, `grid_to_world` (a 4×4 row-major matrix taking (i, j, k, 1) to input
//! coordinates), `units` (with `--units`), `sign` and `distance` (how the values were made).
//! Deterministic: fixed key order, Rust's shortest round-trip float formatting.

use std::io::Write;

use super::units::LengthUnit;
use super::ExportError;
use crate::distance::volume::{DenseVolume, BAND_VOXELS};

/// Writes `volume` as a `.npy` file (see the module docs) to `out`.
///
/// # Errors
/// [`ExportError::Format`] when the values do not fill the grid; [`ExportError::Write`] when
/// `out` fails.
pub(crate) fn write(volume: &DenseVolume, out: &mut impl Write) -> Result<(), ExportError> {
    let [nx, ny, nz] = volume.grid.shape;
    if volume.values.len() != nx * ny * nz {
        return Err(ExportError::Format(format!(
            "the volume has {} values for a grid of {nx} × {ny} × {nz}",
            volume.values.len()
        )));
    }
    let dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({nx}, {ny}, {nz}), }}");
    // Magic (6) + version (2) + length (2) + dict + padding + '\n', a multiple of 64.
    let total = (10 + dict.len() + 1).div_ceil(64) * 64;
    let mut header = Vec::with_capacity(total);
    header.extend_from_slice(b"\x93NUMPY\x01\x00");
    header.extend_from_slice(&((total - 10) as u16).to_le_bytes());
    header.extend_from_slice(dict.as_bytes());
    header.resize(total - 1, b' ');
    header.push(b'\n');
    out.write_all(&header).map_err(ExportError::Write)?;
    let mut data = Vec::with_capacity(volume.values.len() * 4);
    for v in &volume.values {
        data.extend_from_slice(&v.to_le_bytes());
    }
    out.write_all(&data).map_err(ExportError::Write)
}

/// The sidecar JSON of `volume.npy` (see the module docs); `units` is the input's unit, if
/// known.
pub(crate) fn sidecar(volume: &DenseVolume, units: Option<LengthUnit>) -> Vec<u8> {
    let g = &volume.grid;
    let h = g.voxel_size;
    let o = g.origin;
    let mut value = serde_json::json!({
        "format": "stablesurf.volume",
        "version": 1,
        "data": "volume.npy",
        "dtype": "float32 little-endian",
        "shape": g.shape,
        "axis_order": "C order: volume[i, j, k], i along x, j along y, k along z (k fastest)",
        "origin": o,
        "origin_is": "the centre of voxel (0, 0, 0), input coordinates",
        "voxel_size": h,
        "grid_to_world": [
            [h, 0.0, 0.0, o[0]],
            [0.0, h, 0.0, o[1]],
            [0.0, 0.0, h, o[2]],
            [0.0, 0.0, 0.0, 1.0],
        ],
        "sign": "negative inside, positive outside (the sign of the model's f)",
        "distance": format!(
            "Euclidean distance to the output mesh, in input units: exact within {BAND_VOXELS} voxels of it, elsewhere within the mesh's chord error"
        ),
    });
    if let Some(u) = units {
        value["units"] = serde_json::Value::from(u.symbol());
    }
    let mut bytes = serde_json::to_vec_pretty(&value).unwrap_or_default();
    bytes.push(b'\n');
    bytes
}

/// What `stablesurf info` shows of a `.npy` file: its version, dtype, shape and order from the
/// header, and the range of the values when they are little-endian `float32` (what `write()`
/// writes), NaN ignored.
///
/// # Errors
/// [`ExportError::Format`] when the bytes are not a NumPy `.npy` file or end before the data
/// its header announces.
pub fn read_info(bytes: &[u8]) -> Result<serde_json::Value, ExportError> {
    let bad = |why: &str| ExportError::Format(format!("not a readable .npy file: {why}"));
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad("no NumPy magic string"));
    }
    let (major, minor) = (bytes[6], bytes[7]);
    let (len, start) = match major {
        1 => (usize::from(u16::from_le_bytes([bytes[8], bytes[9]])), 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => return Err(bad("an unknown format version")),
    };
    let header = bytes
        .get(start..start + len)
        .ok_or_else(|| bad("the header is cut short"))?;
    let header = String::from_utf8_lossy(header);
    // The header is a Python dict literal: 'descr': '<f4', 'fortran_order': False, 'shape': (…).
    let field = |key: &str| -> Option<String> {
        let at = header.find(&format!("'{key}':"))? + key.len() + 3;
        let rest = header[at..].trim_start();
        let end = if rest.starts_with('(') {
            rest.find(')')? + 1
        } else {
            rest.find([',', '}'])?
        };
        Some(rest[..end].trim().trim_matches('\'').to_string())
    };
    let descr = field("descr").ok_or_else(|| bad("no 'descr' in the header"))?;
    let fortran = field("fortran_order").ok_or_else(|| bad("no 'fortran_order' in the header"))?;
    let shape_text = field("shape").ok_or_else(|| bad("no 'shape' in the header"))?;
    let shape: Vec<usize> = shape_text
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(|t| {
            t.parse()
                .map_err(|_| bad("a shape that is not whole numbers"))
        })
        .collect::<Result<_, _>>()?;
    let count = shape.iter().try_fold(1usize, |a, &n| a.checked_mul(n));
    let count = count.ok_or_else(|| bad("a shape too large"))?;
    let mut info = serde_json::json!({
        "format": "npy",
        "version": format!("{major}.{minor}"),
        "dtype": descr,
        "fortran_order": fortran == "True",
        "shape": shape,
    });
    if descr == "<f4" {
        let data = &bytes[start + len..];
        if data.len() < count * 4 {
            return Err(bad("the data is shorter than its shape"));
        }
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for c in data[..count * 4].chunks_exact(4) {
            let v = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
            if !v.is_nan() {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        if lo <= hi {
            info["min"] = lo.into();
            info["max"] = hi.into();
        }
    }
    Ok(info)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::distance::volume::VoxelGrid;

    #[test]
    fn info_reads_what_write_writes() {
        let grid = VoxelGrid {
            origin: [0.0; 3],
            voxel_size: 1.0,
            shape: [2, 3, 4],
        };
        let values: Vec<f32> = (0..24).map(|i| i as f32 - 5.5).collect();
        let mut bytes = Vec::new();
        write(&DenseVolume { grid, values }, &mut bytes).unwrap();
        let info = read_info(&bytes).unwrap();
        assert_eq!(info["format"], "npy");
        assert_eq!(info["version"], "1.0");
        assert_eq!(info["dtype"], "<f4");
        assert_eq!(info["fortran_order"], false);
        assert_eq!(info["shape"], serde_json::json!([2, 3, 4]));
        assert_eq!(info["min"], -5.5);
        assert_eq!(info["max"], 17.5);
        for n in [0, 9, 40, bytes.len() - 1] {
            assert!(read_info(&bytes[..n]).is_err(), "prefix of {n} bytes");
        }
    }
}

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn write() {
        use crate::distance::volume::{DenseVolume, VoxelGrid};
        use crate::export::npy::write;
        let grid = VoxelGrid {
            origin: [0.0; 3],
            voxel_size: 1.0,
            shape: [2, 3, 4],
        };
        let volume = DenseVolume {
            grid,
            values: vec![0.5; 24],
        };
        let mut bytes = Vec::new();
        write(&volume, &mut bytes).unwrap();
        assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
        assert_eq!(bytes.len(), 128 + 24 * 4);
    }
}
