//! Seeded, deterministic byte-mutation fuzz of every scan reader: PLY (ascii, binary
//! little-endian, binary big-endian), OBJ, STL (ascii, binary) and the XYZ family (.xyz, .pts,
//! .txt, .csv).
//!
//! The seeds are small files: cheap, consistent cuts of the real scans in ../shared/data (a few
//! hundred vertices with their real header, the same vertices re-encoded as big-endian PLY, STL,
//! XYZ, PTS and CSV) plus hand-made files of each format. Each case applies 1 to 4 mutations
//! (bit flips, bytes set to 0, 0xff or a random value, inserted and deleted runs, truncation,
//! duplicated chunks, edits of the numbers in the header or the first lines) and runs the result
//! through `read_scan_bytes` and `import_bytes` under its own name and another extension, and
//! through every reader forced with `read_scan_bytes_as`, inside `catch_unwind`. The test fails
//! when any case panics, or parses into triangles that index past the points, and prints the
//! seed and case to reproduce (`FUZZ_SEED=… FUZZ_CASE=… cargo test --test all fuzz_readers`).
//!
//! `FUZZ_SEED` (decimal or 0x-hex) and `FUZZ_CASES` override the fixed seed and the case count.
//! When ../shared/data is absent the test fails if `CI` is set, and otherwise fuzzes the
//! hand-made seeds only, with a notice.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use stablesurf::import::{
    import_bytes, read_scan_bytes, read_scan_bytes_as, scan_info, ScanFormat,
};

use crate::fixtures::{binary_stl, shared, Rng};

/// The fixed seed of a normal run.
const SEED: u64 = 0x5eed_0f5c_a11e_d001;
/// Cases of a normal run.
const CASES: u64 = 20_000;

// ---------------------------------------------------------------------------------------------
// Seeds

/// A seed file: the name it is read under (its extension matters) and its bytes.
type Seed = (String, Vec<u8>);

/// The header of a PLY (through the `end_header` line, LF or CRLF) and the body, or `None`.
fn split_ply(bytes: &[u8]) -> Option<(&str, &[u8])> {
    let at = bytes.windows(10).position(|w| w == b"end_header")?;
    let end = at + bytes[at..].iter().position(|&b| b == b'\n')? + 1;
    Some((std::str::from_utf8(&bytes[..end]).ok()?, &bytes[end..]))
}

/// The header with each `element NAME COUNT` line's count replaced by `count(NAME)`.
fn recount(header: &str, count: impl Fn(&str) -> usize) -> String {
    header
        .lines()
        .map(
            |line| match line.split_ascii_whitespace().collect::<Vec<_>>()[..] {
                ["element", name, _] => format!("element {name} {}", count(name)),
                _ => line.to_owned(),
            },
        )
        .map(|l| l + "\n")
        .collect()
}

/// The first `n` vertices of an ascii PLY with its real header, the other elements emptied.
fn ascii_ply_cut(bytes: &[u8], n: usize) -> Option<Vec<u8>> {
    let (header, body) = split_ply(bytes)?;
    let lines: Vec<&[u8]> = body.split(|&b| b == b'\n').take(n).collect();
    let mut out = recount(
        header,
        |name| if name == "vertex" { lines.len() } else { 0 },
    )
    .into_bytes();
    for l in &lines {
        out.extend_from_slice(l);
        out.push(b'\n');
    }
    Some(out)
}

/// The first `n` float x y z vertices of one of the shared binary little-endian PLYs (float
/// x, y, z then a uchar/int face list), as `[x, y, z]`.
fn binary_ply_points(bytes: &[u8], n: usize) -> Option<Vec<[f32; 3]>> {
    let (header, body) = split_ply(bytes)?;
    if !header.contains("binary_little_endian") {
        return None;
    }
    let points = body
        .chunks_exact(12)
        .take(n)
        .map(|c| {
            let f = |i: usize| f32::from_le_bytes([c[i], c[i + 1], c[i + 2], c[i + 3]]);
            [f(0), f(4), f(8)]
        })
        .collect();
    Some(points)
}

/// A binary PLY of `points` (float x y z) and the strip triangles (i, i+1, i+2), with `header`'s
/// comments kept when given.
fn binary_ply(points: &[[f32; 3]], big: bool, comment: &str) -> Vec<u8> {
    let faces = points.len().saturating_sub(2);
    let mut out = format!(
        "ply\nformat {} 1.0\ncomment {comment}\nelement vertex {}\nproperty float x\n\
         property float y\nproperty float z\nelement face {faces}\n\
         property list uchar int vertex_indices\nend_header\n",
        if big {
            "binary_big_endian"
        } else {
            "binary_little_endian"
        },
        points.len()
    )
    .into_bytes();
    for c in points.iter().flatten() {
        out.extend_from_slice(&if big {
            c.to_be_bytes()
        } else {
            c.to_le_bytes()
        });
    }
    for i in 0..faces as i32 {
        out.push(3);
        for v in [i, i + 1, i + 2] {
            out.extend_from_slice(&if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            });
        }
    }
    out
}

