//! The PLY ascii body reader: body bytes and the [`Header`] and [`Plan`] → [`PointCloud`] (and a
//! range grid's cells), one entry per line, a large body read in blocks in parallel with the
//! errors of a reader going line by line.

use super::header::{Header, PropertyType};
use super::{vertex_index, Plan};
use crate::cloud::PointCloud;
use crate::import::{push_fan, ImportError, Lines};

/// Converts a face index to u32, rejecting indices outside `0..n_points` with the face number.
/// `n_points` is the header's vertex count, which the vertex element matches once it is read
/// (the face element may come first).
fn to_index(value: i64, face: u64, n_points: u64, path: &str) -> Result<u32, ImportError> {
    vertex_index(value, n_points).ok_or_else(|| index_error(value, face, n_points, path))
}

/// The error for face `face` using the out-of-range index `value`.
fn index_error(value: i64, face: u64, n_points: u64, path: &str) -> ImportError {
    ImportError::IndexOutOfRange {
        path: path.to_owned(),
        line: None,
        face: usize::try_from(face).unwrap_or(usize::MAX),
        index: value,
        n_points: usize::try_from(n_points).unwrap_or(usize::MAX),
    }
}

pub(super) fn read_ascii(
    body: &[u8],
    header: &Header,
    plan: &Plan,
    path: &str,
    cells: &mut Vec<u32>,
) -> Result<PointCloud, ImportError> {
    let block_bytes = (body.len() >= ASCII_PARALLEL_BYTES).then_some(ASCII_BLOCK);
    match read_ascii_blocks(body, header, plan, path, block_bytes, cells) {
        Ok(cloud) => Ok(cloud),
        // A count that disagrees with the number of lines explains most parse errors (the next
        // element's lines are read as this one's), so report that instead when it is the case.
        Err(error) => Err(count_mismatch(body, header, path).unwrap_or(error)),
    }
}

/// When the body's non-empty lines differ from the total the header declares, the error that
/// says so.
fn count_mismatch(body: &[u8], header: &Header, path: &str) -> Option<ImportError> {
    // Saturating: a header may declare counts whose sum overflows a u64.
    let declared = header
        .elements
        .iter()
        .fold(0u64, |sum, e| sum.saturating_add(e.count));
    let found = body
        .split(|&b| b == b'\n')
        .filter(|l| l.iter().any(|b| !b.is_ascii_whitespace()))
        .count() as u64;
    (declared != found).then(|| {
        let list: Vec<String> = header
            .elements
            .iter()
            .map(|e| format!("{} {}", e.name, e.count))
            .collect();
        ImportError::HeaderCountMismatch {
            path: path.to_owned(),
            what: format!("entries in all ({}), one per line,", list.join(", ")),
            declared,
            found,
        }
    })
}

/// Bytes per block of a large ascii body, the unit of parallel work; a block ends after a `\n`.
const ASCII_BLOCK: usize = 64 * 1024;
/// Ascii bodies smaller than this are read as one block on the calling thread.
const ASCII_PARALLEL_BYTES: usize = 256 * 1024;

/// One element as the ascii reader sees it.
struct EntryLayout {
    /// Index among the body's non-blank lines of the element's first entry, and one past its
    /// last (saturating: a header may declare more entries than a u64 counts).
    start: u64,
    end: u64,
    /// For each property, where its value goes: 0..3 coordinates, 3..6 normals, 6..9 colours.
    slot_of: Vec<Option<usize>>,
    is_vertex: bool,
    /// Whether the entries' normals are kept (the vertex element, when it has nx, ny and nz).
    normals: bool,
    /// The index-list property when this is the face element.
    face_list: Option<usize>,
    /// The index-list property when this is the range grid element.
    grid_list: Option<usize>,
}

fn entry_layouts(header: &Header, plan: &Plan) -> Vec<EntryLayout> {
    let mut start = 0u64;
    let mut layouts = Vec::with_capacity(header.elements.len());
    for (e, element) in header.elements.iter().enumerate() {
        let is_vertex = e == plan.vertex;
        let mut slot_of = vec![None; element.properties.len()];
        if is_vertex {
            for (p, slot) in plan.vertex_slots() {
                slot_of[p] = Some(slot);
            }
        }
        let end = start.saturating_add(element.count);
        layouts.push(EntryLayout {
            start,
            end,
            slot_of,
            is_vertex,
            normals: is_vertex && plan.normals.is_some(),
            face_list: plan.face_list(e),
            grid_list: plan.grid_list(e),
        });
        start = end;
    }
    layouts
}

