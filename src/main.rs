//! The `stablesurf` binary: parse the command line, run it ([`cli::run`]), map errors to exit
//! codes.
//!
//! Exit codes: 0 success (also when stdout is a closed pipe), 1 runtime error (bad input, failed
//! fit, unwritable output), 2 usage error (clap's, and [`cli::UsageError`]). stdout carries only
//! machine-readable output (`--json`) and a batch run's result table; everything else goes to
//! stderr.

use std::process::ExitCode;

use clap::Parser;

mod cli;

fn main() -> ExitCode {
    cli::allocator::keep_freed_memory();
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(()) => ExitCode::SUCCESS,
        // `stablesurf info --json f | head -c 1`: the reader has what it asked for.
        Err(err) if is_broken_pipe(&err) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("stablesurf: error: {err:#}");
            if err.downcast_ref::<cli::UsageError>().is_some() {
                ExitCode::from(2)
            } else {
                ExitCode::from(1)
            }
        }
    }
}

/// Whether any error in the chain is a write to a closed pipe.
fn is_broken_pipe(err: &anyhow::Error) -> bool {
    err.chain().any(|e| {
        e.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}
