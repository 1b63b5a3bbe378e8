//! Point-cloud artifacts passed between the `import`, `normals` and `fit` stages.
//!
//! Input: nothing (plain data). Output: [`PointCloud`] (what a scan file holds) and
//! [`OrientedCloud`] (points with unit outward normals), plus the axis-aligned box [`Aabb`].
//!
//! Invariants: every index in `triangles` is `< points.len()`; when `normals` is present it has
//! one entry per point, and so have a range surface's `falloff`, a cloud's `colours` and
//! `intensity`, and an oriented cloud's `weights`; a cloud's `scans` count its points in order
//! (their `n_points` sum to `points.len()`). All coordinates are in the input file's frame and
//! units, as `f64`.

use serde::{Deserialize, Serialize};

/// A scan as imported: points, optional per-point normals, optional triangles.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointCloud {
    /// Point positions in the input file's coordinates and units.
    pub points: Vec<[f64; 3]>,
    /// Per-point normals as stored in the file (not necessarily unit length, not necessarily
    /// outward), or `None` when the file has none.
    pub normals: Option<Vec<[f64; 3]>>,
    /// Triangles as indices into `points`, polygons fan-triangulated, winding as in the file.
    /// Empty for a pure point cloud.
    pub triangles: Vec<[u32; 3]>,
    /// Set when `triangles` were made from a range scan's grid: they are then an open surface
    /// wound so that their normals face the scanner, not a closed mesh. `None` for any other file.
    pub range: Option<RangeSurface>,
    /// Per-point colour as 16-bit RGB (65535 is full intensity; a file's 8-bit colours are
    /// scaled by 257 and LAS colours are kept as stored), or `None` when the file has none.
    /// Carried through outlier removal; the surface stages do not use it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub colours: Option<Vec<[u16; 3]>>,
    /// Per-point return intensity in the file's own units (LAS: 0–65535; PTS: as written;
    /// E57: as stored, before the file's limits would normalize it), or `None` when the file
    /// has none. Carried through outlier removal; the surface stages do not use it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intensity: Option<Vec<f32>>,
    /// For a file of several registered scans (E57): where each scan's scanner stood and how
    /// many consecutive points are its, in file order. The normals stage turns each point's
    /// normal to face its own scan's scanner. `None` for a file without scanner positions.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scans: Option<Vec<ScanOrigin>>,
}

impl PointCloud {
    /// Version of this artifact's layout; bump it whenever a field changes.
    pub(crate) const FORMAT_VERSION: u32 = 3;
}

/// One registered scan of a multi-scan file: its scanner's position and its share of the points.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ScanOrigin {
    /// The scanner's position in the cloud's frame (the translation of the scan's pose).
    pub sensor: [f64; 3],
    /// How many consecutive points of the cloud this scan gave.
    pub n_points: usize,
}

/// What a range grid tells about its samples beyond their positions.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RangeSurface {
    /// The scanner's estimated position in the file's coordinates, or `None` when the grid's
    /// scan lines do not fix it.
    pub sensor: Option<[f64; 3]>,
    /// Per point, in (0, 1]: how far it lies from the edge of the scanned surface (1 inside,
    /// lower within a few samples of a hole, a cut or the grid's border), as VRIP ramps its
    /// confidence down towards a range mesh's boundary.
    pub falloff: Vec<f32>,
}

/// Points with unit-length outward normals: the input of the `fit` stage.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct OrientedCloud {
    /// Point positions in input coordinates.
    pub points: Vec<[f64; 3]>,
    /// One unit-length normal per point, pointing out of the object.
    pub normals: Vec<[f64; 3]>,
    /// Per point, a confidence in (0, 1] that weighs its rows in the detail mode's local fits
    /// (head-on range samples more than grazing ones or those near a scan's edge); `None` weighs
    /// every point 1.
    pub weights: Option<Vec<f32>>,
}

impl OrientedCloud {
    /// Version of this artifact's layout; bump it whenever a field changes.
    pub(crate) const FORMAT_VERSION: u32 = 2;
}

/// An axis-aligned box in input coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Aabb {
    /// Smallest corner.
    pub min: [f64; 3],
    /// Largest corner.
    pub max: [f64; 3],
}

impl Aabb {
    /// The tightest box around the finite points of `points`, or `None` when there is none.
    ///
    /// ```
    /// use stablesurf::Aabb;
    /// let b = Aabb::from_points(&[[0.0, 1.0, 2.0], [1.0, -1.0, 3.0]]).unwrap();
    /// assert_eq!(b.min, [0.0, -1.0, 2.0]);
    /// assert_eq!(b.max, [1.0, 1.0, 3.0]);
    /// ```
    pub fn from_points(points: &[[f64; 3]]) -> Option<Aabb> {
        let mut finite = points.iter().filter(|p| p.iter().all(|c| c.is_finite()));
        let first = *finite.next()?;
        let mut b = Aabb {
            min: first,
            max: first,
        };
        for p in finite {
            b.min = [0, 1, 2].map(|a| b.min[a].min(p[a]));
            b.max = [0, 1, 2].map(|a| b.max[a].max(p[a]));
        }
        Some(b)
    }

    /// The box grown by `fraction` of its size on each side (0.1 grows each side by 10%).
    /// A side of zero length is grown by `fraction` of the diagonal instead.
    pub fn grown(&self, fraction: f64) -> Aabb {
        let diag = self.diagonal();
        let mut b = *self;
        for a in 0..3 {
            let size = self.max[a] - self.min[a];
            let pad = if size > 0.0 {
                size * fraction
            } else {
                diag * fraction
            };
            b.min[a] -= pad;
            b.max[a] += pad;
        }
        b
    }

    /// Length of the box's diagonal.
    pub fn diagonal(&self) -> f64 {
        (0..3)
            .map(|a| (self.max[a] - self.min[a]).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// Centre of the box.
    pub(crate) fn center(&self) -> [f64; 3] {
        [0, 1, 2].map(|a| 0.5 * (self.min[a] + self.max[a]))
    }

    /// Whether `p` lies in the closed box.
    pub fn contains(&self, p: [f64; 3]) -> bool {
        (0..3).all(|a| p[a] >= self.min[a] && p[a] <= self.max[a])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grown_box_keeps_center_and_scales_sides() {
        let b = Aabb {
            min: [0.0, 0.0, 0.0],
            max: [10.0, 2.0, 0.0],
        };
        let g = b.grown(0.1);
        assert_eq!(g.min[0], -1.0);
        assert_eq!(g.max[1], 2.2);
        // The flat z side grows by 10% of the diagonal.
        assert!((g.max[2] - 0.1 * b.diagonal()).abs() < 1e-12);
        assert_eq!(g.center()[0], b.center()[0]);
    }

    #[test]
    fn from_points_skips_non_finite() {
        let b = Aabb::from_points(&[[f64::NAN, 0.0, 0.0], [1.0, 2.0, 3.0]]).unwrap();
        assert_eq!(b.min, [1.0, 2.0, 3.0]);
        assert!(Aabb::from_points(&[]).is_none());
    }
}
