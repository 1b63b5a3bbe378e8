//! Export stage, glTF 2.0 writer: [`TriangleMesh`] → `.glb` (one file) or `.gltf` + `.bin`.
//!
//! Input: a triangle mesh in input coordinates. Output: a glTF 2.0 asset (Khronos, *glTF 2.0
//! Specification*) with one buffer, three buffer views (positions, normals, indices), three
//! accessors, one mesh with one triangle primitive, one material, one node and one scene, and
//! `asset.generator = "stablesurf"`. The JSON is built with `gltf-json` and the binary container
//! framed with `gltf::binary::Glb`.
//!
//! Invariants of what is written, all checked by the Khronos glTF-Validator in `tests/all/export.rs`:
//! positions and normals are `f32` `VEC3`, little-endian, tightly packed; the POSITION accessor
//! carries the exact per-component `min`/`max` of the `f32` values written (the validator compares
//! them bit for bit); normals are renormalised in `f32`; indices are `u16` when every index fits
//! below the primitive-restart value 65535 and `u32` otherwise; triangles keep the mesh's
//! counter-clockwise-from-outside winding, which is glTF's front face. The output is
//! deterministic: the same mesh and options give the same bytes.
//!
//! glTF is +Y up and in metres. A scan from a Z-up device appears lying on its back in Blender;
//! [`UpAxis::Z`] rotates it upright with the proper rotation (x, y, z) ↦ (x, z, −y) applied to
//! positions and normals, which Blender's importer maps back to the original (x, y, z) in its own
//! Z-up frame. With [`GltfOptions::units`] the positions are scaled to metres (a millimetre scan
//! by 0.001); without, they are written unchanged (a scan in metres needs no unit).
//!
//! Far-off coordinates (a LiDAR tile in UTM coordinates, where `f32` steps are 0.25 m; the
//! test is `needs_double`) are written relative to the centre of
//! their bounding box, and the node's `translation` holds that centre as a JSON number with every
//! digit of the `f64`: the shape keeps its detail and viewers place it where it belongs. Other
//! meshes are written as before, with no translation.
//!
//! Vertex colours ([`write_glb_coloured`], [`write_gltf_coloured`]) come in as 8-bit sRGB, as
//! scans store them, and are written after the indices as a fourth buffer view and a `COLOR_0`
//! accessor of `f32` `VEC3` *linear* RGB (glTF defines `COLOR_0` as linear; the sRGB transfer
//! function of IEC 61966-2-1 is undone, so Blender and three.js show the scan's own colours).
//! Float rather than normalized bytes: linear 8-bit values would lose the dark shades. The
//! material's base colour factor, which multiplies them, is then white. Without colours the file
//! is as before.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::io::Write;

use gltf_json as json;
use json::validation::Checked::Valid;
use json::validation::USize64;

pub use crate::frame::UpAxis;

use crate::export::units::LengthUnit;
use crate::export::ExportError;
use crate::mesh::TriangleMesh;

/// Options of the glTF writers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct GltfOptions {
    /// Which input axis points up; default [`UpAxis::Y`] (no change).
    pub up: UpAxis,
    /// The unit of the input coordinates: positions are scaled to metres, glTF's unit. `None`
    /// (the default) writes them unchanged.
    pub units: Option<LengthUnit>,
}

/// The largest index a `u16` index buffer may hold: 65535 is the primitive-restart value.
const MAX_U16_INDEX: u32 = 65534;

/// Writes `mesh` as a binary glTF (`.glb`) to `out`.
///
/// ```
/// use stablesurf::export::gltf::{write_glb, GltfOptions};
/// use stablesurf::TriangleMesh;
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 3],
///     triangles: vec![[0, 1, 2]],
/// };
/// let mut glb = Vec::new();
/// write_glb(&mesh, &mut glb, &GltfOptions::default()).unwrap();
/// assert_eq!(&glb[0..4], b"glTF");
/// assert_eq!(u32::from_le_bytes([glb[8], glb[9], glb[10], glb[11]]) as usize, glb.len());
/// ```
///
/// # Errors
/// [`ExportError::InvalidMesh`] when the mesh is empty, has non-finite coordinates or zero
/// normals, or an index out of range; [`ExportError::TooLarge`] when the file would exceed the
/// 4 GiB limit of the GLB container; [`ExportError::Write`] when `out` fails.
pub fn write_glb(
    mesh: &TriangleMesh,
    out: &mut impl Write,
    opts: &GltfOptions,
) -> Result<(), ExportError> {
    write_glb_coloured(mesh, None, out, opts)
}

