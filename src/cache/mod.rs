//! The content-addressed artifact cache: each stage's output stored under a key that hashes
//! everything it depends on, so a rerun redoes only what changed.
//!
//! Input: a key and an artifact. Output: the artifact back, or a miss.
//!
//! Key recipe (one for every stage): BLAKE3 over, in this order, each field length-prefixed,
//!
//! ```text
//! CACHE_FORMAT_VERSION | stage name | STAGE_VERSION | canonical params bytes | input key
//! ```
//!
//! The import stage's input key is the BLAKE3 of the scan file's bytes (never its path or
//! mtime); every later stage's input key is the key of the artifact it consumes, so keys chain.
//! Params are canonicalized as JSON of the `…Params` struct (fields in declaration order).
//!
//! Layout on disk: `<root>/CACHEDIR.TAG` (the marker, written when the cache creates the
//! folder) and `<root>/<stage>/<k0k1>/<key>.bin`. Each entry holds, inside its checksummed bytes,
//! the key, stage and versions it was stored under and the stage's figures (see [`codec`]), so an
//! entry answers only for its own key. Writes go to a unique temporary file
//! (`.tmp-<pid>-<n>`) in the same directory and are renamed into place, so a killed run or two
//! concurrent runs never leave a torn entry (no sync before the rename: an entry torn by a power
//! loss fails its checksum and is a miss). An entry that fails to decode or verify is a miss and
//! is rewritten; it is never an error. Temporaries of processes that are gone are removed by the
//! next lookup in their folder and by `cache info` / `cache clear`.
//!
//! The cache owns only what it made: it works in a folder that carries its marker, or that it
//! creates (or finds empty) and marks; any other folder is refused with [`CacheError::NotACache`].
//! [`Cache::clear`] removes only names it makes (entries, its temporaries, then the folders
//! they leave empty), never follows a link, and leaves everything else where it is.
//!
//! A run stores its entries through `Puts`, on a background thread, while its next stages
//! compute. A store that fails costs only the next run's time (a full disk included), so the
//! pipeline reports it once as a warning and the run's outputs are complete; the failed write's
//! temporary is removed, so no partial entry is left.
//!
//! The cache keeps under a size limit ([`lru`]): after each run, the least recently used
//! entries go until the rest fit (5 GB unless `--cache-max-size` or
//! `STABLESURF_CACHE_MAX_SIZE` say otherwise), and `<root>/stats.json` counts hits, misses and
//! evictions. A reader holds a shared lock on the entry it reads, so eviction by another
//! process passes it by.

pub mod codec;
pub mod lru;

use std::fmt;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

pub use codec::{Artifact, OutputFiles};

/// Version of the cache as a whole (entry envelope and key recipe). If you change either,
/// bump it: every key changes and old entries are simply never read again.
pub(crate) const CACHE_FORMAT_VERSION: u32 = 2;

/// The stage folders a cache holds; nothing else under the root is the cache's.
pub(crate) const STAGES: &[&str] = &[
    "import",
    "normals",
    "merge",
    "fit",
    "detail",
    "polygonize",
    "finish",
    "export",
];

/// The marker file of a cache root (the cache directory tag convention, which backup tools
/// honour), and its first line.
const MARKER: &str = "CACHEDIR.TAG";
const MARKER_SIGNATURE: &str = "Signature: 8a477f597d28d172789f06886806bc55";
/// The line that says the tag is stablesurf's (other tools write the same signature).
const MARKER_OWNER: &str = "# This folder is a stablesurf cache";

/// Errors of the cache that the caller must see (reads never fail: a bad entry is a miss).
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    /// The cache directory could not be created or written.
    #[error("cannot write the cache at {path}: {source}; {}, pick another place with --cache-dir, lower --cache-max-size, or use --no-cache", crate::files::io_hint(.source))]
    Io {
        /// The path.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The folder is not a stablesurf cache, so the cache will neither write into it nor
    /// remove anything from it.
    #[error("{path} is not a stablesurf cache: {why}; pass --cache-dir a new or empty folder (stablesurf never writes into or clears a folder it did not create)")]
    NotACache {
        /// The folder.
        path: String,
        /// What was found there instead.
        why: String,
    },
}

/// A 32-byte cache key.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Key(pub [u8; 32]);

impl Key {
    /// The key of raw input bytes (the import stage's input).
    pub(crate) fn of_bytes(bytes: &[u8]) -> Key {
        Key(*blake3::hash(bytes).as_bytes())
    }

