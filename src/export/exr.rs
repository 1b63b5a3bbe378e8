//! Export stage, OpenEXR writer: one distance [`Slice`] → one single-channel float32 `.exr`.
//!
//! Input: a slice from [`distance::slices`](crate::distance::slices). Output: a scan-line
//! OpenEXR 2 image of R×R pixels with one channel `Y` (a grey image in any viewer) of 32-bit
//! floats holding the signed distance in input units, negative inside, compressed losslessly
//! (ZIP by default, PIZ on request). Row 0 of the image is the top (largest in-plane v).
//!
//! Header attributes (besides the required ones), all checked by the OpenEXR Python bindings in
//! `tests/all/export.rs`:
//!
//! | name                    | type   | value                                                  |
//! |-------------------------|--------|--------------------------------------------------------|
//! | `gridToWorld`           | m44d   | grid → input coordinates, Imath row-vector convention: |
//! |                         |        | `[x y z 1] = [col row slice 1] · M`                   |
//! | `gridToWorldConvention` | string | that sentence, for readers of the file                 |
//! | `voxelSize`             | v3d    | spacing along (columns, rows, slices), input units     |
//! | `sliceAxis`             | string | `x`, `y` or `z`                                        |
//! | `sliceIndex`            | int    | k, 0-based from the axis minimum                       |
//! | `sliceCount`            | int    | K                                                      |
//! | `signConvention`        | string | `negative inside`                                      |
//! | `distanceMethod`        | string | `exact` or `taubin`                                    |
//! | `distanceUnits`         | string | `input units`, or the unit's symbol with `--units`     |
//!
//! `gridToWorld` is the transpose of [`Slice::grid_to_world`] (which uses column vectors), so
//! Imath's `M44d::multVecMatrix` maps (col, row, k) to the input-space pixel centre. `m44d` and
//! `v3d` are OpenEXR's standard double-precision attribute types, written as raw little-endian
//! doubles because the `exr` crate has only their single-precision forms.
//!
//! The `exr` crate keeps custom attributes in a hash map and writes them in its iteration order,
//! which changes from run to run; to keep the output deterministic the writer sorts the header's
//! attributes by name after encoding (the header's length does not change, so the chunk offsets
//! that follow stay valid, and attribute order carries no meaning in OpenEXR).

use std::io::{Cursor, Write};

use exr::prelude::{
    AnyChannel, AnyChannels, AttributeValue, Blocks, Compression, Encoding, FlatSamples, Image,
    Layer, LayerAttributes, LineOrder, SmallVec, Text, WritableImage,
};

use crate::distance::Slice;
use crate::export::ExportError;

/// Lossless compression of the EXR pixels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ExrCompression {
    /// zlib over blocks of 16 scan lines: the usual choice for float data; the default.
    #[default]
    Zip,
    /// Wavelet + Huffman (PIZ): often smaller on noisy data, slower.
    Piz,
}

/// Options of the EXR writer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ExrOptions {
    /// Pixel compression; default ZIP.
    pub compression: ExrCompression,
    /// The unit of the input coordinates, written as `distanceUnits` (the distances and the
    /// geometry stay in input units); `None` writes `input units`.
    pub units: Option<crate::export::units::LengthUnit>,
}

/// What `gridToWorldConvention` says.
pub(crate) const GRID_TO_WORLD_CONVENTION: &str = "Imath row-vector: [x y z 1] = [col row slice 1] * gridToWorld; integer col, row are pixel centres; row 0 is the top of the image";

