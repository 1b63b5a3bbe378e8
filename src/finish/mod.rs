//! Stage `finish`: the polygonized mesh → the mesh `run` writes, with its figures.
//!
//! Input: a [`Model`], the [`TriangleMesh`] polygonized from it, the data points (with their
//! colours, when the scan has them) and [`FinishParams`]. Output: [`Finished`] (the mesh as
//! written, the closed mesh the distance outputs measure, and each vertex's distance to the data
//! and colour) and a [`FinishReport`] (components left out, what the trim and the decimation
//! did, the topology checks, the accuracy against the data).
//!
//! ```text
//! mesh ─ keep ─ trim ─ decimate ─┬─ checks
//!          │                     ├─ accuracy against the data
//!          │                     └─ each vertex's distance to the data, and its colour
//!          └─ closed: the mesh the slices and volumes measure
//! ```
//!
//! *Keep* leaves out the components far from the data and small nested or unsupported ones
//! ([`Keep::Data`]); *trim* ([`crate::trim`](mod@crate::trim)) removes what the data does not support and fairs
//! the holes it leaves; *decimate* ([`decimate`]) collapses edges down to a triangle budget. The
//! checks, the accuracy and the per-vertex values all measure the mesh as written, so they run
//! last. One k-d tree of the data serves every nearest-point query. The stage does no IO and
//! encodes nothing: [`crate::export`](mod@crate::export) turns its output into bytes. Every part runs on the rayon
//! pool and its results do not depend on the thread count.

pub mod decimate;

use std::borrow::Cow;

use serde::Serialize;

use crate::cloud::Aabb;
use crate::measure::{self, Accuracy};
use crate::mesh::{self, MeshReport, TriangleMesh};
use crate::model::Model;
use crate::numerics::point_tree::PointIndex;
use crate::trim::{self, TrimParams, TrimReport};
use decimate::{DecimateParams, DecimateReport};

/// The finish stage's version. If you change any input to this stage's key (the fields of
/// [`FinishParams`] or how they are written), or anything that changes its output for the same
/// input and params, bump `STAGE_VERSION`.
pub(crate) const STAGE_VERSION: u32 = 1;

/// With [`Keep::Data`], closed pieces inside another piece and smaller than this share of the
/// largest piece's area are left out ([`mesh::drop_small_nested_components`]).
pub(crate) const NESTED_AREA_FRACTION: f64 = 0.01;

/// With [`Keep::Data`], pieces smaller than [`NESTED_AREA_FRACTION`] of the largest piece's area
/// whose bounding box holds fewer than this many data points are left out
/// ([`mesh::drop_small_unsupported_components`]): fewer than a local fit of degree 2 needs.
pub(crate) const SUPPORT_POINTS_MIN: usize = 15;

/// Components whose nearest data point is farther than this share of the data's diagonal are
/// left out by [`Keep::Data`].
const FAR_COMPONENT_SHARE: f64 = 0.02;

/// How many of the nearest data points a vertex's colour is interpolated from.
const COLOUR_NEIGHBOURS: usize = 4;

/// Which zero-set components the mesh keeps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum Keep {
    /// Every component.
    #[default]
    All,
    /// Only components with a data point within 2% of the data's diagonal, and no small closed
    /// piece inside another (`mesh::drop_small_nested_components`; see `NESTED_AREA_FRACTION`),
    /// nor a small piece with fewer than `SUPPORT_POINTS_MIN` data points in its box
    /// (`mesh::drop_small_unsupported_components`).
    Data,
}

/// Everything besides the model, the mesh and the data that decides the finish stage's output.
///
/// Its [`Serialize`] form is the stage's canonical key bytes (fields by name, in a fixed order,
/// with the trim's and the decimation's versions, since both run inside this stage).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FinishParams {
    /// Which zero-set components the mesh keeps.
    pub keep: Keep,
    /// The trim of the mesh to the surface its data supports ([`TrimParams::off`] keeps it all).
    pub trim: TrimParams,
    /// The decimation to a triangle budget after the filter and the trim (`--target-triangles`);
    /// `None` keeps every triangle.
    pub decimate: Option<DecimateParams>,
}

impl Serialize for FinishParams {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut value = serde_json::json!({
            "keep": format!("{:?}", self.keep),
            "trim": self.trim,
            "trim_version": trim::STAGE_VERSION,
        });
        // Only a decimating run has these.
        if let Some(decimate) = self.decimate {
            value["target_triangles"] = serde_json::Value::from(decimate.target_triangles);
            value["decimate_version"] = serde_json::Value::from(decimate::VERSION);
        }
        value.serialize(serializer)
    }
}

