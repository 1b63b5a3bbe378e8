//! Signed distance from an implicit polynomial's zero set (for distance slices).
//!
//! (Skeleton: the export helper fills this file.)