/// [`write_glb`] with one 8-bit sRGB colour per vertex, written as the `COLOR_0` attribute
/// (linear RGB `f32` `VEC3`, see the module docs) when `colours` is given.
///
/// ```
/// use stablesurf::export::gltf::{write_glb_coloured, GltfOptions};
/// use stablesurf::TriangleMesh;
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 3],
///     triangles: vec![[0, 1, 2]],
/// };
/// let colours = [[255, 0, 0], [0, 255, 0], [0, 0, 255]];
/// let mut glb = Vec::new();
/// write_glb_coloured(&mesh, Some(&colours), &mut glb, &GltfOptions::default()).unwrap();
/// assert!(glb.windows(9).any(|w| w == b"\"COLOR_0\""));
/// ```
///
/// # Errors
/// As [`write_glb`], and [`ExportError::InvalidMesh`] when `colours` does not hold one colour
/// per vertex.
pub fn write_glb_coloured(
    mesh: &TriangleMesh,
    colours: Option<&[[u8; 3]]>,
    out: &mut impl Write,
    opts: &GltfOptions,
) -> Result<(), ExportError> {
    let (root, bin, translation) = encode(mesh, colours, opts, None)?;
    let json_bytes = json_bytes(&root, translation, false)?;
    // 12-byte file header, two 8-byte chunk headers, both chunks padded to 4 bytes.
    let total = 12 + 8 + json_bytes.len().next_multiple_of(4) + 8 + bin.len().next_multiple_of(4);
    let length = u32::try_from(total).map_err(|_| ExportError::TooLarge {
        what: "binary glTF".into(),
        bytes: total as u64,
        limit: u64::from(u32::MAX),
    })?;
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length,
        },
        json: Cow::Owned(json_bytes),
        bin: Some(Cow::Owned(bin)),
    };
    glb.to_writer(out).map_err(|e| match e {
        gltf::Error::Io(io) => ExportError::Write(io),
        other => ExportError::Format(format!("cannot frame binary glTF: {other}")),
    })
}

/// Writes `mesh` as a JSON glTF to `json_out` and its buffer to `bin_out`; the JSON refers to
/// the buffer by `bin_uri` (a URI relative to the `.gltf` file, such as `"mesh.bin"`), with one
/// 8-bit sRGB colour per vertex, written as the `COLOR_0` attribute, when `colours` is given (as
/// [`write_glb_coloured`]).
///
/// ```
/// use stablesurf::export::gltf::{write_gltf_coloured, GltfOptions, UpAxis};
/// use stablesurf::TriangleMesh;
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
///     normals: vec![[0.0, -1.0, 0.0]; 3],
///     triangles: vec![[0, 1, 2]],
/// };
/// let (mut json, mut bin) = (Vec::new(), Vec::new());
/// let opts = GltfOptions { up: UpAxis::Z, ..Default::default() };
/// write_gltf_coloured(&mesh, None, &mut json, &mut bin, "mesh.bin", &opts).unwrap();
/// let text = String::from_utf8(json).unwrap();
/// assert!(text.contains("\"uri\": \"mesh.bin\"") && text.contains("\"generator\": \"stablesurf\""));
/// assert_eq!(bin.len(), 3 * 12 + 3 * 12 + 8); // positions, normals, u16 indices padded to 4
/// ```
///
/// # Errors
/// As [`write_glb_coloured`], and [`ExportError::InvalidMesh`] when `bin_uri` is empty.
pub fn write_gltf_coloured(
    mesh: &TriangleMesh,
    colours: Option<&[[u8; 3]]>,
    json_out: &mut impl Write,
    bin_out: &mut impl Write,
    bin_uri: &str,
    opts: &GltfOptions,
) -> Result<(), ExportError> {
    if bin_uri.is_empty() {
        return Err(ExportError::InvalidMesh(
            "the .bin URI of a .gltf must not be empty".into(),
        ));
    }
    let (root, bin, translation) = encode(mesh, colours, opts, Some(bin_uri))?;
    let json_bytes = json_bytes(&root, translation, true)?;
    json_out
        .write_all(&json_bytes)
        .map_err(ExportError::Write)?;
    json_out.write_all(b"\n").map_err(ExportError::Write)?;
    bin_out.write_all(&bin).map_err(ExportError::Write)
}

