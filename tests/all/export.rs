//! Export tests: every file format is checked by the tool it is for, not only by our readers.
//!
//! - glTF (.glb and .gltf + .bin): the Khronos glTF-Validator (npm `gltf-validator`) reports no
//!   errors and no warnings.
//! - PLY (binary and ASCII): Python `plyfile` reads it strictly and MeshLab (`pymeshlab`) loads
//!   it, finds the vertex quality, and reports a closed mesh watertight and two-manifold.
//! - OpenEXR slices: the OpenEXR Python bindings read each slice with one float32 channel `Y`,
//!   the expected size and header attributes, and no NaN; PNG previews decode at the right size.
//! - Distance: for a sphere of radius 1 the exact slices match |p − c| − 1 within 1e-4
//!   everywhere, Taubin's within 1e-4 near the surface.
//! - An unwritable output path is a clear error and leaves no file behind.
//!
//! The validators live in tools/validate (installed by `bash tools/install-validators.sh`).
//! When one is missing the test prints a notice and skips that check, unless the environment
//! variable CI is set, where a missing validator fails the test.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::Command;

use stablesurf::cloud::Aabb;
use stablesurf::distance::{slices, Axis, DistanceMethod, Slice, SliceParams};
use stablesurf::export::exr::{write_slice, ExrOptions};
use stablesurf::export::gltf::{
    write_glb, write_glb_coloured, write_gltf_coloured, GltfOptions, UpAxis,
};
use stablesurf::export::ply::{self, nearest_point_distances, PlyEncoding, PlyOptions};
use stablesurf::export::png::write_preview;
use stablesurf::export::units::LengthUnit;
use stablesurf::export::{write_atomic, ExportError};
use stablesurf::model::json::{read_model, write_model};
use stablesurf::{ImplicitModel, ImplicitPolynomial, TriangleMesh};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// A closed torus around z as a regular (u, v) grid: watertight, two-manifold, genus 1, wound
/// counter-clockwise seen from outside, with analytic unit normals.
fn torus_mesh(n_u: usize, n_v: usize, big: f64, small: f64) -> TriangleMesh {
    let mut mesh = TriangleMesh::default();
    for i in 0..n_u {
        let u = i as f64 / n_u as f64 * std::f64::consts::TAU;
        for j in 0..n_v {
            let v = j as f64 / n_v as f64 * std::f64::consts::TAU;
            let n = [v.cos() * u.cos(), v.cos() * u.sin(), v.sin()];
            let rho = big + small * v.cos();
            mesh.positions
                .push([rho * u.cos(), rho * u.sin(), small * v.sin()]);
            mesh.normals.push(n);
        }
    }
    let id = |i: usize, j: usize| ((i % n_u) * n_v + (j % n_v)) as u32;
    for i in 0..n_u {
        for j in 0..n_v {
            mesh.triangles
                .push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            mesh.triangles
                .push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    mesh
}

/// The sphere of radius 1 around `center`, stored with normalization scale `scale`.
fn unit_sphere(center: [f64; 3], scale: f64) -> ImplicitPolynomial {
    let rn = 1.0 / scale;
    let mut coefficients = vec![0.0; 10];
    coefficients[0] = -rn * rn;
    coefficients[4] = 1.0;
    coefficients[7] = 1.0;
    coefficients[9] = 1.0;
    ImplicitPolynomial {
        degree: 2,
        coefficients,
        center,
        scale,
    }
}

/// How to run one external validator, or `None` (after a notice, or a failure under CI).
/// `kind` names its script in tools/validate; `blender` and `vdb_blender` run in Blender's own
/// environment.
pub(crate) fn validator(kind: &str) -> Option<Command> {
    let dir = Path::new(ROOT).join("tools/validate");
    let (found, command) = match kind {
        "gltf" => {
            let ok = dir
                .join("node_modules/gltf-validator/package.json")
                .is_file()
                && Command::new("node").arg("--version").output().is_ok();
            let mut c = Command::new("node");
            c.arg(dir.join("gltf.mjs"));
            (ok, c)
        }
        // Blender's checks run in Blender's own Python (bpy).
        "blender" | "vdb_blender" => {
            let python = dir.join(".venv-blender/bin/python");
            let mut c = Command::new(&python);
            c.arg(dir.join(format!("{kind}.py")));
            (python.exists(), c)
        }
        _ => {
            let python = std::env::var_os("STABLESURF_VALIDATOR_PYTHON")
                .map(PathBuf::from)
                .unwrap_or_else(|| dir.join(".venv/bin/python"));
            let mut c = Command::new(&python);
            c.arg(dir.join(format!("{kind}.py")));
            (python.exists(), c)
        }
    };
    if found {
        return Some(command);
    }
    let msg = format!(
        "validator for {kind} is not installed; run `bash tools/install-validators.sh` to check \
         this format with its own tool"
    );
    assert!(
        std::env::var_os("CI").is_none(),
        "{msg} (CI is set, so this is a failure)"
    );
    eprintln!("notice: skipping the {kind} validator: {msg}");
    None
}

/// Runs a validator on `args`; returns its JSON lines, asserting it exited 0.
pub(crate) fn run(mut command: Command, args: &[&Path]) -> Vec<serde_json::Value> {
    let out = command.args(args).output().expect("cannot start validator");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "validator failed on {args:?}:\n{stdout}\n{stderr}"
    );
    stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("validator printed bad JSON"))
        .collect()
}

