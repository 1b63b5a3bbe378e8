//! Integration tests of the `import` stage: the shared test scans import with the counts their
//! SOURCES.md lists, hand-made bad files give the right error, mutated and truncated files never
//! panic any reader, and small files written in every encoding read back exactly. The `reject_*`
//! tests are the reproducers of files the readers once accepted although their bytes contradict
//! their header or grammar (see "Believe the bytes" in src/import/mod.rs); the broader seeded
//! byte-mutation fuzz of every reader is tests/fuzz_readers.rs.

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

use crate::fixtures::{binary_stl, shared};

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
        // Its range grid, triangulated (see `range_grid_is_triangulated_facing_the_sensor`).
        triangles: 78_081,
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
    let Some(dir) = shared("data", "the shared-data import checks") else {
        return;
    };
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
    let Some(dir) = shared("data", "the shared-data import checks") else {
        return;
    };
    let cloud = read_scan(&dir.join("bunny_zipper.ply")).unwrap().cloud;
    let mut used = vec![false; cloud.points.len()];
    for &i in cloud.triangles.iter().flatten() {
        used[i as usize] = true;
    }
    assert_eq!(used.iter().filter(|u| !**u).count(), 1_113);
}

#[test]
fn quadknot_normals_are_unit_and_per_vertex() {
    let Some(dir) = shared("data", "the shared-data import checks") else {
        return;
    };
    let scan = read_scan(&dir.join("quadknot.obj")).unwrap();
    let normals = scan.cloud.normals.unwrap();
    assert_eq!(normals.len(), 1_440);
    for n in normals {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-3, "{n:?}");
    }
}

