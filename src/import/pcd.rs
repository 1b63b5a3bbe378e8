//! Stage `import`, PCD reader: a Point Cloud Library file (ascii or binary body) → [`PointCloud`].
//!
//! Input: the whole file as bytes: a text header (`VERSION`, `FIELDS`, `SIZE`, `TYPE`, `COUNT`,
//! `WIDTH`, `HEIGHT`, `VIEWPOINT`, `POINTS`, `DATA`, `#` comments) and a body of `POINTS`
//! records, one text line each (`DATA ascii`) or packed little-endian in the order of `FIELDS`
//! (`DATA binary`). Output: the points (fields `x y z`), with normals when the file has
//! `normal_x normal_y normal_z`, colour from `rgb` or `rgba` (a packed 0x00RRGGBB, stored as a
//! float's or an integer's bits; kept as 16-bit, each 8-bit value times 257), intensity from
//! `intensity`, and no triangles. Other fields are named in a notice.
//!
//! Points with a NaN coordinate (an organized cloud's pixels without a return, written when
//! PCL's `is_dense` is false) are dropped, with a notice that counts them. A `VIEWPOINT` whose
//! translation is not the origin (PCL's default, which most writers leave) is the sensor's
//! position: the cloud becomes one registered scan ([`PointCloud::scans`]), so its normals are
//! turned to face it. `DATA binary_compressed` (LZF) is not read; the error says how to convert
//! it.

use crate::cloud::{PointCloud, ScanOrigin};
use crate::import::{ImportError, Lines};

/// Whether the bytes start like a PCD header (after `#` comment lines).
pub(crate) fn looks_like_pcd(bytes: &[u8]) -> bool {
    let mut lines = Lines::new(&bytes[..bytes.len().min(1024)], 1);
    while let Some(Ok((_, text))) = lines.next_line("") {
        let text = text.trim();
        if text.starts_with("# .PCD") {
            return true;
        }
        if !text.is_empty() && !text.starts_with('#') {
            return text.starts_with("VERSION ") || text.starts_with("FIELDS ");
        }
    }
    false
}

/// One field of the header: its name, byte size, type letter (F, U, I) and count.
struct Field {
    name: String,
    size: usize,
    kind: u8,
    count: usize,
}