/// A block of the body's text and where it starts in the body's lines and non-blank lines.
struct Block {
    bytes: std::ops::Range<usize>,
    first_line: usize,
    first_entry: u64,
}

/// What reading one block gives.
#[derive(Default)]
struct BlockOutput {
    points: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    colours: Vec<[u16; 3]>,
    triangles: Vec<[u32; 3]>,
    /// Range grid cells (`u32::MAX` when empty).
    cells: Vec<u32>,
    /// Entries read, and the line of the last one.
    entries: u64,
    last_entry_line: Option<usize>,
    /// Lines walked, blank ones included.
    lines: usize,
    /// The first non-blank line after the last declared entry; the block stops there.
    extra_line: Option<usize>,
}

/// Reads the ascii body: cuts it into blocks, places each block in the sequence of lines and
/// entries from the counts of the blocks before it, reads the blocks (in parallel for a large
/// body) and joins their outputs in file order. Errors are those of a reader going line by
/// line: the first block's first error; else, when the lines ran out, the line that is not
/// UTF-8 or the missing entries; else the first line after the last entry; else the line that
/// is not UTF-8.
///
/// Blocks are `block_bytes` long and read in parallel, or the body is one block read on the
/// calling thread when `None`. A range grid's cells go to `cells`.
fn read_ascii_blocks(
    body: &[u8],
    header: &Header,
    plan: &Plan,
    path: &str,
    block_bytes: Option<usize>,
    cells: &mut Vec<u32>,
) -> Result<PointCloud, ImportError> {
    use rayon::prelude::*;
    // A `\n` byte is never part of a multi-byte UTF-8 sequence, so the lines before the one
    // holding the first invalid byte are all text, and that line is the first that is not.
    let text = match std::str::from_utf8(body) {
        Ok(text) => text,
        Err(e) => {
            let valid = body.get(..e.valid_up_to()).unwrap_or(&[]);
            let line_start = valid.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
            std::str::from_utf8(&body[..line_start]).unwrap_or("")
        }
    };
    let layouts = entry_layouts(header, plan);
    let n_vertices = header.elements[plan.vertex].count;
    let blocks = split_blocks(text, header.body_line, block_bytes);
    let read = |block: &Block| read_block(text, block, header, plan, &layouts, n_vertices, path);
    let parallel = block_bytes.is_some();
    let outputs: Vec<Result<BlockOutput, ImportError>> = if parallel {
        blocks.par_iter().map(read).collect()
    } else {
        blocks.iter().map(read).collect()
    };
    // The first error in block order, which is file order.
    let outputs = outputs.into_iter().collect::<Result<Vec<_>, _>>()?;

    // Every entry read parsed. What a line-by-line reader meets next: the end of the lines
    // before the last declared entry, a line after it, or the end of the body. `not_text` is
    // its error for the first line that is not UTF-8 (numbered `line`), if the body has one.
    let not_text = |line: usize| -> Result<(), ImportError> {
        match Lines::new(body.get(text.len()..).unwrap_or(&[]), line).next_line(path) {
            Some(Err(e)) => Err(e),
            _ => Ok(()),
        }
    };
    let entries: u64 = outputs.iter().map(|o| o.entries).sum();
    // Exact whenever it is used: no block stopped early, so every line of the text was walked.
    let line_after_text = header.body_line + outputs.iter().map(|o| o.lines).sum::<usize>();
    if let Some((e, layout)) = layouts.iter().enumerate().find(|(_, l)| l.end > entries) {
        not_text(line_after_text)?;
        let element = &header.elements[e];
        return Err(ImportError::HeaderCountMismatch {
            path: path.to_owned(),
            what: format!("`{}` entries", element.name),
            declared: element.count,
            found: entries - layout.start,
        });
    }
    if let Some(n) = outputs.iter().find_map(|o| o.extra_line) {
        let last_line = outputs
            .iter()
            .rev()
            .find_map(|o| o.last_entry_line)
            .unwrap_or(header.body_line);
        return Err(
            count_mismatch(body, header, path).unwrap_or(ImportError::Malformed {
                path: path.to_owned(),
                line: n,
                message: format!(
                    "data after the last element (which ended on line {last_line}); remove it or \
                     fix the counts in the header"
                ),
            }),
        );
    }
    not_text(line_after_text)?;

    let points = outputs.iter().map(|o| o.points.as_slice());
    let normals = outputs.iter().map(|o| o.normals.as_slice());
    let colours = outputs.iter().map(|o| o.colours.as_slice());
    let triangles = outputs.iter().map(|o| o.triangles.as_slice());
    *cells = concat(
        outputs.iter().map(|o| o.cells.as_slice()).collect(),
        parallel,
    );
    Ok(PointCloud {
        points: concat(points.collect(), parallel),
        normals: plan.normals.map(|_| concat(normals.collect(), parallel)),
        colours: plan.colours.map(|_| concat(colours.collect(), parallel)),
        triangles: concat(triangles.collect(), parallel),
        range: None,
        ..Default::default()
    })
}

