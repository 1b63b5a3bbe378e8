//! Batch runs: `stablesurf run FOLDER -o OUT` and `stablesurf run A B --batch -o OUT`. Each
//! input's folder must hold exactly what a single run of that input writes (byte for byte,
//! report.json's timings aside); a failed input must leave no folder, stop no other input and
//! make the command exit 1 naming it; the summary (stdout, `--json`, OUT/summary.csv) must have
//! one correct row per input.
//!
//! Each test runs the real binary on small generated scans in a temporary folder.

use std::collections::BTreeMap;
use std::fs;
use std::path::Path;
use std::time::Instant;

use crate::fixtures::{bin, read_report, stderr_of};

/// Flags that keep the runs small: a coarse mesh and two small slices.
const SMALL: [&str; 6] = [
    "--depth",
    "5",
    "--slice-count",
    "2",
    "--slice-resolution",
    "16",
];

/// `n` points of an ellipsoid with semi-axes `axes` about `centre` (a Fibonacci spiral) and
/// their exact outward unit normals.
fn ellipsoid(n: usize, centre: [f64; 3], axes: [f64; 3]) -> Vec<([f64; 3], [f64; 3])> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let t = golden * i as f64;
            let u = [r * t.cos(), r * t.sin(), z];
            let p = [0, 1, 2].map(|k| centre[k] + axes[k] * u[k]);
            let g = [0, 1, 2].map(|k| u[k] / axes[k]);
            let len = g.iter().map(|v| v * v).sum::<f64>().sqrt();
            (p, g.map(|v| v / len))
        })
        .collect()
}

/// The points as XYZ text with normals.
fn xyz(points: &[([f64; 3], [f64; 3])]) -> String {
    points
        .iter()
        .map(|(p, n)| format!("{} {} {} {} {} {}\n", p[0], p[1], p[2], n[0], n[1], n[2]))
        .collect()
}

/// The points as OBJ `v` and `vn` lines.
fn obj(points: &[([f64; 3], [f64; 3])]) -> String {
    let mut text: String = points
        .iter()
        .map(|(p, _)| format!("v {} {} {}\n", p[0], p[1], p[2]))
        .collect();
    text += &points
        .iter()
        .map(|(_, n)| format!("vn {} {} {}\n", n[0], n[1], n[2]))
        .collect::<String>();
    text
}

/// The points as an ascii PLY with normals.
fn ply(points: &[([f64; 3], [f64; 3])]) -> String {
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nproperty double nx\nproperty double ny\nproperty double nz\nend_header\n",
        points.len()
    );
    text += &xyz(points);
    text
}

/// Every file under `dir` (relative path → bytes).
fn files_under(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Vec<u8>>) {
        for entry in fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                let name = path.strip_prefix(root).unwrap().display().to_string();
                out.insert(name, fs::read(&path).unwrap());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// A report.json without its timings (every `seconds` field).
fn without_timings(mut v: serde_json::Value) -> serde_json::Value {
    fn strip(v: &mut serde_json::Value) {
        match v {
            serde_json::Value::Object(map) => {
                map.remove("seconds");
                map.values_mut().for_each(strip);
            }
            serde_json::Value::Array(items) => items.iter_mut().for_each(strip),
            _ => {}
        }
    }
    strip(&mut v);
    v
}

/// Asserts that `batch_dir` holds exactly the files of a single `run input -o …` with the same
/// flags (and a fresh cache, as the batch had), byte for byte, report.json's timings aside.
fn assert_same_as_single_run(input: &Path, batch_dir: &Path, scratch: &Path, extra: &[&str]) {
    let single = scratch.join("single");
    let done = bin()
        .arg("run")
        .arg(input)
        .arg("-o")
        .arg(&single)
        .arg("--cache-dir")
        .arg(scratch.join("cache"))
        .args(SMALL)
        .args(extra)
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", stderr_of(&done));
    let mut expected = files_under(&single);
    let mut got = files_under(batch_dir);
    let names = |m: &BTreeMap<String, Vec<u8>>| m.keys().cloned().collect::<Vec<_>>();
    assert_eq!(names(&got), names(&expected), "{}", input.display());
    assert_eq!(
        without_timings(read_report(batch_dir)),
        without_timings(read_report(&single)),
        "report.json of {}",
        input.display()
    );
    expected.remove("report.json");
    got.remove("report.json");
    for (name, bytes) in &expected {
        assert!(
            got[name] == *bytes,
            "{name} of {} differs from a single run's",
            input.display()
        );
    }
}

/// The rows of a summary.csv, each field by column name. The fields before `error` hold no
/// comma here (plain temporary paths), so the split is exact for them.
fn csv_rows(text: &str) -> Vec<BTreeMap<String, String>> {
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header.last(), Some(&"error"), "{text}");
    lines
        .map(|line| {
            let fields = line.splitn(header.len(), ',');
            header
                .iter()
                .map(|h| h.to_string())
                .zip(fields.map(str::to_string))
                .collect()
        })
        .collect()
}

