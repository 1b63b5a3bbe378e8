//! The integration tests, linked into one test binary (`cargo test --test all`).
//!
//! One module per area of the product, plus `fixtures` (the real binary, generated scans, the
//! shared scans of ../shared) that several of them use and `tidy` (checks of the source tree
//! itself). One binary links the library once instead of once per file, which is most of the time
//! and disk `cargo test` spends. Run one area with its module path as the filter, e.g.
//! `cargo test --test all golden::` or `cargo test --test all cli::`.

mod fixtures;

mod batch;
mod blender;
mod cli;
mod decimate;
mod detail;
mod export;
mod fit;
mod fuzz_readers;
mod golden;
mod import;
mod load;
mod noise;
mod normals;
mod polygonize;
mod reliability;
mod tidy;
mod volume;
