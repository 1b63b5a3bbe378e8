//! CLI tests: exit codes, stderr messages, stdout JSON, cache hits and misses, atomic outputs.
//!
//! Each test runs the real binary in a temporary directory with its own cache directory.

use std::fs;
use std::path::{Path, PathBuf};

use crate::fixtures::{bin, flags, read_report, run_ok, shared, sphere_xyz, stderr_of};
use stablesurf::pipeline::{reconstruct, Mode, PipelineConfig, ScanSource, Silent, StageFigures};

/// The `-v` line of a stage: "stablesurf: <stage> <hit|miss|corrupt> ...".
fn cache_state(stderr: &str, stage: &str) -> String {
    stderr
        .lines()
        .find_map(|l| {
            let mut w = l.split_whitespace();
            (w.next() == Some("stablesurf:") && w.next() == Some(stage))
                .then(|| w.next().unwrap_or("").to_string())
        })
        .unwrap_or_else(|| panic!("no -v line for stage {stage} in:\n{stderr}"))
}

#[test]
fn info_json_has_the_documented_keys() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 100, "");
    let out = bin().args(["info", "--json"]).arg(&input).output().unwrap();
    assert!(out.status.success(), "{}", stderr_of(&out));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["format"], "xyz");
    assert_eq!(v["points"], 100);
    assert_eq!(v["triangles"], 0);
    assert_eq!(v["has_normals"], true);
    assert_eq!(v["nan_points"], 0);
    assert_eq!(v["duplicate_points"], 0);
    // Fibonacci points reach within 2·(1/n) of the poles: z from 1.02 to 4.98.
    assert!((v["bbox_min"][2].as_f64().unwrap() - 1.0).abs() < 0.05);
    assert!((v["bbox_max"][2].as_f64().unwrap() - 5.0).abs() < 0.05);
}

#[test]
fn bad_input_is_exit_1_and_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("broken.ply");
    fs::write(
        &bad,
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1\n",
    )
    .unwrap();
    let out = bin()
        .args(["fit"])
        .arg(&bad)
        .args(["-o"])
        .arg(dir.path().join("m.json"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = stderr_of(&out);
    assert!(
        err.contains("stablesurf: error:") && err.contains("broken.ply"),
        "{err}"
    );
    assert!(!dir.path().join("m.json").exists());
    let missing = bin().args(["info", "does-not-exist.ply"]).output().unwrap();
    assert_eq!(missing.status.code(), Some(1));
    assert!(stderr_of(&missing).contains("does-not-exist.ply"));
}

#[test]
fn usage_errors_are_exit_2() {
    for args in [
        vec!["run", "-o", "x", "--degree", "5"],
        vec!["run", "-o", "x", "--formats", "glb,obj"],
        vec!["run", "-o", "x", "--kappa", "lots"],
        vec!["run"],
        vec!["frobnicate"],
    ] {
        let out = bin().args(&args).output().unwrap();
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", stderr_of(&out));
    }
    let odd = bin()
        .args(["run", "-o", "x", "--degree", "5"])
        .output()
        .unwrap();
    assert!(
        stderr_of(&odd).contains("even degree"),
        "{}",
        stderr_of(&odd)
    );
}

/// `stablesurf run INPUT -o OUT --degree 4 --cache-dir CACHE` with the given flags; asserts
/// that it succeeded.
fn run_degree_4(input: &Path, out: &Path, cache: &Path, flags: &[&str]) -> std::process::Output {
    let mut all = vec!["--mode", "global", "--degree", "4"];
    all.extend_from_slice(flags);
    all.extend(["--cache-dir", cache.to_str().unwrap()]);
    run_ok(input, out, &all)
}

#[test]
fn polynomial_slices_do_not_depend_on_the_mesh() {
    // The exact slices of a global model are computed beside the meshing, from the model alone:
    // two depths (two meshes, the fit reused) give byte-identical slice files, and a third run
    // with the distance to the mesh gives different ones (so the comparison can fail).
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let cache = dir.path().join("cache");
    let run = |depth: &str, method: &str, out: &str| {
        run_degree_4(
            &input,
            &dir.path().join(out),
            &cache,
            &[
                "--depth",
                depth,
                "--formats",
                "exr,json",
                "-q",
                "--slice-count",
                "3",
                "--slice-resolution",
                "24",
                "--slice-distance",
                method,
            ],
        );
        dir.path().join(out).join("slices")
    };
    let a = run("4", "exact", "a");
    let b = run("6", "exact", "b");
    let c = run("4", "mesh", "c");
    for k in 0..3 {
        let name = format!("slice_{k:03}.exr");
        let bytes = fs::read(a.join(&name)).unwrap();
        assert_eq!(bytes, fs::read(b.join(&name)).unwrap(), "{name}");
        assert_ne!(bytes, fs::read(c.join(&name)).unwrap(), "{name}");
    }
}

#[test]
fn rerun_hits_cache_and_depth_change_reuses_the_fit() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let cache = dir.path().join("cache");
    let run = |depth: &str, out: &str| {
        let o = run_degree_4(
            &input,
            &dir.path().join(out),
            &cache,
            &["--depth", depth, "--formats", "ply,json", "-v"],
        );
        stderr_of(&o)
    };
    let first = run("5", "a");
    for stage in ["import", "normals", "fit", "polygonize", "finish", "export"] {
        assert_eq!(cache_state(&first, stage), "miss", "first run, {stage}");
    }
    let second = run("5", "b");
    for stage in ["import", "normals", "fit", "polygonize", "finish", "export"] {
        assert_eq!(cache_state(&second, stage), "hit", "second run, {stage}");
    }
    // Byte-identical outputs from a cold and a warm run.
    for f in ["mesh.ply", "model.json"] {
        assert_eq!(
            fs::read(dir.path().join("a").join(f)).unwrap(),
            fs::read(dir.path().join("b").join(f)).unwrap(),
            "{f}"
        );
    }
    let deeper = run("6", "c");
    for stage in ["import", "normals", "fit"] {
        assert_eq!(cache_state(&deeper, stage), "hit", "depth change, {stage}");
    }
    assert_eq!(cache_state(&deeper, "polygonize"), "miss");
    assert_eq!(cache_state(&deeper, "export"), "miss");

    // Corrupt the fit entry: it is detected, recomputed and rewritten.
    corrupt_first_entry(&cache, "fit");
    let repaired = run("5", "d");
    assert_eq!(cache_state(&repaired, "fit"), "corrupt");
    assert_eq!(cache_state(&run("5", "e"), "fit"), "hit");
}

/// Flips a byte in the middle of the first `.bin` entry of `stage` in the cache at `cache`.
fn corrupt_first_entry(cache: &Path, stage: &str) {
    let entry = fs::read_dir(cache.join(stage))
        .unwrap()
        .flat_map(|shard| fs::read_dir(shard.unwrap().path()).unwrap())
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "bin"))
        .unwrap();
    let mut bytes = fs::read(&entry).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0xff;
    fs::write(&entry, bytes).unwrap();
}

#[test]
fn corrupt_export_entry_is_rebuilt_into_the_same_files() {
    // A corrupt export entry is found on disk, so the run does not start the export's parts
    // beside the meshing; the export stage then makes them all itself, and every file comes
    // out as from the cold run.
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let cache = dir.path().join("cache");
    let run = |out: &str| {
        let o = run_degree_4(
            &input,
            &dir.path().join(out),
            &cache,
            &[
                "--depth",
                "4",
                "--formats",
                "json,ply,glb,exr,png",
                "--slice-count",
                "2",
                "--slice-resolution",
                "16",
                "-v",
            ],
        );
        stderr_of(&o)
    };
    assert_eq!(cache_state(&run("a"), "export"), "miss");
    corrupt_first_entry(&cache, "export");
    let repaired = run("b");
    assert_eq!(cache_state(&repaired, "polygonize"), "hit");
    assert_eq!(cache_state(&repaired, "export"), "corrupt");
    let files = |out: &str| -> Vec<(String, Vec<u8>)> {
        let mut names = vec![
            "model.json".to_string(),
            "mesh.ply".into(),
            "mesh.glb".into(),
            "preview.png".into(),
        ];
        for k in 0..2 {
            names.push(format!("slices/slice_{k:03}.exr"));
            names.push(format!("slices/slice_{k:03}.png"));
        }
        names
            .into_iter()
            .map(|n| {
                let bytes = fs::read(dir.path().join(out).join(&n)).unwrap();
                (n, bytes)
            })
            .collect()
    };
    assert_eq!(files("a"), files("b"));
}

