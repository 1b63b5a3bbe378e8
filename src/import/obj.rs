//! Stage `import`, Wavefront OBJ reader: OBJ text → [`PointCloud`].
//!
//! Input: the whole file as bytes. Output: one point per `v` line (in file order, never
//! merged), triangles from `f` lines (fan-triangulated polygons), and per-vertex normals when the
//! file's `vn` data maps consistently onto the vertices.
//!
//! Face corners may be `v`, `v/vt`, `v//vn` or `v/vt/vn`; indices are 1-based, and negative
//! indices count back from the last `v` (or `vt`, `vn`) defined so far (Wavefront, *Object Files
//! (.obj)*, Advanced Visualizer manual, appendix B1). A positive index may point forward, but
//! once the file is read every vertex, texture and normal index must name an existing `v`, `vt`
//! or `vn` line; a corner with a fourth slash field, or a face with fewer than three corners, is
//! an error naming the line. Everything else (`g`, `o`, `s`, `usemtl`, `mtllib`, `l`, `p`,
//! unknown keywords) is skipped. A file with no `v` line, or with a NUL byte, is an error that
//! says what the file looks like, not an empty cloud.
//!
//! Normals: OBJ attaches a normal to each face corner, not to a vertex. A vertex gets a normal
//! when every corner that uses it names the same normal vector; the cloud has normals only when
//! every vertex gets one this way. When no corner names a normal and the file has exactly one
//! `vn` per `v` (a point-cloud export), the i-th `vn` belongs to the i-th `v`. In any other case
//! (split normals along hard edges, vertices without a normal) the normals are dropped, since
//! the `normals` stage can estimate them, and a notice says so.
//!
//! Hand-written rather than `tobj`: tobj rebuilds the vertex list of each `o`/`g` group from
//! the faces that use it, so unreferenced vertices vanish and shared ones repeat (counts would
//! not be as stored); its errors carry no line number. It is also slower: `cargo bench --bench
//! import` read max_planck.obj in 12.9 ms here against 18.3 ms with tobj (2 shared cores).

use crate::cloud::PointCloud;
use crate::import::{first_line_quoted, nul_byte, parse_f64, push_fan, ImportError, Lines};