/// What `stablesurf info` shows of a glTF asset (`.glb`, or `.gltf` JSON; its buffers are not
/// read): the generator, and per mesh primitive its vertex and triangle counts, its POSITION
/// bounds and whether it has normals, all from the JSON.
///
/// # Errors
/// [`ExportError::Format`] when the bytes are not a glTF 2.0 asset the `gltf` crate accepts.
pub fn read_info(bytes: &[u8]) -> Result<serde_json::Value, ExportError> {
    let asset = gltf::Gltf::from_slice(bytes)
        .map_err(|e| ExportError::Format(format!("not a readable glTF 2.0 asset: {e}")))?;
    let mut primitives = Vec::new();
    let (mut vertices, mut triangles) = (0, 0);
    for mesh in asset.meshes() {
        for primitive in mesh.primitives() {
            let position = primitive.get(&gltf::Semantic::Positions);
            let n = position.as_ref().map_or(0, |a| a.count());
            let corners = primitive.indices().map_or(n, |a| a.count());
            let t = if primitive.mode() == gltf::mesh::Mode::Triangles {
                corners / 3
            } else {
                0
            };
            vertices += n;
            triangles += t;
            primitives.push(serde_json::json!({
                "vertices": n,
                "triangles": t,
                "normals": primitive.get(&gltf::Semantic::Normals).is_some(),
                "min": position.as_ref().and_then(|a| a.min()),
                "max": position.as_ref().and_then(|a| a.max()),
            }));
        }
    }
    Ok(serde_json::json!({
        "format": if bytes.starts_with(b"glTF") { "glb" } else { "gltf" },
        "generator": asset.document.as_json().asset.generator,
        "version": asset.document.as_json().asset.version,
        "vertices": vertices,
        "triangles": triangles,
        "primitives": primitives,
    }))
}

/// The JSON text of `root`; with a `translation`, the first node gets it with every digit of
/// its `f64` values (`gltf-json` holds translations as `f32`, 0.25 m steps at UTM northings).
fn json_bytes(
    root: &json::Root,
    translation: Option<[f64; 3]>,
    pretty: bool,
) -> Result<Vec<u8>, ExportError> {
    let error =
        |e: serde_json::Error| ExportError::Format(format!("cannot serialize glTF JSON: {e}"));
    let Some(translation) = translation else {
        return if pretty {
            json::serialize::to_vec_pretty(root)
        } else {
            json::serialize::to_vec(root)
        }
        .map_err(error);
    };
    let mut value = serde_json::to_value(root).map_err(error)?;
    value["nodes"][0]["translation"] = serde_json::json!(translation);
    if pretty {
        serde_json::to_vec_pretty(&value)
    } else {
        serde_json::to_vec(&value)
    }
    .map_err(error)
}

/// A glTF document, its binary buffer, and the node translation of far-off coordinates.
type Encoded = (json::Root, Vec<u8>, Option<[f64; 3]>);

