//! The PLY binary body reader, little- and big-endian: body bytes and the [`Header`] and
//! [`Plan`] → [`PointCloud`] (and a range grid's cells), with the element count that would make
//! a bad body read when one would.

use super::header::{Element, Header, PropertyType, Scalar};
use super::{vertex_index, Plan};
use crate::cloud::PointCloud;
use crate::import::{push_fan, ImportError};

/// A capacity that a lying header count cannot blow up: at most one entry per remaining byte.
fn capped_capacity(count: u64, remaining_bytes: usize) -> usize {
    usize::try_from(count)
        .unwrap_or(usize::MAX)
        .min(remaining_bytes)
}

/// Reads one scalar at the start of `bytes`, or `None` when too few bytes remain.
#[inline(always)]
fn scalar_f64<const BIG: bool>(bytes: &[u8], ty: Scalar) -> Option<f64> {
    macro_rules! get {
        ($t:ty, $n:literal) => {{
            let raw: [u8; $n] = bytes.get(..$n)?.try_into().ok()?;
            if BIG {
                <$t>::from_be_bytes(raw)
            } else {
                <$t>::from_le_bytes(raw)
            }
        }};
    }
    Some(match ty {
        Scalar::I8 => f64::from(get!(i8, 1)),
        Scalar::U8 => f64::from(get!(u8, 1)),
        Scalar::I16 => f64::from(get!(i16, 2)),
        Scalar::U16 => f64::from(get!(u16, 2)),
        Scalar::I32 => f64::from(get!(i32, 4)),
        Scalar::U32 => f64::from(get!(u32, 4)),
        Scalar::F32 => f64::from(get!(f32, 4)),
        Scalar::F64 => get!(f64, 8),
    })
}

/// Reads one integer scalar at the start of `bytes` (list counts and indices).
#[inline(always)]
fn scalar_i64<const BIG: bool>(bytes: &[u8], ty: Scalar) -> Option<i64> {
    macro_rules! get {
        ($t:ty, $n:literal) => {{
            let raw: [u8; $n] = bytes.get(..$n)?.try_into().ok()?;
            i64::from(if BIG {
                <$t>::from_be_bytes(raw)
            } else {
                <$t>::from_le_bytes(raw)
            })
        }};
    }
    Some(match ty {
        Scalar::I8 => get!(i8, 1),
        Scalar::U8 => get!(u8, 1),
        Scalar::I16 => get!(i16, 2),
        Scalar::U16 => get!(u16, 2),
        Scalar::I32 => get!(i32, 4),
        Scalar::U32 => get!(u32, 4),
        // Float indices are refused by `Plan::new` and float counts by the header parser.
        Scalar::F32 | Scalar::F64 => return None,
    })
}

/// The values a binary walk collects from one entry.
struct Wanted<'a> {
    /// Property indices whose scalar values go to `values[slot]`.
    scalars: &'a [(usize, usize)],
    /// Property index of the list to collect.
    list: Option<usize>,
}

/// Reads a binary body. On an error, when the body reads without error with one element count
/// changed by up to 3, the error says so: that is what a wrong count in the header looks like
/// (a vertex count one too large reads a face's bytes as a vertex and the faces out of place).
pub(super) fn read_binary<const BIG: bool>(
    body: &[u8],
    header: &Header,
    plan: &Plan,
    path: &str,
    cells: &mut Vec<u32>,
) -> Result<PointCloud, ImportError> {
    let error = match read_binary_body::<BIG>(body, header, plan, path, cells) {
        Ok(cloud) => return Ok(cloud),
        Err(error) => error,
    };
    let Some(hint) = count_hint::<BIG>(body, header, plan) else {
        return Err(error);
    };
    Err(match error {
        ImportError::Truncated { path, detail } => ImportError::Truncated {
            path,
            detail: format!("{detail}; {hint}"),
        },
        ImportError::BadBinary {
            path,
            element,
            entry,
            offset,
            message,
        } => ImportError::BadBinary {
            path,
            element,
            entry,
            offset,
            message: format!("{message}; {hint}"),
        },
        ImportError::HeaderCountMismatch {
            path,
            what,
            declared,
            found,
        } => ImportError::HeaderCountMismatch {
            path,
            what: format!("{what} ({hint})"),
            declared,
            found,
        },
        other => other,
    })
}

