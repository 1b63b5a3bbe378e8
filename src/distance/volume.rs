//! Signed-distance volumes (the `vdb` and `npy` outputs): a model, its mesh and a region → a
//! narrow-band level set (`NarrowBand`) and a dense grid (`DenseVolume`) of signed
//! Euclidean distances in input units, negative inside. No IO: the writers are
//! `export::vdb` and `export::npy`.
//!
//! # Grid
//!
//! ```text
//!   voxel (i, j, k) has its centre at origin + h·(i, j, k);  i along x, j along y, k along z
//!   shape = ⌈extent / h⌉ per axis (at least 1), the grid centred on the region's centre,
//!   so it covers the region; h = the voxel size (VolumeParams), the same on every axis
//! ```
//!
//! # Values
//!
//! - **Narrow band** (`narrow_band`): the exact Euclidean distance to the mesh for every voxel
//!   within `BAND_VOXELS` voxels of it. Each triangle is binned into the 8³-voxel blocks
//!   (OpenVDB's leaves) that its bounding box grown by the band touches; per block, every voxel
//!   in a triangle's grown box gets the distance to the triangle's closest point (Ericson 5.1.5),
//!   and the smallest wins, so the value is the distance to the nearest triangle whenever that is
//!   below the band's half-width (any triangle that near has the voxel in its grown box). A voxel
//!   is active when that distance is below the half-width 3h; every other voxel of a block, and
//!   every block the band does not reach, holds ± the background 3h (OpenVDB's level-set
//!   convention, what its signed flood fill leaves). Blocks the band does not reach are listed
//!   by their sign (`NarrowBand::inside_blocks`); the surface does not cross them, so one
//!   value of f at a block's centre voxel decides it.
//! - **Dense** (`dense`): the band's exact values where the band is active; every other voxel
//!   gets the distance of the mesh distance slices (`crate::measure::GridMeshDistance`,
//!   within the mesh's chord error, warm-started along each row of constant (i, j)) and the
//!   sign the band holds for it (its block's voxel, or its block's sign).
//! - **Sign**: inside the band, the side of the mesh the voxel centre lies on, seen from its
//!   closest point q on the nearest triangle: the sign of (p − q) · n(q), the vertex normals
//!   (f's gradient directions) interpolated at q, so the band's zero crossing is the mesh's
//!   own, not f's zero set a chord error away; where that says nothing (p on the tangent
//!   plane) and outside the band, the sign of the model's f at the voxel centre (f < 0
//!   inside), the convention of every output.
//!
//! Invariants: values are finite; blocks and rows are fixed tasks computed sequentially, in a
//! fixed order, so the output does not depend on the thread count.

use rayon::prelude::*;

use super::{check_region, DistanceError};
use crate::cloud::Aabb;
use crate::implicit::ImplicitFunction;
use crate::measure::{closest_point_on_triangle, GridMeshDistance};
use crate::mesh::TriangleMesh;
use crate::vec3::dist2;
use crate::vec3::{cross, dot, norm, sub};

/// Half-width of the narrow band in voxels: voxels nearer the surface than this are active.
pub(crate) const BAND_VOXELS: f64 = 3.0;
/// The default voxel count along the region's longest side ([`VoxelSize::Auto`]).
pub(crate) const DEFAULT_VOXELS: usize = 256;
/// Most voxels along one axis (OpenVDB's top internal node spans 4096 voxels; the grid lives in
/// one of them).
pub(crate) const MAX_VOXELS_PER_AXIS: usize = 4096;
/// Most voxels a dense grid may hold (2 GB of float32).
pub(crate) const MAX_DENSE_VOXELS: usize = 1 << 29;
/// Voxels along a side of a block (OpenVDB's leaf node, `Tree_float_5_4_3`'s 3).
pub(crate) const BLOCK: usize = 8;
/// Voxels in a block.
pub(crate) const BLOCK_VOXELS: usize = BLOCK * BLOCK * BLOCK;

/// The edge length of a voxel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum VoxelSize {
    /// The region's longest side / `DEFAULT_VOXELS` (256 voxels along it). The default.
    #[default]
    Auto,
    /// This size, input units, > 0.
    Size(f64),
}

/// Parameters of `narrow_band` and `dense`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VolumeParams {
    /// The voxel size; default [`VoxelSize::Auto`].
    pub voxel_size: VoxelSize,
}

