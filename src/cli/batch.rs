//! `stablesurf run` as a batch: a folder given as INPUT, or several inputs with `--batch`, each
//! input run on its own through [`run::run_source`], the path of a single run, into a folder of
//! its own under OUT_DIR.
//!
//! Input: the command line's inputs (a folder alone, or files with `--batch`), the run's
//! [`PipelineConfig`] and [`Cache`], shared by every input. Output: `OUT_DIR/<name>/` per input
//! that succeeded, holding exactly what `run INPUT -o OUT_DIR/<name>` writes (report.json's
//! timings aside); `OUT_DIR/summary.csv` and a table on stdout (JSON with `--json`), one row per
//! input; exit status 1 naming every input that failed.
//!
//! Invariants:
//! - A folder's scans are the files directly in it whose extension is one of
//!   [`import::SCAN_EXTENSIONS`], in byte order of their names; nothing recurses.
//! - Output folder names are the file stems; stems shared by several inputs give way to the
//!   file names, and a name still taken (or `summary.csv`) gets `-2`, `-3`, … in input order
//!   ([`folder_names`]). The names depend only on the inputs' paths, never on the disk.
//! - A failed input leaves no folder of its own (the output set removes the folder it made,
//!   see [`stablesurf::outputs`]) and does not stop the inputs after it.

use std::collections::{HashMap, HashSet};
use std::fs;
use std::io::Write;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use serde::Serialize;
use stablesurf::cache::Cache;
use stablesurf::export::{write_atomic, ExportError};
use stablesurf::import;
use stablesurf::pipeline::{PipelineConfig, RunReport, ScanSource};

use super::args::RunArgs;
use super::progress::Verbosity;
use super::{run, usage};

/// The summary file written into OUT_DIR.
pub const SUMMARY_FILE: &str = "summary.csv";

/// The inputs of a batch and their output folders.
#[derive(Debug, PartialEq)]
pub struct Plan {
    /// Each input and the name of its folder under OUT_DIR, in the order they run.
    pub inputs: Vec<(PathBuf, String)>,
    /// The folder the inputs come from, when INPUT was a folder.
    pub folder: Option<PathBuf>,
    /// Entries of that folder that are not scan files (folders end with `/`).
    pub skipped: Vec<String>,
}

/// The batch the command line asks for, or `None` for a single run: a folder (given alone), or
/// any inputs with `--batch`.
///
/// # Errors
/// A usage error for a folder given with other inputs, a folder without a scan file, or
/// `--batch` without inputs; a runtime error when the folder cannot be read.
pub fn plan(inputs: &[PathBuf], batch: bool, output: &Path) -> Result<Option<Plan>> {
    let folders: Vec<&PathBuf> = inputs.iter().filter(|p| p.is_dir()).collect();
    if let Some(folder) = folders.first() {
        if inputs.len() > 1 {
            return Err(usage(format!(
                "{} is a folder: give a folder alone (its scans run one by one), or give scan files (with --batch to run each on its own)",
                folder.display()
            )));
        }
        let (scans, skipped) = list_folder(folder, output)?;
        if scans.is_empty() {
            let also = if skipped.is_empty() {
                "it is empty".to_string()
            } else {
                format!("it holds {}", skipped.join(", "))
            };
            return Err(usage(format!(
                "{} holds no scan file (none named .{}; {also}); give a folder of scans, or the scan files",
                folder.display(),
                import::SCAN_EXTENSIONS.join(" ."),
            )));
        }
        let names = folder_names(&scans);
        return Ok(Some(Plan {
            inputs: scans.into_iter().zip(names).collect(),
            folder: Some(folder.to_path_buf()),
            skipped,
        }));
    }
    if !batch {
        return Ok(None);
    }
    if inputs.is_empty() {
        return Err(usage(
            "--batch runs each input on its own: give the scan files (or a folder) to run",
        ));
    }
    let names = folder_names(inputs);
    Ok(Some(Plan {
        inputs: inputs.iter().cloned().zip(names).collect(),
        folder: None,
        skipped: Vec::new(),
    }))
}

