//! Reliability tests: the cache owns only what it made and an entry answers only for its own
//! key; a run's outputs land as one set or not at all, whatever fails or kills it; debris of
//! killed runs is cleared by the next run; outliers do not destroy the object.
//!
//! Each test runs the real binary on generated input inside a temporary folder. Faults are
//! injected with `STABLESURF_FAULT` (see `src/outputs.rs`): `abort@N` ends the process at the
//! N-th step of the output writes as `kill -9` would, `enospc@N` fails that step as a full disk.

use std::fs;
use std::path::{Path, PathBuf};

use assert_cmd::Command;

use crate::fixtures::{
    bin, files_under, flags, hidden_names, outputs, read_report, run_ok, sphere_xyz, stderr_of,
};

/// `run INPUT -o OUT --depth DEPTH` with small settings and the cache at `cache`.
fn run_cmd(input: &Path, out: &Path, depth: &str, cache: &Path) -> Command {
    let mut cmd = bin();
    cmd.arg("run")
        .arg(input)
        .arg("-o")
        .arg(out)
        .args(["--mode", "global", "--degree", "4", "--depth", depth])
        .args(["--formats", "glb,ply,png,json", "--slice-count", "2"])
        .args(["--slice-resolution", "16", "--cache-dir"])
        .arg(cache);
    cmd
}

#[test]
fn cache_clear_refuses_a_folder_it_did_not_make() {
    let dir = tempfile::tempdir().unwrap();
    let v = dir.path().join("v");
    fs::create_dir_all(v.join("my_project")).unwrap();
    fs::write(v.join("my_project/thesis.tex"), b"years of work").unwrap();
    for action in ["clear", "info"] {
        let out = bin()
            .args(["cache", action, "--cache-dir"])
            .arg(&v)
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(1), "{action}: {}", stderr_of(&out));
        let err = stderr_of(&out);
        assert!(
            err.contains("is not a stablesurf cache") && err.contains(&v.display().to_string()),
            "{err}"
        );
    }
    assert_eq!(
        fs::read(v.join("my_project/thesis.tex")).unwrap(),
        b"years of work"
    );
    // No folder, or a file: no cache there either.
    let missing = dir.path().join("does-not-exist");
    let out = bin()
        .args(["cache", "clear", "--cache-dir"])
        .arg(&missing)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(
        stderr_of(&out).contains("does not exist"),
        "{}",
        stderr_of(&out)
    );
    assert!(!missing.exists());
    let file = dir.path().join("some-file");
    fs::write(&file, b"data").unwrap();
    let out = bin()
        .args(["cache", "info", "--cache-dir"])
        .arg(&file)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr_of(&out).contains("is a file"), "{}", stderr_of(&out));
    assert_eq!(fs::read(&file).unwrap(), b"data");
    // A run refuses it as its cache too, before any work.
    let input = sphere_xyz(dir.path(), 300, "");
    let out = run_cmd(&input, &dir.path().join("out"), "5", &v)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{}", stderr_of(&out));
    assert!(!dir.path().join("out").exists());
    assert_eq!(fs::read_dir(&v).unwrap().count(), 1);
}

#[test]
fn cache_clear_removes_the_entries_and_keeps_everything_else() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    let cache = dir.path().join("cache");
    let out = run_cmd(&input, &dir.path().join("out"), "5", &cache)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", stderr_of(&out));
    fs::write(cache.join("notes.txt"), b"mine").unwrap();
    let info = bin()
        .args(["cache", "info", "--cache-dir"])
        .arg(&cache)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&info.stdout);
    for stage in ["import", "normals", "fit", "polygonize", "finish", "export"] {
        assert!(text.contains(stage), "{text}");
    }
    let cleared = bin()
        .args(["cache", "clear", "--cache-dir"])
        .arg(&cache)
        .output()
        .unwrap();
    assert!(cleared.status.success(), "{}", stderr_of(&cleared));
    let err = stderr_of(&cleared);
    assert!(
        err.contains("cleared 6 entries") && err.contains("notes.txt"),
        "{err}"
    );
    let mut left: Vec<String> = fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    // The marker and the hit and eviction counts stay with the cache (as ccache's do).
    assert_eq!(left, ["CACHEDIR.TAG", "notes.txt", "stats.json"]);
}

