//! Stage `normals`: [`PointCloud`] → [`OrientedCloud`] (unit outward normals).
//!
//! (Skeleton: the normals helper replaces this file; the public signatures below are the
//! contract the CLI and pipeline use.)

use crate::cloud::{OrientedCloud, PointCloud};

/// Errors of the normals stage.
#[derive(Debug, thiserror::Error)]
pub enum NormalsError {
    /// Not built yet.
    #[error("normal estimation is not built yet")]
    NotBuilt,
}

/// Where the normals come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum NormalSource {
    /// `input` when the file has normals, else `mesh` when it has faces, else `crust`
    /// (falling back to `pca` with a warning where the crust fails).
    #[default]
    Auto,
    /// Crust (Voronoi/Delaunay) triangulation, paper section 5.
    Crust,
    /// k-nearest-neighbour plane fits.
    Pca,
    /// The input mesh's own faces.
    Mesh,
    /// The file's normals.
    Input,
}

/// Parameters of the normals stage.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NormalsParams {
    /// Where the normals come from.
    pub source: NormalSource,
}

/// The stage's result: the oriented cloud plus what was done.
#[derive(Clone, Debug, Default)]
pub struct Normals {
    /// Points with unit outward normals.
    pub cloud: OrientedCloud,
    /// The source actually used (never `Auto`).
    pub source_used: NormalSource,
    /// The crust triangulation when the crust was used (indices into the points).
    pub crust_triangles: Vec<[u32; 3]>,
    /// Messages for the user (for example a fallback from crust to pca).
    pub warnings: Vec<String>,
}

/// Estimates unit outward normals.
///
/// # Errors
/// Too few or degenerate points.
pub fn estimate_normals(_cloud: &PointCloud, _params: &NormalsParams) -> Result<Normals, NormalsError> {
    Err(NormalsError::NotBuilt)
}