fn strip_triangles(points: &[[f32; 3]]) -> Vec<[[f32; 3]; 3]> {
    points.windows(3).map(|w| [w[0], w[1], w[2]]).collect()
}

fn ascii_stl(triangles: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut s = String::from("solid fuzz\n");
    for t in triangles {
        s.push_str("  facet normal 0 0 1\n    outer loop\n");
        for c in t {
            s.push_str(&format!("      vertex {} {} {}\n", c[0], c[1], c[2]));
        }
        s.push_str("    endloop\n  endfacet\n");
    }
    s.push_str("endsolid fuzz\n");
    s.into_bytes()
}

/// The XYZ-family files of `points`: 3 and 6 columns, a .pts with a count and 7 columns, a csv
/// with column names, a .txt with tabs.
fn point_lists(points: &[[f32; 3]], tag: &str) -> Vec<Seed> {
    let mut xyz3 = String::from("# x y z\n");
    let mut xyz6 = String::new();
    let mut pts = format!("{}\n", points.len());
    let mut csv = String::from("x,y,z,nx,ny,nz\n");
    let mut txt = String::new();
    for (i, p) in points.iter().enumerate() {
        xyz3.push_str(&format!("{} {} {}\n", p[0], p[1], p[2]));
        xyz6.push_str(&format!("{} {} {} 0 0 1\n", p[0], p[1], p[2]));
        pts.push_str(&format!(
            "{} {} {} {} 200 10 0\n",
            p[0],
            p[1],
            p[2],
            i % 256
        ));
        csv.push_str(&format!("{},{},{},1,0,0\n", p[0], p[1], p[2]));
        txt.push_str(&format!("{}\t{}\t{}\n", p[0], p[1], p[2]));
    }
    vec![
        (format!("{tag}3.xyz"), xyz3.into_bytes()),
        (format!("{tag}6.xyz"), xyz6.into_bytes()),
        (format!("{tag}.pts"), pts.into_bytes()),
        (format!("{tag}.csv"), csv.into_bytes()),
        (format!("{tag}.txt"), txt.into_bytes()),
    ]
}

/// The first `n` lines of a text file.
fn text_prefix(bytes: &[u8], n: usize) -> Vec<u8> {
    let end = bytes
        .iter()
        .enumerate()
        .filter(|&(_, &b)| b == b'\n')
        .nth(n.saturating_sub(1))
        .map_or(bytes.len(), |(i, _)| i + 1);
    bytes[..end].to_vec()
}

/// Seeds cut from the shared data, or `None` (after a notice; a failure under CI) when the
/// folder is absent.
fn data_seeds() -> Option<Vec<Seed>> {
    let dir = shared("data", "the fuzz seeds cut from real scans")?;
    let read = |name: &str| {
        let path = dir.join(name);
        std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    };
    let mut seeds = Vec::new();
    for name in ["bunny_zipper.ply", "bun000.ply", "bunny-scans/top2.ply"] {
        let bytes = read(name);
        let cut = ascii_ply_cut(&bytes, 60).unwrap_or_else(|| panic!("{name}: no ply header"));
        let short = name.rsplit('/').next().unwrap_or(name);
        seeds.push((format!("cut-{short}"), cut));
        // The raw prefix, header and all: a truncated file.
        seeds.push((
            format!("prefix-{short}"),
            bytes[..bytes.len().min(1500)].to_vec(),
        ));
    }
    for name in ["duck.ply", "fertility.ply", "patella_vhf_left.ply"] {
        let bytes = read(name);
        let points = binary_ply_points(&bytes, 40).unwrap_or_else(|| panic!("{name}: layout"));
        seeds.push((format!("le-{name}"), binary_ply(&points, false, name)));
        seeds.push((format!("be-{name}"), binary_ply(&points, true, name)));
        seeds.push((
            format!("prefix-{name}"),
            bytes[..bytes.len().min(1200)].to_vec(),
        ));
        let tag = name.trim_end_matches(".ply");
        let triangles = strip_triangles(&points[..points.len().min(16)]);
        seeds.push((
            format!("{tag}.stl"),
            binary_stl("solid binary header", &triangles),
        ));
        seeds.push((format!("{tag}-ascii.stl"), ascii_stl(&triangles)));
        seeds.extend(point_lists(&points[..points.len().min(30)], tag));
    }
    for name in [
        "max_planck.obj",
        "quadknot.obj",
        "fandisk.obj",
        "spot.obj",
        "teapot.obj",
    ] {
        let bytes = read(name);
        seeds.push((format!("prefix-{name}"), text_prefix(&bytes, 80)));
    }
    // OBJ with faces whose indices exist: the v lines of a prefix and strip faces over them.
    let quadknot = read("quadknot.obj");
    let mut obj = Vec::new();
    for (keyword, n) in [(&b"v "[..], 30), (b"vt ", 3), (b"vn ", 3)] {
        for line in quadknot
            .split(|&b| b == b'\n')
            .filter(|l| l.starts_with(keyword))
            .take(n)
        {
            obj.extend_from_slice(line);
            obj.push(b'\n');
        }
    }
    for i in 1..10 {
        obj.extend_from_slice(format!("f {i}/1/1 {}/2/2 {}/3/3\n", i + 1, i + 2).as_bytes());
    }
    seeds.push(("strip-quadknot.obj".to_owned(), obj));
    Some(seeds)
}

