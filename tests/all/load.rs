//! Load and long use: runs killed and left as zombies, two runs into one folder, a cache under a
//! size limit, and a cache on a full disk.
//!
//! Each test runs the real binary on generated input inside a temporary folder. A killed child
//! that the test does not wait for stays a zombie (its id taken, its process ended), as a run
//! killed in a container whose first process does not reap does.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::fixtures::{bin, hidden_names, outputs, read_report, sphere_xyz, stderr_of};

/// A small run's settings.
const SMALL: &[&str] = &["--mode", "global", "--degree", "4", "--depth", "6"];

/// `stablesurf run INPUT -o OUT --cache-dir CACHE` with small outputs and `extra` flags (the
/// settings, e.g. [`SMALL`]), as a std command (to spawn and kill).
fn run_command(input: &Path, out: &Path, cache: &Path, extra: &[&str]) -> Command {
    let mut cmd = Command::new(assert_cmd::cargo::cargo_bin("stablesurf"));
    cmd.env_remove("XDG_CACHE_HOME")
        .env_remove("STABLESURF_FAULT")
        .env_remove("STABLESURF_CACHE_MAX_SIZE")
        .arg("run")
        .arg(input)
        .arg("-o")
        .arg(out)
        .args(["--formats", "glb,ply,png,json", "--slice-count", "2"])
        .args(["--slice-resolution", "16", "--cache-dir"])
        .arg(cache)
        .args(extra)
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    cmd
}

/// Waits until the process `pid` is a zombie whose threads have all exited (Linux); false
/// after 10 s.
fn became_zombie(pid: u32) -> bool {
    let stat = format!("/proc/{pid}/stat");
    let tasks = format!("/proc/{pid}/task");
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(10) {
        let state = fs::read_to_string(&stat)
            .ok()
            .and_then(|s| s[s.rfind(')')? + 2..].chars().next());
        // The main thread turns zombie before the others have finished exiting, and they hold
        // the open files (the output folder's lock among them) until the last one is gone: a
        // zombie with one task left has ended whole.
        let threads = fs::read_dir(&tasks).map_or(usize::MAX, |d| d.count());
        if state == Some('Z') && threads == 1 {
            return true;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    false
}

/// The reproducer: runs killed with SIGKILL at several moments and left unreaped
/// (zombies), some of them at fixed steps of the output writes; the next run to completion
/// finishes or removes every killed run's staging folder and temporaries, in the output folder
/// and the cache, and leaves exactly a clean run's files.
#[test]
fn killed_runs_left_as_zombies_leave_no_debris_after_the_next_run() {
    if !cfg!(target_os = "linux") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 2000, "");
    let clean = dir.path().join("clean");
    let done = run_command(&input, &clean, &dir.path().join("clean-cache"), SMALL)
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", stderr_of(&done));
    let out = dir.path().join("out");
    let cache = dir.path().join("cache");
    let mut zombies: Vec<Child> = Vec::new();
    // Aborts at a staged file (no journal) and in the moves (journal written), then kills at
    // moments through the run (the cache's temporaries and the staging folder in between).
    for fault in ["abort@2", "abort@9"] {
        let child = run_command(&input, &out, &cache, SMALL)
            .env("STABLESURF_FAULT", fault)
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        assert!(became_zombie(child.id()), "{fault}: no zombie");
        assert!(
            !hidden_names(&out).is_empty(),
            "{fault}: the aborted run left no staging folder to clean"
        );
        zombies.push(child);
    }
    for ms in [30, 80, 150, 300, 600] {
        let mut child = run_command(
            &input,
            &out,
            &cache,
            &["--mode", "global", "--degree", "4", "--depth", "7"],
        )
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
        std::thread::sleep(Duration::from_millis(ms));
        // SIGKILL, and no wait: the child stays a zombie.
        let _ = child.kill();
        zombies.push(child);
    }
    for z in &zombies {
        assert!(became_zombie(z.id()));
    }
    let done = run_command(&input, &out, &cache, SMALL).output().unwrap();
    assert!(done.status.success(), "{}", stderr_of(&done));
    assert!(hidden_names(&out).is_empty(), "{:?}", hidden_names(&out));
    assert_eq!(outputs(&out), outputs(&clean));
    // The cache's lookups swept the folders they read; `cache info` sweeps the rest.
    let info = bin()
        .args(["cache", "info", "--cache-dir"])
        .arg(&cache)
        .output()
        .unwrap();
    assert!(info.status.success(), "{}", stderr_of(&info));
    assert!(
        hidden_names(&cache).is_empty(),
        "{:?}",
        hidden_names(&cache)
    );
    for mut z in zombies {
        z.wait().unwrap();
    }
}

/// A second run into a folder that a live run is writing stops at once: exit 1, the folder
/// named; it writes nothing anywhere, and the first run's outputs land whole.
#[test]
fn a_second_run_into_a_folder_a_live_run_is_writing_exits_1_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let input = sphere_xyz(dir.path(), 20_000, "");
    let out = dir.path().join("out");
    let slow = ["--mode", "detail", "--depth", "8"];
    let mut first = run_command(&input, &out, &dir.path().join("cache-1"), &slow)
        .spawn()
        .unwrap();
    // The first run holds the folder from its staging folder's creation to its commit.
    let start = Instant::now();
    while hidden_names(&out).is_empty() && start.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(5));
    }
    let second_cache = dir.path().join("cache-2");
    let second = run_command(&input, &out, &second_cache, &slow)
        .output()
        .unwrap();
    let first_still_running = first.try_wait().unwrap().is_none();
    let first_done = first.wait_with_output().unwrap();
    assert!(first_done.status.success(), "{}", stderr_of(&first_done));
    assert!(
        first_still_running,
        "the first run ended before the second began: the test needs a slower first run"
    );
    let message = stderr_of(&second);
    assert_eq!(second.status.code(), Some(1), "{message}");
    assert!(
        message.contains(&out.display().to_string()) && message.contains("another stablesurf run"),
        "{message}"
    );
    // Refused before any work: no cache made, nothing else written beside the folders.
    assert!(!second_cache.exists());
    let mut beside: Vec<String> = fs::read_dir(dir.path())
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    beside.sort();
    assert_eq!(beside, ["cache-1", "out", "sphere.xyz"]);
    assert!(out.join("mesh.ply").is_file() && hidden_names(&out).is_empty());
}

