//! `stablesurf cache`: where the stage cache is and how much each stage holds (`info`, on
//! stdout), or remove its entries (`clear`), leaving anything the cache did not make.

use std::io::Write;

use anyhow::Result;
use stablesurf::cache::Cache;

use super::args::{CacheAction, CacheArgs};
use super::usage;

/// Runs `stablesurf cache`.
pub fn cache(args: CacheArgs) -> Result<()> {
    let dir = args
        .cache_dir
        .or_else(stablesurf::cache::default_dir)
        .ok_or_else(|| {
            usage("no cache directory: set HOME or XDG_CACHE_HOME, or pass --cache-dir")
        })?;
    let cache = Cache::at(&dir);
    match args.action {
        CacheAction::Info => {
            // Refuses a folder that is not a stablesurf cache (exit 1, saying why).
            let usage = cache.usage()?;
            let mut out = std::io::stdout().lock();
            writeln!(out, "cache directory: {}", dir.display())?;
            if usage.is_empty() {
                writeln!(out, "(no entries)")?;
            }
            for u in usage {
                writeln!(
                    out,
                    "{:<12} {:>6} entries {:>12.1} KiB",
                    u.stage,
                    u.entries,
                    u.bytes as f64 / 1024.0
                )?;
            }
        }
        CacheAction::Clear => {
            let done = cache.clear()?;
            eprintln!(
                "stablesurf: cleared {} entries ({:.1} KiB) from {}",
                done.entries,
                done.bytes as f64 / 1024.0,
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
