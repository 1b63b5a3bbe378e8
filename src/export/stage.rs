//! Stage `export`: the fitted model and its mesh → the bytes of every output file of `run`,
//! with the figures the report gives about them.
//!
//! Input: a [`Model`], the [`TriangleMesh`] polygonized from it, the data points (with their
//! colours, when the scan has them), and [`ExportParams`]. Output: an [`ExportOutput`]: the files as (name relative to the output
//! folder, bytes), in a fixed order, and the figures of the mesh as written (components left
//! out, what the trim removed, the topology checks, the accuracy against the data).
//!
//! ```text
//! mesh ─ keep (components far from the data, small nested ones) ─ trim ─┬─ checks, accuracy
//!                                                                       ├─ model, glb, gltf, ply, png
//!                                                                       └─ slices from the mesh
//! model ────────────────────────────────────────────────────────────────── slices from the model
//! ```
//!
//! [`export`] is the stage. Its two halves are public too, for a caller that starts the slices
//! of a polynomial model before the mesh exists: [`model_slices`] (the slice files the model
//! alone decides, when it does) and [`export_mesh`] (everything else); `export` is `export_mesh`
//! followed by the files of `model_slices`, so both orders give the same bytes. The stage does no
//! IO: writing the files is the caller's ([`crate::outputs`]). Every part runs on the rayon pool
//! and its bytes do not depend on the thread count.

use std::borrow::Cow;

use serde::Serialize;

use super::gltf::GltfOptions;
use super::{exr, mesh_files, npy, ply, png, vdb, ExportError, MeshFileOptions, MeshFormat};
use crate::cloud::Aabb;
use crate::distance::volume::{self, VolumeParams, VoxelSize};
use crate::distance::{DistanceMethod, Slice, SliceParams};
use crate::measure::{self, Accuracy};
use crate::mesh::{self, MeshReport, TriangleMesh};
use crate::model::Model;
use crate::polygonize::decimate::{self, DecimateParams, DecimateReport};
use crate::trim::{self, TrimParams, TrimReport};

/// The export stage's version. If you change any input to this stage's key (the fields of
/// [`ExportParams`] or how they are written), or anything that changes its output for the same
/// input and params, bump `STAGE_VERSION`.
pub const STAGE_VERSION: u32 = 14;

/// With [`Keep::Data`], closed pieces inside another piece and smaller than this share of the
/// largest piece's area are left out ([`mesh::drop_small_nested_components`]).
pub const NESTED_AREA_FRACTION: f64 = 0.01;

/// With [`Keep::Data`], pieces smaller than [`NESTED_AREA_FRACTION`] of the largest piece's area
/// whose bounding box holds fewer than this many data points are left out
/// ([`mesh::drop_small_unsupported_components`]): fewer than a local fit of degree 2 needs.
pub const SUPPORT_POINTS_MIN: usize = 15;

/// One output file: its name relative to the output folder, and its bytes.
pub type OutputFile = (String, Vec<u8>);

/// An output file kind of `run`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum OutputFormat {
    /// `mesh.glb`.
    Glb,
    /// `mesh.gltf` + `mesh.bin`.
    Gltf,
    /// `mesh.ply` (binary, with normals and per-vertex quality).
    Ply,
    /// `slices/slice_NNN.exr` signed-distance slices.
    Exr,
    /// `preview.png` (a shaded render of the mesh) and `slices/slice_NNN.png` previews.
    Png,
    /// The model file (`model.json`, or `model.mpu` in detail mode) and `report.json`.
    Json,
    /// `volume.vdb`: the narrow-band signed-distance level set (OpenVDB).
    Vdb,
    /// `volume.npy` + `volume.json`: the dense signed-distance grid (NumPy) and its transform.
    Npy,
}

impl std::str::FromStr for OutputFormat {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Ok(match s.trim() {
            "glb" => OutputFormat::Glb,
            "gltf" => OutputFormat::Gltf,
            "ply" => OutputFormat::Ply,
            "exr" => OutputFormat::Exr,
            "png" => OutputFormat::Png,
            "json" => OutputFormat::Json,
            "vdb" => OutputFormat::Vdb,
            "npy" => OutputFormat::Npy,
            other => {
                return Err(format!(
                    "unknown output format '{other}' (choose from glb, gltf, ply, exr, png, json, vdb, npy)"
                ))
            }
        })
    }
}