/// Cuts `text` into blocks of about `block_bytes` (one block when `None`), each but the last
/// ending after a `\n`, and numbers them from the lines and non-blank lines of the blocks
/// before, counted in parallel.
fn split_blocks(text: &str, first_line: usize, block_bytes: Option<usize>) -> Vec<Block> {
    use rayon::prelude::*;
    let Some(size) = block_bytes else {
        return vec![Block {
            bytes: 0..text.len(),
            first_line,
            first_entry: 0,
        }];
    };
    let bytes = text.as_bytes();
    let mut ranges = Vec::new();
    let mut start = 0;
    while start < bytes.len() {
        let from = start + size.max(1) - 1;
        let end = match bytes
            .get(from..)
            .and_then(|r| r.iter().position(|&b| b == b'\n'))
        {
            Some(i) => from + i + 1,
            None => bytes.len(),
        };
        ranges.push(start..end);
        start = end;
    }
    // The last block's counts would place nothing.
    let counted = ranges.len().saturating_sub(1);
    let counts: Vec<(usize, u64)> = ranges[..counted]
        .par_iter()
        .map(|r| {
            let mut lines = TextLines::new(text.get(r.clone()).unwrap_or(""), 1);
            let mut entries = 0;
            while lines.next_entry().is_some() {
                entries += 1;
            }
            (lines.line, entries)
        })
        .collect();
    let (mut line, mut entry) = (first_line, 0);
    ranges
        .into_iter()
        .enumerate()
        .map(|(i, bytes)| {
            let block = Block {
                bytes,
                first_line: line,
                first_entry: entry,
            };
            if let Some(&(lines, entries)) = counts.get(i) {
                line += lines;
                entry += entries;
            }
            block
        })
        .collect()
}