#[test]
fn no_cache_writes_no_cache() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    let out = bin()
        .arg("run")
        .arg(&input)
        .args(["-o"])
        .arg(dir.path().join("out"))
        .args([
            "--mode",
            "global",
            "--degree",
            "2",
            "--depth",
            "4",
            "--formats",
            "json",
            "--no-cache",
            "-q",
        ])
        .env("XDG_CACHE_HOME", dir.path().join("xdg"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr_of(&out));
    assert!(
        out.stderr.is_empty(),
        "-q must print nothing: {}",
        stderr_of(&out)
    );
    assert!(!dir.path().join("xdg").exists());
    let report = read_report(&dir.path().join("out"));
    assert_eq!(report["mesh"]["watertight"], true);
}

#[test]
fn unwritable_cache_is_one_warning_and_complete_outputs() {
    // The cache is stored beside the run's work; a cache that cannot be written costs only the
    // next run's time, so the run succeeds, says so once, and writes every output.
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    let blocker = dir.path().join("not-a-dir");
    fs::write(&blocker, b"").unwrap();
    let out = bin()
        .arg("run")
        .arg(&input)
        .arg("-o")
        .arg(dir.path().join("out"))
        .args([
            "--mode",
            "global",
            "--degree",
            "2",
            "--depth",
            "4",
            "--formats",
            "json,ply",
        ])
        .arg("--cache-dir")
        .arg(blocker.join("cache"))
        .output()
        .unwrap();
    let stderr = stderr_of(&out);
    assert!(out.status.success(), "{stderr}");
    // One warning about the cache (the fit may warn of its own choices too).
    let warnings: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("warning") && l.contains("cache"))
        .collect();
    assert_eq!(warnings.len(), 1, "{stderr}");
    assert!(warnings[0].contains("cannot write the cache"), "{stderr}");
    for file in ["report.json", "model.json", "mesh.ply"] {
        assert!(dir.path().join("out").join(file).is_file(), "{file}");
    }
}

#[test]
fn unwritable_output_is_exit_1_and_leaves_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    // A regular file where the output directory should be.
    let blocker = dir.path().join("blocker");
    fs::write(&blocker, "x").unwrap();
    let out = bin()
        .arg("fit")
        .arg(&input)
        .arg("-o")
        .arg(blocker.join("model.json"))
        .args(["--mode", "global", "--degree", "2"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr_of(&out).contains("model.json"),
        "{}",
        stderr_of(&out)
    );
    let leftovers: Vec<_> = fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(leftovers.len(), 2, "{leftovers:?}");
}

#[test]
fn json_goes_to_stdout_only() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    let out = run_ok(
        &input,
        &dir.path().join("out"),
        &flags("--mode global --degree 2 --depth 4 --formats json --no-cache --json"),
    );
    let v: serde_json::Value =
        serde_json::from_slice(&out.stdout).expect("stdout is one JSON document");
    assert_eq!(v["stages"][0]["stage"], "import");
}

/// Kills runs part-way at several moments: every visible output file that exists is complete
/// (identical to an uninterrupted run's), and the cache left behind serves a correct rerun.
#[test]
fn killed_runs_leave_no_partial_output_and_no_corrupt_cache() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let cache = dir.path().join("cache");
    let args = |out: &Path| {
        let mut a: Vec<std::ffi::OsString> = vec!["run".into(), input.clone().into(), "-o".into()];
        a.push(out.into());
        for s in [
            "--mode",
            "global",
            "--degree",
            "4",
            "--depth",
            "6",
            "--formats",
            "glb,ply,json",
            "-q",
            "--cache-dir",
        ] {
            a.push(s.into());
        }
        a.push(cache.clone().into());
        a
    };
    let reference = dir.path().join("reference");
    let ok = bin()
        .args(args(&reference))
        .arg("--no-cache")
        .output()
        .unwrap();
    assert!(ok.status.success(), "{}", stderr_of(&ok));
    let exe = assert_cmd::cargo::cargo_bin("stablesurf");
    for (i, delay_ms) in [5u64, 30, 80, 200, 400].into_iter().enumerate() {
        let out = dir.path().join(format!("killed{i}"));
        let mut child = std::process::Command::new(&exe)
            .args(args(&out))
            .env_remove("XDG_CACHE_HOME")
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(delay_ms));
        let _ = child.kill();
        let _ = child.wait();
        for entry in fs::read_dir(&out).into_iter().flatten() {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if name.starts_with('.') || name == "report.json" {
                continue; // temporary files of an interrupted write; the report holds timings
            }
            assert_eq!(
                fs::read(&path).unwrap(),
                fs::read(reference.join(&name)).unwrap(),
                "{name} after kill at {delay_ms} ms"
            );
        }
    }
    let after = dir.path().join("after");
    let rerun = bin().args(args(&after)).output().unwrap();
    assert!(rerun.status.success(), "{}", stderr_of(&rerun));
    for f in ["mesh.glb", "mesh.ply", "model.json"] {
        assert_eq!(
            fs::read(after.join(f)).unwrap(),
            fs::read(reference.join(f)).unwrap(),
            "{f}"
        );
    }
}

/// Two runs at once on the same cache both succeed, and the entries they leave are valid hits.
#[test]
fn concurrent_runs_share_a_cache_safely() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let cache = dir.path().join("cache");
    let exe = assert_cmd::cargo::cargo_bin("stablesurf");
    let spawn = |out: &str, verbose: bool| {
        let mut cmd = std::process::Command::new(&exe);
        cmd.arg("run")
            .arg(&input)
            .arg("-o")
            .arg(dir.path().join(out))
            .args([
                "--mode",
                "global",
                "--degree",
                "4",
                "--depth",
                "6",
                "--formats",
                "ply,json",
            ])
            .arg(if verbose { "-v" } else { "-q" })
            .arg("--cache-dir")
            .arg(&cache)
            .stderr(std::process::Stdio::piped());
        cmd.spawn().unwrap()
    };
    let (a, b) = (spawn("a", false), spawn("b", false));
    for child in [a, b] {
        let out = child.wait_with_output().unwrap();
        assert!(out.status.success(), "{}", stderr_of(&out));
    }
    assert_eq!(
        fs::read(dir.path().join("a/mesh.ply")).unwrap(),
        fs::read(dir.path().join("b/mesh.ply")).unwrap()
    );
    let third = spawn("c", true).wait_with_output().unwrap();
    let err = stderr_of(&third);
    for stage in ["import", "normals", "fit", "polygonize", "finish", "export"] {
        assert_eq!(cache_state(&err, stage), "hit", "{stage}");
    }
}