/// The scan files directly in `folder` (by extension, sorted by name) and the names of the
/// other entries, folders with a trailing `/`. The summary of a batch that writes into this
/// same folder is not an input.
fn list_folder(folder: &Path, output: &Path) -> Result<(Vec<PathBuf>, Vec<String>)> {
    let read = || -> std::io::Result<Vec<(std::ffi::OsString, PathBuf)>> {
        let mut entries = Vec::new();
        for entry in fs::read_dir(folder)? {
            let entry = entry?;
            entries.push((entry.file_name(), entry.path()));
        }
        Ok(entries)
    };
    let mut entries = read().with_context(|| {
        format!(
            "cannot list the folder {}; check that it exists and that you may read it",
            folder.display()
        )
    })?;
    entries.sort();
    let writes_here = match (fs::canonicalize(folder), fs::canonicalize(output)) {
        (Ok(folder), Ok(output)) => folder == output,
        _ => false,
    };
    let mut scans = Vec::new();
    let mut skipped = Vec::new();
    for (name, path) in entries {
        let shown = name.to_string_lossy().into_owned();
        if path.is_dir() {
            skipped.push(format!("{shown}/"));
        } else if import::has_scan_extension(&path) && !(writes_here && shown == SUMMARY_FILE) {
            scans.push(path);
        } else {
            skipped.push(shown);
        }
    }
    Ok((scans, skipped))
}

/// The output folder name of each input: its file stem; where several inputs share a stem,
/// their file names; then `-2`, `-3`, … on a name already taken (by an earlier input, or
/// [`SUMMARY_FILE`]), in input order. Deterministic, and never empty, `.` or `..`.
pub fn folder_names(inputs: &[PathBuf]) -> Vec<String> {
    let stem = |p: &PathBuf| {
        p.file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .filter(|s| !s.is_empty() && s != "." && s != "..")
            .unwrap_or_else(|| "input".to_string())
    };
    let mut stem_count: HashMap<String, usize> = HashMap::new();
    for p in inputs {
        *stem_count.entry(stem(p)).or_default() += 1;
    }
    let mut taken: HashSet<String> = HashSet::from([SUMMARY_FILE.to_string()]);
    let mut names = Vec::with_capacity(inputs.len());
    for p in inputs {
        let s = stem(p);
        let base = if stem_count[&s] > 1 {
            p.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or(s)
        } else {
            s
        };
        let mut name = base.clone();
        let mut k = 2;
        while taken.contains(&name) {
            name = format!("{base}-{k}");
            k += 1;
        }
        taken.insert(name.clone());
        names.push(name);
    }
    names
}

/// One input's line in the summary.
#[derive(Debug, Serialize)]
pub struct Row {
    /// The input as given (or its path in the folder).
    pub input: String,
    /// `ok` or `failed`.
    pub status: &'static str,
    /// Points read (all views of a registration file).
    pub points: Option<u64>,
    /// Triangles of the mesh.
    pub triangles: Option<usize>,
    /// The mesh is closed and manifold.
    pub watertight: Option<bool>,
    /// No non-manifold edge or vertex.
    pub manifold: Option<bool>,
    /// Faces that cross another face.
    pub self_intersecting_faces: Option<usize>,
    /// Mean distance data → mesh over the data's bounding-box diagonal.
    pub mean_distance_data_to_mesh: Option<f64>,
    /// Mean distance mesh → data (by area) over the diagonal.
    pub mean_distance_mesh_to_data: Option<f64>,
    /// Wall time of this input.
    pub seconds: f64,
    /// Its output folder (none for a failed input).
    pub output: Option<String>,
    /// Why it failed.
    pub error: Option<String>,
}

impl Row {
    /// The row of a finished run.
    fn done(input: String, report: &RunReport, output: &Path) -> Row {
        let figure = |stage: &str| -> Vec<u64> {
            report
                .stages
                .iter()
                .filter(|s| s.stage == stage)
                .filter_map(|s| s.figures.points().map(|p| p as u64))
                .collect()
        };
        let merged = figure("merge");
        let points = merged
            .first()
            .copied()
            .unwrap_or_else(|| figure("import").iter().sum());
        let mesh = &report.mesh;
        Row {
            input,
            status: "ok",
            points: Some(points),
            triangles: Some(mesh.faces),
            watertight: Some(mesh.watertight),
            manifold: Some(mesh.non_manifold_edges == 0 && mesh.non_manifold_vertices == 0),
            self_intersecting_faces: Some(mesh.self_intersecting_faces),
            mean_distance_data_to_mesh: Some(report.accuracy.data_to_mesh.mean_relative),
            mean_distance_mesh_to_data: Some(report.accuracy.mesh_to_data.mean_relative),
            seconds: report.seconds,
            output: Some(output.display().to_string()),
            error: None,
        }
    }

    /// The row of a failed run.
    fn failed(input: String, seconds: f64, error: String) -> Row {
        Row {
            input,
            status: "failed",
            points: None,
            triangles: None,
            watertight: None,
            manifold: None,
            self_intersecting_faces: None,
            mean_distance_data_to_mesh: None,
            mean_distance_mesh_to_data: None,
            seconds,
            output: None,
            error: Some(error),
        }
    }

