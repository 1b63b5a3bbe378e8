//! Compact binary encoding of the artifacts stored in the cache.
//!
//! Input: an artifact and the identity of its entry. Output: bytes, and back. Layout of one entry:
//!
//! ```text
//! "SSCA" | u32 cache format version | u32 artifact kind | u32 artifact format version
//!        | 32-byte key | u32 stage version | u64 length + stage name
//!        | u64 length + meta (JSON: what went into the key, the stage's figures)
//!        | u64 payload length | payload | 32-byte blake3 of everything before it
//! ```
//!
//! Numbers are little-endian; `f64` values are stored bit-exactly, so a decoded artifact equals
//! the encoded one. An entry proves its identity: the key, stage and versions it was stored
//! under sit inside the checksummed bytes, so a file copied or renamed onto another key's path
//! is refused, and so is one whose figures were edited. Any mismatch (magic, versions, identity,
//! length, checksum, trailing bytes) makes [`decode_entry`] return `None`, which the cache
//! treats as a miss.

use crate::cloud::{OrientedCloud, PointCloud, RangeSurface, ScanOrigin};
use crate::mesh::TriangleMesh;
use crate::poly::ImplicitModel;

use super::{Key, CACHE_FORMAT_VERSION};

const MAGIC: &[u8; 4] = b"SSCA";

/// An artifact the cache can store.
pub trait Artifact: Sized {
    /// A number unique to the artifact type.
    const KIND: u32;
    /// The artifact's own layout version.
    const VERSION: u32;
    /// Appends the payload bytes.
    fn encode_payload(&self, out: &mut Vec<u8>);
    /// Reads the payload back; `None` when it is malformed.
    fn decode_payload(r: &mut Reader<'_>) -> Option<Self>;
}

/// What an entry is stored under: checked on every read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EntryId {
    /// The full key.
    pub key: Key,
    /// The stage that made the artifact.
    pub stage: String,
    /// That stage's version.
    pub stage_version: u32,
}

/// A decoded entry: its identity, its explanation and figures (JSON), and the artifact.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry<T> {
    /// What the entry says it was stored under.
    pub id: EntryId,
    /// The explanation stored with it (what went into the key, the stage's figures).
    pub meta: serde_json::Value,
    /// The artifact.
    pub value: T,
}

/// Encodes an artifact with its identity and explanation as a self-checking cache entry.
pub fn encode<T: Artifact>(artifact: &T, id: &EntryId, meta: &serde_json::Value) -> Vec<u8> {
    let mut payload = Vec::new();
    artifact.encode_payload(&mut payload);
    let meta = serde_json::to_vec(meta).expect("json value serializes");
    let mut out = Vec::with_capacity(payload.len() + meta.len() + 128);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&CACHE_FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&T::KIND.to_le_bytes());
    out.extend_from_slice(&T::VERSION.to_le_bytes());
    out.extend_from_slice(&id.key.0);
    out.extend_from_slice(&id.stage_version.to_le_bytes());
    for field in [id.stage.as_bytes(), &meta] {
        out.extend_from_slice(&(field.len() as u64).to_le_bytes());
        out.extend_from_slice(field);
    }
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&payload);
    let digest = blake3::hash(&out);
    out.extend_from_slice(digest.as_bytes());
    out
}

/// Decodes a cache entry; `None` when it is corrupt, truncated or of another version or type.
/// The identity is returned, not checked: `decode_as` checks it.
pub fn decode_entry<T: Artifact>(bytes: &[u8]) -> Option<Entry<T>> {
    let body_len = bytes.len().checked_sub(32)?;
    let (body, digest) = bytes.split_at(body_len);
    if blake3::hash(body).as_bytes() != digest {
        return None;
    }
    let mut r = Reader { bytes: body };
    if r.take(4)? != MAGIC
        || r.u32()? != CACHE_FORMAT_VERSION
        || r.u32()? != T::KIND
        || r.u32()? != T::VERSION
    {
        return None;
    }
    let key = Key(r.take(32)?.try_into().ok()?);
    let stage_version = r.u32()?;
    let stage = std::str::from_utf8(r.bytes()?).ok()?.to_string();
    let meta = serde_json::from_slice(r.bytes()?).ok()?;
    let len = usize::try_from(r.u64()?).ok()?;
    if r.bytes.len() != len {
        return None;
    }
    let value = T::decode_payload(&mut r)?;
    r.bytes.is_empty().then_some(Entry {
        id: EntryId {
            key,
            stage,
            stage_version,
        },
        meta,
        value,
    })
}

