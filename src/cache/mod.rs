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
//! Layout on disk: `<root>/<stage>/<k0k1>/<key>.bin` plus `<key>.json` describing what went into
//! the key (for `-v`). Writes go to a unique temporary file in the same directory and are renamed
//! into place, so a killed run or two concurrent runs never leave a torn entry (no sync before
//! the rename: an entry torn by a power loss fails its checksum and is a miss). An entry that
//! fails to decode or verify (see [`codec`]) is a miss and is rewritten; it is never an error.
//!
//! A run stores its entries through [`Puts`], on a background thread, while its next stages
//! compute. A store that fails costs only the next run's time, so the pipeline reports it as a
//! warning and the run's outputs are complete.

pub mod codec;

use std::fmt;
use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

pub use codec::{Artifact, OutputFiles};

/// Version of the cache as a whole (entry envelope and key recipe). If you change either,
/// bump it: every key changes and old entries are simply never read again.
pub const CACHE_FORMAT_VERSION: u32 = 1;

/// Errors of the cache that the caller must see (reads never fail: a bad entry is a miss).
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    /// The cache directory could not be created or written.
    #[error("cannot write the cache at {path}: {source} (pick another place with --cache-dir, or use --no-cache)")]
    Io {
        /// The path.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
}

/// A 32-byte cache key.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Key(pub [u8; 32]);

impl Key {
    /// The key of raw input bytes (the import stage's input).
    pub fn of_bytes(bytes: &[u8]) -> Key {
        Key(*blake3::hash(bytes).as_bytes())
    }