/// The size of every entry file of a cache.
fn entry_bytes(cache: &Path) -> u64 {
    let mut total = 0;
    let mut stack = vec![cache.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "bin") {
                total += e.metadata().unwrap().len();
            }
        }
    }
    total
}

/// Runs over different inputs with a size limit well under their entries' total: after each
/// run the cache's entries fit the limit, every entry left verifies, the most recent input's
/// rerun is a hit at every stage, and `cache info` counts the evictions and hits.
#[test]
fn a_size_limit_keeps_the_cache_under_it_and_the_latest_run_whole() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let inputs: Vec<PathBuf> = (0..6)
        .map(|i| {
            let sub = dir.path().join(format!("in{i}"));
            fs::create_dir(&sub).unwrap();
            sphere_xyz(&sub, 800 + 50 * i, "")
        })
        .collect();
    // The limit: twice one run's entries, so old runs must go.
    let probe = run_command(
        &inputs[0],
        &dir.path().join("probe"),
        &dir.path().join("c0"),
        SMALL,
    )
    .output()
    .unwrap();
    assert!(probe.status.success(), "{}", stderr_of(&probe));
    let one_run = entry_bytes(&dir.path().join("c0"));
    let limit = 2 * one_run + one_run / 2;
    let limit_arg = limit.to_string();
    for (i, input) in inputs.iter().enumerate() {
        let out = dir.path().join(format!("out{i}"));
        let done = run_command(
            input,
            &out,
            &cache,
            &[SMALL, &["--cache-max-size", &limit_arg]].concat(),
        )
        .output()
        .unwrap();
        assert!(done.status.success(), "{}", stderr_of(&done));
        assert!(
            entry_bytes(&cache) <= limit,
            "run {i}: {} > {limit}",
            entry_bytes(&cache)
        );
    }
    let verify = bin()
        .args(["cache", "verify", "--json", "--cache-dir"])
        .arg(&cache)
        .output()
        .unwrap();
    assert!(verify.status.success(), "{}", stderr_of(&verify));
    let verified: serde_json::Value = serde_json::from_slice(&verify.stdout).unwrap();
    assert!(verified["valid"].as_u64().unwrap() >= 6, "{verified}");
    // The latest input again, through the environment's limit: every stage a hit.
    let again = dir.path().join("again");
    let done = run_command(inputs.last().unwrap(), &again, &cache, SMALL)
        .env("STABLESURF_CACHE_MAX_SIZE", &limit_arg)
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", stderr_of(&done));
    let report = read_report(&again);
    let stages = report["stages"].as_array().unwrap();
    let cached: Vec<&str> = stages
        .iter()
        .filter_map(|s| s["cache"].as_str())
        .filter(|c| *c != "none")
        .collect();
    assert!(
        !cached.is_empty() && cached.iter().all(|c| *c == "hit"),
        "{cached:?}"
    );
    let info = bin()
        .args([
            "cache",
            "info",
            "--json",
            "--cache-max-size",
            &limit_arg,
            "--cache-dir",
        ])
        .arg(&cache)
        .output()
        .unwrap();
    assert!(info.status.success(), "{}", stderr_of(&info));
    let info: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    assert_eq!(info["max_size"].as_u64(), Some(limit));
    assert!(info["bytes"].as_u64().unwrap() <= limit, "{info}");
    assert!(info["evicted_entries"].as_u64().unwrap() > 0, "{info}");
    assert_eq!(info["runs"].as_u64(), Some(7));
    assert_eq!(info["hits"].as_u64(), Some(cached.len() as u64), "{info}");
    // A bad size is a usage error.
    let bad = bin()
        .args(["cache", "info", "--cache-max-size", "lots", "--cache-dir"])
        .arg(&cache)
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2), "{}", stderr_of(&bad));
    // Entries unused for a day: none yet; for no time at all: every one.
    let kept = bin()
        .args(["cache", "clear", "--older-than", "1d", "--cache-dir"])
        .arg(&cache)
        .output()
        .unwrap();
    assert!(kept.status.success() && stderr_of(&kept).contains("cleared 0 entries"));
    let cleared = bin()
        .args(["cache", "clear", "--older-than", "0s", "--cache-dir"])
        .arg(&cache)
        .output()
        .unwrap();
    assert!(cleared.status.success(), "{}", stderr_of(&cleared));
    assert_eq!(entry_bytes(&cache), 0);
}