#[test]
fn detail_mode_runs_end_to_end_and_its_model_file_works_everywhere() {
    // `run --mode detail` on a sphere: one closed component close to the data, a model.mpu
    // that `info`, `mesh` and `slices` accept, and a detail stage that a rerun hits.
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 3000, "");
    let out = dir.path().join("out");
    let cache = dir.path().join("cache");
    let run = |extra: &[&str]| {
        let mut cmd = bin();
        cmd.args(["run", input.to_str().unwrap(), "-o", out.to_str().unwrap()])
            .args(["--mode", "detail", "--depth", "5", "-v", "--json"])
            .args(["--cache-dir", cache.to_str().unwrap()])
            .args(extra);
        cmd.output().unwrap()
    };
    let first = run(&[]);
    assert!(first.status.success(), "{}", stderr_of(&first));
    assert_eq!(cache_state(&stderr_of(&first), "detail"), "miss");
    let report: serde_json::Value = serde_json::from_slice(&first.stdout).unwrap();
    assert_eq!(report["fit"]["mode"], "detail");
    assert_eq!(report["fit"]["params"]["degree"], 2);
    assert_eq!(report["mesh"]["components"], 1);
    assert_eq!(report["mesh"]["watertight"], true);
    // Data within 0.5% of the diagonal (2·√3·2 ≈ 6.9) of the mesh on average.
    let mean = report["accuracy"]["mean_relative"].as_f64().unwrap();
    assert!(mean < 5e-3, "mean distance {mean}");
    for f in [
        "model.mpu",
        "mesh.glb",
        "mesh.ply",
        "report.json",
        "preview.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    assert!(!out.join("model.json").exists());
    assert!(out.join("slices/slice_000.exr").is_file());
    let second = run(&[]);
    assert!(second.status.success());
    assert_eq!(cache_state(&stderr_of(&second), "detail"), "hit");

    let model = out.join("model.mpu");
    let info = bin()
        .args(["info", "--json", model.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(info.status.success(), "{}", stderr_of(&info));
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    assert_eq!(info["format"], "stablesurf.mpu");
    assert!(info["cells"].as_u64().unwrap() > 0);

    let mesh = dir.path().join("again.ply");
    let meshed = bin()
        .args([
            "mesh",
            model.to_str().unwrap(),
            "-o",
            mesh.to_str().unwrap(),
        ])
        .args(["--depth", "5"])
        .output()
        .unwrap();
    assert!(meshed.status.success(), "{}", stderr_of(&meshed));
    assert!(fs::metadata(&mesh).unwrap().len() > 1000);

    let slices = dir.path().join("slices");
    let sliced = bin()
        .args([
            "slices",
            model.to_str().unwrap(),
            "-o",
            slices.to_str().unwrap(),
        ])
        .args(["--count", "2", "--resolution", "16", "--depth", "5"])
        .output()
        .unwrap();
    assert!(sliced.status.success(), "{}", stderr_of(&sliced));
    assert!(slices.join("slice_001.exr").is_file());
    // The exact distance needs a polynomial: a usage error for a detail model.
    let exact = bin()
        .args([
            "slices",
            model.to_str().unwrap(),
            "-o",
            slices.to_str().unwrap(),
        ])
        .args(["--distance", "exact"])
        .output()
        .unwrap();
    assert_eq!(exact.status.code(), Some(2), "{}", stderr_of(&exact));

    // And for `run` it is refused before any work.
    let refused = run(&["--slice-distance", "exact"]);
    assert_eq!(refused.status.code(), Some(2), "{}", stderr_of(&refused));

    // `fit --mode detail` writes the same kind of file.
    let fitted = dir.path().join("fit.mpu");
    let fit = bin()
        .args([
            "fit",
            input.to_str().unwrap(),
            "-o",
            fitted.to_str().unwrap(),
        ])
        .args(["--mode", "detail"])
        .output()
        .unwrap();
    assert!(fit.status.success(), "{}", stderr_of(&fit));
    assert!(fs::read(&fitted).unwrap().starts_with(b"stablesurf.mpu"));
}

/// Runs `stablesurf ARGS` and asserts a usage error (exit 2) whose stderr holds every one of
/// `needles`; returns stderr.
fn assert_usage_error(args: &[&str], needles: &[&str]) -> String {
    // In an empty directory, so that relative outputs land there if a check is missing.
    let cwd = tempfile::tempdir().unwrap();
    let out = bin().current_dir(cwd.path()).args(args).output().unwrap();
    let err = stderr_of(&out);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
    for n in needles {
        assert!(err.contains(n), "{args:?}: expected {n:?} in: {err}");
    }
    // Not clap's "to pass '-1' as a value, use '-- -1'" tip: negative values are values.
    assert!(!err.contains("-- -"), "{args:?}: {err}");
    err
}

#[test]
fn thread_count_out_of_range_is_a_usage_error() {
    // `-j 100000` used to try to spawn 100,000 threads and fail with "Resource temporarily
    // unavailable (os error 11)".
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 100, "");
    let input = input.to_str().unwrap();
    for j in ["100000", "257", "0", "-1"] {
        assert_usage_error(&["-j", j, "info", input], &["-j", "1 to 256"]);
    }
    let ok = bin().args(["-j", "2", "info", input]).output().unwrap();
    assert!(ok.status.success(), "{}", stderr_of(&ok));
}

#[test]
fn negative_values_are_values_and_out_of_range() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.ply");
    let missing = missing.to_str().unwrap();
    let out = dir.path().join("out");
    let out = out.to_str().unwrap();
    for kappa in [&["--kappa", "-1"][..], &["--kappa=-1"]] {
        let mut args = vec!["run", missing, "-o", out];
        args.extend_from_slice(kappa);
        assert_usage_error(&args, &["--kappa", "auto or a number from 0 to 1000", "-1"]);
    }
    assert_usage_error(
        &["run", missing, "-o", out, "--depth", "-1"],
        &["--depth", "1 to 12"],
    );
    assert_usage_error(
        &["mesh", missing, "-o", "x.ply", "--depth", "-1"],
        &["--depth", "1 to 12"],
    );
    assert_usage_error(
        &["run", missing, "-o", out, "--epsilon", "-0.05"],
        &["--epsilon", "1e-4 to 0.5"],
    );
}

