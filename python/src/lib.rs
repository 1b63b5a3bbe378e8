//! The Python package `stablesurf`: the library's pipeline on numpy arrays.
//!
//! Input: points (and optionally normals and triangles) as numpy arrays, or a scan read with
//! `read_points`, and keyword arguments named like the command line's options. Output: the
//! mesh `stablesurf run` writes (`reconstruct`), or the global polynomial `stablesurf fit`
//! writes (`fit`), as numpy arrays and small objects.
//!
//! Nothing here computes: the arguments become the library's [`PipelineConfig`] (the mode's
//! defaults from [`PipelineConfig::for_mode`], overridden by the keywords given, each checked
//! against the command line's range in [`stablesurf::limits`]) and an in-memory
//! [`ScanSource::Cloud`], which go to [`pipeline::reconstruct`] and [`pipeline::fit_model`],
//! the functions `run` and `fit` use. The interpreter's lock is released while they run.
//! Library errors become `ValueError` (bad input or arguments), `OSError` (files) or
//! `RuntimeError` (a computation that failed), with the library's messages.

use std::str::FromStr;

use numpy::{PyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{PyOSError, PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

use ::stablesurf::cache::Cache;
use ::stablesurf::fit::{FitMethod, Kappa, KappaRule};
use ::stablesurf::limits::{self, Range};
use ::stablesurf::normals::NormalSource;
use ::stablesurf::pipeline::{
    self, Keep, Mode, Model, PipelineConfig, PipelineError, ScanSource, Setting,
};
use ::stablesurf::trim::TrimParams;
use ::stablesurf::{import, ImplicitModel, PointCloud, TriangleMesh};

/// The error `e` and its causes in one line, as the command line prints them.
fn chain(e: &dyn std::error::Error) -> String {
    let mut message = e.to_string();
    let mut source = e.source();
    while let Some(cause) = source {
        message.push_str(": ");
        message.push_str(&cause.to_string());
        source = cause.source();
    }
    message
}

/// A pipeline error as the Python exception of its kind.
fn pipeline_error(e: PipelineError) -> PyErr {
    let message = chain(&e);
    match e {
        PipelineError::Import(_)
        | PipelineError::Normals(_)
        | PipelineError::Fit(_)
        | PipelineError::Detail(_)
        | PipelineError::Unsupported(_) => PyValueError::new_err(message),
        PipelineError::Read { .. } | PipelineError::Output(_) | PipelineError::Cache(_) => {
            PyOSError::new_err(message)
        }
        _ => PyRuntimeError::new_err(message),
    }
}

/// `value` as a contiguous float64 array of shape (N, 3), N ≥ 1 unless `allow_empty`.
fn rows3_f64(value: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[f64; 3]>> {
    let np = value.py().import("numpy")?;
    let array = np
        .call_method1("ascontiguousarray", (value, "float64"))
        .map_err(|e| {
            PyValueError::new_err(format!(
                "{name} must be an array of numbers of shape (N, 3): {e}"
            ))
        })?;
    let array = array.cast::<PyArrayDyn<f64>>()?;
    let shape = array.shape().to_vec();
    if shape.len() != 2 || shape[1] != 3 {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape (N, 3), one row of x, y, z per point; got shape {}",
            shape_text(&shape)
        )));
    }
    let readonly = array.readonly();
    let flat = readonly.as_slice()?;
    Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// `(5, 2)` for a shape.
fn shape_text(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// `value` as triangles: an integer array of shape (F, 3) with indices in 0..2³².
fn triangles(value: &Bound<'_, PyAny>) -> PyResult<Vec<[u32; 3]>> {
    let np = value.py().import("numpy")?;
    let as_array = np.call_method1("asarray", (value,))?;
    let kind: String = as_array.getattr("dtype")?.getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "i" | "u") || as_array.getattr("ndim")?.extract::<usize>()? != 2 {
        let shape: Vec<usize> = as_array.getattr("shape")?.extract()?;
        return Err(PyValueError::new_err(format!(
            "faces must be an integer array of shape (F, 3), three 0-based point indices per triangle; got dtype kind '{kind}' and shape {}",
            shape_text(&shape)
        )));
    }
    let array = np.call_method1("ascontiguousarray", (as_array, "int64"))?;
    let array = array.cast::<PyArrayDyn<i64>>()?;
    let shape = array.shape().to_vec();
    if shape[1] != 3 {
        return Err(PyValueError::new_err(format!(
            "faces must have shape (F, 3), three 0-based point indices per triangle; got shape {}",
            shape_text(&shape)
        )));
    }
    let readonly = array.readonly();
    readonly
        .as_slice()?
        .chunks_exact(3)
        .enumerate()
        .map(|(face, c)| {
            let index = |i: i64| {
                u32::try_from(i).map_err(|_| {
                    PyValueError::new_err(format!(
                        "faces: face {face} refers to point {i}; give 0-based indices into points"
                    ))
                })
            };
            Ok([index(c[0])?, index(c[1])?, index(c[2])?])
        })
        .collect()
}

/// `True` or `False`, as Python prints a bool.
fn py_bool(b: bool) -> &'static str {
    if b {
        "True"
    } else {
        "False"
    }
}

