//! Unit tests of `cache`.

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
    assert_eq!(cache.get::<PointCloud>("import", 1, &key).1, Lookup::Miss);
    cache
        .put(
            "import",
            1,
            &key,
            &cloud,
            &serde_json::json!({"stage": "import"}),
        )
        .unwrap();
    assert_eq!(
        cache.get::<PointCloud>("import", 1, &key),
        (
            Some((cloud.clone(), serde_json::json!({"stage": "import"}))),
            Lookup::Hit
        )
    );
    let path = cache.entry_path("import", &key).unwrap();
    let mut bytes = fs::read(&path).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 1;
    fs::write(&path, bytes).unwrap();
    assert_eq!(
        cache.get::<PointCloud>("import", 1, &key).1,
        Lookup::Corrupt
    );
    cache
        .put("import", 1, &key, &cloud, &serde_json::json!({}))
        .unwrap();
    assert_eq!(cache.get::<PointCloud>("import", 1, &key).1, Lookup::Hit);
    // Another stage version under the same key: not this entry.
    assert_eq!(
        cache.get::<PointCloud>("import", 2, &key).1,
        Lookup::Corrupt
    );
    assert_eq!(cache.usage().unwrap()[0].entries, 1);
    let cleared = cache.clear().unwrap();
    assert_eq!((cleared.entries, cleared.foreign.len()), (1, 0));
    assert_eq!(cache.get::<PointCloud>("import", 1, &key).1, Lookup::Miss);
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
            1,
            key,
            cloud,
            &serde_json::json!({"i": cloud.points[0][0]}),
        );
    }
    assert!(puts.finish().is_empty());
    for (key, cloud) in &clouds {
        assert_eq!(
            cache.get::<PointCloud>("import", 1, key),
            (
                Some((cloud.clone(), serde_json::json!({"i": cloud.points[0][0]}))),
                Lookup::Hit
            )
        );
    }
    // Dropping the writer also waits: the entry is there right after.
    let key = Key::of_bytes(b"dropped");
    {
        let mut puts = cache.puts();
        puts.put("fit", 1, &key, &clouds[0].1, &serde_json::json!({}));
    }
    assert_eq!(cache.get::<PointCloud>("fit", 1, &key).1, Lookup::Hit);

    // A root below a file cannot be created: one error, whatever the number of entries.
    let file = dir.path().join("file");
    fs::write(&file, b"").unwrap();
    let mut puts = Cache::at(file.join("cache")).puts();
    for (key, cloud) in &clouds {
        puts.put("import", 1, key, cloud, &serde_json::json!({}));
    }
    let errors = puts.finish();
    assert_eq!(errors.len(), 1);
    assert!(errors[0].to_string().contains("cannot write the cache"));
    // A disabled cache queues nothing and starts no thread.
    let mut puts = Cache::disabled().puts();
    puts.put("import", 1, &key, &clouds[0].1, &serde_json::json!({}));
    assert!(puts.worker.is_none() && puts.finish().is_empty());
}

#[test]
fn disabled_cache_stores_nothing() {
    let cache = Cache::disabled();
    let key = Key::of_bytes(b"x");
    cache
        .put(
            "import",
            1,
            &key,
            &PointCloud::default(),
            &serde_json::json!({}),
        )
        .unwrap();
    assert_eq!(cache.get::<PointCloud>("import", 1, &key).1, Lookup::Miss);
}

fn cloud_entry(cache: &Cache, n: u8) -> (Key, PathBuf) {
    let key = Key::of_bytes(&[n]);
    let cloud = PointCloud {
        points: vec![[f64::from(n), 0.0, 0.0]],
        ..Default::default()
    };
    cache
        .put("import", 1, &key, &cloud, &serde_json::json!({}))
        .unwrap();
    (key, cache.entry_path("import", &key).unwrap())
}

#[test]
fn a_folder_the_cache_did_not_make_is_refused_and_left_alone() {
    let dir = tempfile::tempdir().unwrap();
    // A user's folder: never used, never cleared.
    let user = dir.path().join("v");
    fs::create_dir_all(user.join("my_project")).unwrap();
    fs::write(user.join("my_project/notes.txt"), b"mine").unwrap();
    let cache = Cache::at(&user);
    for err in [
        cache.prepare().unwrap_err(),
        cache.clear().unwrap_err(),
        cache.usage().unwrap_err(),
    ] {
        let msg = err.to_string();
        assert!(
            msg.contains("is not a stablesurf cache") && msg.contains("my_project"),
            "{msg}"
        );
    }
    assert_eq!(
        fs::read(user.join("my_project/notes.txt")).unwrap(),
        b"mine"
    );
    // A folder that does not exist, and a file, are no caches to clear or list.
    let missing = Cache::at(dir.path().join("missing"));
    assert!(missing
        .clear()
        .unwrap_err()
        .to_string()
        .contains("does not exist"));
    assert!(!dir.path().join("missing").exists());
    fs::write(dir.path().join("file"), b"x").unwrap();
    let file = Cache::at(dir.path().join("file"));
    assert!(file.usage().unwrap_err().to_string().contains("is a file"));
    assert!(file.prepare().is_err());
    // Another program's cache directory tag is not ours either.
    let other = dir.path().join("other");
    fs::create_dir(&other).unwrap();
    fs::write(
        other.join(MARKER),
        format!("{MARKER_SIGNATURE}\n# made by cargo\n"),
    )
    .unwrap();
    assert!(Cache::at(&other)
        .clear()
        .unwrap_err()
        .to_string()
        .contains("another program"));
    assert!(other.join(MARKER).exists());
}