#[test]
fn degree_range_in_help_is_the_one_checked() {
    let help = bin().args(["run", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&help.stdout).into_owned();
    assert!(
        help.contains("Polynomial degree, even for automatic κ [range: 2 to 14]"),
        "{help}"
    );
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.ply");
    let missing = missing.to_str().unwrap();
    // `--degree 20` used to be accepted (and ran for minutes); `--degree 1` too.
    for d in ["1", "15", "20"] {
        assert_usage_error(
            &[
                "fit", missing, "-o", "m.json", "--degree", d, "--kappa", "1e-3",
            ],
            &["--degree", "2 to 14"],
        );
    }
    // In range, the command goes on to read the (missing) file: exit 1.
    let o = bin()
        .current_dir(dir.path())
        .args(["fit", missing, "-o", "m.json", "--degree", "14"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr_of(&o));
}

#[test]
fn huge_kappa_and_epsilon_name_their_flag() {
    // They used to reach the fit and fail there, blaming outliers or a singular system.
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let input = input.to_str().unwrap();
    assert_usage_error(
        &["fit", input, "-o", "m.json", "--kappa", "1e308"],
        &["--kappa", "0 to 1000", "1e308"],
    );
    assert_usage_error(
        &["fit", input, "-o", "m.json", "--epsilon", "1e308"],
        &["--epsilon", "1e-4 to 0.5", "1e308"],
    );
    assert_usage_error(
        &["fit", input, "-o", "m.json", "--kappa", "nan"],
        &["--kappa", "0 to 1000"],
    );
}

#[test]
fn every_numeric_flag_is_checked_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    // Missing files: a flag that passed its check would go on to fail reading them (exit 1).
    let scan = dir.path().join("missing.ply");
    let scan = scan.to_str().unwrap();
    let model = dir.path().join("missing.json");
    let model = model.to_str().unwrap();
    let cases: &[(&[&str], &str, &str)] = &[
        (
            &["run", scan, "-o", "o", "--degree", "16"],
            "--degree",
            "2 to 14",
        ),
        (
            &["run", scan, "-o", "o", "--degree", "2.5"],
            "--degree",
            "2 to 14",
        ),
        (
            &["run", scan, "-o", "o", "--kappa", "1e4"],
            "--kappa",
            "0 to 1000",
        ),
        (
            &["run", scan, "-o", "o", "--epsilon", "0"],
            "--epsilon",
            "1e-4 to 0.5",
        ),
        (
            &["run", scan, "-o", "o", "--epsilon", "0.6"],
            "--epsilon",
            "1e-4 to 0.5",
        ),
        (
            &["run", scan, "-o", "o", "--epsilon", "inf"],
            "--epsilon",
            "1e-4 to 0.5",
        ),
        (
            &["run", scan, "-o", "o", "--tolerance", "0"],
            "--tolerance",
            "1e-6 to 0.5",
        ),
        (
            &["run", scan, "-o", "o", "--tolerance", "1e-7"],
            "--tolerance",
            "1e-6 to 0.5",
        ),
        (
            &["fit", scan, "-o", "m", "--tolerance", "0.75"],
            "--tolerance",
            "1e-6 to 0.5",
        ),
        (
            &["run", scan, "-o", "o", "--fit-stride", "0"],
            "--fit-stride",
            "1 to 4096",
        ),
        (
            &["fit", scan, "-o", "m", "--fit-stride", "5000"],
            "--fit-stride",
            "1 to 4096",
        ),
        (
            &["run", scan, "-o", "o", "--local-degree", "5"],
            "--local-degree",
            "2 to 4",
        ),
        (
            &["fit", scan, "-o", "m", "--local-degree", "1"],
            "--local-degree",
            "2 to 4",
        ),
        (
            &["run", scan, "-o", "o", "--depth", "13"],
            "--depth",
            "1 to 12",
        ),
        (
            &["run", scan, "-o", "o", "--depth", "0"],
            "--depth",
            "1 to 12",
        ),
        (
            &["mesh", model, "-o", "x.ply", "--depth", "13"],
            "--depth",
            "1 to 12",
        ),
        (
            &["slices", model, "-o", "d", "--depth", "0"],
            "--depth",
            "1 to 12",
        ),
        (
            &["run", scan, "-o", "o", "--slice-count", "0"],
            "--slice-count",
            "1 to 1024",
        ),
        (
            &["run", scan, "-o", "o", "--slice-count", "5000"],
            "--slice-count",
            "1 to 1024",
        ),
        (
            &["run", scan, "-o", "o", "--slice-resolution", "1"],
            "--slice-resolution",
            "2 to 4096",
        ),
        (
            &["run", scan, "-o", "o", "--slice-resolution", "16384"],
            "--slice-resolution",
            "2 to 4096",
        ),
        (
            &["slices", model, "-o", "d", "--count", "0"],
            "--count",
            "1 to 1024",
        ),
        (
            &["slices", model, "-o", "d", "--count", "-3"],
            "--count",
            "1 to 1024",
        ),
        (
            &["slices", model, "-o", "d", "--resolution", "8192"],
            "--resolution",
            "2 to 4096",
        ),
        (
            &["render", scan, "-o", "p.png", "--size", "8"],
            "--size",
            "16 to 8192",
        ),
        (
            &["render", scan, "-o", "p.png", "--size", "-800"],
            "--size",
            "16 to 8192",
        ),
        (
            &["mesh", model, "-o", "x.ply", "--bounds", "0,0,0,1e308,1,1"],
            "--bounds",
            "-1e15 to 1e15",
        ),
        (
            &["slices", model, "-o", "d", "--bounds", "-1e16,0,0,1,1,1"],
            "--bounds",
            "-1e15 to 1e15",
        ),
        (
            &["mesh", model, "-o", "x.ply", "--bounds", "0,0,0,0,1,1"],
            "--bounds",
            "min below its max",
        ),
    ];
    for (args, flag, range) in cases {
        assert_usage_error(args, &[flag, range]);
    }
}

#[test]
fn help_prints_every_range() {
    let help = |sub: &str| {
        let o = bin().args([sub, "--help"]).output().unwrap();
        assert!(o.status.success());
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    // `run` takes the fit's flags and the meshing, slicing and thread flags.
    let fit_ranges = [
        "[range: 2 to 14]",
        "[range: 0 to 1000]",
        "[range: 1e-4 to 0.5]",
        "[range: 2 to 4]",
        "[range: 1e-6 to 0.5]",
    ];
    let run_only_ranges = [
        "[range: 1 to 12]",
        "[range: 1 to 1024]",
        "[range: 2 to 4096]",
        "[range: 1 to 256]",
        "[range: 1 to 1e9]",
    ];
    let run = help("run");
    for range in fit_ranges.iter().chain(&run_only_ranges) {
        assert!(run.contains(range), "run --help lacks {range}:\n{run}");
    }
    let fit = help("fit");
    for range in fit_ranges {
        assert!(fit.contains(range), "fit --help lacks {range}:\n{fit}");
    }
    let mesh = help("mesh");
    assert!(
        mesh.contains("[range: 1 to 12]")
            && mesh.contains("-1e15 to 1e15")
            && mesh.contains("[range: 1 to 1e9]"),
        "{mesh}"
    );
    let slices = help("slices");
    for range in [
        "[range: 1 to 12]",
        "[range: 1 to 1024]",
        "[range: 2 to 4096]",
        "-1e15 to 1e15",
    ] {
        assert!(
            slices.contains(range),
            "slices --help lacks {range}:\n{slices}"
        );
    }
    assert!(help("render").contains("[range: 16 to 8192]"));
}

/// An OBJ file of 300 sphere points (centre (1, 2, 3), radius 2, coordinates on a 1/1024 grid)
/// and 500 faces over 1,500 more vertices whose corners coincide (even faces) or lie on one line
/// (odd faces; exact in binary, so exactly collinear).
fn degenerate_faces_obj(dir: &Path) -> PathBuf {
    let n = 300;
    let grid = |x: f64| (x * 1024.0).round() / 1024.0;
    let mut sphere = Vec::new();
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let t = 2.399_963_229_728_653 * i as f64;
        sphere.push([
            grid(1.0 + 2.0 * r * t.cos()),
            grid(2.0 + 2.0 * r * t.sin()),
            grid(3.0 + 2.0 * z),
        ]);
    }
    let mut text = String::new();
    for p in &sphere {
        text += &format!("v {} {} {}\n", p[0], p[1], p[2]);
    }
    for f in 0..500 {
        let p = sphere[f % n];
        let step = if f % 2 == 0 { 0.0 } else { 1.0 / 64.0 };
        for k in 0..3 {
            let s = k as f64 * step;
            text += &format!("v {} {} {}\n", p[0] + s, p[1] + 2.0 * s, p[2] + 3.0 * s);
        }
    }
    for f in 0..500 {
        let v = n + 3 * f + 1;
        text += &format!("f {} {} {}\n", v, v + 1, v + 2);
    }
    let path = dir.join("degenerate.obj");
    fs::write(&path, text).unwrap();
    path
}

#[test]
fn auto_normals_on_degenerate_faces_use_the_crust() {
    let dir = tempfile::tempdir().unwrap();
    let input = degenerate_faces_obj(dir.path());
    let info = bin().args(["info", "--json"]).arg(&input).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    assert_eq!(v["triangles"], 500);

    let out = bin()
        .arg("normals")
        .arg(&input)
        .arg("-o")
        .arg(dir.path().join("n.ply"))
        .output()
        .unwrap();
    let err = stderr_of(&out);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("all 500 faces are degenerate") && err.contains("normals from the crust"),
        "{err}"
    );
    assert!(err.contains("oriented normals from crust"), "{err}");

    let out = bin()
        .arg("normals")
        .arg(&input)
        .args(["--normals", "mesh", "-o"])
        .arg(dir.path().join("m.ply"))
        .output()
        .unwrap();
    let err = stderr_of(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("all 500 faces of the input are degenerate") && !err.contains("no faces"),
        "{err}"
    );
}

/// Every warning of the run (the fit's own, such as a κ that fell back, included) is printed
/// on stderr and listed in report.json.
#[test]
fn every_warning_in_the_report_is_printed() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    let out = dir.path().join("out");
    let done = run_ok(
        &input,
        &out,
        &flags("--mode global --degree 4 --depth 5 --formats json --no-cache"),
    );
    let stderr = stderr_of(&done);
    let report = read_report(&out);
    let listed: Vec<&str> = report["warnings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|w| w.as_str().unwrap())
        .collect();
    let fit_warnings = report["fit"]["diagnostics"]["warnings"].as_array().unwrap();
    assert!(
        !fit_warnings.is_empty(),
        "this case's κ falls back: {report}"
    );
    for w in fit_warnings {
        assert!(
            listed.contains(&w.as_str().unwrap()),
            "{w} not in {listed:?}"
        );
    }
    for w in &listed {
        assert!(
            stderr.contains(&format!("warning: {w}")),
            "{w} not printed:\n{stderr}"
        );
    }
}