/// Hand-made seeds of every format.
fn generated_seeds() -> Vec<Seed> {
    let square: Vec<[f32; 3]> = vec![
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.5, 0.5, 1.0],
    ];
    let mut seeds = vec![
        (
            "a.ply".to_owned(),
            b"ply\nformat ascii 1.0\ncomment c\nelement vertex 4\nproperty float x\n\
              property float y\nproperty float z\nproperty float nx\nproperty float ny\n\
              property float nz\nproperty uchar confidence\nelement face 2\n\
              property list uchar int vertex_indices\nelement extra 1\n\
              property list int float data\nend_header\n0 0 0 0 0 1 9\n1 0 0 0 0 1 9\n\
              1 1 0 0 0 1 9\n0 1 0 0 0 1 9\n3 0 1 2\n4 0 2 3 1\n2 0.5 0.25\n"
                .to_vec(),
        ),
        ("le.ply".to_owned(), binary_ply(&square, false, "square")),
        ("be.ply".to_owned(), binary_ply(&square, true, "square")),
        (
            "e.obj".to_owned(),
            b"# square\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n\
              f 1/1/1 2/1/1 3/1/1 4/1/1\nf -1//1 -2//1 -3//1\n"
                .to_vec(),
        ),
        ("f.stl".to_owned(), ascii_stl(&strip_triangles(&square))),
        (
            "g.stl".to_owned(),
            binary_stl("solid binary header", &strip_triangles(&square)),
        ),
    ];
    // A big-endian PLY whose vertices hold a list (the walking path) and odd types.
    let mut odd = b"ply\nformat binary_big_endian 1.0\nelement vertex 3\n\
        property list uchar short tags\nproperty short x\nproperty uint y\nproperty double z\n\
        element face 1\nproperty list ushort uint vertex_index\nend_header\n"
        .to_vec();
    for (tags, x, y, z) in [
        (vec![1i16, 2], -3i16, 7u32, 0.25f64),
        (vec![], 4, 9, -1.5),
        (vec![5], 0, 1, 2.0),
    ] {
        odd.push(tags.len() as u8);
        for t in tags {
            odd.extend_from_slice(&t.to_be_bytes());
        }
        odd.extend_from_slice(&x.to_be_bytes());
        odd.extend_from_slice(&y.to_be_bytes());
        odd.extend_from_slice(&z.to_be_bytes());
    }
    odd.extend_from_slice(&3u16.to_be_bytes());
    for i in [1u32, 0, 2] {
        odd.extend_from_slice(&i.to_be_bytes());
    }
    seeds.push(("odd.ply".to_owned(), odd));
    seeds.extend(point_lists(&square, "sq"));
    seeds
}

// ---------------------------------------------------------------------------------------------
// Mutations