/// Whether `bytes` are a whole entry of this cache format stored under the key whose hex is
/// `key_hex` by `stage`: checksum, magic, format version, identity and lengths, whatever the
/// artifact's type (whose payload the checksum covers).
pub(crate) fn envelope_matches(bytes: &[u8], key_hex: &str, stage: &str) -> bool {
    (|| {
        let body_len = bytes.len().checked_sub(32)?;
        let (body, digest) = bytes.split_at(body_len);
        if blake3::hash(body).as_bytes() != digest {
            return None;
        }
        let mut r = Reader { bytes: body };
        if r.take(4)? != MAGIC || r.u32()? != CACHE_FORMAT_VERSION {
            return None;
        }
        let (_kind, _version) = (r.u32()?, r.u32()?);
        let key = Key(r.take(32)?.try_into().ok()?);
        let _stage_version = r.u32()?;
        let stored_stage = std::str::from_utf8(r.bytes()?).ok()?.to_string();
        let _meta = r.bytes()?;
        let len = usize::try_from(r.u64()?).ok()?;
        (key.hex() == key_hex && stored_stage == stage && r.bytes.len() == len).then_some(())
    })()
    .is_some()
}

/// Decodes a cache entry that must have been stored as `id`; `None` otherwise.
pub(crate) fn decode_as<T: Artifact>(bytes: &[u8], id: &EntryId) -> Option<Entry<T>> {
    decode_entry(bytes).filter(|e| &e.id == id)
}

/// The artifact of a cache entry, whatever it was stored under (for tools that read a cache).
pub fn decode<T: Artifact>(bytes: &[u8]) -> Option<T> {
    decode_entry(bytes).map(|e| e.value)
}

/// A cursor over payload bytes.
pub struct Reader<'a> {
    bytes: &'a [u8],
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        if self.bytes.len() < n {
            return None;
        }
        let (head, tail) = self.bytes.split_at(n);
        self.bytes = tail;
        Some(head)
    }

    fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }

    fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }

    /// A length-prefixed vector of fixed-size items, refusing lengths the bytes cannot hold.
    fn vec<const N: usize, T>(&mut self, item: impl Fn(&[u8; N]) -> T) -> Option<Vec<T>> {
        let n = usize::try_from(self.u64()?).ok()?;
        let raw = self.take(n.checked_mul(N)?)?;
        Some(
            raw.chunks_exact(N)
                .map(|c| item(c.try_into().expect("chunk of N bytes")))
                .collect(),
        )
    }

    fn vec3_f64(&mut self) -> Option<Vec<[f64; 3]>> {
        self.vec::<24, _>(|c| {
            [0, 1, 2].map(|a| f64::from_le_bytes(c[8 * a..8 * a + 8].try_into().expect("8 bytes")))
        })
    }

    fn vec3_u32(&mut self) -> Option<Vec<[u32; 3]>> {
        self.vec::<12, _>(|c| {
            [0, 1, 2].map(|a| u32::from_le_bytes(c[4 * a..4 * a + 4].try_into().expect("4 bytes")))
        })
    }

    fn f32s(&mut self) -> Option<Vec<f32>> {
        self.vec::<4, _>(|c| f32::from_le_bytes(*c))
    }

    fn vec3_u16(&mut self) -> Option<Vec<[u16; 3]>> {
        self.vec::<6, _>(|c| [0, 1, 2].map(|a| u16::from_le_bytes([c[2 * a], c[2 * a + 1]])))
    }

    /// `None` (the field absent) after a 0 byte, `read`'s value after a 1 byte; any other byte
    /// is malformed (`Some(None)` is returned as the outer `None`).
    fn optional<T>(&mut self, read: impl FnOnce(&mut Self) -> Option<T>) -> Option<Option<T>> {
        match self.take(1)?[0] {
            0 => Some(None),
            1 => Some(Some(read(self)?)),
            _ => None,
        }
    }

    fn bytes(&mut self) -> Option<&'a [u8]> {
        let n = usize::try_from(self.u64()?).ok()?;
        self.take(n)
    }
}