#[test]
fn raw_scan_matches_the_zippered_frame() {
    let Some(dir) = shared("data", "the shared-data import checks") else {
        return;
    };
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

/// The header of the binary STL files here: it starts with `solid` like an ASCII STL, as some
/// exporters' headers do, so the reader must look further to tell the encodings apart.
const STL_HEADER: &str = "solid (a binary header that starts like ascii)";

fn square_stl() -> Vec<u8> {
    let s = SQUARE.map(|p| p.map(|c| c as f32));
    binary_stl(STL_HEADER, &[[s[0], s[1], s[2]], [s[0], s[2], s[3]]])
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
    vec![vec![0, 1, 2], vec![1, 2, 3, 4]]
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
        // The quad is fanned.
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
    for bytes in [binary_stl(STL_HEADER, &tris), ascii.into_bytes()] {
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
    let e = err(&fewer, "count.ply");
    assert!(
        matches!(&e, ImportError::BadBinary { element, .. } if element == "range_grid"),
        "{e}"
    );
    assert!(e.to_string().contains("`element range_grid 3`"), "{e}");
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
        // Binary: the entry and its byte offset in the file (after the header, five 27-byte
        // vertices and the 10-byte first face).
        let header_end = ply.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let e = err(&ply, "range.ply");
        match &e {
            ImportError::BadBinary {
                element,
                entry: 1,
                offset,
                message,
                ..
            } => {
                assert_eq!(element, "face");
                assert_eq!(*offset as usize, header_end + 5 * 27 + 10, "{e}");
                assert!(message.contains("refers to vertex 5"), "{e}");
            }
            other => panic!("{other}"),
        }
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
    let stl = binary_stl(
        STL_HEADER,
        &[[[0.0, 0.0, 0.0], [f32::NAN, 1.0, 0.0], [0.0, 1.0, 0.0]]],
    );
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
    // A text file without a point says what it holds instead.
    let e = err(b"# only a comment\n", "none.xyz");
    assert!(matches!(e, ImportError::NoPointFound { .. }), "{e}");
    assert!(e.to_string().contains("line 1: `# only a comment`"), "{e}");
    let e = err(b"o empty\n", "none.obj");
    assert!(matches!(e, ImportError::NoPointFound { .. }), "{e}");
    assert!(e.to_string().contains("line 1: `o empty`"), "{e}");
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
// Reproducers: files whose bytes contradict their header or grammar, once accepted

/// A binary little-endian PLY of `n` float vertices on a spiral and `faces` uchar/int triangles
/// `(i, i+1, i+2)`, with the header declaring `declared` vertices. Returns the bytes and the
/// offset of the body.
fn spiral_ply(n: usize, faces: usize, declared: usize) -> (Vec<u8>, usize) {
    let mut bytes = format!(
        "ply\nformat binary_little_endian 1.0\ncomment generated\nelement vertex {declared}\n\
         property float x\nproperty float y\nproperty float z\nelement face {faces}\n\
         property list uchar int vertex_indices\nend_header\n"
    )
    .into_bytes();
    let body = bytes.len();
    for i in 0..n {
        let t = i as f32 * 0.1;
        for c in [t.cos(), t.sin(), t] {
            bytes.extend_from_slice(&c.to_le_bytes());
        }
    }
    for j in 0..faces as i32 {
        bytes.push(3);
        for v in [j, j + 1, j + 2] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    (bytes, body)
}

#[test]
fn reject_binary_ply_whose_vertex_count_overruns_into_the_faces() {
    let (good, body) = spiral_ply(162, 160, 162);
    assert_eq!(
        import_bytes(&good, Path::new("ok.ply"))
            .unwrap()
            .points
            .len(),
        162
    );
    // The header says 163 over a body of 162: the 163rd vertex is the first face's count and
    // indices, and the faces are then read one byte out of place. The byte counts happen to add
    // up (the out-of-place first face has 0 corners), so this used to import 163 points.
    let (bad, _) = spiral_ply(162, 160, 163);
    let e = err(&bad, "overrun.ply");
    match &e {
        ImportError::BadBinary {
            element,
            entry: 0,
            offset,
            message,
            ..
        } => {
            assert_eq!(element, "face");
            assert_eq!(*offset as usize, body + 163 * 12, "{e}");
            assert!(message.contains("0 corner"), "{e}");
            assert!(
                message.contains("`element vertex 162` instead of 163"),
                "{e}"
            );
        }
        other => panic!("{other}"),
    }
    assert!(read_scan_bytes(&bad, Path::new("overrun.ply")).is_err());
    // One vertex too few: the faces start inside the last vertex; also an error.
    let (fewer, _) = spiral_ply(162, 160, 161);
    let e = err(&fewer, "under.ply");
    assert!(
        e.to_string()
            .contains("`element vertex 162` instead of 161"),
        "{e}"
    );
}

#[test]
fn reject_binary_ply_body_shorter_or_longer_than_its_counts() {
    let (good, body) = spiral_ply(20, 10, 20);
    let end = good.len();
    // Shorter: cut inside face 9 (each face is 13 bytes).
    let e = err(&good[..end - 5], "short.ply");
    match &e {
        ImportError::Truncated { detail, .. } => {
            assert!(detail.contains("`face` entry 9"), "{e}");
            assert!(
                detail.contains(&format!("starting at byte {}", end - 13)),
                "{e}"
            );
            assert!(detail.contains(&format!("at byte {}", end - 5)), "{e}");
        }
        other => panic!("{other}"),
    }
    // Longer: a stray byte, a trailing newline, a whole extra face.
    for extra in [
        &b"\x00"[..],
        b"\n",
        b"\r\n",
        &[3, 0, 0, 0, 0, 1, 0, 0, 0, 2, 0, 0, 0],
    ] {
        let mut longer = good.clone();
        longer.extend_from_slice(extra);
        let e = err(&longer, "long.ply");
        match &e {
            ImportError::BadBinary {
                element, offset, ..
            } => {
                assert_eq!(element, "face", "{e}");
                assert_eq!(*offset as usize, end, "{e}");
            }
            other => panic!("{extra:?}: {other}"),
        }
    }
    // With a fixed-size last element, the extra bytes are counted in its entries.
    let points_only = {
        let mut b = b"ply\nformat binary_big_endian 1.0\nelement vertex 2\nproperty float x\n\
              property float y\nproperty float z\nend_header\n"
            .to_vec();
        b.extend_from_slice(&[0; 36]);
        b
    };
    let e = err(&points_only, "three.ply");
    assert!(
        matches!(
            e,
            ImportError::HeaderCountMismatch {
                declared: 2,
                found: 3,
                ..
            }
        ),
        "{e}"
    );
    let text = e.to_string();
    assert!(text.contains("`vertex` entries"), "{text}");
    assert!(
        text.contains(&format!("ends at byte {}", points_only.len() - 12)),
        "{text}"
    );
    let _ = body;
}

#[test]
fn reject_binary_ply_from_real_data_with_a_wrong_vertex_count() {
    let Some(dir) = shared("data", "the shared-data import checks") else {
        return;
    };
    let duck = std::fs::read(dir.join("duck.ply")).unwrap();
    for (to, fixed) in [
        (&b"element vertex 2109"[..], "2108"),
        (b"element vertex 2107", "2108"),
    ] {
        let bad = replace_bytes(&duck, b"element vertex 2108", to);
        let e = err(&bad, "duck.ply");
        let text = e.to_string();
        assert!(
            text.contains(&format!("`element vertex {fixed}`")),
            "{text}"
        );
    }
}

#[test]
fn reject_text_files_in_which_no_point_parses() {
    let nul = vec![0u8; 4096];
    let mut nul_late = b"# header\n".to_vec();
    nul_late.extend_from_slice(&[0; 100]);
    let cases: [(&[u8], &str); 5] = [
        (
            b"hello world\nthis is not a scan\n",
            "line 1: `hello world`",
        ),
        (b"\n\n  \n", "only blank lines"),
        (&nul, "every byte is 0"),
        (&nul_late, "NUL bytes (the first at byte 9"),
        (b"%PDF-1.4 binary \xff\n", "not text"),
    ];
    for name in ["a.xyz", "a.txt", "a.pts", "a.csv", "a.obj"] {
        for (bytes, needle) in cases {
            let e = match read_scan_bytes(bytes, Path::new(name)) {
                Ok(scan) => panic!(
                    "{name} {needle}: read as {} points",
                    scan.cloud.points.len()
                ),
                Err(e) => e,
            };
            let text = e.to_string();
            assert!(text.starts_with(name), "{text}");
            assert!(text.contains(needle), "{name}: {text}");
            let _ = err(bytes, name);
        }
    }
    // The .xyz reader also says when the only line was read as column names or a count.
    let e = read_scan_bytes(b"x,y,z\n", Path::new("a.csv")).unwrap_err();
    assert!(e.to_string().contains("read as column names"), "{e}");
    let e = read_scan_bytes(b"0\n", Path::new("a.pts")).unwrap_err();
    assert!(e.to_string().contains("states 0 points"), "{e}");
    // A .xyz file of 0 characters (bytes `0`): one number, a point count of 0.
    let e = read_scan_bytes(b"0000000000", Path::new("a.xyz")).unwrap_err();
    assert!(matches!(e, ImportError::NoPointFound { .. }), "{e}");
}

#[test]
fn reject_obj_normal_index_out_of_range() {
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//5 3//1\n";
    let e = err(obj.as_bytes(), "vn.obj");
    match &e {
        ImportError::Malformed {
            line: 5, message, ..
        } => {
            assert!(message.contains("normal index 5"), "{e}");
            assert!(message.contains("1 `vn` line"), "{e}");
        }
        other => panic!("{other}"),
    }
    // A texture index past the `vt` lines, and a normal index defined later, are the same.
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/2 2/1 3/1\n";
    assert!(matches!(
        err(obj.as_bytes(), "vt.obj"),
        ImportError::Malformed { line: 5, .. }
    ));
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//1 2//1 3//1\nvn 0 0 1\n";
    assert!(import_bytes(obj.as_bytes(), Path::new("later.obj"))
        .unwrap()
        .normals
        .is_some());
}

#[test]
fn reject_obj_corner_with_too_many_slash_fields() {
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n\nf 1/1/1 2/1/1 1/2/3/4\n";
    let e = err(obj.as_bytes(), "slash.obj");
    match &e {
        ImportError::Malformed {
            line: 7, message, ..
        } => {
            assert!(message.contains("`1/2/3/4` has 4"), "{e}")
        }
        other => panic!("{other}"),
    }
}

#[test]
fn reject_ply_faces_with_fewer_than_three_corners() {
    // No file in ../shared/data has one (checked), so the reader need not skip them.
    for (faces, corners) in [
        (vec![vec![0, 1, 2], vec![4, 3]], 2),
        (vec![vec![0, 1, 2], vec![]], 0),
    ] {
        for encoding in [
            Encoding::Ascii,
            Encoding::BinaryLittleEndian,
            Encoding::BinaryBigEndian,
        ] {
            let ply = odd_ply(encoding, &ODD_POINTS, &faces);
            let e = err(&ply, "short.ply");
            let text = e.to_string();
            assert!(
                text.contains(&format!("face 1 has {corners} corner")),
                "{text}"
            );
            match e {
                ImportError::Malformed { line, .. } => assert_eq!(line, 22, "{text}"),
                ImportError::BadBinary { entry: 1, .. } => {}
                other => panic!("{other}"),
            }
        }
    }
}

#[test]
fn reject_ascii_stl_facet_with_four_vertices() {
    let quad = STL_ASCII.replacen("  vertex 1 1 0\n", "  vertex 1 1 0\n  vertex 0 1 0\n", 1);
    let e = err(quad.as_bytes(), "quad.stl");
    match &e {
        ImportError::Malformed {
            line: 7, message, ..
        } => {
            assert!(message.contains("fourth `vertex`"), "{e}")
        }
        other => panic!("{other}"),
    }
}

#[test]
fn reject_ascii_stl_content_after_endsolid() {
    // The second facet after an early `endsolid`, with no `solid` line of its own.
    let early = STL_ASCII.replacen("endfacet\nfacet", "endfacet\nendsolid sq\nfacet", 1);
    let e = err(early.as_bytes(), "early.stl");
    match &e {
        ImportError::Malformed {
            line: 10, message, ..
        } => {
            assert!(message.contains("after the `endsolid` of line 9"), "{e}")
        }
        other => panic!("{other}"),
    }
    // Trailing text after the last `endsolid` too.
    let junk = format!("{STL_ASCII}garbage\n");
    assert!(matches!(
        err(junk.as_bytes(), "junk.stl"),
        ImportError::Malformed { line: 17, .. }
    ));
    // A second solid is legitimate (multi-solid ascii STL), and blank lines after the end too.
    let two = STL_ASCII.replacen(
        "endfacet\nfacet",
        "endfacet\nendsolid sq\n\nsolid second\nfacet",
        1,
    ) + "\n\n";
    let cloud = import_bytes(two.as_bytes(), Path::new("two.stl")).unwrap();
    assert_eq!(cloud.points, SQUARE.to_vec());
    assert_eq!(cloud.triangles, vec![[0, 1, 2], [0, 2, 3]]);
}

#[test]
fn pts_extra_columns_are_named_in_the_notices() {
    // The .pts layout's intensity and colour are kept, so nothing is left unread.
    let pts = b"2\n0 0 0 10 255 0 0\n1 0 0 12 0 255 0\n";
    let scan = read_scan_bytes(pts, Path::new("scan.pts")).unwrap();
    assert_eq!(scan.cloud.points.len(), 2);
    assert!(scan.cloud.normals.is_none());
    assert!(scan.notices.is_empty(), "{:?}", scan.notices);
    let info = scan_info(&scan);
    assert!(info.has_colours && info.has_intensity);
    // Seven unnamed columns in a file of another extension are named as the likely layout.
    let scan = read_scan_bytes(&pts[2..], Path::new("scan.txt")).unwrap();
    let expected = "columns 4 to 7 of each line (often intensity, r, g, b) are not read: the \
                    cloud keeps x y z only";
    assert_eq!(scan.notices, [expected]);
    let info = scan_info(&scan);
    assert_eq!(info.notices, [expected]);
    assert!(!info.has_colours && !info.has_intensity);
    let json = serde_json::to_value(&info).unwrap();
    assert_eq!(json["notices"][0], expected);
    // Column names, when the file has them, name the columns.
    let csv = b"x,y,z,intensity,quality\n0,0,0,1,2\n";
    let scan = read_scan_bytes(csv, Path::new("scan.csv")).unwrap();
    assert_eq!(
        scan.notices,
        [
            "columns 4 to 5 of each line (intensity, quality) are not read: the cloud keeps x y z \
          only"
        ]
    );
    // Six columns in an .xyz stay normals, without a notice.
    let scan = read_scan_bytes(XYZ.as_bytes(), Path::new("n.xyz")).unwrap();
    assert!(scan.cloud.normals.is_some());
    assert!(scan.notices.is_empty());
    // The PLY reader names what it skips as well; a file it keeps whole has no notice.
    let scan = read_scan_bytes(PLY_ASCII.as_bytes(), Path::new("a.ply")).unwrap();
    assert_eq!(
        scan.notices,
        [
            "vertex properties not read: confidence; the cloud keeps x y z and nx ny nz",
            "elements not read: extra (1 entries)"
        ]
    );
    let scan = read_scan_bytes(STL_ASCII.as_bytes(), Path::new("a.stl")).unwrap();
    assert!(scan.notices.is_empty());
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

// ---------------------------------------------------------------------------------------------
// Range grids

/// An ascii PLY range image of the unit sphere seen from a pinhole at (0, 0, 5): `cols` × `rows`
/// rays, each cell holding its sample, except the cells in `holes` (row-major indices). The
/// header and grid follow Stanford's raw scans (`obj_info num_cols`, `range_grid`).
fn sphere_range_ply(cols: usize, rows: usize, holes: &[usize], bad_cell: Option<&str>) -> String {
    let mut points = Vec::new();
    let mut cells = Vec::new();
    for r in 0..rows {
        for c in 0..cols {
            let u = (c as f64 / (cols - 1) as f64 - 0.5) * 0.25;
            let v = (r as f64 / (rows - 1) as f64 - 0.5) * 0.25;
            let l = (u * u + v * v + 1.0).sqrt();
            let d = [u / l, v / l, -1.0 / l];
            // |s + t d| = 1 with s = (0, 0, 5).
            let b = 5.0 * d[2];
            let t = -b - (b * b - 24.0).sqrt();
            if holes.contains(&(r * cols + c)) {
                cells.push("0".to_string());
            } else {
                cells.push(format!("1 {}", points.len()));
                points.push([t * d[0], t * d[1], 5.0 + t * d[2]]);
            }
        }
    }
    if let Some(bad) = bad_cell {
        cells[0] = bad.to_string();
    }
    let mut s = format!(
        "ply\nformat ascii 1.0\nobj_info num_cols {cols}\nobj_info num_rows {rows}\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         element range_grid {}\nproperty list uchar int vertex_indices\nend_header\n",
        points.len(),
        cells.len()
    );
    for p in &points {
        s += &format!("{} {} {}\n", p[0], p[1], p[2]);
    }
    for c in &cells {
        s += c;
        s.push('\n');
    }
    s
}

#[test]
fn range_grid_is_triangulated_facing_the_sensor() {
    let (cols, rows) = (24, 20);
    // A hole of one sample in the middle: the four squares around it keep one triangle each.
    let hole = 10 * cols + 12;
    let text = sphere_range_ply(cols, rows, &[hole], None);
    let scan = read_scan_bytes(text.as_bytes(), Path::new("grid.ply")).unwrap();
    let info = scan.range_grid.as_ref().expect("range grid info");
    assert_eq!(
        (info.cols, info.rows, info.samples),
        (cols, rows, cols * rows - 1)
    );
    assert_eq!(info.squares, (cols - 1) * (rows - 1));
    // Two triangles per full square, one per square with three samples, none cut (the cap is
    // seen within 60 degrees of the rays, all spacings alike).
    assert_eq!(info.triangles, 2 * info.squares - 4);
    assert_eq!(info.cut_long_edges + info.cut_grazing, 0);
    let sensor = info.sensor.expect("sensor");
    let err = ((sensor[0]).powi(2) + sensor[1].powi(2) + (sensor[2] - 5.0).powi(2)).sqrt();
    assert!(err < 0.05, "sensor {sensor:?}");
    let cloud = &scan.cloud;
    assert_eq!(cloud.triangles.len(), info.triangles);
    assert_eq!(cloud.range.as_ref().unwrap().sensor, Some(sensor));
    for t in &cloud.triangles {
        let [a, b, c] = t.map(|v| cloud.points[v as usize]);
        let n = [
            (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1]),
            (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2]),
            (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]),
        ];
        // Facing the sensor at +z, which on the sphere is outward.
        assert!(n[0] * a[0] + n[1] * a[1] + n[2] * a[2] > 0.0);
    }
    let notices = scan.notices.join("\n");
    assert!(
        notices.contains("range_grid 24 x 20 triangulated"),
        "{notices}"
    );
    assert!(!notices.contains("elements not read"), "{notices}");
    let shown = serde_json::to_value(scan_info(&scan)).unwrap();
    assert_eq!(shown["range_grid"]["triangles"], info.triangles);
}

#[test]
fn range_grid_cell_with_two_indices_is_an_error_naming_the_line() {
    let text = sphere_range_ply(6, 5, &[], Some("2 0 1"));
    let err = read_scan_bytes(text.as_bytes(), Path::new("grid.ply")).unwrap_err();
    let msg = err.to_string();
    // 4 header lines before the vertices + 30 vertices + end of header block (11 lines).
    assert!(msg.contains("grid.ply:42"), "{msg}");
    assert!(msg.contains("holds 2 vertex indices"), "{msg}");
}

// ---------------------------------------------------------------------------------------------
// LAS and LAZ, written by the `las` crate's own writer

/// A sphere of `n` points (radius 10 about a UTM-like centre) as `las` points with colour,
/// intensity and GPS time (point format 3).
fn las_sphere(n: usize) -> Vec<las::Point> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let t = golden * i as f64;
            las::Point {
                x: 500_123.25 + 10.0 * r * t.cos(),
                y: 4_000_456.5 + 10.0 * r * t.sin(),
                z: 101.75 + 10.0 * z,
                intensity: (i % 4096) as u16,
                color: Some(las::Color::new((i * 21 % 65536) as u16, 32768, 65535)),
                gps_time: Some(i as f64),
                ..Default::default()
            }
        })
        .collect()
}

