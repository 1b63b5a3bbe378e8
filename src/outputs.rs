//! A run's output files written as one set: the folder ends up holding either the complete new
//! set or exactly what it held before.
//!
//! Input: an output folder and the files of a run (name relative to the folder, bytes).
//! Output: the files in place, or an [`OutputError`] that names the path and what to do.
//!
//! How (`OutputSet`):
//!
//! 1. `OutputSet::begin`, before any work: creates the folder if needed, takes its lock (see
//!    below), removes the debris of runs that were killed, and creates a staging folder
//!    `.stablesurf-staging-<pid>-<n>` inside it. That is the check that the folder is writable,
//!    so a bad `-o` fails at once.
//! 2. `OutputSet::stage` writes every file, synced, under `staging/new/`.
//! 3. `OutputSet::commit` writes the journal `staging/COMMITTING` (the names, synced, renamed
//!    into place), then for each file moves the file it replaces to `staging/old/` and the new
//!    one into place: renames within one file system, no copying. A failure part-way moves
//!    everything back. Then the staging folder, with the replaced files, is removed.
//! 4. Any failure before the journal, or dropping the set uncommitted, removes the staging
//!    folder (and the output folder, when this set created it and it is still empty).
//!
//! A killed run leaves its staging folder. The next `begin` on that folder finds it by name,
//! and only when the process in its name is gone: with a journal it finishes the moves (every
//! new file is complete by then), without one it removes it; either way the folder then holds
//! one whole set. It also removes the `.NAME.tmp<pid>` files of [`crate::export::write_atomic`]
//! left by ended processes.
//!
//! One run at a time writes a folder: `begin` takes the folder's lock
//! (`files::lock_folder`) and holds it until the set is committed or dropped. A second
//! run into a folder that a live run is writing stops at once with an error that names the
//! folder, so no two sets mix and the last writer does not silently win. The lock dies with its
//! process, so a killed run never blocks the next one.
//!
//! Files of an earlier run that the new set does not include are left alone (the tool removes
//! nothing it did not create in this run); `report.json` lists the files of the run.
//!
//! Fault injection, for the crash-consistency tests: `STABLESURF_FAULT=abort@N` aborts the
//! process (as a `kill -9` would) at the N-th step of the output writes, and
//! `STABLESURF_FAULT=enospc@N` makes that step fail as a full disk does. The steps, counted
//! from 1 over the whole process: each staged file, the journal, each file moved into place, and
//! the removal of the staging folder.

use std::fs;
use std::io::Write;
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};

use crate::files::{io_message, pid_after, process_is_gone};

/// The name prefix of staging folders.
const STAGING_PREFIX: &str = ".stablesurf-staging-";
/// The journal that marks a staging folder whose files are all complete and being moved.
const JOURNAL: &str = "COMMITTING";
/// Threads that write the staged files: each write waits mostly for the disk (the sync), so
/// several overlap even on two cores.
const WRITE_THREADS: usize = 8;

/// An output write failed; the message names the path and what to do.
#[derive(Debug, thiserror::Error)]
#[error("{message}")]
pub struct OutputError {
    message: String,
    /// The IO error's kind, when an IO error caused it.
    pub kind: Option<std::io::ErrorKind>,
}

impl OutputError {
    fn io(action: &str, path: &Path, error: &std::io::Error) -> OutputError {
        OutputError {
            message: io_message(action, path, error),
            kind: Some(error.kind()),
        }
    }

    fn other(message: String) -> OutputError {
        OutputError {
            message,
            kind: None,
        }
    }
}

static STAGING_COUNTER: AtomicU64 = AtomicU64::new(0);
static FAULT_STEP: AtomicUsize = AtomicUsize::new(0);

/// Counts one step of the output writes and applies `STABLESURF_FAULT` to it.
fn step() -> std::io::Result<()> {
    let Some(fault) = std::env::var("STABLESURF_FAULT").ok() else {
        return Ok(());
    };
    let n = FAULT_STEP.fetch_add(1, Ordering::SeqCst) + 1;
    match fault.split_once('@') {
        Some(("abort", at)) if at.parse() == Ok(n) => std::process::abort(),
        Some(("enospc", at)) if at.parse() == Ok(n) => {
            Err(std::io::Error::from(std::io::ErrorKind::StorageFull))
        }
        _ => Ok(()),
    }
}

