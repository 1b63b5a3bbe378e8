//! A shaded picture of a mesh: z-buffered triangles with Lambert shading, for previews
//! (`stablesurf render`, `preview.png` of `run`).
//!
//! Input: a [`TriangleMesh`] and [`RenderParams`]. Output: an RGB image (row-major, 3 bytes per
//! pixel) as an `image::RgbImage`; encoding it as PNG is the caller's job.
//!
//! The camera is orthographic, looking at the mesh's bounding-box centre along the chosen view
//! direction, framed so the whole box fits with a 5% margin. Triangles are rasterized with
//! barycentric edge functions and a depth buffer; each pixel is shaded once, after the depth
//! pass, for its nearest triangle (the first drawn among equal depths), with the interpolated
//! vertex normal (two-sided, so an open mesh seen from inside is still readable) under a key
//! light and a dim fill light, over a light grey background. Deterministic: the image is cut
//! into bands of `BAND_ROWS` rows rasterized side by side (rayon), each seeing the triangles
//! that reach it in index order, so every pixel sees the same triangles in the same order
//! whatever the thread count; no randomness.

use image::{Rgb, RgbImage};
use rayon::prelude::*;

use crate::frame::UpAxis;
use crate::mesh::TriangleMesh;
use crate::vec3::{cross, dot, norm};

/// Which direction the camera looks from, relative to the model's up axis
/// ([`RenderParams::up`]): the front is where +z faces for a y-up model (glTF's convention),
/// where −y faces for a z-up one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum View {
    /// From the front-right, a little above.
    #[default]
    Iso,
    /// From the front, up pointing up.
    Front,
    /// From above, the front at the bottom of the picture.
    Top,
    /// From the right (+x), up pointing up.
    Side,
}

impl View {
    /// Unit vector from the scene towards the camera, and the screen's up vector, for a model
    /// whose up axis is `up`.
    pub(crate) fn direction(self, up: UpAxis) -> ([f64; 3], [f64; 3]) {
        // In a y-up frame (x right, y up, z towards the front), then turned into the model's.
        let (towards, screen_up) = match self {
            View::Iso => (normalize([1.0, 0.9, 1.2]), [0.0, 1.0, 0.0]),
            View::Front => ([0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
            View::Top => ([0.0, 1.0, 0.0], [0.0, 0.0, -1.0]),
            View::Side => ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        };
        (up.y_up_to_input(towards), up.y_up_to_input(screen_up))
    }
}

impl std::str::FromStr for View {
    type Err = String;
    fn from_str(s: &str) -> Result<View, String> {
        match s {
            "iso" => Ok(View::Iso),
            "front" => Ok(View::Front),
            "top" => Ok(View::Top),
            "side" => Ok(View::Side),
            _ => Err(format!(
                "unknown view '{s}' (choose iso, front, top or side)"
            )),
        }
    }
}

/// Parameters of a render.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderParams {
    /// Image width and height in pixels.
    pub size: u32,
    /// Camera direction.
    pub view: View,
    /// The model's up axis: up in the picture (default y, as glTF).
    pub up: UpAxis,
    /// Surface colour (linear 0–1 RGB).
    pub color: [f64; 3],
}

impl Default for RenderParams {
    fn default() -> Self {
        RenderParams {
            size: 800,
            view: View::Iso,
            up: UpAxis::Y,
            color: [0.62, 0.70, 0.82],
        }
    }
}

/// Rows per band of the parallel rasterization.
const BAND_ROWS: u32 = 16;

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let n = norm(v);
    if n > 0.0 {
        v.map(|c| c / n)
    } else {
        v
    }
}

