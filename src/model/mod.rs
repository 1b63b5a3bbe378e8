//! The fitted model of a run, the artifact between the model stages (`fit`, `detail`) and the
//! stages that use it (`polygonize`, `export`).
//!
//! Input: the output of [`fit::fit`](crate::fit::fit) (one polynomial) or of
//! [`detail::fit_detail`](crate::detail::fit_detail) (a blend of local fits), or a model file.
//! Output: a [`Model`], which gives the function to mesh, the region to mesh it in, its file and
//! its report.
//!
//! The model files are here too: `model.json`, the polynomial ([`json`]), and `model.mpu`, the
//! detail model ([`mpu`]). The cache stores the models in them, `export` writes them and the CLI
//! reads them, so none of those reaches into another.

pub mod json;
pub mod mpu;

use std::path::Path;

use serde::Serialize;

use crate::cloud::Aabb;
use crate::detail::MpuModel;
use crate::implicit::ImplicitFunction;
use crate::poly::ImplicitModel;

/// Why a model file cannot be read or written.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// A `model.json` could not be read: bad JSON, a missing field, or values that do not
    /// describe a polynomial (wrong coefficient count, non-finite numbers, scale ≤ 0).
    #[error("cannot read model {path}: {reason}")]
    Read {
        /// The file.
        path: String,
        /// What is wrong and what to change.
        reason: String,
    },
    /// A model cannot be written as JSON (a non-finite number, which JSON cannot hold).
    #[error("cannot write model: {0}")]
    Value(String),
    /// A `model.mpu` is not a valid detail model (the message names the file, the fault and its
    /// byte offset), or its diagnostics cannot be encoded.
    #[error("{0}")]
    Format(String),
    /// The output stream failed (the caller knows which file it was).
    #[error("write failed: {0}")]
    Write(#[source] std::io::Error),
}

/// Which model the pipeline fits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub enum Mode {
    /// One polynomial (the paper's compact, invariant descriptor).
    #[default]
    Global,
    /// A multi-level partition of unity of local fits.
    Detail,
}

/// The fitted model of a run: one polynomial, or the detail mode's blend of local fits.
#[derive(Clone, Debug)]
pub enum Model {
    /// `--mode global`.
    Global(ImplicitModel),
    /// `--mode detail`.
    Detail(MpuModel),
}

impl Model {
    /// The mode that makes this kind of model.
    pub fn mode(&self) -> Mode {
        match self {
            Model::Global(_) => Mode::Global,
            Model::Detail(_) => Mode::Detail,
        }
    }

    /// Reads a model file of either kind from its bytes: a `stablesurf.mpu` file (detail) by its
    /// magic, else `model.json` (global). `path` names the file in errors.
    ///
    /// # Errors
    /// [`ModelError`] when the bytes are not a valid model file of the kind they look like.
    ///
    /// ```
    /// use std::path::Path;
    /// use stablesurf::model::Model;
    /// let err = Model::from_bytes(b"{}", Path::new("m.json")).unwrap_err();
    /// assert!(err.to_string().contains("m.json"));
    /// ```
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Model, ModelError> {
        Ok(if mpu::is_mpu(bytes) {
            Model::Detail(mpu::read_mpu(bytes, path)?)
        } else {
            Model::Global(json::read_model(bytes, path)?)
        })
    }

    /// The model as a function to mesh and sign distances with.
    pub fn function(&self) -> &dyn ImplicitFunction {
        match self {
            Model::Global(m) => &m.polynomial,
            Model::Detail(m) => m,
        }
    }

    /// The region the model is meshed in (input coordinates).
    pub fn region(&self) -> Aabb {
        match self {
            Model::Global(m) => meshing_region(m),
            Model::Detail(m) => m.region,
        }
    }

    /// The model's settings and diagnostics, for `report.json`.
    pub fn report(&self) -> ModelReport {
        match self {
            Model::Global(m) => ModelReport::Global {
                fit: m.fit.clone(),
                diagnostics: m.diagnostics.clone(),
                clipped: false,
            },
            Model::Detail(m) => ModelReport::Detail {
                diagnostics: m.diagnostics.clone(),
                params: None,
            },
        }
    }

    /// The model file's name and bytes: `model.json` (global) or `model.mpu` (detail).
    ///
    /// # Errors
    /// [`ModelError`] from the writer.
    pub fn file(&self) -> Result<(&'static str, Vec<u8>), ModelError> {
        match self {
            Model::Global(m) => {
                let mut bytes = Vec::new();
                json::write_model(m, &mut bytes)?;
                Ok(("model.json", bytes))
            }
            Model::Detail(m) => Ok(("model.mpu", mpu::mpu_bytes(m)?)),
        }
    }
}

/// A model's settings and diagnostics: report.json's `fit`, printed as one JSON object with
/// sorted keys (`mode`, and per mode its record and diagnostics).
#[derive(Clone, Debug, PartialEq)]
pub enum ModelReport {
    /// A polynomial.
    Global {
        /// How it was fitted.
        fit: Option<crate::poly::FitRecord>,
        /// What the fit measured (its `bounded` false when the mesh is clipped).
        diagnostics: Option<crate::poly::FitDiagnostics>,
        /// Whether the zero set runs out of the meshing box (printed only when it does).
        clipped: bool,
    },
    /// A blend of local fits.
    Detail {
        /// What the detail fit did.
        diagnostics: crate::detail::DetailDiagnostics,
        /// The params it ran with, when a run reports them.
        params: Option<crate::detail::DetailParams>,
    },
}

impl ModelReport {
    /// Whether the fit certified the zero set bounded (global models the fit checked).
    pub fn bounded(&self) -> Option<bool> {
        match self {
            ModelReport::Global { diagnostics, .. } => diagnostics.as_ref().map(|d| d.bounded),
            ModelReport::Detail { .. } => None,
        }
    }

    /// Marks a global model's zero set as clipped by the meshing box: not bounded in its mesh.
    pub(crate) fn clip(&mut self) {
        if let ModelReport::Global {
            diagnostics,
            clipped,
            ..
        } = self
        {
            *clipped = true;
            if let Some(d) = diagnostics {
                d.bounded = false;
            }
        }
    }

    /// The report as one JSON object with sorted keys.
    pub fn to_json(&self) -> serde_json::Value {
        let mut value = match self {
            ModelReport::Global {
                fit, diagnostics, ..
            } => serde_json::json!({ "mode": "global", "fit": fit, "diagnostics": diagnostics }),
            ModelReport::Detail { diagnostics, .. } => {
                serde_json::json!({ "mode": "detail", "diagnostics": diagnostics })
            }
        };
        if let (
            ModelReport::Detail {
                params: Some(p), ..
            },
            Some(map),
        ) = (self, value.as_object_mut())
        {
            map.insert(
                "params".into(),
                serde_json::to_value(p).expect("params serialize"),
            );
        }
        if let (ModelReport::Global { clipped: true, .. }, Some(map)) =
            (self, value.as_object_mut())
        {
            map.insert("clipped".into(), true.into());
        }
        value
    }
}

impl Serialize for ModelReport {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.to_json().serialize(serializer)
    }
}

/// The region a model is meshed in: its stored box, or the normalization sphere's cube.
pub fn meshing_region(model: &ImplicitModel) -> Aabb {
    model.bounds.unwrap_or_else(|| {
        let p = &model.polynomial;
        let r = 1.6 * p.scale;
        Aabb {
            min: [p.center[0] - r, p.center[1] - r, p.center[2] - r],
            max: [p.center[0] + r, p.center[1] + r, p.center[2] + r],
        }
    })
}