/// A uniform grid of cubic voxels (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct VoxelGrid {
    /// Centre of voxel (0, 0, 0), input coordinates.
    pub origin: [f64; 3],
    /// Edge length h of a voxel, input units.
    pub voxel_size: f64,
    /// Voxels along x, y and z.
    pub shape: [usize; 3],
}

impl VoxelGrid {
    /// The grid over `region` with the voxel size of `params` (see the module docs).
    ///
    /// # Errors
    /// [`DistanceError::InvalidRegion`] for an empty or non-finite region,
    /// [`DistanceError::InvalidParams`] for a voxel size that is not positive and finite or that
    /// would give more than [`MAX_VOXELS_PER_AXIS`] voxels along an axis.
    pub(crate) fn over(region: &Aabb, params: &VolumeParams) -> Result<VoxelGrid, DistanceError> {
        check_region(region)?;
        let extent = [0, 1, 2].map(|a| region.max[a] - region.min[a]);
        let longest = extent.iter().cloned().fold(0.0, f64::max);
        let h = match params.voxel_size {
            VoxelSize::Auto => longest / DEFAULT_VOXELS as f64,
            VoxelSize::Size(h) => h,
        };
        if !(h.is_finite() && h > 0.0) {
            return Err(DistanceError::InvalidParams(format!(
                "the voxel size must be a positive number, not {h}"
            )));
        }
        let n = ((longest / h).ceil() as usize).max(1);
        if longest / h > MAX_VOXELS_PER_AXIS as f64 {
            return Err(DistanceError::InvalidParams(format!(
                "a voxel size of {h} gives {n} voxels along the region's longest side ({longest}); \
                 at most {MAX_VOXELS_PER_AXIS}: raise --voxel-size to at least {}",
                longest / MAX_VOXELS_PER_AXIS as f64
            )));
        }
        let shape = extent.map(|e| ((e / h).ceil() as usize).clamp(1, MAX_VOXELS_PER_AXIS));
        let center = region.center();
        let origin = [0, 1, 2].map(|a| center[a] - 0.5 * (shape[a] as f64 - 1.0) * h);
        Ok(VoxelGrid {
            origin,
            voxel_size: h,
            shape,
        })
    }

    /// Centre of voxel `ijk` (any integer coordinates), input coordinates.
    pub(crate) fn position(&self, ijk: [i64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| self.origin[a] + ijk[a] as f64 * self.voxel_size)
    }

    /// Number of voxels.
    pub(crate) fn len(&self) -> usize {
        self.shape.iter().product()
    }
}

/// One 8³ block of the narrow band (an OpenVDB leaf node).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct BandBlock {
    /// Index of the block's first voxel (multiples of [`BLOCK`]).
    pub origin: [i32; 3],
    /// The 512 values, x-major: voxel origin + (x, y, z) at `x·64 + y·8 + z` (OpenVDB's leaf
    /// order). Active voxels hold their signed distance; the others ± the background.
    pub values: Vec<f32>,
    /// Active voxels, bit `n % 64` of word `n / 64` for the value at `n`.
    pub active: [u64; 8],
}

/// A narrow-band level set of the signed distance (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct NarrowBand {
    /// The voxel grid.
    pub grid: VoxelGrid,
    /// The background: [`BAND_VOXELS`] × the voxel size (input units), the value of inactive
    /// voxels outside (negated inside).
    pub background: f32,
    /// The blocks with active voxels, by origin (x, then y, then z).
    pub blocks: Vec<BandBlock>,
    /// Origins of the blocks of the grid that the band does not reach and that lie inside
    /// (f < 0), in the same order; every other block of the grid lies outside.
    pub inside_blocks: Vec<[i32; 3]>,
}

impl NarrowBand {
    /// Number of active voxels.
    #[cfg(test)] // only the unit tests call it
    pub(crate) fn active_voxels(&self) -> u64 {
        self.blocks
            .iter()
            .map(|b| {
                b.active
                    .iter()
                    .map(|w| u64::from(w.count_ones()))
                    .sum::<u64>()
            })
            .sum()
    }
}

/// A dense grid of signed distances (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct DenseVolume {
    /// The voxel grid.
    pub grid: VoxelGrid,
    /// One value per voxel, C order over (i, j, k): voxel (i, j, k) at `(i·ny + j)·nz + k`.
    pub values: Vec<f32>,
}

fn check_mesh(mesh: &TriangleMesh) -> Result<(), DistanceError> {
    let n = mesh.positions.len();
    if mesh.triangles.is_empty()
        || !mesh.positions.iter().flatten().all(|c| c.is_finite())
        || mesh.triangles.iter().flatten().any(|&i| i as usize >= n)
    {
        return Err(DistanceError::NoSurface);
    }
    Ok(())
}

