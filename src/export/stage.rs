//! Stage `export`: the fitted model and the finished mesh → the bytes of every output file of
//! `run`.
//!
//! Input: a [`Model`], the [`Finished`] mesh of the finish stage ([`crate::finish`]) and
//! [`ExportParams`]. Output: the files as (name relative to the output folder, bytes), in a
//! fixed order. The stage only encodes: the mesh, its per-vertex values and its figures are the
//! finish stage's.
//!
//! ```text
//! finished ─┬─ model, glb, gltf, ply, png        (the mesh as written)
//!           ├─ slices and volumes from the mesh  (the closed mesh before the trim)
//! model ────┴─ slices from the model             (a polynomial's exact distances)
//! ```
//!
//! [`export`] is the stage. Its two halves are public too, for a caller that starts the slices
//! of a polynomial model before the mesh exists: [`model_slices`] (the slice files the model
//! alone decides, when it does) and [`export_mesh`] (everything else); `export` is `export_mesh`
//! followed by the files of `model_slices`, so both orders give the same bytes. The stage does no
//! IO: writing the files is the caller's ([`crate::outputs`]). Every part runs on the rayon pool
//! and its bytes do not depend on the thread count.

use serde::Serialize;

use super::gltf::GltfOptions;
use super::{exr, mesh_files, npy, ply, png, vdb, ExportError, MeshFileOptions, MeshFormat};
use crate::distance::volume::{self, VolumeParams, VoxelSize};
use crate::distance::{DistanceMethod, Slice, SliceParams};
use crate::finish::Finished;
use crate::mesh::TriangleMesh;
use crate::model::Model;

/// The export stage's version. If you change any input to this stage's key (the fields of
/// [`ExportParams`] or how they are written), or anything that changes its output for the same
/// input and params, bump `STAGE_VERSION`.
pub(crate) const STAGE_VERSION: u32 = 15;

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

/// Everything besides the model and the finished mesh that decides the export stage's output.
///
/// Its [`Serialize`] form is the stage's canonical key bytes (fields by name, in a fixed order).
#[derive(Clone, Debug, PartialEq)]
pub struct ExportParams {
    /// Which files to make.
    pub formats: Vec<OutputFormat>,
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
    /// The signed-distance volumes (`vdb`, `npy`): their voxel size.
    pub volume: VolumeParams,
}

impl Default for ExportParams {
    /// Every format, 16 slices of 128² along z with exact distances, Y up: the export part of `PipelineConfig::for_mode(Mode::Global)`.
    fn default() -> Self {
        ExportParams {
            formats: vec![
                OutputFormat::Glb,
                OutputFormat::Ply,
                OutputFormat::Exr,
                OutputFormat::Png,
                OutputFormat::Json,
            ],
            slices: SliceParams {
                resolution: 128,
                method: DistanceMethod::Exact,
                ..Default::default()
            },
            gltf: Default::default(),
            units: None,
            ply_up: None,
            volume: VolumeParams::default(),
        }
    }
}