/// A zero set that leaves the meshing box (a plane fitted to a flat patch) is reported as
/// clipped and not bounded, on stderr and in report.json.
#[test]
fn a_clipped_zero_set_is_not_reported_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let mut text = String::new();
    for i in 0..20 {
        for j in 0..20 {
            let (x, y) = (f64::from(i) / 19.0, f64::from(j) / 19.0);
            let z = 0.05 * (x * x + y * y);
            text += &format!("{x} {y} {z} 0 0 1\n");
        }
    }
    let input = dir.path().join("patch.xyz");
    fs::write(&input, text).unwrap();
    let out = dir.path().join("out");
    let done = run_ok(
        &input,
        &out,
        &flags("--mode global --degree 2 --kappa 0 --depth 5 --formats json --no-cache"),
    );
    let stderr = stderr_of(&done);
    assert!(stderr.contains("clipped by the meshing box"), "{stderr}");
    let report = read_report(&out);
    assert!(
        report["mesh"]["boundary_edges"].as_u64().unwrap() > 0,
        "{report}"
    );
    assert_eq!(report["fit"]["clipped"], true);
    assert_eq!(report["fit"]["diagnostics"]["bounded"], false);
}

/// `run` fits the detail model unless told otherwise, and says so; `--mode global` gives the
/// one polynomial.
#[test]
fn run_defaults_to_detail_mode_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let out = dir.path().join("out");
    let done = run_ok(&input, &out, &flags("--formats json --no-cache --depth 5"));
    let stderr = stderr_of(&done);
    assert!(stderr.contains("mode detail by default"), "{stderr}");
    assert!(out.join("model.mpu").is_file() && !out.join("model.json").exists());
    let report = read_report(&out);
    assert_eq!(report["fit"]["mode"], "detail");
    let global = dir.path().join("global");
    let done = run_ok(
        &input,
        &global,
        &flags("--mode global --degree 4 --depth 5 --formats json --no-cache"),
    );
    assert!(!stderr_of(&done).contains("by default"));
    assert!(global.join("model.json").is_file());
}

/// Detail mode leaves out unsupported pieces by default (`keep data`), global mode keeps every
/// piece of the polynomial's zero set; `--keep` overrides either, and the first line says which.
#[test]
fn keep_defaults_follow_the_mode() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    let header = |extra: &[&str]| {
        let done = bin()
            .arg("run")
            .arg(&input)
            .arg("-o")
            .arg(dir.path().join("out"))
            .args(flags("--formats json --no-cache --depth 4 --degree 4"))
            .args(extra)
            .output()
            .unwrap();
        assert!(done.status.success(), "{}", stderr_of(&done));
        stderr_of(&done)
            .lines()
            .next()
            .unwrap_or_default()
            .to_string()
    };
    assert!(header(&[]).contains("keep data"));
    assert!(header(&["--keep", "all"]).contains("keep all"));
    assert!(header(&["--mode", "global"]).contains("keep all"));
    assert!(header(&["--mode", "global", "--keep", "data"]).contains("keep data"));
}

/// Writes a half cylinder patch (radius 1, axis z, angle 0 to π, height 0 to 2) as `n_around`
/// × `n_up` points with exact outward normals; its area is 2π.
fn half_cylinder_xyz(dir: &Path, n_around: usize, n_up: usize) -> PathBuf {
    let mut text = String::from("# half cylinder, radius 1, height 2\n");
    for j in 0..n_up {
        let z = 2.0 * (j as f64 + 0.5) / n_up as f64;
        for i in 0..n_around {
            let t = std::f64::consts::PI * (i as f64 + 0.5) / n_around as f64;
            let (c, s) = (t.cos(), t.sin());
            text += &format!("{c} {s} {z} {c} {s} 0\n");
        }
    }
    let path = dir.join("half_cylinder.xyz");
    fs::write(&path, text).unwrap();
    path
}

/// `run` with `--formats ply,json` and the extra flags; returns report.json and the mesh bytes.
fn run_report(input: &Path, out: &Path, extra: &[&str]) -> (serde_json::Value, Vec<u8>) {
    let mut flags = vec!["--formats", "ply,json", "--no-cache", "-q"];
    flags.extend_from_slice(extra);
    run_ok(input, out, &flags);
    (read_report(out), fs::read(out.join("mesh.ply")).unwrap())
}

#[test]
fn an_open_patch_is_trimmed_to_a_manifold_patch_with_one_boundary() {
    // The detail blend of a half cylinder runs on past its edges; trimmed, the mesh is one
    // manifold patch with one boundary loop, at least 98% of its area within 1% of the
    // diagonal (3) of the data, and its area within 5% of the analytic 2π: the cut lies up to
    // two sample spacings (2 × 0.013, under 1% of the diagonal) outside the data's edge, which
    // is 2π + 4 long, at most 0.27 (4.3%) of extra area.
    let dir = tempfile::tempdir().unwrap();
    let input = half_cylinder_xyz(dir.path(), 240, 160);
    let (untrimmed, _) = run_report(&input, &dir.path().join("off"), &["--trim", "off"]);
    let (report, _) = run_report(&input, &dir.path().join("auto"), &[]);
    let mesh = &report["mesh"];
    assert_eq!(mesh["components"], 1, "{mesh}");
    assert_eq!(mesh["boundary_loops"], 1, "{mesh}");
    assert_eq!(mesh["non_manifold_edges"], 0, "{mesh}");
    assert_eq!(mesh["non_manifold_vertices"], 0, "{mesh}");
    assert_eq!(mesh["self_intersecting_faces"], 0, "{mesh}");
    assert_eq!(mesh["orientation_consistent"], true, "{mesh}");
    assert_eq!(mesh["watertight"], false, "{mesh}");
    let trim = &report["trim"];
    assert_eq!(trim["open"], true, "{trim}");
    assert!(trim["removed_triangles"].as_u64().unwrap() > 0, "{trim}");
    let far = |r: &serde_json::Value| r["accuracy"]["mesh_to_data"]["far_area_share"].as_f64();
    assert!(far(&untrimmed).unwrap() > 0.1, "{}", untrimmed["accuracy"]);
    assert!(
        far(&report).unwrap() <= 0.02,
        "{} {}",
        report["accuracy"],
        report["trim"]
    );
    let area = report["accuracy"]["mesh_to_data"]["area"].as_f64().unwrap();
    let exact = 2.0 * std::f64::consts::PI;
    assert!(
        (area - exact).abs() <= 0.1 * exact,
        "area {area}, exact {exact}"
    );
    println!(
        "half cylinder: area {area:.4} (exact {exact:.4}), far share {:.2e}, removed {:.1}% of the area",
        far(&report).unwrap(),
        100.0 * trim["removed_area_share"].as_f64().unwrap()
    );
}

#[test]
fn a_closed_scan_is_not_trimmed() {
    // Every triangle of a sphere's mesh is supported: `--trim auto` gives the bytes of
    // `--trim off`, watertight.
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 3000, "");
    let flags = ["--depth", "5"];
    let (auto, auto_bytes) = run_report(&input, &dir.path().join("auto"), &flags);
    let (_, off_bytes) = run_report(
        &input,
        &dir.path().join("off"),
        &["--depth", "5", "--trim", "off"],
    );
    assert!(auto_bytes == off_bytes, "trimming changed a closed mesh");
    assert_eq!(auto["mesh"]["watertight"], true);
    assert_eq!(auto["mesh"]["boundary_loops"], 0);
    assert_eq!(auto["trim"]["removed_triangles"], 0);
    assert_eq!(auto["trim"]["open"], false);
}

