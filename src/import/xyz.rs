//! Stage `import`, XYZ reader: a text point list (.xyz, .pts, .txt, .csv) → [`PointCloud`].
//!
//! Input: the whole file as bytes. Output: one point per data line, with normals when every
//! line has six columns, and no triangles.
//!
//! Each data line is `x y z` or `x y z nx ny nz`, the numbers separated by spaces, tabs or commas.
//! Empty lines and `#` comments (whole lines or line ends) are skipped. Two common preambles are
//! accepted: a first line holding a single whole number (the point count of Leica .pts files,
//! which must then match), and a first line of column names such as `x,y,z` (csv). Every line
//! must have the same number of columns, because a change in mid-file means a corrupt or
//! concatenated file. Six columns are read as normals whatever the extension. Four and seven
//! columns are the Leica .pts layout `x y z intensity [r g b]` in a .pts file, or in any file
//! whose column names line says so (`x y z intensity r g b`, also `i`, `red`, …): intensity is
//! kept as written and colour as 16-bit (each 0–255 value times 257; colour columns with a
//! value outside 0–255 are not read, with a notice). Other column counts keep x, y, z and
//! ignore the rest; the ignored columns are named in a notice (with the names the column names
//! line gives), which `stablesurf info` prints.
//!
//! A file in which no point parses is an error that says what the file looks like (NUL bytes,
//! or its first non-blank line), never an empty cloud: text garbage, a zero-filled file or a
//! binary file with a .xyz name would otherwise import as "0 points" without a word.

use crate::cloud::PointCloud;
use crate::import::{first_line_quoted, nul_byte, parse_f64, ImportError, Lines};