/// Which zero-set components the mesh keeps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum Keep {
    /// Every component.
    #[default]
    All,
    /// Only components with a data point within 2% of the data's diagonal, and no small closed
    /// piece inside another ([`mesh::drop_small_nested_components`]; see [`NESTED_AREA_FRACTION`]),
    /// nor a small piece with fewer than [`SUPPORT_POINTS_MIN`] data points in its box
    /// ([`mesh::drop_small_unsupported_components`]).
    Data,
}

/// Everything besides the model, the mesh and the data that decides the export stage's output.
///
/// Its [`Serialize`] form is the stage's canonical key bytes (fields by name, in a fixed order,
/// with the trim stage's version, since the trim runs inside this stage).
#[derive(Clone, Debug, PartialEq)]
pub struct ExportParams {
    /// Which files to make.
    pub formats: Vec<OutputFormat>,
    /// Which zero-set components the mesh keeps.
    pub keep: Keep,
    /// The trim of the mesh to the surface its data supports ([`TrimParams::off`] keeps it all).
    pub trim: TrimParams,
    /// The distance slices: axis, count, resolution (pixels per side) and distance method.
    pub slices: SliceParams,
    /// The glTF options; their up axis also turns the preview render. Their `units` is
    /// replaced by [`ExportParams::units`].
    pub gltf: super::gltf::GltfOptions,
    /// The unit of the input coordinates (`--units`): glTF is scaled to metres, PLY and OpenEXR
    /// record it; `None` (the default) leaves every file as without units.
    pub units: Option<super::units::LengthUnit>,
    /// The input's up axis when the PLY is to stand upright in Blender (`--up`): the PLY is
    /// turned so that axis is +Z ([`ply::PlyOptions::up`]); `None` (the default) keeps the
    /// input's frame, so the mesh lies on the scan in MeshLab.
    pub ply_up: Option<super::gltf::UpAxis>,
    /// The decimation to a triangle budget after the filter and the trim (`--target-triangles`;
    /// [`crate::polygonize::decimate`]); `None` (the default) keeps every triangle.
    pub decimate: Option<DecimateParams>,
    /// The signed-distance volumes (`vdb`, `npy`): their voxel size.
    pub volume: VolumeParams,
}

impl Default for ExportParams {
    /// Every format, every component kept, no trim, 16 slices of 128² along z with exact
    /// distances, Y up: the export part of `PipelineConfig::for_mode(Mode::Global)`.
    fn default() -> Self {
        ExportParams {
            formats: vec![
                OutputFormat::Glb,
                OutputFormat::Ply,
                OutputFormat::Exr,
                OutputFormat::Png,
                OutputFormat::Json,
            ],
            keep: Keep::All,
            trim: TrimParams::off(),
            slices: SliceParams {
                resolution: 128,
                method: DistanceMethod::Exact,
                ..Default::default()
            },
            gltf: Default::default(),
            units: None,
            ply_up: None,
            decimate: None,
            volume: VolumeParams::default(),
        }
    }
}

impl ExportParams {
    /// Whether the params ask for `format`.
    pub fn wants(&self, format: OutputFormat) -> bool {
        self.formats.contains(&format)
    }

    /// Whether the formats ask for a signed-distance volume (OpenVDB or NumPy).
    fn volumes_wanted(&self) -> bool {
        self.wants(OutputFormat::Vdb) || self.wants(OutputFormat::Npy)
    }

    /// Whether the formats ask for slices (OpenEXR or their PNG previews).
    fn slices_wanted(&self) -> bool {
        self.wants(OutputFormat::Exr) || self.wants(OutputFormat::Png)
    }
}

