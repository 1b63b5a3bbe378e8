//! The stages' reports and the run's: one plain struct per stage, stored inside the stage's
//! checksummed cache entry and read back typed, and the [`RunReport`] assembled from their
//! fields, never from keys.
//!
//! Input: a stage's output. Output: its figures, as the `-v` line and report.json's `stages`
//! print them (a JSON object, keys in sorted order), and report.json itself.

use serde::{Deserialize, Serialize};

use crate::export::ExportReport;
use crate::finish::decimate::DecimateReport;
use crate::finish::{self, FinishReport};
use crate::measure::Accuracy;
use crate::mesh::MeshReport;
use crate::model::{Mode, Model, ModelReport};
use crate::normals::NoiseEstimate;
use crate::trim::TrimReport;

use super::{Ctx, ResolvedConfig};

/// The import stage's figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ImportReport {
    /// Points read.
    pub points: usize,
    /// Faces read.
    pub triangles: usize,
    /// Whether the file gave normals.
    pub has_normals: bool,
    /// What the reader did not read (extra columns, other elements); none for an in-memory
    /// cloud.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub notices: Option<Vec<String>>,
}

/// The merge stage's figures (several views into one cloud).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MergeReport {
    /// Views merged.
    pub views: usize,
    /// Points of the merged cloud.
    pub points: usize,
    /// Whether the points carry confidences.
    pub weighted: bool,
}

/// The normals stage's figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NormalsReport {
    /// The source used (`crust`, `pca`, …).
    pub source: String,
    /// Points added on large faces.
    pub surface_samples: usize,
    /// What the user should know (the run tells them on a hit as on a miss).
    pub warnings: Vec<String>,
}

/// The global fit's figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FitReport {
    /// The polynomial's degree.
    pub degree: u32,
    /// The ridge weight used, when the fit has one.
    pub kappa: Option<f64>,
    /// Whether the zero set was certified bounded, when checked.
    pub bounded: Option<bool>,
}

/// The detail fit's figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DetailReport {
    /// Octree cells.
    pub cells: usize,
    /// Cells whose support grew to hold enough points.
    pub grown_cells: usize,
    /// Cells fitted with a cubic.
    pub cubic_cells: usize,
    /// The deepest level reached.
    pub depth_reached: u32,
    /// Mean residual of the fit at the points, over the diagonal.
    pub mean_residual: f64,
    /// Largest residual, over the diagonal.
    pub max_residual: f64,
}

/// The polygonize stage's figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PolygonizeReport {
    /// The depth meshed.
    pub depth: u32,
    /// Whether the facets were fitted to the points.
    pub fit_chords: bool,
    /// The chords' share of their least-squares move, when fitted.
    pub chord_share: Option<f64>,
    /// Mesh vertices.
    pub vertices: usize,
    /// Mesh triangles.
    pub triangles: usize,
    /// Evaluations of the implicit.
    pub evaluations: u64,
    /// Whether the mesh was simplified where flat.
    pub simplified: bool,
    /// Vertices pinned by the repairs.
    pub pinned_vertices: usize,
    /// The sagitta of the edge split, when on.
    pub refine: Option<f64>,
    /// Vertices the edge split added.
    pub refined_vertices: usize,
    /// Whether the meshing proved that no triangle crosses another.
    pub embedded: bool,
}

/// The write step's figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct WriteReport {
    /// Files written.
    pub files: usize,
}

/// What a cache entry says beside its artifact: what went into its key, the time the stage
/// took, and the stage's report.
#[derive(Serialize, Deserialize)]
pub(crate) struct EntryMeta<R> {
    pub stage: String,
    pub stage_version: u32,
    pub cache_format_version: u32,
    /// The canonical params, as JSON.
    pub params: serde_json::Value,
    /// The input artifact's key, hex.
    pub input_key: String,
    pub seconds: f64,
    pub figures: R,
}

/// One stage's figures, whichever stage.
#[derive(Clone, Debug, PartialEq)]
pub enum StageFigures {
    /// `import`.
    Import(ImportReport),
    /// `merge`.
    Merge(MergeReport),
    /// `normals`.
    Normals(NormalsReport),
    /// `fit`.
    Fit(FitReport),
    /// `detail`.
    Detail(DetailReport),
    /// `polygonize`.
    Polygonize(PolygonizeReport),
    /// `finish`.
    Finish(Box<FinishReport>),
    /// `export`.
    Export(ExportReport),
    /// `write`.
    Write(WriteReport),
}

