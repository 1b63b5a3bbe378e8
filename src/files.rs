//! File-system helpers shared by the cache and the output writer: which temporary names belong
//! to a process that is gone, and IO errors that name the path and say what to do.
//!
//! Input: paths and IO errors. Output: verdicts and messages. No stage calls these; only the
//! parts of the pipeline that touch the disk ([`crate::cache`], [`crate::outputs`],
//! [`crate::export::write_atomic`]).
//!
//! Debris rule: a temporary name this tool makes carries the id of the process that made it.
//! It is removed only when that process has ended, so a run never removes another live run's
//! work in progress. On Linux a process has ended when `/proc/PID` is gone, when it is a zombie
//! (killed, but not reaped by its parent: in a container whose first process does not reap,
//! such a zombie stays for good), or when the process now holding that id started after the
//! name was last written (the id was reused). Elsewhere, a name older than a day is debris.
//!
//! Folder locks ([`lock_folder`]) say that a live run is writing a folder: an advisory lock on
//! the folder itself, which the system releases when the process ends however it ends, so a
//! killed run never leaves a stale lock and no lock file is left behind.

use std::path::Path;
use std::time::{Duration, SystemTime};

/// Whether the process `pid` has ended (so its temporary files are debris). A temporary whose
/// maker may still run is never debris. `path` is the temporary: its age decides where the
/// system cannot say.
pub(crate) fn process_is_gone(pid: u32, path: &Path) -> bool {
    if pid == std::process::id() {
        return false;
    }
    if cfg!(target_os = "linux") && Path::new("/proc/self/stat").exists() {
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
            return true;
        };
        let Some(stat) = ProcStat::parse(&stat) else {
            // Unreadable: taken for alive.
            return false;
        };
        return stat.ended() || stat.started_after(path);
    }
    // No process table to ask: only an old temporary is taken for debris.
    std::fs::symlink_metadata(path)
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| SystemTime::now().duration_since(t).ok())
        .is_some_and(|age| age > Duration::from_secs(24 * 3600))
}

/// The fields of a Linux `/proc/PID/stat` line that say whether a process has ended.
struct ProcStat {
    /// The state letter: `Z` a zombie, `X` dead.
    state: char,
    /// Start time, in clock ticks after boot.
    start_ticks: u64,
}

impl ProcStat {
    /// Parses `pid (comm) S ppid … starttime …`; the name may hold spaces and parentheses, so
    /// the fields are counted from the last `)`.
    fn parse(line: &str) -> Option<ProcStat> {
        let rest = &line[line.rfind(')')? + 1..];
        let fields: Vec<&str> = rest.split_ascii_whitespace().collect();
        // After the name: state is field 3 of the line, starttime field 22.
        Some(ProcStat {
            state: fields.first()?.chars().next()?,
            start_ticks: fields.get(19)?.parse().ok()?,
        })
    }

    /// A zombie has ended: it runs no code and holds no file, only its id until reaped.
    fn ended(&self) -> bool {
        matches!(self.state, 'Z' | 'X')
    }

    /// Whether this process started after `path` was last written, with two seconds of slack
    /// for the clocks' resolution: then it did not make `path` (its id was reused).
    fn started_after(&self, path: &Path) -> bool {
        let (Some(ticks), Some(boot)) = (clock_ticks_per_second(), boot_time()) else {
            return false;
        };
        let Some(written) = std::fs::symlink_metadata(path)
            .and_then(|m| m.modified())
            .ok()
            .and_then(|t| t.duration_since(SystemTime::UNIX_EPOCH).ok())
        else {
            return false;
        };
        let started = boot as f64 + self.start_ticks as f64 / ticks;
        started > written.as_secs_f64() + 2.0
    }
}

/// The system's boot time, seconds since the epoch (`btime` of `/proc/stat`).
fn boot_time() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/stat").ok()?;
    text.lines()
        .find_map(|l| l.strip_prefix("btime "))
        .and_then(|v| v.trim().parse().ok())
}

/// Clock ticks per second of `/proc`'s times, where the system can say.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn clock_ticks_per_second() -> Option<f64> {
    // SAFETY: sysconf reads a constant of the system and has no preconditions.
    let ticks = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    (ticks > 0).then_some(ticks as f64)
}

/// Clock ticks per second of `/proc`'s times: unknown here, so an id is never taken for reused.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn clock_ticks_per_second() -> Option<f64> {
    None
}

/// An exclusive lock on a folder, held while the value lives ([`lock_folder`]).
#[derive(Debug)]
pub(crate) struct FolderLock {
    _folder: Option<std::fs::File>,
}

/// Takes the exclusive advisory lock of the folder `dir` without waiting: `Ok(None)` when another
/// live process holds it. The lock is the system's (`flock` on the open folder), released when
/// the returned value drops or the process ends. Where folders cannot be opened or locked
/// (not Unix, or a file system without locks) there is no lock and every caller gets one.
///
/// # Errors
/// The folder cannot be opened.
pub(crate) fn lock_folder(dir: &Path) -> std::io::Result<Option<FolderLock>> {
    if !cfg!(unix) {
        return Ok(Some(FolderLock { _folder: None }));
    }
    let folder = std::fs::File::open(dir)?;
    match folder.try_lock() {
        Ok(()) => Ok(Some(FolderLock {
            _folder: Some(folder),
        })),
        Err(std::fs::TryLockError::WouldBlock) => Ok(None),
        Err(std::fs::TryLockError::Error(e)) if e.kind() == std::io::ErrorKind::Unsupported => {
            Ok(Some(FolderLock { _folder: None }))
        }
        Err(std::fs::TryLockError::Error(e)) => Err(e),
    }
}

