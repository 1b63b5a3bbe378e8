//! Export stage, OpenVDB writer: a `NarrowBand` level set → one `.vdb` file.
//!
//! Input: the narrow band of [`crate::distance::volume`] and `VdbOptions` (the unit and the
//! glTF up axis). Output: the bytes of an OpenVDB file (file format version 224, the current
//! one) holding one grid: a `FloatGrid` (`Tree_float_5_4_3`) named `surface` of class
//! `level set`, uncompressed, with the standard grid metadata (`class`, `name`,
//! `file_bbox_min`/`max` of the active voxels, `file_voxel_count`, `file_mem_bytes`,
//! `file_compression` `none`, `is_saved_as_half_float` false, `creator`).
//!
//! # Layout (little-endian; strings are a u32 length and the bytes)
//!
//! ```text
//! header   i64 magic 0x56444220, u32 file version 224, u32 u32 library version 12.0,
//!          u8 1 (grid offsets follow), 36-character UUID, file metadata (i32 0), i32 grid count 1
//! grid     name, type "Tree_float_5_4_3", instance parent "", i64 grid / blocks / end offsets;
//!          at the grid offset: u32 compression 0, the metadata (i32 count; per entry name,
//!          type name, u32 size, value; sorted by name), the transform
//!          ("UniformScaleTranslateMap": translation, scale, voxel size, 1/scale, 1/scale²,
//!          1/(2·scale), each three f64), the topology, then at the blocks offset the leaves
//! topology u32 1 (buffers), f32 background, u32 tiles 0, u32 children 1, the root's child:
//!          i32×3 origin, its child and value masks (u64 words), a node-values record, then
//!          per child (in index order) the same for the 16³ node and its leaves' value masks
//! record   u8 6 (every value follows), then the node's values as f32, uncompressed
//! leaves   per leaf in the topology's order: its value mask (8 words), a record of 512 values
//! ```
//!
//! Offsets within a node: a leaf holds voxel (x, y, z) at `(x & 7)·64 + (y & 7)·8 + (z & 7)`;
//! the 16³ node holds its child covering (x, y, z) at
//! `((x & 127) >> 3)·256 + ((y & 127) >> 3)·16 + ((z & 127) >> 3)`; the 32³ node at
//! `((x & 4095) >> 7)·1024 + ((y & 4095) >> 7)·32 + ((z & 4095) >> 7)`. The grid's voxels have
//! indices 0 ..= 4095 (the volume's limit), so the root has one child, at the origin. Every slot
//! without a child is an inactive tile of value ± the background, its sign that of the blocks
//! it covers, so the level set is signed everywhere as OpenVDB's signed flood fill would leave
//! it.
//!
//! # Frame
//!
//! Index (i, j, k) maps to world as `voxel size · (i, j, k) + translation`, voxel centres at
//! integer indices. Values and the transform are in input units, or in metres with
//! `VdbOptions::units`, like the glTF. With [`UpAxis::Y`] (the glTF default) the grid is put
//! in Blender's Z-up frame the way Blender's glTF importer puts the glb: input (x, y, z) ↦
//! (x, −z, y), by a permutation of the index axes (the map stays a uniform scale and a
//! translation), so a `.glb` and a `.vdb` of one run imported together overlap; with
//! [`UpAxis::Z`] the input frame is Blender's already. The UUID is derived from the file's
//! contents (BLAKE3), so the bytes are deterministic.

use std::io::Write;

use super::gltf::UpAxis;
use super::units::LengthUnit;
use super::ExportError;
use crate::distance::volume::{NarrowBand, BLOCK, BLOCK_VOXELS};

/// OpenVDB's file magic number.
const MAGIC: i64 = 0x5644_4220;
/// The file format version written: 224 (multi-pass IO), OpenVDB's current one.
pub(crate) const FILE_VERSION: u32 = 224;
/// The OpenVDB library version recorded in the header (the format's version 224 is current
/// there).
const LIBRARY_VERSION: [u32; 2] = [12, 0];
/// The grid's name.
pub(crate) const GRID_NAME: &str = "surface";
/// The grid's tree type.
pub(crate) const GRID_TYPE: &str = "Tree_float_5_4_3";
/// Node-values record: no mask, every value follows.
const NO_MASK_AND_ALL_VALS: u8 = 6;

