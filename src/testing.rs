//! Internals for the repository's tests, benchmarks and tools, not API: they may change in any
//! release, and the crate's documentation hides them.
//!
//! Input: nothing of its own. Output: the normals stage's Delaunay tetrahedralization (its exact
//! predicates and the artifact's conventions, which the tests check), the crust and its normals
//! alone (which the benchmarks time phase by phase), and two fixtures: [`shapes`], exact implicit
//! polynomials of known topology (the polygonize tests and benchmarks), and [`study`], the
//! synthetic κ study's shapes, sampling and judge (`tools/kappa_study.rs`, the paper experiments,
//! the fit and detail tests).

pub mod shapes;
pub mod study;

pub use crate::normals::crust::{crust, crust_normals, Crust, CrustNormals};
pub use crate::normals::delaunay::{
    face_vertices, tetrahedralize, Tetrahedralization, NO_NEIGHBOUR,
};
pub use crate::numerics::predicates::{insphere, orient3d};