#[test]
fn trim_values_are_checked_before_any_work() {
    for bad in ["0.1", "-2", "sometimes", "1e9"] {
        assert_usage_error(
            &["run", "missing.ply", "-o", "out", "--trim", bad],
            &["--trim takes auto, off or a number from 0.5 to 100"],
        );
    }
}

/// The Chamfer distance (symmetric mean, relative to the data's diagonal) of Open3D's Poisson
/// reconstruction of bun000 at depth 8, trimmed at the 5% density quantile, from the same
/// points and the normals `stablesurf normals` gives (data → mesh exact, mesh → data over 10
/// area-weighted samples per triangle).
const BUN000_POISSON_CHAMFER: f64 = 1.026e-3;

/// Runs the default `run` on the raw scan `relative` (under ../shared) and checks that it is a
/// clean open patch: manifold, consistently wound, without self-intersections, with a boundary,
/// at most 2% of its area farther than 1% of the diagonal from the data, and a Chamfer distance
/// at or below `poisson_chamfer`.
fn assert_clean_open_patch(relative: &str, what: &str, poisson_chamfer: f64) {
    let Some(data) = shared(relative, what) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (report, _) = run_report(&data, &dir.path().join("out"), &[]);
    let mesh = &report["mesh"];
    assert_eq!(mesh["non_manifold_edges"], 0, "{mesh}");
    assert_eq!(mesh["non_manifold_vertices"], 0, "{mesh}");
    assert_eq!(mesh["self_intersecting_faces"], 0, "{mesh}");
    assert_eq!(mesh["orientation_consistent"], true, "{mesh}");
    assert!(mesh["boundary_loops"].as_u64().unwrap() >= 1, "{mesh}");
    let accuracy = &report["accuracy"];
    let far = accuracy["mesh_to_data"]["far_area_share"].as_f64().unwrap();
    assert!(far <= 0.02, "{accuracy}");
    let chamfer = accuracy["chamfer_relative"].as_f64().unwrap();
    assert!(chamfer <= poisson_chamfer, "{accuracy}");
    println!("{relative}: Chamfer {chamfer:.3e} of the diagonal, {far:.2e} of the area far");
}

#[test]
fn a_single_range_scan_becomes_a_clean_open_patch() {
    // One raw Stanford range scan (one side of the bunny): before trimming, 69% of the mesh's
    // area lay more than 1% of the diagonal from the data.
    assert_clean_open_patch(
        "data/bun000.ply",
        "the range-scan patch check",
        BUN000_POISSON_CHAMFER,
    );
}

/// Open3D's Poisson depth 8 of the top view `bunny-scans/top2.ply`, trimmed at the 5% density
/// quantile, measured as [`BUN000_POISSON_CHAMFER`] (tools/bench_scans.py).
const TOP2_POISSON_CHAMFER: f64 = 1.49e-3;

#[test]
fn a_top_view_loses_the_bulge_under_its_unseen_side() {
    // Seen from above, the bunny's underside is unseen; the blend closes it with a bulge up to
    // 8% of the diagonal below the data (7% of the area), enclosed by supported surface. The
    // trim opens the mesh elsewhere, so the bulge goes too.
    assert_clean_open_patch(
        "data/bunny-scans/top2.ply",
        "the top-view patch check",
        TOP2_POISSON_CHAMFER,
    );
}

#[test]
fn shared_models_keep_their_topology_without_self_intersections() {
    // quadknot: a knotted tube (genus 1) of 1,440 points, whose local fits could bridge the
    // gaps where the tube passes itself; teapot: spout and handle meet the body, where edge
    // collapses can make crossings.
    // The teapot file is not a closed manifold, so only the quadknot has a genus to keep.
    for (file, euler) in [("quadknot.obj", Some(0)), ("teapot.obj", None)] {
        let Some(data) = shared(&format!("data/{file}"), "the shared models' topology") else {
            continue;
        };
        let dir = tempfile::tempdir().unwrap();
        let (report, _) = run_report(&data, &dir.path().join("out"), &[]);
        let mesh = &report["mesh"];
        assert_eq!(mesh["components"], 1, "{file}: {mesh}");
        assert_eq!(mesh["watertight"], true, "{file}: {mesh}");
        assert_eq!(mesh["self_intersecting_faces"], 0, "{file}: {mesh}");
        if let Some(euler) = euler {
            assert_eq!(mesh["euler_characteristic"], euler, "{file}: {mesh}");
        }
    }
}

#[test]
fn a_crossing_that_survives_the_simplified_mesh_is_remade_without_collapses_around_it() {
    // The teapot meshed at level 7 everywhere (no coarser level between the data points): an
    // edge collapse where spout and handle meet the body makes a crossing on the very positions
    // it was judged on, so the stage makes the collapses again with the vertices around it
    // pinned (the mesh there is the one without collapses), and the crossing is gone.
    let Some(data) = shared("data/teapot.obj", "the polygonize fallback") else {
        return;
    };
    let mut config = PipelineConfig::for_mode(Mode::Detail);
    config.polygonize.data_levels = 0;
    let out = reconstruct(&ScanSource::File(data), &config, &mut Silent).unwrap();
    let polygonize = out
        .report
        .stages
        .iter()
        .find(|s| s.stage == "polygonize")
        .unwrap();
    let StageFigures::Polygonize(figures) = &polygonize.figures else {
        panic!("{:?}", polygonize.figures);
    };
    assert!(figures.simplified, "{figures:?}");
    let pinned = figures.pinned_vertices;
    // A few rings around the crossing, not the whole mesh (about 65,000 vertices).
    assert!(pinned > 0 && pinned < 2_000, "{figures:?}");
    assert_eq!(out.report.mesh.self_intersecting_faces, 0);
    assert!(out.report.mesh.watertight);
    assert_eq!(out.report.mesh.components, 1);
}

#[test]
fn viewpoint_is_checked_and_turns_every_normal_toward_it() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let input = input.to_str().unwrap();
    for bad in ["1,2", "1,2,3,4", "a,0,0", "1e16,0,0", "0,nan,0"] {
        assert_usage_error(
            &["normals", input, "-o", "n.ply", "--viewpoint", bad],
            &["--viewpoint", "three numbers X,Y,Z"],
        );
    }
    // The sphere's centre is (1, 2, 3): seen from there, every outward normal turns inward.
    let out_ply = dir.path().join("n.ply");
    let out = bin()
        .args(["-v", "normals", input, "-o"])
        .arg(&out_ply)
        .args(["--viewpoint", "1,2,3"])
        .output()
        .unwrap();
    let err = stderr_of(&out);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("turned 400 of 400 normals to face the viewpoint (1, 2, 3)"),
        "{err}"
    );
    // From far below (-z), the upper half turns: its normals pointed away.
    let out = bin()
        .args(["-v", "normals", input, "-o"])
        .arg(&out_ply)
        .args(["--viewpoint", "1,2,-1e6"])
        .output()
        .unwrap();
    let err = stderr_of(&out);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("turned 200 of 400 normals"), "{err}");
}