/// Reads the entries of one block; the error is the one of its first bad line.
fn read_block(
    text: &str,
    block: &Block,
    header: &Header,
    plan: &Plan,
    layouts: &[EntryLayout],
    n_vertices: u64,
    path: &str,
) -> Result<BlockOutput, ImportError> {
    let mut out = BlockOutput::default();
    let mut lines = TextLines::new(
        text.get(block.bytes.clone()).unwrap_or(""),
        block.first_line,
    );
    let mut polygon: Vec<u32> = Vec::new();
    let mut values = [0.0; 9];
    // The element of entry `index` (counted over the body's non-blank lines).
    let mut e = 0;
    let mut index = block.first_entry;
    while let Some((line_number, line)) = lines.next_entry() {
        while layouts.get(e).is_some_and(|l| l.end <= index) {
            e += 1;
        }
        let (Some(layout), Some(element)) = (layouts.get(e), header.elements.get(e)) else {
            // Past the last element: the header does not declare this line.
            out.extra_line = Some(line_number);
            break;
        };
        let entry = index - layout.start;
        let malformed = |message: String| ImportError::malformed(path, line_number, message);
        let mut tokens = line.split_ascii_whitespace();
        for (p, property) in element.properties.iter().enumerate() {
            let mut next = |what: &str| {
                tokens.next().ok_or_else(|| {
                    malformed(format!(
                        "the `{}` entry ends before its {what} `{}`; each entry needs one \
                         value per property, in header order",
                        element.name, property.name
                    ))
                })
            };
            match property.ty {
                PropertyType::Scalar(_) => {
                    let token = next("property")?;
                    if let Some(slot) = layout.slot_of[p] {
                        values[slot] = crate::import::parse_f64(token).ok_or_else(|| {
                            malformed(format!(
                                "`{token}` is not a number (property `{}`)",
                                property.name
                            ))
                        })?;
                    }
                }
                PropertyType::List { .. } => {
                    let token = next("list length")?;
                    let n: usize = token.parse().map_err(|_| {
                        malformed(format!(
                            "`{token}` is not a list length (property `{}`)",
                            property.name
                        ))
                    })?;
                    if layout.face_list == Some(p) {
                        if n < 3 {
                            return Err(malformed(format!(
                                "face {entry} has {n} corner(s) and a face needs at least three; \
                                 remove that line and lower the `{}` count in the header",
                                element.name
                            )));
                        }
                        polygon.clear();
                        for _ in 0..n {
                            let token = next("list item")?;
                            let value: i64 = token.parse().map_err(|_| {
                                malformed(format!("`{token}` is not a vertex index"))
                            })?;
                            polygon.push(to_index(value, entry, n_vertices, path)?);
                        }
                    } else if layout.grid_list == Some(p) {
                        if n > 1 {
                            return Err(malformed(format!(
                                "range_grid cell {entry} holds {n} vertex indices; a range grid \
                                 cell holds 0 or 1"
                            )));
                        }
                        let mut cell = u32::MAX;
                        for _ in 0..n {
                            let token = next("list item")?;
                            let value: i64 = token.parse().map_err(|_| {
                                malformed(format!("`{token}` is not a vertex index"))
                            })?;
                            cell = to_index(value, entry, n_vertices, path)?;
                        }
                        out.cells.push(cell);
                    } else {
                        for _ in 0..n {
                            next("list item")?;
                        }
                    }
                }
            }
        }
        if let Some(extra) = tokens.next() {
            return Err(malformed(format!(
                "extra value `{extra}` after the last property of a `{}` entry; each entry \
                 holds one value per property, in header order",
                element.name
            )));
        }
        if layout.is_vertex {
            out.points.push([values[0], values[1], values[2]]);
            if layout.normals {
                out.normals.push([values[3], values[4], values[5]]);
            }
            out.colours.extend(plan.colour(&values));
        } else if layout.face_list.is_some() {
            push_fan(&mut out.triangles, &polygon);
        }
        out.entries += 1;
        out.last_entry_line = Some(line_number);
        index += 1;
    }
    out.lines = lines.line + 1 - block.first_line;
    Ok(out)
}

/// The parts one after the other, copied in parallel when `parallel`.
fn concat<T: Copy + Default + Send + Sync>(parts: Vec<&[T]>, parallel: bool) -> Vec<T> {
    use rayon::prelude::*;
    if !parallel {
        return parts.concat();
    }
    let mut all = vec![T::default(); parts.iter().map(|p| p.len()).sum()];
    let mut rest = all.as_mut_slice();
    let mut pairs = Vec::with_capacity(parts.len());
    for part in parts {
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(part.len());
        pairs.push((head, part));
        rest = tail;
    }
    pairs
        .into_par_iter()
        .for_each(|(head, part)| head.copy_from_slice(part));
    all
}

/// The lines of text already checked as UTF-8, numbered like [`Lines`]: split at `\n`, one
/// trailing `\r` removed, no empty line after a final `\n`.
///
/// The `\n`s are found 64 bytes at a time with [`newline_mask`] and the mask's bits taken one by
/// one: on the bunny a search per line (`position`, or `str::find` and its memchr) cost about
/// as much as converting the numbers, and the counting pass does little else.
struct TextLines<'a> {
    text: &'a str,
    /// Byte offset of the next line.
    pos: usize,
    /// Start of the 64-byte block `mask` describes, and its `\n`s not yet passed.
    block: usize,
    mask: u64,
    /// Number of the line last returned.
    line: usize,
}