    /// Lower-case hex.
    pub(crate) fn hex(&self) -> String {
        self.0.iter().map(|b| format!("{b:02x}")).collect()
    }
}

impl fmt::Debug for Key {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Key({})", self.hex())
    }
}

impl fmt::Display for Key {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.hex())
    }
}

/// Computes a stage's key. `params` are the canonical bytes of the stage's params.
pub(crate) fn stage_key(stage: &str, stage_version: u32, params: &[u8], input: &Key) -> Key {
    let mut h = blake3::Hasher::new();
    let mut field = |bytes: &[u8]| {
        h.update(&(bytes.len() as u64).to_le_bytes());
        h.update(bytes);
    };
    field(&CACHE_FORMAT_VERSION.to_le_bytes());
    field(stage.as_bytes());
    field(&stage_version.to_le_bytes());
    field(params);
    field(&input.0);
    Key(*h.finalize().as_bytes())
}

/// Canonical bytes of a params struct: its JSON, fields in declaration order.
pub(crate) fn params_bytes<P: serde::Serialize>(params: &P) -> Vec<u8> {
    serde_json::to_vec(params).expect("params always serialize")
}

/// The default cache location: `$XDG_CACHE_HOME/stablesurf`, else `~/.cache/stablesurf`.
pub fn default_dir() -> Option<PathBuf> {
    if let Some(x) = std::env::var_os("XDG_CACHE_HOME").filter(|v| !v.is_empty()) {
        return Some(PathBuf::from(x).join("stablesurf"));
    }
    std::env::var_os("HOME")
        .filter(|v| !v.is_empty())
        .map(|h| PathBuf::from(h).join(".cache").join("stablesurf"))
}

/// Whether a lookup found a usable entry.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Lookup {
    /// Found and verified.
    Hit,
    /// Not present (or the cache is disabled).
    Miss,
    /// Present but corrupt, of another version or stored under another key: recomputed and
    /// rewritten.
    Corrupt,
}

impl Lookup {
    /// "hit", "miss" or "corrupt".
    pub(crate) fn as_str(self) -> &'static str {
        match self {
            Lookup::Hit => "hit",
            Lookup::Miss => "miss",
            Lookup::Corrupt => "corrupt",
        }
    }
}

/// An on-disk cache, or a disabled one that always misses and stores nothing.
#[derive(Clone, Debug)]
pub struct Cache {
    root: Option<PathBuf>,
    /// The entries' bytes kept after a run ([`lru`]).
    max_size: u64,
}

/// One stage's share of a cache ([`Cache::usage`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StageUsage {
    /// The stage.
    pub stage: String,
    /// Its entries.
    pub entries: u64,
    /// Their bytes.
    pub bytes: u64,
}

/// What [`Cache::clear`] did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Cleared {
    /// Entries removed.
    pub entries: u64,
    /// Their bytes.
    pub bytes: u64,
    /// Temporaries of ended processes removed.
    pub debris: u64,
    /// Paths under the root that are not the cache's, left where they are.
    pub foreign: Vec<PathBuf>,
}

/// What [`Cache::verify`] found.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Verified {
    /// Entries whose envelope verifies.
    pub valid: u64,
    /// Their bytes.
    pub bytes: u64,
    /// Entries that fail (a later lookup recomputes and rewrites them).
    pub invalid: Vec<PathBuf>,
}

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// The temporary-file prefix of the cache's atomic writes (`.tmp-<pid>-<n>`).
const TMP_PREFIX: &str = ".tmp-";

/// Whether `name` is an entry's file name: 64 lower-case hex digits and `.bin` (or the `.json`
/// that caches of format 1 kept beside it).
fn is_entry_name(name: &str) -> bool {
    let Some((stem, ext)) = name.split_once('.') else {
        return false;
    };
    stem.len() == 64
        && stem
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
        && (ext == "bin" || ext == "json")
}

