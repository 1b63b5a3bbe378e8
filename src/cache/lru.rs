//! The cache's size limit and its counts: least-recently-used eviction of whole entries, and the
//! hits, misses and evictions that `stablesurf cache info` shows.
//!
//! Input: a cache root, a limit in bytes, a run's hits and misses. Output: entries removed until
//! the cache fits, and the counts in `<root>/stats.json`.
//!
//! - **Last use** is an entry's modification time: set when it is written, and again on each hit
//!   ([`super::Cache`] touches it), so the entries of the latest runs are the last to go.
//! - **Eviction** after each run lists every entry, and when their bytes exceed the limit removes
//!   the least recently used until they fit. It never removes an entry another process is
//!   reading (readers hold a shared lock on the entry while they read it; eviction passes by
//!   an entry whose exclusive lock it cannot take) nor one being written (writes go to
//!   temporaries, which are not entries until renamed into place). Removal cannot tear a reader
//!   that opened the entry first: its open file keeps the bytes.
//! - **Counts** live in `stats.json`, read and rewritten under an exclusive lock of that file;
//!   the same lock makes one eviction at a time per cache. The counts only inform: a file
//!   that cannot be read counts from zero again.

use std::fs;
use std::io::{Read, Seek, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use super::{is_entry_name, is_shard_name, listing, STAGES};

/// The size limit when none is given: 5 GB, as ccache's default.
pub const DEFAULT_MAX_SIZE: u64 = 5_000_000_000;

/// The counts file under the cache root.
pub(crate) const STATS_FILE: &str = "stats.json";

/// What a cache has served and removed, since it was made.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Stats {
    /// Runs that finished with this cache.
    pub runs: u64,
    /// Stage lookups that found a valid entry.
    pub hits: u64,
    /// Stage lookups that found none, or a corrupt one (recomputed).
    pub misses: u64,
    /// Entries removed to keep the cache under its limit.
    pub evicted_entries: u64,
    /// Their bytes.
    pub evicted_bytes: u64,
}

impl Stats {
    /// Hits over lookups, when there were any.
    pub fn hit_rate(&self) -> Option<f64> {
        let lookups = self.hits + self.misses;
        (lookups > 0).then(|| self.hits as f64 / lookups as f64)
    }
}

/// What one eviction pass removed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Evicted {
    /// Entries removed.
    pub entries: u64,
    /// Their bytes.
    pub bytes: u64,
    /// The entries' bytes left.
    pub remaining: u64,
}

/// One entry on disk.
pub(crate) struct EntryFile {
    pub path: PathBuf,
    pub bytes: u64,
    pub last_use: SystemTime,
}

/// Every entry file of the cache at `root` (each stage's shards), in no set order.
pub(crate) fn entries(root: &Path) -> Vec<EntryFile> {
    let mut out = Vec::new();
    for stage in STAGES {
        for (shard_name, shard, meta) in listing(&root.join(stage)) {
            if !(meta.is_dir() && is_shard_name(&shard_name)) {
                continue;
            }
            for (name, path, meta) in listing(&shard) {
                if meta.is_file() && is_entry_name(&name) {
                    out.push(EntryFile {
                        path,
                        bytes: meta.len(),
                        last_use: meta.modified().unwrap_or(SystemTime::UNIX_EPOCH),
                    });
                }
            }
        }
    }
    out
}

/// Opens the counts file of `root` with its exclusive lock taken (waiting for another process
/// that holds it), and its counts.
fn open_stats(root: &Path) -> std::io::Result<(fs::File, Stats)> {
    let mut file = fs::File::options()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(root.join(STATS_FILE))?;
    file.lock()?;
    let mut text = String::new();
    let stats = file
        .read_to_string(&mut text)
        .ok()
        .and_then(|_| serde_json::from_str(&text).ok())
        .unwrap_or_default();
    Ok((file, stats))
}

/// Rewrites the counts file held by `file` (the lock is released when `file` drops).
fn store_stats(file: &mut fs::File, stats: &Stats) -> std::io::Result<()> {
    let bytes = serde_json::to_vec_pretty(stats).expect("counts serialize");
    file.set_len(0)?;
    file.rewind()?;
    file.write_all(&bytes)
}

/// The counts of the cache at `root` (zero when it has none yet).
pub(crate) fn read_stats(root: &Path) -> Stats {
    fs::read_to_string(root.join(STATS_FILE))
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or_default()
}