impl Serialize for ExportParams {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let formats: Vec<String> = self.formats.iter().map(|f| format!("{f:?}")).collect();
        let value = serde_json::json!({
            "formats": formats,
            "keep": format!("{:?}", self.keep),
            "trim": self.trim,
            "trim_version": trim::STAGE_VERSION,
            "up": format!("{:?}", self.gltf.up),
            "slices": {
                "axis": self.slices.axis.name(),
                "count": self.slices.count,
                "resolution": self.slices.resolution,
                "method": self.slices.method.name(),
            },
        });
        // Only a run with a unit has the key, so the keys of runs without stay as they were.
        let mut value = value;
        if let Some(units) = self.units {
            value["units"] = serde_json::Value::from(units.symbol());
        }
        if let Some(up) = self.ply_up {
            value["ply_up"] = serde_json::Value::from(format!("{up:?}"));
        }
        // Likewise only a decimating run has these.
        if let Some(decimate) = self.decimate {
            value["target_triangles"] = serde_json::Value::from(decimate.target_triangles);
            value["decimate_version"] =
                serde_json::Value::from(crate::polygonize::decimate::VERSION);
        }
        // Likewise the voxel size, only when a volume is asked for.
        if self.volumes_wanted() {
            value["voxel_size"] = match self.volume.voxel_size {
                VoxelSize::Auto => serde_json::Value::from("auto"),
                VoxelSize::Size(h) => serde_json::Value::from(h),
            };
        }
        value.serialize(serializer)
    }
}

/// What the export stage makes: the output files and the figures of the mesh they hold.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExportOutput {
    /// The files, in a fixed order: the model file, `mesh.glb`, `mesh.bin` + `mesh.gltf`,
    /// `mesh.ply`, `preview.png`, `volume.vdb`, `volume.npy` + `volume.json`, then the slices in slice order (per slice its `.exr`, then its
    /// `.png`), each as the formats ask.
    pub files: Vec<OutputFile>,
    /// Components left out for having no data point within 2% of the data's diagonal.
    pub dropped_components: usize,
    /// Small closed components left out for lying inside another ([`NESTED_AREA_FRACTION`]).
    pub dropped_nested: usize,
    /// Small components left out for holding fewer than [`SUPPORT_POINTS_MIN`] data points in
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
    /// The mesh as written (after the component filter and the trim), in input coordinates:
    /// the positions and triangles of `mesh.ply`, before its `float` conversion.
    pub surface: TriangleMesh,
}

impl ExportOutput {
    /// The stage's figures for the report and the cache entry: file count, total bytes, and the
    /// figures of the mesh.
    pub fn report(&self) -> ExportReport {
        ExportReport {
            files: self.files.len(),
            bytes: self.files.iter().map(|f| f.1.len()).sum(),
            dropped_components: self.dropped_components,
            dropped_nested: self.dropped_nested,
            dropped_unsupported: self.dropped_unsupported,
            trim: self.trim,
            decimate: self.decimate.clone(),
            mesh: self.mesh.clone(),
            accuracy: self.accuracy,
        }
    }
}

/// The export stage's figures ([`ExportOutput::report`]), stored in its cache entry.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExportReport {
    /// Files made.
    pub files: usize,
    /// Their bytes.
    pub bytes: usize,
    /// As [`ExportOutput::dropped_components`].
    pub dropped_components: usize,
    /// As [`ExportOutput::dropped_nested`].
    pub dropped_nested: usize,
    /// As [`ExportOutput::dropped_unsupported`].
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

/// The export stage: keeps the components `params.keep` asks for, trims the mesh to its data,
/// checks it, measures it against `points`, and encodes every file the formats ask for.
///
/// `known_embedded` passes on what the meshing proved: no triangle of `mesh` crosses another
/// ([`crate::polygonize::Polygonized::embedded`]); the check then counts no self-intersecting
/// face without testing again ([`mesh::check_with`]). Pass `false` for any other mesh.
///
/// # Errors
/// [`ExportError`] from a writer or the trim; [`ExportError::Distance`] when the slices cannot
/// be computed; [`ExportError::Unsupported`] for `exact` or `taubin` slices of a detail model.
///
/// ```
/// use stablesurf::export::{export, ExportParams, OutputFormat};
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
/// let model = ImplicitModel { polynomial: plane, bounds: None, fit: None, diagnostics: None };
/// let model = Model::Global(model);
/// let params = ExportParams { formats: vec![OutputFormat::Ply], ..Default::default() };
/// let out = export(&model, &mesh, false, &mesh.positions, None, &params).unwrap();
/// assert_eq!(out.files.len(), 1);
/// assert_eq!(out.files[0].0, "mesh.ply");
/// assert_eq!(out.mesh.boundary_edges, 3);
/// ```
pub fn export(
    model: &Model,
    mesh: &TriangleMesh,
    known_embedded: bool,
    points: &[[f64; 3]],
    colours: Option<&[[u16; 3]]>,
    params: &ExportParams,
) -> Result<ExportOutput, ExportError> {
    let (slices, out) = rayon::join(
        || model_slices(model, params),
        || export_mesh(model, mesh, known_embedded, points, colours, params),
    );
    let mut out = out?;
    if let Some(files) = slices {
        out.files.extend(files?);
    }
    Ok(out)
}

