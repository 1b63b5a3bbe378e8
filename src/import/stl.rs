//! Stage `import`, STL reader: binary or ascii STL → [`PointCloud`].
//!
//! Input: the whole file as bytes. Output: a cloud whose points are the triangle corners welded
//! by exact position (an STL file repeats each shared corner once per triangle), numbered in
//! order of first appearance, and one triangle per facet. STL's per-facet normals are not
//! per-point normals, so the cloud has none.
//!
//! Binary STL: an 80-byte header, a little-endian u32 triangle count n, then n records of 50
//! bytes (normal, three corners as f32 x/y/z, a u16 attribute); the file is exactly 84 + 50·n
//! bytes. Ascii STL: `solid NAME`, then per facet `facet normal nx ny nz` / `outer loop` /
//! three `vertex x y z` / `endloop` / `endfacet`, and `endsolid`; several solids may follow one
//! another. Welding keys are the coordinate bits with -0.0 folded onto 0.0.
//!
//! The ascii reader checks that grammar line by line: a facet has exactly three `vertex` lines
//! (STL facets are triangles; a fourth corner is an error naming its line, not a fan), each
//! keyword comes where the grammar puts it, and after an `endsolid` only blank lines or the
//! `solid` line of a further solid may follow (multi-solid files are legitimate; anything else
//! after `endsolid`, such as facets of a solid whose `solid` line is missing, is an error naming
//! the line).
//!
//! Hand-written rather than `stl_io`: the reader is short, works on the byte slice the other
//! readers take, and names the facet or line at fault in its errors.

use std::collections::HashMap;

use crate::cloud::PointCloud;
use crate::import::{parse_f64, position_key, ImportError, Lines};

/// Size of the binary header plus the triangle count.
const HEADER: usize = 84;
/// Size of one binary triangle record.
const RECORD: usize = 50;

/// The triangle count a binary STL header states, if the file is long enough to hold one.
fn stated_count(bytes: &[u8]) -> Option<u32> {
    let raw: [u8; 4] = bytes.get(80..84)?.try_into().ok()?;
    Some(u32::from_le_bytes(raw))
}

/// Whether the file is exactly as long as a binary STL with the count it states.
pub(crate) fn is_binary_size(bytes: &[u8]) -> bool {
    stated_count(bytes)
        .is_some_and(|n| HEADER as u64 + RECORD as u64 * u64::from(n) == bytes.len() as u64)
}

/// Whether the file starts like an ascii STL: `solid` and, within the first kilobyte, `facet`
/// or `endsolid` (a binary header that starts with `solid` has neither, as text).
pub(crate) fn looks_ascii(bytes: &[u8]) -> bool {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    let text = &bytes[start..];
    if !text.starts_with(b"solid") {
        return false;
    }
    let head = &text[..text.len().min(1024)];
    head.windows(5).any(|w| w == b"facet") || head.windows(8).any(|w| w == b"endsolid")
}

/// Welds corners into points by exact position.
#[derive(Default)]
struct Welder {
    points: Vec<[f64; 3]>,
    index: HashMap<[u64; 3], u32>,
}

impl Welder {
    fn with_capacity(n: usize) -> Welder {
        Welder {
            points: Vec::with_capacity(n),
            index: HashMap::with_capacity(n),
        }
    }

    /// The point index of `p`, added if new; `None` past u32::MAX points.
    fn weld(&mut self, p: [f64; 3]) -> Option<u32> {
        let next = u32::try_from(self.points.len()).ok()?;
        let index = *self.index.entry(position_key(p)).or_insert(next);
        if index == next {
            self.points.push(p);
        }
        Some(index)
    }

    /// The welded corners and `triangles` over them: the cloud an STL gives (no per-point
    /// normals; see the module docs).
    fn into_cloud(self, triangles: Vec<[u32; 3]>) -> PointCloud {
        PointCloud {
            points: self.points,
            triangles,
            ..Default::default()
        }
    }
}

fn too_many(path: &str) -> ImportError {
    ImportError::BadLayout {
        path: path.to_owned(),
        message: "the stl has more than 2^32 distinct corners; split the file".to_owned(),
    }
}

