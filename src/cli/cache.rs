//! `stablesurf cache`: where the stage cache is, how much each stage holds, its size limit and
//! hit rate (`info`, on stdout), a check of every entry (`verify`), or the removal of its
//! entries, all or the long unused (`clear`), leaving anything the cache did not make.

use std::io::Write;

use anyhow::Result;
use stablesurf::cache::{lru, Cache};

use super::args::{CacheAction, CacheArgs};
use super::usage;

/// Bytes in the unit people read: B, kB, MB or GB (powers of 1000, as the limit is given).
fn human(bytes: u64) -> String {
    let b = bytes as f64;
    match bytes {
        0..1_000 => format!("{bytes} B"),
        1_000..1_000_000 => format!("{:.1} kB", b / 1e3),
        1_000_000..1_000_000_000 => format!("{:.1} MB", b / 1e6),
        _ => format!("{:.2} GB", b / 1e9),
    }
}

/// Runs `stablesurf cache`.
pub fn cache(args: CacheArgs) -> Result<()> {
    let dir = args
        .cache_dir
        .or_else(stablesurf::cache::default_dir)
        .ok_or_else(|| {
            usage("no cache directory: set HOME or XDG_CACHE_HOME, or pass --cache-dir")
        })?;
    let limit = args.cache_max_size.unwrap_or(lru::DEFAULT_MAX_SIZE);
    let cache = Cache::at(&dir).with_max_size(limit);
    match args.action {
        CacheAction::Info { json } => {
            // Refuses a folder that is not a stablesurf cache (exit 1, saying why).
            let usage = cache.usage()?;
            let stats = cache.stats()?;
            let bytes: u64 = usage.iter().map(|u| u.bytes).sum();
            let entries: u64 = usage.iter().map(|u| u.entries).sum();
            let mut out = std::io::stdout().lock();
            if json {
                let stages: serde_json::Map<String, serde_json::Value> = usage
                    .iter()
                    .map(|u| {
                        let figures = serde_json::json!({ "entries": u.entries, "bytes": u.bytes });
                        (u.stage.clone(), figures)
                    })
                    .collect();
                let info = serde_json::json!({
                    "directory": dir.display().to_string(),
                    "entries": entries,
                    "bytes": bytes,
                    "max_size": limit,
                    "stages": stages,
                    "runs": stats.runs,
                    "hits": stats.hits,
                    "misses": stats.misses,
                    "hit_rate": stats.hit_rate(),
                    "evicted_entries": stats.evicted_entries,
                    "evicted_bytes": stats.evicted_bytes,
                });
                writeln!(out, "{info}")?;
                return Ok(());
            }
            writeln!(out, "cache directory: {}", dir.display())?;
            writeln!(
                out,
                "size: {} in {entries} entries, limit {} ({:.0}% used)",
                human(bytes),
                human(limit),
                100.0 * bytes as f64 / limit.max(1) as f64
            )?;
            let rate = stats
                .hit_rate()
                .map_or("-".to_string(), |r| format!("{:.0}%", 100.0 * r));
            writeln!(
                out,
                "lookups: {} hits, {} misses (hit rate {rate}) over {} runs; evicted {} entries ({})",
                stats.hits,
                stats.misses,
                stats.runs,
                stats.evicted_entries,
                human(stats.evicted_bytes)
            )?;
            if usage.is_empty() {
                writeln!(out, "(no entries)")?;
            }
            for u in usage {
                writeln!(
                    out,
                    "{:<12} {:>6} entries {:>12}",
                    u.stage,
                    u.entries,
                    human(u.bytes)
                )?;
            }
        }
        CacheAction::Verify { json } => {
            let done = cache.verify()?;
            let mut out = std::io::stdout().lock();
            if json {
                let info = serde_json::json!({
                    "directory": dir.display().to_string(),
                    "valid": done.valid,
                    "bytes": done.bytes,
                    "invalid": done.invalid.iter().map(|p| p.display().to_string()).collect::<Vec<_>>(),
                });
                writeln!(out, "{info}")?;
            } else {
                writeln!(
                    out,
                    "{} entries verified ({}), {} failed",
                    done.valid,
                    human(done.bytes),
                    done.invalid.len()
                )?;
                for p in &done.invalid {
                    writeln!(out, "failed: {}", p.display())?;
                }
            }
            if !done.invalid.is_empty() {
                anyhow::bail!(
                    "{} cache entries in {} fail their checksum or identity; a run recomputes and rewrites them, or `stablesurf cache clear` removes them",
                    done.invalid.len(),
                    dir.display()
                );
            }
        }
        CacheAction::Clear { older_than } => {
            let done = match older_than {
                Some(age) => cache.clear_older_than(age)?,
                None => cache.clear()?,
            };
            eprintln!(
                "stablesurf: cleared {} entries ({}) from {}",
                done.entries,
                human(done.bytes),
                dir.display()
            );
            if !done.foreign.is_empty() {
                let shown: Vec<String> = done
                    .foreign
                    .iter()
                    .take(5)
                    .map(|p| p.display().to_string())
                    .collect();
                eprintln!(
                    "stablesurf: left {} item(s) that the cache did not make: {}{}",
                    done.foreign.len(),
                    shown.join(", "),
                    if done.foreign.len() > 5 { ", …" } else { "" }
                );
            }
        }
    }
    Ok(())
}