/// Bit `i` is set when `block[i]` is `\n`; a block shorter than 64 bytes is padded with zeros.
///
/// Eight bytes at a time without branches: a byte of `x` is zero exactly when the top bit of
/// `(x & 0x7f..) + 0x7f.. | x` is clear (no carry crosses bytes), and the multiplication gathers
/// the eight top bits into one byte, byte `k`'s bit at position `k`.
#[inline(always)]
fn newline_mask(block: &[u8]) -> u64 {
    let mut padded = [0u8; 64];
    let block: &[u8; 64] = match block.try_into() {
        Ok(full) => full,
        Err(_) => {
            let n = block.len().min(64);
            padded[..n].copy_from_slice(&block[..n]);
            &padded
        }
    };
    const LOW7: u64 = 0x7f7f_7f7f_7f7f_7f7f;
    let mut mask = 0;
    for (k, word) in block.chunks_exact(8).enumerate() {
        let mut bytes = [0u8; 8];
        bytes.copy_from_slice(word);
        let x = u64::from_le_bytes(bytes) ^ 0x0a0a_0a0a_0a0a_0a0a;
        let zero = !(((x & LOW7).wrapping_add(LOW7)) | x) & !LOW7;
        mask |= ((zero >> 7).wrapping_mul(0x0102_0408_1020_4080) >> 56) << (8 * k);
    }
    mask
}