#[test]
fn conf_files_and_several_scans_merge_and_bad_lines_name_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let conf = dir.path().join("views.conf");
    // The same sphere twice, both with the identity pose.
    fs::write(
        &conf,
        "camera 0 0 5 0 0 0 1\n# two views\nbmesh sphere.xyz 0 0 0 0 0 0 1\n\nbmesh sphere.xyz 0 0 0 0 0 0 1\n",
    )
    .unwrap();
    let out = bin()
        .args(["run"])
        .arg(&conf)
        .arg("-o")
        .arg(dir.path().join("out"))
        .args(["--formats", "json", "--no-cache", "--json"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr_of(&out));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let merge = report["stages"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["stage"] == "merge")
        .expect("a merge stage");
    assert_eq!(merge["figures"]["points"], 800);
    assert_eq!(report["mesh"]["components"], 1);
    // Several files: the same merge with identity poses.
    let out = bin()
        .args(["run"])
        .args([&input, &input])
        .arg("-o")
        .arg(dir.path().join("out2"))
        .args(["--formats", "json", "--no-cache"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr_of(&out));
    fs::write(&conf, "bmesh sphere.xyz 0 0 0 0 0 0 1\nscan sphere.xyz\n").unwrap();
    let out = bin()
        .args(["run"])
        .arg(&conf)
        .arg("-o")
        .arg(dir.path().join("out3"))
        .args(["--no-cache"])
        .output()
        .unwrap();
    let err = stderr_of(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("views.conf:2"), "{err}");
    assert!(!dir.path().join("out3").exists());
}

#[test]
fn normals_fit_moments_and_info_read_a_conf_and_render_says_what_it_is() {
    let dir = tempfile::tempdir().unwrap();
    sphere_xyz(dir.path(), 400, "");
    let conf = dir.path().join("views.conf");
    // The second view is a quarter turn about z (R(q)ᵀ takes y to x) and a shift of 10 in x.
    let h = std::f64::consts::FRAC_1_SQRT_2;
    fs::write(
        &conf,
        format!("bmesh sphere.xyz 0 0 0 0 0 0 1\nbmesh sphere.xyz 10 0 0 0 0 {h} {h}\n"),
    )
    .unwrap();
    let (points, crust) = (dir.path().join("n.ply"), dir.path().join("crust.ply"));
    let out = bin()
        .arg("normals")
        .arg(&conf)
        .arg("-o")
        .arg(&points)
        .arg("--mesh")
        .arg(&crust)
        .args(["--normals", "crust"])
        .output()
        .unwrap();
    let err = stderr_of(&out);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("sphere.xyz: 400 oriented normals from crust"),
        "{err}"
    );
    assert!(
        err.contains("800 oriented normals in the common frame"),
        "{err}"
    );
    let read =
        |path: &Path| stablesurf::import::import_bytes(&fs::read(path).unwrap(), path).unwrap();
    let (cloud, mesh) = (read(&points), read(&crust));
    assert_eq!(cloud.points.len(), 800);
    let normals = cloud.normals.as_ref().expect("normals in the PLY");
    // The second view is the first one moved: p = (y + 10, -x, z), n = (n_y, -n_x, n_z), within
    // the f32 rounding of the PLY (1e-5 at coordinates up to 13).
    for i in 0..400 {
        let (p, q) = (cloud.points[i], cloud.points[400 + i]);
        let (n, m) = (normals[i], normals[400 + i]);
        let moved = [p[1] + 10.0, -p[0], p[2]];
        let turned = [n[1], -n[0], n[2]];
        for k in 0..3 {
            assert!(
                (q[k] - moved[k]).abs() < 1e-5,
                "point {i}: {q:?} vs {moved:?}"
            );
            assert!(
                (m[k] - turned[k]).abs() < 1e-5,
                "normal {i}: {m:?} vs {turned:?}"
            );
        }
        // Outward on the sphere of centre (1, 2, 3) in the first view's frame.
        let r = [p[0] - 1.0, p[1] - 2.0, p[2] - 3.0];
        assert!(
            r[0] * n[0] + r[1] * n[1] + r[2] * n[2] > 0.0,
            "normal {i} inward"
        );
    }
    // Each view's crust, the second's indices moved past the first's points: the same
    // triangles twice.
    let tris = &mesh.triangles;
    assert!(!tris.is_empty() && tris.len() % 2 == 0);
    let (first, second) = tris.split_at(tris.len() / 2);
    assert!(first.iter().flatten().all(|&i| i < 400));
    for (a, b) in first.iter().zip(second) {
        assert_eq!(a.map(|i| i + 400), *b);
    }

    // `fit` and `moments` merge the same views.
    let model = dir.path().join("model.json");
    let out = bin()
        .args(["-q", "fit"])
        .arg(&conf)
        .arg("-o")
        .arg(&model)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr_of(&out));
    assert!(model.exists());
    let part = moments_part(&conf, &dir.path().join("p.moments"), &[]);
    assert!(part.exists());

    // `info` lists the views; the box is the merged one: the sphere (x 1 ± 2) and its copy
    // moved to x = 10 + y (y 2 ± 2), within the Fibonacci lattice's reach of the poles and
    // the equator (1e-2).
    let out = bin().args(["info", "--json"]).arg(&conf).output().unwrap();
    assert!(out.status.success(), "{}", stderr_of(&out));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(
        (v["views"].as_u64(), v["points"].as_u64()),
        (Some(2), Some(800))
    );
    assert_eq!(
        v["scans"][1]["translation"],
        serde_json::json!([10.0, 0.0, 0.0])
    );
    let (lo, hi) = (
        v["bbox_min"][0].as_f64().unwrap(),
        v["bbox_max"][0].as_f64().unwrap(),
    );
    assert!(
        (lo + 1.0).abs() < 1e-2 && (hi - 14.0).abs() < 1e-2,
        "{lo} {hi}"
    );

    // A command that takes one scan names the file and says where it goes.
    let png = dir.path().join("p.png");
    let out = bin()
        .arg("render")
        .arg(&conf)
        .arg("-o")
        .arg(&png)
        .output()
        .unwrap();
    let err = stderr_of(&out);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("views.conf: a .conf registration lists scans"),
        "{err}"
    );
    assert!(
        err.contains("`stablesurf run`, `fit`, `normals` or `moments`"),
        "{err}"
    );
    assert!(!png.exists());
}

/// Runs `stablesurf moments` on `chunk` with `flags`; returns the part path.
fn moments_part(chunk: &Path, out: &Path, flags: &[&str]) -> PathBuf {
    let output = bin()
        .args(["-q", "moments"])
        .arg(chunk)
        .arg("-o")
        .arg(out)
        .args(flags)
        .output()
        .unwrap();
    assert!(output.status.success(), "{}", stderr_of(&output));
    out.to_path_buf()
}

#[test]
fn moments_parts_fit_like_the_whole_and_bad_parts_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let whole = sphere_xyz(dir.path(), 600, "");
    let text = fs::read_to_string(&whole).unwrap();
    let lines: Vec<&str> = text.lines().skip(1).collect();
    let chunks: Vec<PathBuf> = (0..2)
        .map(|k| {
            let path = dir.path().join(format!("chunk{k}.xyz"));
            fs::write(&path, lines[k * 300..(k + 1) * 300].join("\n") + "\n").unwrap();
            path
        })
        .collect();
    let fit_flags = ["--degree", "4", "--kappa", "1e-4", "--normals", "input"];
    let mut frame = String::new();
    let mut parts = Vec::new();
    for pass in 1..=3 {
        parts = chunks
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let out = dir.path().join(format!("p{pass}-{k}.moments"));
                let mut flags = fit_flags.to_vec();
                match pass {
                    2 => flags.extend(["--center", frame.as_str()]),
                    3 => flags.extend(["--frame", frame.as_str()]),
                    _ => {}
                }
                moments_part(c, &out, &flags)
            })
            .collect();
        if pass < 3 {
            let out = bin().arg("frame").args(&parts).output().unwrap();
            assert!(out.status.success(), "{}", stderr_of(&out));
            frame = String::from_utf8(out.stdout).unwrap().trim().to_string();
        }
    }
    let model_of = |args: &[&std::ffi::OsStr]| {
        let out = bin()
            .args(["-q", "fit"])
            .args(args)
            .args(fit_flags)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", stderr_of(&out));
    };
    let merged = dir.path().join("merged.json");
    let whole_model = dir.path().join("whole.json");
    let mut args: Vec<&std::ffi::OsStr> =
        vec!["-o".as_ref(), merged.as_os_str(), "--from-moments".as_ref()];
    args.extend(parts.iter().map(|p| p.as_os_str()));
    model_of(&args);
    model_of(&[
        whole.as_os_str(),
        "-o".as_ref(),
        whole_model.as_os_str(),
        "--keep-outliers".as_ref(),
    ]);
    let coefficients = |p: &Path| -> Vec<f64> {
        let v: serde_json::Value = serde_json::from_str(&fs::read_to_string(p).unwrap()).unwrap();
        v["coefficients"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let (a, b) = (coefficients(&merged), coefficients(&whole_model));
    let scale = b.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).abs() <= 1e-9 * scale, "{x} vs {y}");
    }

    // A part of another degree: exit 1, naming that file.
    let d6 = moments_part(
        &chunks[1],
        &dir.path().join("d6.moments"),
        &[
            "--degree",
            "6",
            "--normals",
            "input",
            "--frame",
            frame.as_str(),
        ],
    );
    let out_model = dir.path().join("bad.json");
    let out = bin()
        .args(["fit", "--kappa", "1e-4", "--degree", "4", "-o"])
        .arg(&out_model)
        .arg("--from-moments")
        .arg(&parts[0])
        .arg(&d6)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{}", stderr_of(&out));
    assert!(
        stderr_of(&out).contains("d6.moments"),
        "{}",
        stderr_of(&out)
    );
    assert!(stderr_of(&out).contains("degree 6"), "{}", stderr_of(&out));
    assert!(!out_model.exists());

    // A truncated part: exit 1, naming the file; no model written.
    let bytes = fs::read(&parts[1]).unwrap();
    let cut = dir.path().join("cut.moments");
    fs::write(&cut, &bytes[..bytes.len() - 9]).unwrap();
    let out = bin()
        .args(["fit", "--kappa", "1e-4", "--degree", "4", "-o"])
        .arg(&out_model)
        .arg("--from-moments")
        .arg(&parts[0])
        .arg(&cut)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{}", stderr_of(&out));
    assert!(
        stderr_of(&out).contains("cut.moments"),
        "{}",
        stderr_of(&out)
    );
    assert!(
        stderr_of(&out).contains("truncated or corrupt"),
        "{}",
        stderr_of(&out)
    );
    assert!(!out_model.exists());

    // The stable κ rule needs the points: a usage error saying what to pass.
    let out = bin()
        .args(["fit", "--degree", "4", "-o"])
        .arg(&out_model)
        .arg("--from-moments")
        .args(&parts)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{}", stderr_of(&out));
    assert!(stderr_of(&out).contains("--kappa"), "{}", stderr_of(&out));
}