/// Options of [`write()`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct VdbOptions {
    /// The unit of the input coordinates: the transform and the values are scaled to metres
    /// (as the glTF); `None` writes input units.
    pub units: Option<LengthUnit>,
    /// The up axis of the input, as for the glTF (see the module docs).
    pub up: UpAxis,
}

/// A leaf of the output tree: index-space origin, values and active mask, in the output frame.
struct Leaf {
    origin: [i32; 3],
    values: Vec<f32>,
    active: [u64; 8],
}

/// The grid in the output frame: its leaves (sorted by origin), the origins of the inside
/// blocks, the index-to-world translation and the scale of lengths.
struct Framed {
    leaves: Vec<Leaf>,
    inside: Vec<[i32; 3]>,
    translation: [f64; 3],
    voxel_size: f64,
    background: f32,
}

/// Moves `band` into the output frame of `opts` (see the module docs).
fn frame(band: &NarrowBand, opts: &VdbOptions) -> Framed {
    let scale = opts.units.map_or(1.0, LengthUnit::metres);
    let h = band.grid.voxel_size * scale;
    let o = band.grid.origin.map(|c| c * scale);
    let n_blocks_z = band.grid.shape[2].div_ceil(BLOCK) as i32;
    let last_z = n_blocks_z * BLOCK as i32 - 1;
    // Output origin of a block at input origin (i, j, k), and output offset of a voxel's
    // offset inside its block. With Y up: (i, j, k) ↦ (i, last_z − k, j), world (x, −z, y).
    let turn = opts.up == UpAxis::Y;
    let map_origin = |b: [i32; 3]| {
        if turn {
            [b[0], last_z - (b[2] + BLOCK as i32 - 1), b[1]]
        } else {
            b
        }
    };
    let map_offset = |n: usize| {
        let (x, y, z) = (n / 64, (n / 8) % 8, n % 8);
        if turn {
            x * 64 + (7 - z) * 8 + y
        } else {
            n
        }
    };
    let translation = if turn {
        [o[0], -o[2] - h * f64::from(last_z), o[1]]
    } else {
        o
    };
    let mut leaves: Vec<Leaf> = band
        .blocks
        .iter()
        .map(|b| {
            let mut values = vec![0.0; BLOCK_VOXELS];
            let mut active = [0u64; 8];
            for n in 0..BLOCK_VOXELS {
                let m = map_offset(n);
                values[m] = (f64::from(b.values[n]) * scale) as f32;
                if b.active[n / 64] >> (n % 64) & 1 == 1 {
                    active[m / 64] |= 1 << (m % 64);
                }
            }
            Leaf {
                origin: map_origin(b.origin),
                values,
                active,
            }
        })
        .collect();
    // The topology's order: by 16³ node (its slot in the 32³ node), then by slot within it;
    // both are the lexicographic order of the coordinates, at their own scale.
    leaves.sort_by_key(|l| (l.origin.map(|c| c >> 7), l.origin));
    let mut inside: Vec<[i32; 3]> = band.inside_blocks.iter().map(|&b| map_origin(b)).collect();
    inside.sort_unstable_by_key(|&o| (o.map(|c| c >> 7), o));
    Framed {
        leaves,
        inside,
        translation,
        voxel_size: h,
        background: (f64::from(band.background) * scale) as f32,
    }
}

/// Little-endian writers into a byte buffer.
struct Bytes(Vec<u8>);

