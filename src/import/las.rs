//! Stage `import`, LAS/LAZ reader: an ASPRS LAS file, plain or LASzip-compressed → [`PointCloud`].
//!
//! Input: the whole file as bytes (it starts with `LASF`). Output: one point per point record,
//! in file order, in the file's real coordinates (each stored integer times the header's scale
//! plus its offset, as `f64`), with the records' colours and intensities when the file has them,
//! and no normals or triangles.
//!
//! The `las` crate parses the header and the records, and its `laz` feature (the pure-Rust `laz`
//! crate) decompresses LAZ. LAS has no normals and no scanner position (its scan angle is an
//! angle from nadir, not a position), so the normals stage estimates and orients the normals as
//! for any cloud without them. What the records hold beyond position, colour and intensity
//! (classification, returns, GPS time, …) is named in a notice.
//!
//! Intensity is kept when some point's is not 0 (every point format has the field, and 0
//! everywhere means the producer did not record it); colour is kept when the point format has
//! it (formats 2, 3, 5, 7, 8, 10), as the 16-bit values stored.

use std::io::Cursor;

use crate::cloud::PointCloud;
use crate::import::{ImportError, ScanFormat};

/// Reads a LAS or LAZ file; what it reads but does not keep goes to `notices`.
pub(crate) fn read(
    bytes: &[u8],
    path: &str,
    notices: &mut Vec<String>,
) -> Result<(ScanFormat, PointCloud), ImportError> {
    // The reader wants to own its source ('static), so it gets a copy of the bytes.
    let mut reader =
        ::las::Reader::new(Cursor::new(bytes.to_vec())).map_err(|e| ImportError::BadLayout {
            path: path.to_owned(),
            message: format!(
                "not a readable las file: {e}; export the scan again as LAS 1.0–1.4 (or LAZ)"
            ),
        })?;
    let header = reader.header().clone();
    let format = *header.point_format();
    let scan_format = if format.is_compressed {
        ScanFormat::Laz
    } else {
        ScanFormat::Las
    };
    let declared = header.number_of_points();
    // Read in chunks, so that a header declaring more points than the file holds costs no more
    // memory than the points that are there.
    const CHUNK: u64 = 1 << 20;
    let capacity = usize::try_from(declared.min(CHUNK)).unwrap_or(0);
    let mut points: Vec<[f64; 3]> = Vec::with_capacity(capacity);
    let mut intensity: Vec<f32> = Vec::with_capacity(capacity);
    let mut colours: Vec<[u16; 3]> = Vec::new();
    let mut data = ::las::PointDataBuilder::new().for_header(&header).build();
    while (points.len() as u64) < declared {
        let truncated = |e: &dyn std::fmt::Display, n: usize| ImportError::Truncated {
            path: path.to_owned(),
            detail: format!(
                "the header declares {declared} point records and reading stops after {n}: {e}"
            ),
        };
        let n = reader
            .fill_points(CHUNK, &mut data)
            .map_err(|e| truncated(&e, points.len()))?;
        if n == 0 {
            return Err(truncated(&"no more records", points.len()));
        }
        points.extend(
            data.x()
                .zip(data.y())
                .zip(data.z())
                .map(|((x, y), z)| [x, y, z]),
        );
        intensity.extend(data.intensity().map(f32::from));
        if format.has_color {
            for point in data.points() {
                let point = point.map_err(|e| ImportError::BadLayout {
                    path: path.to_owned(),
                    message: format!(
                        "point record {} cannot be read: {e}; export the scan again",
                        colours.len()
                    ),
                })?;
                let c = point.color.unwrap_or_default();
                colours.push([c.red, c.green, c.blue]);
            }
        }
    }
    let intensity = intensity.iter().any(|&i| i != 0.0).then_some(intensity);
    let colours = format.has_color.then_some(colours);
    let mut skipped = vec!["classification", "returns", "scan angle", "point source"];
    if format.has_gps_time {
        skipped.push("gps time");
    }
    if format.has_nir {
        skipped.push("nir");
    }
    if format.has_waveform {
        skipped.push("waveform");
    }
    if format.extra_bytes > 0 {
        skipped.push("extra bytes");
    }
    let kept = match (colours.is_some(), intensity.is_some()) {
        (true, true) => "x y z, colour and intensity",
        (true, false) => "x y z and colour",
        (false, true) => "x y z and intensity",
        (false, false) => "x y z",
    };
    notices.push(format!(
        "point record fields not read: {}; the cloud keeps {kept}",
        skipped.join(", ")
    ));
    Ok((
        scan_format,
        PointCloud {
            points,
            colours,
            intensity,
            ..Default::default()
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(points: &[::las::Point], format: u8, compressed: bool) -> Vec<u8> {
        let mut builder = ::las::Builder::from((1, 2));
        builder.point_format = ::las::point::Format::new(format).unwrap();
        builder.point_format.is_compressed = compressed;
        builder.transforms = ::las::Vector {
            x: ::las::Transform {
                scale: 0.001,
                offset: 500_000.0,
            },
            y: ::las::Transform {
                scale: 0.001,
                offset: 4_000_000.0,
            },
            z: ::las::Transform {
                scale: 0.01,
                offset: 0.0,
            },
        };
        let mut writer =
            ::las::Writer::new(Cursor::new(Vec::new()), builder.into_header().unwrap()).unwrap();
        for p in points {
            writer.write_point(p.clone()).unwrap();
        }
        writer.into_inner().unwrap().into_inner()
    }

    fn points() -> Vec<::las::Point> {
        (0..50)
            .map(|i| ::las::Point {
                x: 500_000.0 + 0.125 * f64::from(i),
                y: 4_000_000.0 - 0.001 * f64::from(i),
                z: 12.34 + 0.01 * f64::from(i),
                intensity: (i * 1000) as u16,
                color: Some(::las::Color::new(i as u16, 257 * i as u16, 65535)),
                gps_time: Some(f64::from(i)),
                ..Default::default()
            })
            .collect()
    }

    #[test]
    fn las_and_laz_read_real_coordinates_colours_and_intensity() {
        for compressed in [false, true] {
            let bytes = write(&points(), 3, compressed);
            let mut notices = Vec::new();
            let (format, cloud) = read(&bytes, "t.las", &mut notices).unwrap();
            let expected = if compressed {
                ScanFormat::Laz
            } else {
                ScanFormat::Las
            };
            assert_eq!(format, expected);
            assert_eq!(cloud.points.len(), 50);
            for (p, q) in cloud.points.iter().zip(points()) {
                assert!((p[0] - q.x).abs() <= 0.0005, "{p:?}");
                assert!((p[1] - q.y).abs() <= 0.0005, "{p:?}");
                assert!((p[2] - q.z).abs() <= 0.005, "{p:?}");
            }
            assert_eq!(cloud.colours.as_ref().unwrap()[7], [7, 7 * 257, 65535]);
            assert_eq!(cloud.intensity.as_ref().unwrap()[7], 7000.0);
            assert!(notices[0].contains("gps time"), "{notices:?}");
        }
    }

    #[test]
    fn format_0_has_no_colour_and_zero_intensity_is_dropped() {
        let plain: Vec<::las::Point> = points()
            .into_iter()
            .map(|p| ::las::Point {
                color: None,
                gps_time: None,
                intensity: 0,
                ..p
            })
            .collect();
        let (_, cloud) = read(&write(&plain, 0, false), "t.las", &mut Vec::new()).unwrap();
        assert!(cloud.colours.is_none() && cloud.intensity.is_none());
    }
}