/// Whether `name` is a plain relative path (no root, no `..`), as every output name must be.
fn plain_relative(name: &str) -> bool {
    !name.is_empty()
        && Path::new(name)
            .components()
            .all(|c| matches!(c, Component::Normal(_)))
}

/// One run's output files on their way into a folder (see the module docs).
pub(crate) struct OutputSet {
    dir: PathBuf,
    staging: PathBuf,
    /// The output folder did not exist before [`OutputSet::begin`].
    created_dir: bool,
    /// Names staged, in order.
    staged: Vec<String>,
    /// Set once the staging folder must not be removed (committed, or a failed roll-back left
    /// earlier files in it).
    keep_staging: bool,
    /// The folder's lock, released after the staging folder is gone (fields drop after
    /// [`Drop::drop`]).
    _lock: crate::files::FolderLock,
}

impl OutputSet {
    /// Prepares `dir` for a new set: removes the debris of killed runs, creates the folder if
    /// needed and the staging folder inside it.
    ///
    /// # Errors
    /// The folder cannot be created or written (the message names it and what to do), or a
    /// killed run's files cannot be put back in order.
    pub(crate) fn begin(dir: &Path) -> Result<OutputSet, OutputError> {
        let created_dir = !dir.exists();
        if let Ok(meta) = fs::metadata(dir)
            && !meta.is_dir()
        {
            return Err(OutputError::other(format!(
                "the output folder {} is a file; choose another folder with -o",
                dir.display()
            )));
        }
        fs::create_dir_all(dir)
            .map_err(|e| OutputError::io("create the output folder", dir, &e))?;
        let lock = crate::files::lock_folder(dir)
            .map_err(|e| OutputError::io("open the output folder", dir, &e))?
            .ok_or_else(|| {
                OutputError::other(format!(
                    "another stablesurf run is writing the output folder {}; wait for it to end, or choose another folder with -o",
                    dir.display()
                ))
            })?;
        recover(dir)?;
        let n = STAGING_COUNTER.fetch_add(1, Ordering::Relaxed);
        let staging = dir.join(format!("{STAGING_PREFIX}{}-{n}", std::process::id()));
        let set = OutputSet {
            dir: dir.to_path_buf(),
            staging,
            created_dir,
            staged: Vec::new(),
            keep_staging: false,
            _lock: lock,
        };
        fs::create_dir(&set.staging)
            .and_then(|()| fs::create_dir(set.staging.join("new")))
            .map_err(|e| OutputError::io("write in the output folder", dir, &e))?;
        // A file written and synced: the folder takes data, not only names.
        let probe = set.staging.join("new").join(".probe");
        fs::File::create(&probe)
            .and_then(|mut f| f.write_all(b"x").and_then(|()| f.sync_all()))
            .and_then(|()| fs::remove_file(&probe))
            .map_err(|e| OutputError::io("write in the output folder", dir, &e))?;
        Ok(set)
    }

    /// Writes `files` (names relative to the output folder) into the staging folder, several
    /// at once, each synced.
    ///
    /// # Errors
    /// A name that is not a plain relative path, a name given twice, or a write that fails
    /// (the message names the file in the output folder).
    pub(crate) fn stage(&mut self, files: &[(String, Vec<u8>)]) -> Result<(), OutputError> {
        for (name, _) in files {
            if !plain_relative(name) {
                return Err(OutputError::other(format!(
                    "output file name {name:?} is not a plain relative path"
                )));
            }
            if self.staged.contains(name) {
                return Err(OutputError::other(format!(
                    "output file {name} is written twice"
                )));
            }
        }
        let new = self.staging.join("new");
        let write_one = |name: &str, bytes: &[u8]| -> Result<(), OutputError> {
            let path = new.join(name);
            let shown = self.dir.join(name);
            let result = (|| {
                if let Some(parent) = path.parent() {
                    fs::create_dir_all(parent)?;
                }
                let mut file = fs::File::create(&path)?;
                file.write_all(bytes)?;
                step()?;
                file.sync_all()
            })();
            result.map_err(|e| OutputError::io("write", &shown, &e))
        };
        let threads = WRITE_THREADS.min(files.len()).max(1);
        let results: Vec<(usize, Result<(), OutputError>)> = std::thread::scope(|scope| {
            let workers: Vec<_> = (0..threads)
                .map(|t| {
                    let write_one = &write_one;
                    scope.spawn(move || {
                        files
                            .iter()
                            .enumerate()
                            .skip(t)
                            .step_by(threads)
                            .map(|(i, (name, bytes))| (i, write_one(name, bytes)))
                            .collect::<Vec<_>>()
                    })
                })
                .collect();
            workers
                .into_iter()
                .flat_map(|w| {
                    w.join()
                        .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
                })
                .collect()
        });
        // The first error in file order, whatever the thread count.
        if let Some((_, Err(e))) = results
            .into_iter()
            .filter(|r| r.1.is_err())
            .min_by_key(|r| r.0)
        {
            return Err(e);
        }
        self.staged
            .extend(files.iter().map(|(name, _)| name.clone()));
        Ok(())
    }