/// A float64 array of shape (N, 3).
fn array_rows3<'py>(py: Python<'py>, rows: &[[f64; 3]]) -> PyResult<Bound<'py, PyAny>> {
    let flat: Vec<f64> = rows.iter().flatten().copied().collect();
    Ok(PyArray::from_vec(py, flat)
        .reshape([rows.len(), 3])?
        .into_any())
}

/// A JSON value as the Python object `json.loads` makes of it.
fn to_python<'py>(py: Python<'py>, value: &impl serde::Serialize) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(value).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

/// A scan read by the tool's own importer (`read_points`): its points, and whatever else the
/// file holds that the pipeline uses (normals, triangles, a range grid's sensor, colours).
/// Passing it to `reconstruct` or `fit` gives exactly what `stablesurf run` and `stablesurf fit`
/// compute from the file.
#[pyclass(frozen, module = "stablesurf")]
struct Scan {
    cloud: PointCloud,
    /// What the importer did not read (extra columns, other elements), one sentence each.
    #[pyo3(get)]
    notices: Vec<String>,
}

#[pymethods]
impl Scan {
    /// The points, float64 of shape (N, 3), in the file's coordinates and units.
    #[getter]
    fn points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        array_rows3(py, &self.cloud.points)
    }

    /// The file's per-point normals, float64 of shape (N, 3) as stored, or None.
    #[getter]
    fn normals<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.cloud
            .normals
            .as_deref()
            .map(|n| array_rows3(py, n))
            .transpose()
    }

    /// The file's triangles, uint32 of shape (F, 3) (polygons fan-triangulated, or a range
    /// grid's triangles), or None for a pure point cloud.
    #[getter]
    fn faces<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        if self.cloud.triangles.is_empty() {
            return Ok(None);
        }
        let flat: Vec<u32> = self.cloud.triangles.iter().flatten().copied().collect();
        Ok(Some(
            PyArray::from_vec(py, flat)
                .reshape([self.cloud.triangles.len(), 3])?
                .into_any(),
        ))
    }

    /// The per-point colours, uint16 RGB of shape (N, 3) (65535 full intensity), or None.
    #[getter]
    fn colours<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let Some(colours) = &self.cloud.colours else {
            return Ok(None);
        };
        let flat: Vec<u16> = colours.iter().flatten().copied().collect();
        Ok(Some(
            PyArray::from_vec(py, flat)
                .reshape([colours.len(), 3])?
                .into_any(),
        ))
    }

    fn __len__(&self) -> usize {
        self.cloud.points.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "Scan({} points, {} triangles, normals={}, colours={})",
            self.cloud.points.len(),
            self.cloud.triangles.len(),
            py_bool(self.cloud.normals.is_some()),
            py_bool(self.cloud.colours.is_some())
        )
    }
}