/// Renders `mesh`. An empty mesh gives a background-only image.
///
/// ```
/// use stablesurf::render::{render, RenderParams};
/// let img = render(&stablesurf::TriangleMesh::default(), &RenderParams { size: 16, ..Default::default() });
/// assert_eq!(img.dimensions(), (16, 16));
/// ```
pub fn render(mesh: &TriangleMesh, params: &RenderParams) -> RgbImage {
    let size = params.size.max(1);
    let background = Rgb([236u8, 238, 242]);
    let mut img = RgbImage::from_pixel(size, size, background);
    let Some(bounds) = crate::cloud::Aabb::from_points(&mesh.positions) else {
        return img;
    };
    let (towards_camera, up_hint) = params.view.direction(params.up);
    // Screen basis: right, up, and depth towards the camera.
    let right = normalize(cross(up_hint, towards_camera));
    let up = cross(towards_camera, right);
    let center = bounds.center();
    let radius = 0.5 * bounds.diagonal().max(f64::MIN_POSITIVE);
    let scale = 0.95 * f64::from(size) / (2.0 * radius);
    let half = f64::from(size) / 2.0;
    let project = |p: [f64; 3]| {
        let d = [p[0] - center[0], p[1] - center[1], p[2] - center[2]];
        [
            half + dot(d, right) * scale,
            half - dot(d, up) * scale,
            dot(d, towards_camera),
        ]
    };
    let screen: Vec<[f64; 3]> = mesh.positions.par_iter().map(|&p| project(p)).collect();
    let key = normalize([0.4, 0.6, 1.0]);
    let fill = normalize([-0.6, -0.2, 0.4]);
    let light = |n: [f64; 3]| {
        // Light directions are given in screen space: transform the normal there.
        let ns = [dot(n, right), dot(n, up), dot(n, towards_camera)];
        let ns = if ns[2] < 0.0 { ns.map(|c| -c) } else { ns };
        0.18 + 0.72 * dot(ns, key).max(0.0) + 0.22 * dot(ns, fill).max(0.0)
    };
    let corners = |tri: &[u32; 3]| {
        let [a, b, c] = tri.map(|i| screen[i as usize]);
        let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
        ([a, b, c], area)
    };
    let weights = |[a, b, c]: [[f64; 3]; 3], area: f64, px: f64, py: f64| {
        let w0 = ((b[0] - px) * (c[1] - py) - (b[1] - py) * (c[0] - px)) / area;
        let w1 = ((c[0] - px) * (a[1] - py) - (c[1] - py) * (a[0] - px)) / area;
        (w0, w1, 1.0 - w0 - w1)
    };
    // Each drawable triangle's pixel rectangle, then the triangles of each band in index order.
    let rects: Vec<Option<[u32; 4]>> = mesh
        .triangles
        .par_iter()
        .map(|tri| {
            let ([a, b, c], area) = corners(tri);
            if area.abs() < 1e-12 {
                return None;
            }
            let x0 = a[0].min(b[0]).min(c[0]).floor().max(0.0) as u32;
            let x1 = (a[0].max(b[0]).max(c[0]).ceil() as i64).clamp(0, i64::from(size) - 1) as u32;
            let y0 = a[1].min(b[1]).min(c[1]).floor().max(0.0) as u32;
            let y1 = (a[1].max(b[1]).max(c[1]).ceil() as i64).clamp(0, i64::from(size) - 1) as u32;
            // Off the picture (it draws nothing), so it belongs to no band.
            if x0 > x1 || y0 > y1 {
                return None;
            }
            Some([x0, x1, y0, y1])
        })
        .collect();
    let mut bands: Vec<Vec<u32>> = vec![Vec::new(); size.div_ceil(BAND_ROWS) as usize];
    for (ti, rect) in rects.iter().enumerate() {
        if let Some([_, _, y0, y1]) = *rect {
            for band in &mut bands[(y0 / BAND_ROWS) as usize..=(y1 / BAND_ROWS) as usize] {
                band.push(ti as u32);
            }
        }
    }
    // Depth pass: the nearest triangle of each pixel (the first drawn among equal depths).
    // Shading only the winners, afterwards, gives the same colours as shading every pixel a
    // nearer triangle overwrites: the barycentric weights are recomputed by the same formula.
    let band_pixels = (BAND_ROWS * size) as usize;
    let mut winner = vec![u32::MAX; (size * size) as usize];
    winner
        .par_chunks_mut(band_pixels)
        .zip(&bands)
        .enumerate()
        .for_each(|(band, (winner, triangles))| {
            let first_row = band as u32 * BAND_ROWS;
            let last_row = first_row + (winner.len() / size as usize) as u32 - 1;
            let mut depth = vec![f64::NEG_INFINITY; winner.len()];
            for &ti in triangles {
                let tri = &mesh.triangles[ti as usize];
                let Some([x0, x1, y0, y1]) = rects[ti as usize] else {
                    continue;
                };
                let ([a, b, c], area) = corners(tri);
                for y in y0.max(first_row)..=y1.min(last_row) {
                    for x in x0..=x1 {
                        let (px, py) = (f64::from(x) + 0.5, f64::from(y) + 0.5);
                        let (w0, w1, w2) = weights([a, b, c], area, px, py);
                        if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                            continue;
                        }
                        let z = w0 * a[2] + w1 * b[2] + w2 * c[2];
                        let idx = ((y - first_row) * size + x) as usize;
                        if z <= depth[idx] {
                            continue;
                        }
                        depth[idx] = z;
                        winner[idx] = ti;
                    }
                }
            }
        });
    let row_bytes = 3 * size as usize;
    let pixels: &mut [u8] = &mut img;
    pixels
        .par_chunks_mut(row_bytes)
        .zip(winner.par_chunks(size as usize))
        .enumerate()
        .for_each(|(y, (row, winners))| {
            for (x, &ti) in winners.iter().enumerate() {
                let Some(tri) = mesh.triangles.get(ti as usize) else {
                    continue;
                };
                let (abc, area) = corners(tri);
                let (w0, w1, w2) = weights(abc, area, x as f64 + 0.5, y as f64 + 0.5);
                let normals = tri.map(|i| {
                    mesh.normals
                        .get(i as usize)
                        .copied()
                        .unwrap_or([0.0, 0.0, 1.0])
                });
                let n = normalize(
                    [0, 1, 2].map(|k| w0 * normals[0][k] + w1 * normals[1][k] + w2 * normals[2][k]),
                );
                let shade = light(n);
                let rgb = params
                    .color
                    .map(|c| ((c * shade).clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8);
                row[3 * x..3 * x + 3].copy_from_slice(&rgb);
            }
        });
    img
}

