//! Integration tests of the `import` stage: the shared test scans import with the counts their
//! SOURCES.md lists, hand-made bad files give the right error, mutated and truncated files never
//! panic any reader, and small files written in every encoding read back exactly.

use std::path::Path;

use ply_rs_bw::ply::{
    Addable, DefaultElement, ElementDef, Encoding, Ply, Property, PropertyDef, PropertyType,
    ScalarType,
};
use ply_rs_bw::writer::Writer;
use proptest::prelude::*;
use stablesurf::import::{
    import_bytes, read_scan, read_scan_bytes, read_scan_bytes_as, scan_info, ImportError,
    ScanFormat,
};

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data");

/// The shared data folder, or `None` (with a notice) when it is absent.
fn data_dir() -> Option<&'static Path> {
    let dir = Path::new(DATA);
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("notice: {DATA} is absent; skipping the shared-data import checks");
        None
    }
}

// ---------------------------------------------------------------------------------------------
// Shared data

/// One row of ../shared/data/SOURCES.md: file, format, points, triangles after fan
/// triangulation, normals, duplicate positions (where SOURCES.md states them), bbox size.
struct Expected {
    file: &'static str,
    format: ScanFormat,
    points: usize,
    triangles: usize,
    has_normals: bool,
    duplicates: Option<usize>,
    bbox_size: [f64; 3],
    /// Relative tolerance on the bbox size, which SOURCES.md rounds.
    bbox_tolerance: f64,
}

const EXPECTED: &[Expected] = &[
    Expected {
        file: "bunny_zipper.ply",
        format: ScanFormat::PlyAscii,
        points: 35_947,
        triangles: 69_451,
        has_normals: false,
        // SOURCES.md says "1,113 duplicate vertex positions", but no two vertices of the file
        // share a position: 1,113 is the number of vertices no face uses (checked below).
        duplicates: Some(0),
        bbox_size: [0.156, 0.154, 0.121],
        bbox_tolerance: 0.01,
    },
    Expected {
        file: "bun000.ply",
        format: ScanFormat::PlyAscii,
        points: 40_256,
        triangles: 0,
        has_normals: false,
        duplicates: None,
        bbox_size: [0.156, 0.152, 0.117],
        bbox_tolerance: 0.01,
    },
    Expected {
        file: "duck.ply",
        format: ScanFormat::PlyBinaryLe,
        points: 2_108,
        triangles: 4_212,
        has_normals: false,
        duplicates: None,
        bbox_size: [1.65, 1.54, 1.15],
        bbox_tolerance: 0.01,
    },
    Expected {
        file: "max_planck.obj",
        format: ScanFormat::Obj,
        points: 5_272,
        triangles: 10_540,
        has_normals: false,
        duplicates: None,
        bbox_size: [193.0, 340.0, 244.0],
        bbox_tolerance: 0.01,
    },
    Expected {
        file: "patella_vhf_left.ply",
        format: ScanFormat::PlyBinaryLe,
        points: 3_264,
        triangles: 6_524,
        has_normals: false,
        duplicates: None,
        bbox_size: [42.8, 24.0, 46.9],
        bbox_tolerance: 0.01,
    },
    Expected {
        file: "quadknot.obj",
        format: ScanFormat::Obj,
        points: 1_440,
        triangles: 2_880,
        has_normals: true,
        duplicates: None,
        bbox_size: [171.0, 134.0, 181.0],
        bbox_tolerance: 0.01,
    },
    Expected {
        file: "fertility.ply",
        format: ScanFormat::PlyBinaryLe,
        points: 4_494,
        triangles: 9_000,
        has_normals: false,
        duplicates: None,
        bbox_size: [199.0, 144.0, 73.0],
        bbox_tolerance: 0.01,
    },
    Expected {
        file: "fandisk.obj",
        format: ScanFormat::Obj,
        points: 6_475,
        triangles: 12_946,
        has_normals: false,
        duplicates: None,
        bbox_size: [4.83, 5.24, 2.68],
        bbox_tolerance: 0.01,
    },
    Expected {
        file: "spot.obj",
        format: ScanFormat::Obj,
        points: 2_930,
        triangles: 5_856,
        has_normals: false,
        duplicates: None,
        bbox_size: [0.94, 1.69, 1.72],
        bbox_tolerance: 0.01,
    },
    Expected {
        file: "teapot.obj",
        format: ScanFormat::Obj,
        points: 3_644,
        triangles: 6_320,
        has_normals: false,
        duplicates: Some(403),
        bbox_size: [6.43, 3.15, 4.0],
        bbox_tolerance: 0.01,
    },
];