impl StageFigures {
    /// The figures as a JSON object with sorted keys, nested objects too (the form of the
    /// `-v` line and of report.json's `stages`).
    pub fn to_json(&self) -> serde_json::Value {
        let value = match self {
            StageFigures::Import(r) => serde_json::to_value(r),
            StageFigures::Merge(r) => serde_json::to_value(r),
            StageFigures::Normals(r) => serde_json::to_value(r),
            StageFigures::Fit(r) => serde_json::to_value(r),
            StageFigures::Detail(r) => serde_json::to_value(r),
            StageFigures::Polygonize(r) => serde_json::to_value(r),
            StageFigures::Finish(r) => serde_json::to_value(r),
            StageFigures::Export(r) => serde_json::to_value(r),
            StageFigures::Write(r) => serde_json::to_value(r),
        };
        value.expect("stage figures serialize")
    }

    /// Points of the cloud, for the stages that read or make one (import, merge).
    pub fn points(&self) -> Option<usize> {
        match self {
            StageFigures::Import(r) => Some(r.points),
            StageFigures::Merge(r) => Some(r.points),
            _ => None,
        }
    }
}

impl Serialize for StageFigures {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.to_json().serialize(serializer)
    }
}

impl std::fmt::Display for StageFigures {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.to_json())
    }
}

/// A stage's report type and its place in [`StageFigures`].
pub(crate) trait StageReport:
    Serialize + serde::de::DeserializeOwned + Clone + Into<StageFigures>
{
}

impl<T> StageReport for T where
    T: Serialize + serde::de::DeserializeOwned + Clone + Into<StageFigures>
{
}

macro_rules! into_figures {
    ($($report:ty => $variant:ident),+) => {
        $(impl From<$report> for StageFigures {
            fn from(r: $report) -> StageFigures {
                StageFigures::$variant(r.into())
            }
        })+
    };
}

into_figures!(
    ImportReport => Import,
    MergeReport => Merge,
    NormalsReport => Normals,
    FitReport => Fit,
    DetailReport => Detail,
    PolygonizeReport => Polygonize,
    FinishReport => Finish,
    ExportReport => Export,
    WriteReport => Write
);

/// One stage's line in the report.
#[derive(Clone, Debug, Serialize)]
pub struct StageRecord {
    /// Stage name.
    pub stage: &'static str,
    /// "hit", "miss" or "corrupt" (recomputed), or "none" for uncached stages.
    pub cache: &'static str,
    /// Wall time in seconds.
    pub seconds: f64,
    /// Cache key (hex), when cached.
    pub key: Option<String>,
    /// Key figures of the stage's output.
    pub figures: StageFigures,
}

/// What the run produced and measured (written as `report.json`).
#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    /// The scan (file path or sample name).
    pub input: String,
    /// One record per stage, in order.
    pub stages: Vec<StageRecord>,
    /// The fitted model's settings and diagnostics.
    pub fit: ModelReport,
    /// What the trim stage removed and closed.
    pub trim: TrimReport,
    /// What the decimation did (`--target-triangles`): the budget, triangles before and after,
    /// and whether the budget was reached.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub decimate: Option<DecimateReport>,
    /// Mesh topology checks.
    pub mesh: MeshReport,
    /// Two-sided distances between the input points and the mesh, absolute and relative to the
    /// data's diagonal: data → mesh, mesh → data by area, and the share of the mesh's area far
    /// from every data point.
    pub accuracy: Accuracy,
    /// The unit of the input coordinates when `--units` named one (distances in this report
    /// are in input units).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub units: Option<crate::export::units::LengthUnit>,
    /// Files written, relative to the output directory.
    pub outputs: Vec<String>,
    /// Every warning the run printed.
    pub warnings: Vec<String>,
    /// The measured noise of the points and the noise the fit averaged (absent when it could
    /// not be measured: fewer than 25 points).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise: Option<NoiseReport>,
    /// Total wall time in seconds.
    pub seconds: f64,
}

/// The noise of a run's points as the report gives it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct NoiseReport {
    /// The median estimate of the points' standard deviation across their surface, input units.
    pub sigma: f64,
    /// `sigma` over the diagonal of the points' bounding box.
    pub sigma_per_diagonal: f64,
    /// The 10% and 90% quantiles of the local estimates (cleaner and noisier regions), input
    /// units.
    pub sigma_low: f64,
    /// See `sigma_low`.
    pub sigma_high: f64,
    /// `sigma` over the median spacing of the points.
    pub sigma_per_spacing: f64,
    /// The noise the detail fit averaged, over the diagonal ([`crate::detail::DetailParams::noise`]; 0 in
    /// global mode, with `--smooth 0`, or where the noise is below `super::NOISE_FLOOR` × the
    /// tolerance).
    pub smoothed_per_diagonal: f64,
}

