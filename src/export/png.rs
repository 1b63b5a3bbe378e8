//! Export stage, PNG preview: one distance [`Slice`] → an R×R RGB picture.
//!
//! Input: a slice from [`distance::slices`](crate::distance::slices). Output: an 8-bit RGB PNG
//! of the same size and orientation as the slice's EXR (row 0 at the top), written with the
//! `image` crate, for looking at a stack without an EXR viewer:
//!
//! - a diverging colour map (Moreland's cool-warm, 2009): blue inside (negative), light grey at
//!   the surface, red outside (positive); the scale is symmetric, ±a quarter of the slice's
//!   width (R·h/4), the same for every slice of a stack so colours compare across slices, and
//!   saturates beyond;
//! - thin darker iso-distance lines every tenth of the slice's width (R·h/10);
//! - the zero contour in black: a pixel is drawn when its sign differs from a 4-neighbour's and
//!   it is the one of the pair nearer to zero, so the line is one pixel wide.
//!
//! Invariant: the bytes depend only on the slice.

use std::io::Write;

use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder};

use crate::distance::Slice;
use crate::export::ExportError;

/// Moreland's cool-warm control points (t ∈ [−1, 1] → sRGB).
const COOL_WARM: [(f32, [f32; 3]); 5] = [
    (-1.0, [59.0, 76.0, 192.0]),
    (-0.5, [141.0, 176.0, 254.0]),
    (0.0, [221.0, 221.0, 221.0]),
    (0.5, [244.0, 154.0, 123.0]),
    (1.0, [180.0, 4.0, 38.0]),
];

/// The colour of the normalized distance t ∈ [−1, 1] (clamped).
fn colour(t: f32) -> [f32; 3] {
    let t = t.clamp(-1.0, 1.0);
    for w in COOL_WARM.windows(2) {
        let ((t0, c0), (t1, c1)) = (w[0], w[1]);
        if t <= t1 {
            let s = (t - t0) / (t1 - t0);
            return [0, 1, 2].map(|a| c0[a] + s * (c1[a] - c0[a]));
        }
    }
    COOL_WARM[COOL_WARM.len() - 1].1
}

/// Writes a colour preview of `slice` as PNG to `out`.
///
/// ```
/// use stablesurf::cloud::Aabb;
/// use stablesurf::distance::{slices, DistanceMethod, SliceParams};
/// use stablesurf::export::png::write_preview;
/// use stablesurf::ImplicitPolynomial;
/// let mut c = vec![0.0; 10];
/// (c[0], c[4], c[7], c[9]) = (-1.0, 1.0, 1.0, 1.0);
/// let sphere = ImplicitPolynomial { degree: 2, coefficients: c, center: [0.0; 3], scale: 1.0 };
/// let region = Aabb { min: [-1.5; 3], max: [1.5; 3] };
/// let params = SliceParams { count: 1, resolution: 32, method: DistanceMethod::Taubin, ..Default::default() };
/// let slice = &slices(&sphere, &region, &params).unwrap()[0];
/// let mut png = Vec::new();
/// write_preview(slice, &mut png).unwrap();
/// assert_eq!(&png[1..4], b"PNG");
/// ```
///
/// # Errors
/// [`ExportError::InvalidSlice`] when the data length is not R²; [`ExportError::Format`] when
/// encoding fails; [`ExportError::Write`] when `out` fails.
pub fn write_preview(slice: &Slice, out: &mut impl Write) -> Result<(), ExportError> {
    let r = slice.resolution;
    if r == 0 || slice.data.len() != r * r {
        return Err(ExportError::InvalidSlice(format!(
            "{} samples for a {r}×{r} slice",
            slice.data.len()
        )));
    }
    let side = u32::try_from(r)
        .map_err(|_| ExportError::InvalidSlice(format!("resolution {r} is too large for PNG")))?;
    let width = r as f64 * slice.voxel_size[0];
    let range = (width / 4.0) as f32;
    let band = (width / 10.0) as f32;
    let d = |col: usize, row: usize| slice.data[row * r + col];
    let mut rgb = Vec::with_capacity(r * r * 3);
    for row in 0..r {
        for col in 0..r {
            let v = d(col, row);
            let mut c = colour(if range > 0.0 { v / range } else { 0.0 });
            let mut on_zero = false;
            let mut on_band = false;
            let neighbours = [
                (col > 0).then(|| d(col - 1, row)),
                (col + 1 < r).then(|| d(col + 1, row)),
                (row > 0).then(|| d(col, row - 1)),
                (row + 1 < r).then(|| d(col, row + 1)),
            ];
            for n in neighbours.into_iter().flatten() {
                // Ties go to the negative side so exactly one pixel of each pair is drawn.
                if (v < 0.0) != (n < 0.0) && (v.abs() < n.abs() || (v.abs() == n.abs() && v < 0.0))
                {
                    on_zero = true;
                }
                if band > 0.0 && (v / band).floor() != (n / band).floor() && v.abs() <= n.abs() {
                    on_band = true;
                }
            }
            if on_zero {
                c = [0.0; 3];
            } else if on_band {
                c = c.map(|x| x * 0.8);
            }
            rgb.extend(c.map(|x| x.round().clamp(0.0, 255.0) as u8));
        }
    }
    let mut bytes = Vec::new();
    PngEncoder::new(&mut bytes)
        .write_image(&rgb, side, side, ExtendedColorType::Rgb8)
        .map_err(|e| ExportError::Format(format!("cannot encode PNG: {e}")))?;
    out.write_all(&bytes).map_err(ExportError::Write)
}