/// Writes `points` to `path` (LAZ when it ends in .laz) with a 1 mm scale and large offsets.
fn write_las(path: &Path, points: &[las::Point]) {
    let mut builder = las::Builder::from((1, 2));
    builder.point_format = las::point::Format::new(3).unwrap();
    builder.point_format.is_compressed = path.extension().is_some_and(|e| e == "laz");
    let t = |offset| las::Transform {
        scale: 0.001,
        offset,
    };
    builder.transforms = las::Vector {
        x: t(500_000.0),
        y: t(4_000_000.0),
        z: t(0.0),
    };
    let mut writer = las::Writer::from_path(path, builder.into_header().unwrap()).unwrap();
    for p in points {
        writer.write_point(p.clone()).unwrap();
    }
    writer.close().unwrap();
}

#[test]
fn las_and_laz_from_the_las_writer_import_exactly_with_colour_and_intensity() {
    let dir = tempfile::tempdir().unwrap();
    let points = las_sphere(3000);
    for (name, format) in [("s.las", ScanFormat::Las), ("s.laz", ScanFormat::Laz)] {
        let path = dir.path().join(name);
        write_las(&path, &points);
        let scan = read_scan(&path).unwrap();
        assert_eq!(scan.format, format);
        let cloud = &scan.cloud;
        assert_eq!(cloud.points.len(), points.len());
        // The stored integers times the scale plus the offset: exactly what the las crate's own
        // reader gives, and within half the scale of what was written.
        let mut reader = las::Reader::from_path(&path).unwrap();
        let expected: Vec<[f64; 3]> = reader
            .read_all()
            .unwrap()
            .points()
            .map(|p| p.map(|p| [p.x, p.y, p.z]).unwrap())
            .collect();
        assert_eq!(cloud.points, expected);
        for (p, q) in cloud.points.iter().zip(&points) {
            for (a, b) in p.iter().zip([q.x, q.y, q.z]) {
                assert!((a - b).abs() <= 0.0005 + 1e-9, "{a} vs {b}");
            }
        }
        let colours = cloud.colours.as_ref().unwrap();
        let intensity = cloud.intensity.as_ref().unwrap();
        for (i, q) in points.iter().enumerate() {
            let c = q.color.unwrap();
            assert_eq!(colours[i], [c.red, c.green, c.blue]);
            assert_eq!(intensity[i], f32::from(q.intensity));
        }
        let info = scan_info(&scan);
        assert!(info.has_colours && info.has_intensity && !info.has_normals);
        assert_eq!(info.format, format.as_str());
        // The CLI reports the same.
        let out = crate::fixtures::bin()
            .args(["info", "--json"])
            .arg(&path)
            .output()
            .unwrap();
        assert!(out.status.success());
        let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(json["points"], 3000);
        assert_eq!(json["has_colours"], true);
        assert_eq!(json["bbox_min"][0], info.bbox_min[0]);
    }
    // A run meshes the LAZ file: normals are estimated, the mesh lies on the sphere.
    let out = dir.path().join("out");
    crate::fixtures::run_ok(
        &dir.path().join("s.laz"),
        &out,
        &["-q", "--no-cache", "--formats", "ply,json"],
    );
    let report = crate::fixtures::read_report(&out);
    assert_eq!(report["stages"][0]["figures"]["points"], 3000);
    assert_eq!(report["mesh"]["watertight"], true);
}