/// Writes `slice` as an OpenEXR image to `out`.
///
/// ```
/// use stablesurf::cloud::Aabb;
/// use stablesurf::distance::{slices, DistanceMethod, SliceParams};
/// use stablesurf::export::exr::{write_slice, ExrOptions};
/// use stablesurf::ImplicitPolynomial;
/// let mut c = vec![0.0; 10];
/// (c[0], c[4], c[7], c[9]) = (-1.0, 1.0, 1.0, 1.0);
/// let sphere = ImplicitPolynomial { degree: 2, coefficients: c, center: [0.0; 3], scale: 1.0 };
/// let region = Aabb { min: [-1.5; 3], max: [1.5; 3] };
/// let params = SliceParams { count: 1, resolution: 16, method: DistanceMethod::Taubin, ..Default::default() };
/// let slice = &slices(&sphere, &region, &params).unwrap()[0];
/// let mut bytes = Vec::new();
/// write_slice(slice, &ExrOptions::default(), &mut bytes).unwrap();
/// assert_eq!(&bytes[0..4], &[0x76, 0x2f, 0x31, 0x01]); // the OpenEXR magic number
/// ```
///
/// # Errors
/// [`ExportError::InvalidSlice`] when the data length is not R² or holds NaN;
/// [`ExportError::Format`] when encoding fails; [`ExportError::Write`] when `out` fails.
pub fn write_slice(
    slice: &Slice,
    opts: &ExrOptions,
    out: &mut impl Write,
) -> Result<(), ExportError> {
    let bytes = encode(slice, opts)?;
    out.write_all(&bytes).map_err(ExportError::Write)
}