/// Reads a binary STL.
pub(crate) fn read_binary(bytes: &[u8], path: &str) -> Result<PointCloud, ImportError> {
    let Some(stated) = stated_count(bytes) else {
        return Err(ImportError::Truncated {
            path: path.to_owned(),
            detail: format!(
                "a binary stl needs an 84-byte header and the file has {} bytes",
                bytes.len()
            ),
        });
    };
    let body = &bytes[HEADER..];
    let whole = (body.len() / RECORD) as u64;
    if u64::from(stated) * RECORD as u64 != body.len() as u64 {
        // Fewer bytes than the count needs: cut short. More (or a ragged tail): a wrong count.
        return Err(if whole < u64::from(stated) {
            ImportError::Truncated {
                path: path.to_owned(),
                detail: format!(
                    "the header states {stated} triangles ({} bytes) but the file has {} bytes",
                    HEADER as u64 + u64::from(stated) * RECORD as u64,
                    bytes.len()
                ),
            }
        } else {
            ImportError::HeaderCountMismatch {
                path: path.to_owned(),
                what: "triangles".to_owned(),
                declared: u64::from(stated),
                found: whole,
            }
        });
    }
    let mut welder = Welder::with_capacity(body.len() / RECORD / 2);
    let mut triangles = Vec::with_capacity(body.len() / RECORD);
    for record in body.chunks_exact(RECORD) {
        let mut triangle = [0u32; 3];
        for (corner, slot) in triangle.iter_mut().enumerate() {
            let mut p = [0.0; 3];
            for (axis, c) in p.iter_mut().enumerate() {
                let at = 12 + 12 * corner + 4 * axis;
                let raw: [u8; 4] = record
                    .get(at..at + 4)
                    .and_then(|b| b.try_into().ok())
                    .unwrap_or([0; 4]);
                *c = f64::from(f32::from_le_bytes(raw));
            }
            *slot = welder.weld(p).ok_or_else(|| too_many(path))?;
        }
        triangles.push(triangle);
    }
    Ok(welder.into_cloud(triangles))
}

/// Where the ascii reader is in the STL grammar.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    /// Before the first `solid` or after an `endsolid`.
    Outside,
    /// Inside `solid`, between facets.
    Solid,
    /// After `facet normal …`, before `outer loop`.
    Facet,
    /// Inside `outer loop`, with this many `vertex` lines so far.
    Loop(usize),
    /// After `endloop`, before `endfacet`.
    LoopDone,
}