    /// The cells of the table and of the CSV, in [`COLUMNS`] order; `exact` writes numbers
    /// in full (CSV), otherwise rounded for reading.
    fn cells(&self, exact: bool) -> Vec<String> {
        fn or_dash<T>(v: Option<T>, f: impl Fn(T) -> String) -> String {
            v.map_or_else(|| "-".to_string(), f)
        }
        let yes_no = |b: bool| if b { "yes" } else { "no" }.to_string();
        let relative = |x: f64| {
            if exact {
                format!("{x:e}")
            } else {
                format!("{x:.2e}")
            }
        };
        vec![
            self.input.clone(),
            self.status.to_string(),
            or_dash(self.points, |n| n.to_string()),
            or_dash(self.triangles, |n| n.to_string()),
            or_dash(self.watertight, yes_no),
            or_dash(self.manifold, yes_no),
            or_dash(self.self_intersecting_faces, |n| n.to_string()),
            or_dash(self.mean_distance_data_to_mesh, relative),
            or_dash(self.mean_distance_mesh_to_data, relative),
            if exact {
                format!("{:.3}", self.seconds)
            } else {
                format!("{:.1}", self.seconds)
            },
            self.output.clone().unwrap_or_else(|| "-".to_string()),
        ]
    }
}

/// The summary's columns: the table's headers, and the CSV's (which adds `error`).
const COLUMNS: [(&str, &str); 11] = [
    ("input", "input"),
    ("status", "status"),
    ("points", "points"),
    ("triangles", "triangles"),
    ("watertight", "watertight"),
    ("manifold", "manifold"),
    ("self_intersecting_faces", "self-int."),
    ("mean_distance_data_to_mesh", "data->mesh"),
    ("mean_distance_mesh_to_data", "mesh->data"),
    ("seconds", "seconds"),
    ("output", "output"),
];

/// The summary as CSV (RFC 4180: a field with a comma, quote or line break is quoted).
pub fn summary_csv(rows: &[Row]) -> String {
    fn field(s: &str) -> String {
        if s.contains([',', '"', '\n', '\r']) {
            format!("\"{}\"", s.replace('"', "\"\""))
        } else {
            s.to_string()
        }
    }
    let mut header: Vec<&str> = COLUMNS.iter().map(|c| c.0).collect();
    header.push("error");
    let mut text = header.join(",") + "\n";
    for row in rows {
        let mut cells = row.cells(true);
        // Empty, not a dash, for a value a failed input does not have.
        for cell in &mut cells {
            if cell == "-" {
                cell.clear();
            }
        }
        cells.push(row.error.clone().unwrap_or_default());
        let line: Vec<String> = cells.iter().map(|c| field(c)).collect();
        text += &line.join(",");
        text += "\n";
    }
    text
}

/// The summary as an aligned text table, one row per input.
pub fn summary_table(rows: &[Row]) -> String {
    let header: Vec<String> = COLUMNS.iter().map(|c| c.1.to_string()).collect();
    let body: Vec<Vec<String>> = rows.iter().map(|r| r.cells(false)).collect();
    let mut widths: Vec<usize> = header.iter().map(|h| h.chars().count()).collect();
    for cells in &body {
        for (w, c) in widths.iter_mut().zip(cells) {
            *w = (*w).max(c.chars().count());
        }
    }
    let line = |cells: &[String]| {
        let padded: Vec<String> = cells
            .iter()
            .zip(&widths)
            .map(|(c, w)| format!("{c:<w$}"))
            .collect();
        padded.join("  ").trim_end().to_string() + "\n"
    };
    let mut text = line(&header);
    for cells in &body {
        text += &line(cells);
    }
    text
}

/// The summary as `--json` prints it.
#[derive(Serialize)]
struct Summary<'a> {
    format: &'static str,
    version: u32,
    /// OUT_DIR.
    output: String,
    inputs: usize,
    failed: usize,
    rows: &'a [Row],
}

