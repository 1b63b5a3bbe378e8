//! Blender's own importers on the files `run` writes (Blender 5.0 as the `bpy` module, through
//! tools/validate/blender.py): each file makes one smooth-shaded mesh object of the right size,
//! standing upright with `--up`, with the scan's colours.
//!
//! - `--units mm`: the shared patella's glb comes in at its real size in metres (4.3 × 4.7 ×
//!   2.4 cm, the scan's extent), the PLY in millimetres, which its header records.
//! - `--up y`: the glb and the PLY of a Y-up scan land on the same place in Blender, the scan's
//!   up axis on Blender's +Z; without `--up` the PLY keeps the scan's own coordinates.
//! - Colour: an RGB scan's colours come through both files as a colour attribute whose mean
//!   sRGB value is the scan's.

use std::fmt::Write as _;
use std::fs;
use std::path::Path;

use crate::export::{run, validator};
use crate::fixtures::{run_ok, shared};

/// Blender's description of each file (see tools/validate/blender.py), or `None` when Blender
/// is not installed and CI is not set.
fn blender(files: &[&Path]) -> Option<Vec<serde_json::Value>> {
    let command = validator("blender")?;
    Some(run(command, files))
}

fn triple(v: &serde_json::Value) -> [f64; 3] {
    std::array::from_fn(|a| v[a].as_f64().unwrap())
}

/// Writes `dir/egg.ply`: 4,000 points of an ellipsoid standing along +Y (semi-axes 1, 2, 0.7,
/// centre (0.5, 3, −1)) with exact outward normals and a colour that grows redder upwards.
/// Returns the path and the mean sRGB colour of the points (0–1).
fn y_up_coloured_scan(dir: &Path) -> (std::path::PathBuf, [f64; 3]) {
    let n = 4000;
    let axes = [1.0, 2.0, 0.7];
    let centre = [0.5, 3.0, -1.0];
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut body = String::new();
    let mut sum = [0.0f64; 3];
    for i in 0..n {
        let h = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let r = (1.0 - h * h).sqrt();
        let t = golden * i as f64;
        // The unit sphere direction (x, h, z), stretched; the normal is the gradient of
        // Σ (p/a)², the direction divided by the axes.
        let d = [r * t.cos(), h, r * t.sin()];
        let p: [f64; 3] = std::array::from_fn(|a| centre[a] + axes[a] * d[a]);
        let g: [f64; 3] = std::array::from_fn(|a| d[a] / axes[a]);
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        let red = ((h + 1.0) * 127.5).round() as u8;
        let colour = [red, 64, 255 - red];
        for a in 0..3 {
            sum[a] += f64::from(colour[a]) / 255.0;
        }
        let _ = writeln!(
            body,
            "{} {} {} {} {} {} {} {} {}",
            p[0],
            p[1],
            p[2],
            g[0] / len,
            g[1] / len,
            g[2] / len,
            colour[0],
            colour[1],
            colour[2]
        );
    }
    let header = format!(
        "ply\nformat ascii 1.0\nelement vertex {n}\nproperty double x\nproperty double y\n\
         property double z\nproperty double nx\nproperty double ny\nproperty double nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    );
    let path = dir.join("egg.ply");
    fs::write(&path, header + &body).unwrap();
    (path, sum.map(|s| s / n as f64))
}

#[test]
fn a_y_up_scan_stands_upright_in_blender_with_its_colours() {
    let dir = tempfile::tempdir().unwrap();
    let (scan, mean_colour) = y_up_coloured_scan(dir.path());
    let upright = dir.path().join("upright");
    let plain = dir.path().join("plain");
    let formats = ["--formats", "glb,ply,json", "--no-cache"];
    run_ok(&scan, &upright, &[&["--up", "y"], &formats[..]].concat());
    run_ok(&scan, &plain, &formats);
    let files = [
        upright.join("mesh.glb"),
        upright.join("mesh.ply"),
        plain.join("mesh.glb"),
        plain.join("mesh.ply"),
    ];
    let Some(seen) = blender(&files.iter().map(|f| f.as_path()).collect::<Vec<_>>()) else {
        return;
    };
    for file in &seen {
        assert_eq!(file["objects"], 1, "{file}");
        assert_eq!(file["smooth"], true, "{file}");
        let colour = triple(&file["colour_mean"]);
        for a in 0..3 {
            // The mesh's vertices interpolate the scan's colours: their mean is the scan's.
            assert!(
                (colour[a] - mean_colour[a]).abs() <= 0.03,
                "colour {colour:?} vs the scan's {mean_colour:?}: {file}"
            );
        }
    }
    let (glb, ply) = (&seen[0], &seen[1]);
    assert_eq!(glb["vertices"], ply["vertices"]);
    assert_eq!(glb["faces"], ply["faces"]);
    // Both files land on the same place, the scan's height (4 units along +Y) on Blender's +Z.
    for key in ["min", "max"] {
        let (g, p) = (triple(&glb[key]), triple(&ply[key]));
        for a in 0..3 {
            assert!((g[a] - p[a]).abs() <= 1e-5, "{key}: glb {g:?}, ply {p:?}");
        }
    }
    let size = triple(&glb["dimensions"]);
    assert!(
        (size[2] - 4.0).abs() < 0.05 && size[0] < 2.1 && size[1] < 2.1,
        "upright: {size:?}"
    );
    // Without --up the glb is the same (the scan is taken as Y-up), while the PLY keeps the
    // scan's coordinates: Blender shows it lying along its +Y.
    assert_eq!(triple(&seen[2]["dimensions"]), size);
    let lying = triple(&seen[3]["dimensions"]);
    assert!((lying[1] - 4.0).abs() < 0.05, "input frame: {lying:?}");
}

#[test]
fn the_patella_in_millimetres_imports_at_its_size_in_metres() {
    let Some(scan) = shared("data/patella_vhf_left.ply", "the patella's size in Blender") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    run_ok(
        &scan,
        &out,
        &["--units", "mm", "--formats", "glb,ply,json", "--no-cache"],
    );
    let Some(seen) = blender(&[&out.join("mesh.glb"), &out.join("mesh.ply")]) else {
        return;
    };
    let (glb, ply) = (
        triple(&seen[0]["dimensions"]),
        triple(&seen[1]["dimensions"]),
    );
    // The scan's extent is 42.8 × 24.0 × 46.9 mm (x, y, z); Blender turns glTF's +Y up to +Z.
    for (got, cm) in glb.iter().zip([4.28, 4.69, 2.40]) {
        assert!(
            (got * 100.0 - cm).abs() <= 0.05,
            "glb in Blender: {glb:?} m"
        );
    }
    // The PLY keeps millimetres (its header says `comment units mm`) and the scan's frame.
    for (got, mm) in ply.iter().zip([42.8, 24.0, 46.9]) {
        assert!((got - mm).abs() <= 0.5, "ply in Blender: {ply:?}");
    }
    assert!(fs::read(out.join("mesh.ply"))
        .unwrap()
        .windows(17)
        .any(|w| w == b"comment units mm\n"));
}
