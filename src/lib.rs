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
//!
//! # The API
//!
//! The crate is public only as far as its consumers need: the command line (`src/cli/`, compiled
//! into the binary), the Python package (`python/`), the developer tools (`tools/*.rs`, behind
//! the `tools` feature), the repository's tests and benchmarks, and a library user who runs the
//! pipeline or one stage. Everything else is `pub(crate)`. The public modules, and who needs
//! each beyond a library user:
//!
//! | module | what it holds | needed by |
//! |--------|---------------|-----------|
//! | [`pipeline`] | `run`, `reconstruct`, `PipelineConfig`, `RunReport` and the stage reports | CLI, Python, tests, benches |
//! | [`cache`] | the artifact store, its usage, verification and size limit; `codec` (entries) | CLI, Python, tools, tests |
//! | [`limits`] | the numeric options' ranges | CLI, Python |
//! | [`import`] | the scan readers, `scan_info`, `.conf` registrations, range grids | CLI, Python, tools, tests |
//! | [`outliers`] | outlier removal (its params are `PipelineConfig::outliers`) | library users |
//! | [`merge`] | the views' poses and their merge | CLI (`normals`, `info`) |
//! | [`normals`] | normal estimation, the noise estimate | CLI, Python, tools, tests |
//! | [`fit`](mod@fit) | the global fit, its κ rules, and the moments of `stablesurf moments` | CLI, Python, tools, tests |
//! | [`detail`] | the detail (MPU) fit and its model | CLI, tools, tests |
//! | [`polygonize`](mod@polygonize) | the adaptive octree mesher | CLI (`mesh`), tools, tests |
//! | [`finish`](mod@finish) | the finish stage; `decimate` (also `stablesurf mesh`) | CLI, tests |
//! | [`trim`](mod@trim) | the trim's params, report and errors | CLI, Python |
//! | [`distance`] | the signed-distance slices; `volume` (vdb/npy) | CLI, tools, tests |
//! | [`export`](mod@export) | the export stage and the writers (glTF, PLY, EXR, PNG, units) | CLI, tools, tests |
//! | [`model`] | the fitted model and its files (`json`, `mpu`) | CLI, tools, tests |
//! | [`outputs`] | a run's output files moved into place as one set | CLI |
//! | [`render`] | the shaded preview | CLI (`render`, `preview.png`), tools |
//! | [`cloud`], [`mesh`], [`poly`], [`implicit`] | the artifacts, mesh checks, the polynomial and the model interface | everyone |
//! | [`measure`], [`point_tree`] | accuracy measures; the nearest-point index | tools, tests |
//!
//! `testing` (hidden from the docs) holds internals for the repository's tests, benchmarks and
//! tools, not API: the Delaunay tetrahedralization and its predicates, the crust, and the
//! fixtures `testing::shapes` (exact polynomials of known topology) and `testing::study` (the
//! synthetic κ study).
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
