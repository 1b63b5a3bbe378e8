//! Stage `polygonize`: [`ImplicitPolynomial`] + region → [`TriangleMesh`] by an adaptive octree.
//!
//! (Skeleton: the polygonize helper replaces this file; the public signatures below are the
//! contract the CLI and pipeline use.)

use crate::cloud::Aabb;
use crate::mesh::TriangleMesh;
use crate::poly::ImplicitPolynomial;

/// Errors of the polygonize stage.
#[derive(Debug, thiserror::Error)]
pub enum PolygonizeError {
    /// Not built yet.
    #[error("meshing is not built yet")]
    NotBuilt,
}

/// Parameters of the polygonize stage.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PolygonizeParams {
    /// Octree depth near the surface: the finest cell is the region's longest side / 2^depth.
    pub depth: u32,
}

impl Default for PolygonizeParams {
    fn default() -> Self {
        PolygonizeParams { depth: 8 }
    }
}

/// The stage's result.
#[derive(Clone, Debug, Default)]
pub struct Polygonized {
    /// The extracted mesh.
    pub mesh: TriangleMesh,
    /// Number of polynomial evaluations (values and bounds) spent.
    pub evaluations: u64,
}

/// Meshes the zero set of `poly` inside `region`.
///
/// # Errors
/// Invalid region or depth.
pub fn polygonize(
    _poly: &ImplicitPolynomial,
    _region: &Aabb,
    _params: &PolygonizeParams,
) -> Result<Polygonized, PolygonizeError> {
    Err(PolygonizeError::NotBuilt)
}