fn is_shard_name(name: &str) -> bool {
    name.len() == 2
        && name
            .bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// The process id in a name of the cache's temporaries, when it is one.
fn tmp_pid(name: &str) -> Option<u32> {
    let pid = crate::files::pid_after(name, TMP_PREFIX)?;
    let rest = &name[TMP_PREFIX.len() + pid.to_string().len()..];
    let n = rest.strip_prefix('-')?;
    (!n.is_empty() && n.bytes().all(|b| b.is_ascii_digit())).then_some(pid)
}

/// A directory's entries as (name, path, metadata without following links); none when it
/// cannot be read.
fn listing(dir: &Path) -> Vec<(String, PathBuf, fs::Metadata)> {
    let mut out: Vec<_> = fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let path = e.path();
            let meta = fs::symlink_metadata(&path).ok()?;
            Some((e.file_name().to_string_lossy().into_owned(), path, meta))
        })
        .collect();
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

/// Removes the cache's temporaries of ended processes in one folder (a shard, or the root);
/// returns how many.
fn sweep_shard(shard: &Path) -> u64 {
    crate::files::remove_debris(shard, tmp_pid)
}

/// What a folder is, as a cache root.
enum RootState {
    /// Not there: the cache creates and marks it.
    Absent,
    /// Carries the marker.
    Marked,
    /// Empty (or holding only the temporary of another run that is marking it): a run marks
    /// it and uses it; `cache info` and `cache clear` find no cache there.
    Empty,
    /// A cache of format 1 (stage folders of entries only, from before the marker): marked and
    /// used like a marked one.
    Legacy,
    /// Anything else: refused.
    Foreign(String),
}

fn root_state(root: &Path) -> RootState {
    let meta = match fs::symlink_metadata(root) {
        // Not there, or not reachable (a file stands on its path): creating it will fail with
        // the IO error that says why.
        Err(_) => return RootState::Absent,
        Ok(m) => m,
    };
    // A link to a folder is followed for the root itself (a user may keep the cache on
    // another disk), never below it.
    let is_dir = meta.is_dir() || (meta.is_symlink() && root.is_dir());
    if !is_dir {
        return RootState::Foreign("it is a file, not a folder".into());
    }
    // The marker's verdict, when there is a marker to read.
    let marker = || {
        let text = fs::read_to_string(root.join(MARKER)).ok()?;
        let mut lines = text.lines();
        Some(
            if lines.next() == Some(MARKER_SIGNATURE) && lines.any(|l| l.starts_with(MARKER_OWNER))
            {
                RootState::Marked
            } else {
                RootState::Foreign(format!("its {MARKER} belongs to another program"))
            },
        )
    };
    if let Some(state) = marker() {
        return state;
    }
    // Another run's temporary, while it writes the marker, leaves the folder empty.
    let items: Vec<_> = listing(root)
        .into_iter()
        .filter(|(name, _, meta)| !(meta.is_file() && tmp_pid(name).is_some()))
        .collect();
    if items.is_empty() {
        return RootState::Empty;
    }
    // Another run making the cache may have put its marker in place since it was read above
    // (the marker is renamed into place whole): read it again.
    if items.iter().any(|(name, ..)| name == MARKER)
        && let Some(state) = marker()
    {
        return state;
    }
    // A cache of format 1: every item a stage folder of shard folders of entries.
    let legacy = items.iter().all(|(name, path, meta)| {
        meta.is_dir()
            && STAGES.contains(&name.as_str())
            && listing(path).iter().all(|(shard, path, meta)| {
                meta.is_dir()
                    && is_shard_name(shard)
                    && listing(path).iter().all(|(file, _, meta)| {
                        meta.is_file() && (is_entry_name(file) || tmp_pid(file).is_some())
                    })
            })
    });
    if legacy {
        return RootState::Legacy;
    }
    let shown: Vec<&str> = items.iter().take(3).map(|i| i.0.as_str()).collect();
    RootState::Foreign(format!(
        "it holds other things ({}{}) and no {MARKER} of stablesurf",
        shown.join(", "),
        if items.len() > 3 { ", …" } else { "" }
    ))
}

impl Cache {
    /// A cache rooted at `root` (created and marked by `Cache::prepare` or the first write).
    pub fn at(root: impl Into<PathBuf>) -> Cache {
        Cache {
            root: Some(root.into()),
            max_size: lru::DEFAULT_MAX_SIZE,
        }
    }

    /// A cache that stores nothing (`--no-cache`).
    pub fn disabled() -> Cache {
        Cache {
            root: None,
            max_size: lru::DEFAULT_MAX_SIZE,
        }
    }

    /// The same cache with a size limit of `bytes` ([`lru`]).
    pub fn with_max_size(self, bytes: u64) -> Cache {
        Cache {
            max_size: bytes,
            ..self
        }
    }