    /// Moves every staged file into place, replacing files of the same names, and removes the
    /// staging folder. Returns the names, in the order they were staged.
    ///
    /// # Errors
    /// A file cannot be moved (a folder stands where a file goes, no permission): everything
    /// is moved back first, so the folder holds what it held before.
    pub(crate) fn commit(mut self) -> Result<Vec<String>, OutputError> {
        for name in &self.staged {
            let target = self.dir.join(name);
            if fs::symlink_metadata(&target).is_ok_and(|m| m.is_dir()) {
                return Err(OutputError::other(format!(
                    "cannot write {}: a folder stands there; move it away or choose another folder with -o",
                    target.display()
                )));
            }
        }
        let journal = self.staging.join(JOURNAL);
        let journal_tmp = self.staging.join(format!("{JOURNAL}.tmp"));
        let mut list = String::new();
        for name in &self.staged {
            list.push_str(name);
            list.push('\n');
        }
        (|| {
            let mut f = fs::File::create(&journal_tmp)?;
            f.write_all(list.as_bytes())?;
            f.sync_all()?;
            step()?;
            fs::rename(&journal_tmp, &journal)
        })()
        .map_err(|e| OutputError::io("write", &self.dir, &e))?;

        let mut moved: Vec<(usize, bool)> = Vec::new();
        let mut failure = None;
        for (i, name) in self.staged.iter().enumerate() {
            match move_into_place(&self.dir, &self.staging, name) {
                Ok(replaced) => moved.push((i, replaced)),
                Err(e) => {
                    failure = Some(e);
                    break;
                }
            }
        }
        if let Some(error) = failure {
            // Back to the state before the commit, newest move first.
            let mut stuck = None;
            for &(i, replaced) in moved.iter().rev() {
                let name = &self.staged[i];
                let target = self.dir.join(name);
                let back =
                    fs::rename(&target, self.staging.join("new").join(name)).and_then(|()| {
                        if replaced {
                            fs::rename(self.staging.join("old").join(name), &target)
                        } else {
                            Ok(())
                        }
                    });
                if back.is_err() {
                    stuck = Some(name.clone());
                }
            }
            let _ = fs::remove_file(&journal);
            if let Some(name) = stuck {
                self.keep_staging = true;
                return Err(OutputError::other(format!(
                    "{error}; and {name} could not be put back: the earlier files are in {}",
                    self.staging.join("old").display()
                )));
            }
            return Err(error);
        }
        self.keep_staging = true;
        step().map_err(|e| OutputError::io("clean up", &self.staging, &e))?;
        fs::remove_dir_all(&self.staging)
            .map_err(|e| OutputError::io("clean up", &self.staging, &e))?;
        Ok(std::mem::take(&mut self.staged))
    }
}

impl Drop for OutputSet {
    fn drop(&mut self) {
        if !self.keep_staging {
            let _ = fs::remove_dir_all(&self.staging);
            if self.created_dir {
                // Only when nothing else was put there meanwhile.
                let _ = fs::remove_dir(&self.dir);
            }
        }
    }
}

/// Moves the staged `name` into place, the file it replaces (if any) to `old/` first. Returns
/// whether a file was replaced.
fn move_into_place(dir: &Path, staging: &Path, name: &str) -> Result<bool, OutputError> {
    let target = dir.join(name);
    let new = staging.join("new").join(name);
    let old = staging.join("old").join(name);
    let result = (|| {
        if let Some(parent) = target.parent() {
            fs::create_dir_all(parent)?;
        }
        step()?;
        let replaced = fs::symlink_metadata(&target).is_ok();
        if replaced {
            if let Some(parent) = old.parent() {
                fs::create_dir_all(parent)?;
            }
            fs::rename(&target, &old)?;
        }
        fs::rename(&new, &target).inspect_err(|_| {
            if replaced {
                let _ = fs::rename(&old, &target);
            }
        })?;
        Ok(replaced)
    })();
    result.map_err(|e| OutputError::io("write", &target, &e))
}