impl ExportParams {
    /// Whether the params ask for `format`.
    pub(crate) fn wants(&self, format: OutputFormat) -> bool {
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

/// The export stage's figures, stored in its cache entry.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExportReport {
    /// Files made.
    pub files: usize,
    /// Their bytes.
    pub bytes: usize,
}

impl ExportReport {
    /// The figures of `files`.
    pub(crate) fn of(files: &[OutputFile]) -> ExportReport {
        ExportReport {
            files: files.len(),
            bytes: files.iter().map(|f| f.1.len()).sum(),
        }
    }
}

/// The export stage: encodes every file the formats ask for, from the model and the finished
/// mesh.
///
/// # Errors
/// [`ExportError`] from a writer; [`ExportError::Distance`] when the slices cannot be computed;
/// [`ExportError::Unsupported`] for `exact` or `taubin` slices of a detail model.
///
/// ```
/// use stablesurf::export::{export, ExportParams, OutputFormat};
/// use stablesurf::finish::Finished;
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
/// let finished = Finished { mesh, quality: Some(vec![0.0; 3]), ..Default::default() };
/// let params = ExportParams { formats: vec![OutputFormat::Ply], ..Default::default() };
/// let files = export(&model, &finished, &params).unwrap();
/// assert_eq!(files.len(), 1);
/// assert_eq!(files[0].0, "mesh.ply");
/// ```
pub fn export(
    model: &Model,
    finished: &Finished,
    params: &ExportParams,
) -> Result<Vec<OutputFile>, ExportError> {
    let (slices, files) = rayon::join(
        || model_slices(model, params),
        || export_mesh(model, finished, params),
    );
    let mut files = files?;
    if let Some(slices) = slices {
        files.extend(slices?);
    }
    Ok(files)
}

/// Whether [`model_slices`] makes the slice files (from the model alone): slices are asked for,
/// the model is a polynomial, and their distance is not the mesh's.
pub(crate) fn slices_from_model(model: &Model, params: &ExportParams) -> bool {
    params.slices_wanted()
        && matches!(model, Model::Global(_))
        && params.slices.method != DistanceMethod::Mesh
}

/// The slice files when the model alone decides them ([`slices_from_model`]), in slice order;
/// `None` otherwise (then [`export_mesh`] makes them).
///
/// # Errors
/// [`ExportError::Distance`] when the slices cannot be computed, or a writer's error.
pub(crate) fn model_slices(
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

/// The export stage without the files of [`model_slices`]: the model, glTF, PLY (with each
/// vertex's distance to the data as its quality, and the vertex colours when the finished mesh
/// has them: PLY `red green blue` and glTF `COLOR_0`) and preview files, the volumes and, unless
/// [`model_slices`] makes them, the slice files from the distance to the closed mesh.
///
/// # Errors
/// As [`export`].
pub(crate) fn export_mesh(
    model: &Model,
    finished: &Finished,
    params: &ExportParams,
) -> Result<Vec<OutputFile>, ExportError> {
    let m = &finished.mesh;
    // The slices and volumes measure the closed mesh before the trim (and its fairing): the
    // zero set whose sides f's sign tells, so that the distance and the sign agree everywhere.
    let closed = finished.closed();
    let with_slices = !slices_from_model(model, params);
    let one = |name: &str, bytes: Vec<u8>| vec![(name.to_string(), bytes)];
    let mesh_opts = MeshFileOptions {
        gltf: GltfOptions {
            units: params.units,
            ..params.gltf
        },
        colours: finished.colours.as_deref(),
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
        let quality = finished.quality.as_deref().ok_or_else(|| {
            ExportError::InvalidMesh(
                "no finite input point to measure vertex quality against".into(),
            )
        })?;
        let opts = MeshFileOptions {
            ply: ply::PlyOptions {
                quality: Some(quality),
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
    let distances = || {
        rayon::join(
            || with_slices.then(|| mesh_slices(model, closed, params)),
            || volume_files(model, closed, params),
        )
    };
    let ((slices, volumes), (json, ((glb, gltf), (ply, preview)))) = rayon::join(distances, || {
        rayon::join(json, || {
            rayon::join(|| rayon::join(glb, gltf), || rayon::join(ply, preview))
        })
    });
    let slices = slices.transpose()?;
    let mut files = Vec::new();
    for part in [json?, glb?, gltf?, ply?, preview?, volumes?] {
        files.extend(part);
    }
    files.extend(slices.into_iter().flatten());
    Ok(files)
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
        let expected = serde_json::json!({
            "formats": ["Glb", "Ply", "Exr", "Png", "Json"],
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
                units: Some(crate::export::units::LengthUnit::Mm),
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
        let finished = Finished {
            mesh,
            quality: Some(vec![0.0; 3]),
            ..Default::default()
        };
        let whole = export(&model, &finished, &params).unwrap();
        let mut halves = export_mesh(&model, &finished, &params).unwrap();
        halves.extend(model_slices(&model, &params).unwrap().unwrap());
        assert_eq!(whole, halves);
        let names: Vec<&str> = whole.iter().map(|f| f.0.as_str()).collect();
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