/// The two runs of different degrees into one cache; their export entries swapped; the rerun
/// of the first must not serve the second's files.
#[test]
fn a_cache_entry_moved_onto_another_key_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let cache = dir.path().join("cache");
    let run = |degree: &str, out: &str, verbose: bool| {
        let out = bin()
            .arg("run")
            .arg(&input)
            .arg("-o")
            .arg(dir.path().join(out))
            .args(["--mode", "global", "--degree", degree, "--depth", "5"])
            .args(["--formats", "ply,json"])
            .arg(if verbose { "-v" } else { "-q" })
            .arg("--cache-dir")
            .arg(&cache)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", stderr_of(&out));
        stderr_of(&out)
    };
    run("4", "d4", false);
    run("6", "d6", false);
    let entries: Vec<PathBuf> = fs::read_dir(cache.join("export"))
        .unwrap()
        .flat_map(|shard| fs::read_dir(shard.unwrap().path()).unwrap())
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(entries.len(), 2, "{entries:?}");
    let (a, b) = (
        fs::read(&entries[0]).unwrap(),
        fs::read(&entries[1]).unwrap(),
    );
    fs::write(&entries[0], &b).unwrap();
    fs::write(&entries[1], &a).unwrap();
    let err = run("4", "again", true);
    assert!(
        err.lines()
            .any(|l| l.contains(" export ") && l.contains("corrupt")),
        "{err}"
    );
    assert_eq!(
        fs::read(dir.path().join("again/mesh.ply")).unwrap(),
        fs::read(dir.path().join("d4/mesh.ply")).unwrap()
    );
    let report = read_report(&dir.path().join("again"));
    let first = read_report(&dir.path().join("d4"));
    assert_eq!(report["mesh"], first["mesh"]);
    assert_eq!(report["fit"], first["fit"]);
}