/// Adds one run's lookups to the counts of `root`, then removes least recently used entries
/// until the entries' bytes are at most `max_size`.
///
/// # Errors
/// The counts file cannot be opened, locked or written (the eviction is done all the same).
pub(crate) fn record_run_and_evict(
    root: &Path,
    hits: u64,
    misses: u64,
    max_size: u64,
) -> std::io::Result<Evicted> {
    let (mut file, mut stats) = match open_stats(root) {
        Ok(opened) => opened,
        Err(e) => {
            // The limit holds even when the counts cannot be kept (a full disk).
            evict(root, max_size, |_| true);
            return Err(e);
        }
    };
    let evicted = evict(root, max_size, |_| true);
    stats.runs += 1;
    stats.hits += hits;
    stats.misses += misses;
    stats.evicted_entries += evicted.entries;
    stats.evicted_bytes += evicted.bytes;
    store_stats(&mut file, &stats)?;
    Ok(evicted)
}

/// Removes entries, least recently used first, while their bytes exceed `max_size`; with
/// `max_size` 0, every entry `doomed` accepts. An entry another process holds (reading it) is
/// passed by. Never fails: what cannot be removed stays and counts as remaining.
pub(crate) fn evict(root: &Path, max_size: u64, doomed: impl Fn(&EntryFile) -> bool) -> Evicted {
    let mut all = entries(root);
    let mut done = Evicted {
        remaining: all.iter().map(|e| e.bytes).sum(),
        ..Evicted::default()
    };
    all.sort_by(|a, b| a.last_use.cmp(&b.last_use).then(a.path.cmp(&b.path)));
    for entry in all {
        if done.remaining <= max_size {
            break;
        }
        if doomed(&entry) && remove_unless_held(&entry.path) {
            done.entries += 1;
            done.bytes += entry.bytes;
            done.remaining -= entry.bytes;
        }
    }
    done
}

/// Removes the entry at `path` unless another process holds a lock on it; whether it went.
fn remove_unless_held(path: &Path) -> bool {
    let Ok(file) = fs::File::open(path) else {
        return false;
    };
    match file.try_lock() {
        Ok(()) | Err(fs::TryLockError::Error(_)) => fs::remove_file(path).is_ok(),
        Err(fs::TryLockError::WouldBlock) => false,
    }
}

/// Removes the entries of `root` last used more than `age` ago; what [`evict`] did.
pub(crate) fn evict_older_than(root: &Path, age: Duration) -> Evicted {
    let cutoff = SystemTime::now()
        .checked_sub(age)
        .unwrap_or(SystemTime::UNIX_EPOCH);
    evict(root, 0, |e| e.last_use < cutoff)
}

/// Parses a size: a number of bytes with an optional unit, `K`, `M`, `G`, `T` (powers of 1000,
/// a trailing `B` allowed) or `KiB`, `MiB`, `GiB`, `TiB` (powers of 1024), in any case:
/// `5G`, `500MB`, `1.5GiB`, `1048576`.
///
/// ```
/// use stablesurf::cache::lru::parse_size;
/// assert_eq!(parse_size("50M"), Ok(50_000_000));
/// assert_eq!(parse_size("1.5 GiB"), Ok(1_610_612_736));
/// assert!(parse_size("ten").is_err());
/// ```
///
/// # Errors
/// Text that is not such a size, in words that say what is expected.
pub fn parse_size(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let unit = unit.trim().to_ascii_lowercase();
    let scale: f64 = match unit.as_str() {
        "" | "b" => 1.0,
        "k" | "kb" => 1e3,
        "m" | "mb" => 1e6,
        "g" | "gb" => 1e9,
        "t" | "tb" => 1e12,
        "kib" => 1024.0,
        "mib" => 1024f64.powi(2),
        "gib" => 1024f64.powi(3),
        "tib" => 1024f64.powi(4),
        _ => f64::NAN,
    };
    let value = number.parse::<f64>().ok().map(|n| n * scale);
    match value {
        Some(v) if (0.0..1.8e19).contains(&v) => Ok(v.round() as u64),
        _ => Err(format!(
            "'{text}' is not a size: give bytes with an optional unit, e.g. 5G, 500MB or 2GiB"
        )),
    }
}