/// Reads a scan file (PLY, OBJ, STL, XYZ/PTS, LAS/LAZ, E57, PCD) with the tool's own importer,
/// exactly as `stablesurf run` and `stablesurf fit` read it.
///
/// Raises OSError when the file cannot be read and ValueError when it is not a valid scan.
#[pyfunction]
fn read_points(py: Python<'_>, path: std::path::PathBuf) -> PyResult<Scan> {
    let bytes = std::fs::read(&path)
        .map_err(|e| PyOSError::new_err(format!("cannot read {}: {e}", path.display())))?;
    let scan = py
        .detach(|| import::import_scan_bytes(&bytes, &path))
        .map_err(|e| PyValueError::new_err(chain(&e)))?;
    Ok(Scan {
        cloud: scan.cloud,
        notices: scan.notices,
    })
}

/// The cloud of the first arguments: a [`Scan`] as read, or arrays.
fn cloud_of(
    points: &Bound<'_, PyAny>,
    normals: Option<&Bound<'_, PyAny>>,
    faces: Option<&Bound<'_, PyAny>>,
) -> PyResult<PointCloud> {
    if let Ok(scan) = points.cast::<Scan>() {
        if normals.is_some() || faces.is_some() {
            return Err(PyValueError::new_err(
                "a Scan carries its own normals and faces: pass normals= and faces= only with a points array",
            ));
        }
        return Ok(scan.get().cloud.clone());
    }
    let points = rows3_f64(points, "points")?;
    let normals = normals.map(|n| rows3_f64(n, "normals")).transpose()?;
    if let Some(i) = normals
        .iter()
        .flatten()
        .position(|n| !n.iter().all(|c| c.is_finite()))
    {
        return Err(PyValueError::new_err(format!(
            "normals: row {i} has a non-finite component; give finite normals or none"
        )));
    }
    let triangles = faces.map(triangles).transpose()?.unwrap_or_default();
    let cloud = PointCloud {
        points,
        normals,
        triangles,
        ..Default::default()
    };
    // The importer's checks, with its messages (here before the lock is released, so a bad
    // array fails at once).
    import::validate_cloud(&cloud, pipeline::CLOUD_NAME)
        .map_err(|e| PyValueError::new_err(chain(&e)))?;
    Ok(cloud)
}

/// The keyword arguments `reconstruct` takes beyond its named ones, and what they set.
const RECONSTRUCT_PARAMS: &[&str] = &[
    "degree",
    "kappa",
    "kappa_rule",
    "epsilon",
    "method",
    "local_degree",
    "tolerance",
    "smooth",
    "fit_stride",
    "normal_source",
    "viewpoint",
    "keep_outliers",
    "depth",
    "keep",
    "trim",
];
/// The keyword arguments `fit` takes beyond its named ones.
const FIT_PARAMS: &[&str] = &[
    "kappa_rule",
    "epsilon",
    "method",
    "normal_source",
    "viewpoint",
    "keep_outliers",
];

/// `value` as a number within `range`, named `name` in the message.
fn number(value: &Bound<'_, PyAny>, name: &str, range: Range) -> PyResult<f64> {
    let v: f64 = value.extract().map_err(|_| {
        PyValueError::new_err(format!(
            "{name} takes a number from {}, got {}",
            range.describe(),
            value
                .repr()
                .map_or_else(|_| "?".to_string(), |r| r.to_string())
        ))
    })?;
    range.check_value(name, v).map_err(PyValueError::new_err)
}

/// `value` as a string parsed by the library's `FromStr`.
fn choice<T: FromStr<Err = String>>(value: &Bound<'_, PyAny>, name: &str) -> PyResult<T> {
    let text: String = value
        .extract()
        .map_err(|_| PyValueError::new_err(format!("{name} takes a string")))?;
    text.parse::<T>()
        .map_err(|e| PyValueError::new_err(format!("{name}: {e}")))
}

