//! stablesurf: stable algebraic surfaces from 3D scans.
//!
//! The method is Sahin & Unel, *Stable Algebraic Surfaces for 3D Object Representation*
//! (J Math Imaging Vis 32:127–137, 2008): an implicit polynomial f(x, y, z) = 0 fitted with the
//! 3L method and Euclidean-invariant ridge regression (3LRR).
//!
//! ```text
//! scan file ─import─▶ PointCloud ─normals─▶ OrientedCloud ─fit─▶ ImplicitModel ─polygonize─▶ TriangleMesh ─finish─▶ Finished ─export─▶ files
//! ```
//!
//! Each stage is a free function from its input artifact and a `…Params` struct to its output
//! artifact; [`pipeline`] chains them through the content-addressed [`cache`]. The stage
//! functions, their params, artifacts and errors are re-exported here; the modules hold the
//! rest (formats, diagnostics, lower-level entry points).
#![warn(missing_docs)]

pub mod cache;
pub mod cloud;
pub mod detail;
pub mod distance;
pub mod export;
mod files;
pub mod finish;
pub mod fit;
mod frame;
pub mod implicit;
pub mod import;
pub mod limits;
pub mod measure;
pub use numerics::point_tree;
pub mod merge;
pub mod mesh;
pub mod model;
pub mod normals;
pub(crate) mod numerics;
pub mod outliers;
pub mod outputs;
pub mod pipeline;
pub mod poly;
pub mod polygonize;
pub mod render;
#[doc(hidden)]
pub mod testing;
pub mod trim;
mod vec3;

// The artifacts passed between the stages.
pub use cloud::{Aabb, OrientedCloud, PointCloud};
pub use detail::MpuModel;
pub use frame::UpAxis;
pub use implicit::ImplicitFunction;
pub use import::Scan;
pub use mesh::TriangleMesh;
pub use model::{Mode, Model};
pub use poly::{ImplicitModel, ImplicitPolynomial};

// The stages (see the table in docs/ARCHITECTURE.md for their order), each with its params
// and its error.
pub use detail::{fit_detail, DetailError, DetailParams};
pub use distance::{slices, DistanceError, Slice, SliceParams};
pub use export::{export, ExportError, ExportParams};
pub use finish::{finish, FinishError, FinishParams, Finished};
pub use fit::{fit, FitError, FitParams};
pub use import::{import_scan_bytes, read_scan, ImportError};
pub use merge::{merge_views, Pose};
pub use normals::{estimate_noise, estimate_normals, NoiseEstimate, NormalsError, NormalsParams};
pub use outliers::{remove_outliers, OutlierParams};
pub use polygonize::{polygonize, PolygonizeError, PolygonizeParams};
pub use trim::{trim, TrimError, TrimParams};

// The whole run, through the cache.
pub use cache::{Cache, CacheError};
pub use pipeline::{run, PipelineConfig, PipelineError, RunReport};