    /// The root directory, if enabled.
    pub fn root(&self) -> Option<&Path> {
        self.root.as_deref()
    }

    /// Makes the root ready for use: creates and marks it when it is absent, marks it when it
    /// is empty (or a cache of format 1), accepts it when it carries the marker.
    ///
    /// # Errors
    /// [`CacheError::NotACache`] for any other folder (or a file);
    /// [`CacheError::Io`] when it cannot be created or marked.
    pub(crate) fn prepare(&self) -> Result<(), CacheError> {
        let Some(root) = &self.root else {
            return Ok(());
        };
        let io = |source| CacheError::Io {
            path: root.display().to_string(),
            source,
        };
        match root_state(root) {
            RootState::Marked => Ok(()),
            RootState::Foreign(why) => Err(CacheError::NotACache {
                path: root.display().to_string(),
                why,
            }),
            RootState::Absent | RootState::Empty | RootState::Legacy => {
                fs::create_dir_all(root).map_err(io)?;
                let marker = format!(
                    "{MARKER_SIGNATURE}\n{MARKER_OWNER} (format {CACHE_FORMAT_VERSION}): `stablesurf cache clear` removes\n# only the entries it made here. Backup tools that honour cache directory tags skip it.\n"
                );
                write_atomic(&root.join(MARKER), marker.as_bytes())
            }
        }
    }

    /// The root, when it is a marked cache (for `info` and `clear`).
    fn marked_root(&self) -> Result<Option<&Path>, CacheError> {
        let Some(root) = &self.root else {
            return Ok(None);
        };
        match root_state(root) {
            RootState::Marked => Ok(Some(root)),
            RootState::Absent => Err(CacheError::NotACache {
                path: root.display().to_string(),
                why: "the folder does not exist".into(),
            }),
            RootState::Empty => Err(CacheError::NotACache {
                path: root.display().to_string(),
                why: format!("it is empty, with no {MARKER} (a run marks the folder when it makes the cache)"),
            }),
            RootState::Legacy => {
                self.prepare()?;
                Ok(Some(root))
            }
            RootState::Foreign(why) => Err(CacheError::NotACache {
                path: root.display().to_string(),
                why,
            }),
        }
    }

    fn entry_path(&self, stage: &str, key: &Key) -> Option<PathBuf> {
        // A folder not in the list would escape the size limit, `clear` and `verify`.
        debug_assert!(
            STAGES.contains(&stage),
            "stage {stage} is not in cache::STAGES"
        );
        let hex = key.hex();
        Some(
            self.root
                .as_ref()?
                .join(stage)
                .join(&hex[..2])
                .join(format!("{hex}.bin")),
        )
    }

    /// Looks an artifact up under the identity it must have been stored with. Never fails:
    /// unreadable, corrupt or foreign entries are misses. Returns the artifact and the
    /// explanation stored with it.
    pub(crate) fn get<T: Artifact>(
        &self,
        stage: &str,
        stage_version: u32,
        key: &Key,
    ) -> (Option<(T, serde_json::Value)>, Lookup) {
        let Some(path) = self.entry_path(stage, key) else {
            return (None, Lookup::Miss);
        };
        if let Some(shard) = path.parent() {
            sweep_shard(shard);
        }
        let id = codec::EntryId {
            key: *key,
            stage: stage.to_string(),
            stage_version,
        };
        match read_entry(&path) {
            Ok((bytes, file)) => match codec::decode_as::<T>(&bytes, &id) {
                Some(entry) => {
                    // The hit is this entry's last use: eviction takes the oldest uses first.
                    let _ = file.set_modified(std::time::SystemTime::now());
                    (Some((entry.value, entry.meta)), Lookup::Hit)
                }
                None => (None, Lookup::Corrupt),
            },
            Err(_) if path.exists() => (None, Lookup::Corrupt),
            Err(_) => (None, Lookup::Miss),
        }
    }

    /// Adds a run's lookups to the cache's counts and evicts the least recently used entries
    /// beyond the size limit (see [`lru`]); nothing for a disabled cache.
    ///
    /// # Errors
    /// The counts file cannot be written (nothing was evicted).
    pub(crate) fn after_run(&self, hits: u64, misses: u64) -> Result<lru::Evicted, CacheError> {
        let Some(root) = &self.root else {
            return Ok(lru::Evicted::default());
        };
        lru::record_run_and_evict(root, hits, misses, self.max_size).map_err(|source| {
            CacheError::Io {
                path: root.join(lru::STATS_FILE).display().to_string(),
                source,
            }
        })
    }