/// Sets the field of `config` that the keyword `key` names (one of `allowed`).
fn apply_param(
    config: &mut PipelineConfig,
    function: &str,
    allowed: &[&str],
    key: &str,
    value: &Bound<'_, PyAny>,
) -> PyResult<()> {
    if !allowed.contains(&key) {
        return Err(PyTypeError::new_err(format!(
            "{function}() got an unexpected keyword argument '{key}'; it takes {}",
            allowed.join(", ")
        )));
    }
    match key {
        "degree" => config.fit.degree = number(value, key, limits::DEGREE)? as u32,
        "kappa" => {
            config.fit.kappa = match value.cast::<PyString>() {
                Ok(s) if s.to_cow()?.eq_ignore_ascii_case("auto") => Kappa::Auto,
                Ok(_) => {
                    return Err(PyValueError::new_err(
                        "kappa takes \"auto\" or a number from 0 to 1000",
                    ))
                }
                Err(_) => Kappa::Fixed(number(value, key, limits::KAPPA)?),
            }
        }
        "kappa_rule" => config.fit.kappa_rule = choice::<KappaRule>(value, key)?,
        "epsilon" => config.fit.epsilon = number(value, key, limits::EPSILON)?,
        "method" => config.fit.method = choice::<FitMethod>(value, key)?,
        "local_degree" => config.detail.degree = number(value, key, limits::LOCAL_DEGREE)? as u32,
        "tolerance" => {
            // As `--tolerance`: kept over the one the data's resolution would choose.
            config.tolerance = Setting::Fixed(number(value, key, limits::TOLERANCE)?);
        }
        "smooth" => config.smooth = number(value, key, limits::SMOOTH)?,
        "fit_stride" => {
            // As `--fit-stride`: kept over the one the data's resolution would choose.
            config.fit_stride = Setting::Fixed(number(value, key, limits::FIT_STRIDE)? as u32);
        }
        "normal_source" => config.normals.source = choice::<NormalSource>(value, key)?,
        "viewpoint" => {
            let v: Vec<Bound<'_, PyAny>> = value.try_iter()?.collect::<PyResult<_>>()?;
            if v.len() != 3 {
                return Err(PyValueError::new_err(format!(
                    "viewpoint takes three coordinates (x, y, z), got {}",
                    v.len()
                )));
            }
            let mut p = [0.0; 3];
            for (c, item) in p.iter_mut().zip(&v) {
                *c = number(item, key, limits::VIEWPOINT)?;
            }
            config.normals.viewpoint = Some(p);
        }
        "keep_outliers" => {
            config.outliers.keep = value
                .extract()
                .map_err(|_| PyValueError::new_err("keep_outliers takes True or False"))?
        }
        "depth" => {
            // As `--depth`: kept over the one the data's resolution would choose.
            config.depth = Setting::Fixed(number(value, key, limits::DEPTH)? as u32);
        }
        "keep" => {
            let text: String = value.extract().unwrap_or_default();
            config.finish.keep = match text.as_str() {
                "data" => Keep::Data,
                "all" => Keep::All,
                _ => return Err(PyValueError::new_err("keep takes \"data\" or \"all\"")),
            }
        }
        "trim" => match value.cast::<PyString>() {
            Ok(s) => match s.to_cow()?.as_ref() {
                // The mode's own trim.
                "auto" => {}
                "off" => config.finish.trim = TrimParams::off(),
                _ => {
                    return Err(PyValueError::new_err(
                        "trim takes \"auto\", \"off\" or a support factor from 0.5 to 100",
                    ))
                }
            },
            Err(_) => {
                config.finish.trim = TrimParams {
                    support_factor: number(value, key, limits::TRIM)?,
                    ..TrimParams::default()
                }
            }
        },
        _ => unreachable!("every allowed keyword is handled"),
    }
    Ok(())
}