/// Encodes an RGB image (for example a render of the mesh) as PNG.
///
/// # Errors
/// [`ExportError::Format`] when encoding fails; [`ExportError::Write`] when `out` fails.
pub fn write_rgb(image: &image::RgbImage, out: &mut impl Write) -> Result<(), ExportError> {
    use image::ImageEncoder;
    let mut bytes = Vec::new();
    image::codecs::png::PngEncoder::new(&mut bytes)
        .write_image(
            image.as_raw(),
            image.width(),
            image.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| ExportError::Format(format!("png encoding failed: {e}")))?;
    out.write_all(&bytes).map_err(ExportError::Write)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::distance::{Axis, DistanceMethod};

    fn slice_with(data: Vec<f32>, r: usize) -> Slice {
        Slice {
            index: 0,
            count: 1,
            axis: Axis::Z,
            method: DistanceMethod::Exact,
            resolution: r,
            data,
            grid_to_world: [[0.0; 4]; 4],
            voxel_size: [1.0, 1.0, 1.0],
        }
    }

    #[test]
    fn colours_and_contour() {
        assert_eq!(colour(-5.0), [59.0, 76.0, 192.0]);
        assert_eq!(colour(0.0), [221.0, 221.0, 221.0]);
        assert_eq!(colour(1.0), [180.0, 4.0, 38.0]);
        // A vertical step: columns 0..2 inside, 2..4 outside; the contour is column 1.
        let r = 4;
        let data: Vec<f32> = (0..r * r).map(|i| (i % r) as f32 - 1.4).collect();
        let mut png = Vec::new();
        write_preview(&slice_with(data, r), &mut png).unwrap();
        let img = image::load_from_memory(&png).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (4, 4));
        for row in 0..4 {
            assert_eq!(img.get_pixel(1, row).0, [0, 0, 0]);
            assert_ne!(img.get_pixel(2, row).0, [0, 0, 0]);
            assert!(img.get_pixel(0, row).0[2] > img.get_pixel(0, row).0[0]); // blue inside
            assert!(img.get_pixel(3, row).0[0] > img.get_pixel(3, row).0[2]); // red outside
        }
    }
}