/// Reads an XYZ point list; what it reads but does not keep goes to `notices`.
pub(crate) fn read(
    bytes: &[u8],
    path: &str,
    notices: &mut Vec<String>,
) -> Result<PointCloud, ImportError> {
    if let Some(e) = nul_byte(bytes, path, "point list") {
        return Err(e);
    }
    let mut column_names: Option<(usize, String)> = None;
    let mut lines = Lines::new(bytes, 1);
    let mut points = Vec::new();
    let mut normals = Vec::new();
    let mut columns: Option<(usize, usize)> = None; // (count, line where it was set)
    let mut stated_count: Option<(u64, usize)> = None;
    let mut first_data_line = true;
    let mut values: Vec<f64> = Vec::with_capacity(8);
    // The .pts layout's extra columns, filled once the column count says they are there.
    let mut intensity: Vec<f32> = Vec::new();
    let mut colours: Vec<[u16; 3]> = Vec::new();
    let mut colour_out_of_range: Option<usize> = None;
    let mut pts_layout = false;
    while let Some(line) = lines.next_line(path) {
        let (line_number, text) = line?;
        let text = text.split('#').next().unwrap_or("");
        let tokens = text
            .split(|c: char| c.is_ascii_whitespace() || c == ',')
            .filter(|t| !t.is_empty());
        values.clear();
        let mut bad_token = None;
        for token in tokens {
            match parse_f64(token) {
                Some(v) => values.push(v),
                None => {
                    bad_token = Some(token);
                    break;
                }
            }
        }
        let is_first = std::mem::replace(&mut first_data_line, false);
        if values.is_empty() && bad_token.is_none() {
            first_data_line = is_first;
            continue;
        }
        if is_first {
            if bad_token.is_some() && values.is_empty() {
                // Column names (csv header).
                column_names = Some((line_number, text.trim().to_owned()));
                continue;
            }
            if let ([count], None) = (values.as_slice(), bad_token)
                && count.fract() == 0.0
                && *count >= 0.0
            {
                stated_count = Some((*count as u64, line_number));
                continue;
            }
        }
        // Before any point, a bad line says more about the file than about the line.
        let no_point_yet = points.is_empty();
        let malformed = |message: String| {
            if no_point_yet {
                ImportError::NoPointFound {
                    path: path.to_owned(),
                    detail: format!(
                        "the first non-blank line is {}, no line before line {line_number} \
                         holds a point, and line {line_number} fails: {message}",
                        first_line_quoted(bytes).unwrap_or_default()
                    ),
                }
            } else {
                ImportError::Malformed {
                    path: path.to_owned(),
                    line: line_number,
                    message,
                }
            }
        };
        if let Some(token) = bad_token {
            return Err(malformed(format!(
                "`{token}` is not a number; each line needs x y z [nx ny nz]"
            )));
        }
        if values.len() < 3 {
            return Err(malformed(format!(
                "{} value(s) on a line; each line needs x y z [nx ny nz]",
                values.len()
            )));
        }
        match columns {
            None => {
                columns = Some((values.len(), line_number));
                pts_layout = matches!(values.len(), 4 | 7)
                    && is_pts_layout(values.len(), path, column_names.as_ref());
            }
            Some((n, first)) if n != values.len() => {
                return Err(malformed(format!(
                    "{} columns here but {n} on line {first}; every line needs the same columns",
                    values.len()
                )))
            }
            Some(_) => {}
        }
        points.push([values[0], values[1], values[2]]);
        if values.len() == 6 {
            normals.push([values[3], values[4], values[5]]);
        }
        if pts_layout {
            intensity.push(values[3] as f32);
            if values.len() == 7 {
                let rgb = [values[4], values[5], values[6]];
                if colour_out_of_range.is_none() && !rgb.iter().all(|c| (0.0..=255.0).contains(c)) {
                    colour_out_of_range = Some(line_number);
                }
                colours.push(rgb.map(|c| (c.clamp(0.0, 255.0).round() as u16) * 257));
            }
        }
    }
    if points.is_empty() {
        let detail = match (&column_names, stated_count) {
            (Some((line, names)), _) => format!(
                "line {line} (`{}`) was read as column names and no line of numbers follows; \
                 a point list needs lines of x y z [nx ny nz] (this file may be in another \
                 format: check its extension)",
                names.chars().take(60).collect::<String>()
            ),
            (None, Some((declared, line))) => format!(
                "line {line} states {declared} points and no point line follows; a point list \
                 needs lines of x y z [nx ny nz]"
            ),
            (None, None) => match first_line_quoted(bytes) {
                Some(first) => format!(
                    "no line of three numbers; the first non-blank line is {first}; a point \
                     list needs lines of x y z [nx ny nz]"
                ),
                None => "the file holds only blank lines; a point list needs lines of x y z \
                         [nx ny nz]"
                    .to_owned(),
            },
        };
        return Err(ImportError::NoPointFound {
            path: path.to_owned(),
            detail,
        });
    }
    if let Some((n, _)) = columns.filter(|&(n, _)| n != 3 && n != 6 && !pts_layout) {
        notices.push(ignored_columns(n, column_names.as_ref(), path));
    }
    if let Some(line) = colour_out_of_range {
        colours.clear();
        notices.push(format!(
            "columns 5 to 7 (r, g, b in the .pts layout) are not read: line {line} holds a \
             value outside 0–255; the cloud keeps x y z and intensity"
        ));
    }
    if let Some((declared, line)) = stated_count
        && declared != points.len() as u64
    {
        return Err(ImportError::HeaderCountMismatch {
            path: path.to_owned(),
            what: format!("points (line {line})"),
            declared,
            found: points.len() as u64,
        });
    }
    let normals = (!normals.is_empty()).then_some(normals);
    Ok(PointCloud {
        points,
        normals,
        colours: (!colours.is_empty()).then_some(colours),
        intensity: pts_layout.then_some(intensity),
        ..Default::default()
    })
}

/// Whether an `n`-column file (4 or 7) is in the .pts layout `x y z intensity [r g b]`: its
/// extension is .pts, or its column names line names those columns.
fn is_pts_layout(n: usize, path: &str, names: Option<&(usize, String)>) -> bool {
    let Some((_, line)) = names else {
        return path.to_ascii_lowercase().ends_with(".pts");
    };
    let words: Vec<String> = line
        .split(|c: char| c.is_ascii_whitespace() || c == ',')
        .filter(|t| !t.is_empty())
        .map(str::to_ascii_lowercase)
        .collect();
    let is = |i: usize, names: &[&str]| words.get(i).is_some_and(|w| names.contains(&w.as_str()));
    words.len() == n
        && is(3, &["intensity", "i"])
        && (n == 4 || (is(4, &["r", "red"]) && is(5, &["g", "green"]) && is(6, &["b", "blue"])))
}