/// Whether `name` (relative to the output folder) is a file `run` writes.
fn is_run_output(name: &str) -> bool {
    const TOP: &[&str] = &[
        "mesh.glb",
        "mesh.gltf",
        "mesh.bin",
        "mesh.ply",
        "model.json",
        "model.mpu",
        "preview.png",
        "report.json",
    ];
    if TOP.contains(&name) {
        return true;
    }
    name.strip_prefix("slices/slice_")
        .and_then(|rest| {
            rest.strip_suffix(".exr")
                .or_else(|| rest.strip_suffix(".png"))
        })
        .is_some_and(|n| n.len() >= 3 && n.bytes().all(|b| b.is_ascii_digit()))
}

/// Finishes or removes the staging folders of ended processes in `dir`, and removes the
/// temporaries that [`crate::export::write_atomic`] made for `run`'s file names there and in
/// `slices/` when their process is gone.
fn recover(dir: &Path) -> Result<(), OutputError> {
    let entries: Vec<_> = fs::read_dir(dir)
        .map_err(|e| OutputError::io("read the output folder", dir, &e))?
        .flatten()
        .collect();
    for entry in entries {
        let name = entry.file_name().to_string_lossy().into_owned();
        let path = entry.path();
        let is_dir = fs::symlink_metadata(&path).is_ok_and(|m| m.is_dir());
        if let Some(pid) = pid_after(&name, STAGING_PREFIX).filter(|_| is_dir)
            && process_is_gone(pid, &path)
        {
            finish_or_discard(dir, &path)?;
        }
    }
    crate::export::remove_stale_temporaries(dir, is_run_output);
    crate::export::remove_stale_temporaries(&dir.join("slices"), |n| {
        is_run_output(&format!("slices/{n}"))
    });
    Ok(())
}

