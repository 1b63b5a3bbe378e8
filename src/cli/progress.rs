//! What the commands print on stderr while they work: the [`Verbosity`] of `-q`/`-v`, and the
//! pipeline [`Observer`] that shows a spinner per stage on a terminal and one line per stage
//! with `-v`.

use std::io::IsTerminal;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use stablesurf::pipeline::{Observer, StageRecord};

/// How much goes to stderr: `-q`, the default, or `-v`.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Verbosity {
    /// Errors only.
    Quiet,
    /// Summaries, warnings and notes.
    Normal,
    /// Also one line per stage.
    Verbose,
}

/// Progress on stderr: a spinner per stage on a terminal, one line per stage with `-v`.
pub struct StderrObserver {
    verbosity: Verbosity,
    bar: Option<ProgressBar>,
}

impl StderrObserver {
    /// An observer printing at `verbosity`.
    pub fn new(verbosity: Verbosity) -> Self {
        StderrObserver {
            verbosity,
            bar: None,
        }
    }
}

impl Observer for StderrObserver {
    fn stage_started(&mut self, stage: &'static str) {
        let on_terminal =
            std::io::stderr().is_terminal() && std::env::var_os("TERM").is_none_or(|t| t != "dumb");
        if self.verbosity != Verbosity::Quiet && on_terminal {
            let bar = ProgressBar::new_spinner();
            if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} {elapsed}") {
                bar.set_style(style);
            }
            bar.set_message(stage);
            bar.enable_steady_tick(Duration::from_millis(100));
            self.bar = Some(bar);
        }
    }

    fn stage_finished(&mut self, record: &StageRecord) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
        if self.verbosity == Verbosity::Verbose {
            eprintln!(
                "stablesurf: {:<10} {:<7} {:>8.3}s  {}",
                record.stage, record.cache, record.seconds, record.figures
            );
        }
    }

    fn warning(&mut self, message: &str) {
        if self.verbosity != Verbosity::Quiet {
            eprintln!("stablesurf: warning: {message}");
        }
    }

    fn note(&mut self, message: &str) {
        if self.verbosity != Verbosity::Quiet {
            eprintln!("stablesurf: note: {message}");
        }
    }
}