impl NoiseReport {
    pub(super) fn new(
        noise: NoiseEstimate,
        points: &[[f64; 3]],
        resolved: &ResolvedConfig,
    ) -> NoiseReport {
        let diagonal = crate::cloud::Aabb::from_points(points).map_or(0.0, |b| b.diagonal());
        NoiseReport {
            sigma: noise.sigma,
            sigma_per_diagonal: if diagonal > 0.0 {
                noise.sigma / diagonal
            } else {
                0.0
            },
            sigma_low: noise.sigma_low,
            sigma_high: noise.sigma_high,
            sigma_per_spacing: noise.relative_to_spacing(),
            smoothed_per_diagonal: match resolved.mode {
                Mode::Detail => resolved.detail.noise,
                Mode::Global => 0.0,
            },
        }
    }
}

/// The figures of the mesh as written, from the finish stage's record.
pub(super) struct MeshFigures {
    mesh: MeshReport,
    accuracy: Accuracy,
    trim: TrimReport,
    decimate: Option<DecimateReport>,
    /// A polynomial's zero set runs out of the meshing box.
    clipped: bool,
}

/// The finish stage's figures, with the warnings they call for: pieces of the surface left
/// out, a polynomial's zero set clipped by the meshing box.
pub(super) fn mesh_figures(ctx: &mut Ctx<'_>, model: &Model, report: FinishReport) -> MeshFigures {
    let FinishReport {
        mesh,
        accuracy,
        trim,
        decimate,
        dropped_components: dropped,
        dropped_nested: nested,
        dropped_unsupported: unsupported,
    } = report;
    if let Some(message) = decimate.as_ref().and_then(DecimateReport::shortfall) {
        ctx.warn(message);
    }
    if dropped > 0 {
        ctx.warn(format!(
            "left out {dropped} piece(s) of the surface with no data point within 2% of the diagonal; --keep all keeps them"
        ));
    }
    if nested > 0 {
        ctx.warn(format!(
            "left out {nested} small closed piece(s) inside the surface (each under {}% of the largest piece's area); --keep all keeps them",
            100.0 * finish::NESTED_AREA_FRACTION
        ));
    }
    if unsupported > 0 {
        ctx.warn(format!(
            "left out {unsupported} small piece(s) of the surface with fewer than {} data points in their box (each under {}% of the largest piece's area); --keep all keeps them",
            finish::SUPPORT_POINTS_MIN,
            100.0 * finish::NESTED_AREA_FRACTION
        ));
    }
    // A polynomial's zero set that runs out of the meshing box is open there: not a bounded
    // surface in this mesh, whatever the fit certified.
    let clipped = matches!(model, Model::Global(_)) && mesh.boundary_edges > 0;
    if clipped {
        ctx.warn(format!(
            "the zero set is clipped by the meshing box: the mesh is open along {} boundary edges, so it is not a bounded surface here; try another --degree or --kappa, or --mode detail",
            mesh.boundary_edges
        ));
    }
    MeshFigures {
        mesh,
        accuracy,
        trim,
        decimate,
        clipped,
    }
}

/// The run's report (its `seconds` still 0): the stages and warnings of `ctx`, the model's
/// settings and diagnostics, the figures of the mesh as written, and the files.
pub(super) fn run_report(
    input: String,
    ctx: Ctx<'_>,
    model: &Model,
    config: &ResolvedConfig,
    figures: MeshFigures,
    outputs: Vec<String>,
) -> RunReport {
    let mut fit = model.report();
    if let ModelReport::Detail { params, .. } = &mut fit {
        *params = Some(config.detail.clone());
    }
    if figures.clipped {
        fit.clip();
    }
    RunReport {
        input,
        stages: ctx.stages,
        fit,
        trim: figures.trim,
        decimate: figures.decimate,
        mesh: figures.mesh,
        accuracy: figures.accuracy,
        units: config.export.units,
        outputs,
        warnings: ctx.warnings,
        noise: ctx.noise,
        seconds: 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_print_as_sorted_json_and_read_back_typed() {
        let import = ImportReport {
            points: 3,
            triangles: 1,
            has_normals: true,
            notices: Some(vec!["extra column".into()]),
        };
        let figures = StageFigures::from(import.clone());
        assert_eq!(
            figures.to_string(),
            r#"{"has_normals":true,"notices":["extra column"],"points":3,"triangles":1}"#
        );
        let back: ImportReport = serde_json::from_value(figures.to_json()).unwrap();
        assert_eq!(back, import);
        // An in-memory cloud's import has no notices, and prints none.
        let memory = ImportReport {
            notices: None,
            ..import
        };
        assert!(!StageFigures::from(memory).to_string().contains("notices"));
        assert_eq!(figures.points(), Some(3));
    }
}
