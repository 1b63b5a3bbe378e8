//! Stage `import`, registration files: a Stanford `.conf` → the scans it lists and their poses.
//!
//! Input: the bytes of a `.conf` file and its path (the scans' names are relative to its
//! folder). Output: one [`View`] per `bmesh` line, in file order.
//!
//! The format (Stanford 3D Scanning Repository, e.g. the bunny's `bun.conf`): one record per
//! line, `camera tx ty tz qx qy qz qw` (a viewing camera: ignored) or
//! `bmesh FILE tx ty tz qx qy qz qw` (a scan and its pose). Blank lines and lines starting with
//! `#` are skipped; anything else is an error naming the line. A scan point p goes to the common
//! frame as R(q)ᵀ·p + t, with R(q) the rotation of the unit quaternion (qx, qy, qz, qw)
//! (checked on the bunny's scans against its zippered mesh: the other reading misses it by
//! centimetres).

use std::path::{Path, PathBuf};

use crate::import::ImportError;
use crate::merge::Pose;

/// One scan of a registration file.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    /// The scan file, joined to the `.conf`'s folder.
    pub path: PathBuf,
    /// Its pose: scan coordinates → common frame.
    pub pose: Pose,
}

/// Whether `path` names a registration file (extension `.conf`, any case).
pub fn is_conf(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("conf"))
}

/// Parses a `.conf` file's bytes; `path` names it in errors and gives the scans' folder.
///
/// ```
/// use std::path::Path;
/// use stablesurf::import::conf::read_conf;
/// let text = b"camera 0 0 1 0 0 0 1\n# two scans\nbmesh a.ply 0 0 0 0 0 0 1\nbmesh b.ply 1 2 3 0 0 0.7071068 0.7071068\n";
/// let views = read_conf(text, Path::new("scans/all.conf")).unwrap();
/// assert_eq!(views.len(), 2);
/// assert_eq!(views[1].path, Path::new("scans/b.ply"));
/// assert_eq!(views[1].pose.translation, [1.0, 2.0, 3.0]);
/// ```
///
/// # Errors
/// [`ImportError::Malformed`] naming the line for a record that is not `camera` or `bmesh`
/// with seven finite numbers (a zero quaternion included), or text that is not UTF-8;
/// [`ImportError::NoPointFound`] when no line is a `bmesh`.
pub fn read_conf(bytes: &[u8], path: &Path) -> Result<Vec<View>, ImportError> {
    let name = path.display().to_string();
    let folder = path.parent().unwrap_or(Path::new(""));
    let mut lines = crate::import::Lines::new(bytes, 1);
    let mut views = Vec::new();
    while let Some(line) = lines.next_line(&name) {
        let (number, text) = line?;
        let malformed = |message: String| ImportError::malformed(&name, number, message);
        let words: Vec<&str> = text.split_ascii_whitespace().collect();
        let (numbers, file) = match words.as_slice() {
            [] => continue,
            [first, ..] if first.starts_with('#') => continue,
            ["camera", rest @ ..] => (rest, None),
            ["bmesh", file, rest @ ..] => (rest, Some(*file)),
            _ => {
                return Err(malformed(format!(
                    "`{}` is not a registration record; expected `bmesh FILE tx ty tz qx qy qz \
                     qw` or `camera tx ty tz qx qy qz qw` (or a blank or # comment line)",
                    text.trim()
                )))
            }
        };
        let values: Vec<f64> = numbers
            .iter()
            .map(|t| t.parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect::<Option<_>>()
            .filter(|v: &Vec<f64>| v.len() == 7)
            .ok_or_else(|| {
                malformed(format!(
                    "expected seven finite numbers tx ty tz qx qy qz qw after `{}`, got `{}`",
                    words[0],
                    numbers.join(" ")
                ))
            })?;
        let Some(file) = file else { continue };
        let rotation = [values[3], values[4], values[5], values[6]];
        if rotation.iter().map(|c| c * c).sum::<f64>() < 1e-12 {
            return Err(malformed(
                "the quaternion qx qy qz qw is zero; give a unit quaternion (0 0 0 1 for none)"
                    .into(),
            ));
        }
        views.push(View {
            path: folder.join(file),
            pose: Pose {
                translation: [values[0], values[1], values[2]],
                rotation,
            },
        });
    }
    if views.is_empty() {
        return Err(ImportError::NoPointFound {
            path: name,
            detail: "the registration file lists no scan; add `bmesh FILE tx ty tz qx qy qz qw` \
                     lines"
                .into(),
        });
    }
    Ok(views)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_lines_name_the_file_and_line() {
        let error = |text: &[u8]| {
            read_conf(text, Path::new("x.conf"))
                .unwrap_err()
                .to_string()
        };
        let err = error(b"bmesh a.ply 0 0 0 0 0 0 1\n\nmesh b.ply\n");
        assert!(err.starts_with("x.conf:3:"), "{err}");
        let err = error(b"bmesh a.ply 0 0 0 0 0 1\n");
        assert!(err.contains("x.conf:1:") && err.contains("seven"), "{err}");
        let err = error(b"bmesh a.ply 0 0 0 0 0 0 0\n");
        assert!(err.contains("zero"), "{err}");
        let err = error(b"camera 0 0 0 0 0 0 1\n");
        assert!(err.contains("lists no scan"), "{err}");
    }
}
