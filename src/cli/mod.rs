//! The binary's command line, in the layers it passes through: [`args`] is what clap parses
//! (with the numeric flags' ranges in [`range`]), [`config`] turns the parsed values into the
//! library's parameters, and one module per subcommand reads its inputs, calls the library and
//! writes its outputs, reporting on stderr through [`progress`]. Nothing in the library depends
//! on this module.
//!
//! Input: a parsed [`Cli`]. Output: files, stdout for machine-readable output (`--json`), and
//! stderr for everything else. A command line that parses but makes no sense is a
//! [`UsageError`] (exit code 2); every other error is a runtime error (exit code 1).

pub mod allocator;
mod args;
mod batch;
mod cache;
mod config;
mod fit;
mod info;
mod logger;
mod mesh;
mod moments;
mod normals;
mod progress;
mod range;
mod render;
mod run;
mod slices;

use anyhow::{Context, Result};

pub use args::Cli;
use args::CommandArgs;
use progress::Verbosity;

/// A command line that parsed but makes no sense (exit code 2).
#[derive(Debug)]
pub struct UsageError(String);

impl std::fmt::Display for UsageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for UsageError {}

/// A [`UsageError`] saying `msg`.
fn usage(msg: impl Into<String>) -> anyhow::Error {
    anyhow::Error::new(UsageError(msg.into()))
}

/// Runs the parsed command line.
///
/// # Errors
/// A [`UsageError`], or the command's runtime error with its context.
pub fn run(cli: Cli) -> Result<()> {
    // Every numeric flag was checked against its range (`range::THREADS`, `range::DEGREE`, …)
    // while the command line was parsed: out of range is clap's usage error, before any work.
    if let Some(n) = cli.threads {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .with_context(|| format!("setting up the thread pool of -j {n}"))?;
    }
    logger::install(cli.verbose);
    let verbosity = if cli.quiet {
        Verbosity::Quiet
    } else if cli.verbose > 0 {
        Verbosity::Verbose
    } else {
        Verbosity::Normal
    };
    match cli.command {
        CommandArgs::Run(args) => run::run(args, verbosity),
        CommandArgs::Normals(args) => normals::normals(args, verbosity),
        CommandArgs::Fit(args) => fit::fit(args, verbosity),
        CommandArgs::Moments(args) => moments::moments(args, verbosity),
        CommandArgs::Frame(args) => moments::frame(args),
        CommandArgs::Mesh(args) => mesh::mesh(args, verbosity),
        CommandArgs::Slices(args) => slices::slices(args, verbosity),
        CommandArgs::Render(args) => render::render(args),
        CommandArgs::Info(args) => info::info(args),
        CommandArgs::Cache(args) => cache::cache(args),
    }
}
