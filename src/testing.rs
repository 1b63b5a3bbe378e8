//! Internals re-exported for the integration tests, benchmarks and tools of this repository, not
//! part of the library's API: they may change in any release.
//!
//! Input: nothing of its own. Output: the normals stage's Delaunay tetrahedralization (its exact
//! predicates and the artifact's conventions, which the tests check), and the crust and its
//! normals alone (which the benchmarks time phase by phase).

pub use crate::normals::crust::{crust, crust_normals, Crust, CrustNormals};
pub use crate::normals::delaunay::{
    face_vertices, tetrahedralize, Tetrahedralization, NO_NEIGHBOUR,
};
pub use crate::numerics::predicates::{insphere, orient3d};