/// Reads a PCD file; what it reads but does not keep goes to `notices`.
pub(crate) fn read(
    bytes: &[u8],
    path: &str,
    notices: &mut Vec<String>,
) -> Result<(bool, PointCloud), ImportError> {
    let bad = |line: usize, message: String| ImportError::BadHeader {
        path: path.to_owned(),
        line,
        message,
    };
    let mut lines = Lines::new(bytes, 1);
    let mut header: std::collections::HashMap<String, (usize, Vec<String>)> = Default::default();
    let (data_line, data_kind) = loop {
        let Some(line) = lines.next_line(path) else {
            return Err(ImportError::Truncated {
                path: path.to_owned(),
                detail: "the pcd header has no DATA line".to_owned(),
            });
        };
        let (number, text) = line?;
        let text = text.trim();
        if text.is_empty() || text.starts_with('#') {
            continue;
        }
        let mut words = text.split_ascii_whitespace();
        let key = words.next().unwrap_or_default().to_ascii_uppercase();
        let values: Vec<String> = words.map(str::to_owned).collect();
        if key == "DATA" {
            break (number, values.first().cloned().unwrap_or_default());
        }
        header.insert(key, (number, values));
    };
    let body = lines.rest;
    let get = |key: &str| {
        header.get(key).ok_or_else(|| ImportError::BadLayout {
            path: path.to_owned(),
            message: format!("the pcd header has no {key} line; add it before DATA"),
        })
    };
    let (fields_line, names) = get("FIELDS")?;
    let numbers = |key: &str| -> Result<Vec<usize>, ImportError> {
        match header.get(key) {
            None if key == "COUNT" => Ok(vec![1; names.len()]),
            None => Err(bad(
                *fields_line,
                format!("no {key} line; a pcd header needs one value per field"),
            )),
            Some((line, v)) => {
                let parsed: Option<Vec<usize>> = v.iter().map(|t| t.parse().ok()).collect();
                match parsed {
                    Some(p) if p.len() == names.len() => Ok(p),
                    _ => Err(bad(
                        *line,
                        format!(
                            "{key} needs {} whole numbers, one per field of FIELDS",
                            names.len()
                        ),
                    )),
                }
            }
        }
    };
    let sizes = numbers("SIZE")?;
    let counts = numbers("COUNT")?;
    if counts.iter().any(|&c| c == 0 || c > 1 << 16) {
        return Err(bad(
            header.get("COUNT").map_or(*fields_line, |(l, _)| *l),
            "COUNT needs values from 1 to 65536".to_owned(),
        ));
    }
    let (type_line, types) = get("TYPE")?;
    if types.len() != names.len() {
        return Err(bad(
            *type_line,
            format!(
                "TYPE needs {} letters (F, U or I), one per field",
                names.len()
            ),
        ));
    }
    let mut fields = Vec::with_capacity(names.len());
    for (i, name) in names.iter().enumerate() {
        let kind = types[i].as_bytes().first().copied().unwrap_or(b'?');
        let valid = match kind {
            b'F' => matches!(sizes[i], 4 | 8),
            b'U' | b'I' => matches!(sizes[i], 1 | 2 | 4 | 8),
            _ => false,
        };
        if !valid {
            return Err(bad(
                *type_line,
                format!(
                    "field `{name}` has TYPE {} and SIZE {}; use F with 4 or 8, U or I with 1, \
                     2, 4 or 8",
                    types[i], sizes[i]
                ),
            ));
        }
        fields.push(Field {
            name: name.clone(),
            size: sizes[i],
            kind,
            count: counts[i],
        });
    }
    let n_points: usize = match header.get("POINTS") {
        Some((line, v)) => v
            .first()
            .and_then(|t| t.parse().ok())
            .ok_or_else(|| bad(*line, "POINTS needs one whole number".to_owned()))?,
        None => {
            let dim = |key: &str| -> Option<usize> { header.get(key)?.1.first()?.parse().ok() };
            dim("WIDTH")
                .zip(dim("HEIGHT"))
                .and_then(|(w, h)| w.checked_mul(h))
                .ok_or_else(|| bad(*fields_line, "no POINTS and no WIDTH and HEIGHT".to_owned()))?
        }
    };
    // The value index of each field's first value in a record, counting `count` values each.
    let mut first_value = Vec::with_capacity(fields.len());
    let mut n_values = 0;
    for f in &fields {
        first_value.push(n_values);
        n_values += f.count;
    }
    let index_of = |name: &str| {
        fields
            .iter()
            .position(|f| f.name == name && f.count == 1)
            .map(|i| first_value[i])
    };
    let Some(xyz) = ["x", "y", "z"]
        .iter()
        .map(|n| index_of(n))
        .collect::<Option<Vec<_>>>()
    else {
        return Err(bad(
            *fields_line,
            "FIELDS lacks x, y or z (each of count 1); a point cloud needs all three".to_owned(),
        ));
    };
    let normal = ["normal_x", "normal_y", "normal_z"]
        .iter()
        .map(|n| index_of(n))
        .collect::<Option<Vec<_>>>();
    // A packed colour is four bytes: a float's or an integer's bits.
    let rgb_field = fields
        .iter()
        .position(|f| (f.name == "rgb" || f.name == "rgba") && f.count == 1 && f.size == 4);
    let rgb = rgb_field.map(|i| first_value[i]);
    let rgb_is_float = rgb_field.is_some_and(|i| fields[i].kind == b'F');
    let intensity_at = index_of("intensity");
    let used: Vec<&str> = [
        "x", "y", "z", "normal_x", "normal_y", "normal_z", "rgb", "rgba",
    ]
    .into_iter()
    .chain(intensity_at.map(|_| "intensity"))
    .collect();
    let skipped: Vec<&str> = fields
        .iter()
        .map(|f| f.name.as_str())
        .filter(|n| !used.contains(n) && *n != "_")
        .collect();
    if !skipped.is_empty() {
        notices.push(format!(
            "pcd fields not read: {}; the cloud keeps x y z{}{}{}",
            skipped.join(", "),
            if normal.is_some() { ", normals" } else { "" },
            if rgb.is_some() { ", colour" } else { "" },
            if intensity_at.is_some() {
                ", intensity"
            } else {
                ""
            },
        ));
    }

    // Every record as its values (f64), and the raw bits of the colour value.
    let mut values = vec![0.0; n_values];
    let mut colour_bits = 0_u32;
    let mut cloud = PointCloud::default();
    let mut normals = Vec::new();
    let mut colours = Vec::new();
    let mut intensity = Vec::new();
    let mut dropped = 0_usize;
    let mut keep_record = |values: &[f64], colour_bits: u32| {
        let p = [values[xyz[0]], values[xyz[1]], values[xyz[2]]];
        if p.iter().any(|c| c.is_nan()) {
            dropped += 1;
            return;
        }
        cloud.points.push(p);
        if let Some(n) = &normal {
            normals.push([values[n[0]], values[n[1]], values[n[2]]]);
        }
        if rgb.is_some() {
            let [b, g, r, _] = colour_bits.to_le_bytes();
            colours.push([r, g, b].map(|c| u16::from(c) * 257));
        }
        if let Some(i) = intensity_at {
            intensity.push(values[i] as f32);
        }
    };
    let binary = match data_kind.as_str() {
        "ascii" => false,
        "binary" => true,
        other => {
            return Err(bad(
                data_line,
                format!(
                    "DATA {other} is not read (ascii and binary are); convert the file with \
                     `pcl_convert_pcd_ascii_binary IN.pcd OUT.pcd 1` (binary)"
                ),
            ))
        }
    };
    if binary {
        let record: usize = fields.iter().map(|f| f.size * f.count).sum();
        let needed = n_points.saturating_mul(record);
        if body.len() < needed {
            return Err(ImportError::Truncated {
                path: path.to_owned(),
                detail: format!(
                    "the header declares {n_points} points of {record} bytes but the body holds \
                     {} bytes",
                    body.len()
                ),
            });
        }
        for chunk in body[..needed].chunks_exact(record.max(1)) {
            let mut at = 0;
            let mut v = 0;
            for f in &fields {
                for _ in 0..f.count {
                    let raw = &chunk[at..at + f.size];
                    values[v] = decode(raw, f.kind);
                    if Some(v) == rgb {
                        colour_bits = u32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]);
                    }
                    at += f.size;
                    v += 1;
                }
            }
            keep_record(&values, colour_bits);
        }
    } else {
        let mut read = 0;
        let mut body_lines = Lines::new(body, data_line + 1);
        while let Some(line) = body_lines.next_line(path) {
            let (number, text) = line?;
            let text = text.trim();
            if text.is_empty() {
                continue;
            }
            let tokens: Vec<&str> = text.split_ascii_whitespace().collect();
            if tokens.len() != n_values {
                return Err(ImportError::Malformed {
                    path: path.to_owned(),
                    line: number,
                    message: format!(
                        "{} values on a point line but FIELDS and COUNT make {n_values}",
                        tokens.len()
                    ),
                });
            }
            for (v, token) in tokens.iter().enumerate() {
                values[v] = token.parse::<f64>().map_err(|_| ImportError::Malformed {
                    path: path.to_owned(),
                    line: number,
                    message: format!("`{token}` is not a number"),
                })?;
            }
            if let Some(c) = rgb {
                // A float field holds the colour's bits; an integer field holds it as a number.
                colour_bits = if rgb_is_float {
                    tokens[c].parse::<f32>().map_or(0, f32::to_bits)
                } else {
                    values[c] as u32
                };
            }
            keep_record(&values, colour_bits);
            read += 1;
        }
        if read != n_points {
            return Err(ImportError::HeaderCountMismatch {
                path: path.to_owned(),
                what: "POINTS".to_owned(),
                declared: n_points as u64,
                found: read as u64,
            });
        }
    }
    if dropped > 0 {
        notices.push(format!(
            "{dropped} points with NaN coordinates (pixels of an organized cloud without a \
             return) are dropped"
        ));
    }
    let n_kept = cloud.points.len();
    cloud.normals = normal.is_some().then_some(normals);
    cloud.colours = rgb.is_some().then_some(colours);
    cloud.intensity = intensity_at.is_some().then_some(intensity);
    if let Some((_, v)) = header.get("VIEWPOINT") {
        let t: Vec<f64> = v.iter().take(3).filter_map(|t| t.parse().ok()).collect();
        if t.len() == 3 && t.iter().any(|&c| c != 0.0) && t.iter().all(|c| c.is_finite()) {
            cloud.scans = Some(vec![ScanOrigin {
                sensor: [t[0], t[1], t[2]],
                n_points: n_kept,
            }]);
        }
    }
    Ok((binary, cloud))
}