/// Every cache write failing half-way, as on a full disk: the run completes with the same
/// outputs as a run without the cache, says once that it could not cache, and leaves no new
/// entry and no temporary in the cache.
#[test]
fn a_full_disk_under_the_cache_costs_only_the_cache() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    // A cache that already holds one run's entries.
    let earlier = sphere_xyz(dir.path(), 800, "");
    let done = run_command(&earlier, &dir.path().join("earlier"), &cache, SMALL)
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", stderr_of(&done));
    let held = entry_bytes(&cache);
    let sub = dir.path().join("b");
    fs::create_dir(&sub).unwrap();
    let input = sphere_xyz(&sub, 900, "");
    let plain = dir.path().join("plain");
    let done = run_command(&input, &plain, &cache, &[SMALL, &["--no-cache"]].concat())
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", stderr_of(&done));
    let out = dir.path().join("out");
    let done = run_command(&input, &out, &cache, SMALL)
        .env("STABLESURF_FAULT", "cache-full")
        .output()
        .unwrap();
    let message = stderr_of(&done);
    assert!(done.status.success(), "{message}");
    assert_eq!(outputs(&out), outputs(&plain));
    let warnings: Vec<&str> = message
        .lines()
        .filter(|l| l.starts_with("stablesurf: warning:") && l.contains("cache"))
        .collect();
    assert_eq!(warnings.len(), 1, "{message}");
    assert!(warnings[0].contains("free space"), "{message}");
    assert_eq!(entry_bytes(&cache), held);
    assert!(
        hidden_names(&cache).is_empty(),
        "{:?}",
        hidden_names(&cache)
    );
}