/// Removes the regular files of `dir` whose name `pid_of` reads a process id from, when that
/// process is gone (a killed run's temporaries); returns how many. Never fails: what cannot be
/// read or removed stays. Links and folders are never touched.
pub(crate) fn remove_debris(dir: &Path, pid_of: impl Fn(&str) -> Option<u32>) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let path = entry.path();
        if pid_of(&name).is_some_and(|pid| process_is_gone(pid, &path))
            && std::fs::symlink_metadata(&path).is_ok_and(|m| m.is_file())
            && std::fs::remove_file(&path).is_ok()
        {
            removed += 1;
        }
    }
    removed
}

/// What to do about an IO error on `path`, in a few words.
pub(crate) fn io_hint(error: &std::io::Error) -> &'static str {
    use std::io::ErrorKind as K;
    match error.kind() {
        K::StorageFull | K::QuotaExceeded => "free space on that disk or write elsewhere",
        K::PermissionDenied | K::ReadOnlyFilesystem => {
            "choose a folder you can write, or change its permissions"
        }
        K::NotADirectory => "a file stands where a folder is needed; choose another path",
        K::IsADirectory => "a folder stands where a file is needed; choose another path",
        K::NotFound => "check that the folder exists",
        _ => "check the path and the disk, then run again",
    }
}

/// A one-line message for an IO error on `path`: the path, the cause and what to do.
pub(crate) fn io_message(action: &str, path: &Path, error: &std::io::Error) -> String {
    format!(
        "cannot {action} {}: {error}; {}",
        path.display(),
        io_hint(error)
    )
}

/// Parses `<prefix><pid><rest>` names: the pid when `name` starts with `prefix` followed by
/// decimal digits.
pub(crate) fn pid_after(name: &str, prefix: &str) -> Option<u32> {
    let digits: String = name
        .strip_prefix(prefix)?
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    digits.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_process_is_alive_and_a_huge_pid_is_gone() {
        let here = Path::new(".");
        assert!(!process_is_gone(std::process::id(), here));
        if cfg!(target_os = "linux") {
            assert!(process_is_gone(u32::MAX - 7, here));
        }
    }

    #[test]
    fn a_zombie_has_ended() {
        if !cfg!(target_os = "linux") {
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let tmp = dir.path().join(".tmp-0-0");
        std::fs::write(&tmp, b"x").unwrap();
        // A child that exits and is not waited for stays a zombie: ended, its id still taken.
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let status = format!("/proc/{}/stat", child.id());
        let zombie = (0..500).any(|_| {
            std::thread::sleep(Duration::from_millis(10));
            std::fs::read_to_string(&status)
                .ok()
                .and_then(|s| ProcStat::parse(&s))
                .is_some_and(|s| s.state == 'Z')
        });
        assert!(zombie, "the child did not become a zombie within 5 s");
        assert!(process_is_gone(child.id(), &tmp));
        child.wait().unwrap();
        assert!(process_is_gone(child.id(), &tmp));
    }

    #[test]
    fn a_live_process_started_before_the_file_is_alive_and_one_started_after_is_not_its_maker() {
        if !cfg!(target_os = "linux") {
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let tmp = dir.path().join(".tmp-0-0");
        std::fs::write(&tmp, b"x").unwrap();
        let mut child = std::process::Command::new("sleep")
            .arg("30")
            .spawn()
            .unwrap();
        // Written after the child started: the child may have made it.
        std::thread::sleep(Duration::from_millis(50));
        std::fs::write(&tmp, b"y").unwrap();
        assert!(!process_is_gone(child.id(), &tmp));
        // Last written a minute before the child started: another process with that id made it.
        let old = SystemTime::now() - Duration::from_secs(60);
        std::fs::File::options()
            .write(true)
            .open(&tmp)
            .unwrap()
            .set_modified(old)
            .unwrap();
        let reuse_known = clock_ticks_per_second().is_some() && boot_time().is_some();
        assert_eq!(process_is_gone(child.id(), &tmp), reuse_known);
        child.kill().unwrap();
        child.wait().unwrap();
    }

    #[test]
    fn proc_stat_lines_parse_past_odd_names() {
        let line = "42 (a) b (c)) S 1 42 42 0 -1 4194560 100 0 0 0 1 2 0 0 20 0 1 0 12345 9000 200";
        let stat = ProcStat::parse(line).unwrap();
        assert_eq!((stat.state, stat.start_ticks), ('S', 12345));
        assert!(ProcStat::parse("garbage").is_none());
    }

    #[test]
    fn a_folder_lock_excludes_a_second_holder_until_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let first = lock_folder(dir.path()).unwrap();
        assert!(first.is_some());
        if cfg!(unix) {
            assert!(lock_folder(dir.path()).unwrap().is_none());
        }
        drop(first);
        assert!(lock_folder(dir.path()).unwrap().is_some());
    }

    #[test]
    fn pids_parse_after_their_prefix() {
        assert_eq!(pid_after(".tmp-123-4", ".tmp-"), Some(123));
        assert_eq!(pid_after(".mesh.ply.tmp77", ".mesh.ply.tmp"), Some(77));
        assert_eq!(pid_after(".tmp-x", ".tmp-"), None);
        assert_eq!(pid_after("other", ".tmp-"), None);
    }

    #[test]
    fn messages_name_the_path_and_the_remedy() {
        let e = std::io::Error::from(std::io::ErrorKind::StorageFull);
        let m = io_message("write", Path::new("out/mesh.ply"), &e);
        assert!(
            m.contains("out/mesh.ply") && m.contains("free space"),
            "{m}"
        );
    }
}