#[test]
fn a_folder_runs_each_scan_as_a_single_run_would_and_a_corrupt_one_fails_alone() {
    let dir = tempfile::tempdir().unwrap();
    let scans = dir.path().join("scans");
    fs::create_dir_all(scans.join("more")).unwrap();
    let ball = ellipsoid(300, [1.0, 2.0, 3.0], [2.0, 2.0, 2.0]);
    let egg = ellipsoid(400, [0.0, 0.0, 0.0], [1.0, 1.0, 1.6]);
    let pebble = ellipsoid(350, [-5.0, 1.0, 0.5], [3.0, 2.0, 1.2]);
    fs::write(scans.join("ball.xyz"), xyz(&ball)).unwrap();
    fs::write(scans.join("egg.obj"), obj(&egg)).unwrap();
    fs::write(scans.join("pebble.ply"), ply(&pebble)).unwrap();
    // A PLY whose header promises more vertices than its body holds.
    let mut broken = ply(&ball[..40]);
    broken = broken.replacen("element vertex 40", "element vertex 90", 1);
    fs::write(scans.join("broken.ply"), broken).unwrap();
    fs::write(scans.join("notes.md"), "# where these came from\n").unwrap();
    fs::write(scans.join("more").join("inner.xyz"), xyz(&egg)).unwrap();

    let out = dir.path().join("out");
    let started = Instant::now();
    let done = bin()
        .arg("run")
        .arg(&scans)
        .arg("-o")
        .arg(&out)
        .arg("--cache-dir")
        .arg(dir.path().join("cache"))
        .args(SMALL)
        .output()
        .unwrap();
    eprintln!(
        "batch of 4 inputs: {:.1} s",
        started.elapsed().as_secs_f64()
    );
    let stderr = stderr_of(&done);
    assert_eq!(done.status.code(), Some(1), "{stderr}");
    // The failure is reported where it happens and again at the end, naming the file.
    let broken_path = scans.join("broken.ply").display().to_string();
    let last = stderr.lines().last().unwrap();
    assert!(
        last.contains("1 of 4 inputs failed") && last.contains(&broken_path),
        "{stderr}"
    );
    assert!(
        stderr
            .lines()
            .filter(|l| l.starts_with("stablesurf: error:") && l.contains("broken.ply"))
            .count()
            == 2,
        "{stderr}"
    );
    // One notice names what was skipped: the non-scan file and the subfolder.
    let notice: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("not a scan file") || l.contains("not scan files"))
        .collect();
    assert_eq!(notice.len(), 1, "{stderr}");
    assert!(
        notice[0].contains("notes.md") && notice[0].contains("more/"),
        "{stderr}"
    );

    // One folder per scan that ran, none for the corrupt one, nothing from the subfolder.
    let mut entries: Vec<String> = fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    entries.sort();
    assert_eq!(entries, ["ball", "egg", "pebble", "summary.csv"]);
    for (name, file) in [
        ("ball", "ball.xyz"),
        ("egg", "egg.obj"),
        ("pebble", "pebble.ply"),
    ] {
        let scratch = dir.path().join(format!("single-{name}"));
        assert_same_as_single_run(&scans.join(file), &out.join(name), &scratch, &[]);
    }

    // The summary: one row per input in name order, the figures of each report.
    let rows = csv_rows(&fs::read_to_string(out.join("summary.csv")).unwrap());
    let inputs: Vec<&str> = rows.iter().map(|r| r["input"].as_str()).collect();
    let path_of = |f: &str| scans.join(f).display().to_string();
    assert_eq!(
        inputs,
        [
            path_of("ball.xyz"),
            path_of("broken.ply"),
            path_of("egg.obj"),
            path_of("pebble.ply")
        ]
    );
    for (row, (name, n_points)) in rows.iter().filter(|r| r["status"] == "ok").zip([
        ("ball", 300),
        ("egg", 400),
        ("pebble", 350),
    ]) {
        let report = read_report(&out.join(name));
        assert_eq!(row["points"], n_points.to_string(), "{row:?}");
        assert_eq!(
            row["triangles"],
            report["mesh"]["faces"].to_string(),
            "{row:?}"
        );
        assert_eq!(row["watertight"], "yes", "{row:?}");
        assert_eq!(row["manifold"], "yes", "{row:?}");
        assert_eq!(row["self_intersecting_faces"], "0", "{row:?}");
        let relative: f64 = row["mean_distance_data_to_mesh"].parse().unwrap();
        let reported = report["accuracy"]["mean_relative"].as_f64().unwrap();
        assert!(
            (relative - reported).abs() <= 1e-12 * reported.abs(),
            "{row:?}"
        );
        // A smooth closed shape: well within 1% of its diagonal.
        assert!(relative > 0.0 && relative < 1e-2, "{row:?}");
        assert_eq!(row["output"], out.join(name).display().to_string());
        assert_eq!(row["error"], "");
    }
    let failed = &rows[1];
    assert_eq!(failed["status"], "failed");
    assert_eq!(failed["output"], "");
    assert_eq!(failed["points"], "");
    assert!(failed["error"].contains("broken.ply"), "{failed:?}");

    // The same table on stdout: a header and one line per input.
    let stdout = String::from_utf8(done.stdout).unwrap();
    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.len(), 5, "{stdout}");
    assert!(lines[0].starts_with("input") && lines[0].contains("watertight"));
    for (line, input) in lines[1..].iter().zip(&inputs) {
        assert!(line.starts_with(input), "{stdout}");
    }
    assert!(lines[2].contains("failed"), "{stdout}");
}