/// Runs `f` without the interpreter's lock, on `threads` workers when given.
fn compute<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    f: impl FnOnce() -> T + Send,
) -> PyResult<T> {
    match threads {
        None => Ok(py.detach(f)),
        Some(n) => {
            let n = limits::THREADS
                .check_value("threads", n as f64)
                .map_err(PyValueError::new_err)?;
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n as usize)
                .build()
                .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
            Ok(py.detach(|| pool.install(f)))
        }
    }
}

/// The mesh `stablesurf run` writes, with the model it was meshed from and the run's report.
#[pyclass(frozen, module = "stablesurf")]
struct Reconstruction {
    /// Vertex positions, float64 of shape (V, 3), in the input's coordinates and units (the
    /// positions of `mesh.ply`, which stores them as float32).
    #[pyo3(get)]
    vertices: Py<PyAny>,
    /// Triangles, uint32 of shape (F, 3), counter-clockwise seen from outside.
    #[pyo3(get)]
    faces: Py<PyAny>,
    /// Unit outward vertex normals, float64 of shape (V, 3).
    #[pyo3(get)]
    normals: Py<PyAny>,
    /// The report `run` writes as `report.json`, as a dict (stages, fit, trim, mesh checks,
    /// accuracy, warnings).
    #[pyo3(get)]
    report: Py<PyAny>,
    /// The mesh is closed and 2-manifold (no boundary edge, no non-manifold edge or vertex).
    #[pyo3(get)]
    watertight: bool,
    /// No non-manifold edge or vertex (an open patch can be manifold).
    #[pyo3(get)]
    manifold: bool,
    /// Triangles that cross another triangle of the mesh.
    #[pyo3(get)]
    self_intersections: usize,
    /// Distances between the data and the mesh both ways, as a dict (`mean_relative`,
    /// `max_relative`, `mesh_to_data`, `chamfer_relative`, …).
    #[pyo3(get)]
    accuracy: Py<PyAny>,
    /// The warnings the run would print.
    #[pyo3(get)]
    warnings: Vec<String>,
    /// The global polynomial (mode "global"), or None in detail mode.
    #[pyo3(get)]
    polynomial: Option<Py<Polynomial>>,
}

#[pymethods]
impl Reconstruction {
    fn __repr__(&self, py: Python<'_>) -> String {
        let len = |a: &Py<PyAny>| a.bind(py).len().unwrap_or(0);
        format!(
            "Reconstruction({} vertices, {} faces, watertight={}, manifold={}, self_intersections={})",
            len(&self.vertices),
            len(&self.faces),
            py_bool(self.watertight),
            py_bool(self.manifold),
            self.self_intersections
        )
    }
}