#[test]
fn unreadable_las_files_name_the_file_and_write_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.las");
    write_las(&good, &las_sphere(100));
    let bytes = std::fs::read(&good).unwrap();
    // Cut in the middle of the point records.
    let e = err(&bytes[..bytes.len() - 50], "cut.las");
    assert!(matches!(e, ImportError::Truncated { .. }), "{e}");
    assert!(e.to_string().contains("declares 100 point records"), "{e}");
    // Not a LAS file at all, under a LAS name.
    let e = err(b"hello, not a las file, only some words", "words.laz");
    assert!(e.to_string().contains("export the scan again"), "{e}");
    // The CLI: exit code 1, the file named, no output files.
    let cut = dir.path().join("cut.las");
    std::fs::write(&cut, &bytes[..bytes.len() - 50]).unwrap();
    let out = dir.path().join("out");
    let done = crate::fixtures::bin()
        .arg("run")
        .arg(&cut)
        .arg("-o")
        .arg(&out)
        .arg("--no-cache")
        .output()
        .unwrap();
    assert_eq!(done.status.code(), Some(1));
    let stderr = crate::fixtures::stderr_of(&done);
    assert!(
        stderr.contains("cut.las") && stderr.contains("truncated"),
        "{stderr}"
    );
    let written = std::fs::read_dir(&out).map_or(0, |d| d.count());
    assert_eq!(written, 0, "no partial output");
}