/// A colour per position that varies with it: each channel is its coordinate mapped from
/// [-1.5, 1.5] to [0, 255].
fn position_colours(positions: &[[f64; 3]]) -> Vec<[u8; 3]> {
    positions
        .iter()
        .map(|p| p.map(|c| ((c + 1.5) / 3.0 * 255.0).round().clamp(0.0, 255.0) as u8))
        .collect()
}

fn write_file<F>(path: &Path, f: F)
where
    F: FnOnce(&mut BufWriter<&mut File>) -> Result<(), ExportError>,
{
    write_atomic(path, f).unwrap_or_else(|e| panic!("writing {}: {e}", path.display()));
}

#[test]
fn gltf_passes_the_khronos_validator() {
    let dir = tempfile::tempdir().unwrap();
    // 2 400 vertices (u16 indices) and 75 000 vertices (u32 indices, Z up, millimetres scaled
    // to metres); the small torus once more at UTM-like coordinates (a node translation).
    let mut far_off = torus_mesh(60, 40, 1.0, 0.3);
    for p in &mut far_off.positions {
        *p = [p[0] + 500_123.25, p[1] + 4_000_456.5, p[2] + 101.75];
    }
    let cases = [
        ("small", torus_mesh(60, 40, 1.0, 0.3), UpAxis::Y, None),
        (
            "large",
            torus_mesh(300, 250, 2.0, 0.5),
            UpAxis::Z,
            Some(LengthUnit::Mm),
        ),
        ("far_off", far_off, UpAxis::Z, None),
    ];
    let mut files = Vec::new();
    // The small torus once more with a colour per vertex (COLOR_0).
    let coloured = torus_mesh(60, 40, 1.0, 0.3);
    let colours = position_colours(&coloured.positions);
    let cases = cases
        .iter()
        .map(|(name, mesh, up, units)| (*name, mesh, *up, *units, None))
        .chain([(
            "coloured",
            &coloured,
            UpAxis::Y,
            None,
            Some(colours.as_slice()),
        )]);
    for (name, mesh, up, units, colours) in cases {
        let opts = GltfOptions { up, units };
        let glb = dir.path().join(format!("{name}.glb"));
        write_file(&glb, |w| write_glb_coloured(mesh, colours, w, &opts));
        let gltf = dir.path().join(format!("{name}.gltf"));
        let bin_name = format!("{name}.bin");
        let mut bin = Vec::new();
        write_file(&gltf, |w| {
            write_gltf_coloured(mesh, colours, w, &mut bin, &bin_name, &opts)
        });
        write_file(&dir.path().join(&bin_name), |w| {
            w.write_all(&bin).map_err(ExportError::Write)
        });

        // Deterministic bytes, and no colours are no colours.
        let (mut a, mut b) = (Vec::new(), Vec::new());
        write_glb_coloured(mesh, colours, &mut a, &opts).unwrap();
        write_glb_coloured(mesh, colours, &mut b, &opts).unwrap();
        assert_eq!(a, b);
        if colours.is_none() {
            let mut plain = Vec::new();
            write_glb(mesh, &mut plain, &opts).unwrap();
            assert_eq!(plain, a);
        }
        assert_eq!(std::fs::read(&glb).unwrap(), a);
        files.push((glb, mesh.positions.len(), mesh.triangles.len()));
        files.push((gltf, mesh.positions.len(), mesh.triangles.len()));
    }
    for (file, n_vertices, n_triangles) in files {
        let Some(command) = validator("gltf") else {
            return;
        };
        let report = &run(command, &[&file])[0];
        assert_eq!(report["errors"], 0, "{report}");
        assert_eq!(report["warnings"], 0, "{report}");
        let info = &report["info"];
        let coloured = file.to_string_lossy().contains("coloured");
        // POSITION, NORMAL, and COLOR_0 when coloured.
        assert_eq!(info["maxAttributes"], 2 + u64::from(coloured), "{report}");
        assert_eq!(info["generator"], "stablesurf");
        assert_eq!(info["version"], "2.0");
        assert_eq!(info["totalVertexCount"], n_vertices as u64, "{report}");
        assert_eq!(info["totalTriangleCount"], n_triangles as u64, "{report}");
    }
}