/// Bodies larger than this get no [`count_hint`] (each try reads the whole body again).
const HINT_MAX_BYTES: usize = 32 << 20;

/// `the body reads without error with `element NAME N` instead of M: fix that count in the
/// header` when changing one element's count by up to 3 makes the whole body read.
fn count_hint<const BIG: bool>(body: &[u8], header: &Header, plan: &Plan) -> Option<String> {
    if body.len() > HINT_MAX_BYTES {
        return None;
    }
    for e in 0..header.elements.len() {
        for delta in [-1i64, 1, -2, 2, -3, 3] {
            let count = header.elements[e].count;
            let Some(new) = count.checked_add_signed(delta) else {
                continue;
            };
            let mut changed = header.clone();
            changed.elements[e].count = new;
            if read_binary_body::<BIG>(body, &changed, plan, "", &mut Vec::new()).is_ok() {
                return Some(format!(
                    "the body reads without error with `element {} {new}` instead of {count}: \
                     fix that count in the header",
                    header.elements[e].name
                ));
            }
        }
    }
    None
}

/// What is wrong with a face that refers to vertex `index`, which the header does not declare.
fn bad_index(header: &Header, face: u64, index: i64) -> String {
    let n = header.elements[header_vertex(header)].count;
    format!(
        "face {face} refers to vertex {index}, but the header declares {n} vertices (0-based \
         indices 0..{n}); fix or remove that face"
    )
}

/// A [`ImportError::BadBinary`] for `entry` of `element`, which starts at body byte `pos`.
fn bad_binary(
    path: &str,
    header: &Header,
    element: &Element,
    entry: u64,
    pos: usize,
    message: String,
) -> ImportError {
    ImportError::BadBinary {
        path: path.to_owned(),
        element: element.name.clone(),
        entry,
        offset: (header.body_start + pos) as u64,
        message,
    }
}

/// Index of the `vertex` element (`Plan::new` has checked that there is one).
fn header_vertex(header: &Header) -> usize {
    header
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .unwrap_or(0)
}

/// What is wrong with a face of fewer than three corners.
fn short_face(face: u64, corners: usize) -> String {
    format!(
        "face {face} has {corners} corner(s) and a face needs at least three; remove the face \
         (or, if the counts in the header are wrong, the faces are read from the wrong bytes: \
         fix the counts)"
    )
}

