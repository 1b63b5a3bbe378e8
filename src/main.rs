//! The stablesurf binary.
fn main() {}