/// Replaces a run of ASCII digits near the start (the header, a count line) with another number.
fn edit_number(bytes: &mut Vec<u8>, rng: &mut Rng) -> String {
    let head = bytes.len().min(1024);
    let runs: Vec<(usize, usize)> = {
        let mut runs = Vec::new();
        let mut i = 0;
        while i < head {
            if bytes[i].is_ascii_digit() {
                let start = i;
                while i < head && bytes[i].is_ascii_digit() {
                    i += 1;
                }
                runs.push((start, i));
            } else {
                i += 1;
            }
        }
        runs
    };
    if runs.is_empty() {
        return "number edit (no number)".to_owned();
    }
    let (start, end) = runs[rng.below(runs.len())];
    let old: u64 = std::str::from_utf8(&bytes[start..end])
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    let new = match rng.below(9) {
        0 => "0".to_owned(),
        1 => "1".to_owned(),
        2 => old.saturating_add(1).to_string(),
        3 => old.saturating_sub(1).to_string(),
        4 => (old.saturating_mul(2)).to_string(),
        5 => u32::MAX.to_string(),
        6 => u64::MAX.to_string(),
        7 => "-1".to_owned(),
        _ => "99999999999999999999999".to_owned(),
    };
    bytes.splice(start..end, new.bytes());
    format!("number at {start}: {old} -> {new}")
}

/// Applies one random mutation and describes it.
fn mutate(bytes: &mut Vec<u8>, rng: &mut Rng) -> String {
    let len = bytes.len();
    match rng.below(10) {
        0 => {
            let at = rng.below(len);
            let bit = rng.below(8);
            if let Some(b) = bytes.get_mut(at) {
                *b ^= 1 << bit;
            }
            format!("flip bit {bit} of byte {at}")
        }
        1 => {
            let at = rng.below(len);
            let value = [0u8, 0xff, rng.byte()][rng.below(3)];
            if let Some(b) = bytes.get_mut(at) {
                *b = value;
            }
            format!("set byte {at} to {value:#04x}")
        }
        2 => {
            let at = rng.below(len + 1);
            let n = 1 + rng.below(16);
            let run: Vec<u8> = if rng.below(2) == 0 {
                (0..n).map(|_| rng.byte()).collect()
            } else {
                let pick = [b'\n', b' ', b'0', b'-', b'.', b'/', 0, 0xff];
                vec![pick[rng.below(pick.len())]; n]
            };
            bytes.splice(at..at, run.iter().copied());
            format!("insert {run:?} at {at}")
        }
        3 => {
            let at = rng.below(len);
            let end = (at + 1 + rng.below(64)).min(len);
            bytes.drain(at..end);
            format!("delete {at}..{end}")
        }
        4 => {
            let at = rng.below(len + 1);
            bytes.truncate(at);
            format!("truncate at {at}")
        }
        5 => {
            let from = rng.below(len);
            let end = (from + 1 + rng.below(256)).min(len);
            let chunk: Vec<u8> = bytes[from..end].to_vec();
            let at = rng.below(bytes.len() + 1);
            bytes.splice(at..at, chunk);
            format!("duplicate {from}..{end} at {at}")
        }
        6 => {
            // Swap two bytes: a reordering that keeps the length.
            let (a, b) = (rng.below(len), rng.below(len));
            if a < len && b < len {
                bytes.swap(a, b);
            }
            format!("swap bytes {a} and {b}")
        }
        _ => edit_number(bytes, rng),
    }
}

/// A panic or a broken invariant, with what reproduces it.
struct Failure {
    case: u64,
    seed: String,
    mutations: Vec<String>,
    what: String,
}

/// Runs every reader on `bytes`; `Err` describes a broken invariant (a panic is caught outside).
fn check(bytes: &[u8], name: &str, other_ext: &str) -> Result<(), String> {
    let other = format!("m.{other_ext}");
    for path in [name, other.as_str()] {
        let path = Path::new(path);
        if let Ok(scan) = read_scan_bytes(bytes, path) {
            let n = scan.cloud.points.len();
            if let Some(t) = scan
                .cloud
                .triangles
                .iter()
                .find(|t| t.iter().any(|&i| i as usize >= n))
            {
                return Err(format!(
                    "{}: triangle {t:?} with {n} points",
                    path.display()
                ));
            }
            if let Some(normals) = &scan.cloud.normals
                && normals.len() != n
            {
                return Err(format!(
                    "{}: {} normals, {n} points",
                    path.display(),
                    normals.len()
                ));
            }
            let _ = scan_info(&scan);
        }
        if let Ok(cloud) = import_bytes(bytes, path)
            && (cloud.points.is_empty() || cloud.points.iter().flatten().any(|c| !c.is_finite()))
        {
            return Err(format!(
                "{}: import_bytes broke its invariants",
                path.display()
            ));
        }
    }
    for format in [
        ScanFormat::PlyAscii,
        ScanFormat::Obj,
        ScanFormat::StlAscii,
        ScanFormat::StlBinary,
        ScanFormat::Xyz,
    ] {
        let _ = read_scan_bytes_as(bytes, Path::new(name), format);
    }
    Ok(())
}