/// Reconstructs a surface from points, as `stablesurf run` does, and returns its mesh.
///
/// `points` is an array of shape (N, 3), or a `Scan` from `read_points` (then exactly what
/// `stablesurf run FILE` computes). `normals` (N, 3) and `faces` (F, 3) are optional, as in a
/// scan file: with `normal_source="auto"` the normals come from them when given, else from the
/// crust (plane fits beyond 200,000 points). `mode` is "detail" (blended local fits, `run`'s
/// default) or "global" (one polynomial).
/// The other keywords are the command line's options, with its defaults: `depth`, `trim`
/// ("auto", "off" or a factor), `keep` ("data" or "all"), `degree`, `kappa` ("auto" or a
/// number), `kappa_rule`, `epsilon`, `method`, `local_degree`, `tolerance`, `smooth`, `fit_stride`,
/// `normal_source`, `viewpoint`, `keep_outliers`; `threads` limits the worker threads (the
/// result does not depend on it).
///
/// Raises ValueError for bad arguments or input (with the library's message), TypeError for
/// an unknown keyword.
#[pyfunction]
#[pyo3(signature = (points, normals=None, mode="detail", *, faces=None, threads=None, **params))]
fn reconstruct(
    py: Python<'_>,
    points: &Bound<'_, PyAny>,
    normals: Option<&Bound<'_, PyAny>>,
    mode: &str,
    faces: Option<&Bound<'_, PyAny>>,
    threads: Option<usize>,
    params: Option<&Bound<'_, PyDict>>,
) -> PyResult<Reconstruction> {
    let mode = match mode {
        "detail" => Mode::Detail,
        "global" => Mode::Global,
        other => {
            return Err(PyValueError::new_err(format!(
                "mode takes \"detail\" or \"global\", got {other:?}"
            )))
        }
    };
    let mut config = PipelineConfig::for_mode(mode);
    for (key, value) in params.iter().flat_map(|d| d.iter()) {
        let key: String = key.extract()?;
        apply_param(&mut config, "reconstruct", RECONSTRUCT_PARAMS, &key, &value)?;
    }
    let source = ScanSource::Cloud(Box::new(cloud_of(points, normals, faces)?));
    let out = compute(py, threads, || {
        pipeline::reconstruct(&source, &config, &mut pipeline::Silent)
    })?
    .map_err(pipeline_error)?;
    let mesh: &TriangleMesh = &out.mesh;
    let flat: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let faces = PyArray::from_vec(py, flat)
        .reshape([mesh.triangles.len(), 3])?
        .into_any();
    let report = &out.report;
    let polynomial = match out.model {
        Model::Global(model) => Some(Py::new(py, Polynomial { model })?),
        Model::Detail(_) => None,
    };
    Ok(Reconstruction {
        vertices: array_rows3(py, &mesh.positions)?.unbind(),
        faces: faces.unbind(),
        normals: array_rows3(py, &mesh.normals)?.unbind(),
        report: to_python(py, report)?.unbind(),
        watertight: report.mesh.watertight,
        manifold: report.mesh.non_manifold_edges == 0 && report.mesh.non_manifold_vertices == 0,
        self_intersections: report.mesh.self_intersecting_faces,
        accuracy: to_python(py, &report.accuracy)?.unbind(),
        warnings: report.warnings.clone(),
        polynomial,
    })
}

/// An implicit polynomial f fitted to a scan (the model `stablesurf fit` writes as
/// `model.json`): f(p) = Σ coefficients[l] · m_l((p − center) / scale), with the monomials m_l
/// in the graded order of Sahin & Unel (6.16); f < 0 inside, f > 0 outside.
#[pyclass(frozen, module = "stablesurf")]
struct Polynomial {
    model: ImplicitModel,
}

#[pymethods]
impl Polynomial {
    /// The degree n.
    #[getter]
    fn degree(&self) -> u32 {
        self.model.polynomial.degree
    }

    /// The (n+1)(n+2)(n+3)/6 coefficients, float64, in the graded monomial order.
    #[getter]
    fn coefficients<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        PyArray::from_vec(py, self.model.polynomial.coefficients.clone()).into_any()
    }

    /// The normalization's centre μ (the data's centroid), float64 of shape (3,).
    #[getter]
    fn center<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        PyArray::from_vec(py, self.model.polynomial.center.to_vec()).into_any()
    }

    /// The normalization's scale s (the data's mean distance to μ).
    #[getter]
    fn scale(&self) -> f64 {
        self.model.polynomial.scale
    }

    /// The ridge weight κ the fit used, or None for a model without its fit record.
    #[getter]
    fn kappa(&self) -> Option<f64> {
        self.model.fit.as_ref().map(|f| f.kappa)
    }

    /// Whether the fit certified a closed, bounded zero set, or None when unknown.
    #[getter]
    fn bounded(&self) -> Option<bool> {
        self.model.diagnostics.as_ref().map(|d| d.bounded)
    }

    /// The model's settings and diagnostics, as a dict (the `fit` object of report.json).
    #[getter]
    fn report<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        to_python(py, &Model::Global(self.model.clone()).report())
    }

    /// f at each point of `points` (N, 3), as float64 of shape (N,).
    fn evaluate<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let points = rows3_f64(points, "points")?;
        let values = py.detach(|| {
            let mut out = vec![0.0; points.len()];
            self.model.polynomial.eval_many(&points, &mut out);
            out
        });
        Ok(PyArray::from_vec(py, values).into_any())
    }

    /// The model file `stablesurf fit` writes (`model.json`), as a string.
    fn to_json(&self) -> PyResult<String> {
        let (_, bytes) = Model::Global(self.model.clone())
            .file()
            .map_err(|e| PyRuntimeError::new_err(chain(&e)))?;
        String::from_utf8(bytes).map_err(|e| PyRuntimeError::new_err(e.to_string()))
    }

    fn __repr__(&self) -> String {
        format!(
            "Polynomial(degree={}, {} coefficients, kappa={}, bounded={})",
            self.model.polynomial.degree,
            self.model.polynomial.coefficients.len(),
            self.kappa()
                .map_or("None".to_string(), |k| format!("{k:e}")),
            self.bounded().map_or("None", py_bool)
        )
    }
}