#[test]
fn batch_runs_each_input_alone_and_colliding_stems_get_file_names() {
    let dir = tempfile::tempdir().unwrap();
    let a_ply = dir.path().join("a.ply");
    let a_obj = dir.path().join("a.obj");
    fs::write(&a_ply, ply(&ellipsoid(300, [0.0; 3], [1.0, 1.0, 1.0]))).unwrap();
    fs::write(
        &a_obj,
        obj(&ellipsoid(320, [4.0, 0.0, 0.0], [1.0, 1.5, 1.0])),
    )
    .unwrap();
    let out = dir.path().join("out");
    let done = bin()
        .arg("run")
        .arg(&a_ply)
        .arg(&a_obj)
        .arg("--batch")
        .arg("-o")
        .arg(&out)
        .arg("--cache-dir")
        .arg(dir.path().join("cache"))
        .arg("--json")
        .args(SMALL)
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", stderr_of(&done));
    let summary: serde_json::Value = serde_json::from_slice(&done.stdout).unwrap();
    assert_eq!(summary["format"], "stablesurf.batch-summary");
    assert_eq!(summary["inputs"], 2);
    assert_eq!(summary["failed"], 0);
    let rows = summary["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 2);
    for (row, (input, folder, n)) in rows
        .iter()
        .zip([(&a_ply, "a.ply", 300), (&a_obj, "a.obj", 320)])
    {
        assert_eq!(row["input"], input.display().to_string());
        assert_eq!(row["status"], "ok");
        assert_eq!(row["points"], n);
        assert_eq!(row["watertight"], true);
        assert_eq!(row["output"], out.join(folder).display().to_string());
        assert!(row["error"].is_null());
        // Each input alone: one import, no merge.
        let report = read_report(&out.join(folder));
        let stages: Vec<&str> = report["stages"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s["stage"].as_str().unwrap())
            .collect();
        assert_eq!(stages.iter().filter(|s| **s == "import").count(), 1);
        assert!(!stages.contains(&"merge"), "{stages:?}");
    }
    assert_same_as_single_run(&a_obj, &out.join("a.obj"), &dir.path().join("single"), &[]);
    // summary.csv agrees with the JSON.
    let csv = csv_rows(&fs::read_to_string(out.join("summary.csv")).unwrap());
    assert_eq!(csv.len(), 2);
    assert_eq!(csv[1]["output"], out.join("a.obj").display().to_string());

    // Without --batch the same two inputs are still views of one object, merged.
    let merged = dir.path().join("merged");
    let done = bin()
        .arg("run")
        .arg(&a_ply)
        .arg(&a_obj)
        .arg("-o")
        .arg(&merged)
        .arg("--cache-dir")
        .arg(dir.path().join("cache"))
        .args(SMALL)
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", stderr_of(&done));
    let report = read_report(&merged);
    assert!(
        report["stages"]
            .as_array()
            .unwrap()
            .iter()
            .any(|s| s["stage"] == "merge"),
        "{report}"
    );
    assert!(!merged.join("summary.csv").exists());
}

#[test]
fn a_folder_without_scans_or_given_with_other_inputs_is_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("docs");
    fs::create_dir_all(empty.join("sub")).unwrap();
    fs::write(empty.join("README.md"), "text\n").unwrap();
    let scan = dir.path().join("ball.xyz");
    fs::write(&scan, xyz(&ellipsoid(100, [0.0; 3], [1.0; 3]))).unwrap();
    let out = dir.path().join("out");
    let cases: [(Vec<&Path>, &[&str], &str); 3] = [
        (vec![empty.as_path()], &[], "holds no scan file"),
        (vec![empty.as_path(), scan.as_path()], &[], "is a folder"),
        (vec![], &["--batch"], "--batch"),
    ];
    for (inputs, extra, needle) in cases {
        let done = bin()
            .arg("run")
            .args(&inputs)
            .args(extra)
            .arg("-o")
            .arg(&out)
            .arg("--no-cache")
            .output()
            .unwrap();
        let stderr = stderr_of(&done);
        assert_eq!(done.status.code(), Some(2), "{inputs:?}: {stderr}");
        assert!(stderr.contains(needle), "{inputs:?}: {stderr}");
        if !inputs.is_empty() {
            assert!(
                stderr.contains(&inputs[0].display().to_string()),
                "{stderr}"
            );
        }
        assert!(!out.exists(), "a usage error wrote {}", out.display());
    }
}

