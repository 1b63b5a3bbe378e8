//! stablesurf: stable algebraic surfaces from 3D scans.
//!
//! The method is Sahin & Unel, *Stable Algebraic Surfaces for 3D Object Representation*
//! (J Math Imaging Vis 32:127–137, 2008): an implicit polynomial f(x, y, z) = 0 fitted with the
//! 3L method and Euclidean-invariant ridge regression (3LRR).
//!
//! ```text
//! scan file ─import─▶ PointCloud ─normals─▶ OrientedCloud ─fit─▶ ImplicitModel ─polygonize─▶ TriangleMesh ─export─▶ files
//! ```
//!
//! Each stage is a free function from its input artifact and a `…Params` struct to its output
//! artifact; [`pipeline`] chains them through the content-addressed [`cache`].
#![warn(missing_docs)]

pub mod cache;
pub mod cloud;
pub mod detail;
pub mod distance;
pub mod export;
mod files;
pub mod fit;
pub mod implicit;
pub mod import;
pub mod measure;
pub mod merge;
pub mod mesh;
pub mod model;
pub mod normals;
pub mod numerics;
pub mod outliers;
pub mod outputs;
pub mod pipeline;
pub mod poly;
pub mod polygonize;
pub mod render;
pub mod trim;
mod vec3;

pub use cloud::{Aabb, OrientedCloud, PointCloud};
pub use mesh::TriangleMesh;
pub use poly::{ImplicitModel, ImplicitPolynomial};