/// The notice for the columns after x y z that an `n`-column file has and the cloud does not
/// keep: their names from the column names line, else the .pts names for 4 and 7 columns.
fn ignored_columns(n: usize, names: Option<&(usize, String)>, path: &str) -> String {
    let from_names: Option<Vec<&str>> = names.and_then(|(_, line)| {
        let words: Vec<&str> = line
            .split(|c: char| c.is_ascii_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
            .collect();
        (words.len() == n).then(|| words[3..].to_vec())
    });
    let pts = path.to_ascii_lowercase().ends_with(".pts");
    let which = if n == 4 {
        "column 4 of each line".to_owned()
    } else {
        format!("columns 4 to {n} of each line")
    };
    let named = match (from_names, n) {
        (Some(words), _) => format!(" ({})", words.join(", ")),
        (None, 4) if pts => " (intensity in the .pts layout)".to_owned(),
        (None, 7) if pts => " (intensity, r, g, b in the .pts layout)".to_owned(),
        (None, 4) => " (often intensity)".to_owned(),
        (None, 7) => " (often intensity, r, g, b)".to_owned(),
        _ => String::new(),
    };
    let verb = if n == 4 { "is" } else { "are" };
    format!("{which}{named} {verb} not read: the cloud keeps x y z only")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn separators_comments_and_normals() {
        let text = "# scan\n1 2 3 0 0 1\n4,5,6,0,1,0 # end\n\t7\t8\t9\t1\t0\t0\n\n";
        let cloud = read(text.as_bytes(), "t.xyz", &mut Vec::new()).unwrap();
        assert_eq!(
            cloud.points,
            vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]
        );
        assert_eq!(cloud.normals.unwrap()[1], [0.0, 1.0, 0.0]);
    }

    #[test]
    fn preambles() {
        let cloud = read(b"x,y,z\n1,2,3\n", "t.csv", &mut Vec::new()).unwrap();
        assert_eq!(cloud.points.len(), 1);
        let mut notices = Vec::new();
        let cloud = read(
            b"2\n1 2 3 10 255 0 0\n4 5 6 11 0 255 0\n",
            "t.pts",
            &mut notices,
        )
        .unwrap();
        assert_eq!(cloud.points.len(), 2);
        assert!(cloud.normals.is_none());
        assert!(notices.is_empty(), "{notices:?}");
        assert_eq!(cloud.intensity, Some(vec![10.0, 11.0]));
        assert_eq!(cloud.colours, Some(vec![[65535, 0, 0], [0, 65535, 0]]));
        assert!(matches!(
            read(b"3\n1 2 3\n", "t.pts", &mut Vec::new()),
            Err(ImportError::HeaderCountMismatch {
                declared: 3,
                found: 1,
                ..
            })
        ));
    }

    #[test]
    fn pts_layout_keeps_intensity_and_colour() {
        let mut notices = Vec::new();
        let cloud = read(b"0 0 0 -3.5\n1 0 0 7\n", "a.PTS", &mut notices).unwrap();
        assert_eq!(cloud.intensity, Some(vec![-3.5, 7.0]));
        assert!(cloud.colours.is_none() && notices.is_empty());
        // Named columns select the layout in any file; unnamed 7 columns in a .txt do not.
        let csv = b"X,Y,Z,Intensity,Red,Green,Blue\n0,0,0,1,1,2,255\n";
        let cloud = read(csv, "a.csv", &mut notices).unwrap();
        assert_eq!(cloud.colours, Some(vec![[257, 514, 65535]]));
        assert!(notices.is_empty());
        let cloud = read(b"0 0 0 1 1 2 3\n", "a.txt", &mut notices).unwrap();
        assert!(cloud.colours.is_none() && cloud.intensity.is_none());
        assert_eq!(notices.len(), 1);
        // A colour value outside 0–255 drops the colour columns, not the file.
        notices.clear();
        let cloud = read(b"0 0 0 1 1 2 3\n1 0 0 1 1 2 300\n", "a.pts", &mut notices).unwrap();
        assert!(cloud.colours.is_none());
        assert_eq!(cloud.intensity, Some(vec![1.0, 1.0]));
        assert!(notices[0].contains("line 2"), "{notices:?}");
    }

    #[test]
    fn errors_name_the_line() {
        for (text, line) in [
            ("1 2 3\n1 2\n", 2),
            ("1 2 3\n1 2 x\n", 2),
            ("1 2 3\n\n1 2 3 4\n", 3),
        ] {
            match read(text.as_bytes(), "t.xyz", &mut Vec::new()) {
                Err(ImportError::Malformed { line: l, .. }) => assert_eq!(l, line, "{text}"),
                other => panic!("{text}: {other:?}"),
            }
        }
    }
}
