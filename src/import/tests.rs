//! Unit tests of `import`.

use super::*;

#[test]
fn fan_triangulates_polygons_and_skips_short_ones() {
    let mut t = Vec::new();
    push_fan(&mut t, &[0, 1, 2, 3, 4]);
    assert_eq!(t, vec![[0, 1, 2], [0, 2, 3], [0, 3, 4]]);
    push_fan(&mut t, &[7, 8]);
    push_fan(&mut t, &[]);
    assert_eq!(t.len(), 3);
}

#[test]
fn position_key_folds_negative_zero() {
    assert_eq!(
        position_key([0.0, -0.0, 1.0]),
        position_key([-0.0, 0.0, 1.0])
    );
    assert_ne!(
        position_key([0.0, 0.0, 1.0]),
        position_key([0.0, 0.0, -1.0])
    );
}

#[test]
fn detection_uses_content_before_extension() {
    let p = Path::new("scan.obj");
    assert_eq!(
        detect_format(b"ply\nformat ascii 1.0\n", p),
        Some(Detected::Ply)
    );
    // A binary STL whose header starts with "solid".
    let mut stl = b"solid binary header".to_vec();
    stl.resize(80, b' ');
    stl.extend_from_slice(&1u32.to_le_bytes());
    stl.resize(134, 0);
    assert_eq!(detect_format(&stl, p), Some(Detected::StlBinary));
    let ascii = b"solid x\nfacet normal 0 0 1\nouter loop\n";
    assert_eq!(detect_format(ascii, p), Some(Detected::StlAscii));
    assert_eq!(
        detect_format(b"v 0 0 0\n", Path::new("a")),
        Some(Detected::Obj)
    );
    assert_eq!(
        detect_format(b"# c\n1,2,3\n", Path::new("a")),
        Some(Detected::Xyz)
    );
    assert_eq!(detect_format(b"\x00\x01garbage", Path::new("a.bin")), None);
    assert_eq!(
        detect_format(b"1 2 3\n", Path::new("a.PTS")),
        Some(Detected::Xyz)
    );
}

#[test]
fn every_scan_extension_selects_a_reader() {
    // Text with no signature and no OBJ or number lines: only the extension can decide.
    for extension in SCAN_EXTENSIONS {
        let path = format!("scan.{}", extension.to_ascii_uppercase());
        assert!(detect_format(b"\x00", Path::new(&path)).is_some(), "{path}");
        assert!(has_scan_extension(Path::new(&path)), "{path}");
    }
    assert_eq!(detect_format(b"\x00", Path::new("scan.md")), None);
}

#[test]
fn lines_strip_carriage_returns_and_count() {
    let mut lines = Lines::new(b"a\r\nb\n\nc", 1);
    let mut got = Vec::new();
    while let Some(l) = lines.next_line("f") {
        got.push(l.unwrap());
    }
    assert_eq!(got, vec![(1, "a"), (2, "b"), (3, ""), (4, "c")]);
}

#[test]
fn validate_reports_each_problem() {
    let ok = PointCloud {
        points: vec![[0.0; 3]; 3],
        normals: None,
        triangles: vec![[0, 1, 2]],
        range: None,
        ..Default::default()
    };
    assert!(validate(&ok, "f").is_ok());
    let mut bad = ok.clone();
    bad.triangles.push([0, 1, 3]);
    assert!(matches!(
        validate(&bad, "f"),
        Err(ImportError::IndexOutOfRange {
            face: 1,
            index: 3,
            n_points: 3,
            ..
        })
    ));
    let mut bad = ok.clone();
    bad.normals = Some(vec![[0.0; 3]; 2]);
    assert!(matches!(
        validate(&bad, "f"),
        Err(ImportError::NormalCountMismatch { .. })
    ));
    let empty = PointCloud::default();
    assert!(matches!(
        validate(&empty, "f"),
        Err(ImportError::NoPoints { .. })
    ));
}
