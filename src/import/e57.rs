//! Stage `import`, E57 reader: an ASTM E57 file of one or more registered scans → [`PointCloud`].
//!
//! Input: the whole file as bytes (it starts with `ASTM-E57`). Output: the points of every scan
//! in file order, each moved by its scan's pose into the file's common frame (spherical
//! coordinates converted to Cartesian first), with colour and intensity when every scan has
//! them, no normals and no triangles, and [`PointCloud::scans`]: each scan's scanner position
//! (the translation of its pose, since a scan's own frame has the scanner at its origin) and
//! point count, so that the normals stage turns each point's normal to face its own scanner.
//!
//! The `e57` crate (pure Rust) parses the file, checks its page checksums, and applies the poses.
//! Colour is normalized by the scan's colour limits and kept as 16-bit (1.0 ↦ 65535); intensity
//! is kept as stored. Points whose Cartesian coordinates are invalid or only a direction (no
//! range) are dropped, with a notice that counts them. When a scan has no pose, its frame is the
//! file's, but where its scanner stood is unknown, so no scan's position is used (a notice says
//! so) and the normals are oriented as for any cloud.

use std::io::Cursor;

use crate::cloud::{PointCloud, ScanOrigin};
use crate::import::ImportError;

/// Reads an E57 file; what it reads but does not keep goes to `notices`.
pub(crate) fn read(
    bytes: &[u8],
    path: &str,
    notices: &mut Vec<String>,
) -> Result<PointCloud, ImportError> {
    let unreadable = |what: String| ImportError::BadLayout {
        path: path.to_owned(),
        message: format!("not a readable e57 file: {what}; export the scans again as E57"),
    };
    let mut reader =
        ::e57::E57Reader::new(Cursor::new(bytes)).map_err(|e| unreadable(e.to_string()))?;
    let scans = reader.pointclouds();
    let all_colour = !scans.is_empty() && scans.iter().all(|s| s.has_color());
    let all_intensity = !scans.is_empty() && scans.iter().all(|s| s.has_intensity());
    let all_posed = scans.iter().all(|s| s.transform.is_some());
    let mut cloud = PointCloud::default();
    let mut colours = Vec::new();
    let mut intensity = Vec::new();
    let mut origins = Vec::with_capacity(scans.len());
    let mut no_range = 0_usize;
    for (index, scan) in scans.iter().enumerate() {
        let name = scan
            .name
            .as_deref()
            .map_or_else(String::new, |n| format!(" (`{n}`)"));
        let bad_scan = |e: ::e57::Error| unreadable(format!("scan {index}{name}: {e}"));
        let mut points = reader.pointcloud_simple(scan).map_err(bad_scan)?;
        points.apply_pose(true);
        points.spherical_to_cartesian(true);
        points.intensity_to_color(false);
        points.normalize_color(true);
        points.normalize_intensity(false);
        let before = cloud.points.len();
        for point in points {
            let point = point.map_err(bad_scan)?;
            let ::e57::CartesianCoordinate::Valid { x, y, z } = point.cartesian else {
                no_range += 1;
                continue;
            };
            cloud.points.push([x, y, z]);
            if all_colour {
                let c = point.color.map_or([0.0; 3], |c| [c.red, c.green, c.blue]);
                colours.push(c.map(|v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16));
            }
            if all_intensity {
                intensity.push(point.intensity.unwrap_or(0.0));
            }
        }
        let sensor = scan.transform.as_ref().map_or([0.0; 3], |t| {
            [t.translation.x, t.translation.y, t.translation.z]
        });
        origins.push(ScanOrigin {
            sensor,
            n_points: cloud.points.len() - before,
        });
    }
    if no_range > 0 {
        notices.push(format!(
            "{no_range} points without a valid Cartesian position (invalid, or a direction \
             without range) are dropped"
        ));
    }
    let partial = |what: &str, all: bool, any: bool| {
        (any && !all).then(|| format!("{what} is not kept: some scans have none"))
    };
    notices.extend(partial(
        "colour",
        all_colour,
        scans.iter().any(|s| s.has_color()),
    ));
    notices.extend(partial(
        "intensity",
        all_intensity,
        scans.iter().any(|s| s.has_intensity()),
    ));
    if all_posed {
        cloud.scans = Some(origins);
    } else {
        notices.push(
            "a scan without a pose gives no scanner position, so normals are oriented without \
             the scanners"
                .to_owned(),
        );
    }
    cloud.colours = all_colour.then_some(colours);
    cloud.intensity = all_intensity.then_some(intensity);
    Ok(cloud)
}