    /// The cache's counts of hits, misses and evictions (zero for a cache that has none yet).
    ///
    /// # Errors
    /// As [`Cache::usage`]: the folder is not a stablesurf cache.
    pub fn stats(&self) -> Result<lru::Stats, CacheError> {
        Ok(self.marked_root()?.map(lru::read_stats).unwrap_or_default())
    }

    /// Removes the entries last used more than `age` ago (`cache clear --older-than`); entries
    /// another process is reading stay.
    ///
    /// # Errors
    /// As [`Cache::clear`].
    pub fn clear_older_than(&self, age: std::time::Duration) -> Result<Cleared, CacheError> {
        let Some(root) = self.marked_root()? else {
            return Ok(Cleared::default());
        };
        let debris = STAGES
            .iter()
            .flat_map(|stage| listing(&root.join(stage)))
            .filter(|(name, _, meta)| meta.is_dir() && is_shard_name(name))
            .map(|(_, shard, _)| sweep_shard(&shard))
            .sum::<u64>()
            + sweep_shard(root);
        let done = lru::evict_older_than(root, age);
        Ok(Cleared {
            entries: done.entries,
            bytes: done.bytes,
            debris,
            foreign: Vec::new(),
        })
    }

    /// Checks every entry's envelope: its checksum, format, and the key and stage of its path
    /// (the payload is covered by the checksum). Reads each entry under its shared lock.
    ///
    /// # Errors
    /// As [`Cache::usage`]: the folder is not a stablesurf cache.
    pub fn verify(&self) -> Result<Verified, CacheError> {
        let mut done = Verified::default();
        let Some(root) = self.marked_root()? else {
            return Ok(done);
        };
        for entry in lru::entries(root) {
            let name = entry
                .path
                .file_name()
                .map(|n| n.to_string_lossy().into_owned());
            let stage = entry
                .path
                .parent()
                .and_then(Path::parent)
                .and_then(Path::file_name)
                .map(|n| n.to_string_lossy().into_owned());
            let (Some(name), Some(stage)) = (name, stage) else {
                continue;
            };
            if !name.ends_with(".bin") {
                continue;
            }
            let good = read_entry(&entry.path)
                .ok()
                .is_some_and(|(bytes, _)| codec::envelope_matches(&bytes, &name[..64], &stage));
            if good {
                done.valid += 1;
                done.bytes += entry.bytes;
            } else if entry.path.exists() {
                done.invalid.push(entry.path);
            }
        }
        Ok(done)
    }

    /// Whether an entry for `key` is on disk (not decoded: a corrupt entry still counts). Lets a
    /// caller skip work that only a miss would need.
    pub(crate) fn contains(&self, stage: &str, key: &Key) -> bool {
        self.entry_path(stage, key)
            .is_some_and(|path| path.is_file())
    }

    /// Stores an artifact with its identity and explanation (`meta`, JSON) atomically.
    ///
    /// # Errors
    /// The directory cannot be created or written.
    #[cfg(test)]
    pub(crate) fn put<T: Artifact>(
        &self,
        stage: &str,
        stage_version: u32,
        key: &Key,
        artifact: &T,
        meta: &serde_json::Value,
    ) -> Result<(), CacheError> {
        let Some(path) = self.entry_path(stage, key) else {
            return Ok(());
        };
        self.prepare()?;
        write_entry(
            &path,
            &encode_entry(stage, stage_version, key, artifact, meta),
        )
    }

    /// A writer that stores this cache's entries on a background thread (see [`Puts`]).
    pub(crate) fn puts(&self) -> Puts {
        Puts {
            cache: self.clone(),
            sender: None,
            worker: None,
        }
    }