/// One little-endian value of `raw.len()` bytes and type `kind` (F, U, I) as f64.
fn decode(raw: &[u8], kind: u8) -> f64 {
    let mut b = [0_u8; 8];
    b[..raw.len()].copy_from_slice(raw);
    match (kind, raw.len()) {
        (b'F', 4) => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        (b'F', _) => f64::from_le_bytes(b),
        (b'U', _) => u64::from_le_bytes(b) as f64,
        (_, n) => {
            // Sign-extend an n-byte integer.
            let shift = 64 - 8 * n as u32;
            ((i64::from_le_bytes(b) << shift) >> shift) as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str = "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n\
                          FIELDS x y z rgb intensity\nSIZE 4 4 4 4 2\nTYPE F F F F U\n\
                          COUNT 1 1 1 1 1\nWIDTH 3\nHEIGHT 1\nVIEWPOINT 1 2 3 1 0 0 0\nPOINTS 3\n";

    fn points() -> Vec<([f32; 3], u32, u16)> {
        vec![
            ([0.5, 1.0, -2.0], 0x00ff_0001, 7),
            ([f32::NAN, 0.0, 0.0], 0, 0),
            ([3.0, 4.0, 5.25], 0x0000_ff00, 65535),
        ]
    }

    fn check(bytes: &[u8], binary: bool) {
        let mut notices = Vec::new();
        assert!(looks_like_pcd(bytes));
        let (is_binary, cloud) = read(bytes, "t.pcd", &mut notices).unwrap();
        assert_eq!(is_binary, binary);
        assert_eq!(cloud.points, vec![[0.5, 1.0, -2.0], [3.0, 4.0, 5.25]]);
        assert_eq!(cloud.colours, Some(vec![[65535, 0, 257], [0, 65535, 0]]));
        assert_eq!(cloud.intensity, Some(vec![7.0, 65535.0]));
        assert_eq!(cloud.scans.unwrap()[0].sensor, [1.0, 2.0, 3.0]);
        assert!(notices[0].contains("1 points with NaN"), "{notices:?}");
    }

    #[test]
    fn ascii_and_binary_bodies_read_the_same() {
        let mut ascii = format!("{HEADER}DATA ascii\n");
        for (p, rgb, i) in points() {
            let rgb = f32::from_bits(rgb);
            ascii += &format!("{} {} {} {rgb:e} {i}\n", p[0], p[1], p[2]);
        }
        check(ascii.as_bytes(), false);
        let mut binary = format!("{HEADER}DATA binary\n").into_bytes();
        for (p, rgb, i) in points() {
            for c in p {
                binary.extend_from_slice(&c.to_le_bytes());
            }
            binary.extend_from_slice(&rgb.to_le_bytes());
            binary.extend_from_slice(&i.to_le_bytes());
        }
        check(&binary, true);
        // One byte short.
        let e = read(&binary[..binary.len() - 1], "t.pcd", &mut Vec::new()).unwrap_err();
        assert!(matches!(e, ImportError::Truncated { .. }), "{e}");
    }

    #[test]
    fn normals_and_header_errors() {
        let text = "VERSION .7\nFIELDS x y z normal_x normal_y normal_z curvature\n\
                    SIZE 4 4 4 4 4 4 4\nTYPE F F F F F F F\nWIDTH 1\nHEIGHT 1\nDATA ascii\n\
                    1 2 3 0 0 1 0.5\n";
        let mut notices = Vec::new();
        let (_, cloud) = read(text.as_bytes(), "n.pcd", &mut notices).unwrap();
        assert_eq!(cloud.normals, Some(vec![[0.0, 0.0, 1.0]]));
        assert!(cloud.scans.is_none() && cloud.colours.is_none());
        assert!(notices[0].contains("curvature"), "{notices:?}");
        let compressed = text.replace("DATA ascii", "DATA binary_compressed");
        let e = read(compressed.as_bytes(), "c.pcd", &mut notices).unwrap_err();
        assert!(
            e.to_string().contains("pcl_convert_pcd_ascii_binary"),
            "{e}"
        );
        let no_z = text.replace("FIELDS x y z ", "FIELDS x y w ");
        let e = read(no_z.as_bytes(), "z.pcd", &mut notices).unwrap_err();
        assert!(e.to_string().contains("lacks x, y or z"), "{e}");
    }
}