#[test]
fn shared_data_imports_with_the_listed_counts() {
    let Some(dir) = data_dir() else { return };
    for e in EXPECTED {
        let path = dir.join(e.file);
        let scan = read_scan(&path).unwrap_or_else(|err| panic!("{err}"));
        let info = scan_info(&scan);
        assert_eq!(scan.format, e.format, "{}", e.file);
        assert_eq!(info.format, e.format.as_str());
        assert_eq!(info.points, e.points, "{}", e.file);
        assert_eq!(info.triangles, e.triangles, "{}", e.file);
        assert_eq!(info.has_normals, e.has_normals, "{}", e.file);
        assert_eq!(info.nan_points, 0, "{}", e.file);
        if let Some(d) = e.duplicates {
            assert_eq!(info.duplicate_points, d, "{}", e.file);
        }
        for a in 0..3 {
            let size = info.bbox_max[a] - info.bbox_min[a];
            let rel = (size - e.bbox_size[a]).abs() / e.bbox_size[a];
            assert!(rel < e.bbox_tolerance, "{} axis {a}: size {size}", e.file);
        }
        // The validated import agrees with the raw parse.
        let bytes = std::fs::read(&path).unwrap();
        let cloud = import_bytes(&bytes, &path).unwrap_or_else(|err| panic!("{err}"));
        assert_eq!(cloud, scan.cloud, "{}", e.file);
    }
}

#[test]
fn bunny_has_1113_vertices_no_face_uses() {
    let Some(dir) = data_dir() else { return };
    let cloud = read_scan(&dir.join("bunny_zipper.ply")).unwrap().cloud;
    let mut used = vec![false; cloud.points.len()];
    for &i in cloud.triangles.iter().flatten() {
        used[i as usize] = true;
    }
    assert_eq!(used.iter().filter(|u| !**u).count(), 1_113);
}

#[test]
fn quadknot_normals_are_unit_and_per_vertex() {
    let Some(dir) = data_dir() else { return };
    let scan = read_scan(&dir.join("quadknot.obj")).unwrap();
    let normals = scan.cloud.normals.unwrap();
    assert_eq!(normals.len(), 1_440);
    for n in normals {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-3, "{n:?}");
    }
}

#[test]
fn raw_scan_skips_the_range_grid_and_matches_the_zippered_frame() {
    let Some(dir) = data_dir() else { return };
    let raw = scan_info(&read_scan(&dir.join("bun000.ply")).unwrap());
    let zip = scan_info(&read_scan(&dir.join("bunny_zipper.ply")).unwrap());
    // Same frame (identity transform in bun.conf): the boxes overlap to within a centimetre.
    for a in 0..3 {
        assert!((raw.bbox_min[a] - zip.bbox_min[a]).abs() < 0.01, "axis {a}");
        assert!((raw.bbox_max[a] - zip.bbox_max[a]).abs() < 0.01, "axis {a}");
    }
}

// ---------------------------------------------------------------------------------------------
// Small valid files in every format

/// An ascii PLY square with an extra property and element.
const PLY_ASCII: &str = "ply\nformat ascii 1.0\ncomment test\nelement vertex 4\n\
    property float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\n\
    property float nz\nproperty uchar confidence\nelement face 2\n\
    property list uchar int vertex_indices\nelement extra 1\nproperty list int float data\n\
    end_header\n0 0 0 0 0 1 9\n1 0 0 0 0 1 9\n1 1 0 0 0 1 9\n0 1 0 0 0 1 9\n3 0 1 2\n3 0 2 3\n\
    2 0.5 0.25\n";

const OBJ: &str = "# square\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n\
    f 1/1/1 2/1/1 3/1/1 4/1/1\n";

const STL_ASCII: &str =
    "solid sq\nfacet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n\
    \x20 vertex 1 1 0\n endloop\nendfacet\nfacet normal 0 0 1\n outer loop\n  vertex 0 0 0\n\
    \x20 vertex 1 1 0\n  vertex 0 1 0\n endloop\nendfacet\nendsolid sq\n";

