//! The signed-distance volumes of `run` (`--formats vdb,npy`): the dense grid against the
//! analytic distance of a sphere, byte-identical reruns whatever the thread count, and the files
//! read back by NumPy (`tools/validate/npy.py`) and by Blender and its OpenVDB module
//! (`tools/validate/vdb_blender.py`) on the sphere and on the Stanford bunny.

use std::fs;
use std::path::Path;

use crate::export::{run, validator};
use crate::fixtures::{flags, run_ok, shared, sphere_xyz};

/// Shape and values of a `.npy` file of float32 in C order, read by the layout of NumPy's
/// format 1.0.
fn read_npy(path: &Path) -> ([usize; 3], Vec<f32>) {
    let bytes = fs::read(path).unwrap();
    assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
    let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    assert_eq!((10 + header_len) % 64, 0, "data aligned to 64 bytes");
    let header = std::str::from_utf8(&bytes[10..10 + header_len]).unwrap();
    assert!(header.contains("'descr': '<f4'") && header.contains("'fortran_order': False"));
    let shape_text = header.split("'shape': (").nth(1).unwrap();
    let shape_text = shape_text.split(')').next().unwrap();
    let dims: Vec<usize> = shape_text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().unwrap())
        .collect();
    let shape = [dims[0], dims[1], dims[2]];
    let values: Vec<f32> = bytes[10 + header_len..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(values.len(), shape.iter().product::<usize>());
    (shape, values)
}

fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&fs::read(path).unwrap()).unwrap()
}

/// The flags of the sphere runs: the global mode's polynomial of degree 2 without ridge
/// weight, which fits the exact sphere points to well under the tolerance below.
const SPHERE_FLAGS: &str =
    "--mode global --degree 2 --kappa 0 --formats glb,ply,json,vdb,npy --voxel-size 0.05 --no-cache";

/// Largest difference allowed between a voxel's value and the sphere's analytic signed
/// distance: the fit's error plus the mesh's chord error (depth 7 over a box of side ~5: edges
/// under 0.07, chord error (0.07)²/(8·2) ≈ 3e-4), with room: 0.25% of the radius.
const SPHERE_TOLERANCE: f64 = 5e-3;

#[test]
fn sphere_volumes_match_the_analytic_distance_and_rerun_identically() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 3000, "");
    let out = dir.path().join("out");
    run_ok(&input, &out, &flags(SPHERE_FLAGS));

    let side = read_json(&out.join("volume.json"));
    let h = side["voxel_size"].as_f64().unwrap();
    assert_eq!(h, 0.05);
    let origin: Vec<f64> = side["origin"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let (shape, values) = read_npy(&out.join("volume.npy"));
    let side_shape: Vec<usize> = side["shape"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as usize)
        .collect();
    assert_eq!(side_shape, shape);
    // The sphere: centre (1, 2, 3), radius 2 (fixtures::sphere_xyz).
    let mut worst: f64 = 0.0;
    let (mut inside, mut wrong_sign) = (0, 0);
    for i in 0..shape[0] {
        for j in 0..shape[1] {
            for k in 0..shape[2] {
                let p = [i, j, k]
                    .iter()
                    .zip(&origin)
                    .map(|(&n, o)| o + h * n as f64)
                    .collect::<Vec<_>>();
                let truth = ((p[0] - 1.0).powi(2) + (p[1] - 2.0).powi(2) + (p[2] - 3.0).powi(2))
                    .sqrt()
                    - 2.0;
                let v = f64::from(values[(i * shape[1] + j) * shape[2] + k]);
                worst = worst.max((v - truth).abs());
                if truth.abs() > SPHERE_TOLERANCE && (v < 0.0) != (truth < 0.0) {
                    wrong_sign += 1;
                }
                inside += usize::from(v < 0.0);
            }
        }
    }
    assert!(worst < SPHERE_TOLERANCE, "worst error {worst}");
    assert_eq!(wrong_sign, 0);
    // The ball holds 4/3·π·2³/h³ ≈ 268,000 voxel centres.
    let ball = 4.0 / 3.0 * std::f64::consts::PI * 8.0 / h.powi(3);
    assert!(
        (inside as f64 - ball).abs() < 0.01 * ball,
        "{inside} inside"
    );

    // Rerun on one thread: the same bytes.
    let again = dir.path().join("again");
    run_ok(&input, &again, &flags(&format!("{SPHERE_FLAGS} -j 1")));
    for name in ["volume.vdb", "volume.npy", "volume.json"] {
        assert!(
            fs::read(out.join(name)).unwrap() == fs::read(again.join(name)).unwrap(),
            "{name} differs between runs"
        );
    }

    // NumPy reads it back, and finds the same.
    if let Some(npy) = validator("npy") {
        let sphere = "1,2,3,2".to_string();
        let tolerance = SPHERE_TOLERANCE.to_string();
        let report = run(
            npy,
            &[
                &out.join("volume.json"),
                Path::new("--sphere"),
                Path::new(&sphere),
                Path::new("--tolerance"),
                Path::new(&tolerance),
            ],
        );
        assert_eq!(report[0]["problems"], serde_json::json!([]));
        assert_eq!(report[0]["sign_errors"], 0);
        assert!(report[0]["max_error"].as_f64().unwrap() < SPHERE_TOLERANCE);
    }

    // Blender imports the vdb, meshes it, and finds the PLY's surface; OpenVDB reads the same
    // values as the npy holds.
    if let Some(blender) = validator("vdb_blender") {
        let report = run(
            blender,
            &[
                &out.join("volume.vdb"),
                &out.join("mesh.ply"),
                &out.join("volume.json"),
                Path::new("--glb"),
                &out.join("mesh.glb"),
            ],
        );
        let r = &report[0];
        assert_eq!(r["problems"], serde_json::json!([]), "{r}");
        assert!(r["volume_to_ply_voxels"]["max"].as_f64().unwrap() < 1.0);
        assert!(r["glb_to_volume_voxels"]["max"].as_f64().unwrap() < 1.0);
        assert_eq!(r["sign_mismatches"], 0);
    }
}