/// An entry re-signed with another stage version, or edited figures, is not a hit.
#[test]
fn an_entry_with_another_identity_or_edited_figures_is_recomputed() {
    use stablesurf::cache::codec::{decode_entry, encode, EntryId};
    use stablesurf::cache::OutputFiles;
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 400, "");
    let cache = dir.path().join("cache");
    let run = |out: &str| {
        let out = bin()
            .arg("run")
            .arg(&input)
            .arg("-o")
            .arg(dir.path().join(out))
            .args(["--mode", "global", "--degree", "4", "--depth", "5"])
            .args(["--formats", "ply,json", "-v", "--cache-dir"])
            .arg(&cache)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", stderr_of(&out));
        stderr_of(&out)
    };
    run("first");
    let shard = fs::read_dir(cache.join("export"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let entry = fs::read_dir(shard).unwrap().next().unwrap().unwrap().path();
    let original = fs::read(&entry).unwrap();
    let decoded = decode_entry::<OutputFiles>(&original).expect("a valid entry");
    let tampered: [(EntryId, serde_json::Value); 3] = [
        (
            EntryId {
                stage_version: decoded.id.stage_version + 1,
                ..decoded.id.clone()
            },
            decoded.meta.clone(),
        ),
        (
            EntryId {
                stage: "fit".into(),
                ..decoded.id.clone()
            },
            decoded.meta.clone(),
        ),
        (
            decoded.id.clone(),
            serde_json::json!({"figures": {"bogus": 1}}),
        ),
    ];
    for (i, (id, meta)) in tampered.into_iter().enumerate() {
        let bytes = encode(&decoded.value, &id, &meta);
        fs::write(&entry, &bytes).unwrap();
        let err = run(&format!("t{i}"));
        let line = err
            .lines()
            .find(|l| l.contains(" export "))
            .unwrap_or_default()
            .to_string();
        // Another version or stage is refused by the identity check; figures that do not
        // read as the stage's report (edited by someone who rewrote the checksum too) are
        // refused when they are read: the stage is recomputed either way.
        assert!(line.contains("corrupt"), "case {i}: {err}");
        let report = read_report(&dir.path().join(format!("t{i}")));
        assert!(report["mesh"]["faces"].as_u64().unwrap() > 0, "{report}");
        assert_eq!(
            fs::read(dir.path().join(format!("t{i}/mesh.ply"))).unwrap(),
            fs::read(dir.path().join("first/mesh.ply")).unwrap()
        );
    }
    // A stray .json beside an entry (as caches of format 1 kept) is never read.
    fs::write(&entry, &original).unwrap();
    fs::write(
        entry.with_extension("json"),
        br#"{"figures": {"bogus": 1}}"#,
    )
    .unwrap();
    let err = run("stray");
    assert!(
        err.lines()
            .any(|l| l.contains(" export ") && l.contains("hit")),
        "{err}"
    );
    let report = read_report(&dir.path().join("stray"));
    assert!(report["mesh"]["faces"].as_u64().unwrap() > 0, "{report}");
}

#[test]
fn a_folder_at_an_entry_path_is_rewritten() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    let cache = dir.path().join("cache");
    let verbose = |out: &str| {
        let mut cmd = run_cmd(&input, &dir.path().join(out), "5", &cache);
        let out = cmd.arg("-v").output().unwrap();
        assert!(out.status.success(), "{}", stderr_of(&out));
        stderr_of(&out)
    };
    verbose("a");
    let shard = fs::read_dir(cache.join("fit"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let entry = fs::read_dir(&shard)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    fs::remove_file(&entry).unwrap();
    fs::create_dir(&entry).unwrap();
    let second = verbose("b");
    assert!(
        second
            .lines()
            .any(|l| l.contains(" fit ") && l.contains("corrupt")),
        "{second}"
    );
    assert!(entry.is_file());
    let third = verbose("c");
    assert!(
        third
            .lines()
            .any(|l| l.contains(" fit ") && l.contains("hit")),
        "{third}"
    );
}

#[test]
fn an_unwritable_output_folder_fails_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    let blocker = dir.path().join("a-file");
    fs::write(&blocker, b"x").unwrap();
    let target = blocker.join("out");
    let mut cmd = run_cmd(&input, &target, "5", &dir.path().join("cache"));
    let out = cmd.arg("-v").output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = stderr_of(&out);
    assert!(err.contains(&target.display().to_string()), "{err}");
    assert!(err.contains("choose another path"), "{err}");
    // No stage ran.
    assert!(!err.contains("stablesurf: import"), "{err}");
    assert!(!dir.path().join("cache").exists());
}

/// A full disk at each step of the writes: exit 1 with the file named, and the folder holds
/// exactly the earlier run's files, no temporaries.
#[test]
fn a_full_disk_leaves_the_earlier_set_untouched() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    let cache = dir.path().join("cache");
    let out = dir.path().join("out");
    let first = run_cmd(&input, &out, "5", &cache).output().unwrap();
    assert!(first.status.success(), "{}", stderr_of(&first));
    let before = files_under(&out);
    // 7 files staged (steps 1-7), the journal (8), 7 moves (9-15).
    for step in [1, 4, 7, 8, 9, 12, 15] {
        let failed = run_cmd(&input, &out, "6", &cache)
            .env("STABLESURF_FAULT", format!("enospc@{step}"))
            .output()
            .unwrap();
        assert_eq!(failed.status.code(), Some(1), "step {step}");
        let err = stderr_of(&failed);
        assert!(
            err.contains(&out.display().to_string()) && err.contains("free space"),
            "step {step}: {err}"
        );
        assert_eq!(
            err.matches("no storage space").count(),
            1,
            "step {step}: {err}"
        );
        assert_eq!(files_under(&out), before, "step {step}");
        assert!(
            hidden_names(&out).is_empty(),
            "step {step}: {:?}",
            hidden_names(&out)
        );
    }
    // Into a new folder: nothing is left at all.
    let fresh = dir.path().join("fresh");
    let failed = run_cmd(&input, &fresh, "6", &cache)
        .env("STABLESURF_FAULT", "enospc@3")
        .output()
        .unwrap();
    assert_eq!(failed.status.code(), Some(1));
    assert!(!fresh.exists());
}

/// Killed at every step of the writes, into a folder holding an earlier run: right after the
/// kill the visible files are the earlier set (or the journal is written and the next run
/// finishes the moves); a normal rerun then gives exactly a clean run's files, and no
/// temporary is left in the output folder or the cache.
#[test]
fn a_run_killed_at_any_write_step_is_made_whole_by_the_next_run() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 300, "");
    let reference = |depth: &str, name: &str| {
        let out = dir.path().join(name);
        let done = run_cmd(
            &input,
            &out,
            depth,
            &dir.path().join(format!("cache-{name}")),
        )
        .output()
        .unwrap();
        assert!(done.status.success(), "{}", stderr_of(&done));
        outputs(&out)
    };
    let old_set = reference("5", "ref5");
    let new_set = reference("6", "ref6");
    assert_ne!(old_set, new_set);
    let cache = dir.path().join("cache");
    // 7 staged files, the journal, 7 moves, the clean-up: 16 steps.
    for step in 1..=16 {
        let out = dir.path().join(format!("killed{step}"));
        assert!(run_cmd(&input, &out, "5", &cache)
            .output()
            .unwrap()
            .status
            .success());
        let killed = run_cmd(&input, &out, "6", &cache)
            .env("STABLESURF_FAULT", format!("abort@{step}"))
            .output()
            .unwrap();
        assert!(!killed.status.success(), "step {step} did not abort");
        let journal = fs::read_dir(&out)
            .unwrap()
            .flatten()
            .any(|e| e.path().join("COMMITTING").exists());
        let visible: Vec<_> = outputs(&out)
            .into_iter()
            .filter(|(n, _)| !n.starts_with('.'))
            .collect();
        if !journal {
            assert!(visible == old_set || visible == new_set, "step {step}");
        }
        let rerun = run_cmd(&input, &out, "6", &cache).output().unwrap();
        assert!(rerun.status.success(), "step {step}: {}", stderr_of(&rerun));
        assert_eq!(outputs(&out), new_set, "step {step}");
        assert!(out.join("report.json").is_file());
        assert!(
            hidden_names(&out).is_empty(),
            "step {step}: {:?}",
            hidden_names(&out)
        );
        assert!(
            hidden_names(&cache).is_empty(),
            "step {step}: {:?}",
            hidden_names(&cache)
        );
    }
}