fn env_u64(name: &str) -> Option<u64> {
    let v = std::env::var(name).ok()?;
    let v = v.trim();
    match v.strip_prefix("0x") {
        Some(hex) => u64::from_str_radix(hex, 16).ok(),
        None => v.parse().ok(),
    }
}

#[test]
fn mutated_files_never_panic_any_reader() {
    let mut seeds = generated_seeds();
    match data_seeds() {
        Some(data) => seeds.extend(data),
        None => eprintln!("notice: fuzzing the {} hand-made seeds only", seeds.len()),
    }
    // Every seed reads as its format before it is mutated (a seed that is already broken would
    // fuzz only the first error path), except the raw prefixes, which are truncated on purpose.
    for (name, bytes) in &seeds {
        if !name.starts_with("prefix-")
            && let Err(e) = read_scan_bytes(bytes, Path::new(name))
        {
            panic!("seed {name} does not read: {e}");
        }
    }
    let seed = env_u64("FUZZ_SEED").unwrap_or(SEED);
    let only = env_u64("FUZZ_CASE");
    let cases = env_u64("FUZZ_CASES").unwrap_or(CASES);
    let extensions = ["ply", "obj", "stl", "xyz", "pts", "txt", "csv", "bin"];
    // The panic messages are collected below; the default hook would print each one too. The
    // hook is process-wide and the other test modules run beside this one in the same process,
    // so only panics on this thread and on unnamed threads (the readers' worker threads) are
    // kept quiet: a panic on another test's thread still reaches the previous hook. The guard
    // puts the previous hook back however this test ends.
    type Hook = Box<dyn Fn(&std::panic::PanicHookInfo<'_>) + Sync + Send>;
    struct RestoreHook(Option<Arc<Hook>>);
    impl Drop for RestoreHook {
        fn drop(&mut self) {
            if let Some(hook) = self.0.take() {
                std::panic::set_hook(Box::new(move |info| hook(info)));
            }
        }
    }
    let previous: Arc<Hook> = Arc::new(std::panic::take_hook());
    let mut restore = RestoreHook(Some(Arc::clone(&previous)));
    let fuzz_thread = std::thread::current().id();
    std::panic::set_hook(Box::new(move |info| {
        let current = std::thread::current();
        if current.id() != fuzz_thread && current.name().is_some() {
            previous(info);
        }
    }));
    let start = Instant::now();
    let mut failures: Vec<Failure> = Vec::new();
    let mut run = 0u64;
    let mut parsed = 0u64;
    for case in 0..cases {
        if only.is_some_and(|c| c != case) {
            continue;
        }
        let mut rng = Rng(seed ^ case.wrapping_mul(0xa076_1d64_78bd_642f));
        let (name, original) = &seeds[rng.below(seeds.len())];
        let mut bytes = original.clone();
        let n = 1 + rng.below(4);
        let mutations: Vec<String> = (0..n).map(|_| mutate(&mut bytes, &mut rng)).collect();
        let other_ext = extensions[rng.below(extensions.len())];
        run += 1;
        let result = catch_unwind(AssertUnwindSafe(|| check(&bytes, name, other_ext)));
        let what = match result {
            Ok(Ok(())) => {
                if read_scan_bytes(&bytes, Path::new(name)).is_ok() {
                    parsed += 1;
                }
                continue;
            }
            Ok(Err(broken)) => broken,
            Err(panic) => {
                let message = panic
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| panic.downcast_ref::<&str>().map(|s| (*s).to_owned()))
                    .unwrap_or_default();
                format!("panic: {message}")
            }
        };
        failures.push(Failure {
            case,
            seed: name.clone(),
            mutations,
            what,
        });
    }
    drop(std::mem::replace(&mut restore, RestoreHook(None)));
    let elapsed = start.elapsed();
    eprintln!(
        "fuzz_readers: {run} cases from {} seeds in {:.2} s ({parsed} still parse), seed {seed:#x}",
        seeds.len(),
        elapsed.as_secs_f64()
    );
    if !failures.is_empty() {
        for f in failures.iter().take(10) {
            eprintln!(
                "FUZZ_SEED={seed:#x} FUZZ_CASE={} (seed file {}; {}): {}",
                f.case,
                f.seed,
                f.mutations.join("; "),
                f.what
            );
        }
        panic!(
            "{} of {run} fuzz cases failed (first ones above)",
            failures.len()
        );
    }
    assert!(only.is_some() || run >= 2_000.min(cases), "{run} cases");
}