#[test]
fn vdb_in_metres_and_z_up_overlaps_the_ply_in_blender() {
    // With --units mm the vdb's transform and values are in metres; with --up z it stays in the
    // input's axes (Blender's frame). The checker puts the PLY in the same frame.
    let Some(blender) = validator("vdb_blender") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 3000, "");
    let out = dir.path().join("out");
    run_ok(
        &input,
        &out,
        &flags(&format!("{SPHERE_FLAGS} --units mm --up z")),
    );
    assert_eq!(read_json(&out.join("volume.json"))["units"], "mm");
    let report = run(
        blender,
        &[
            &out.join("volume.vdb"),
            &out.join("mesh.ply"),
            &out.join("volume.json"),
            Path::new("--up"),
            Path::new("z"),
            Path::new("--metres-per-unit"),
            Path::new("0.001"),
            Path::new("--glb"),
            &out.join("mesh.glb"),
        ],
    );
    assert_eq!(
        report[0]["problems"],
        serde_json::json!([]),
        "{}",
        report[0]
    );
    let m = &report[0]["matrix_object"];
    // Blender keeps the matrix in float32.
    assert!((m[0][0].as_f64().unwrap() - 5e-5).abs() < 1e-10, "{m}");
}

#[test]
fn bunny_vdb_in_blender() {
    // The default (detail) run of the bunny on a grid of 128 voxels along the meshing box's
    // longest side (0.187; the default grid of 256, which the unit test `grid_limits_and_threads`
    // checks, takes 8 times as long to fill the dense npy): Blender's mesh of the vdb against
    // mesh.ply, OpenVDB's values against the npy. The volume measures the mesh before the
    // trim, which leaves a closed scan whole but fairs the patches over its holes (the
    // bunny's open base moves by up to 2 voxels here): `--trim off` writes that mesh.
    let Some(scan) = shared("data/bunny_zipper.ply", "the bunny volume check") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    run_ok(
        &scan,
        &out,
        &flags("--formats ply,vdb,npy --voxel-size 0.00146 --no-cache --trim off"),
    );
    let side = read_json(&out.join("volume.json"));
    let shape = side["shape"].as_array().unwrap();
    assert_eq!(
        shape.iter().map(|n| n.as_u64().unwrap()).max(),
        Some(128),
        "{side}"
    );
    if let Some(blender) = validator("vdb_blender") {
        let report = run(
            blender,
            &[
                &out.join("volume.vdb"),
                &out.join("mesh.ply"),
                &out.join("volume.json"),
            ],
        );
        assert_eq!(
            report[0]["problems"],
            serde_json::json!([]),
            "{}",
            report[0]
        );
    }
}
