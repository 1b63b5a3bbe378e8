//! The `TriangleMesh` artifact (output of `polygonize`, input of `export`) and its topology checks.
//!
//! Invariants: positions and normals have the same length; normals are unit length; every index
//! is `< positions.len()`; triangles are wound counter-clockwise seen from outside (the side
//! where the implicit function is positive).

use serde::{Deserialize, Serialize};

/// A triangle mesh in input coordinates.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TriangleMesh {
    /// Vertex positions in input coordinates and units.
    pub positions: Vec<[f64; 3]>,
    /// Unit-length outward vertex normals, one per position.
    pub normals: Vec<[f64; 3]>,
    /// Triangles as indices into `positions`, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

impl TriangleMesh {
    /// Version of this artifact's layout; bump it whenever a field changes.
    pub const FORMAT_VERSION: u32 = 1;
}