const XYZ: &str = "# points\n0 0 0 0 0 1\n1,0,0,0,0,1\n1\t1\t0\t0\t0\t1\n0 1 0 0 0 1\n";

const SQUARE: [[f64; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [1.0, 1.0, 0.0],
    [0.0, 1.0, 0.0],
];

fn binary_stl(triangles: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut b = b"solid (a binary header that starts like ascii)".to_vec();
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

fn square_stl() -> Vec<u8> {
    let s = SQUARE.map(|p| p.map(|c| c as f32));
    binary_stl(&[[s[0], s[1], s[2]], [s[0], s[2], s[3]]])
}

/// A PLY written by ply-rs-bw with unusual types: char x, ushort y, double z, float normals, a
/// uint-counted list of shorts for the faces, and an extra element with a list.
fn odd_ply(encoding: Encoding, points: &[[i16; 3]], faces: &[Vec<i16>]) -> Vec<u8> {
    let mut ply = Ply::<DefaultElement>::new();
    ply.header.encoding = encoding;
    let mut vertex = ElementDef::new("vertex".to_string());
    for (name, ty) in [
        ("x", ScalarType::Char),
        ("y", ScalarType::UShort),
        ("z", ScalarType::Double),
        ("nx", ScalarType::Float),
        ("ny", ScalarType::Float),
        ("nz", ScalarType::Float),
        ("intensity", ScalarType::UInt),
    ] {
        vertex
            .properties
            .add(PropertyDef::new(name.to_string(), PropertyType::Scalar(ty)));
    }
    ply.header.elements.add(vertex);
    let mut face = ElementDef::new("face".to_string());
    face.properties.add(PropertyDef::new(
        "vertex_index".to_string(),
        PropertyType::List(ScalarType::UInt, ScalarType::Short),
    ));
    ply.header.elements.add(face);
    let mut extra = ElementDef::new("range_grid".to_string());
    extra.properties.add(PropertyDef::new(
        "vertex_indices".to_string(),
        PropertyType::List(ScalarType::UChar, ScalarType::Int),
    ));
    ply.header.elements.add(extra);
    let vertices = points
        .iter()
        .map(|p| {
            let mut e = DefaultElement::new();
            e.insert("x".into(), Property::Char(p[0] as i8));
            e.insert("y".into(), Property::UShort(p[1] as u16));
            e.insert("z".into(), Property::Double(f64::from(p[2]) * 0.5));
            e.insert("nx".into(), Property::Float(0.0));
            e.insert("ny".into(), Property::Float(-1.0));
            e.insert("nz".into(), Property::Float(0.25));
            e.insert("intensity".into(), Property::UInt(7));
            e
        })
        .collect();
    ply.payload.insert("vertex".into(), vertices);
    let face_elements = faces
        .iter()
        .map(|f| {
            let mut e = DefaultElement::new();
            e.insert("vertex_index".into(), Property::ListShort(f.clone()));
            e
        })
        .collect();
    ply.payload.insert("face".into(), face_elements);
    let grid = (0..3)
        .map(|i| {
            let mut e = DefaultElement::new();
            e.insert(
                "vertex_indices".into(),
                Property::ListInt(vec![i; i as usize]),
            );
            e
        })
        .collect();
    ply.payload.insert("range_grid".into(), grid);
    let mut out = Vec::new();
    Writer::new().write_ply(&mut out, &mut ply).unwrap();
    out
}

const ODD_POINTS: [[i16; 3]; 5] = [
    [-128, 0, -3],
    [127, 65, 7],
    [0, 1000, 0],
    [5, 6, 7],
    [1, 2, 3],
];

fn odd_faces() -> Vec<Vec<i16>> {
    vec![vec![0, 1, 2], vec![1, 2, 3, 4], vec![4, 3]]
}

/// Every small valid file with the name it is read under.
fn valid_files() -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("a.ply", PLY_ASCII.as_bytes().to_vec()),
        (
            "b.ply",
            odd_ply(Encoding::BinaryLittleEndian, &ODD_POINTS, &odd_faces()),
        ),
        (
            "c.ply",
            odd_ply(Encoding::BinaryBigEndian, &ODD_POINTS, &odd_faces()),
        ),
        ("d.ply", odd_ply(Encoding::Ascii, &ODD_POINTS, &odd_faces())),
        ("e.obj", OBJ.as_bytes().to_vec()),
        ("f.stl", STL_ASCII.as_bytes().to_vec()),
        ("g.stl", square_stl()),
        ("h.xyz", XYZ.as_bytes().to_vec()),
    ]
}

