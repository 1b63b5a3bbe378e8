//! The symmetric Chamfer distance between a mesh and a point set, the accuracy figure of the
//! detail mode (docs/benchmarks.md compares it with Poisson reconstruction's).
//!
//! The measure lives with the other accuracy measures in [`crate::measure`] (one k-d tree
//! query path for the PLY vertex quality and the Chamfer mesh → points term); this module
//! re-exports it so `crate::detail::chamfer_distance` keeps working.
//!
//! ```
//! use stablesurf::detail::chamfer_distance;
//! use stablesurf::TriangleMesh;
//! let mesh = TriangleMesh {
//!     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
//!     normals: vec![[0.0, 0.0, 1.0]; 3],
//!     triangles: vec![[0, 1, 2]],
//! };
//! let c = chamfer_distance(&[[0.2, 0.2, 0.5]], &mesh).unwrap();
//! assert!((c.points_to_mesh - 0.5).abs() < 1e-12);
//! ```

pub use crate::measure::{chamfer_distance, ChamferDistance};