    /// Entries and bytes per stage (stages without entries left out). Temporaries of ended
    /// processes are removed on the way and counted in nothing.
    ///
    /// # Errors
    /// [`CacheError::NotACache`] when the folder is not a marked cache.
    pub fn usage(&self) -> Result<Vec<StageUsage>, CacheError> {
        let mut out = Vec::new();
        let Some(root) = self.marked_root()? else {
            return Ok(out);
        };
        for stage in STAGES {
            let (mut bytes, mut entries) = (0, 0);
            let stage_dir = root.join(stage);
            if !fs::symlink_metadata(&stage_dir).is_ok_and(|m| m.is_dir()) {
                continue;
            }
            for (_, shard, meta) in listing(&stage_dir) {
                if !meta.is_dir() {
                    continue;
                }
                sweep_shard(&shard);
                for (name, _, meta) in listing(&shard) {
                    if meta.is_file() && name.ends_with(".bin") && is_entry_name(&name) {
                        bytes += meta.len();
                        entries += 1;
                    }
                }
            }
            if entries > 0 {
                out.push(StageUsage {
                    stage: stage.to_string(),
                    entries,
                    bytes,
                });
            }
        }
        Ok(out)
    }

    /// Removes every entry and the temporaries of ended processes, then the stage and shard
    /// folders they leave empty. The root and its marker stay; anything else found under the
    /// root is left where it is and listed in [`Cleared::foreign`]. Links are never followed.
    ///
    /// # Errors
    /// [`CacheError::NotACache`] when the folder is not a marked cache; [`CacheError::Io`]
    /// when an entry cannot be removed.
    pub fn clear(&self) -> Result<Cleared, CacheError> {
        let mut done = Cleared::default();
        let Some(root) = self.marked_root()? else {
            return Ok(done);
        };
        let io = |path: &Path| {
            let path = path.display().to_string();
            move |source| CacheError::Io { path, source }
        };
        done.debris += sweep_shard(root);
        for (name, path, meta) in listing(root) {
            let ours = name == MARKER
                || name == lru::STATS_FILE
                || (meta.is_dir() && STAGES.contains(&name.as_str()))
                // A live run's temporary is its own.
                || (meta.is_file() && tmp_pid(&name).is_some());
            if !ours {
                done.foreign.push(path);
            }
        }
        for stage in STAGES {
            let stage_dir = root.join(stage);
            if !fs::symlink_metadata(&stage_dir).is_ok_and(|m| m.is_dir()) {
                continue;
            }
            for (shard_name, shard, meta) in listing(&stage_dir) {
                if !(meta.is_dir() && is_shard_name(&shard_name)) {
                    done.foreign.push(shard);
                    continue;
                }
                done.debris += sweep_shard(&shard);
                for (name, path, meta) in listing(&shard) {
                    if meta.is_file() && is_entry_name(&name) {
                        fs::remove_file(&path).map_err(io(&path))?;
                        done.bytes += meta.len();
                        done.entries += u64::from(name.ends_with(".bin"));
                    } else if !(meta.is_file() && tmp_pid(&name).is_some()) {
                        // A live run's temporary is its own; anything else is not the cache's.
                        done.foreign.push(path);
                    }
                }
                // Fails, harmlessly, when something is left in it.
                let _ = fs::remove_dir(&shard);
            }
            let _ = fs::remove_dir(&stage_dir);
        }
        Ok(done)
    }
}

/// An entry's bytes: the artifact, its identity and its explanation.
fn encode_entry<T: Artifact>(
    stage: &str,
    stage_version: u32,
    key: &Key,
    artifact: &T,
    meta: &serde_json::Value,
) -> Vec<u8> {
    let id = codec::EntryId {
        key: *key,
        stage: stage.to_string(),
        stage_version,
    };
    codec::encode(artifact, &id, meta)
}

/// Cache writes that run beside the caller's work, as sccache stores a compile's result after it
/// has answered: [`Puts::put`] encodes the entry (so it owns no borrowed data) and returns at
/// once; a background thread writes the files, each atomically as [`Cache::put`] does, in the
/// order they were put. The caller's next stage computes meanwhile, so a cold run does not wait
/// for the disk between stages.
///
/// [`Puts::finish`] waits for every write and returns the errors. Dropping the writer waits
/// too, so the entries of the stages that completed are stored even when a later stage fails.
pub(crate) struct Puts {
    cache: Cache,
    sender: Option<std::sync::mpsc::Sender<(PathBuf, Vec<u8>)>>,
    worker: Option<std::thread::JoinHandle<Vec<CacheError>>>,
}

