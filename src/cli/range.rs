//! The numeric flags' ranges: the library's [`stablesurf::limits`], which the Python package
//! checks its keyword arguments against too.

pub use stablesurf::limits::*;