/// laspy (with its lazrs backend) writes a LAS and a LAZ file; `tools/validate/las.py` runs
/// `stablesurf info` and `stablesurf run` on them and checks the counts, the bounding box to
/// the scale, colour and intensity, and that the mesh lies on the sphere it wrote.
#[test]
fn las_and_laz_written_by_laspy_read_and_mesh() {
    let Some(command) = crate::export::validator("las") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let binary = assert_cmd::cargo::cargo_bin("stablesurf");
    let lines = crate::export::run(command, &[&binary, dir.path()]);
    assert_eq!(lines.len(), 2, "{lines:?}");
    for (line, format) in lines.iter().zip(["las", "laz"]) {
        assert_eq!(line["format"], format);
        assert_eq!(line["points"], 3000);
    }
}

/// pye57 (libE57Format, the reference E57 library) writes a sphere as four scans, each in its
/// scanner's frame with its pose; `tools/validate/e57.py` checks `info`'s count and bounding box
/// (the poses applied), and that `run` makes one watertight mesh on the sphere (every normal
/// turned towards its own scanner).
#[test]
fn e57_written_by_pye57_reads_with_its_poses_and_meshes() {
    let Some(command) = crate::export::validator("e57") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let binary = assert_cmd::cargo::cargo_bin("stablesurf");
    let lines = crate::export::run(command, &[&binary, dir.path()]);
    assert_eq!(lines.len(), 1, "{lines:?}");
    let line = &lines[0];
    assert_eq!(line["format"], "e57");
    assert_eq!(line["scans"], 4);
    assert_eq!(line["watertight"], true);
}