/// The narrow-band level set of the signed distance to `mesh` (the polygonized zero set of
/// `f`) over `region`.
///
/// # Errors
/// As [`VoxelGrid::over`]; [`DistanceError::NoSurface`] when the mesh has no triangles or a
/// vertex that is not finite or an index out of range.
pub(crate) fn narrow_band<F: ImplicitFunction + ?Sized>(
    f: &F,
    mesh: &TriangleMesh,
    region: &Aabb,
    params: &VolumeParams,
) -> Result<NarrowBand, DistanceError> {
    let grid = VoxelGrid::over(region, params)?;
    check_mesh(mesh)?;
    let h = grid.voxel_size;
    let half_width = BAND_VOXELS * h;
    let background = half_width as f32;
    let n_blocks = grid.shape.map(|n| n.div_ceil(BLOCK));
    let block_key = |b: [usize; 3]| ((b[0] * n_blocks[1] + b[1]) * n_blocks[2] + b[2]) as u64;

    // (block, triangle) for every block a triangle's grown box reaches; sorted, each block's
    // triangles come in index order.
    let ranges: Vec<Option<[[usize; 2]; 3]>> = mesh
        .triangles
        .par_iter()
        .map(|t| voxel_range(&grid, &t.map(|i| mesh.positions[i as usize]), half_width))
        .collect();
    let mut pairs: Vec<(u64, u32)> = Vec::new();
    for (ti, range) in ranges.iter().enumerate() {
        let Some(r) = range else { continue };
        for bx in r[0][0] / BLOCK..=r[0][1] / BLOCK {
            for by in r[1][0] / BLOCK..=r[1][1] / BLOCK {
                for bz in r[2][0] / BLOCK..=r[2][1] / BLOCK {
                    pairs.push((block_key([bx, by, bz]), ti as u32));
                }
            }
        }
    }
    pairs.par_sort_unstable();
    let mut groups: Vec<(u64, std::ops::Range<usize>)> = Vec::new();
    let mut start = 0;
    for i in 1..=pairs.len() {
        if i == pairs.len() || pairs[i].0 != pairs[start].0 {
            groups.push((pairs[start].0, start..i));
            start = i;
        }
    }
    let unkey = |key: u64| {
        let key = key as usize;
        [
            key / (n_blocks[1] * n_blocks[2]),
            (key / n_blocks[2]) % n_blocks[1],
            key % n_blocks[2],
        ]
    };
    let blocks: Vec<Option<BandBlock>> = groups
        .par_iter()
        .map(|(key, members)| {
            let b = unkey(*key);
            let lo = b.map(|c| c * BLOCK);
            let mut d2 = vec![f64::INFINITY; BLOCK_VOXELS];
            // Per voxel, the nearest triangle found so far and its closest point.
            let mut nearest = vec![(u32::MAX, [0.0; 3]); BLOCK_VOXELS];
            for &(_, ti) in &pairs[members.clone()] {
                let Some(r) = ranges[ti as usize] else {
                    continue;
                };
                let tri = mesh.triangles[ti as usize].map(|i| mesh.positions[i as usize]);
                let from = [0, 1, 2].map(|a| r[a][0].max(lo[a]) - lo[a]);
                let to = [0, 1, 2].map(|a| r[a][1].min(lo[a] + BLOCK - 1) - lo[a]);
                for x in from[0]..=to[0] {
                    for y in from[1]..=to[1] {
                        for z in from[2]..=to[2] {
                            let p =
                                grid.position([lo[0] + x, lo[1] + y, lo[2] + z].map(|c| c as i64));
                            let q = closest_point_on_triangle(p, tri[0], tri[1], tri[2]);
                            let n = x * 64 + y * 8 + z;
                            let d = dist2(p, q);
                            if d < d2[n] {
                                d2[n] = d;
                                nearest[n] = (ti, q);
                            }
                        }
                    }
                }
            }
            let mut active = [0u64; 8];
            let values: Vec<f32> = (0..BLOCK_VOXELS)
                .map(|n| {
                    let ijk = [lo[0] + n / 64, lo[1] + (n / 8) % 8, lo[2] + n % 8];
                    let p = grid.position(ijk.map(|c| c as i64));
                    let d = d2[n].sqrt();
                    let in_grid = (0..3).all(|a| ijk[a] < grid.shape[a]);
                    let inside = match nearest[n] {
                        (ti, q) if d < half_width => {
                            mesh_side(mesh, ti, q, p).unwrap_or_else(|| f.value(p) < 0.0)
                        }
                        _ => f.value(p) < 0.0,
                    };
                    let magnitude = if in_grid && d < half_width {
                        active[n / 64] |= 1 << (n % 64);
                        d as f32
                    } else {
                        background
                    };
                    if inside {
                        -magnitude
                    } else {
                        magnitude
                    }
                })
                .collect();
            active.iter().any(|&w| w != 0).then(|| BandBlock {
                origin: lo.map(|c| c as i32),
                values,
                active,
            })
        })
        .collect();
    let blocks: Vec<BandBlock> = blocks.into_iter().flatten().collect();

    // Every other block of the grid takes the sign of f at its centre voxel (clamped into the
    // grid): the band does not reach it, so the surface does not cross it.
    let mut banded = vec![false; n_blocks.iter().product()];
    for b in &blocks {
        banded[block_key(b.origin.map(|c| c as usize / BLOCK)) as usize] = true;
    }
    let inside_blocks: Vec<[i32; 3]> = (0..banded.len())
        .into_par_iter()
        .filter_map(|key| {
            if banded[key] {
                return None;
            }
            let lo = unkey(key as u64).map(|c| c * BLOCK);
            let centre = [0, 1, 2].map(|a| (lo[a] + BLOCK / 2).min(grid.shape[a] - 1) as i64);
            (f.value(grid.position(centre)) < 0.0).then_some(lo.map(|c| c as i32))
        })
        .collect();
    Ok(NarrowBand {
        grid,
        background,
        blocks,
        inside_blocks,
    })
}