/// An input whose outputs cannot be written (a full disk at its first file) fails alone: its
/// folder, which its run created, is gone, and the next input's is complete.
#[test]
fn an_input_that_cannot_write_leaves_no_folder_and_the_next_one_runs() {
    let dir = tempfile::tempdir().unwrap();
    let first = dir.path().join("first.xyz");
    let second = dir.path().join("second.xyz");
    fs::write(&first, xyz(&ellipsoid(300, [0.0; 3], [1.0; 3]))).unwrap();
    fs::write(&second, xyz(&ellipsoid(300, [0.0; 3], [1.0, 1.2, 1.0]))).unwrap();
    let out = dir.path().join("out");
    let done = bin()
        .arg("run")
        .arg(&first)
        .arg(&second)
        .arg("--batch")
        .arg("-o")
        .arg(&out)
        .arg("--no-cache")
        .args(SMALL)
        .env("STABLESURF_FAULT", "enospc@1")
        .output()
        .unwrap();
    let stderr = stderr_of(&done);
    assert_eq!(done.status.code(), Some(1), "{stderr}");
    assert!(
        stderr
            .lines()
            .last()
            .unwrap()
            .contains("1 of 2 inputs failed"),
        "{stderr}"
    );
    assert!(!out.join("first").exists(), "{stderr}");
    assert!(out.join("second").join("report.json").is_file(), "{stderr}");
    let rows = csv_rows(&fs::read_to_string(out.join("summary.csv")).unwrap());
    assert_eq!(rows[0]["status"], "failed");
    assert_eq!(rows[1]["status"], "ok");
}