/// Parses an age: a number with a unit `s`, `m` (minutes), `h`, `d` or `w`: `90m`, `12h`,
/// `7d`.
///
/// ```
/// use std::time::Duration;
/// use stablesurf::cache::lru::parse_age;
/// assert_eq!(parse_age("7d"), Ok(Duration::from_secs(7 * 86_400)));
/// assert!(parse_age("7").is_err());
/// ```
///
/// # Errors
/// Text that is not such an age, in words that say what is expected.
pub fn parse_age(text: &str) -> Result<Duration, String> {
    let t = text.trim();
    let unit_seconds = match t.chars().last() {
        Some('s') => 1.0,
        Some('m') => 60.0,
        Some('h') => 3600.0,
        Some('d') => 86_400.0,
        Some('w') => 604_800.0,
        _ => f64::NAN,
    };
    let number = t.get(..t.len().saturating_sub(1)).unwrap_or("");
    match number.trim().parse::<f64>().map(|n| n * unit_seconds) {
        Ok(s) if (0.0..1e15).contains(&s) => Ok(Duration::from_secs_f64(s)),
        _ => Err(format!(
            "'{text}' is not an age: give a number and a unit (s, m, h, d or w), e.g. 12h or 7d"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_and_ages_parse_with_their_units() {
        assert_eq!(parse_size("5G"), Ok(5_000_000_000));
        assert_eq!(parse_size("5gb"), Ok(5_000_000_000));
        assert_eq!(parse_size("2KiB"), Ok(2048));
        assert_eq!(parse_size(" 123 "), Ok(123));
        assert_eq!(parse_size("0"), Ok(0));
        for bad in ["", "G", "-1G", "5X", "1e400", "5 G B"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_age("90s"), Ok(Duration::from_secs(90)));
        assert_eq!(parse_age("1.5h"), Ok(Duration::from_secs(5400)));
        assert_eq!(parse_age("2w"), Ok(Duration::from_secs(1_209_600)));
        for bad in ["", "d", "7", "-1d", "7y"] {
            assert!(parse_age(bad).is_err(), "{bad}");
        }
    }

    /// Writes an entry file of `bytes` bytes, last used `age_s` seconds ago.
    fn entry(root: &Path, stage: &str, n: u8, bytes: usize, age_s: u64) -> PathBuf {
        let name = format!("{:02x}{}.bin", n, "0".repeat(62));
        let path = root.join(stage).join(&name[..2]).join(name);
        fs::create_dir_all(path.parent().unwrap()).unwrap();
        fs::write(&path, vec![7u8; bytes]).unwrap();
        fs::File::options()
            .write(true)
            .open(&path)
            .unwrap()
            .set_modified(SystemTime::now() - Duration::from_secs(age_s))
            .unwrap();
        path
    }

    #[test]
    fn eviction_removes_the_least_recently_used_until_the_entries_fit() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        let old = entry(root, "import", 1, 400, 300);
        let mid = entry(root, "fit", 2, 400, 200);
        let new = entry(root, "export", 3, 400, 100);
        let done = record_run_and_evict(root, 2, 1, 900).unwrap();
        assert_eq!(
            done,
            Evicted {
                entries: 1,
                bytes: 400,
                remaining: 800
            }
        );
        assert!(!old.exists() && mid.exists() && new.exists());
        let stats = read_stats(root);
        assert_eq!(
            (stats.runs, stats.hits, stats.misses, stats.evicted_entries),
            (1, 2, 1, 1)
        );
        assert_eq!(stats.hit_rate(), Some(2.0 / 3.0));
        // Under the limit: nothing goes, the counts add up.
        record_run_and_evict(root, 3, 0, 900).unwrap();
        assert!(mid.exists() && new.exists());
        assert_eq!(read_stats(root).hits, 5);
    }

    #[test]
    fn an_entry_being_read_is_passed_by() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        let old = entry(root, "import", 1, 400, 300);
        let new = entry(root, "fit", 2, 400, 100);
        let reader = fs::File::open(&old).unwrap();
        reader.lock_shared().unwrap();
        let done = evict(root, 500, |_| true);
        if cfg!(unix) {
            assert!(old.exists() && !new.exists(), "{done:?}");
        }
        drop(reader);
        evict(root, 0, |_| true);
        assert!(entries(root).is_empty());
    }

    #[test]
    fn older_than_removes_only_entries_unused_for_that_long() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        let old = entry(root, "import", 1, 10, 3 * 86_400);
        let new = entry(root, "import", 2, 10, 60);
        let done = evict_older_than(root, Duration::from_secs(86_400));
        assert_eq!((done.entries, done.bytes, done.remaining), (1, 10, 10));
        assert!(!old.exists() && new.exists());
    }

    #[test]
    fn unreadable_counts_start_from_zero() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(dir.path().join(STATS_FILE), b"{torn").unwrap();
        assert_eq!(read_stats(dir.path()), Stats::default());
        record_run_and_evict(dir.path(), 1, 0, 10).unwrap();
        assert_eq!(read_stats(dir.path()).hits, 1);
    }
}