/// Reads a binary body; a range grid's cells go to `cells` (`u32::MAX` for an empty cell).
fn read_binary_body<const BIG: bool>(
    body: &[u8],
    header: &Header,
    plan: &Plan,
    path: &str,
    cells: &mut Vec<u32>,
) -> Result<PointCloud, ImportError> {
    let n_vertices = header.elements[plan.vertex].count;
    let mut pos = 0;
    let mut points = Vec::new();
    let mut normals = plan.normals.map(|_| Vec::new());
    let mut colours = plan.colours.map(|_| Vec::new());
    let mut triangles = Vec::new();
    for (e, element) in header.elements.iter().enumerate() {
        let remaining = body.len() - pos;
        let truncated = |entry: u64, at: usize| ImportError::Truncated {
            path: path.to_owned(),
            detail: format!(
                "the body ends at byte {} of the file, inside `{}` entry {entry} (starting at \
                 byte {}) of the {} the header declares",
                header.body_start + body.len(),
                element.name,
                header.body_start + at,
                element.count
            ),
        };
        let bad = |entry: u64, at: usize, message: String| {
            bad_binary(path, header, element, entry, at, message)
        };
        let stride = element.fixed_stride();
        if let Some(stride) = stride {
            let size = usize::try_from(element.count)
                .ok()
                .and_then(|n| n.checked_mul(stride))
                .filter(|&size| size <= remaining)
                .ok_or_else(|| {
                    let whole = remaining.checked_div(stride).unwrap_or(0);
                    truncated(whole as u64, pos + whole * stride)
                })?;
            let records = &body[pos..pos + size];
            pos += size;
            if e == plan.vertex && stride > 0 {
                read_vertex_records::<BIG>(
                    records,
                    stride,
                    element,
                    plan,
                    &mut points,
                    &mut normals,
                    &mut colours,
                );
            }
            continue;
        }
        // The common face element, a single index list: read it without the general walk.
        if let ([only], Some((f, _))) = (element.properties.as_slice(), plan.face)
            && let (true, PropertyType::List { count, item }) = (f == e, only.ty)
        {
            pos = read_face_lists::<BIG>(
                body,
                pos,
                element.count,
                (count, item),
                n_vertices,
                &mut triangles,
            )
            .map_err(|error| match error {
                FaceError::Truncated { face, at } => truncated(face, at),
                FaceError::Index { face, index, at } => {
                    bad(face, at, bad_index(header, face, index))
                }
                FaceError::Short { face, corners, at } => bad(face, at, short_face(face, corners)),
            })?;
            continue;
        }
        // Elements with lists: walk each entry.
        let mut slots = Vec::new();
        let mut list = None;
        if e == plan.vertex {
            slots = plan.vertex_slots().collect();
        } else {
            list = plan.face_list(e).or(plan.grid_list(e));
        }
        let is_grid = plan.grid_list(e).is_some();
        let wanted = Wanted {
            scalars: &slots,
            list,
        };
        let mut values = [0.0; 9];
        let mut polygon: Vec<i64> = Vec::new();
        let mut polygon_u32: Vec<u32> = Vec::new();
        if e == plan.vertex {
            points.reserve(capped_capacity(element.count, remaining));
        }
        for entry in 0..element.count {
            let start = pos;
            pos = walk_entry::<BIG>(body, pos, element, &wanted, &mut values, &mut polygon)
                .ok_or_else(|| truncated(entry, start))?;
            if e == plan.vertex {
                points.push([values[0], values[1], values[2]]);
                if let Some(n) = normals.as_mut() {
                    n.push([values[3], values[4], values[5]]);
                }
                if let (Some(c), Some(colour)) = (colours.as_mut(), plan.colour(&values)) {
                    c.push(colour);
                }
            } else if is_grid {
                cells.push(match polygon.as_slice() {
                    [] => u32::MAX,
                    [v] => vertex_index(*v, n_vertices)
                        .ok_or_else(|| bad(entry, start, bad_index(header, entry, *v)))?,
                    more => {
                        return Err(bad(
                            entry,
                            start,
                            format!(
                                "range_grid cell {entry} holds {} vertex indices; a range grid \
                                 cell holds 0 or 1",
                                more.len()
                            ),
                        ))
                    }
                });
            } else if list.is_some() {
                if polygon.len() < 3 {
                    return Err(bad(entry, start, short_face(entry, polygon.len())));
                }
                polygon_u32.clear();
                for &v in &polygon {
                    polygon_u32.push(
                        vertex_index(v, n_vertices)
                            .ok_or_else(|| bad(entry, start, bad_index(header, entry, v)))?,
                    );
                }
                push_fan(&mut triangles, &polygon_u32);
            }
        }
    }
    if pos < body.len() {
        // More bytes than the header accounts for: a count is too small (or bytes were
        // appended; the format has no terminator, so even a trailing newline is an error). Say
        // where, and how many bytes remain, in the units of the last element when it has a
        // fixed size.
        let last = header.elements.last();
        let extra = body.len() - pos;
        let at = header.body_start + pos;
        return Err(match last.and_then(|l| l.fixed_stride().map(|s| (l, s))) {
            Some((last, stride)) if stride > 0 && extra.is_multiple_of(stride) => {
                ImportError::HeaderCountMismatch {
                    path: path.to_owned(),
                    what: format!(
                        "`{}` entries (the last one ends at byte {at} of the file and {extra} \
                         more bytes follow)",
                        last.name
                    ),
                    declared: last.count,
                    found: last.count.saturating_add((extra / stride) as u64),
                }
            }
            _ => ImportError::BadBinary {
                path: path.to_owned(),
                element: last.map_or(String::new(), |l| l.name.clone()),
                entry: last.map_or(0, |l| l.count),
                offset: at as u64,
                message: format!(
                    "{extra} bytes follow the last entry the header declares (the body is {} \
                     bytes, the header's counts account for {pos}); fix the counts in the \
                     header or remove the extra bytes",
                    body.len()
                ),
            },
        });
    }
    Ok(PointCloud {
        points,
        normals,
        colours,
        triangles,
        range: None,
        ..Default::default()
    })
}