fn encode(slice: &Slice, opts: &ExrOptions) -> Result<Vec<u8>, ExportError> {
    let r = slice.resolution;
    if r == 0 || slice.data.len() != r * r {
        return Err(ExportError::InvalidSlice(format!(
            "{} samples for a {r}×{r} slice",
            slice.data.len()
        )));
    }
    if slice.data.iter().any(|v| v.is_nan()) {
        return Err(ExportError::InvalidSlice(
            "the slice holds NaN samples".into(),
        ));
    }
    let to_i32 = |v: usize, what: &str| {
        i32::try_from(v).map_err(|_| ExportError::InvalidSlice(format!("{what} {v} is too large")))
    };

    let mut attributes = LayerAttributes::default();
    let mut set = |name: &str, value: AttributeValue| {
        attributes.other.insert(Text::from(name), value);
    };
    // Imath stores row vectors: M_imath[row][col] = grid_to_world[col][row].
    let m = &slice.grid_to_world;
    let mut matrix = Vec::with_capacity(128);
    for row in 0..4 {
        for column in m {
            matrix.extend_from_slice(&column[row].to_le_bytes());
        }
    }
    set(
        "gridToWorld",
        AttributeValue::Custom {
            kind: Text::from("m44d"),
            bytes: matrix.into(),
        },
    );
    set(
        "gridToWorldConvention",
        AttributeValue::Text(Text::from(GRID_TO_WORLD_CONVENTION)),
    );
    let voxel: Vec<u8> = slice
        .voxel_size
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    set(
        "voxelSize",
        AttributeValue::Custom {
            kind: Text::from("v3d"),
            bytes: voxel.into(),
        },
    );
    set(
        "sliceAxis",
        AttributeValue::Text(Text::from(slice.axis.name())),
    );
    set(
        "sliceIndex",
        AttributeValue::I32(to_i32(slice.index, "slice index")?),
    );
    set(
        "sliceCount",
        AttributeValue::I32(to_i32(slice.count, "slice count")?),
    );
    set(
        "signConvention",
        AttributeValue::Text(Text::from("negative inside")),
    );
    set(
        "distanceMethod",
        AttributeValue::Text(Text::from(slice.method.name())),
    );
    set(
        "distanceUnits",
        AttributeValue::Text(Text::from(opts.units.map_or("input units", |u| u.symbol()))),
    );

    let compression = match opts.compression {
        ExrCompression::Zip => Compression::ZIP16,
        ExrCompression::Piz => Compression::PIZ,
    };
    let encoding = Encoding {
        compression,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let channel = AnyChannel::new("Y", FlatSamples::F32(slice.data.clone()));
    let channels = AnyChannels::sort(SmallVec::from_vec(vec![channel]));
    let layer = Layer::new((r, r), attributes, encoding, channels);
    let image = Image::from_layer(layer);
    let mut bytes = Vec::new();
    // One thread: the slices are encoded side by side already, and the crate's parallel mode
    // builds a thread pool per file.
    image
        .write()
        .non_parallel()
        .to_buffered(Cursor::new(&mut bytes))
        .map_err(|e| ExportError::Format(format!("cannot encode OpenEXR: {e}")))?;
    sort_header_attributes(&mut bytes)?;
    Ok(bytes)
}

/// Sorts the attributes of a single-part EXR header by name, in place (see the module docs).
fn sort_header_attributes(bytes: &mut [u8]) -> Result<(), ExportError> {
    let corrupt = || ExportError::Format("the OpenEXR encoder wrote an unexpected header".into());
    let read_cstr = |at: usize| -> Option<usize> {
        bytes
            .get(at..)?
            .iter()
            .position(|&b| b == 0)
            .map(|n| at + n)
    };
    let mut attributes: Vec<(usize, usize, usize)> = Vec::new(); // (start, name_end, end)
    let mut at = 8; // magic number and version field
    loop {
        let name_end = read_cstr(at).ok_or_else(corrupt)?;
        if name_end == at {
            break; // the empty name that ends the header
        }
        let type_end = read_cstr(name_end + 1).ok_or_else(corrupt)?;
        let size_bytes = bytes.get(type_end + 1..type_end + 5).ok_or_else(corrupt)?;
        let size = i32::from_le_bytes(size_bytes.try_into().map_err(|_| corrupt())?);
        let end = type_end + 5 + usize::try_from(size).map_err(|_| corrupt())?;
        if end > bytes.len() {
            return Err(corrupt());
        }
        attributes.push((at, name_end, end));
        at = end;
    }
    let (start, stop) = match (attributes.first(), attributes.last()) {
        (Some(first), Some(last)) => (first.0, last.2),
        _ => return Ok(()),
    };
    attributes.sort_by(|a, b| bytes[a.0..a.1].cmp(&bytes[b.0..b.1]));
    let mut sorted = Vec::with_capacity(stop - start);
    for &(s, _, e) in &attributes {
        sorted.extend_from_slice(&bytes[s..e]);
    }
    bytes[start..stop].copy_from_slice(&sorted);
    Ok(())
}

/// Reads back the distances of a slice file (any single-channel float32 OpenEXR image, as
/// [`write_slice`] writes): the samples of its first channel, row by row from the top. For the
/// tools and tests that compare slice stacks.
///
/// # Errors
/// [`ExportError::Format`] when the bytes are not such an image.
pub fn read_samples(bytes: &[u8]) -> Result<Vec<f32>, ExportError> {
    let image = read_image(bytes)
        .map_err(|e| ExportError::Format(format!("not a readable OpenEXR image: {e}")))?;
    match image
        .layer_data
        .channel_data
        .list
        .first()
        .map(|c| &c.sample_data)
    {
        Some(FlatSamples::F32(v)) => Ok(v.clone()),
        _ => Err(ExportError::Format(
            "the image's first channel is not float32".into(),
        )),
    }
}

/// What `stablesurf info` shows of an OpenEXR image: its size, its channels, the range of its
/// first channel and the slice attributes [`write_slice`] writes (whichever are present).
///
/// # Errors
/// [`ExportError::Format`] when the bytes are not a readable OpenEXR image.
pub fn read_info(bytes: &[u8]) -> Result<serde_json::Value, ExportError> {
    use exr::meta::attribute::AttributeValue as A;
    let image = read_image(bytes)
        .map_err(|e| ExportError::Format(format!("not a readable OpenEXR image: {e}")))?;
    let layer = &image.layer_data;
    let channels: Vec<String> = layer
        .channel_data
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    if let Some(FlatSamples::F32(v)) = layer.channel_data.list.first().map(|c| &c.sample_data) {
        for &x in v.iter().filter(|x| x.is_finite()) {
            lo = lo.min(f64::from(x));
            hi = hi.max(f64::from(x));
        }
    }
    let mut info = serde_json::json!({
        "format": "openexr",
        "width": layer.size.0,
        "height": layer.size.1,
        "channels": channels,
        "min": lo.is_finite().then_some(lo),
        "max": hi.is_finite().then_some(hi),
    });
    let doubles = |bytes: &[u8]| -> Vec<f64> {
        bytes
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
            .collect()
    };
    let mut names: Vec<_> = layer.attributes.other.iter().collect();
    names.sort_by_key(|(name, _)| name.to_string());
    for (name, value) in names {
        let value = match value {
            A::Text(t) => serde_json::Value::from(t.to_string()),
            A::I32(i) => serde_json::Value::from(*i),
            A::F32(x) => serde_json::Value::from(*x),
            A::F64(x) => serde_json::Value::from(*x),
            A::Custom { kind, bytes } if kind == "v3d" || kind == "m44d" => {
                serde_json::Value::from(doubles(bytes))
            }
            _ => continue,
        };
        info[name.to_string()] = value;
    }
    Ok(info)
}

/// The first valid layer of an OpenEXR image with all its channels and attributes, read with
/// the `exr` crate (for [`read_samples`] and the tests).
fn read_image(
    bytes: &[u8],
) -> exr::error::Result<
    exr::prelude::Image<exr::prelude::Layer<exr::prelude::AnyChannels<FlatSamples>>>,
> {
    use exr::prelude::{read, ReadChannels, ReadLayers};
    read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(Cursor::new(bytes))
}

#[cfg(test)]
mod tests {
    use exr::prelude::Vec2;

    use super::*;
    use crate::cloud::Aabb;
    use crate::distance::{slices, Axis, DistanceMethod, SliceParams};
    use crate::poly::ImplicitPolynomial;

    fn sphere_slice(axis: Axis) -> Slice {
        let mut c = vec![0.0; 10];
        (c[0], c[4], c[7], c[9]) = (-1.0, 1.0, 1.0, 1.0);
        let sphere = ImplicitPolynomial {
            degree: 2,
            coefficients: c,
            center: [0.0; 3],
            scale: 1.0,
        };
        let region = Aabb {
            min: [-1.5, -1.2, -1.0],
            max: [1.5, 1.2, 1.0],
        };
        let params = SliceParams {
            axis,
            count: 3,
            resolution: 20,
            method: DistanceMethod::Taubin,
        };
        slices(&sphere, &region, &params).unwrap().swap_remove(1)
    }

    #[test]
    fn reads_back_with_exr_crate() {
        let slice = sphere_slice(Axis::X);
        for compression in [ExrCompression::Zip, ExrCompression::Piz] {
            let mut bytes = Vec::new();
            write_slice(
                &slice,
                &ExrOptions {
                    compression,
                    ..Default::default()
                },
                &mut bytes,
            )
            .unwrap();
            let image = read_image(&bytes).unwrap();
            let layer = &image.layer_data;
            assert_eq!(layer.size, Vec2(20, 20));
            assert_eq!(layer.channel_data.list.len(), 1);
            let ch = &layer.channel_data.list[0];
            assert_eq!(ch.name, Text::from("Y"));
            match &ch.sample_data {
                FlatSamples::F32(v) => assert_eq!(*v, slice.data),
                other => panic!("unexpected samples {other:?}"),
            }
            let attrs = &layer.attributes.other;
            assert_eq!(attrs[&Text::from("sliceIndex")], AttributeValue::I32(1));
            assert_eq!(
                attrs[&Text::from("sliceAxis")],
                AttributeValue::Text(Text::from("x"))
            );
        }
    }

    #[test]
    fn read_samples_gives_back_the_distances() {
        let slice = sphere_slice(Axis::Y);
        let bytes = encode(&slice, &ExrOptions::default()).unwrap();
        assert_eq!(read_samples(&bytes).unwrap(), slice.data);
        assert!(matches!(
            read_samples(&bytes[..bytes.len() / 2]),
            Err(ExportError::Format(_))
        ));
    }

    #[test]
    fn bytes_are_deterministic() {
        let slice = sphere_slice(Axis::Z);
        let first = encode(&slice, &ExrOptions::default()).unwrap();
        for _ in 0..5 {
            assert_eq!(encode(&slice, &ExrOptions::default()).unwrap(), first);
        }
    }

    #[test]
    fn bad_slices_are_errors() {
        let mut slice = sphere_slice(Axis::Y);
        slice.data.pop();
        assert!(matches!(
            write_slice(&slice, &ExrOptions::default(), &mut Vec::new()),
            Err(ExportError::InvalidSlice(_))
        ));
        let mut slice = sphere_slice(Axis::Y);
        slice.data[3] = f32::NAN;
        assert!(write_slice(&slice, &ExrOptions::default(), &mut Vec::new()).is_err());
    }
}