/// A killed run's staging folder: with its journal, the moves are finished; without, it goes.
fn finish_or_discard(dir: &Path, staging: &Path) -> Result<(), OutputError> {
    if let Ok(list) = fs::read_to_string(staging.join(JOURNAL)) {
        for name in list.lines().filter(|n| plain_relative(n)) {
            if staging.join("new").join(name).exists() {
                move_into_place(dir, staging, name)?;
            }
        }
    }
    fs::remove_dir_all(staging).map_err(|e| OutputError::io("clean up", staging, &e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn files(tag: &str) -> Vec<(String, Vec<u8>)> {
        ["model.json", "mesh.ply", "slices/slice_000.exr"]
            .iter()
            .map(|n| (n.to_string(), format!("{tag} {n}").into_bytes()))
            .collect()
    }

    fn listing(dir: &Path) -> Vec<(String, Vec<u8>)> {
        let mut out = Vec::new();
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            for e in fs::read_dir(&d).unwrap().flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
                    out.push((rel, fs::read(&p).unwrap()));
                }
            }
        }
        out.sort();
        out
    }

    /// Asserts that `dir` holds exactly `files` of set `tag` and `extra` (name, bytes), in any order.
    fn assert_holds(dir: &Path, tag: &str, extra: &[(&str, &[u8])]) {
        let mut want = files(tag);
        want.extend(extra.iter().map(|(n, b)| (n.to_string(), b.to_vec())));
        want.sort();
        assert_eq!(listing(dir), want);
    }

    fn write(dir: &Path, files: &[(String, Vec<u8>)]) -> Result<Vec<String>, OutputError> {
        let mut set = OutputSet::begin(dir)?;
        set.stage(files)?;
        set.commit()
    }

    /// A temporary folder and its `out/`, which holds set "a".
    fn folder_with_set_a() -> (tempfile::TempDir, std::path::PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        write(&out, &files("a")).unwrap();
        (dir, out)
    }

    #[test]
    fn a_set_replaces_the_earlier_one_and_leaves_nothing_else() {
        let (_dir, out) = folder_with_set_a();
        fs::write(out.join("user.txt"), b"mine").unwrap();
        let names = write(&out, &files("b")).unwrap();
        assert_eq!(names.len(), 3);
        assert_holds(&out, "b", &[("user.txt", b"mine")]);
    }

    #[test]
    fn a_set_dropped_before_its_commit_leaves_the_folder_as_it_was() {
        let (dir, out) = folder_with_set_a();
        {
            let mut set = OutputSet::begin(&out).unwrap();
            set.stage(&files("b")).unwrap();
        }
        assert_holds(&out, "a", &[]);
        // A folder the set created is removed again.
        let fresh = dir.path().join("fresh");
        drop(OutputSet::begin(&fresh).unwrap());
        assert!(!fresh.exists());
    }

    #[test]
    fn a_failed_move_puts_everything_back() {
        let (_dir, out) = folder_with_set_a();
        fs::write(out.join("zzz"), b"user").unwrap();
        let mut set = OutputSet::begin(&out).unwrap();
        // The last file cannot go into place: a file stands where its folder goes.
        set.stage(&files("b")).unwrap();
        set.stage(&[("zzz/inner".into(), b"x".to_vec())]).unwrap();
        let err = set.commit().unwrap_err().to_string();
        assert!(err.contains("zzz"), "{err}");
        assert_holds(&out, "a", &[("zzz", b"user")]);
    }

    #[test]
    fn bad_names_and_a_file_as_the_folder_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out");
        let mut set = OutputSet::begin(&out).unwrap();
        for bad in ["../x", "/etc/x", "", "a/../../b"] {
            assert!(set.stage(&[(bad.into(), vec![])]).is_err(), "{bad}");
        }
        drop(set);
        let file = dir.path().join("file");
        fs::write(&file, b"x").unwrap();
        let err = OutputSet::begin(&file).err().unwrap().to_string();
        assert!(err.contains("is a file") && err.contains("-o"), "{err}");
        let err = OutputSet::begin(&file.join("sub"))
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("file/sub"), "{err}");
    }

    #[test]
    fn a_killed_runs_staging_is_finished_or_removed() {
        let (_dir, out) = folder_with_set_a();
        let dead = u32::MAX - 7;
        // Killed while staging: removed, the earlier set stays.
        let staging = out.join(format!("{STAGING_PREFIX}{dead}-0"));
        fs::create_dir_all(staging.join("new")).unwrap();
        fs::write(staging.join("new/mesh.ply"), b"half").unwrap();
        // Killed during the moves: one file moved, one replaced file set aside.
        let committing = out.join(format!("{STAGING_PREFIX}{dead}-1"));
        fs::create_dir_all(committing.join("new/slices")).unwrap();
        fs::create_dir_all(committing.join("old")).unwrap();
        fs::write(
            committing.join(JOURNAL),
            "model.json\nmesh.ply\nslices/slice_000.exr\n",
        )
        .unwrap();
        fs::write(out.join("model.json"), b"c model.json").unwrap();
        fs::rename(out.join("mesh.ply"), committing.join("old/mesh.ply")).unwrap();
        fs::write(committing.join("new/mesh.ply"), b"c mesh.ply").unwrap();
        fs::write(
            committing.join("new/slices/slice_000.exr"),
            b"c slices/slice_000.exr",
        )
        .unwrap();
        // An export temporary of an ended process.
        fs::write(out.join(format!(".mesh.glb.tmp{dead}")), b"half").unwrap();
        if !cfg!(target_os = "linux") {
            return;
        }
        drop(OutputSet::begin(&out).unwrap());
        assert_holds(&out, "c", &[]);
    }

    #[test]
    fn a_folder_that_a_live_set_is_writing_is_refused_by_name_and_left_alone() {
        let (_dir, out) = folder_with_set_a();
        let mut first = OutputSet::begin(&out).unwrap();
        first.stage(&files("b")).unwrap();
        if cfg!(unix) {
            let err = OutputSet::begin(&out).err().unwrap().to_string();
            assert!(
                err.contains(&out.display().to_string()) && err.contains("another stablesurf run"),
                "{err}"
            );
        }
        // The refused set took nothing away from the live one.
        first.commit().unwrap();
        assert_holds(&out, "b", &[]);
        // Once the first set is done, the folder is free again.
        write(&out, &files("c")).unwrap();
        assert_holds(&out, "c", &[]);
    }
}