#[test]
fn ply_passes_plyfile_and_meshlab() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = torus_mesh(48, 32, 1.0, 0.25);
    // Quality: distance to a sparse "scan" of the same torus, shifted outwards by 0.01.
    let scan: Vec<[f64; 3]> = mesh
        .positions
        .iter()
        .zip(&mesh.normals)
        .step_by(7)
        .map(|(p, n)| [0, 1, 2].map(|a| p[a] + 0.01 * n[a]))
        .collect();
    let quality = nearest_point_distances(&mesh.positions, &scan).unwrap();
    let q_max = quality.iter().copied().fold(0.0f32, f32::max);
    assert!(
        quality.iter().all(|&q| q >= 0.0099),
        "every vertex is ≥ 0.01 from the scan"
    );

    for encoding in [PlyEncoding::BinaryLittleEndian, PlyEncoding::Ascii] {
        let path = dir.path().join(format!("mesh-{encoding:?}.ply"));
        // The unit's comment line must not bother the readers either.
        // Colours in the binary file only, so both layouts are checked.
        let colours = position_colours(&mesh.positions);
        let opts = PlyOptions {
            encoding,
            quality: Some(&quality),
            units: (encoding == PlyEncoding::Ascii).then_some(LengthUnit::Mm),
            colours: (encoding == PlyEncoding::BinaryLittleEndian).then_some(colours.as_slice()),
            up: None,
        };
        write_file(&path, |w| ply::write(&mesh, w, &opts));
        let Some(mut command) = validator("ply") else {
            return;
        };
        command.arg("--closed");
        let report = &run(command, &[&path])[0];
        let (plyfile, meshlab) = (&report["plyfile"], &report["pymeshlab"]);
        assert_eq!(report["problems"], serde_json::json!([]), "{report}");
        let expected_format = if encoding == PlyEncoding::Ascii {
            "ascii"
        } else {
            "<"
        };
        assert_eq!(plyfile["format"], expected_format);
        assert_eq!(plyfile["vertices"], mesh.positions.len() as u64);
        assert_eq!(plyfile["faces"], mesh.triangles.len() as u64);
        assert_eq!(meshlab["watertight"], true, "{report}");
        assert_eq!(meshlab["is_mesh_two_manifold"], true, "{report}");
        assert_eq!(meshlab["boundary_edges"], 0);
        assert_eq!(meshlab["connected_components_number"], 1);
        assert_eq!(meshlab["genus"], 1);
        assert_eq!(meshlab["has_vertex_quality"], true);
        assert_eq!(
            meshlab["has_vertex_colour"],
            opts.colours.is_some(),
            "{report}"
        );
        let seen = meshlab["quality_max"].as_f64().unwrap();
        assert!(
            (seen - f64::from(q_max)).abs() < 1e-6,
            "quality max {seen} vs {q_max}"
        );
    }
}