impl Bytes {
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn i64(&mut self, v: i64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f32s(&mut self, v: &[f32]) {
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn vec3d(&mut self, v: [f64; 3]) {
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn words(&mut self, v: &[u64]) {
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32);
        self.0.extend_from_slice(s.as_bytes());
    }
    /// One metadata entry: name, type name, size, value.
    fn meta(&mut self, name: &str, type_name: &str, value: &[u8]) {
        self.string(name);
        self.string(type_name);
        self.u32(value.len() as u32);
        self.0.extend_from_slice(value);
    }
}

fn vec3i_bytes(v: [i32; 3]) -> Vec<u8> {
    v.iter().flat_map(|c| c.to_le_bytes()).collect()
}

/// Writes `band` as an OpenVDB file (see the module docs) to `out`.
///
/// # Errors
/// [`ExportError::Write`] when `out` fails; [`ExportError::Format`] for a band without active
/// voxels or with an index outside 0 ..= 4095.
pub(crate) fn write(
    band: &NarrowBand,
    opts: &VdbOptions,
    out: &mut impl Write,
) -> Result<(), ExportError> {
    let framed = frame(band, opts);
    let Some(bounds) = active_bounds(&framed.leaves) else {
        return Err(ExportError::Format(
            "the signed-distance volume has no voxel near the surface; use a smaller voxel size"
                .into(),
        ));
    };
    let in_range = |o: &[i32; 3]| o.iter().all(|&c| (0..4096).contains(&c));
    if !framed.leaves.iter().all(|l| in_range(&l.origin)) || !framed.inside.iter().all(in_range) {
        return Err(ExportError::Format(
            "the signed-distance volume has voxel indices outside 0 ..= 4095; use a larger voxel size"
                .into(),
        ));
    }
    let voxel_count: u64 = framed
        .leaves
        .iter()
        .map(|l| {
            l.active
                .iter()
                .map(|w| u64::from(w.count_ones()))
                .sum::<u64>()
        })
        .sum();

    // The grid: compression, metadata, transform, topology; then the leaves' buffers.
    let mut grid = Bytes(Vec::new());
    grid.u32(0);
    let n_nodes4 = {
        let mut origins: Vec<[i32; 3]> = framed
            .leaves
            .iter()
            .map(|l| l.origin.map(|c| c & !127))
            .collect();
        origins.dedup();
        origins.len()
    };
    // What OpenVDB's memUsage would report, roughly: the nodes' value and mask arrays.
    let mem_bytes = (32768 * 4 + 2 * 4096)
        + n_nodes4 * (4096 * 4 + 2 * 512)
        + framed.leaves.len() * (BLOCK_VOXELS * 4 + 64 + 16);
    let mut metadata: Vec<(&str, &str, Vec<u8>)> = vec![
        ("class", "string", b"level set".to_vec()),
        ("creator", "string", b"stablesurf".to_vec()),
        ("file_bbox_max", "vec3i", vec3i_bytes(bounds.1)),
        ("file_bbox_min", "vec3i", vec3i_bytes(bounds.0)),
        ("file_compression", "string", b"none".to_vec()),
        (
            "file_mem_bytes",
            "int64",
            (mem_bytes as i64).to_le_bytes().to_vec(),
        ),
        (
            "file_voxel_count",
            "int64",
            (voxel_count as i64).to_le_bytes().to_vec(),
        ),
        ("is_local_space", "bool", vec![0]),
        ("is_saved_as_half_float", "bool", vec![0]),
        ("name", "string", GRID_NAME.as_bytes().to_vec()),
    ];
    metadata.sort_by(|a, b| a.0.cmp(b.0));
    grid.i32(metadata.len() as i32);
    for (name, type_name, value) in &metadata {
        grid.meta(name, type_name, value);
    }
    let h = framed.voxel_size;
    grid.string("UniformScaleTranslateMap");
    grid.vec3d(framed.translation);
    grid.vec3d([h; 3]);
    grid.vec3d([h; 3]);
    grid.vec3d([1.0 / h; 3]);
    grid.vec3d([1.0 / (h * h); 3]);
    grid.vec3d([0.5 / h; 3]);
    write_topology(&mut grid, &framed);
    let blocks_at = grid.0.len();
    for leaf in &framed.leaves {
        grid.words(&leaf.active);
        grid.u8(NO_MASK_AND_ALL_VALS);
        grid.f32s(&leaf.values);
    }

    // The header; the descriptor's offsets are absolute, so the header's length comes first.
    let descriptor_len = [GRID_NAME, GRID_TYPE, ""]
        .iter()
        .map(|s| 4 + s.len())
        .sum::<usize>()
        + 24;
    let header_len = 8 + 4 + 8 + 1 + 36 + 4 + 4;
    let grid_pos = (header_len + descriptor_len) as i64;
    let mut head = Bytes(Vec::new());
    head.i64(MAGIC);
    head.u32(FILE_VERSION);
    head.u32(LIBRARY_VERSION[0]);
    head.u32(LIBRARY_VERSION[1]);
    head.u8(1);
    head.0.extend_from_slice(uuid(&grid.0).as_bytes());
    head.i32(0);
    head.i32(1);
    head.string(GRID_NAME);
    head.string(GRID_TYPE);
    head.string("");
    head.i64(grid_pos);
    head.i64(grid_pos + blocks_at as i64);
    head.i64(grid_pos + grid.0.len() as i64);
    debug_assert_eq!(head.0.len() as i64, grid_pos);
    out.write_all(&head.0).map_err(ExportError::Write)?;
    out.write_all(&grid.0).map_err(ExportError::Write)?;
    Ok(())
}

/// The root (one child at the origin), its 32³ node, the 16³ nodes and the leaves' masks.
fn write_topology(out: &mut Bytes, g: &Framed) {
    let bg = g.background;
    out.u32(1);
    out.f32s(&[bg]);
    out.u32(0);
    out.u32(1);
    out.i32(0);
    out.i32(0);
    out.i32(0);
    let slot5 = |o: [i32; 3]| ((o[0] >> 7) * 1024 + (o[1] >> 7) * 32 + (o[2] >> 7)) as usize;
    let slot4 = |o: [i32; 3]| {
        (((o[0] & 127) >> 3) * 256 + ((o[1] & 127) >> 3) * 16 + ((o[2] & 127) >> 3)) as usize
    };
    // Leaves grouped by their 16³ node, in the 32³ node's slot order (which is the sorted order
    // of the node origins), and within a node in slot order (the sorted order of the leaves).
    let mut nodes: Vec<(usize, Vec<&Leaf>)> = Vec::new();
    for leaf in &g.leaves {
        let s = slot5(leaf.origin);
        match nodes.last_mut() {
            Some((last, members)) if *last == s => members.push(leaf),
            _ => nodes.push((s, vec![leaf])),
        }
    }
    // The inside blocks, by the 16³ node they fall in.
    let inside_node: std::collections::BTreeSet<usize> =
        g.inside.iter().map(|&o| slot5(o)).collect();
    let mut child5 = vec![0u64; 512];
    let mut values5 = vec![bg; 32768];
    for &s in &inside_node {
        values5[s] = -bg;
    }
    for (s, _) in &nodes {
        child5[s / 64] |= 1 << (s % 64);
        values5[*s] = 0.0;
    }
    out.words(&child5);
    out.words(&[0u64; 512]);
    out.u8(NO_MASK_AND_ALL_VALS);
    out.f32s(&values5);
    for (s, members) in &nodes {
        let mut child4 = vec![0u64; 64];
        let mut values4 = vec![bg; 4096];
        for &o in &g.inside {
            if slot5(o) == *s {
                values4[slot4(o)] = -bg;
            }
        }
        for leaf in members {
            let t = slot4(leaf.origin);
            child4[t / 64] |= 1 << (t % 64);
            values4[t] = 0.0;
        }
        out.words(&child4);
        out.words(&[0u64; 64]);
        out.u8(NO_MASK_AND_ALL_VALS);
        out.f32s(&values4);
        for leaf in members {
            out.words(&leaf.active);
        }
    }
}

/// Smallest and largest index of an active voxel.
fn active_bounds(leaves: &[Leaf]) -> Option<([i32; 3], [i32; 3])> {
    let mut bounds: Option<([i32; 3], [i32; 3])> = None;
    for leaf in leaves {
        for n in 0..BLOCK_VOXELS {
            if leaf.active[n / 64] >> (n % 64) & 1 == 1 {
                let offset = [n / 64, (n / 8) % 8, n % 8];
                let p = [0, 1, 2].map(|a| leaf.origin[a] + offset[a] as i32);
                let (lo, hi) = bounds.get_or_insert((p, p));
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
        }
    }
    bounds
}

/// A version-4-style UUID (36 characters) from the BLAKE3 hash of `bytes`.
fn uuid(bytes: &[u8]) -> String {
    let h = blake3::hash(bytes);
    let mut b: [u8; 16] = h.as_bytes()[..16].try_into().unwrap_or([0; 16]);
    b[6] = (b[6] & 0x0f) | 0x40;
    b[8] = (b[8] & 0x3f) | 0x80;
    let hex: String = b.iter().map(|x| format!("{x:02X}")).collect();
    format!(
        "{}-{}-{}-{}-{}",
        &hex[0..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..32]
    )
}

/// A little-endian reader over a byte slice for [`read_info`]; every read is bounds-checked.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], ExportError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or_else(|| {
            ExportError::Format(format!(
                "not a readable OpenVDB file: it ends at byte {}",
                self.bytes.len()
            ))
        })?;
        let out = &self.bytes[self.at..end];
        self.at = end;
        Ok(out)
    }
    fn u32(&mut self) -> Result<u32, ExportError> {
        Ok(u32::from_le_bytes(
            self.take(4)?.try_into().unwrap_or_default(),
        ))
    }
    fn i64(&mut self) -> Result<i64, ExportError> {
        Ok(i64::from_le_bytes(
            self.take(8)?.try_into().unwrap_or_default(),
        ))
    }
    fn vec3d(&mut self) -> Result<[f64; 3], ExportError> {
        let mut v = [0.0; 3];
        for c in &mut v {
            *c = f64::from_le_bytes(self.take(8)?.try_into().unwrap_or_default());
        }
        Ok(v)
    }
    fn string(&mut self) -> Result<String, ExportError> {
        let n = self.u32()? as usize;
        Ok(String::from_utf8_lossy(self.take(n)?).into_owned())
    }
    /// A metadata block: a count, then name, type name and sized value per entry.
    fn metadata(&mut self) -> Result<serde_json::Map<String, serde_json::Value>, ExportError> {
        let count = self.u32()?;
        let mut map = serde_json::Map::new();
        for _ in 0..count {
            let name = self.string()?;
            let type_name = self.string()?;
            let size = self.u32()? as usize;
            let value = self.take(size)?;
            map.insert(name, metadata_value(&type_name, value));
        }
        Ok(map)
    }
}

