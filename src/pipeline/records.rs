//! The stages' reports: one plain struct per stage, stored inside the stage's checksummed cache
//! entry and read back typed, so the run's report is assembled from fields, never from keys.
//!
//! Input: a stage's output. Output: its figures, as the `-v` line and report.json's `stages`
//! print them (a JSON object, keys in sorted order).

use serde::{Deserialize, Serialize};

use crate::export::ExportReport;

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
    /// `export`.
    Export(Box<ExportReport>),
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
    ExportReport => Export,
    WriteReport => Write
);

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