/// Reads an OBJ file; what it reads but does not keep goes to `notices`.
pub(crate) fn read(
    bytes: &[u8],
    path: &str,
    notices: &mut Vec<String>,
) -> Result<PointCloud, ImportError> {
    if let Some(e) = nul_byte(bytes, path, "obj") {
        return Err(e);
    }
    let mut lines = Lines::new(bytes, 1);
    let mut n_vt = 0usize;
    // Per face, the largest 0-based `vt` index its corners name, checked once the file is read.
    let mut face_vt: Vec<Option<u32>> = Vec::new();
    let mut points: Vec<[f64; 3]> = Vec::new();
    let mut vn: Vec<[f64; 3]> = Vec::new();
    let mut triangles = Vec::new();
    // Per triangle corner, the 0-based `vn` index (or u32::MAX when the corner has none).
    let mut corner_normals: Vec<[u32; 3]> = Vec::new();
    let mut any_corner_normal = false;
    let mut polygon: Vec<u32> = Vec::new();
    let mut polygon_normals: Vec<u32> = Vec::new();
    // Per face, the line of its `f` statement, to name it in range errors at the end.
    let mut face_lines: Vec<(usize, usize)> = Vec::new();
    let mut n_faces = 0usize;
    while let Some(line) = lines.next_line(path) {
        let (line_number, text) = line?;
        let malformed = |message: String| ImportError::malformed(path, line_number, message);
        let text = text.split('#').next().unwrap_or("");
        let mut tokens = text.split_ascii_whitespace();
        match tokens.next() {
            Some("v") | Some("vn") => {
                let is_normal = text.trim_start().starts_with("vn");
                let mut xyz = [0.0; 3];
                for c in &mut xyz {
                    let token = tokens.next().ok_or_else(|| {
                        malformed("a `v` or `vn` line needs three numbers x y z".into())
                    })?;
                    *c = parse_f64(token)
                        .ok_or_else(|| malformed(format!("`{token}` is not a number")))?;
                }
                if is_normal {
                    vn.push(xyz);
                } else {
                    points.push(xyz);
                }
            }
            Some("vt") => n_vt += 1,
            Some("f") => {
                polygon.clear();
                polygon_normals.clear();
                let mut max_vt: Option<u32> = None;
                for corner in tokens {
                    let mut parts = corner.split('/');
                    let v = parts.next().unwrap_or("");
                    let vt = parts.next().filter(|s| !s.is_empty());
                    let n = parts.next().filter(|s| !s.is_empty());
                    if parts.next().is_some() {
                        return Err(malformed(format!(
                            "the face corner `{corner}` has {} slash-separated fields; a corner \
                             is v, v/vt, v//vn or v/vt/vn",
                            corner.split('/').count()
                        )));
                    }
                    if let Some(vt) = vt {
                        let t = resolve(vt, n_vt, line_number, "texture", n_faces, path)?;
                        max_vt = max_vt.max(Some(t));
                    }
                    polygon.push(resolve(
                        v,
                        points.len(),
                        line_number,
                        "vertex",
                        n_faces,
                        path,
                    )?);
                    match n {
                        Some(n) => {
                            polygon_normals.push(resolve(
                                n,
                                vn.len(),
                                line_number,
                                "normal",
                                n_faces,
                                path,
                            )?);
                            any_corner_normal = true;
                        }
                        None => polygon_normals.push(u32::MAX),
                    }
                }
                if polygon.len() < 3 {
                    return Err(malformed(format!(
                        "a face needs at least three corners, this one has {}",
                        polygon.len()
                    )));
                }
                let before = triangles.len();
                push_fan(&mut triangles, &polygon);
                push_fan(&mut corner_normals, &polygon_normals);
                face_lines.push((before, line_number));
                face_vt.push(max_vt);
                n_faces += 1;
            }
            _ => {}
        }
    }
    if points.is_empty() {
        let looks = match first_line_quoted(bytes) {
            Some(first) => format!("the first non-blank line is {first}"),
            None => "the file holds only blank lines".to_owned(),
        };
        return Err(ImportError::NoPointFound {
            path: path.to_owned(),
            detail: format!(
                "no `v x y z` line; {looks}; an obj scan needs one `v` line per vertex (if the \
                 file is in another format, give it that format's extension)"
            ),
        });
    }
    // Forward references are legal in the syntax but must exist by the end of the file.
    let n_points = points.len();
    for (face, &(first_triangle, line)) in face_lines.iter().enumerate() {
        let end = face_lines.get(face + 1).map_or(triangles.len(), |f| f.0);
        let out_of_range =
            |what: &str, index: u32, count: usize, keyword: &str| ImportError::Malformed {
                path: path.to_owned(),
                line,
                message: format!(
                    "{what} index {} is out of range: the file has {count} `{keyword}` line(s); \
                     fix the index or remove the {what} from the corner",
                    u64::from(index) + 1
                ),
            };
        if let Some(t) = face_vt.get(face).copied().flatten()
            && t as usize >= n_vt
        {
            return Err(out_of_range("texture", t, n_vt, "vt"));
        }
        for corners in corner_normals.get(first_triangle..end).unwrap_or(&[]) {
            if let Some(&n) = corners
                .iter()
                .find(|&&n| n != u32::MAX && n as usize >= vn.len())
            {
                return Err(out_of_range("normal", n, vn.len(), "vn"));
            }
        }
        for triangle in triangles.get(first_triangle..end).unwrap_or(&[]) {
            if let Some(&index) = triangle.iter().find(|&&i| i as usize >= n_points) {
                return Err(ImportError::IndexOutOfRange {
                    path: path.to_owned(),
                    line: Some(line),
                    face,
                    index: i64::from(index),
                    n_points,
                });
            }
        }
    }
    debug_assert_eq!(face_lines.len(), n_faces);
    let normals = map_normals(
        n_points,
        &vn,
        &triangles,
        &corner_normals,
        any_corner_normal,
    );
    if normals.is_none() && !vn.is_empty() {
        notices.push(format!(
            "the {} `vn` normals are not read: {}, so the `normals` stage estimates normals",
            vn.len(),
            if any_corner_normal {
                "a vertex has different normals at different corners, or none"
            } else {
                "no face corner names one and their count differs from the `v` count"
            }
        ));
    }
    Ok(PointCloud {
        points,
        normals,
        triangles,
        range: None,
        ..Default::default()
    })
}