/// Checks the mesh and converts it to the glTF JSON document and its binary buffer.
fn encode(
    mesh: &TriangleMesh,
    colours: Option<&[[u8; 3]]>,
    opts: &GltfOptions,
    uri: Option<&str>,
) -> Result<Encoded, ExportError> {
    let n_vertices = mesh.positions.len();
    check_mesh(mesh)?;
    if let Some(c) = colours
        && c.len() != n_vertices
    {
        return Err(ExportError::InvalidMesh(format!(
            "{} colours for {n_vertices} vertices",
            c.len()
        )));
    }

    // Positions and normals in f32, with min/max taken from the f32 values actually written.
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    let position_bytes = n_vertices * 12;
    let use_u16 = n_vertices <= MAX_U16_INDEX as usize + 1;
    let index_size = if use_u16 { 2 } else { 4 };
    let index_bytes = mesh.triangles.len() * 3 * index_size;
    let mut bin = Vec::with_capacity(2 * position_bytes + index_bytes.next_multiple_of(4));
    let scale = opts.units.map_or(1.0, LengthUnit::metres);
    let world: Vec<[f64; 3]> = mesh
        .positions
        .iter()
        .map(|p| opts.up.input_to_y_up(*p).map(|c| c * scale))
        .collect();
    // Far-off coordinates: positions relative to the box centre, which the node carries.
    let translation = crate::export::far_off_centre(&world);
    let origin = translation.unwrap_or([0.0; 3]);
    for q in &world {
        let q: [f32; 3] = std::array::from_fn(|a| (q[a] - origin[a]) as f32);
        for a in 0..3 {
            min[a] = min[a].min(q[a]);
            max[a] = max[a].max(q[a]);
            bin.extend_from_slice(&q[a].to_le_bytes());
        }
    }
    for (vertex_idx, n) in mesh.normals.iter().enumerate() {
        let n = opts.up.input_to_y_up(*n).map(|c| c as f32);
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if !(len.is_finite() && len > 0.0) {
            return Err(ExportError::InvalidMesh(format!(
                "vertex {vertex_idx} has a zero or non-finite normal"
            )));
        }
        for c in n {
            bin.extend_from_slice(&(c / len).to_le_bytes());
        }
    }
    for t in &mesh.triangles {
        for &i in t {
            if use_u16 {
                bin.extend_from_slice(&(i as u16).to_le_bytes());
            } else {
                bin.extend_from_slice(&i.to_le_bytes());
            }
        }
    }
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    // The colours, after the indices (which end on a 4-byte boundary), as linear f32 RGB.
    let colour_offset = bin.len();
    if let Some(colours) = colours {
        let linear = srgb_to_linear_table();
        for c in colours {
            for &v in c {
                bin.extend_from_slice(&linear[usize::from(v)].to_le_bytes());
            }
        }
    }

    let mut root = json::Root {
        asset: json::Asset {
            generator: Some("stablesurf".into()),
            version: "2.0".into(),
            ..Default::default()
        },
        ..Default::default()
    };
    let buffer = root.push(json::Buffer {
        byte_length: USize64::from(bin.len()),
        name: None,
        uri: uri.map(str::to_owned),
        extensions: None,
        extras: Default::default(),
    });
    let view = |offset: usize, length: usize, target| json::buffer::View {
        buffer,
        byte_length: USize64::from(length),
        byte_offset: Some(USize64::from(offset)),
        byte_stride: None,
        name: None,
        target: Some(Valid(target)),
        extensions: None,
        extras: Default::default(),
    };
    let position_view = root.push(view(0, position_bytes, json::buffer::Target::ArrayBuffer));
    let normal_view = root.push(view(
        position_bytes,
        position_bytes,
        json::buffer::Target::ArrayBuffer,
    ));
    let index_view = root.push(view(
        2 * position_bytes,
        index_bytes,
        json::buffer::Target::ElementArrayBuffer,
    ));
    let accessor = |view, count: usize, component, type_, bounds: Option<([f32; 3], [f32; 3])>| {
        json::Accessor {
            buffer_view: Some(view),
            byte_offset: None,
            count: USize64::from(count),
            component_type: Valid(json::accessor::GenericComponentType(component)),
            type_: Valid(type_),
            min: bounds.map(|b| json::Value::from(b.0.to_vec())),
            max: bounds.map(|b| json::Value::from(b.1.to_vec())),
            name: None,
            normalized: false,
            sparse: None,
            extensions: None,
            extras: Default::default(),
        }
    };
    let colour_view = colours.map(|_| {
        root.push(view(
            colour_offset,
            position_bytes,
            json::buffer::Target::ArrayBuffer,
        ))
    });
    use json::accessor::{ComponentType, Type};
    let positions = root.push(accessor(
        position_view,
        n_vertices,
        ComponentType::F32,
        Type::Vec3,
        Some((min, max)),
    ));
    let normals = root.push(accessor(
        normal_view,
        n_vertices,
        ComponentType::F32,
        Type::Vec3,
        None,
    ));
    let index_component = if use_u16 {
        ComponentType::U16
    } else {
        ComponentType::U32
    };
    let indices = root.push(accessor(
        index_view,
        mesh.triangles.len() * 3,
        index_component,
        Type::Scalar,
        None,
    ));
    let material = root.push(json::Material {
        name: Some("stablesurf".into()),
        pbr_metallic_roughness: json::material::PbrMetallicRoughness {
            // White under vertex colours, which the factor multiplies; light grey otherwise.
            base_color_factor: json::material::PbrBaseColorFactor(if colours.is_some() {
                [1.0; 4]
            } else {
                [0.8, 0.8, 0.8, 1.0]
            }),
            metallic_factor: json::material::StrengthFactor(0.0),
            roughness_factor: json::material::StrengthFactor(0.6),
            ..Default::default()
        },
        ..Default::default()
    });
    let mut attributes = BTreeMap::new();
    attributes.insert(Valid(json::mesh::Semantic::Positions), positions);
    attributes.insert(Valid(json::mesh::Semantic::Normals), normals);
    if let Some(colour_view) = colour_view {
        let colours = root.push(accessor(
            colour_view,
            n_vertices,
            ComponentType::F32,
            Type::Vec3,
            None,
        ));
        attributes.insert(Valid(json::mesh::Semantic::Colors(0)), colours);
    }
    let mesh_index = root.push(json::Mesh {
        name: Some("surface".into()),
        primitives: vec![json::mesh::Primitive {
            attributes,
            indices: Some(indices),
            material: Some(material),
            mode: Valid(json::mesh::Mode::Triangles),
            targets: None,
            extensions: None,
            extras: Default::default(),
        }],
        weights: None,
        extensions: None,
        extras: Default::default(),
    });
    let node = root.push(json::Node {
        mesh: Some(mesh_index),
        name: Some("surface".into()),
        ..Default::default()
    });
    let scene = root.push(json::Scene {
        name: None,
        nodes: vec![node],
        extensions: None,
        extras: Default::default(),
    });
    root.scene = Some(scene);
    Ok((root, bin, translation))
}