#[test]
fn clear_removes_only_what_the_cache_made() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("cache");
    let cache = Cache::at(&root);
    let (_, entry) = cloud_entry(&cache, 1);
    cloud_entry(&cache, 2);
    // Things the cache did not make, at every level, and a link out of the cache.
    let outside = dir.path().join("outside");
    fs::create_dir(&outside).unwrap();
    fs::write(outside.join("keep.txt"), b"keep").unwrap();
    fs::write(root.join("README"), b"user").unwrap();
    fs::write(root.join("import").join("notes"), b"user").unwrap();
    let shard = entry.parent().unwrap().to_path_buf();
    fs::write(shard.join("mine.bin"), b"user").unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(&outside, root.join("fit")).unwrap();
    // Debris of an ended process, and a temporary of this (live) one.
    let dead = shard.join(format!("{TMP_PREFIX}{}-0", u32::MAX - 7));
    let live = shard.join(format!("{TMP_PREFIX}{}-9", std::process::id()));
    fs::write(&dead, b"torn").unwrap();
    fs::write(&live, b"in progress").unwrap();

    let cleared = cache.clear().unwrap();
    assert_eq!(cleared.entries, 2);
    assert!(!entry.exists());
    for kept in [
        outside.join("keep.txt"),
        root.join("README"),
        root.join("import/notes"),
        shard.join("mine.bin"),
        live.clone(),
        root.join(MARKER),
    ] {
        assert!(kept.exists(), "{} removed", kept.display());
    }
    if cfg!(target_os = "linux") {
        assert!(!dead.exists());
        assert_eq!(cleared.debris, 1);
    }
    assert!(cleared.foreign.contains(&root.join("README")));
    assert!(cleared.foreign.contains(&shard.join("mine.bin")));
    // The cache still works after a clear.
    cloud_entry(&cache, 3);
    assert_eq!(cache.usage().unwrap()[0].entries, 1);
}

#[test]
fn an_empty_folder_or_a_format_1_cache_is_adopted_and_a_marking_race_is_harmless() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty");
    fs::create_dir(&empty).unwrap();
    Cache::at(&empty).prepare().unwrap();
    assert!(empty.join(MARKER).is_file());
    let old = dir.path().join("old");
    let shard = old.join("fit").join("ab");
    fs::create_dir_all(&shard).unwrap();
    let name = format!("ab{}", "0".repeat(62));
    fs::write(shard.join(format!("{name}.bin")), b"x").unwrap();
    fs::write(shard.join(format!("{name}.json")), b"{}").unwrap();
    // `cache clear` on it, before any run has marked it, clears it.
    assert_eq!(Cache::at(&old).clear().unwrap().entries, 1);
    assert!(!old.join("fit").exists() && old.join(MARKER).is_file());
    // An empty folder holds no cache to list or clear.
    let bare = dir.path().join("bare");
    fs::create_dir(&bare).unwrap();
    assert!(Cache::at(&bare)
        .usage()
        .unwrap_err()
        .to_string()
        .contains("empty"));
    // Another run's temporary while it writes the marker does not make the folder foreign.
    let racing = dir.path().join("racing");
    fs::create_dir(&racing).unwrap();
    fs::write(
        racing.join(format!("{TMP_PREFIX}{}-0", std::process::id())),
        b"",
    )
    .unwrap();
    Cache::at(&racing).prepare().unwrap();
}

#[test]
fn a_folder_at_an_entry_path_is_replaced_by_the_entry() {
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::at(dir.path().join("c"));
    let (key, entry) = cloud_entry(&cache, 1);
    fs::remove_file(&entry).unwrap();
    fs::create_dir(&entry).unwrap();
    assert_eq!(
        cache.get::<PointCloud>("import", 1, &key).1,
        Lookup::Corrupt
    );
    cloud_entry(&cache, 1);
    assert_eq!(cache.get::<PointCloud>("import", 1, &key).1, Lookup::Hit);
}

#[test]
fn a_lookup_removes_the_debris_of_ended_processes_in_its_folder() {
    let dir = tempfile::tempdir().unwrap();
    let cache = Cache::at(dir.path().join("c"));
    let (key, entry) = cloud_entry(&cache, 1);
    let dead = entry
        .parent()
        .unwrap()
        .join(format!("{TMP_PREFIX}{}-3", u32::MAX - 7));
    fs::write(&dead, b"torn").unwrap();
    assert_eq!(cache.get::<PointCloud>("import", 1, &key).1, Lookup::Hit);
    if cfg!(target_os = "linux") {
        assert!(!dead.exists());
    }
}