/// A mesh from positions and triangles with area-weighted vertex normals (for rendering files
/// that store no normals). Triangles with an index out of range are skipped.
pub fn with_face_normals(positions: Vec<[f64; 3]>, triangles: Vec<[u32; 3]>) -> TriangleMesh {
    let mut normals = vec![[0.0; 3]; positions.len()];
    let triangles: Vec<[u32; 3]> = triangles
        .into_iter()
        .filter(|t| t.iter().all(|&i| (i as usize) < positions.len()))
        .collect();
    for t in &triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let n = cross(
            [b[0] - a[0], b[1] - a[1], b[2] - a[2]],
            [c[0] - a[0], c[1] - a[1], c[2] - a[2]],
        );
        for &i in t {
            for k in 0..3 {
                normals[i as usize][k] += n[k];
            }
        }
    }
    let normals = normals.into_iter().map(normalize).collect();
    TriangleMesh {
        positions,
        normals,
        triangles,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An axis-aligned unit cube with outward normals per vertex (corner directions).
    fn cube() -> TriangleMesh {
        let mut positions = Vec::new();
        for i in 0..8u32 {
            positions.push([
                f64::from(i & 1),
                f64::from((i >> 1) & 1),
                f64::from((i >> 2) & 1),
            ]);
        }
        let normals = positions
            .iter()
            .map(|p| normalize(p.map(|c| c - 0.5)))
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let triangles = quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect();
        TriangleMesh {
            positions,
            normals,
            triangles,
        }
    }

    #[test]
    fn cube_covers_the_centre_and_leaves_corners_as_background() {
        let img = render(
            &cube(),
            &RenderParams {
                size: 64,
                ..Default::default()
            },
        );
        assert_ne!(*img.get_pixel(32, 32), Rgb([236, 238, 242]));
        assert_eq!(*img.get_pixel(0, 0), Rgb([236, 238, 242]));
        // The rendering is deterministic.
        assert_eq!(
            img,
            render(
                &cube(),
                &RenderParams {
                    size: 64,
                    ..Default::default()
                }
            )
        );
    }

    #[test]
    fn front_view_of_cube_is_a_filled_square() {
        let img = render(
            &cube(),
            &RenderParams {
                size: 100,
                view: View::Front,
                ..Default::default()
            },
        );
        let bg = Rgb([236u8, 238, 242]);
        let covered = img.pixels().filter(|p| **p != bg).count();
        // The cube's face spans 1/√3 of the framed diagonal: about (0.95·100/√3)² pixels.
        let expected = (0.95 * 100.0 / 3f64.sqrt()).powi(2);
        assert!(
            (covered as f64 - expected).abs() < 0.05 * expected,
            "{covered} vs {expected}"
        );
    }

    /// A square pyramid, its base at the bottom of its up axis and its tip at the top.
    fn pyramid(up: UpAxis) -> TriangleMesh {
        // y-up: base square in y = 0, tip at y = 2; turned for z-up.
        let turn = |p: [f64; 3]| up.y_up_to_input(p);
        let positions: Vec<[f64; 3]> = [
            [-1.0, 0.0, -1.0],
            [1.0, 0.0, -1.0],
            [1.0, 0.0, 1.0],
            [-1.0, 0.0, 1.0],
            [0.0, 2.0, 0.0],
        ]
        .map(turn)
        .to_vec();
        let centre = turn([0.0, 0.5, 0.0]);
        let normals = positions
            .iter()
            .map(|p| normalize([0, 1, 2].map(|a| p[a] - centre[a])))
            .collect();
        TriangleMesh {
            positions,
            normals,
            triangles: vec![
                [0, 1, 2],
                [0, 2, 3],
                [0, 4, 1],
                [1, 4, 2],
                [2, 4, 3],
                [3, 4, 0],
            ],
        }
    }

    /// Rows of the image with any surface pixel: (first, last, widest).
    fn rows(img: &RgbImage) -> (u32, u32, u32) {
        let background = *img.get_pixel(0, 0);
        let widths: Vec<u32> = (0..img.height())
            .map(|y| {
                (0..img.width())
                    .filter(|&x| *img.get_pixel(x, y) != background)
                    .count() as u32
            })
            .collect();
        let first = widths.iter().position(|&w| w > 0).unwrap() as u32;
        let last = widths.iter().rposition(|&w| w > 0).unwrap() as u32;
        let widest = (0..widths.len()).max_by_key(|&y| widths[y]).unwrap() as u32;
        (first, last, widest)
    }

    #[test]
    fn every_view_shows_the_model_upright_for_its_up_axis() {
        for up in [UpAxis::Y, UpAxis::Z] {
            for view in [View::Iso, View::Front, View::Side] {
                let params = RenderParams {
                    size: 64,
                    view,
                    up,
                    ..Default::default()
                };
                let img = render(&pyramid(up), &params);
                let (first, last, widest) = rows(&img);
                // The base is at the bottom of the picture, the tip at the top.
                assert!(
                    widest > (first + last) / 2,
                    "{up:?} {view:?}: widest row {widest} of {first}..{last}"
                );
            }
        }
    }
}