// ---------------------------------------------------------------------------------------------
// E57, written by the `e57` crate's own writer

/// The rotation matrix of the unit quaternion (w, x, y, z).
fn rotation(q: [f64; 4]) -> [[f64; 3]; 3] {
    crate::fixtures::quaternion_rotation(q[0], q[1], q[2], q[3])
}

/// One scan to write: its points in the common frame, its pose's quaternion (w, x, y, z) and
/// its scanner's position (the pose's translation).
type E57Scan = (Vec<[f64; 3]>, [f64; 4], [f64; 3]);

/// Writes `path`: one scan per [`E57Scan`], each stored in its own frame
/// (p_local = Rᵀ(p − sensor)) with the pose that moves it back, and with colour and intensity.
fn write_e57(path: &Path, scans: &[E57Scan]) {
    use e57::{
        Quaternion, Record, RecordDataType, RecordName, RecordValue, Transform, Translation,
    };
    let mut writer = e57::E57Writer::from_file(path, "test-file").unwrap();
    for (index, (points, q, sensor)) in scans.iter().enumerate() {
        let prototype = vec![
            Record::CARTESIAN_X_F64,
            Record::CARTESIAN_Y_F64,
            Record::CARTESIAN_Z_F64,
            Record {
                name: RecordName::ColorRed,
                data_type: RecordDataType::U8,
            },
            Record {
                name: RecordName::ColorGreen,
                data_type: RecordDataType::U8,
            },
            Record {
                name: RecordName::ColorBlue,
                data_type: RecordDataType::U8,
            },
            Record {
                name: RecordName::Intensity,
                data_type: RecordDataType::F32,
            },
        ];
        let mut scan = writer
            .add_pointcloud(&format!("scan-{index}"), prototype)
            .unwrap();
        scan.set_transform(Some(Transform {
            rotation: Quaternion {
                w: q[0],
                x: q[1],
                y: q[2],
                z: q[3],
            },
            translation: Translation {
                x: sensor[0],
                y: sensor[1],
                z: sensor[2],
            },
        }));
        let r = rotation(*q);
        for (i, p) in points.iter().enumerate() {
            let d = [0, 1, 2].map(|a| p[a] - sensor[a]);
            let local = [0, 1, 2].map(|c| (0..3).map(|a| r[a][c] * d[a]).sum::<f64>());
            scan.add_point(vec![
                RecordValue::Double(local[0]),
                RecordValue::Double(local[1]),
                RecordValue::Double(local[2]),
                RecordValue::Integer(255),
                RecordValue::Integer(index as i64),
                RecordValue::Integer((i % 256) as i64),
                RecordValue::Single(i as f32 * 0.5),
            ])
            .unwrap();
        }
        scan.finalize().unwrap();
    }
    writer.finalize().unwrap();
}