#[test]
fn small_files_in_every_format_read_the_same_square() {
    let expect_format = [
        ScanFormat::PlyAscii,
        ScanFormat::Obj,
        ScanFormat::StlAscii,
        ScanFormat::StlBinary,
        ScanFormat::Xyz,
    ];
    let files = [
        ("a.ply", PLY_ASCII.as_bytes().to_vec()),
        ("e.obj", OBJ.as_bytes().to_vec()),
        ("f.stl", STL_ASCII.as_bytes().to_vec()),
        ("g.stl", square_stl()),
        ("h.xyz", XYZ.as_bytes().to_vec()),
    ];
    for ((name, bytes), format) in files.iter().zip(expect_format) {
        let cloud = import_bytes(bytes, Path::new(name)).unwrap_or_else(|e| panic!("{e}"));
        let scan = read_scan_bytes(bytes, Path::new(name)).unwrap();
        assert_eq!(scan.format, format, "{name}");
        assert_eq!(cloud.points, SQUARE.to_vec(), "{name}");
        if format != ScanFormat::Xyz {
            assert_eq!(cloud.triangles, vec![[0, 1, 2], [0, 2, 3]], "{name}");
        }
        let has_normals = !matches!(format, ScanFormat::StlAscii | ScanFormat::StlBinary);
        assert_eq!(cloud.normals.is_some(), has_normals, "{name}");
        if let Some(n) = cloud.normals {
            assert_eq!(n, vec![[0.0, 0.0, 1.0]; 4], "{name}");
        }
    }
}

#[test]
fn ply_written_by_ply_rs_bw_reads_back_in_every_encoding() {
    for (encoding, format) in [
        (Encoding::Ascii, ScanFormat::PlyAscii),
        (Encoding::BinaryLittleEndian, ScanFormat::PlyBinaryLe),
        (Encoding::BinaryBigEndian, ScanFormat::PlyBinaryBe),
    ] {
        let bytes = odd_ply(encoding, &ODD_POINTS, &odd_faces());
        let scan = read_scan_bytes(&bytes, Path::new("odd.ply")).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(scan.format, format);
        let expected: Vec<[f64; 3]> = ODD_POINTS
            .iter()
            .map(|p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2]) * 0.5])
            .collect();
        assert_eq!(scan.cloud.points, expected, "{format}");
        assert_eq!(
            scan.cloud.normals,
            Some(vec![[0.0, -1.0, 0.25]; 5]),
            "{format}"
        );
        // The quad is fanned; the two-corner face adds nothing.
        assert_eq!(
            scan.cloud.triangles,
            vec![[0, 1, 2], [1, 2, 3], [1, 3, 4]],
            "{format}"
        );
    }
}