/// What the finish stage makes besides its report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Finished {
    /// The mesh as written (after the component filter, the trim and the decimation), in input
    /// coordinates.
    pub mesh: TriangleMesh,
    /// The mesh after the component filter only, when the trim or the decimation changed it:
    /// the closed zero set whose sides the model's sign tells, which the distance slices and
    /// volumes measure. `None` when it is [`Finished::mesh`].
    pub closed: Option<TriangleMesh>,
    /// Each vertex's distance to its nearest data point (PLY's vertex quality); `None` when no
    /// data point is finite.
    pub quality: Option<Vec<f32>>,
    /// Each vertex's colour, interpolated from its nearest data points, when the data has
    /// colours.
    pub colours: Option<Vec<[u8; 3]>>,
}

impl Finished {
    /// The mesh the distance outputs measure: [`Finished::closed`], else the mesh itself.
    pub(crate) fn closed(&self) -> &TriangleMesh {
        self.closed.as_ref().unwrap_or(&self.mesh)
    }
}

/// The finish stage's figures, stored in its cache entry.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FinishReport {
    /// Components left out for having no data point within 2% of the data's diagonal.
    pub dropped_components: usize,
    /// Small closed components left out for lying inside another (`NESTED_AREA_FRACTION`).
    pub dropped_nested: usize,
    /// Small components left out for holding fewer than `SUPPORT_POINTS_MIN` data points in
    /// their box.
    pub dropped_unsupported: usize,
    /// What the trim removed and closed.
    pub trim: TrimReport,
    /// What the decimation did, when the params asked for one.
    pub decimate: Option<DecimateReport>,
    /// The topology checks of the mesh as written.
    pub mesh: MeshReport,
    /// Two-sided distances between the data points and the mesh as written.
    pub accuracy: Accuracy,
}