/// The linear value of each 8-bit sRGB value (IEC 61966-2-1: v/12.92 up to 0.04045, else
/// ((v + 0.055)/1.055)^2.4), as glTF's `COLOR_0` holds linear RGB.
fn srgb_to_linear_table() -> [f32; 256] {
    std::array::from_fn(|i| {
        let v = i as f64 / 255.0;
        let linear = if v <= 0.04045 {
            v / 12.92
        } else {
            ((v + 0.055) / 1.055).powf(2.4)
        };
        linear as f32
    })
}

/// Checks what glTF requires of the mesh: at least one triangle, finite positions, one normal
/// per position, indices in range.
pub(crate) fn check_mesh(mesh: &TriangleMesh) -> Result<(), ExportError> {
    if mesh.triangles.is_empty() || mesh.positions.is_empty() {
        return Err(ExportError::InvalidMesh(
            "the mesh has no triangles; check that the surface crosses the meshing box".into(),
        ));
    }
    check_vertices(mesh)
}

/// Checks the vertex data of a mesh that may have no triangles (a point set with normals):
/// one normal per position, finite positions, indices in range.
pub(crate) fn check_vertices(mesh: &TriangleMesh) -> Result<(), ExportError> {
    let n_vertices = mesh.positions.len();
    if mesh.normals.len() != n_vertices {
        return Err(ExportError::InvalidMesh(format!(
            "the mesh has {} normals for {} vertices",
            mesh.normals.len(),
            n_vertices
        )));
    }
    if let Some(vertex_idx) = mesh
        .positions
        .iter()
        .position(|p| !p.iter().all(|c| c.is_finite()))
    {
        return Err(ExportError::InvalidMesh(format!(
            "vertex {vertex_idx} has a non-finite coordinate"
        )));
    }
    if u32::try_from(n_vertices).is_err() {
        return Err(ExportError::InvalidMesh(format!(
            "the mesh has {n_vertices} vertices, more than 32-bit indices can address"
        )));
    }
    if let Some((triangle_idx, t)) = mesh
        .triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&i| i as usize >= n_vertices))
    {
        return Err(ExportError::InvalidMesh(format!(
            "triangle {triangle_idx} refers to vertex {} of {n_vertices}",
            t.iter().max().copied().unwrap_or_default()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn triangle() -> TriangleMesh {
        TriangleMesh {
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 3.0]],
            normals: vec![[0.0, 0.0, 2.0]; 3],
            triangles: vec![[0, 1, 2]],
        }
    }

    /// The first primitive of the first mesh of a parsed glTF.
    fn first_primitive(parsed: &gltf::Gltf) -> gltf::Primitive<'_> {
        let mut meshes = parsed.document.meshes();
        meshes.next().unwrap().primitives().next().unwrap()
    }

    #[test]
    fn glb_parses_back_with_gltf_crate() {
        let mut glb = Vec::new();
        write_glb(&triangle(), &mut glb, &GltfOptions::default()).unwrap();
        let parsed = gltf::Gltf::from_slice(&glb).unwrap();
        let doc = &parsed.document;
        assert_eq!(doc.meshes().count(), 1);
        assert_eq!(doc.nodes().count(), 1);
        assert_eq!(doc.scenes().count(), 1);
        let prim = doc.meshes().next().unwrap().primitives().next().unwrap();
        let bounds = prim.bounding_box();
        assert_eq!(bounds.min, [0.0, 0.0, 0.0]);
        assert_eq!(bounds.max, [1.0, 2.0, 3.0]);
        let bin = parsed.blob.as_deref().unwrap();
        // Normals are renormalised: (0, 0, 2) is written as (0, 0, 1).
        let nz = f32::from_le_bytes(bin[36 + 8..36 + 12].try_into().unwrap());
        assert_eq!(nz, 1.0);
    }

    #[test]
    fn z_up_rotates_to_y_up() {
        let mut glb = Vec::new();
        write_glb(
            &triangle(),
            &mut glb,
            &GltfOptions {
                up: UpAxis::Z,
                ..Default::default()
            },
        )
        .unwrap();
        let parsed = gltf::Gltf::from_slice(&glb).unwrap();
        let prim = first_primitive(&parsed);
        assert_eq!(prim.bounding_box().min, [0.0, 0.0, -2.0]);
        assert_eq!(prim.bounding_box().max, [1.0, 3.0, 0.0]);
    }

    #[test]
    fn bad_meshes_are_errors() {
        let mut m = triangle();
        m.triangles[0][2] = 3;
        assert!(matches!(
            write_glb(&m, &mut Vec::new(), &GltfOptions::default()),
            Err(ExportError::InvalidMesh(_))
        ));
        let mut m = triangle();
        m.normals[1] = [0.0; 3];
        assert!(write_glb(&m, &mut Vec::new(), &GltfOptions::default()).is_err());
        let mut m = triangle();
        m.positions[0][0] = f64::NAN;
        assert!(write_glb(&m, &mut Vec::new(), &GltfOptions::default()).is_err());
        assert!(write_glb(
            &TriangleMesh::default(),
            &mut Vec::new(),
            &GltfOptions::default()
        )
        .is_err());
    }

    #[test]
    fn u32_indices_above_65535_vertices() {
        let n = 70_000;
        let mesh = TriangleMesh {
            positions: (0..n).map(|i| [i as f64, (i % 7) as f64, 0.0]).collect(),
            normals: vec![[0.0, 0.0, 1.0]; n],
            triangles: vec![[0, 1, (n - 1) as u32]],
        };
        let mut glb = Vec::new();
        write_glb(&mesh, &mut glb, &GltfOptions::default()).unwrap();
        let parsed = gltf::Gltf::from_slice(&glb).unwrap();
        let prim = first_primitive(&parsed);
        assert_eq!(
            prim.indices().unwrap().data_type(),
            gltf::accessor::DataType::U32
        );
    }
    #[test]
    fn far_off_coordinates_are_relative_to_a_full_precision_translation() {
        let offset = [500_123.25, 4_000_456.5, 101.75];
        let mesh = TriangleMesh {
            positions: vec![
                offset,
                [offset[0] + 2.0, offset[1] + 0.001, offset[2]],
                [offset[0], offset[1] + 2.0, offset[2] + 0.123_456_789],
            ],
            normals: vec![[0.0, 0.0, 1.0]; 3],
            triangles: vec![[0, 1, 2]],
        };
        let mut glb = Vec::new();
        write_glb(&mesh, &mut glb, &GltfOptions::default()).unwrap();
        let asset = gltf::Gltf::from_slice(&glb).unwrap();
        let json_len = u32::from_le_bytes(glb[12..16].try_into().unwrap()) as usize;
        let text: serde_json::Value = serde_json::from_slice(&glb[20..20 + json_len]).unwrap();
        let t: Vec<f64> = text["nodes"][0]["translation"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        // The box centre, every digit kept.
        assert_eq!(
            t,
            [
                offset[0] + 1.0,
                offset[1] + 1.0,
                offset[2] + 0.061_728_394_5
            ]
        );
        let bin = asset.blob.as_deref().unwrap();
        for (i, p) in mesh.positions.iter().enumerate() {
            let back: [f64; 3] = std::array::from_fn(|a| {
                let at = 12 * i + 4 * a;
                f64::from(f32::from_le_bytes(bin[at..at + 4].try_into().unwrap())) + t[a]
            });
            for a in 0..3 {
                assert!(
                    (back[a] - p[a]).abs() < 1e-6,
                    "vertex {i}: {back:?} vs {p:?}"
                );
            }
        }
        // Near the origin nothing changes: no translation.
        let mut near = Vec::new();
        let plain = TriangleMesh {
            positions: vec![[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            ..mesh
        };
        write_glb(&plain, &mut near, &GltfOptions::default()).unwrap();
        assert!(!near.windows(13).any(|w| w == b"\"translation\""));
    }
}