/// Reads an ascii STL: each facet one triangle, checked against the grammar in the module docs.
pub(crate) fn read_ascii(bytes: &[u8], path: &str) -> Result<PointCloud, ImportError> {
    let mut lines = Lines::new(bytes, 1);
    let mut welder = Welder::default();
    let mut triangles = Vec::new();
    let mut triangle = [0u32; 3];
    let mut state = State::Outside;
    let mut last_line = 0;
    // The line of the last `endsolid`, to name it when something other than `solid` follows.
    let mut endsolid_line: Option<usize> = None;
    while let Some(line) = lines.next_line(path) {
        let (line_number, text) = line?;
        let malformed = |message: String| ImportError::malformed(path, line_number, message);
        let mut tokens = text.split_ascii_whitespace();
        let Some(keyword) = tokens.next() else {
            continue;
        };
        last_line = line_number;
        let expected = match state {
            State::Outside => "`solid NAME`",
            State::Solid => "`facet normal nx ny nz` or `endsolid`",
            State::Facet => "`outer loop`",
            State::Loop(n) if n < 3 => "`vertex x y z`",
            State::Loop(_) => "`endloop` (a facet has exactly three vertices)",
            State::LoopDone => "`endfacet`",
        };
        state = match (state, keyword) {
            (State::Outside, "solid") => State::Solid,
            (State::Solid, "facet") => State::Facet,
            (State::Solid, "endsolid") => {
                endsolid_line = Some(line_number);
                State::Outside
            }
            (State::Facet, "outer") if tokens.next() == Some("loop") => State::Loop(0),
            (State::Loop(n), "vertex") if n < 3 => {
                let mut p = [0.0; 3];
                for c in &mut p {
                    let token = tokens
                        .next()
                        .ok_or_else(|| malformed("a `vertex` line needs x y z".into()))?;
                    *c = parse_f64(token)
                        .ok_or_else(|| malformed(format!("`{token}` is not a number")))?;
                }
                triangle[n] = welder.weld(p).ok_or_else(|| too_many(path))?;
                State::Loop(n + 1)
            }
            (State::Loop(3), "endloop") => {
                triangles.push(triangle);
                State::LoopDone
            }
            (State::Loop(n), "endloop") => {
                return Err(malformed(format!(
                    "a facet needs three `vertex` lines, this one has {n}; give each facet \
                     exactly three corners"
                )))
            }
            (State::Loop(_), "vertex") => {
                return Err(malformed(
                    "a fourth `vertex` line in one facet; stl facets are triangles: split the \
                     polygon into facets of three corners"
                        .into(),
                ))
            }
            (State::LoopDone, "endfacet") => State::Solid,
            (State::Outside, other) => {
                let after = match endsolid_line {
                    Some(l) => format!("after the `endsolid` of line {l}"),
                    None => "before any `solid` line".to_owned(),
                };
                return Err(malformed(format!(
                    "`{other}` {after}; only another solid (`solid NAME` … `endsolid`) may \
                     follow, so remove the line or add the missing `solid` line"
                )));
            }
            (_, other) => {
                return Err(malformed(format!(
                    "unexpected `{other}` where the ascii stl grammar expects {expected}"
                )))
            }
        };
    }
    if state != State::Outside || endsolid_line.is_none() {
        return Err(ImportError::Truncated {
            path: path.to_owned(),
            detail: format!(
                "the text ends on line {last_line} {}",
                match state {
                    State::Outside => "before any `solid` line",
                    State::Solid => "inside a solid (no `endsolid`)",
                    _ => "inside a facet",
                }
            ),
        });
    }
    Ok(welder.into_cloud(triangles))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn binary(triangles: &[[[f32; 3]; 3]]) -> Vec<u8> {
        let mut b = b"solid but binary".to_vec();
        b.resize(80, 0);
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

    #[test]
    fn binary_corners_are_welded() {
        let a = [0.0, 0.0, 0.0];
        let b = [1.0, 0.0, 0.0];
        let c = [0.0, 1.0, 0.0];
        let d = [1.0, 1.0, -0.0];
        let bytes = binary(&[[a, b, c], [b, d, c]]);
        assert!(is_binary_size(&bytes));
        let cloud = read_binary(&bytes, "t.stl").unwrap();
        assert_eq!(cloud.points.len(), 4);
        assert_eq!(cloud.triangles, vec![[0, 1, 2], [1, 3, 2]]);
    }

    #[test]
    fn binary_size_errors() {
        let bytes = binary(&[[[0.0; 3]; 3]; 2]);
        assert!(matches!(
            read_binary(&bytes[..bytes.len() - 1], "t.stl"),
            Err(ImportError::Truncated { .. })
        ));
        let mut longer = bytes.clone();
        longer.extend_from_slice(&[0; 50]);
        assert!(matches!(
            read_binary(&longer, "t.stl"),
            Err(ImportError::HeaderCountMismatch {
                declared: 2,
                found: 3,
                ..
            })
        ));
        assert!(matches!(
            read_binary(b"short", "t.stl"),
            Err(ImportError::Truncated { .. })
        ));
    }

    #[test]
    fn ascii_welds_and_reports_lines() {
        let text = "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n\
                    vertex 0 1 0\nendloop\nendfacet\nfacet normal 0 0 1\nouter loop\n\
                    vertex 1 0 0\nvertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid s\n";
        assert!(looks_ascii(text.as_bytes()));
        let cloud = read_ascii(text.as_bytes(), "t.stl").unwrap();
        assert_eq!(cloud.points.len(), 4);
        assert_eq!(cloud.triangles, vec![[0, 1, 2], [1, 3, 2]]);
        let bad = text.replace("vertex 1 1 0", "vertex 1 x 0");
        assert!(matches!(
            read_ascii(bad.as_bytes(), "t.stl"),
            Err(ImportError::Malformed { line: 12, .. })
        ));
        let cut = &text[..text.find("endloop\nendfacet\nendsolid").unwrap()];
        assert!(matches!(
            read_ascii(cut.as_bytes(), "t.stl"),
            Err(ImportError::Truncated { .. })
        ));
    }
}