/// Writes the EXR and PNG of every slice into `dir`, returning the EXR paths.
fn write_stack(dir: &Path, stack: &[Slice]) -> Vec<PathBuf> {
    stack
        .iter()
        .map(|slice| {
            let exr = dir.join(format!("slice_{:03}.exr", slice.index));
            write_file(&exr, |w| write_slice(slice, &ExrOptions::default(), w));
            let png = dir.join(format!("slice_{:03}.png", slice.index));
            write_file(&png, |w| write_preview(slice, w));
            exr
        })
        .collect()
}

#[test]
fn exr_slices_pass_openexr_and_pngs_decode() {
    let dir = tempfile::tempdir().unwrap();
    let center = [0.3, -0.2, 0.1];
    let sphere = unit_sphere(center, 0.8);
    let region = Aabb {
        min: [-1.0, -1.5, -1.1],
        max: [1.6, 1.1, 1.3],
    };
    let params = SliceParams {
        axis: Axis::Y,
        count: 5,
        resolution: 40,
        ..Default::default()
    };
    let stack = slices(&sphere, &region, &params).unwrap();
    let files = write_stack(dir.path(), &stack);

    for slice in &stack {
        let png = std::fs::read(dir.path().join(format!("slice_{:03}.png", slice.index))).unwrap();
        let img = image::load_from_memory(&png).unwrap();
        assert_eq!((img.width(), img.height()), (40, 40));
    }

    let Some(command) = validator("exr") else {
        return;
    };
    let paths: Vec<&Path> = files.iter().map(PathBuf::as_path).collect();
    let reports = run(command, &paths);
    assert_eq!(reports.len(), stack.len());
    for (report, slice) in reports.iter().zip(&stack) {
        assert_eq!(report["problems"], serde_json::json!([]), "{report}");
        assert_eq!(report["channels"], serde_json::json!(["Y"]));
        assert_eq!(report["dtype"], "float32");
        assert_eq!(
            (report["width"].as_u64(), report["height"].as_u64()),
            (Some(40), Some(40))
        );
        assert_eq!(report["compression"], "ZIP_COMPRESSION");
        let attrs = &report["attributes"];
        assert_eq!(attrs["sliceIndex"], slice.index as u64);
        assert_eq!(attrs["sliceCount"], 5);
        assert_eq!(attrs["sliceAxis"], "y");
        assert_eq!(attrs["signConvention"], "negative inside");
        assert_eq!(attrs["distanceMethod"], "exact");
        assert_eq!(attrs["distanceUnits"], "input units");
        let voxel: Vec<f64> = serde_json::from_value(attrs["voxelSize"].clone()).unwrap();
        assert_eq!(voxel, slice.voxel_size.to_vec());
        // Imath row-vector convention: the transpose of the column-vector grid_to_world.
        let m: Vec<Vec<f64>> = serde_json::from_value(attrs["gridToWorld"].clone()).unwrap();
        for (row, m_row) in m.iter().enumerate() {
            for (col, value) in m_row.iter().enumerate() {
                assert_eq!(*value, slice.grid_to_world[col][row]);
            }
        }
        // The values OpenEXR read are ours.
        let lo = slice.data.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = slice.data.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        assert_eq!(report["min"].as_f64(), Some(f64::from(lo)));
        assert_eq!(report["max"].as_f64(), Some(f64::from(hi)));
    }
}

