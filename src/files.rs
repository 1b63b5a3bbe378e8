//! File-system helpers shared by the cache and the output writer: which temporary names belong
//! to a process that is gone, and IO errors that name the path and say what to do.
//!
//! Input: paths and IO errors. Output: verdicts and messages. No stage calls these; only the
//! parts of the pipeline that touch the disk ([`crate::cache`], [`crate::outputs`],
//! [`crate::export::write_atomic`]).
//!
//! Debris rule: a temporary name this tool makes carries the id of the process that made it.
//! It is removed only when that process is gone (on Linux, no `/proc/PID`; elsewhere, when the
//! file is older than a day), so a run never removes another live run's work in progress.

use std::path::Path;
use std::time::{Duration, SystemTime};

/// Whether the process `pid` has ended (so its temporary files are debris). A temporary whose
/// maker may still run is never debris.
pub(crate) fn process_is_gone(pid: u32, path: &Path) -> bool {
    if pid == std::process::id() {
        return false;
    }
    if cfg!(target_os = "linux") && Path::new("/proc/self").exists() {
        return !Path::new(&format!("/proc/{pid}")).exists();
    }
    // No process table to ask: only an old temporary is taken for debris.
    std::fs::symlink_metadata(path)
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| SystemTime::now().duration_since(t).ok())
        .is_some_and(|age| age > Duration::from_secs(24 * 3600))
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