/// Whether `p` lies inside (behind) the mesh as seen from `q`, the closest point of triangle
/// `ti` to it: the sign of (p − q) · n(q), with n(q) the vertex normals interpolated at q
/// (the face's normal when the mesh has no vertex normals). `None` when p is (nearly) on the
/// tangent plane there, where that sign says nothing: within 10⁻⁹ of |p − q|.
fn mesh_side(mesh: &TriangleMesh, ti: u32, q: [f64; 3], p: [f64; 3]) -> Option<bool> {
    let t = mesh.triangles[ti as usize];
    let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
    let face = cross(sub(b, a), sub(c, a));
    let area2 = dot(face, face);
    let normal = if mesh.normals.len() == mesh.positions.len() && area2 > 0.0 {
        // Barycentric coordinates of q by the sub-triangles' areas (signed along `face`).
        let l = [
            dot(cross(sub(b, q), sub(c, q)), face) / area2,
            dot(cross(sub(c, q), sub(a, q)), face) / area2,
            dot(cross(sub(a, q), sub(b, q)), face) / area2,
        ];
        let n = t.map(|i| mesh.normals[i as usize]);
        [0, 1, 2].map(|k| l[0] * n[0][k] + l[1] * n[1][k] + l[2] * n[2][k])
    } else {
        face
    };
    let offset = sub(p, q);
    let side = dot(offset, normal);
    let scale = norm(offset) * norm(normal);
    (side.abs() > 1e-9 * scale).then_some(side < 0.0)
}

/// The voxels (inclusive index ranges per axis, clamped to the grid) whose centres lie in the
/// bounding box of `tri` grown by `margin`; `None` when there are none.
fn voxel_range(grid: &VoxelGrid, tri: &[[f64; 3]; 3], margin: f64) -> Option<[[usize; 2]; 3]> {
    let mut out = [[0; 2]; 3];
    for a in 0..3 {
        let lo = tri.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min) - margin;
        let hi = tri.iter().map(|p| p[a]).fold(f64::NEG_INFINITY, f64::max) + margin;
        let first = ((lo - grid.origin[a]) / grid.voxel_size).ceil().max(0.0);
        let last = ((hi - grid.origin[a]) / grid.voxel_size)
            .floor()
            .min(grid.shape[a] as f64 - 1.0);
        if first
            .partial_cmp(&last)
            .is_none_or(|o| o == std::cmp::Ordering::Greater)
        {
            return None;
        }
        out[a] = [first as usize, last as usize];
    }
    Some(out)
}