fn put_vec3_f64(out: &mut Vec<u8>, v: &[[f64; 3]]) {
    out.extend_from_slice(&(v.len() as u64).to_le_bytes());
    for p in v {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
}

fn put_vec3_u16(out: &mut Vec<u8>, v: &[[u16; 3]]) {
    out.extend_from_slice(&(v.len() as u64).to_le_bytes());
    for t in v {
        for c in t {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
}

fn put_f32s(out: &mut Vec<u8>, v: &[f32]) {
    out.extend_from_slice(&(v.len() as u64).to_le_bytes());
    for x in v {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

/// A 0 byte for `None`, else a 1 byte and `put`'s bytes: what [`Reader::optional`] reads.
fn put_optional<T: ?Sized>(
    out: &mut Vec<u8>,
    value: Option<&T>,
    put: impl FnOnce(&mut Vec<u8>, &T),
) {
    out.push(u8::from(value.is_some()));
    if let Some(v) = value {
        put(out, v);
    }
}

fn put_vec3_u32(out: &mut Vec<u8>, v: &[[u32; 3]]) {
    out.extend_from_slice(&(v.len() as u64).to_le_bytes());
    for t in v {
        for c in t {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
}

impl Artifact for PointCloud {
    const KIND: u32 = 1;
    const VERSION: u32 = PointCloud::FORMAT_VERSION;

    fn encode_payload(&self, out: &mut Vec<u8>) {
        put_vec3_f64(out, &self.points);
        out.push(u8::from(self.normals.is_some()));
        if let Some(normals) = &self.normals {
            put_vec3_f64(out, normals);
        }
        put_vec3_u32(out, &self.triangles);
        out.push(u8::from(self.range.is_some()));
        if let Some(range) = &self.range {
            out.push(u8::from(range.sensor.is_some()));
            for c in range.sensor.unwrap_or_default() {
                out.extend_from_slice(&c.to_le_bytes());
            }
            put_f32s(out, &range.falloff);
        }
        out.push(u8::from(self.colours.is_some()));
        if let Some(colours) = &self.colours {
            put_vec3_u16(out, colours);
        }
        out.push(u8::from(self.intensity.is_some()));
        if let Some(intensity) = &self.intensity {
            put_f32s(out, intensity);
        }
        out.push(u8::from(self.scans.is_some()));
        if let Some(scans) = &self.scans {
            put_vec3_f64(out, &scans.iter().map(|s| s.sensor).collect::<Vec<_>>());
            for s in scans {
                out.extend_from_slice(&(s.n_points as u64).to_le_bytes());
            }
        }
    }

    fn decode_payload(r: &mut Reader<'_>) -> Option<Self> {
        let points = r.vec3_f64()?;
        let normals = match r.take(1)?[0] {
            0 => None,
            1 => Some(r.vec3_f64()?),
            _ => return None,
        };
        let triangles = r.vec3_u32()?;
        let range = match r.take(1)?[0] {
            0 => None,
            1 => {
                let has_sensor = r.take(1)?[0];
                let raw = r.take(24)?;
                let sensor = [0, 1, 2].map(|a| {
                    f64::from_le_bytes(raw[8 * a..8 * a + 8].try_into().expect("8 bytes"))
                });
                Some(RangeSurface {
                    sensor: match has_sensor {
                        0 => None,
                        1 => Some(sensor),
                        _ => return None,
                    },
                    falloff: r.f32s()?,
                })
            }
            _ => return None,
        };
        let colours = r.optional(Reader::vec3_u16)?;
        let intensity = r.optional(Reader::f32s)?;
        let scans = r.optional(|r| {
            let sensors = r.vec3_f64()?;
            sensors
                .into_iter()
                .map(|sensor| {
                    Some(ScanOrigin {
                        sensor,
                        n_points: usize::try_from(r.u64()?).ok()?,
                    })
                })
                .collect::<Option<Vec<_>>>()
        })?;
        Some(PointCloud {
            points,
            normals,
            triangles,
            range,
            colours,
            intensity,
            scans,
        })
    }
}

impl Artifact for OrientedCloud {
    const KIND: u32 = 2;
    const VERSION: u32 = OrientedCloud::FORMAT_VERSION;

    fn encode_payload(&self, out: &mut Vec<u8>) {
        put_vec3_f64(out, &self.points);
        put_vec3_f64(out, &self.normals);
        out.push(u8::from(self.weights.is_some()));
        if let Some(weights) = &self.weights {
            put_f32s(out, weights);
        }
    }

    fn decode_payload(r: &mut Reader<'_>) -> Option<Self> {
        // Fields are read in the order written.
        Some(OrientedCloud {
            points: r.vec3_f64()?,
            normals: r.vec3_f64()?,
            weights: match r.take(1)?[0] {
                0 => None,
                1 => Some(r.f32s()?),
                _ => return None,
            },
        })
    }
}

impl Artifact for TriangleMesh {
    const KIND: u32 = 3;
    const VERSION: u32 = TriangleMesh::FORMAT_VERSION;

    fn encode_payload(&self, out: &mut Vec<u8>) {
        put_vec3_f64(out, &self.positions);
        put_vec3_f64(out, &self.normals);
        put_vec3_u32(out, &self.triangles);
    }

    fn decode_payload(r: &mut Reader<'_>) -> Option<Self> {
        Some(TriangleMesh {
            positions: r.vec3_f64()?,
            normals: r.vec3_f64()?,
            triangles: r.vec3_u32()?,
        })
    }
}

/// The model is small (a few hundred numbers plus diagnostics): JSON inside the checked
/// envelope; serde_json writes `f64` so that it reads back to the same bits.
impl Artifact for ImplicitModel {
    const KIND: u32 = 4;
    const VERSION: u32 = ImplicitModel::FORMAT_VERSION;

    fn encode_payload(&self, out: &mut Vec<u8>) {
        let json = serde_json::to_vec(self).expect("a model always serializes");
        out.extend_from_slice(&(json.len() as u64).to_le_bytes());
        out.extend_from_slice(&json);
    }

    fn decode_payload(r: &mut Reader<'_>) -> Option<Self> {
        serde_json::from_slice(r.bytes()?).ok()
    }
}

/// The detail model: its `stablesurf.mpu` file bytes inside the checked envelope (the file
/// format is versioned on its own; a file that fails to read back is a miss).
impl Artifact for crate::detail::MpuModel {
    const KIND: u32 = 6;
    const VERSION: u32 = crate::detail::STAGE_VERSION;

    fn encode_payload(&self, out: &mut Vec<u8>) {
        let file = crate::model::mpu::mpu_bytes(self).expect("plain diagnostics always encode");
        out.extend_from_slice(&(file.len() as u64).to_le_bytes());
        out.extend_from_slice(&file);
    }

    fn decode_payload(r: &mut Reader<'_>) -> Option<Self> {
        crate::model::mpu::read_mpu(r.bytes()?, std::path::Path::new("cache entry")).ok()
    }
}

/// The bytes of a run's output files, by path relative to the output directory (the cached
/// result of the pipeline's `export` stage).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct OutputFiles(pub Vec<(String, Vec<u8>)>);

impl Artifact for OutputFiles {
    const KIND: u32 = 5;
    const VERSION: u32 = 1;

    fn encode_payload(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&(self.0.len() as u64).to_le_bytes());
        for (name, bytes) in &self.0 {
            for field in [name.as_bytes(), bytes.as_slice()] {
                out.extend_from_slice(&(field.len() as u64).to_le_bytes());
                out.extend_from_slice(field);
            }
        }
    }

    fn decode_payload(r: &mut Reader<'_>) -> Option<Self> {
        let n = usize::try_from(r.u64()?).ok()?;
        let mut files = Vec::new();
        for _ in 0..n {
            let name = std::str::from_utf8(r.bytes()?).ok()?.to_string();
            files.push((name, r.bytes()?.to_vec()));
        }
        Some(OutputFiles(files))
    }
}

/// The finished mesh: the mesh as written, the closed mesh when it differs, and the per-vertex
/// distances and colours.
impl Artifact for crate::finish::Finished {
    const KIND: u32 = 7;
    const VERSION: u32 = 1;

    fn encode_payload(&self, out: &mut Vec<u8>) {
        self.mesh.encode_payload(out);
        put_optional(out, self.closed.as_ref(), |out, m| m.encode_payload(out));
        put_optional(out, self.quality.as_deref(), put_f32s);
        put_optional(out, self.colours.as_deref(), |out, c| {
            out.extend_from_slice(&(c.len() as u64).to_le_bytes());
            out.extend(c.iter().flatten());
        });
    }

    fn decode_payload(r: &mut Reader<'_>) -> Option<Self> {
        Some(crate::finish::Finished {
            mesh: TriangleMesh::decode_payload(r)?,
            closed: r.optional(TriangleMesh::decode_payload)?,
            quality: r.optional(Reader::f32s)?,
            colours: r.optional(|r| r.vec::<3, _>(|c| *c))?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud() -> PointCloud {
        PointCloud {
            points: vec![[0.0, 1.5, -2.25], [1e-300, f64::MAX, 3.0]],
            normals: Some(vec![[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
            triangles: vec![[0, 1, 1]],
            range: Some(RangeSurface {
                sensor: Some([0.0, 0.2, 1.3]),
                falloff: vec![0.25, 1.0],
            }),
            colours: Some(vec![[0, 65535, 257], [1, 2, 3]]),
            intensity: Some(vec![0.5, 1e30]),
            scans: Some(vec![
                ScanOrigin {
                    sensor: [1.0, -2.0, 0.5],
                    n_points: 1,
                },
                ScanOrigin {
                    sensor: [0.0; 3],
                    n_points: 1,
                },
            ]),
        }
    }

    fn id(stage: &str) -> EntryId {
        EntryId {
            key: Key::of_bytes(stage.as_bytes()),
            stage: stage.into(),
            stage_version: 3,
        }
    }

    fn encode<T: Artifact>(artifact: &T) -> Vec<u8> {
        super::encode(
            artifact,
            &id("import"),
            &serde_json::json!({"figures": {"n": 2}}),
        )
    }

    #[test]
    fn round_trip_is_exact() {
        let c = cloud();
        assert_eq!(decode::<PointCloud>(&encode(&c)), Some(c.clone()));
        // Every optional field absent.
        let plain = PointCloud {
            points: c.points.clone(),
            ..Default::default()
        };
        assert_eq!(decode::<PointCloud>(&encode(&plain)), Some(plain));
        let entry = decode_as::<PointCloud>(&encode(&c), &id("import")).unwrap();
        assert_eq!(entry.meta["figures"]["n"], 2);
        assert_eq!(entry.value, c);
        let m = TriangleMesh {
            positions: vec![[0.1, 0.2, 0.3]],
            normals: vec![[0.0, 1.0, 0.0]],
            triangles: vec![[0, 0, 0]],
        };
        assert_eq!(decode::<TriangleMesh>(&encode(&m)), Some(m.clone()));
        let finished = crate::finish::Finished {
            mesh: m.clone(),
            closed: Some(TriangleMesh {
                triangles: vec![],
                ..m.clone()
            }),
            quality: Some(vec![0.5, f32::MIN_POSITIVE]),
            colours: Some(vec![[1, 2, 3], [255, 0, 128]]),
        };
        assert_eq!(
            decode::<crate::finish::Finished>(&encode(&finished)),
            Some(finished)
        );
        let bare = crate::finish::Finished {
            mesh: m,
            ..Default::default()
        };
        assert_eq!(
            decode::<crate::finish::Finished>(&encode(&bare)),
            Some(bare)
        );
    }

    #[test]
    fn any_flipped_byte_or_truncation_is_rejected() {
        let bytes = encode(&cloud());
        for i in 0..bytes.len() {
            let mut bad = bytes.clone();
            bad[i] ^= 0x40;
            assert!(
                decode::<PointCloud>(&bad).is_none(),
                "flip at byte {i} accepted"
            );
        }
        for n in 0..bytes.len() {
            assert!(
                decode::<PointCloud>(&bytes[..n]).is_none(),
                "truncation to {n} accepted"
            );
        }
    }

    #[test]
    fn output_files_round_trip() {
        let files = OutputFiles(vec![
            ("a.ply".into(), vec![1, 2, 3]),
            ("slices/b.exr".into(), vec![]),
        ]);
        assert_eq!(decode::<OutputFiles>(&encode(&files)), Some(files));
    }

    #[test]
    fn an_entry_stored_under_another_identity_is_refused() {
        let bytes = encode(&cloud());
        assert!(decode_as::<PointCloud>(&bytes, &id("import")).is_some());
        assert!(decode_as::<PointCloud>(&bytes, &id("normals")).is_none());
        let other_key = EntryId {
            key: Key::of_bytes(b"another"),
            ..id("import")
        };
        assert!(decode_as::<PointCloud>(&bytes, &other_key).is_none());
        let other_version = EntryId {
            stage_version: 4,
            ..id("import")
        };
        assert!(decode_as::<PointCloud>(&bytes, &other_version).is_none());
    }

    #[test]
    fn wrong_kind_is_rejected() {
        assert!(decode::<OrientedCloud>(&encode(&cloud())).is_none());
    }
}