#[test]
fn sphere_distances_match_analytic() {
    let center = [0.3, -0.2, 0.1];
    let sphere = unit_sphere(center, 0.8);
    let region = Aabb {
        min: [-1.0, -1.5, -1.1],
        max: [1.6, 1.1, 1.3],
    };
    let truth = |p: [f64; 3]| {
        (0..3)
            .map(|a| (p[a] - center[a]).powi(2))
            .sum::<f64>()
            .sqrt()
            - 1.0
    };
    let mut near_surface = 0;
    for axis in [Axis::X, Axis::Y, Axis::Z] {
        for method in [DistanceMethod::Exact, DistanceMethod::Taubin] {
            let params = SliceParams {
                axis,
                count: 6,
                resolution: 48,
                method,
            };
            let stack = slices(&sphere, &region, &params).unwrap();
            assert_eq!(stack.len(), 6);
            for slice in &stack {
                assert_eq!(slice.data.len(), 48 * 48);
                for row in 0..48 {
                    for col in 0..48 {
                        let p = slice.pixel_center(col, row);
                        let expected = truth(p);
                        let got = f64::from(slice.data[row * 48 + col]);
                        // f32 storage adds ≤ 6e-8 relative.
                        let tol = 1e-4;
                        match method {
                            DistanceMethod::Exact => {
                                assert!((got - expected).abs() < tol, "{p:?}: {got} vs {expected}")
                            }
                            DistanceMethod::Taubin if expected.abs() < 0.01 => {
                                near_surface += 1;
                                assert!((got - expected).abs() < tol, "{p:?}: {got} vs {expected}")
                            }
                            DistanceMethod::Taubin => {
                                assert_eq!(got.signum(), expected.signum(), "{p:?}")
                            }
                            DistanceMethod::Mesh => unreachable!("not in this loop"),
                        }
                    }
                }
            }
        }
    }
    assert!(
        near_surface > 100,
        "only {near_surface} pixels near the surface were checked"
    );
}

#[test]
fn unwritable_output_is_a_clear_error_and_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = torus_mesh(8, 6, 1.0, 0.3);

    // A missing directory.
    let missing = dir.path().join("no/such/dir/mesh.glb");
    let err = write_atomic(&missing, |w| write_glb(&mesh, w, &GltfOptions::default())).unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("cannot write") && msg.contains("no/such/dir/mesh.glb"),
        "{msg}"
    );
    assert!(!dir.path().join("no").exists());

    // A parent that is a file.
    let file = dir.path().join("file");
    std::fs::write(&file, b"x").unwrap();
    let err = write_atomic(&file.join("mesh.ply"), |w| {
        ply::write(&mesh, w, &PlyOptions::default())
    })
    .unwrap_err();
    assert!(matches!(err, ExportError::Io { .. }), "{err}");

    // A writer that fails halfway: the target is absent and no temporary file is left.
    let target = dir.path().join("mesh.ply");
    let mut broken = mesh.clone();
    broken.triangles.push([0, 1, 999]);
    let err =
        write_atomic(&target, |w| ply::write(&broken, w, &PlyOptions::default())).unwrap_err();
    assert!(err.to_string().contains("triangle"), "{err}");
    let left: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(
        left,
        vec![std::ffi::OsString::from("file")],
        "files left behind: {left:?}"
    );

    // An existing file is replaced only when the new one is complete.
    std::fs::write(&target, b"old").unwrap();
    assert!(write_atomic(&target, |w| ply::write(&broken, w, &PlyOptions::default())).is_err());
    assert_eq!(std::fs::read(&target).unwrap(), b"old");
}

#[test]
fn model_file_round_trips_through_disk() {
    let dir = tempfile::tempdir().unwrap();
    let model = ImplicitModel {
        polynomial: unit_sphere([0.1, 0.2, 0.3], 0.7),
        bounds: Some(Aabb {
            min: [-1.0; 3],
            max: [1.0, 1.5, 2.0],
        }),
        fit: None,
        diagnostics: None,
    };
    let path = dir.path().join("model.json");
    write_file(&path, |w| Ok(write_model(&model, w)?));
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(read_model(&bytes, &path).unwrap(), model);
    let text = String::from_utf8(bytes).unwrap();
    assert!(text.contains("\"format\": \"stablesurf.implicit-polynomial\""));
}