impl Puts {
    /// Queues an artifact with its identity and explanation (`meta`, JSON) for storing; does
    /// nothing when the cache is disabled. Errors come out of [`Puts::finish`].
    pub(crate) fn put<T: Artifact>(
        &mut self,
        stage: &str,
        stage_version: u32,
        key: &Key,
        artifact: &T,
        meta: &serde_json::Value,
    ) {
        let Some(path) = self.cache.entry_path(stage, key) else {
            return;
        };
        let entry = (
            path,
            encode_entry(stage, stage_version, key, artifact, meta),
        );
        let cache = self.cache.clone();
        let sender = self.sender.get_or_insert_with(|| {
            let (sender, receiver) = std::sync::mpsc::channel::<(PathBuf, Vec<u8>)>();
            self.worker = Some(std::thread::spawn(move || {
                // After a failure the rest is dropped: the cause (a full disk, no permission)
                // is the same for every entry, and one report says it.
                let mut errors = Vec::new();
                if let Err(e) = cache.prepare() {
                    errors.push(e);
                }
                for (path, bytes) in receiver {
                    if errors.is_empty()
                        && let Err(e) = write_entry(&path, &bytes)
                    {
                        errors.push(e);
                    }
                }
                errors
            }));
            sender
        });
        // The worker only stops once the sender is dropped, so the send cannot fail.
        let _ = sender.send(entry);
    }

    /// Waits for every queued write; returns the error that stopped them, if any.
    pub(crate) fn finish(&mut self) -> Vec<CacheError> {
        self.sender = None;
        match self.worker.take().map(std::thread::JoinHandle::join) {
            Some(Ok(errors)) => errors,
            Some(Err(_)) => vec![CacheError::Io {
                path: self
                    .cache
                    .root
                    .as_ref()
                    .map(|r| r.display().to_string())
                    .unwrap_or_default(),
                source: std::io::Error::other("the cache writer stopped"),
            }],
            None => Vec::new(),
        }
    }
}

impl Drop for Puts {
    fn drop(&mut self) {
        self.finish();
    }
}

/// Writes an entry. A folder standing at the entry's path (which no run makes) is removed
/// first when it is empty, so the entry can be stored; a non-empty one is reported.
/// An entry's bytes, read under a shared lock of the file (so eviction by another process
/// passes it by), and the open file.
fn read_entry(path: &Path) -> std::io::Result<(Vec<u8>, fs::File)> {
    use std::io::Read;
    let mut file = fs::File::open(path)?;
    // Without locks on this file system the read goes on: eviction never tears an open file.
    let _ = file.lock_shared();
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes)?;
    Ok((bytes, file))
}

fn write_entry(path: &Path, bytes: &[u8]) -> Result<(), CacheError> {
    if fs::symlink_metadata(path).is_ok_and(|m| m.is_dir()) {
        fs::remove_dir(path).map_err(|source| CacheError::Io {
            path: path.display().to_string(),
            source: std::io::Error::new(
                source.kind(),
                format!("a folder stands where this cache entry belongs ({source}); remove it"),
            ),
        })?;
    }
    write_atomic(path, bytes)
}

/// Writes `bytes` to `path` through a unique temporary file in the same directory.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), CacheError> {
    let err = |source| CacheError::Io {
        path: path.display().to_string(),
        source,
    };
    let dir = path.parent().expect("entry paths have a parent");
    fs::create_dir_all(dir).map_err(err)?;
    let n = TMP_COUNTER.fetch_add(1, Ordering::Relaxed);
    let tmp = dir.join(format!("{TMP_PREFIX}{}-{n}", std::process::id()));
    let result = (|| {
        // No sync before the rename: a killed run leaves either the old entry or the whole new
        // one (the rename is atomic), and an entry torn by a power loss fails its checksum
        // and is a miss, so waiting for the disk here would buy nothing.
        let mut file = fs::File::create(&tmp)?;
        // `STABLESURF_FAULT=cache-full`, for the tests: every cache write fails half-way, as
        // on a full disk.
        if std::env::var("STABLESURF_FAULT").is_ok_and(|f| f == "cache-full") {
            file.write_all(&bytes[..bytes.len() / 2])?;
            return Err(std::io::Error::from(std::io::ErrorKind::StorageFull));
        }
        file.write_all(bytes)?;
        fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.map_err(err)
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn stage_key() {
        use crate::cache::{stage_key, Key};
        let input = Key::of_bytes(b"scan");
        let a = stage_key("fit", 1, br#"{"degree":6}"#, &input);
        assert_eq!(a, stage_key("fit", 1, br#"{"degree":6}"#, &input));
        assert_ne!(a, stage_key("fit", 1, br#"{"degree":8}"#, &input));
    }
}