/// Why [`read_face_lists`] stopped.
enum FaceError {
    /// The body ended in this face entry, which starts at body byte `at` (or its list length
    /// was negative).
    Truncated { face: u64, at: usize },
    /// This face, at body byte `at`, has an index outside `0..n_vertices`.
    Index { face: u64, index: i64, at: usize },
    /// This face, at body byte `at`, has fewer than three corners.
    Short {
        face: u64,
        corners: usize,
        at: usize,
    },
}

/// The fast path for a face element whose only property is its index list. Returns the position
/// after the element.
fn read_face_lists<const BIG: bool>(
    body: &[u8],
    mut pos: usize,
    n_faces: u64,
    (count_ty, item_ty): (Scalar, Scalar),
    n_vertices: u64,
    triangles: &mut Vec<[u32; 3]>,
) -> Result<usize, FaceError> {
    let (count_size, item_size) = (count_ty.size(), item_ty.size());
    let smallest_triangle = count_size + 3 * item_size;
    triangles.reserve(capped_capacity(
        n_faces,
        (body.len() - pos) / smallest_triangle,
    ));
    let mut polygon: Vec<u32> = Vec::new();
    for face in 0..n_faces {
        let at = pos;
        let truncated = FaceError::Truncated { face, at };
        let Some(n) = body
            .get(pos..)
            .and_then(|b| scalar_i64::<BIG>(b, count_ty))
            .and_then(|n| usize::try_from(n).ok())
        else {
            return Err(truncated);
        };
        pos += count_size;
        let Some(items) = n
            .checked_mul(item_size)
            .and_then(|size| body.get(pos..pos.checked_add(size)?))
        else {
            return Err(truncated);
        };
        if n < 3 {
            return Err(FaceError::Short {
                face,
                corners: n,
                at,
            });
        }
        pos += items.len();
        if n == 3 {
            // Triangles, the common case, skip the polygon buffer.
            let mut triangle = [0u32; 3];
            for (slot, chunk) in triangle.iter_mut().zip(items.chunks_exact(item_size)) {
                let index =
                    scalar_i64::<BIG>(chunk, item_ty).ok_or(FaceError::Truncated { face, at })?;
                *slot =
                    vertex_index(index, n_vertices).ok_or(FaceError::Index { face, index, at })?;
            }
            triangles.push(triangle);
            continue;
        }
        polygon.clear();
        for chunk in items.chunks_exact(item_size) {
            let index =
                scalar_i64::<BIG>(chunk, item_ty).ok_or(FaceError::Truncated { face, at })?;
            polygon.push(vertex_index(index, n_vertices).ok_or(FaceError::Index {
                face,
                index,
                at,
            })?);
        }
        push_fan(triangles, &polygon);
    }
    Ok(pos)
}

/// The fast path: a vertex element without lists, read at fixed offsets of each record.
fn read_vertex_records<const BIG: bool>(
    records: &[u8],
    stride: usize,
    element: &Element,
    plan: &Plan,
    points: &mut Vec<[f64; 3]>,
    normals: &mut Option<Vec<[f64; 3]>>,
    colours: &mut Option<Vec<[u16; 3]>>,
) {
    let mut offsets = Vec::with_capacity(element.properties.len());
    let mut offset = 0;
    for p in &element.properties {
        offsets.push(offset);
        if let PropertyType::Scalar(s) = p.ty {
            offset += s.size();
        }
    }
    let field = |p: usize| -> (usize, Scalar) {
        match element.properties[p].ty {
            PropertyType::Scalar(s) => (offsets[p], s),
            // `Plan::new` only accepts scalar coordinates and this path only lists-free elements.
            PropertyType::List { .. } => (0, Scalar::U8),
        }
    };
    let n_records = records.len() / stride;
    let read = field_f64::<BIG>;
    read_triples::<BIG>(records, stride, plan.coords.map(field), points);
    if let (Some(out), Some(n)) = (normals.as_mut(), plan.normals) {
        read_triples::<BIG>(records, stride, n.map(field), out);
    }
    if let (Some(out), Some((c, _))) = (colours.as_mut(), plan.colours) {
        let c = c.map(field);
        out.reserve(n_records);
        let mut values = [0.0; 9];
        for record in records.chunks_exact(stride) {
            for (slot, field) in (6..9).zip(c) {
                values[slot] = read(record, field);
            }
            out.extend(plan.colour(&values));
        }
    }
}