/// An RGB PLY sphere through `run`: the colour of each input point shows on the mesh near it
/// in the PLY (`red green blue`), the glb has one COLOR_0 entry per vertex, and `info` sees the
/// colours.
#[test]
fn scan_colours_reach_the_mesh() {
    let dir = tempfile::tempdir().unwrap();
    // 3000 points on the unit sphere (Fibonacci), each channel (coordinate + 1) / 2 · 255.
    let n = 3000;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let colour_at = |p: [f64; 3]| p.map(|c| (c + 1.0) / 2.0 * 255.0);
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n\
         property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
         end_header\n"
    );
    let mut points = Vec::new();
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let t = i as f64 * golden;
        let p = [r * t.cos(), r * t.sin(), z].map(|c| f64::from(c as f32));
        let c = colour_at(p).map(|c| c.round() as u8);
        text.push_str(&format!(
            "{} {} {} {} {} {}\n",
            p[0] as f32, p[1] as f32, p[2] as f32, c[0], c[1], c[2]
        ));
        points.push(p);
    }
    let input = dir.path().join("sphere.ply");
    std::fs::write(&input, text).unwrap();
    let scan =
        stablesurf::import::read_scan_bytes(&std::fs::read(&input).unwrap(), &input).unwrap();
    assert_eq!(scan.cloud.colours.as_ref().map(Vec::len), Some(n));

    let out = dir.path().join("out");
    crate::fixtures::run_ok(&input, &out, &["-q", "--no-cache", "--formats", "ply,glb"]);
    let mesh_path = out.join("mesh.ply");
    let mesh = stablesurf::import::read_scan_bytes(&std::fs::read(&mesh_path).unwrap(), &mesh_path)
        .unwrap()
        .cloud;
    let vertex_colours = mesh.colours.as_ref().expect("the mesh has colours");
    assert_eq!(vertex_colours.len(), mesh.points.len());
    let dist = |a: [f64; 3], b: [f64; 3]| {
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
    };
    // A vertex's colour is a weighted mean of the colours of its 4 nearest input points, all
    // within r4 (the distance to the 4th). Each channel of the colour field changes by at most
    // 127.5 per unit length, so for the vertex v nearest an input point p every channel is
    // within 127.5 · (|p − v| + r4(v)) of p's colour, plus 1.5 for the three roundings to
    // 8 bits (p's, its neighbours', the vertex's).
    let mut total_error = 0.0;
    let mut worst_excess = f64::NEG_INFINITY;
    for (p, c) in points.iter().zip(scan.cloud.colours.as_ref().unwrap()) {
        let (v, d) = mesh
            .points
            .iter()
            .enumerate()
            .map(|(v, &q)| (v, dist(*p, q)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        let mut near: Vec<f64> = points.iter().map(|&q| dist(mesh.points[v], q)).collect();
        near.select_nth_unstable_by(3, f64::total_cmp);
        let r4 = near[3];
        let bound = 127.5 * (d + r4) + 1.5;
        for k in 0..3 {
            let error = (f64::from(vertex_colours[v][k]) - f64::from(c[k])).abs() / 257.0;
            assert!(
                error <= bound,
                "point {p:?}: vertex {v} channel {k} off by {error} > {bound}"
            );
            total_error += error;
            worst_excess = worst_excess.max(error - bound);
        }
    }
    let mean_error = total_error / (3 * n) as f64;
    eprintln!("mean colour error {mean_error:.3} of 255 (worst margin {worst_excess:.2})");
    assert!(mean_error < 4.0, "mean colour error {mean_error}");

    // The glb: COLOR_0 with one entry per vertex.
    let glb = gltf::Gltf::from_slice(&std::fs::read(out.join("mesh.glb")).unwrap()).unwrap();
    let primitive = glb.meshes().next().unwrap().primitives().next().unwrap();
    let count = |semantic| primitive.get(&semantic).map(|a| a.count());
    let n_vertices = count(gltf::Semantic::Positions).unwrap();
    assert_eq!(count(gltf::Semantic::Colors(0)), Some(n_vertices));

    // `info` of the mesh sees the colours.
    let info = crate::fixtures::bin()
        .args(["info", "--json"])
        .arg(&mesh_path)
        .output()
        .unwrap();
    assert!(info.status.success());
    let json: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    assert_eq!(json["has_colours"], true);
}
