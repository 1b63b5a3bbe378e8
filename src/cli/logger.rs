//! The binary's logger: the library's `log` records (for example the κ rule's checks with their
//! wall times) printed on stderr when `-v` is repeated: `-vv` shows `debug` records and `-vvv`
//! `trace` records too. Without repeated `-v` no logger is installed and the library's log
//! macros cost one level comparison.

/// Prints each record on stderr as `stablesurf: LEVEL: TARGET: MESSAGE`.
struct StderrLogger;

impl log::Log for StderrLogger {
    fn enabled(&self, metadata: &log::Metadata<'_>) -> bool {
        metadata.level() <= log::max_level()
    }

    fn log(&self, record: &log::Record<'_>) {
        if self.enabled(record.metadata()) {
            eprintln!(
                "stablesurf: {}: {}: {}",
                record.level().as_str().to_lowercase(),
                record.target(),
                record.args()
            );
        }
    }

    fn flush(&self) {}
}

/// Installs the stderr logger for `verbose` repetitions of `-v` (none below 2).
pub(crate) fn install(verbose: u8) {
    let level = match verbose {
        0 | 1 => return,
        2 => log::LevelFilter::Debug,
        _ => log::LevelFilter::Trace,
    };
    // A logger is installed at most once per process; a second call changes nothing.
    if log::set_logger(&StderrLogger).is_ok() {
        log::set_max_level(level);
    }
}
