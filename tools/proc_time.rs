//! CPU time of the current process, for the benches and tools that print CPU seconds beside
//! wall time (included with `#[path]`; not part of the library).

/// User + system CPU seconds of this process so far, all threads (from /proc/self/stat, 100 Hz
/// ticks); 0 where /proc is not available.
pub fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // After the command name in parentheses: state is field 0, utime field 11, stime field 12.
    let fields: Vec<&str> = stat
        .rsplit(')')
        .next()
        .unwrap_or("")
        .split_whitespace()
        .collect();
    let ticks = |i: usize| {
        fields
            .get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    (ticks(11) + ticks(12)) / 100.0
}