    /// Lower-case hex.
    pub fn hex(&self) -> String {
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
///
/// ```
/// use stablesurf::cache::{stage_key, Key};
/// let input = Key::of_bytes(b"scan");
/// let a = stage_key("fit", 1, br#"{"degree":6}"#, &input);
/// assert_eq!(a, stage_key("fit", 1, br#"{"degree":6}"#, &input));
/// assert_ne!(a, stage_key("fit", 1, br#"{"degree":8}"#, &input));
/// ```
pub fn stage_key(stage: &str, stage_version: u32, params: &[u8], input: &Key) -> Key {
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
pub fn params_bytes<P: serde::Serialize>(params: &P) -> Vec<u8> {
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
pub enum Lookup {
    /// Found and verified.
    Hit,
    /// Not present (or the cache is disabled).
    Miss,
    /// Present but corrupt or of another version: recomputed and rewritten.
    Corrupt,
}

impl Lookup {
    /// "hit", "miss" or "corrupt".
    pub fn as_str(self) -> &'static str {
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
}

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

impl Cache {
    /// A cache rooted at `root` (created on first write).
    pub fn at(root: impl Into<PathBuf>) -> Cache {
        Cache {
            root: Some(root.into()),
        }
    }

    /// A cache that stores nothing (`--no-cache`).
    pub fn disabled() -> Cache {
        Cache { root: None }
    }

    /// The root directory, if enabled.
    pub fn root(&self) -> Option<&Path> {
        self.root.as_deref()
    }

    fn entry_path(&self, stage: &str, key: &Key, ext: &str) -> Option<PathBuf> {
        let hex = key.hex();
        Some(
            self.root
                .as_ref()?
                .join(stage)
                .join(&hex[..2])
                .join(format!("{hex}.{ext}")),
        )
    }

    /// Looks an artifact up. Never fails: unreadable or corrupt entries are misses.
    pub fn get<T: Artifact>(&self, stage: &str, key: &Key) -> (Option<T>, Lookup) {
        let Some(path) = self.entry_path(stage, key, "bin") else {
            return (None, Lookup::Miss);
        };
        match fs::read(&path) {
            Ok(bytes) => match codec::decode::<T>(&bytes) {
                Some(v) => (Some(v), Lookup::Hit),
                None => (None, Lookup::Corrupt),
            },
            Err(_) => (None, Lookup::Miss),
        }
    }

    /// Whether an entry for `key` is on disk (not decoded: a corrupt entry still counts). Lets a
    /// caller skip work that only a miss would need.
    pub fn contains(&self, stage: &str, key: &Key) -> bool {
        self.entry_path(stage, key, "bin")
            .is_some_and(|path| path.is_file())
    }

    /// The explanation stored beside an entry (what went into its key, its figures), if readable.
    pub fn meta(&self, stage: &str, key: &Key) -> Option<serde_json::Value> {
        let path = self.entry_path(stage, key, "json")?;
        serde_json::from_slice(&fs::read(path).ok()?).ok()
    }

    /// Stores an artifact and its explanation (`meta`, JSON) atomically.
    ///
    /// # Errors
    /// The directory cannot be created or written.
    pub fn put<T: Artifact>(
        &self,
        stage: &str,
        key: &Key,
        artifact: &T,
        meta: &serde_json::Value,
    ) -> Result<(), CacheError> {
        let (Some(bin), Some(json)) = (
            self.entry_path(stage, key, "bin"),
            self.entry_path(stage, key, "json"),
        ) else {
            return Ok(());
        };
        let meta_bytes = serde_json::to_vec_pretty(meta).expect("json value serializes");
        write_atomic(&json, &meta_bytes)?;
        write_atomic(&bin, &codec::encode(artifact))
    }

    /// A writer that stores this cache's entries on a background thread (see [`Puts`]).
    pub fn puts(&self) -> Puts {
        Puts {
            cache: self.clone(),
            sender: None,
            worker: None,
        }
    }

    /// Total size in bytes and number of entries per stage.
    pub fn usage(&self) -> Vec<(String, u64, u64)> {
        let mut out = Vec::new();
        let Some(root) = &self.root else { return out };
        let Ok(stages) = fs::read_dir(root) else {
            return out;
        };
        let mut names: Vec<_> = stages.flatten().filter(|e| e.path().is_dir()).collect();
        names.sort_by_key(|e| e.file_name());
        for stage in names {
            let (mut bytes, mut entries) = (0, 0);
            for shard in fs::read_dir(stage.path()).into_iter().flatten().flatten() {
                for f in fs::read_dir(shard.path()).into_iter().flatten().flatten() {
                    if let Ok(m) = f.metadata() {
                        bytes += m.len();
                        entries += u64::from(f.path().extension().is_some_and(|e| e == "bin"));
                    }
                }
            }
            out.push((
                stage.file_name().to_string_lossy().into_owned(),
                entries,
                bytes,
            ));
        }
        out
    }

    /// Removes every entry.
    ///
    /// # Errors
    /// A file could not be removed.
    pub fn clear(&self) -> Result<(), CacheError> {
        let Some(root) = &self.root else {
            return Ok(());
        };
        match fs::remove_dir_all(root) {
            Ok(()) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
            Err(source) => Err(CacheError::Io {
                path: root.display().to_string(),
                source,
            }),
        }
    }
}

/// One entry for the background writer: the explanation's path and bytes, then the artifact's.
type Entry = [(PathBuf, Vec<u8>); 2];

/// Cache writes that run beside the caller's work, as sccache stores a compile's result after it
/// has answered: [`Puts::put`] encodes the entry (so it owns no borrowed data) and returns at
/// once; a background thread writes the files, each atomically as [`Cache::put`] does, in the
/// order they were put. The caller's next stage computes meanwhile, so a cold run does not wait
/// for the disk between stages.
///
/// [`Puts::finish`] waits for every write and returns the errors. Dropping the writer waits
/// too, so the entries of the stages that completed are stored even when a later stage fails.
pub struct Puts {
    cache: Cache,
    sender: Option<std::sync::mpsc::Sender<Entry>>,
    worker: Option<std::thread::JoinHandle<Vec<CacheError>>>,
}

impl Puts {
    /// Queues an artifact and its explanation (`meta`, JSON) for storing; does nothing when the
    /// cache is disabled. Errors come out of [`Puts::finish`].
    pub fn put<T: Artifact>(
        &mut self,
        stage: &str,
        key: &Key,
        artifact: &T,
        meta: &serde_json::Value,
    ) {
        let (Some(bin), Some(json)) = (
            self.cache.entry_path(stage, key, "bin"),
            self.cache.entry_path(stage, key, "json"),
        ) else {
            return;
        };
        let meta_bytes = serde_json::to_vec_pretty(meta).expect("json value serializes");
        let entry = [(json, meta_bytes), (bin, codec::encode(artifact))];
        let sender = self.sender.get_or_insert_with(|| {
            let (sender, receiver) = std::sync::mpsc::channel::<Entry>();
            self.worker = Some(std::thread::spawn(move || {
                // After a failure the rest is dropped: the cause (a full disk, no permission)
                // is the same for every entry, and one report says it.
                let mut errors = Vec::new();
                for entry in receiver {
                    if errors.is_empty() {
                        if let Some(e) = entry
                            .into_iter()
                            .find_map(|(path, bytes)| write_atomic(&path, &bytes).err())
                        {
                            errors.push(e);
                        }
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
    pub fn finish(&mut self) -> Vec<CacheError> {
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

/// Writes `bytes` to `path` through a unique temporary file in the same directory.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), CacheError> {
    let err = |source| CacheError::Io {
        path: path.display().to_string(),
        source,
    };
    let dir = path.parent().expect("entry paths have a parent");
    fs::create_dir_all(dir).map_err(err)?;
    let n = TMP_COUNTER.fetch_add(1, Ordering::Relaxed);
    let tmp = dir.join(format!(".tmp-{}-{n}", std::process::id()));
    let result = (|| {
        // No sync before the rename: a killed run leaves either the old entry or the whole new
        // one (the rename is atomic), and an entry torn by a power loss fails its checksum
        // and is a miss, so waiting for the disk here would buy nothing.
        fs::File::create(&tmp)?.write_all(bytes)?;
        fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result.map_err(err)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::PointCloud;

    #[test]
    fn same_inputs_same_key_and_each_change_differs() {
        let input = Key::of_bytes(b"ply\n...");
        let base = stage_key("normals", 1, b"{\"k\":12}", &input);
        assert_eq!(base, stage_key("normals", 1, b"{\"k\":12}", &input));
        assert_ne!(base, stage_key("fit", 1, b"{\"k\":12}", &input));
        assert_ne!(base, stage_key("normals", 2, b"{\"k\":12}", &input));
        assert_ne!(base, stage_key("normals", 1, b"{\"k\":13}", &input));
        assert_ne!(
            base,
            stage_key("normals", 1, b"{\"k\":12}", &Key::of_bytes(b"other"))
        );
        // Field boundaries are delimited: moving bytes between fields changes the key.
        assert_ne!(
            stage_key("ab", 1, b"c", &input),
            stage_key("a", 1, b"bc", &input)
        );
    }

    #[test]
    fn renamed_input_file_gives_same_key() {
        let dir = tempfile::tempdir().unwrap();
        let a = dir.path().join("a.xyz");
        let b = dir.path().join("sub-b.xyz");
        fs::write(&a, b"0 0 0\n").unwrap();
        fs::copy(&a, &b).unwrap();
        assert_eq!(
            Key::of_bytes(&fs::read(&a).unwrap()),
            Key::of_bytes(&fs::read(&b).unwrap())
        );
    }

    #[test]
    fn put_get_and_corruption_is_a_miss() {
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::at(dir.path());
        let key = Key::of_bytes(b"x");
        let cloud = PointCloud {
            points: vec![[1.0, 2.0, 3.0]],
            ..Default::default()
        };
        assert_eq!(cache.get::<PointCloud>("import", &key).1, Lookup::Miss);
        cache
            .put(
                "import",
                &key,
                &cloud,
                &serde_json::json!({"stage": "import"}),
            )
            .unwrap();
        assert_eq!(
            cache.get::<PointCloud>("import", &key),
            (Some(cloud.clone()), Lookup::Hit)
        );
        let path = cache.entry_path("import", &key, "bin").unwrap();
        let mut bytes = fs::read(&path).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 1;
        fs::write(&path, bytes).unwrap();
        assert_eq!(cache.get::<PointCloud>("import", &key).1, Lookup::Corrupt);
        cache
            .put("import", &key, &cloud, &serde_json::json!({}))
            .unwrap();
        assert_eq!(cache.get::<PointCloud>("import", &key).1, Lookup::Hit);
        assert_eq!(cache.usage()[0].1, 1);
        cache.clear().unwrap();
        assert_eq!(cache.get::<PointCloud>("import", &key).1, Lookup::Miss);
    }

    #[test]
    fn background_puts_land_by_finish_and_a_failure_is_reported_once() {
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::at(dir.path());
        let clouds: Vec<(Key, PointCloud)> = (0..20)
            .map(|i| {
                let cloud = PointCloud {
                    points: vec![[f64::from(i), 0.0, 0.0]],
                    ..Default::default()
                };
                (Key::of_bytes(&[i as u8]), cloud)
            })
            .collect();
        let mut puts = cache.puts();
        for (key, cloud) in &clouds {
            puts.put(
                "import",
                key,
                cloud,
                &serde_json::json!({"i": cloud.points[0][0]}),
            );
        }
        assert!(puts.finish().is_empty());
        for (key, cloud) in &clouds {
            assert_eq!(
                cache.get::<PointCloud>("import", key),
                (Some(cloud.clone()), Lookup::Hit)
            );
            assert_eq!(
                cache.meta("import", key).unwrap()["i"],
                serde_json::json!(cloud.points[0][0])
            );
        }
        // Dropping the writer also waits: the entry is there right after.
        let key = Key::of_bytes(b"dropped");
        {
            let mut puts = cache.puts();
            puts.put("fit", &key, &clouds[0].1, &serde_json::json!({}));
        }
        assert_eq!(cache.get::<PointCloud>("fit", &key).1, Lookup::Hit);

        // A root below a file cannot be created: one error, whatever the number of entries.
        let file = dir.path().join("file");
        fs::write(&file, b"").unwrap();
        let mut puts = Cache::at(file.join("cache")).puts();
        for (key, cloud) in &clouds {
            puts.put("import", key, cloud, &serde_json::json!({}));
        }
        let errors = puts.finish();
        assert_eq!(errors.len(), 1);
        assert!(errors[0].to_string().contains("cannot write the cache"));
        // A disabled cache queues nothing and starts no thread.
        let mut puts = Cache::disabled().puts();
        puts.put("import", &key, &clouds[0].1, &serde_json::json!({}));
        assert!(puts.worker.is_none() && puts.finish().is_empty());
    }

    #[test]
    fn disabled_cache_stores_nothing() {
        let cache = Cache::disabled();
        let key = Key::of_bytes(b"x");
        cache
            .put(
                "import",
                &key,
                &PointCloud::default(),
                &serde_json::json!({}),
            )
            .unwrap();
        assert_eq!(cache.get::<PointCloud>("import", &key).1, Lookup::Miss);
    }
}