/// Appends the three scalars at `fields` (offset, type) of every record of `records` to `out`,
/// as f64: the reads of [`scalar_f64`], with a loop of its own for the common all-`float`
/// triple (no dispatch on the type per value: a 3M-point file of `float x y z nx ny nz` is read
/// about twice as fast).
fn read_triples<const BIG: bool>(
    records: &[u8],
    stride: usize,
    fields: [(usize, Scalar); 3],
    out: &mut Vec<[f64; 3]>,
) {
    out.reserve(records.len() / stride);
    // The fast path's reads cannot fail either, for the reason [`field_f64`] gives.
    if fields.iter().all(|&(_, s)| s == Scalar::F32) {
        let offsets = fields.map(|(o, _)| o);
        let f32_at = |r: &[u8], o: usize| -> f64 {
            match r.get(o..o + 4).and_then(|b| <[u8; 4]>::try_from(b).ok()) {
                Some(raw) if BIG => f64::from(f32::from_be_bytes(raw)),
                Some(raw) => f64::from(f32::from_le_bytes(raw)),
                None => f64::NAN,
            }
        };
        out.extend(records.chunks_exact(stride).map(|r| {
            [
                f32_at(r, offsets[0]),
                f32_at(r, offsets[1]),
                f32_at(r, offsets[2]),
            ]
        }));
        return;
    }
    let read = field_f64::<BIG>;
    // Written out rather than with `array::map`, which profiling showed was not inlined here.
    out.extend(
        records
            .chunks_exact(stride)
            .map(|r| [read(r, fields[0]), read(r, fields[1]), read(r, fields[2])]),
    );
}

/// The scalar at `field` (offset, type) of `record`, as f64. Every offset plus its size is
/// within the stride of a fixed-stride element, so the read cannot fail there; the NaN is never
/// taken and keeps the path free of panics.
#[inline(always)]
fn field_f64<const BIG: bool>(record: &[u8], (offset, ty): (usize, Scalar)) -> f64 {
    record
        .get(offset..)
        .and_then(|b| scalar_f64::<BIG>(b, ty))
        .unwrap_or(f64::NAN)
}

/// Walks one binary entry from `pos`, storing wanted scalars and the wanted list.
/// Returns the position after the entry, or `None` when the body ends first.
fn walk_entry<const BIG: bool>(
    body: &[u8],
    mut pos: usize,
    element: &Element,
    wanted: &Wanted<'_>,
    values: &mut [f64; 9],
    list_out: &mut Vec<i64>,
) -> Option<usize> {
    for (p, property) in element.properties.iter().enumerate() {
        let rest = body.get(pos..)?;
        match property.ty {
            PropertyType::Scalar(s) => {
                if let Some(&(_, slot)) = wanted.scalars.iter().find(|(q, _)| *q == p) {
                    values[slot] = scalar_f64::<BIG>(rest, s)?;
                } else if rest.len() < s.size() {
                    return None;
                }
                pos += s.size();
            }
            PropertyType::List { count, item } => {
                let n = scalar_i64::<BIG>(rest, count)?;
                let n = usize::try_from(n).ok()?;
                pos += count.size();
                let size = n.checked_mul(item.size())?;
                let items = body.get(pos..pos.checked_add(size)?)?;
                if wanted.list == Some(p) {
                    list_out.clear();
                    for chunk in items.chunks_exact(item.size()) {
                        list_out.push(scalar_i64::<BIG>(chunk, item)?);
                    }
                }
                pos += size;
            }
        }
    }
    Some(pos)
}