/// A 4000-point sphere of radius 2 given as bare points (no normals), with eight stray points
/// 0.5 to 1.2 from it (single ones outside and inside, and a group of three): the default run
/// leaves out the strays it finds isolated and the small pieces the others grow, and meshes the
/// sphere alone (one closed genus-0 piece); with the strays kept (`--keep-outliers`) a second
/// piece appears around them.
#[test]
fn stray_points_beside_a_bare_scan_leave_one_closed_surface() {
    let dir = tempfile::tempdir().unwrap();
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut text = String::new();
    for i in 0..4000 {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / 4000.0;
        let r = (1.0 - z * z).sqrt();
        let t = golden * i as f64;
        text += &format!("{} {} {}\n", 2.0 * r * t.cos(), 2.0 * r * t.sin(), 2.0 * z);
    }
    for p in [
        [2.5, 0.0, 0.0],
        [0.0, -2.7, 0.0],
        [0.0, 0.0, 3.0],
        [1.0, 0.6, 0.2],
        [-0.8, 0.0, -1.0],
        [1.8, 1.8, 0.0],
        [1.82, 1.8, 0.0],
        [1.8, 1.82, 0.0],
    ] {
        text += &format!("{} {} {}\n", p[0], p[1], p[2]);
    }
    let input = dir.path().join("strays.xyz");
    fs::write(&input, text).unwrap();
    let run = |name: &str, extra: &str| {
        let out = dir.path().join(name);
        let line = format!("--formats ply,json --no-cache {extra}");
        let done = run_ok(&input, &out, &flags(&line));
        (stderr_of(&done), read_report(&out))
    };
    let (err, report) = run("default", "");
    assert!(
        err.contains("warning: left out 4 of 4008 points in groups"),
        "{err}"
    );
    assert!(
        err.contains("small piece(s) of the surface with fewer than 15 data points"),
        "{err}"
    );
    assert_eq!(report["mesh"]["components"], 1, "{report}");
    assert_eq!(report["mesh"]["watertight"], true, "{report}");
    assert_eq!(report["mesh"]["euler_characteristic"], 2, "{report}");
    let (err, report) = run("kept", "--keep-outliers");
    assert!(!err.contains("points in groups"), "{err}");
    assert!(
        report["mesh"]["components"].as_u64().unwrap() > 1,
        "{report}"
    );
}

/// One point at (1e30, 1e30, 1e30) beside a 500-point sphere: the sphere is meshed as if the
/// point were not there, and the run says it left it out.
#[test]
fn one_far_outlier_is_left_out_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 500, "1e30 1e30 1e30 0 0 1\n");
    let out = dir.path().join("out");
    let done = run_ok(
        &input,
        &out,
        &flags("--mode global --degree 4 --depth 5 --formats ply,json --no-cache"),
    );
    let err = stderr_of(&done);
    assert!(
        err.contains("warning: left out 1 of 501 points") && err.contains("--keep-outliers"),
        "{err}"
    );
    let report = read_report(&out);
    assert_eq!(report["mesh"]["components"], 1, "{report}");
    assert_eq!(report["mesh"]["watertight"], true, "{report}");
    assert!(
        report["mesh"]["vertices"].as_u64().unwrap() > 500,
        "{report}"
    );
    // The sphere's diagonal is 4√3; the mesh lies within 1% of it from every point.
    assert!(
        report["accuracy"]["max_relative"].as_f64().unwrap() < 0.01,
        "{report}"
    );
    assert!(
        report["warnings"][0]
            .as_str()
            .unwrap()
            .contains("left out 1 of 501 points"),
        "{report}"
    );
}