/// Two scans of the inside of a sphere of radius 5 (a room), from two scanners inside it with
/// different poses: the points come back in the common frame, each scan's scanner is its pose's
/// translation, and the normals face each scan's own scanner (inwards), where a cloud without
/// the scanners gets outward normals.
#[test]
fn e57_scans_from_the_e57_writer_come_back_in_the_common_frame_facing_their_scanners() {
    let n = 4000;
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let sphere: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let t = golden * i as f64;
            [5.0 * r * t.cos(), 5.0 * r * t.sin(), 5.0 * z]
        })
        .collect();
    let (a, b): (Vec<[f64; 3]>, Vec<[f64; 3]>) = sphere.iter().partition(|p| p[0] > 0.0);
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let sensors = [[1.0, 0.0, 0.5], [-1.0, 0.5, 0.0]];
    let scans = vec![
        (a.clone(), [h, 0.0, 0.0, h], sensors[0]),
        (b.clone(), [0.5, 0.5, 0.5, 0.5], sensors[1]),
    ];
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("room.e57");
    write_e57(&path, &scans);

    let scan = read_scan(&path).unwrap();
    assert_eq!(scan.format, ScanFormat::E57);
    let cloud = &scan.cloud;
    let expected: Vec<[f64; 3]> = a.iter().chain(&b).copied().collect();
    assert_eq!(cloud.points.len(), n);
    for (p, q) in cloud.points.iter().zip(&expected) {
        for c in 0..3 {
            assert!((p[c] - q[c]).abs() < 1e-9, "{p:?} vs {q:?}");
        }
    }
    let origins = cloud.scans.as_ref().unwrap();
    assert_eq!(origins.len(), 2);
    assert_eq!(
        (origins[0].sensor, origins[0].n_points),
        (sensors[0], a.len())
    );
    assert_eq!(
        (origins[1].sensor, origins[1].n_points),
        (sensors[1], b.len())
    );
    let colours = cloud.colours.as_ref().unwrap();
    assert_eq!(colours[0], [65535, 0, 0]);
    assert_eq!(colours[a.len() + 3], [65535, 257, 3 * 257]);
    assert_eq!(cloud.intensity.as_ref().unwrap()[a.len() + 3], 1.5);
    assert!(scan.notices.is_empty(), "{:?}", scan.notices);

    // Normals face each point's own scanner: inwards, against the outward orientation that the
    // same points get without scanners.
    let params = stablesurf::normals::NormalsParams::default();
    let with = stablesurf::normals::estimate_normals(cloud, &params).unwrap();
    let mut plain = cloud.clone();
    plain.scans = None;
    let without = stablesurf::normals::estimate_normals(&plain, &params).unwrap();
    let dot = |u: &[f64; 3], v: &[f64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    for (i, (p, nrm)) in with
        .cloud
        .points
        .iter()
        .zip(&with.cloud.normals)
        .enumerate()
    {
        let s = sensors[usize::from(i >= a.len())];
        let to_sensor = [s[0] - p[0], s[1] - p[1], s[2] - p[2]];
        assert!(dot(nrm, &to_sensor) > 0.0, "point {i}");
        assert!(dot(nrm, p) < 0.0, "point {i} faces inwards");
    }
    let outward = without
        .cloud
        .points
        .iter()
        .zip(&without.cloud.normals)
        .filter(|(p, nrm)| dot(nrm, p) > 0.0)
        .count();
    assert_eq!(outward, n, "without scanners the normals point outwards");

    // `stablesurf info` lists the scans.
    let out = crate::fixtures::bin()
        .args(["info", "--json"])
        .arg(&path)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", crate::fixtures::stderr_of(&out));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["format"], "e57");
    assert_eq!(json["points"], n);
    assert_eq!(json["scans"][1]["sensor"][1], 0.5);
    assert_eq!(json["has_colours"], true);
    assert_eq!(json["has_intensity"], true);

    // A cut file is an error that names it.
    let bytes = std::fs::read(&path).unwrap();
    let e = err(&bytes[..bytes.len() / 2], "cut.e57");
    assert!(e.to_string().contains("e57"), "{e}");
}