/// A metadata value as JSON: strings, booleans, numbers and 3-vectors decoded; other types by
/// their type name and size.
fn metadata_value(type_name: &str, v: &[u8]) -> serde_json::Value {
    let le4 = |c: &[u8]| <[u8; 4]>::try_from(c).unwrap_or_default();
    let le8 = |c: &[u8]| <[u8; 8]>::try_from(c).unwrap_or_default();
    match (type_name, v.len()) {
        ("string", _) => String::from_utf8_lossy(v).into(),
        ("bool", 1) => (v[0] != 0).into(),
        ("int32", 4) => i32::from_le_bytes(le4(v)).into(),
        ("int64", 8) => i64::from_le_bytes(le8(v)).into(),
        ("float", 4) => f32::from_le_bytes(le4(v)).into(),
        ("double", 8) => f64::from_le_bytes(le8(v)).into(),
        ("vec3i", 12) => v
            .chunks(4)
            .map(|c| i32::from_le_bytes(le4(c)))
            .collect::<Vec<_>>()
            .into(),
        ("vec3d", 24) => v
            .chunks(8)
            .map(|c| f64::from_le_bytes(le8(c)))
            .collect::<Vec<_>>()
            .into(),
        _ => format!("{type_name} ({} bytes)", v.len()).into(),
    }
}