/// How many of the nearest data points a vertex's colour is interpolated from.
const COLOUR_NEIGHBOURS: usize = 4;

/// Each vertex's colour, interpolated from its [`COLOUR_NEIGHBOURS`] nearest data points with
/// inverse-distance weights (the nearest point's colour when the vertex is on it), in the 16-bit
/// values of the scan and then rounded to 8 bits. `data` indexes the finite ones of `points`,
/// whose colours are `colours`. Per vertex, so the result does not depend on the thread count;
/// ties between equally near points are broken by the k-d tree's fixed order.
fn vertex_colours(
    vertices: &[[f64; 3]],
    data: &crate::numerics::point_tree::PointIndex<'_>,
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

/// Whether [`model_slices`] makes the slice files (from the model alone): slices are asked for,
/// the model is a polynomial, and their distance is not the mesh's.
pub fn slices_from_model(model: &Model, params: &ExportParams) -> bool {
    params.slices_wanted()
        && matches!(model, Model::Global(_))
        && params.slices.method != DistanceMethod::Mesh
}

/// The slice files when the model alone decides them ([`slices_from_model`]), in slice order;
/// `None` otherwise (then [`export_mesh`] makes them).
///
/// # Errors
/// [`ExportError::Distance`] when the slices cannot be computed, or a writer's error.
pub fn model_slices(
    model: &Model,
    params: &ExportParams,
) -> Option<Result<Vec<OutputFile>, ExportError>> {
    match model {
        Model::Global(m) if slices_from_model(model, params) => Some(
            crate::distance::slices(&m.polynomial, &model.region(), &params.slices)
                .map_err(Into::into)
                .and_then(|slices| slice_images(params, &slices)),
        ),
        _ => None,
    }
}

/// The export stage without the files of [`model_slices`]: the component filter, the trim, then
/// at once the checks, the accuracy, the model, glTF, PLY (with the distance of each vertex to
/// the nearest data point as its quality; with `colours`, one per data point, each vertex gets
/// a colour interpolated from its 4 nearest data points, PLY `red green blue` and glTF
/// `COLOR_0`) and preview files and, unless [`model_slices`] makes
/// them, the slice files from the distance to the kept mesh.
///
/// # Errors
/// As [`export`].
pub fn export_mesh(
    model: &Model,
    mesh: &TriangleMesh,
    known_embedded: bool,
    points: &[[f64; 3]],
    colours: Option<&[[u16; 3]]>,
    params: &ExportParams,
) -> Result<ExportOutput, ExportError> {
    if let Some(c) = colours
        && c.len() != points.len()
    {
        return Err(ExportError::InvalidMesh(format!(
            "{} colours for {} data points",
            c.len(),
            points.len()
        )));
    }
    let data_diagonal = Aabb::from_points(points).map_or(0.0, |b| b.diagonal());
    // One index of the data points for every nearest-point query below.
    let data = crate::numerics::point_tree::PointIndex::new(points);
    let input_mesh = mesh;
    let mut mesh = Cow::Borrowed(mesh);
    let (mut dropped_components, mut dropped_nested, mut dropped_unsupported) = (0, 0, 0);
    // The input vertices' distances to the data, when the component filter measured them: the
    // PLY's vertex quality reuses them if the vertices written are those same vertices.
    let mut input_distances = None;
    if params.keep == Keep::Data {
        let distances = data.as_ref().map_or_else(
            || vec![f64::INFINITY; mesh.positions.len()],
            |index| index.distances(&mesh.positions),
        );
        let (kept, n) = mesh::drop_components_by_distance(&mesh, &distances, 0.02 * data_diagonal);
        input_distances = data.is_some().then_some(distances);
        (mesh, dropped_components) = (Cow::Owned(kept), n);
        let (kept, n) = mesh::drop_small_nested_components(&mesh, NESTED_AREA_FRACTION);
        (mesh, dropped_nested) = (Cow::Owned(kept), n);
        let (kept, n) = mesh::drop_small_unsupported_components(
            &mesh,
            points,
            NESTED_AREA_FRACTION,
            SUPPORT_POINTS_MIN,
        );
        (mesh, dropped_unsupported) = (Cow::Owned(kept), n);
    }
    // The volumes measure the kept mesh before the trim: the closed zero set that f's sign
    // describes, so that the distance and the sign agree everywhere.
    let kept = mesh;
    let volumes = || -> Result<Vec<OutputFile>, ExportError> { volume_files(model, &kept, params) };
    // The trim: the surface the data supports (the mesh itself when all of it is).
    let trimmed = trim::trim(&kept, points, &params.trim)?;
    let trim_report = trimmed.report;
    let mut mesh: Cow<'_, TriangleMesh> =
        if trim_report.removed_triangles > 0 || trim_report.faired_vertices > 0 {
            Cow::Owned(trimmed.mesh)
        } else {
            Cow::Borrowed(&*kept)
        };
    // The decimation, last, so that the budget counts the triangles written.
    let mut known_embedded = known_embedded;
    let decimate_report = params.decimate.map(|p| {
        let out = decimate::decimate(&mesh, model.function(), &p);
        if out.report.collapses > 0 {
            mesh = Cow::Owned(out.mesh);
            // Measured again rather than vouched for: the collapses test their new triangles
            // against their neighbours only.
            known_embedded = false;
        }
        out.report
    });
    let m: &TriangleMesh = &mesh;
    // The colours come from the same index as the other nearest-point queries.
    let vertex_colours = colours
        .zip(data.as_ref())
        .map(|(c, index)| vertex_colours(&m.positions, index, points, c));
    let with_slices = !slices_from_model(model, params);
    let one = |name: &str, bytes: Vec<u8>| vec![(name.to_string(), bytes)];
    let mesh_opts = MeshFileOptions {
        gltf: GltfOptions {
            units: params.units,
            ..params.gltf
        },
        colours: vertex_colours.as_deref(),
        ..Default::default()
    };
    let json = || -> Result<Vec<OutputFile>, ExportError> {
        if !params.wants(OutputFormat::Json) {
            return Ok(Vec::new());
        }
        let (name, bytes) = model.file()?;
        Ok(one(name, bytes))
    };
    let glb = || -> Result<Vec<OutputFile>, ExportError> {
        if !params.wants(OutputFormat::Glb) {
            return Ok(Vec::new());
        }
        mesh_files(m, MeshFormat::Glb, "mesh.glb", &mesh_opts)
    };
    let gltf = || -> Result<Vec<OutputFile>, ExportError> {
        if !params.wants(OutputFormat::Gltf) {
            return Ok(Vec::new());
        }
        mesh_files(m, MeshFormat::Gltf, "mesh.gltf", &mesh_opts)
    };
    let ply = || -> Result<Vec<OutputFile>, ExportError> {
        if !params.wants(OutputFormat::Ply) {
            return Ok(Vec::new());
        }
        let index = data.as_ref().ok_or_else(|| {
            ExportError::InvalidMesh(
                "no finite input point to measure vertex quality against".into(),
            )
        })?;
        let quality: Vec<f32> = match &input_distances {
            // The same queries against the same index: the same distances.
            Some(d) if m.positions == input_mesh.positions => d.iter().map(|&d| d as f32).collect(),
            _ => index
                .distances(&m.positions)
                .into_iter()
                .map(|d| d as f32)
                .collect(),
        };
        let opts = MeshFileOptions {
            ply: ply::PlyOptions {
                quality: Some(&quality),
                units: params.units,
                up: params.ply_up,
                ..Default::default()
            },
            ..mesh_opts
        };
        mesh_files(m, MeshFormat::Ply, "mesh.ply", &opts)
    };
    let preview = || -> Result<Vec<OutputFile>, ExportError> {
        if !params.wants(OutputFormat::Png) {
            return Ok(Vec::new());
        }
        let render_params = crate::render::RenderParams {
            up: params.gltf.up,
            ..Default::default()
        };
        let image = crate::render::render(m, &render_params);
        Ok(one("preview.png", encode(&|w| png::write_rgb(&image, w))?))
    };
    // The slices, like the volumes, measure the kept mesh before the trim (and its fairing),
    // the closed zero set whose sides f's sign tells: where the distance is 0 the sign flips.
    let slices = || {
        rayon::join(
            || with_slices.then(|| mesh_slices(model, &kept, params)),
            volumes,
        )
    };
    let ((slices, volumes), ((report, accuracy), (json, ((glb, gltf), (ply, preview))))) =
        rayon::join(slices, || {
            rayon::join(
                || {
                    rayon::join(
                        // The component filter and the trim only take triangles away, add
                        // ones tested against the rest or move vertices whose triangles are
                        // tested against the rest: an embedded mesh stays embedded.
                        || mesh::check_with(m, known_embedded),
                        || {
                            data.as_ref().map_or_else(Default::default, |index| {
                                measure::accuracy(index, m, data_diagonal)
                            })
                        },
                    )
                },
                || {
                    rayon::join(json, || {
                        rayon::join(|| rayon::join(glb, gltf), || rayon::join(ply, preview))
                    })
                },
            )
        });
    let slices = slices.transpose()?;
    let mut files = Vec::new();
    for part in [json?, glb?, gltf?, ply?, preview?, volumes?] {
        files.extend(part);
    }
    files.extend(slices.into_iter().flatten());
    Ok(ExportOutput {
        files,
        dropped_components,
        dropped_nested,
        dropped_unsupported,
        trim: trim_report,
        decimate: decimate_report,
        mesh: report,
        accuracy,
        surface: mesh.into_owned(),
    })
}

/// The bytes `f` writes.
fn encode(f: &dyn Fn(&mut Vec<u8>) -> Result<(), ExportError>) -> Result<Vec<u8>, ExportError> {
    let mut bytes = Vec::new();
    f(&mut bytes)?;
    Ok(bytes)
}

/// The slice files (OpenEXR and PNG, as the formats ask) that [`model_slices`] does not make:
/// from the distance to `mesh`, the only distance a detail model has.
fn mesh_slices(
    model: &Model,
    mesh: &TriangleMesh,
    params: &ExportParams,
) -> Result<Vec<OutputFile>, ExportError> {
    if !params.slices_wanted() {
        return Ok(Vec::new());
    }
    match params.slices.method {
        DistanceMethod::Mesh => {
            let slices = crate::distance::slices_from_mesh(
                model.function(),
                mesh,
                &model.region(),
                &params.slices,
            )?;
            slice_images(params, &slices)
        }
        method => Err(ExportError::Unsupported(format!(
            "{} distance slices need a global (polynomial) model; use --slice-distance mesh in detail mode",
            method.name()
        ))),
    }
}

/// The volume files the formats ask for, from the distance to `mesh` signed by the model:
/// `volume.vdb` (the narrow band, [`super::vdb`]) and `volume.npy` + `volume.json` (the dense
/// grid, [`super::npy`]).
fn volume_files(
    model: &Model,
    mesh: &TriangleMesh,
    params: &ExportParams,
) -> Result<Vec<OutputFile>, ExportError> {
    if !params.volumes_wanted() {
        return Ok(Vec::new());
    }
    let f = model.function();
    let band = volume::narrow_band(f, mesh, &model.region(), &params.volume)?;
    let mut files = Vec::new();
    if params.wants(OutputFormat::Vdb) {
        let opts = vdb::VdbOptions {
            units: params.units,
            up: params.gltf.up,
        };
        files.push((
            "volume.vdb".to_string(),
            encode(&|w| vdb::write(&band, &opts, w))?,
        ));
    }
    if params.wants(OutputFormat::Npy) {
        let dense = volume::dense(mesh, &band)?;
        files.push((
            "volume.npy".to_string(),
            encode(&|w| npy::write(&dense, w))?,
        ));
        files.push((
            "volume.json".to_string(),
            npy::sidecar(&dense, params.units),
        ));
    }
    Ok(files)
}

/// Encodes the slices as the formats ask, in parallel; the files come out in slice order.
fn slice_images(params: &ExportParams, slices: &[Slice]) -> Result<Vec<OutputFile>, ExportError> {
    use rayon::prelude::*;
    let images: Vec<Vec<OutputFile>> = slices
        .par_iter()
        .map(|slice| -> Result<Vec<OutputFile>, ExportError> {
            let mut files = Vec::new();
            if params.wants(OutputFormat::Exr) {
                let bytes = encode(&|w| {
                    exr::write_slice(
                        slice,
                        &exr::ExrOptions {
                            units: params.units,
                            ..Default::default()
                        },
                        w,
                    )
                })?;
                files.push((format!("slices/slice_{:03}.exr", slice.index), bytes));
            }
            if params.wants(OutputFormat::Png) {
                let bytes = encode(&|w| png::write_preview(slice, w))?;
                files.push((format!("slices/slice_{:03}.png", slice.index), bytes));
            }
            Ok(files)
        })
        .collect::<Result<_, _>>()?;
    Ok(images.into_iter().flatten().collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::distance::Axis;
    use crate::export::gltf::{GltfOptions, UpAxis};

    fn key_bytes(params: &ExportParams) -> Vec<u8> {
        serde_json::to_vec(params).unwrap()
    }

    /// The key bytes the stage has always had: a changed spelling would orphan every cache
    /// entry of the export stage without a version bump.
    #[test]
    fn key_bytes_are_the_stage_recipe() {
        let bytes = String::from_utf8(key_bytes(&ExportParams::default())).unwrap();
        let trim = serde_json::to_string(&TrimParams::off()).unwrap();
        let trim_value: serde_json::Value = serde_json::from_str(&trim).unwrap();
        let expected = serde_json::json!({
            "formats": ["Glb", "Ply", "Exr", "Png", "Json"],
            "keep": "All",
            "trim": trim_value,
            "trim_version": trim::STAGE_VERSION,
            "up": "Y",
            "slices": {"axis": "z", "count": 16, "resolution": 128, "method": "exact"},
        });
        assert_eq!(bytes, serde_json::to_string(&expected).unwrap());
    }

    #[test]
    fn same_params_same_key_and_each_change_differs() {
        let base = ExportParams::default();
        assert_eq!(key_bytes(&base), key_bytes(&base.clone()));
        let changed = [
            ExportParams {
                formats: vec![OutputFormat::Ply],
                ..base.clone()
            },
            ExportParams {
                keep: Keep::Data,
                ..base.clone()
            },
            ExportParams {
                trim: TrimParams::default(),
                ..base.clone()
            },
            ExportParams {
                slices: SliceParams {
                    axis: Axis::X,
                    ..base.slices
                },
                ..base.clone()
            },
            ExportParams {
                slices: SliceParams {
                    count: 8,
                    ..base.slices
                },
                ..base.clone()
            },
            ExportParams {
                slices: SliceParams {
                    resolution: 64,
                    ..base.slices
                },
                ..base.clone()
            },
            ExportParams {
                slices: SliceParams {
                    method: DistanceMethod::Mesh,
                    ..base.slices
                },
                ..base.clone()
            },
            ExportParams {
                gltf: GltfOptions {
                    up: UpAxis::Z,
                    ..Default::default()
                },
                ..base.clone()
            },
            ExportParams {
                decimate: Some(DecimateParams {
                    target_triangles: 5000,
                }),
                ..base.clone()
            },
            ExportParams {
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

    #[test]
    fn export_is_its_two_halves() {
        let mesh = TriangleMesh {
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            normals: vec![[0.0, 0.0, 1.0]; 3],
            triangles: vec![[0, 1, 2]],
        };
        let sphere = crate::poly::ImplicitPolynomial {
            degree: 2,
            coefficients: vec![-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0],
            center: [0.0; 3],
            scale: 1.0,
        };
        let model = Model::Global(crate::poly::ImplicitModel {
            polynomial: sphere,
            bounds: None,
            fit: None,
            diagnostics: None,
        });
        let params = ExportParams {
            slices: SliceParams {
                count: 2,
                resolution: 8,
                ..ExportParams::default().slices
            },
            ..ExportParams::default()
        };
        assert!(slices_from_model(&model, &params));
        let whole = export(&model, &mesh, false, &mesh.positions, None, &params).unwrap();
        let mut halves = export_mesh(&model, &mesh, false, &mesh.positions, None, &params).unwrap();
        halves
            .files
            .extend(model_slices(&model, &params).unwrap().unwrap());
        assert_eq!(whole, halves);
        let names: Vec<&str> = whole.files.iter().map(|f| f.0.as_str()).collect();
        assert_eq!(
            names,
            [
                "model.json",
                "mesh.glb",
                "mesh.ply",
                "preview.png",
                "slices/slice_000.exr",
                "slices/slice_000.png",
                "slices/slice_001.exr",
                "slices/slice_001.png",
            ]
        );
    }
}