/// Runs every input of `plan` into its folder under `args.output`, then writes the summary.
///
/// # Errors
/// The output folder cannot be made or the summary written; or, after every input ran, the
/// inputs that failed, named.
pub fn run_batch(
    args: &RunArgs,
    plan: &Plan,
    config: &PipelineConfig,
    cache: &Cache,
    verbosity: Verbosity,
) -> Result<()> {
    let out = &args.output;
    if out.exists() && !out.is_dir() {
        return Err(anyhow!(
            "the output folder {} is a file; choose another folder with -o",
            out.display()
        ));
    }
    fs::create_dir_all(out).with_context(|| {
        format!(
            "cannot create the output folder {}; choose a folder you can write with -o",
            out.display()
        )
    })?;
    if verbosity != Verbosity::Quiet
        && let (Some(folder), false) = (&plan.folder, plan.skipped.is_empty())
    {
        eprintln!(
                "stablesurf: note: {}: skipped {} (a batch runs the files named .{} directly in the folder; it does not look into subfolders): {}",
                folder.display(),
                if plan.skipped.len() == 1 {
                    "1 entry that is not a scan file".to_string()
                } else {
                    format!("{} entries that are not scan files", plan.skipped.len())
                },
                import::SCAN_EXTENSIONS.join(" ."),
                plan.skipped.join(", ")
            );
    }
    let n = plan.inputs.len();
    let mut rows = Vec::with_capacity(n);
    for (i, (input, name)) in plan.inputs.iter().enumerate() {
        if verbosity != Verbosity::Quiet {
            eprintln!("stablesurf: input {} of {n}: {}", i + 1, input.display());
        }
        let dir = out.join(name);
        let source = ScanSource::from_inputs(std::slice::from_ref(input));
        let start = Instant::now();
        let result = catch_unwind(AssertUnwindSafe(|| {
            run::run_source(args, &source, &dir, config, cache, verbosity)
        }));
        let shown = input.display().to_string();
        let row = match result {
            Ok(Ok(report)) => Row::done(shown, &report, &dir),
            Ok(Err(err)) => {
                let message = format!("{err:#}");
                eprintln!(
                    "stablesurf: error: {message}; {} has no output folder, the other inputs go on",
                    input.display()
                );
                Row::failed(shown, start.elapsed().as_secs_f64(), message)
            }
            Err(panic) => {
                let what = panic
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                let message =
                    format!("internal error (a bug; please report it with the input): {what}");
                eprintln!(
                    "stablesurf: error: {}: {message}; the other inputs go on",
                    input.display()
                );
                Row::failed(shown, start.elapsed().as_secs_f64(), message)
            }
        };
        rows.push(row);
    }
    let summary_path = out.join(SUMMARY_FILE);
    let csv = summary_csv(&rows);
    write_atomic(&summary_path, |w| {
        w.write_all(csv.as_bytes())
            .map_err(|e| ExportError::Format(format!("writing the summary: {e}")))
    })
    .with_context(|| format!("writing the batch summary {}", summary_path.display()))?;
    let failed: Vec<&Row> = rows.iter().filter(|r| r.status != "ok").collect();
    if args.json {
        super::config::print_json(&Summary {
            format: "stablesurf.batch-summary",
            version: 1,
            output: out.display().to_string(),
            inputs: n,
            failed: failed.len(),
            rows: &rows,
        })?;
    } else {
        let mut stdout = std::io::stdout().lock();
        stdout.write_all(summary_table(&rows).as_bytes())?;
        stdout.flush()?;
    }
    if !failed.is_empty() {
        let names: Vec<&str> = failed.iter().map(|r| r.input.as_str()).collect();
        return Err(anyhow!(
            "{} of {n} inputs failed: {}; the errors are above and in {}, the other inputs' outputs are in {}",
            failed.len(),
            names.join(", "),
            summary_path.display(),
            out.display()
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paths(list: &[&str]) -> Vec<PathBuf> {
        list.iter().map(PathBuf::from).collect()
    }

    #[test]
    fn folder_names_are_stems_then_file_names_then_numbered() {
        assert_eq!(folder_names(&paths(&["d/a.ply", "d/b.obj"])), ["a", "b"]);
        // Shared stems give way to the file names.
        assert_eq!(
            folder_names(&paths(&["d/a.ply", "d/a.obj", "d/b.obj"])),
            ["a.ply", "a.obj", "b"]
        );
        // The same file name from two folders, and a stem equal to a file name taken before.
        assert_eq!(
            folder_names(&paths(&[
                "x/a.ply",
                "y/a.ply",
                "a.ply.xyz",
                "summary.csv.ply"
            ])),
            ["a.ply", "a.ply-2", "a.ply-3", "summary.csv-2"]
        );
        // No stem: a fixed name.
        assert_eq!(folder_names(&paths(&["..", "/"])), ["input", "input-2"]);
    }

    #[test]
    fn csv_quotes_what_needs_it_and_leaves_missing_values_empty() {
        let rows = [Row::failed(
            "d/b,\"x\".ply".into(),
            0.5,
            "import failed: line 3".into(),
        )];
        let csv = summary_csv(&rows);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], "input,status,points,triangles,watertight,manifold,self_intersecting_faces,mean_distance_data_to_mesh,mean_distance_mesh_to_data,seconds,output,error");
        assert_eq!(
            lines[1],
            "\"d/b,\"\"x\"\".ply\",failed,,,,,,,,0.500,,import failed: line 3"
        );
        let table = summary_table(&rows);
        assert!(table.starts_with("input"), "{table}");
        assert!(
            table.lines().nth(1).unwrap().contains("failed  -"),
            "{table}"
        );
    }
}