/// What `stablesurf info` shows of an OpenVDB file: its format and library versions, and per
/// grid its name, tree type, metadata (class, bounds, voxel count, …) and, for the maps this
/// writer uses, the voxel size and translation. The grids' trees are not read.
///
/// # Errors
/// [`ExportError::Format`] when the bytes are not an OpenVDB file of format version 222 or
/// later (the versions that record grid offsets and per-grid compression), or end early.
pub fn read_info(bytes: &[u8]) -> Result<serde_json::Value, ExportError> {
    let mut r = Reader { bytes, at: 0 };
    if r.i64()? != MAGIC {
        return Err(ExportError::Format(
            "not an OpenVDB file (no VDB magic number)".into(),
        ));
    }
    let file_version = r.u32()?;
    if file_version < 222 {
        return Err(ExportError::Format(format!(
            "OpenVDB file format {file_version} is older than 222, which info does not read"
        )));
    }
    let library = [r.u32()?, r.u32()?];
    if r.take(1)?[0] == 0 {
        return Err(ExportError::Format(
            "an OpenVDB file without grid offsets".into(),
        ));
    }
    let uuid = String::from_utf8_lossy(r.take(36)?).into_owned();
    let file_metadata = r.metadata()?;
    let n_grids = r.u32()?;
    let mut grids = Vec::new();
    for _ in 0..n_grids {
        let name = r.string()?;
        let tree = r.string()?;
        let _instance_parent = r.string()?;
        let grid_pos = r.i64()?;
        let _blocks = r.i64()?;
        let end = r.i64()?;
        let mut g = Reader {
            bytes,
            at: usize::try_from(grid_pos).unwrap_or(usize::MAX),
        };
        let _compression = g.u32()?;
        let metadata = g.metadata()?;
        let map = g.string()?;
        let mut grid =
            serde_json::json!({"name": name, "tree": tree, "metadata": metadata, "map": map});
        if map == "UniformScaleTranslateMap" || map == "ScaleTranslateMap" {
            grid["translation"] = g.vec3d()?.to_vec().into();
            grid["voxel_size"] = g.vec3d()?.to_vec().into();
        }
        grids.push(grid);
        r.at = usize::try_from(end).unwrap_or(usize::MAX).max(r.at);
    }
    Ok(serde_json::json!({
        "format": "vdb",
        "file_version": file_version,
        "library_version": format!("{}.{}", library[0], library[1]),
        "uuid": uuid,
        "metadata": file_metadata,
        "grids": grids,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloud::Aabb;
    use crate::distance::volume::{narrow_band, VolumeParams, VoxelSize};
    use crate::poly::ImplicitPolynomial;
    use crate::polygonize::{polygonize, PolygonizeParams};

    /// A reader of the few things the writer puts down, in order.
    struct Reader<'a> {
        bytes: &'a [u8],
        at: usize,
    }

    impl Reader<'_> {
        fn take(&mut self, n: usize) -> &[u8] {
            let out = &self.bytes[self.at..self.at + n];
            self.at += n;
            out
        }
        fn u32(&mut self) -> u32 {
            u32::from_le_bytes(self.take(4).try_into().unwrap())
        }
        fn i64(&mut self) -> i64 {
            i64::from_le_bytes(self.take(8).try_into().unwrap())
        }
        fn f32(&mut self) -> f32 {
            f32::from_le_bytes(self.take(4).try_into().unwrap())
        }
        fn f64(&mut self) -> f64 {
            f64::from_le_bytes(self.take(8).try_into().unwrap())
        }
        fn string(&mut self) -> String {
            let n = self.u32() as usize;
            String::from_utf8(self.take(n).to_vec()).unwrap()
        }
        fn words(&mut self, n: usize) -> Vec<u64> {
            (0..n)
                .map(|_| u64::from_le_bytes(self.take(8).try_into().unwrap()))
                .collect()
        }
        /// A node-values record of `n` values.
        fn values(&mut self, n: usize) -> Vec<f32> {
            assert_eq!(self.take(1), [NO_MASK_AND_ALL_VALS]);
            (0..n).map(|_| self.f32()).collect()
        }
    }

    fn ones(words: &[u64]) -> Vec<usize> {
        (0..words.len() * 64)
            .filter(|&i| words[i / 64] >> (i % 64) & 1 == 1)
            .collect()
    }

    fn sphere_band(h: f64) -> NarrowBand {
        let mut c = vec![0.0; 10];
        (c[0], c[4], c[7], c[9]) = (-1.0, 1.0, 1.0, 1.0);
        let poly = ImplicitPolynomial {
            degree: 2,
            coefficients: c,
            center: [0.0; 3],
            scale: 1.0,
        };
        let region = Aabb {
            min: [-1.3, -1.2, -1.1],
            max: [1.3, 1.2, 1.1],
        };
        let params = PolygonizeParams {
            depth: 5,
            ..Default::default()
        };
        let mesh = polygonize(&poly, &region, &params).unwrap().mesh;
        let params = VolumeParams {
            voxel_size: VoxelSize::Size(h),
        };
        narrow_band(&poly, &mesh, &region, &params).unwrap()
    }

    /// Reads the file back by the layout of the module docs: the header, the descriptor's
    /// offsets, the metadata, the transform, the topology and every leaf, and compares each
    /// with the band it was written from.
    #[test]
    fn file_structure_reads_back() {
        // 145 × 134 × 123 voxels: more than one 16³ node (128 voxels) along x and y.
        let band = sphere_band(0.018);
        assert!(band.grid.shape[0] > 128 && band.grid.shape[1] > 128);
        for up in [UpAxis::Z, UpAxis::Y] {
            let opts = VdbOptions {
                units: Some(LengthUnit::Mm),
                up,
            };
            let mut bytes = Vec::new();
            write(&band, &opts, &mut bytes).unwrap();
            let mut r = Reader {
                bytes: &bytes,
                at: 0,
            };
            assert_eq!(r.i64(), MAGIC);
            assert_eq!(r.u32(), 224);
            r.take(8);
            assert_eq!(r.take(1), [1]);
            let uuid = String::from_utf8(r.take(36).to_vec()).unwrap();
            assert_eq!(uuid.matches('-').count(), 4);
            assert_eq!((r.u32(), r.u32()), (0, 1));
            assert_eq!(r.string(), "surface");
            assert_eq!(r.string(), "Tree_float_5_4_3");
            assert_eq!(r.string(), "");
            let (grid_pos, blocks_pos, end_pos) = (r.i64(), r.i64(), r.i64());
            assert_eq!(grid_pos as usize, r.at);
            assert_eq!(end_pos as usize, bytes.len());
            assert_eq!(r.u32(), 0, "no compression");
            let n_meta = r.u32();
            let mut names = Vec::new();
            for _ in 0..n_meta {
                let name = r.string();
                let kind = r.string();
                let size = r.u32() as usize;
                let value = r.take(size).to_vec();
                match name.as_str() {
                    "class" => assert_eq!(value, b"level set"),
                    "name" => assert_eq!(value, b"surface"),
                    "is_saved_as_half_float" => {
                        assert_eq!((kind.as_str(), value), ("bool", vec![0]))
                    }
                    "file_voxel_count" => assert_eq!(
                        i64::from_le_bytes(value.try_into().unwrap()) as u64,
                        band.active_voxels()
                    ),
                    _ => {}
                }
                names.push(name);
            }
            let mut sorted = names.clone();
            sorted.sort();
            assert_eq!(names, sorted);
            assert!(names.contains(&"file_bbox_min".to_string()));
            assert_eq!(r.string(), "UniformScaleTranslateMap");
            let translation = [r.f64(), r.f64(), r.f64()];
            let h = band.grid.voxel_size * 0.001;
            for want in [h, h, 1.0 / h, 1.0 / (h * h), 0.5 / h] {
                for _ in 0..3 {
                    assert!((r.f64() - want).abs() <= 1e-12 * want);
                }
            }
            // Voxel (0, 0, 0) lands where the frame puts the grid's origin.
            let o = band.grid.origin.map(|c| c * 0.001);
            match up {
                UpAxis::Z => assert_eq!(translation, o),
                UpAxis::Y => {
                    // Index (0, J, 0) with J = last_z holds input voxel k = 0: world (x, −z, y).
                    let last_z = (band.grid.shape[2].div_ceil(8) * 8 - 1) as f64;
                    assert!((translation[1] + h * last_z - (-o[2])).abs() < 1e-12);
                    assert_eq!([translation[0], translation[2]], [o[0], o[1]]);
                }
            }
            // Topology: one buffer, the background, no root tiles, one child at the origin.
            assert_eq!(r.u32(), 1);
            let bg = r.f32();
            assert!((f64::from(bg) - 3.0 * h).abs() < 1e-9);
            assert_eq!((r.u32(), r.u32()), (0, 1));
            assert_eq!(r.take(12), [0; 12]);
            let children5 = ones(&r.words(512));
            assert!(ones(&r.words(512)).is_empty(), "no active tiles");
            let values5 = r.values(32768);
            assert!(values5.iter().all(|v| v.abs() == bg || *v == 0.0));
            let mut leaf_masks = Vec::new();
            let mut inside_tiles = 0;
            for _ in &children5 {
                let children4 = ones(&r.words(64));
                assert!(ones(&r.words(64)).is_empty());
                let values4 = r.values(4096);
                inside_tiles += values4.iter().filter(|&&v| v == -bg).count();
                for _ in &children4 {
                    leaf_masks.push(r.words(8));
                }
            }
            assert_eq!(leaf_masks.len(), band.blocks.len());
            assert_eq!(r.at as i64, blocks_pos);
            let mut active = 0;
            for mask in &leaf_masks {
                assert_eq!(&r.words(8), mask);
                let values = r.values(512);
                for n in ones(mask) {
                    assert!(values[n].abs() < bg);
                    active += 1;
                }
                assert!(values.iter().all(|v| v.abs() <= bg));
            }
            assert_eq!(active, band.active_voxels());
            assert!(children5.len() > 1);
            // The tiles inside the sphere carry −background.
            assert!(inside_tiles > 0);
            assert_eq!(r.at, bytes.len());
        }
    }

    #[test]
    fn info_reads_the_header_and_the_grid_metadata() {
        let band = sphere_band(0.1);
        let mut bytes = Vec::new();
        write(&band, &VdbOptions::default(), &mut bytes).unwrap();
        let info = read_info(&bytes).unwrap();
        assert_eq!(info["format"], "vdb");
        assert_eq!(info["file_version"], FILE_VERSION);
        let grid = &info["grids"][0];
        assert_eq!(grid["name"], GRID_NAME);
        assert_eq!(grid["tree"], GRID_TYPE);
        assert_eq!(grid["metadata"]["class"], "level set");
        assert_eq!(grid["metadata"]["is_saved_as_half_float"], false);
        assert!(grid["metadata"]["file_voxel_count"].as_i64().unwrap() > 0);
        assert_eq!(grid["map"], "UniformScaleTranslateMap");
        let h = grid["voxel_size"][0].as_f64().unwrap();
        assert!((h - 0.1).abs() < 1e-12, "{grid}");
        // A file cut before its grid's transform is an error, never a panic (the trees are not
        // read, so a file cut inside them still shows its header).
        for n in [0, 7, 20, 60, 200, 400] {
            assert!(read_info(&bytes[..n]).is_err(), "prefix of {n} bytes");
        }
    }

    #[test]
    fn bytes_are_deterministic() {
        let band = sphere_band(0.1);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        write(&band, &VdbOptions::default(), &mut a).unwrap();
        write(&band.clone(), &VdbOptions::default(), &mut b).unwrap();
        assert_eq!(a, b);
    }
}

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn write() -> Result<(), Box<dyn std::error::Error>> {
        use crate::cloud::Aabb;
        use crate::distance::volume::{narrow_band, VolumeParams, VoxelSize};
        use crate::export::vdb::{write, VdbOptions};
        use crate::polygonize::{polygonize, PolygonizeParams};
        use crate::ImplicitPolynomial;
        let mut c = vec![0.0; 10];
        (c[0], c[4], c[7], c[9]) = (-1.0, 1.0, 1.0, 1.0);
        let sphere = ImplicitPolynomial {
            degree: 2,
            coefficients: c,
            center: [0.0; 3],
            scale: 1.0,
        };
        let region = Aabb {
            min: [-1.5; 3],
            max: [1.5; 3],
        };
        let mesh = polygonize(
            &sphere,
            &region,
            &PolygonizeParams {
                depth: 4,
                ..Default::default()
            },
        )?
        .mesh;
        let band = narrow_band(
            &sphere,
            &mesh,
            &region,
            &VolumeParams {
                voxel_size: VoxelSize::Size(0.2),
            },
        )
        .unwrap();
        let mut bytes = Vec::new();
        write(&band, &VdbOptions::default(), &mut bytes).unwrap();
        assert_eq!(&bytes[..8], &[0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0]);
        Ok(())
    }
}
