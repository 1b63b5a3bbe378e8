//! Shared numerical kernels that several stages use: a union-find over indices, a dense
//! Cholesky factorization with its triangular solves, grid indices for exact k-nearest
//! neighbour and nearest-distance queries, exact orientation and insphere predicates, a stable
//! radix sort of keyed pairs, and a deterministic pseudo-random generator for synthetic data and
//! tests.
//!
//! This module belongs to no stage; stages import these kernels from here instead of keeping
//! copies of their own. Each kernel is sequential and performs its floating-point operations in
//! a fixed order, so its results do not depend on the caller or the thread count.

pub(crate) mod cholesky;
mod lcg;
pub(crate) mod point_grid;
pub mod point_tree;
pub(crate) mod predicates;
mod radix;
pub(crate) mod union_find;

pub use lcg::Lcg;
pub(crate) use point_grid::{Neighbours, PointGrid};
pub(crate) use radix::sort_pairs_by_key;
pub(crate) use union_find::UnionFind;