/// The dense grid of the signed distance to `mesh` over the grid of `band` (see the module
/// docs): `band` supplies the grid, its exact values near the surface and every voxel's sign
/// (the sign of f, which [`narrow_band`] evaluated), so f is not needed again.
///
/// # Errors
/// [`DistanceError::InvalidParams`] when the grid has more than [`MAX_DENSE_VOXELS`] voxels (a
/// larger voxel size helps); [`DistanceError::NoSurface`] as for [`narrow_band`].
pub(crate) fn dense(mesh: &TriangleMesh, band: &NarrowBand) -> Result<DenseVolume, DistanceError> {
    let grid = band.grid;
    if grid.len() > MAX_DENSE_VOXELS {
        return Err(DistanceError::InvalidParams(format!(
            "a dense grid of {} × {} × {} voxels is over the limit of {MAX_DENSE_VOXELS}; raise --voxel-size",
            grid.shape[0], grid.shape[1], grid.shape[2]
        )));
    }
    check_mesh(mesh)?;
    let index = GridMeshDistance::new(mesh).ok_or(DistanceError::NoSurface)?;
    let [nx, ny, nz] = grid.shape;
    // The band decides every voxel's sign: its blocks hold the sign of f at each of their
    // voxels, and every other block is listed by its sign. So only the distance is searched.
    let n_blocks = grid.shape.map(|n| n.div_ceil(BLOCK));
    let block_key =
        |o: [usize; 3]| (o[0] / BLOCK * n_blocks[1] + o[1] / BLOCK) * n_blocks[2] + o[2] / BLOCK;
    let mut block_of = vec![u32::MAX; n_blocks.iter().product()];
    for (n, b) in band.blocks.iter().enumerate() {
        block_of[block_key(b.origin.map(|c| c as usize))] = n as u32;
    }
    let mut inside_block = vec![false; block_of.len()];
    for o in &band.inside_blocks {
        inside_block[block_key(o.map(|c| c as usize))] = true;
    }
    let rows: Vec<Vec<f32>> = (0..nx * ny)
        .into_par_iter()
        .map(|row| {
            let (i, j) = (row / ny, row % ny);
            let mut warm = None;
            (0..nz)
                .map(|k| {
                    let key = block_key([i, j, k]);
                    let (inside, exact) = match block_of[key] {
                        u32::MAX => (inside_block[key], None),
                        b => {
                            let block = &band.blocks[b as usize];
                            let n = (i % BLOCK) * 64 + (j % BLOCK) * 8 + k % BLOCK;
                            let active = block.active[n / 64] >> (n % 64) & 1 == 1;
                            (block.values[n] < 0.0, active.then_some(block.values[n]))
                        }
                    };
                    if let Some(v) = exact {
                        return v;
                    }
                    let p = grid.position([i as i64, j as i64, k as i64]);
                    let (d, vertex) = index.distance_from(p, warm);
                    warm = Some(vertex);
                    (if inside { -d } else { d }) as f32
                })
                .collect()
        })
        .collect();
    let values: Vec<f32> = rows.into_iter().flatten().collect();
    Ok(DenseVolume { grid, values })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poly::ImplicitPolynomial;
    use crate::polygonize::{polygonize, PolygonizeParams};

    /// The cube [−half, half]³ and `poly` meshed in it at `depth`.
    fn meshed_in_cube(poly: &ImplicitPolynomial, half: f64, depth: u32) -> (Aabb, TriangleMesh) {
        let region = Aabb {
            min: [-half; 3],
            max: [half; 3],
        };
        let params = PolygonizeParams {
            depth,
            ..Default::default()
        };
        let mesh = polygonize(poly, &region, &params).unwrap().mesh;
        (region, mesh)
    }

    fn sphere(r: f64) -> ImplicitPolynomial {
        let mut c = vec![0.0; 10];
        (c[0], c[4], c[7], c[9]) = (-r * r, 1.0, 1.0, 1.0);
        ImplicitPolynomial {
            degree: 2,
            coefficients: c,
            center: [0.0; 3],
            scale: 1.0,
        }
    }

    #[test]
    fn sphere_band_and_dense_match_the_analytic_distance() {
        // A sphere of radius 1 meshed at depth 6 over [−1.5, 1.5]³: cells of 3/64, chord error
        // (edge)²/(8r) ≤ (√3·3/64)²/8 ≈ 8.3e-4 (the mesh lies inside the sphere by at most that).
        let poly = sphere(1.0);
        let (region, mesh) = meshed_in_cube(&poly, 1.5, 6);
        let params = VolumeParams {
            voxel_size: VoxelSize::Size(0.05),
        };
        let band = narrow_band(&poly, &mesh, &region, &params).unwrap();
        let h = 0.05;
        assert_eq!(band.grid.shape, [60, 60, 60]);
        assert!((band.grid.origin[0] - (-1.475)).abs() < 1e-12);
        let truth = |p: [f64; 3]| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 1.0;
        let mut worst: f64 = 0.0;
        let mut n_active = 0;
        for b in &band.blocks {
            for n in 0..BLOCK_VOXELS {
                let ijk = [n / 64, (n / 8) % 8, n % 8];
                let ijk = [0, 1, 2].map(|a| (b.origin[a] + ijk[a] as i32) as i64);
                let p = band.grid.position(ijk);
                let v = f64::from(b.values[n]);
                let t = truth(p);
                if b.active[n / 64] >> (n % 64) & 1 == 1 {
                    n_active += 1;
                    worst = worst.max((v - t).abs());
                    assert!(t.abs() < 3.0 * h + 1e-3, "active voxel at {t}");
                } else {
                    // Inactive voxels carry ± the background with the true sign.
                    assert_eq!(v.abs(), f64::from(band.background));
                    assert_eq!(v < 0.0, t < 0.0, "sign at {p:?}");
                    assert!(t.abs() > 3.0 * h - 1e-3);
                }
            }
        }
        assert_eq!(n_active as u64, band.active_voxels());
        assert!(worst < 1e-3, "band error {worst}");
        // Every voxel within the band is active: the shell of radii 1 ± 3h holds about
        // 4π·2·3h/h³ ≈ 30,000 voxel centres.
        let expected = 4.0 * std::f64::consts::PI * 6.0 * h / h.powi(3);
        assert!(
            (n_active as f64 - expected).abs() < 0.02 * expected,
            "{n_active} vs {expected}"
        );
        // The centre block is inside, the corner block outside.
        assert!(band.inside_blocks.contains(&[24, 24, 24]));
        assert!(!band.inside_blocks.contains(&[0, 0, 0]));

        let dense = dense(&mesh, &band).unwrap();
        assert_eq!(dense.values.len(), 60 * 60 * 60);
        let mut worst: f64 = 0.0;
        for i in 0..60 {
            for j in 0..60 {
                for k in 0..60 {
                    let p = band.grid.position([i, j, k]);
                    let v = f64::from(dense.values[((i * 60 + j) * 60 + k) as usize]);
                    worst = worst.max((v - truth(p)).abs());
                }
            }
        }
        assert!(worst < 1.5e-3, "dense error {worst}");
    }

    #[test]
    fn grid_limits_and_threads() {
        let region = Aabb {
            min: [0.0; 3],
            max: [2.0, 1.0, 0.5],
        };
        let g = VoxelGrid::over(&region, &VolumeParams::default()).unwrap();
        assert_eq!(g.shape, [256, 128, 64]);
        assert!(matches!(
            VoxelGrid::over(
                &region,
                &VolumeParams {
                    voxel_size: VoxelSize::Size(1e-4)
                }
            ),
            Err(DistanceError::InvalidParams(_))
        ));
        assert!(matches!(
            VoxelGrid::over(
                &region,
                &VolumeParams {
                    voxel_size: VoxelSize::Size(-1.0)
                }
            ),
            Err(DistanceError::InvalidParams(_))
        ));
        let poly = sphere(0.8);
        let (region, mesh) = meshed_in_cube(&poly, 1.0, 4);
        let params = VolumeParams {
            voxel_size: VoxelSize::Size(0.07),
        };
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let a = one.install(|| narrow_band(&poly, &mesh, &region, &params).unwrap());
        let b = narrow_band(&poly, &mesh, &region, &params).unwrap();
        assert_eq!(a, b);
        let empty = TriangleMesh::default();
        assert_eq!(
            narrow_band(&poly, &empty, &region, &params).unwrap_err(),
            DistanceError::NoSurface
        );
    }
}

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn narrow_band() -> Result<(), Box<dyn std::error::Error>> {
        use crate::cloud::Aabb;
        use crate::distance::volume::{narrow_band, VolumeParams, VoxelSize};
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
                depth: 5,
                ..Default::default()
            },
        )?
        .mesh;
        let params = VolumeParams {
            voxel_size: VoxelSize::Size(0.1),
        };
        let band = narrow_band(&sphere, &mesh, &region, &params).unwrap();
        assert_eq!(band.grid.shape, [30, 30, 30]);
        assert!((band.background - 0.3).abs() < 1e-6);
        assert!(band.active_voxels() > 1000);
        Ok(())
    }
}