/// The extent of the positions of a `.glb` written by `run` (its POSITION accessor's min/max).
fn glb_extent(path: &Path) -> [f64; 3] {
    let bytes = fs::read(path).unwrap();
    let len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    let json: serde_json::Value = serde_json::from_slice(&bytes[20..20 + len]).unwrap();
    let accessor = &json["accessors"][0];
    std::array::from_fn(|a| {
        accessor["max"][a].as_f64().unwrap() - accessor["min"][a].as_f64().unwrap()
    })
}

#[test]
fn units_scale_the_gltf_to_metres_and_are_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 2000, "");
    let (plain, mm) = (dir.path().join("plain"), dir.path().join("mm"));
    let common = flags("--mode global --degree 2 --formats glb,ply,exr,json --no-cache -q");
    run_ok(&input, &plain, &common);
    run_ok(&input, &mm, &[&common[..], &["--units", "mm"]].concat());
    // The sphere has radius 2 input units: 4 mm across is 0.004 m in the glTF (f32 values).
    let (a, b) = (
        glb_extent(&plain.join("mesh.glb")),
        glb_extent(&mm.join("mesh.glb")),
    );
    for axis in 0..3 {
        assert!((a[axis] - 4.0).abs() < 0.05, "{a:?}");
        assert!(
            (b[axis] - 0.001 * a[axis]).abs() < 1e-6 * a[axis],
            "{a:?} {b:?}"
        );
    }
    // PLY coordinates stay in input units; the header and the report say which.
    let ply_mm = fs::read(mm.join("mesh.ply")).unwrap();
    let ply_plain = fs::read(plain.join("mesh.ply")).unwrap();
    let header = |b: &[u8]| String::from_utf8_lossy(&b[..200]).into_owned();
    assert!(header(&ply_mm).contains("comment units mm\n"));
    assert!(!header(&ply_plain).contains("units"));
    assert_eq!(
        ply_mm.len(),
        ply_plain.len() + "comment units mm\n".len(),
        "only the comment differs in size"
    );
    assert_eq!(read_report(&mm)["units"], "mm");
    assert!(read_report(&plain).get("units").is_none());
    // OpenEXR's distanceUnits attribute: a string attribute, its length then its bytes.
    let exr = fs::read(mm.join("slices/slice_000.exr")).unwrap();
    let attribute = [&b"distanceUnits\0string\0"[..], &2u32.to_le_bytes(), b"mm"].concat();
    assert!(exr.windows(attribute.len()).any(|w| w == attribute));
    // A unit that is not one of the five is a usage error.
    let bad = bin()
        .args(["run", "-o"])
        .arg(dir.path().join("bad"))
        .args(["--units", "km"])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2), "{}", stderr_of(&bad));
    assert!(!dir.path().join("bad").exists());
}

#[test]
fn info_reads_what_the_tool_writes() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 2000, "");
    let out = dir.path().join("out");
    run_ok(
        &input,
        &out,
        &flags("--mode global --degree 2 --formats glb,gltf,exr,json,vdb,npy --voxel-size 0.2 --no-cache -q"),
    );
    let info = |file: &Path| -> serde_json::Value {
        let done = bin().arg("info").arg(file).arg("--json").output().unwrap();
        assert!(
            done.status.success(),
            "{}: {}",
            file.display(),
            stderr_of(&done)
        );
        serde_json::from_slice(&done.stdout).unwrap()
    };
    let report = read_report(&out);
    for name in ["mesh.glb", "mesh.gltf"] {
        let i = info(&out.join(name));
        assert_eq!(i["generator"], "stablesurf");
        assert_eq!(i["vertices"], report["mesh"]["vertices"], "{name}");
        assert_eq!(i["triangles"], report["mesh"]["faces"], "{name}");
        assert_eq!(i["primitives"][0]["normals"], true);
    }
    let slice = info(&out.join("slices/slice_000.exr"));
    assert_eq!(slice["format"], "openexr");
    assert_eq!(slice["sliceIndex"], 0);
    assert_eq!(slice["signConvention"], "negative inside");
    assert_eq!(slice["voxelSize"].as_array().map(Vec::len), Some(3));
    assert_eq!(info(&out.join("model.json"))["degree"], 2);
    // The volumes: the vdb's grid and its metadata, the npy's header and value range.
    let vdb = info(&out.join("volume.vdb"));
    let grid = &vdb["grids"][0];
    assert_eq!(
        (vdb["format"].as_str(), grid["name"].as_str()),
        (Some("vdb"), Some("surface"))
    );
    assert_eq!(grid["metadata"]["class"], "level set");
    assert!(
        (grid["voxel_size"][0].as_f64().unwrap() - 0.2).abs() < 1e-12,
        "{vdb}"
    );
    let npy = info(&out.join("volume.npy"));
    let sidecar: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("volume.json")).unwrap()).unwrap();
    assert_eq!(
        (npy["format"].as_str(), npy["dtype"].as_str()),
        (Some("npy"), Some("<f4"))
    );
    assert_eq!(npy["shape"], sidecar["shape"]);
    // The sphere of radius 2: the distance is about −2 at its centre, positive at the box's corners.
    assert!(
        npy["min"].as_f64().unwrap() < -1.5 && npy["max"].as_f64().unwrap() > 0.0,
        "{npy}"
    );
    let part = dir.path().join("part.moments");
    let done = bin()
        .arg("moments")
        .arg(&input)
        .arg("-o")
        .arg(&part)
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", stderr_of(&done));
    let m = info(&part);
    assert_eq!(
        (m["format"].as_str(), m["points"].as_u64()),
        (Some("stablesurf.moments"), Some(2000))
    );
    // A damaged file of a known kind is an error naming the file, not a misread.
    let broken = dir.path().join("broken.glb");
    fs::write(&broken, b"glTF\x02\x00\x00\x00garbage").unwrap();
    let done = bin().arg("info").arg(&broken).output().unwrap();
    assert_eq!(done.status.code(), Some(1));
    assert!(
        stderr_of(&done).contains("broken.glb"),
        "{}",
        stderr_of(&done)
    );
}