/// Fits one implicit polynomial to points with 3L + ridge regression, as `stablesurf fit` does.
///
/// `points` is an array of shape (N, 3) or a `Scan` from `read_points`; `normals` and `faces`
/// as in `reconstruct`. `degree` (2 to 14, default 8) and `kappa` ("auto" or 0 to 1000) as
/// the command line's; also `kappa_rule`, `epsilon`, `method`, `normal_source`, `viewpoint`,
/// `keep_outliers`, `threads`. Returns a `Polynomial`.
///
/// Raises ValueError for bad arguments or input, or when the fit fails (an odd degree with
/// automatic κ, too few points), with the library's message.
#[pyfunction]
#[pyo3(signature = (points, normals=None, *, faces=None, degree=None, kappa=None, threads=None, **params))]
#[allow(clippy::too_many_arguments)]
fn fit(
    py: Python<'_>,
    points: &Bound<'_, PyAny>,
    normals: Option<&Bound<'_, PyAny>>,
    faces: Option<&Bound<'_, PyAny>>,
    degree: Option<&Bound<'_, PyAny>>,
    kappa: Option<&Bound<'_, PyAny>>,
    threads: Option<usize>,
    params: Option<&Bound<'_, PyDict>>,
) -> PyResult<Polynomial> {
    let mut config = PipelineConfig::for_mode(Mode::Global);
    let all: Vec<&str> = FIT_PARAMS
        .iter()
        .copied()
        .chain(["degree", "kappa"])
        .collect();
    for (key, value) in [("degree", degree), ("kappa", kappa)] {
        if let Some(value) = value {
            apply_param(&mut config, "fit", &all, key, value)?;
        }
    }
    for (key, value) in params.iter().flat_map(|d| d.iter()) {
        let key: String = key.extract()?;
        apply_param(&mut config, "fit", &all, &key, &value)?;
    }
    let source = ScanSource::Cloud(Box::new(cloud_of(points, normals, faces)?));
    let (model, _, _) = compute(py, threads, || {
        pipeline::fit_model(&source, &config, &Cache::disabled(), &mut pipeline::Silent)
    })?
    .map_err(pipeline_error)?;
    match model {
        Model::Global(model) => Ok(Polynomial { model }),
        Model::Detail(_) => Err(PyRuntimeError::new_err(
            "the global fit returned a detail model",
        )),
    }
}

/// stablesurf: stable algebraic surfaces (Sahin & Unel 2008) and detail meshes from 3D scans.
///
/// `reconstruct(points, ...)` gives the mesh `stablesurf run` writes; `fit(points, ...)` the
/// polynomial `stablesurf fit` writes; `read_points(path)` reads a scan file with the tool's
/// own importer.
#[pymodule(name = "stablesurf")]
fn stablesurf_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_points, m)?)?;
    m.add_function(wrap_pyfunction!(reconstruct, m)?)?;
    m.add_function(wrap_pyfunction!(fit, m)?)?;
    m.add_class::<Scan>()?;
    m.add_class::<Reconstruction>()?;
    m.add_class::<Polynomial>()?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