#[test]
fn stl_round_trip_welds_to_the_original_vertices() {
    // A tetrahedron written as four separate facets (12 corners) welds back to four points.
    let v: [[f32; 3]; 4] = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let faces = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];
    let tris: Vec<[[f32; 3]; 3]> = faces.iter().map(|f| f.map(|i| v[i])).collect();
    let mut ascii = String::from("solid t\n");
    for t in &tris {
        ascii.push_str("facet normal 0 0 0\nouter loop\n");
        for c in t {
            ascii.push_str(&format!("vertex {} {} {}\n", c[0], c[1], c[2]));
        }
        ascii.push_str("endloop\nendfacet\n");
    }
    ascii.push_str("endsolid t\n");
    for bytes in [binary_stl(&tris), ascii.into_bytes()] {
        let cloud = import_bytes(&bytes, Path::new("t.stl")).unwrap();
        assert_eq!(cloud.points.len(), 4);
        assert_eq!(cloud.triangles.len(), 4);
        for (t, f) in cloud.triangles.iter().zip(faces) {
            for (&i, j) in t.iter().zip(f) {
                assert_eq!(cloud.points[i as usize], v[j].map(f64::from));
            }
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Bad input: one hand-made file per error kind

fn err(bytes: &[u8], name: &str) -> ImportError {
    match import_bytes(bytes, Path::new(name)) {
        Ok(c) => panic!("{name}: expected an error, got {} points", c.points.len()),
        Err(e) => {
            let text = e.to_string();
            assert!(text.starts_with(name), "the message names the file: {text}");
            let after =
                text[name.len()..].trim_start_matches(|c: char| c == ':' || c.is_ascii_digit());
            let after = after.trim_start();
            assert!(
                !after.starts_with(|c: char| c.is_ascii_uppercase()),
                "lowercase message: {text}"
            );
            assert!(!text.ends_with('.'), "no trailing period: {text}");
            e
        }
    }
}

#[test]
fn empty_and_unknown_files() {
    assert!(matches!(err(b"", "empty.ply"), ImportError::Empty { .. }));
    let garbage: Vec<u8> = (0..300u32).map(|i| (i * 7919 % 251) as u8).collect();
    assert!(matches!(
        err(&garbage, "noise.bin"),
        ImportError::UnknownFormat { .. }
    ));
    assert!(matches!(
        err(b"hello world\n", "notes"),
        ImportError::UnknownFormat { .. }
    ));
    // Binary garbage under every known extension is an error of that reader.
    for name in ["noise.ply", "noise.obj", "noise.stl", "noise.xyz"] {
        err(&garbage, name);
    }
    assert!(matches!(
        err(&garbage, "noise.ply"),
        ImportError::BadHeader { line: 1, .. }
    ));
}

#[test]
fn truncated_files() {
    let ply = odd_ply(Encoding::BinaryLittleEndian, &ODD_POINTS, &odd_faces());
    let header_end = ply.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    for cut in [header_end + 3, header_end + 40, ply.len() - 1] {
        assert!(
            matches!(err(&ply[..cut], "cut.ply"), ImportError::Truncated { .. }),
            "{cut}"
        );
    }
    assert!(matches!(
        err(&ply[..header_end - 4], "cut.ply"),
        ImportError::Truncated { .. }
    ));
    let stl = square_stl();
    assert!(matches!(
        err(&stl[..stl.len() - 7], "cut.stl"),
        ImportError::Truncated { .. }
    ));
    let ascii = &STL_ASCII[..STL_ASCII.find("endloop\nendfacet\nendsolid").unwrap()];
    assert!(matches!(
        err(ascii.as_bytes(), "cut.stl"),
        ImportError::Truncated { .. }
    ));
}

#[test]
fn wrong_header_counts() {
    for (from, to) in [
        ("element vertex 4", "element vertex 3"),
        ("element face 2", "element face 3"),
    ] {
        let text = PLY_ASCII.replace(from, to);
        let e = err(text.as_bytes(), "count.ply");
        assert!(
            matches!(e, ImportError::HeaderCountMismatch { .. }),
            "{to}: {e}"
        );
    }
    // Binary: a count too small leaves bytes over, a count too large runs out of bytes.
    let ply = odd_ply(Encoding::BinaryLittleEndian, &ODD_POINTS, &odd_faces());
    let text = String::from_utf8_lossy(&ply).into_owned();
    assert!(text.contains("element range_grid 3"));
    let fewer = replace_bytes(&ply, b"element range_grid 3", b"element range_grid 2");
    assert!(matches!(
        err(&fewer, "count.ply"),
        ImportError::HeaderCountMismatch { .. }
    ));
    let more = replace_bytes(&ply, b"element vertex 5", b"element vertex 9");
    err(&more, "count.ply");
    let mut stl = square_stl();
    stl.extend_from_slice(&[0; 50]);
    assert!(matches!(
        err(&stl, "count.stl"),
        ImportError::HeaderCountMismatch {
            declared: 2,
            found: 3,
            ..
        }
    ));
    assert!(matches!(
        err(b"3\n0 0 0\n1 1 1\n", "count.pts"),
        ImportError::HeaderCountMismatch {
            declared: 3,
            found: 2,
            ..
        }
    ));
}

fn replace_bytes(haystack: &[u8], from: &[u8], to: &[u8]) -> Vec<u8> {
    let at = haystack
        .windows(from.len())
        .position(|w| w == from)
        .unwrap();
    [&haystack[..at], to, &haystack[at + from.len()..]].concat()
}

#[test]
fn face_indices_out_of_range() {
    let text = PLY_ASCII.replace("3 0 2 3\n", "3 0 2 4\n");
    assert!(matches!(
        err(text.as_bytes(), "range.ply"),
        ImportError::IndexOutOfRange {
            face: 1,
            index: 4,
            n_points: 4,
            ..
        }
    ));
    let faces = vec![vec![0, 1, 2], vec![1, 2, 3, 5]];
    for encoding in [Encoding::BinaryLittleEndian, Encoding::BinaryBigEndian] {
        let ply = odd_ply(encoding, &ODD_POINTS, &faces);
        assert!(matches!(
            err(&ply, "range.ply"),
            ImportError::IndexOutOfRange {
                face: 1,
                index: 5,
                n_points: 5,
                ..
            }
        ));
    }
    let obj = OBJ.replace("f 1/1/1 2/1/1 3/1/1 4/1/1", "f 1 2 3\nf 1 3 5");
    let e = err(obj.as_bytes(), "range.obj");
    assert!(
        matches!(
            e,
            ImportError::IndexOutOfRange {
                face: 1,
                index: 4,
                line: Some(9),
                ..
            }
        ),
        "{e}"
    );
    let obj = OBJ.replace("f 1/1/1 2/1/1 3/1/1 4/1/1", "f -1 -2 -5");
    assert!(matches!(
        err(obj.as_bytes(), "range.obj"),
        ImportError::IndexOutOfRange { .. }
    ));
}

#[test]
fn non_finite_coordinates_name_the_point() {
    let ply = PLY_ASCII.replace("1 1 0 0 0 1 9", "1 nan 0 0 0 1 9");
    let ply_binary = {
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n\
            property float y\nproperty float z\nend_header\n"
            .to_vec();
        for c in [0.0f32, 0.0, 0.0, 1.0, f32::INFINITY, 0.0] {
            b.extend_from_slice(&c.to_le_bytes());
        }
        b
    };
    let obj = OBJ.replace("v 1 1 0", "v 1 1 -inf");
    let stl = binary_stl(&[[[0.0, 0.0, 0.0], [f32::NAN, 1.0, 0.0], [0.0, 1.0, 0.0]]]);
    let xyz = "0 0 0\n1 1 1\n2 2 2\nNaN 0 0\n";
    for (bytes, name, point) in [
        (ply.as_bytes(), "nan.ply", 2),
        (&ply_binary[..], "inf.ply", 1),
        (obj.as_bytes(), "inf.obj", 2),
        (&stl[..], "nan.stl", 1),
        (xyz.as_bytes(), "nan.xyz", 3),
    ] {
        match err(bytes, name) {
            ImportError::NonFinite { point: p, .. } => assert_eq!(p, point, "{name}"),
            other => panic!("{name}: {other}"),
        }
        // `info` still reads the file and counts the bad point.
        let info = scan_info(&read_scan_bytes(bytes, Path::new(name)).unwrap());
        assert_eq!(info.nan_points, 1, "{name}");
    }
}

#[test]
fn files_without_points() {
    let ply = "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n\
               property float z\nend_header\n";
    assert!(matches!(
        err(ply.as_bytes(), "none.ply"),
        ImportError::NoPoints { .. }
    ));
    assert!(matches!(
        err(b"# only a comment\n", "none.xyz"),
        ImportError::NoPoints { .. }
    ));
    assert!(matches!(
        err(b"o empty\n", "none.obj"),
        ImportError::NoPoints { .. }
    ));
}

#[test]
fn malformed_lines_name_the_line() {
    for (text, name, line) in [
        (OBJ.replace("v 1 1 0", "v 1 one 0"), "bad.obj", 4),
        (XYZ.replace("1,0,0,0,0,1", "1,0,0,0,0"), "bad.xyz", 3),
        (
            STL_ASCII.replace("vertex 1 0 0", "vertex 1 0"),
            "bad.stl",
            5,
        ),
        (
            PLY_ASCII.replace("1 0 0 0 0 1 9", "1 0 zero 0 0 1 9"),
            "bad.ply",
            18,
        ),
    ] {
        match err(text.as_bytes(), name) {
            ImportError::Malformed { line: l, .. } => assert_eq!(l, line, "{name}"),
            other => panic!("{name}: {other}"),
        }
    }
    let e = err(
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nbogus\n",
        "h.ply",
    );
    assert!(matches!(e, ImportError::BadHeader { line: 5, .. }), "{e}");
    let no_z = PLY_ASCII.replace("property float z\n", "");
    assert!(matches!(
        err(no_z.as_bytes(), "noz.ply"),
        ImportError::BadLayout { .. }
    ));
}

// ---------------------------------------------------------------------------------------------
// Robustness: mutated and truncated files never panic any reader

/// One format per reader (the three PLY variants share one reader).
const ALL_READERS: [ScanFormat; 5] = [
    ScanFormat::PlyAscii,
    ScanFormat::Obj,
    ScanFormat::StlAscii,
    ScanFormat::StlBinary,
    ScanFormat::Xyz,
];

#[derive(Clone, Debug)]
enum Mutation {
    Truncate(usize),
    Flip(usize, u8),
    Insert(usize, Vec<u8>),
    Delete(usize, usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        any::<usize>().prop_map(Mutation::Truncate),
        (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Mutation::Flip(i, b)),
        (any::<usize>(), proptest::collection::vec(any::<u8>(), 1..8))
            .prop_map(|(i, b)| Mutation::Insert(i, b)),
        (any::<usize>(), 1usize..64).prop_map(|(i, n)| Mutation::Delete(i, n)),
    ]
}

fn apply(bytes: &mut Vec<u8>, m: &Mutation) {
    let len = bytes.len().max(1);
    match m {
        Mutation::Truncate(i) => bytes.truncate(i % len),
        Mutation::Flip(i, b) => {
            if let Some(x) = bytes.get_mut(i % len) {
                *x ^= b | 1;
            }
        }
        Mutation::Insert(i, b) => {
            let at = i % (bytes.len() + 1);
            bytes.splice(at..at, b.iter().copied());
        }
        Mutation::Delete(i, n) => {
            let at = i % len;
            let end = (at + n).min(bytes.len());
            if at < end {
                bytes.drain(at..end);
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    #[test]
    fn mutated_files_never_panic(
        file in 0usize..8,
        mutations in proptest::collection::vec(mutation(), 1..4),
    ) {
        let files = valid_files();
        let (name, mut bytes) = files[file % files.len()].clone();
        for m in &mutations {
            apply(&mut bytes, m);
        }
        // Every reader, forced, and the detection path under each extension: Ok or Err.
        for format in ALL_READERS {
            let _ = read_scan_bytes_as(&bytes, Path::new(name), format);
        }
        for ext in ["ply", "obj", "stl", "xyz", "bin"] {
            let path = format!("m.{ext}");
            if let Ok(scan) = read_scan_bytes(&bytes, Path::new(&path)) {
                let _ = scan_info(&scan);
                // A parse that succeeds has triangles inside the points.
                let n = scan.cloud.points.len();
                prop_assert!(scan.cloud.triangles.iter().flatten().all(|&i| (i as usize) < n));
            }
            let _ = import_bytes(&bytes, Path::new(&path));
        }
    }

    #[test]
    fn xyz_round_trips_exactly(
        points in proptest::collection::vec(proptest::array::uniform3(-1e6f64..1e6), 1..50),
        sep in prop_oneof![Just(" "), Just("\t"), Just(","), Just(", ")],
    ) {
        let mut text = String::from("# generated\n");
        for p in &points {
            text.push_str(&format!("{:?}{sep}{:?}{sep}{:?}\n", p[0], p[1], p[2]));
        }
        let cloud = import_bytes(text.as_bytes(), Path::new("r.xyz")).unwrap();
        prop_assert_eq!(cloud.points, points);
    }

    #[test]
    fn binary_ply_round_trips_exactly(
        points in proptest::collection::vec(proptest::array::uniform3(any::<f64>()), 1..50),
        big in any::<bool>(),
    ) {
        let encoding = if big { "binary_big_endian" } else { "binary_little_endian" };
        let mut bytes = format!(
            "ply\nformat {encoding} 1.0\nelement vertex {}\nproperty double x\n\
             property double y\nproperty double z\nend_header\n",
            points.len()
        )
        .into_bytes();
        for c in points.iter().flatten() {
            bytes.extend_from_slice(&if big { c.to_be_bytes() } else { c.to_le_bytes() });
        }
        let scan = read_scan_bytes(&bytes, Path::new("r.ply")).unwrap();
        let got: Vec<[u64; 3]> = scan.cloud.points.iter().map(|p| p.map(f64::to_bits)).collect();
        let want: Vec<[u64; 3]> = points.iter().map(|p| p.map(f64::to_bits)).collect();
        prop_assert_eq!(got, want);
    }
}