/// Seeded byte mutations (flips, truncations, overwritten header bytes) of small LAS, LAZ, E57
/// and PCD files never panic their readers or ask for memory the file cannot back: each gives
/// a cloud or an error.
#[test]
fn mutated_las_e57_and_pcd_files_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut files: Vec<(&str, Vec<u8>)> = Vec::new();
    for name in ["m.las", "m.laz"] {
        let path = dir.path().join(name);
        write_las(&path, &las_sphere(60));
        files.push((name, std::fs::read(&path).unwrap()));
    }
    let e57 = dir.path().join("m.e57");
    let pts: Vec<[f64; 3]> = (0..40).map(|i| [i as f64, 1.0, 2.0]).collect();
    write_e57(&e57, &[(pts, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 3.0])]);
    files.push(("m.e57", std::fs::read(&e57).unwrap()));
    let mut pcd = b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F U\n\
                    COUNT 1 1 1 1\nWIDTH 30\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 30\n\
                    DATA binary\n"
        .to_vec();
    for i in 0..30u32 {
        for c in [i as f32, 1.0, 2.0] {
            pcd.extend_from_slice(&c.to_le_bytes());
        }
        pcd.extend_from_slice(&(i * 1000).to_le_bytes());
    }
    files.push(("m.pcd", pcd));
    let mut rng = crate::fixtures::Rng(57);
    for (name, original) in &files {
        for case in 0..300 {
            let mut bytes = original.clone();
            match case % 3 {
                0 => bytes.truncate(rng.below(bytes.len())),
                1 => {
                    // Header bytes, where the counts and offsets are.
                    for _ in 0..1 + rng.below(3) {
                        let at = rng.below(bytes.len().min(400));
                        bytes[at] = rng.byte();
                    }
                }
                _ => {
                    for _ in 0..1 + rng.below(4) {
                        let at = rng.below(bytes.len());
                        bytes[at] ^= 1 << rng.below(8);
                    }
                }
            }
            for format in [ScanFormat::Las, ScanFormat::E57, ScanFormat::PcdBinary] {
                if let Ok(scan) = read_scan_bytes_as(&bytes, Path::new(name), format) {
                    let _ = scan_info(&scan);
                }
            }
            let _ = import_bytes(&bytes, Path::new(name));
        }
    }
}
