//! Checks of the source tree itself: every Rust file under src/, tests/, benches/, tools/ and
//! python/ (the Python package's binding crate) opens with a `//!` header that says what the file is for.

use std::fs;
use std::path::{Path, PathBuf};

/// The folders whose Rust files must carry a header.
const FOLDERS: [&str; 5] = ["src", "tests", "benches", "tools", "python"];

/// Every `.rs` file below `dir`, sorted. Hidden folders and installed third-party trees
/// (`node_modules`, `target`) are not ours and are left out.
fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in fs::read_dir(&d).into_iter().flatten().flatten() {
            let path = entry.path();
            let name = entry.file_name();
            let name = name.to_string_lossy();
            if path.is_dir() {
                if !name.starts_with('.') && name != "node_modules" && name != "target" {
                    stack.push(path);
                }
            } else if name.ends_with(".rs") {
                files.push(path);
            }
        }
    }
    files.sort();
    files
}

/// The Rust files below `root`'s source folders whose first line is not a `//!` comment.
fn missing_headers(root: &Path) -> Vec<PathBuf> {
    FOLDERS
        .iter()
        .flat_map(|folder| rust_files(&root.join(folder)))
        .filter(|path| {
            let text = fs::read_to_string(path).unwrap_or_default();
            !text.starts_with("//!")
        })
        .collect()
}

#[test]
fn every_rust_file_opens_with_a_module_header() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let checked: usize = FOLDERS
        .iter()
        .map(|f| rust_files(&root.join(f)).len())
        .sum();
    assert!(
        checked > 50,
        "only {checked} Rust files found under {root:?}"
    );
    let missing = missing_headers(root);
    assert!(
        missing.is_empty(),
        "these files do not open with a `//!` header saying what they are for:\n{missing:#?}"
    );
}

/// The check itself: a file without a header is found, in any of the folders and at any depth,
/// and a file with one is not.
#[test]
fn the_header_check_finds_a_file_without_one() {
    let root = tempfile::tempdir().unwrap();
    let write = |relative: &str, text: &str| {
        let path = root.path().join(relative);
        fs::create_dir_all(path.parent().unwrap()).unwrap();
        fs::write(path, text).unwrap();
    };
    write("src/lib.rs", "//! The library.\n");
    write(
        "src/stage/mod.rs",
        "/// Not a module header.\npub fn f() {}\n",
    );
    write("tests/all/main.rs", "\n//! Not on the first line.\n");
    write("tools/run.rs", "fn main() {}\n");
    write("tools/node_modules/dep/build.rs", "fn main() {}\n");
    write("docs/example.rs", "fn main() {}\n");
    let missing: Vec<PathBuf> = missing_headers(root.path())
        .into_iter()
        .map(|p| p.strip_prefix(root.path()).unwrap().to_path_buf())
        .collect();
    assert_eq!(
        missing,
        [
            PathBuf::from("src/stage/mod.rs"),
            PathBuf::from("tests/all/main.rs"),
            PathBuf::from("tools/run.rs"),
        ]
    );
}