/// Resolves a 1-based or negative OBJ index against the `count` items defined so far.
/// A positive index may point forward; that is checked once the file is read.
fn resolve(
    token: &str,
    count: usize,
    line: usize,
    what: &str,
    face: usize,
    path: &str,
) -> Result<u32, ImportError> {
    let malformed = |message: String| ImportError::malformed(path, line, message);
    let value: i64 = token
        .parse()
        .map_err(|_| malformed(format!("`{token}` is not a {what} index")))?;
    let resolved = match value {
        0 => {
            return Err(malformed(format!(
                "{what} index 0 is not valid; obj indices start at 1"
            )))
        }
        v if v > 0 => v - 1,
        v => count as i64 + v,
    };
    // u32::MAX marks a corner without a normal, so it is no valid index either.
    u32::try_from(resolved)
        .ok()
        .filter(|&i| i != u32::MAX)
        .ok_or_else(|| match what {
            "vertex" => ImportError::IndexOutOfRange {
                path: path.to_owned(),
                line: Some(line),
                face,
                index: resolved,
                n_points: count,
            },
            _ => malformed(format!(
            "{what} index {value} is out of range: {count} {what}s are defined before this line"
        )),
        })
}

/// Maps per-corner normals to per-vertex normals, as the module docs describe.
fn map_normals(
    n_points: usize,
    vn: &[[f64; 3]],
    triangles: &[[u32; 3]],
    corner_normals: &[[u32; 3]],
    any_corner_normal: bool,
) -> Option<Vec<[f64; 3]>> {
    if !any_corner_normal {
        return (!vn.is_empty() && vn.len() == n_points).then(|| vn.to_vec());
    }
    let mut normals: Vec<Option<[f64; 3]>> = vec![None; n_points];
    for (triangle, corners) in triangles.iter().zip(corner_normals) {
        for (&v, &n) in triangle.iter().zip(corners) {
            let normal = *vn.get(n as usize)?;
            let slot = normals.get_mut(v as usize)?;
            match slot {
                None => *slot = Some(normal),
                Some(existing) if *existing == normal => {}
                Some(_) => return None,
            }
        }
    }
    normals.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corner_forms_and_negative_indices() {
        let text = "# square\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\n\
                    vn 0 0 1\nf 1/1/1 2//1 -2/1/-1 -1//1\n";
        let cloud = read(text.as_bytes(), "t.obj", &mut Vec::new()).unwrap();
        assert_eq!(cloud.points.len(), 4);
        assert_eq!(cloud.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(cloud.normals, Some(vec![[0.0, 0.0, 1.0]; 4]));
    }

    #[test]
    fn split_normals_are_dropped_and_paired_normals_kept() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nvn 0 0 -1\n\
                    f 1//1 2//1 3//1\nf 2//2 4//2 3//2\n";
        assert!(read(text.as_bytes(), "t.obj", &mut Vec::new())
            .unwrap()
            .normals
            .is_none());
        let text = "v 0 0 0\nvn 1 0 0\nv 1 0 0\nvn 0 1 0\n";
        let cloud = read(text.as_bytes(), "t.obj", &mut Vec::new()).unwrap();
        assert_eq!(cloud.normals, Some(vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]));
    }

    #[test]
    fn bad_indices_name_the_line() {
        for (text, line) in [
            ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", 4),
            ("v 0 0 0\nv 1 0\n", 2),
            ("v 0 0 0\nf 1 1\n", 2),
        ] {
            match read(text.as_bytes(), "t.obj", &mut Vec::new()) {
                Err(ImportError::Malformed { line: l, .. }) => assert_eq!(l, line, "{text}"),
                other => panic!("{text}: {other:?}"),
            }
        }
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 -4\n";
        assert!(matches!(
            read(text.as_bytes(), "t.obj", &mut Vec::new()),
            Err(ImportError::IndexOutOfRange {
                line: Some(5),
                face: 0,
                index: -1,
                ..
            })
        ));
        let text = "v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\nf 1 2 4\n";
        match read(text.as_bytes(), "t.obj", &mut Vec::new()) {
            Err(
                e @ ImportError::IndexOutOfRange {
                    line: Some(5),
                    face: 1,
                    index: 3,
                    ..
                },
            ) => {
                assert!(
                    e.to_string()
                        .starts_with("t.obj:5: face 1 refers to vertex 3"),
                    "{e}"
                )
            }
            other => panic!("{other:?}"),
        }
    }
}