/// Why the finish stage failed.
#[derive(Debug, thiserror::Error)]
pub enum FinishError {
    /// The trim failed (see [`crate::trim::TrimError`]).
    #[error("trimming the mesh failed")]
    Trim(#[from] trim::TrimError),
    /// The colours are not one per data point.
    #[error("{colours} colours for {points} data points: give one colour per point")]
    Colours {
        /// Colours given.
        colours: usize,
        /// Data points given.
        points: usize,
    },
}

/// The finish stage (see the module docs).
///
/// `known_embedded` passes on what the meshing proved: no triangle of `mesh` crosses another
/// ([`crate::polygonize::Polygonized::embedded`]); the check then counts no self-intersecting
/// face without testing again (`mesh::check_with`). Pass `false` for any other mesh.
///
/// # Errors
/// [`FinishError::Trim`] from the trim, [`FinishError::Colours`] when `colours` is not one per
/// point.
///
/// ```
/// use stablesurf::finish::{finish, FinishParams};
/// use stablesurf::model::Model;
/// use stablesurf::{ImplicitModel, ImplicitPolynomial, TriangleMesh};
/// let mesh = TriangleMesh {
///     positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
///     normals: vec![[0.0, 0.0, 1.0]; 3],
///     triangles: vec![[0, 1, 2]],
/// };
/// // z = 0, the plane of the triangle (coefficients of 1, x, y, z).
/// let plane = ImplicitPolynomial {
///     degree: 1,
///     coefficients: vec![0.0, 0.0, 0.0, 1.0],
///     center: [0.0; 3],
///     scale: 1.0,
/// };
/// let model = Model::Global(ImplicitModel { polynomial: plane, bounds: None, fit: None, diagnostics: None });
/// let (finished, report) =
///     finish(&model, &mesh, false, &mesh.positions, None, &FinishParams::default()).unwrap();
/// assert_eq!(finished.mesh, mesh);
/// assert_eq!(finished.quality, Some(vec![0.0; 3]));
/// assert_eq!(report.mesh.boundary_edges, 3);
/// ```
pub fn finish(
    model: &Model,
    mesh: &TriangleMesh,
    known_embedded: bool,
    points: &[[f64; 3]],
    colours: Option<&[[u16; 3]]>,
    params: &FinishParams,
) -> Result<(Finished, FinishReport), FinishError> {
    if let Some(c) = colours
        && c.len() != points.len()
    {
        return Err(FinishError::Colours {
            colours: c.len(),
            points: points.len(),
        });
    }
    let data_diagonal = Aabb::from_points(points).map_or(0.0, |b| b.diagonal());
    // One index of the data points for every nearest-point query below.
    let data = PointIndex::new(points);
    let mut kept = Cow::Borrowed(mesh);
    let (mut dropped_components, mut dropped_nested, mut dropped_unsupported) = (0, 0, 0);
    // The input vertices' distances to the data, when the component filter measured them: the
    // vertex quality reuses them if the vertices written are those same vertices.
    let mut input_distances = None;
    if params.keep == Keep::Data {
        let distances = data.as_ref().map_or_else(
            || vec![f64::INFINITY; kept.positions.len()],
            |index| index.distances(&kept.positions),
        );
        let (far, n) = mesh::drop_components_by_distance(
            &kept,
            &distances,
            FAR_COMPONENT_SHARE * data_diagonal,
        );
        input_distances = data.is_some().then_some(distances);
        (kept, dropped_components) = (Cow::Owned(far), n);
        let (nested, n) = mesh::drop_small_nested_components(&kept, NESTED_AREA_FRACTION);
        (kept, dropped_nested) = (Cow::Owned(nested), n);
        let (supported, n) = mesh::drop_small_unsupported_components(
            &kept,
            points,
            NESTED_AREA_FRACTION,
            SUPPORT_POINTS_MIN,
        );
        (kept, dropped_unsupported) = (Cow::Owned(supported), n);
    }
    // The trim: the surface the data supports (the mesh itself when all of it is).
    let trimmed = trim::trim(&kept, points, &params.trim)?;
    let trim_report = trimmed.report;
    let mut written: Option<TriangleMesh> = (trim_report.removed_triangles > 0
        || trim_report.faired_vertices > 0)
        .then_some(trimmed.mesh);
    // The decimation, last, so that the budget counts the triangles written.
    let mut known_embedded = known_embedded;
    let decimate_report = params.decimate.map(|p| {
        let out = decimate::decimate(written.as_ref().unwrap_or(&kept), model.function(), &p);
        if out.report.collapses > 0 {
            written = Some(out.mesh);
            // Measured again rather than vouched for: the collapses test their new triangles
            // against their neighbours only.
            known_embedded = false;
        }
        out.report
    });
    let m: &TriangleMesh = written.as_ref().unwrap_or(&kept);
    let ((report, accuracy), (quality, vertex_colours)) = rayon::join(
        || {
            rayon::join(
                // The component filter and the trim only take triangles away, add ones tested
                // against the rest or move vertices whose triangles are tested against the
                // rest: an embedded mesh stays embedded.
                || mesh::check_with(m, known_embedded),
                || {
                    data.as_ref().map_or_else(Default::default, |index| {
                        measure::accuracy(index, m, data_diagonal)
                    })
                },
            )
        },
        || {
            rayon::join(
                || {
                    data.as_ref().map(|index| match &input_distances {
                        // The same queries against the same index: the same distances.
                        Some(d) if m.positions == mesh.positions => {
                            d.iter().map(|&d| d as f32).collect()
                        }
                        _ => index
                            .distances(&m.positions)
                            .into_iter()
                            .map(|d| d as f32)
                            .collect(),
                    })
                },
                || {
                    colours
                        .zip(data.as_ref())
                        .map(|(c, index)| vertex_colours(&m.positions, index, points, c))
                },
            )
        },
    );
    let (mesh, closed) = match written {
        Some(written) => (written, Some(kept.into_owned())),
        None => (kept.into_owned(), None),
    };
    let finished = Finished {
        mesh,
        closed,
        quality,
        colours: vertex_colours,
    };
    let report = FinishReport {
        dropped_components,
        dropped_nested,
        dropped_unsupported,
        trim: trim_report,
        decimate: decimate_report,
        mesh: report,
        accuracy,
    };
    Ok((finished, report))
}

/// Each vertex's colour, interpolated from its [`COLOUR_NEIGHBOURS`] nearest data points with
/// inverse-distance weights (the nearest point's colour when the vertex is on it), in the 16-bit
/// values of the scan and then rounded to 8 bits. `data` indexes the finite ones of `points`,
/// whose colours are `colours`. Per vertex, so the result does not depend on the thread count;
/// ties between equally near points are broken by the k-d tree's fixed order.
fn vertex_colours(
    vertices: &[[f64; 3]],
    data: &PointIndex<'_>,
    points: &[[f64; 3]],
    colours: &[[u16; 3]],
) -> Vec<[u8; 3]> {
    use rayon::prelude::*;
    // The colours of the indexed points: the finite ones, in order, as the index keeps them.
    let finite_colours: Vec<[u16; 3]> = points
        .iter()
        .zip(colours)
        .filter(|(p, _)| p.iter().all(|c| c.is_finite()))
        .map(|(_, c)| *c)
        .collect();
    let tree = data.tree();
    let colour_of = |q: &[f64; 3]| -> [u8; 3] {
        let mut nearest = [(0.0, 0_u32); COLOUR_NEIGHBOURS];
        let n = tree.nearest_n_within(*q, f64::INFINITY, &mut nearest);
        let nearest = &nearest[..n];
        let to_u8 = |v: f64| (v / 257.0).round().clamp(0.0, 255.0) as u8;
        match nearest {
            [] => [0; 3],
            [(d2, i), ..] if *d2 == 0.0 || n == 1 => {
                finite_colours[*i as usize].map(|c| to_u8(f64::from(c)))
            }
            _ => {
                let mut sum = [0.0; 3];
                let mut total = 0.0;
                for &(d2, i) in nearest {
                    let weight = 1.0 / d2.sqrt();
                    total += weight;
                    for (s, &c) in sum.iter_mut().zip(&finite_colours[i as usize]) {
                        *s += weight * f64::from(c);
                    }
                }
                sum.map(|s| to_u8(s / total))
            }
        }
    };
    vertices.par_iter().map(colour_of).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key_bytes(params: &FinishParams) -> String {
        serde_json::to_string(params).unwrap()
    }

    /// The key bytes name every field; a changed spelling orphans every cache entry of the
    /// stage, so it needs a version bump.
    #[test]
    fn key_bytes_are_the_stage_recipe() {
        let trim: serde_json::Value = serde_json::to_value(TrimParams::off()).unwrap();
        let expected = serde_json::json!({
            "keep": "All",
            "trim": trim,
            "trim_version": trim::STAGE_VERSION,
        });
        let params = FinishParams {
            trim: TrimParams::off(),
            ..Default::default()
        };
        assert_eq!(key_bytes(&params), expected.to_string());
    }

    #[test]
    fn same_params_same_key_and_each_change_differs() {
        let base = FinishParams {
            trim: TrimParams::off(),
            ..Default::default()
        };
        assert_eq!(key_bytes(&base), key_bytes(&base.clone()));
        let changed = [
            FinishParams {
                keep: Keep::Data,
                ..base.clone()
            },
            FinishParams {
                trim: TrimParams::default(),
                ..base.clone()
            },
            FinishParams {
                decimate: Some(DecimateParams {
                    target_triangles: 5000,
                }),
                ..base.clone()
            },
            FinishParams {
                decimate: Some(DecimateParams {
                    target_triangles: 5001,
                }),
                ..base.clone()
            },
        ];
        for (i, params) in changed.iter().enumerate() {
            assert_ne!(key_bytes(params), key_bytes(&base), "change {i}");
        }
    }

    /// A piece far from the data goes with `Keep::Data`, and the closed mesh then is the
    /// filtered one: the written mesh and the measured one agree when nothing is trimmed.
    #[test]
    fn keep_data_drops_a_far_piece_and_measures_what_is_written() {
        let tri = |o: f64| -> TriangleMesh {
            TriangleMesh {
                positions: vec![[o, 0.0, 0.0], [o + 1.0, 0.0, 0.0], [o, 1.0, 0.0]],
                normals: vec![[0.0, 0.0, 1.0]; 3],
                triangles: vec![[0, 1, 2]],
            }
        };
        let (near, far) = (tri(0.0), tri(100.0));
        let mut both = near.clone();
        both.positions.extend(&far.positions);
        both.normals.extend(&far.normals);
        both.triangles.push([3, 4, 5]);
        let plane = crate::poly::ImplicitPolynomial {
            degree: 1,
            coefficients: vec![0.0, 0.0, 0.0, 1.0],
            center: [0.0; 3],
            scale: 1.0,
        };
        let model = Model::Global(crate::poly::ImplicitModel {
            polynomial: plane,
            bounds: None,
            fit: None,
            diagnostics: None,
        });
        let params = FinishParams {
            keep: Keep::Data,
            trim: TrimParams::off(),
            decimate: None,
        };
        let (finished, report) =
            finish(&model, &both, false, &near.positions, None, &params).unwrap();
        assert_eq!(report.dropped_components, 1);
        assert_eq!(finished.mesh.triangles.len(), 1);
        assert!(finished.closed.is_none());
        assert_eq!(finished.quality, Some(vec![0.0; 3]));
        assert_eq!(report.mesh.faces, 1);
        let colours = [[257 * 10, 257 * 20, 257 * 30]; 3];
        let (coloured, _) = finish(
            &model,
            &both,
            false,
            &near.positions,
            Some(&colours),
            &params,
        )
        .unwrap();
        assert_eq!(coloured.colours, Some(vec![[10, 20, 30]; 3]));
        let short = finish(
            &model,
            &both,
            false,
            &near.positions,
            Some(&colours[..2]),
            &params,
        );
        assert!(matches!(
            short,
            Err(FinishError::Colours {
                colours: 2,
                points: 3
            })
        ));
    }
}
