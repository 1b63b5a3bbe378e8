//! The moments protocol for a scan given in chunks: `stablesurf moments` (one pass over one
//! chunk), `stablesurf frame` (merges a pass's files into the next pass's argument), and the
//! moments-file reading `fit --from-moments` shares.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context, Result};
use stablesurf::cache::Cache;
use stablesurf::fit::moments::{self, MomentsError, MomentsPass, PartialMoments};
use stablesurf::pipeline::{self, PipelineConfig, ScanSource};

use super::args::{FrameArgs, MomentsArgs};
use super::config;
use super::progress::{StderrObserver, Verbosity};

/// Reads a moments file; errors name it.
pub fn read_moments(path: &Path) -> Result<PartialMoments> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    PartialMoments::from_bytes(&bytes).with_context(|| format!("reading {}", path.display()))
}

/// A merge error, naming the offending file when the error points at one.
pub fn merge_error(err: MomentsError, parts: &[PathBuf]) -> anyhow::Error {
    let named = match &err {
        MomentsError::Mismatch { index, .. } => parts.get(*index),
        _ => None,
    };
    match named {
        Some(path) => anyhow!("{}: {err}", path.display()),
        None => anyhow!("merging {} moments files: {err}", parts.len()),
    }
}

/// Runs `stablesurf moments`: one pass of the moments protocol over one chunk.
pub fn moments(args: MomentsArgs, verbosity: Verbosity) -> Result<()> {
    let fit = config::fit_params(&args.fit)?;
    let mut config = PipelineConfig::default();
    // Outlier removal needs all the points: a chunk is used as it is.
    config.outliers.keep = true;
    config.normals = config::normals_params(&args.normals);
    let pass = match (args.center, args.frame) {
        (_, Some(f)) => MomentsPass::System {
            frame: moments::Frame {
                center: [f[0], f[1], f[2]],
                scale: f[3],
            },
            degree: fit.degree,
            epsilon: fit.epsilon,
        },
        (Some(center), None) => MomentsPass::Scale { center },
        (None, None) => MomentsPass::Center,
    };
    let mut observer = StderrObserver::new(verbosity);
    let cloud = pipeline::oriented_cloud(
        &ScanSource::from_inputs(std::slice::from_ref(&args.input)),
        &config,
        &Cache::disabled(),
        &mut observer,
    )
    .with_context(|| format!("reading {}", args.input.display()))?;
    let part = moments::moments(&cloud, &pass)
        .with_context(|| format!("moments of {}", args.input.display()))?;
    config::write_file(&args.output, &part.to_bytes())
}

/// Runs `stablesurf frame`: merges pass-1 or pass-2 files and prints the next pass's argument.
pub fn frame(args: FrameArgs) -> Result<()> {
    let parts = args
        .parts
        .iter()
        .map(|p| read_moments(p))
        .collect::<Result<Vec<_>>>()?;
    let merged = moments::merge_frame(&parts).map_err(|e| merge_error(e, &args.parts))?;
    let mut out = std::io::stdout().lock();
    writeln!(out, "{}", merged.argument())?;
    Ok(())
}