impl<'a> TextLines<'a> {
    fn new(text: &'a str, first_line: usize) -> TextLines<'a> {
        TextLines {
            text,
            pos: 0,
            block: 0,
            mask: newline_mask(text.as_bytes().get(..64).unwrap_or(text.as_bytes())),
            line: first_line.saturating_sub(1),
        }
    }

    /// Offset of the next `\n`, or `None` when none is left.
    #[inline(always)]
    fn next_newline(&mut self) -> Option<usize> {
        let bytes = self.text.as_bytes();
        while self.mask == 0 {
            self.block += 64;
            let block = bytes.get(self.block..)?;
            if block.is_empty() {
                return None;
            }
            self.mask = newline_mask(block.get(..64).unwrap_or(block));
        }
        let i = self.mask.trailing_zeros() as usize;
        self.mask &= self.mask - 1;
        Some(self.block + i)
    }

    /// The next line that is not blank (blank lines hold no entry and are skipped) with its
    /// number.
    fn next_entry(&mut self) -> Option<(usize, &'a str)> {
        loop {
            let start = self.pos;
            if start >= self.text.len() {
                return None;
            }
            let end = self.next_newline().unwrap_or(self.text.len());
            self.pos = end + 1;
            self.line += 1;
            // Both ends are next to a `\n` or at an end of the text: char boundaries.
            let raw = self.text.get(start..end).unwrap_or("");
            let line = raw.strip_suffix('\r').unwrap_or(raw);
            let blank = match line.as_bytes().first() {
                Some(b) if b.is_ascii_graphic() => false,
                _ => line.trim_start().is_empty(),
            };
            if !blank {
                return Some((self.line, line));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::header::read_header;
    use super::super::read;
    use super::super::tests::read_str;
    use super::*;
    use crate::import::ScanFormat;

    /// A large ascii PLY (about 600 kB, so `read` cuts it into blocks read in parallel): vertex
    /// `i` is `(i, -i/2, 0.25)` with normal `(0, 0, 1)`, face `j` the quad `j, j+1, j+2, j+3`;
    /// a blank line every 1000 entries and CRLF endings on every 7th line. Returns the bytes and
    /// the number of header lines.
    fn big_ascii(n_vertices: usize, n_faces: usize) -> (String, usize) {
        let mut s = format!(
            "ply\nformat ascii 1.0\nelement vertex {n_vertices}\nproperty double x\n\
             property double y\nproperty double z\nproperty float nx\nproperty float ny\n\
             property float nz\nelement face {n_faces}\n\
             property list uchar int vertex_indices\nend_header\n"
        );
        let header_lines = s.lines().count();
        for i in 0..n_vertices + n_faces {
            if i % 1000 == 999 {
                s.push_str("  \n");
            }
            if i < n_vertices {
                s.push_str(&format!("{i} {} 0.25 0 0 1", -(i as f64) / 2.0));
            } else {
                let j = i - n_vertices;
                s.push_str(&format!("4 {j} {} {} {}", j + 1, j + 2, j + 3));
            }
            s.push_str(if i % 7 == 0 { "\r\n" } else { "\n" });
        }
        (s, header_lines)
    }

    /// The body's line number of entry `i` of `big_ascii` (blank lines included).
    fn big_ascii_line(header_lines: usize, i: usize) -> usize {
        header_lines + 1 + i + (i + 1) / 1000
    }

    /// `big_ascii` with entry `i`'s line replaced.
    fn with_entry(s: &str, header_lines: usize, i: usize, line: &str) -> String {
        let mut lines: Vec<&str> = s.split('\n').collect();
        lines[big_ascii_line(header_lines, i) - 1] = line;
        lines.join("\n")
    }

    /// Reads the ascii body with blocks of `block_bytes` (`None`: one block, no threads).
    fn read_in_blocks(bytes: &[u8], block_bytes: Option<usize>) -> String {
        let header = read_header(bytes, "t.ply").unwrap();
        let plan = Plan::new(&header, "t.ply").unwrap();
        let body = &bytes[header.body_start..];
        format!(
            "{:?}",
            read_ascii_blocks(body, &header, &plan, "t.ply", block_bytes, &mut Vec::new())
        )
    }

    #[test]
    fn ascii_blocks_in_parallel_give_the_generated_values() {
        let (n_vertices, n_faces) = (20_000, 12_000);
        let (s, _) = big_ascii(n_vertices, n_faces);
        assert!(s.len() > 2 * ASCII_PARALLEL_BYTES, "{}", s.len());
        let (format, cloud) = read_str(&s).unwrap();
        assert_eq!(format, ScanFormat::PlyAscii);
        let points: Vec<[f64; 3]> = (0..n_vertices)
            .map(|i| [i as f64, -(i as f64) / 2.0, 0.25])
            .collect();
        assert_eq!(cloud.points, points);
        assert_eq!(cloud.normals, Some(vec![[0.0, 0.0, 1.0]; n_vertices]));
        let triangles: Vec<[u32; 3]> = (0..n_faces as u32)
            .flat_map(|j| [[j, j + 1, j + 2], [j, j + 2, j + 3]])
            .collect();
        assert_eq!(cloud.triangles, triangles);
        // Any cut into blocks reads the same as one block on one thread.
        let one_block = read_in_blocks(s.as_bytes(), None);
        for block_bytes in [1, 100, 4096, ASCII_BLOCK] {
            assert_eq!(read_in_blocks(s.as_bytes(), Some(block_bytes)), one_block);
        }
    }

    #[test]
    fn ascii_blocks_report_the_first_error_in_file_order() {
        let (s, header_lines) = big_ascii(20_000, 12_000);
        let expect_malformed = |s: &str, entry: usize, needle: &str| match read_str(s) {
            Err(ImportError::Malformed { line, message, .. }) => {
                assert_eq!(line, big_ascii_line(header_lines, entry), "{message}");
                assert!(message.contains(needle), "{message}");
            }
            other => panic!("{other:?}"),
        };
        // A bad face in a late block alone is found ...
        let late = with_entry(&s, header_lines, 29_000, "3 1 2 oops");
        expect_malformed(&late, 29_000, "`oops` is not a vertex index");
        // ... but a bad number in an earlier block wins, with its own line number.
        let both = with_entry(&late, header_lines, 3_001, "1 2x 3 0 0 1");
        expect_malformed(&both, 3_001, "`2x` is not a number (property `y`)");
        // A line that is not UTF-8 in between wins over the late error only.
        let mut bytes = with_entry(&late, header_lines, 15_000, "1 2 3 0 0 1 ").into_bytes();
        let at = bytes
            .windows(13)
            .position(|w| w == b"\n1 2 3 0 0 1 ")
            .unwrap()
            + 12;
        bytes[at] = 0xff;
        match read(&bytes, "t.ply", &mut Vec::new()) {
            Err(ImportError::Malformed { line, message, .. }) => {
                assert_eq!(line, big_ascii_line(header_lines, 15_000));
                assert!(message.contains("utf-8"), "{message}");
            }
            other => panic!("{other:?}"),
        }
        // Every cut into blocks gives the same errors as one block.
        let short = &s[..s.len() - 500];
        let index = with_entry(&s, header_lines, 25_000, "3 1 20000 2");
        for text in [&late, &both, short, &index] {
            let one_block = read_in_blocks(text.as_bytes(), None);
            for block_bytes in [1, 100, 4096, ASCII_BLOCK] {
                assert_eq!(
                    read_in_blocks(text.as_bytes(), Some(block_bytes)),
                    one_block
                );
            }
        }
        assert!(read_in_blocks(short.as_bytes(), None).contains("HeaderCountMismatch"));
        assert!(read_in_blocks(index.as_bytes(), None).contains("face: 5000, index: 20000"));
        assert_eq!(
            read_in_blocks(bytes.as_slice(), Some(4096)),
            read_in_blocks(bytes.as_slice(), None)
        );
    }
}
