//! Fixtures shared by the test modules: the real binary and what a run leaves behind, generated
//! scans (sphere points as XYZ text, binary STL), a seeded generator, rotations from quaternions,
//! and the scans and reference cases of ../shared.
//!
//! Everything a fixture writes goes into the folder the test passes in, a temporary one.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Output;

use assert_cmd::Command;

/// The ../shared folder next to the repository: real scans (`data/`) and reference cases
/// (`cases/`), too large to live in the repository.
const SHARED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared");

/// `../shared/<relative>` if it exists. When it is absent a test that needs it is skipped with a
/// notice on stderr, except under CI (the `CI` variable set), where it fails: a CI run must not
/// pass by skipping. `what` names the check for either message.
pub fn shared(relative: &str, what: &str) -> Option<PathBuf> {
    shared_in(
        Path::new(SHARED),
        relative,
        what,
        std::env::var_os("CI").is_some(),
    )
}

/// [`shared`] with the folder and whether this is CI given.
fn shared_in(root: &Path, relative: &str, what: &str, ci: bool) -> Option<PathBuf> {
    let path = root.join(relative);
    if path.exists() {
        return Some(path);
    }
    assert!(
        !ci,
        "{} is absent and CI is set: {what} needs it",
        path.display()
    );
    eprintln!("notice: {} is absent; skipping {what}", path.display());
    None
}

#[test]
fn absent_shared_data_skips_but_fails_under_ci() {
    let root = tempfile::tempdir().unwrap();
    std::fs::create_dir(root.path().join("data")).unwrap();
    let found = shared_in(root.path(), "data", "the check", true);
    assert_eq!(found, Some(root.path().join("data")));
    assert_eq!(shared_in(root.path(), "cases", "the check", false), None);
    let under_ci = std::panic::catch_unwind(|| shared_in(root.path(), "cases", "the check", true));
    let message = under_ci.expect_err("an absent folder under CI is a failure");
    let message = message.downcast_ref::<String>().unwrap();
    assert!(
        message.contains("is absent and CI is set: the check needs it"),
        "{message}"
    );
}

/// The `stablesurf` binary, without the environment that would change where it caches or make
/// it fail on purpose.
pub fn bin() -> Command {
    let mut cmd = Command::cargo_bin("stablesurf").expect("binary built");
    cmd.env_remove("XDG_CACHE_HOME")
        .env_remove("STABLESURF_FAULT")
        .env_remove("STABLESURF_CACHE_MAX_SIZE");
    cmd
}

/// A finished process's stderr as text.
pub fn stderr_of(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// `stablesurf run INPUT -o OUT` with `flags`; asserts that it succeeded and returns its output.
pub fn run_ok(input: &Path, out: &Path, flags: &[&str]) -> Output {
    let done = bin()
        .arg("run")
        .arg(input)
        .arg("-o")
        .arg(out)
        .args(flags)
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", stderr_of(&done));
    done
}

/// Command-line flags written as one line, split at whitespace.
pub fn flags(line: &str) -> Vec<&str> {
    line.split_whitespace().collect()
}

/// The `report.json` a run wrote into its output folder `out`.
pub fn read_report(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&fs::read(out.join("report.json")).unwrap()).unwrap()
}

/// Writes `dir/sphere.xyz`: `n` points of a sphere (centre (1, 2, 3), radius 2, a Fibonacci
/// spiral) with exact outward normals, then the lines `extra`.
pub fn sphere_xyz(dir: &Path, n: usize, extra: &str) -> PathBuf {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut text = String::from("# sphere, radius 2, centre (1, 2, 3)\n");
    for i in 0..n {
        let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let t = golden * i as f64;
        let nrm = [r * t.cos(), r * t.sin(), z];
        text += &format!(
            "{} {} {} {} {} {}\n",
            1.0 + 2.0 * nrm[0],
            2.0 + 2.0 * nrm[1],
            3.0 + 2.0 * nrm[2],
            nrm[0],
            nrm[1],
            nrm[2]
        );
    }
    text += extra;
    let path = dir.join("sphere.xyz");
    fs::write(&path, text).unwrap();
    path
}

/// A binary STL of `triangles` (zero facet normals and attributes) whose 80-byte header starts
/// with `header`.
pub fn binary_stl(header: &str, triangles: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut b = header.as_bytes().to_vec();
    b.resize(80, b' ');
    b.extend_from_slice(&(triangles.len() as u32).to_le_bytes());
    for t in triangles {
        b.extend_from_slice(&[0; 12]);
        for c in t.iter().flatten() {
            b.extend_from_slice(&c.to_le_bytes());
        }
        b.extend_from_slice(&[0; 2]);
    }
    b
}

/// splitmix64 (Steele, Lea and Flood 2014): a tiny, good-enough deterministic generator with a
/// 64-bit state, for samples and fuzz cases that must not change between runs.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (0 when `n` is 0).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next_u64() % n as u64) as usize
        }
    }

    pub fn byte(&mut self) -> u8 {
        self.next_u64() as u8
    }

    /// Uniform in [0, 1), from the top 53 bits.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller).
    pub fn gauss(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

/// The rotation matrix (row-major, acting on column vectors) of the quaternion w + xi + yj + zk,
/// normalized first.
pub fn quaternion_rotation(w: f64, x: f64, y: f64, z: f64) -> [[f64; 3]; 3] {
    let len = [w, x, y, z].iter().map(|v| v * v).sum::<f64>().sqrt();
    let (w, x, y, z) = (w / len, x / len, y / len, z / len);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// Every file under `dir` as (relative path, BLAKE3 of its bytes), sorted.
pub fn files_under(dir: &Path) -> Vec<(String, String)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in fs::read_dir(&d).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
                out.push((
                    rel,
                    blake3::hash(&fs::read(&p).unwrap()).to_hex().to_string(),
                ));
            }
        }
    }
    out.sort();
    out
}

/// The outputs of a run, without report.json (its timings differ between runs).
pub fn outputs(dir: &Path) -> Vec<(String, String)> {
    files_under(dir)
        .into_iter()
        .filter(|(name, _)| name != "report.json")
        .collect()
}

/// Names under `dir` (recursively) that are temporaries or hidden: a run must leave none.
pub fn hidden_names(dir: &Path) -> Vec<String> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in fs::read_dir(&d).into_iter().flatten().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') {
                out.push(e.path().display().to_string());
            }
            if e.path().is_dir() {
                stack.push(e.path());
            }
        }
    }
    out
}
