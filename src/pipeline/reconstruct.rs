//! [`reconstruct`]: `run`'s stages in memory, without the cache or any file, for the Python
//! package and library users.

use std::time::Instant;

use crate::cache::Cache;
use crate::export::{self, ExportParams};

use super::{
    export_figures, fit_stages, polygonize_stage, run_report, Ctx, Model, Observer, PipelineConfig,
    PipelineError, RunReport, ScanSource,
};

/// What [`reconstruct`] makes: the mesh `run` writes, the model it is meshed from, and the
/// report `run` would write beside them.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    /// The mesh as `run` writes it (`mesh.ply`), after the component filter and the trim, in
    /// input coordinates, with unit vertex normals.
    pub mesh: crate::mesh::TriangleMesh,
    /// The fitted model.
    pub model: Model,
    /// What `run` would write as `report.json` (no file is listed: none is made).
    pub report: RunReport,
}

/// What [`super::run`] computes, in memory and without the cache: the same stages with the same
/// functions and params (import, outliers, normals, fit or detail, polygonize, and the export
/// stage's component filter, trim, checks and accuracy), so the mesh is the one `run` writes
/// for the same source and config. No file is encoded or written (`config.export.formats` is not
/// used). The input of the Python package's `reconstruct`.
///
/// ```
/// use stablesurf::pipeline::{reconstruct, Mode, PipelineConfig, ScanSource, Setting, Silent};
/// use stablesurf::PointCloud;
/// // 400 points on the unit sphere, with their normals.
/// let points: Vec<[f64; 3]> = (0..400)
///     .map(|i| {
///         let z = 1.0 - (2.0 * i as f64 + 1.0) / 400.0;
///         let (r, a) = ((1.0 - z * z).sqrt(), 2.399963 * i as f64);
///         [r * a.cos(), r * a.sin(), z]
///     })
///     .collect();
/// let cloud = PointCloud { normals: Some(points.clone()), points, ..Default::default() };
/// let mut config = PipelineConfig::for_mode(Mode::Global);
/// config.fit.degree = 2;
/// config.depth = Setting::Fixed(4);
/// let out = reconstruct(&ScanSource::Cloud(Box::new(cloud)), &config, &mut Silent).unwrap();
/// assert!(out.report.mesh.watertight);
/// assert_eq!(out.mesh.positions.len(), out.report.mesh.vertices);
/// for p in &out.mesh.positions {
///     let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
///     assert!((r - 1.0).abs() < 1e-3, "{r}");
/// }
/// ```
///
/// # Errors
/// Any stage's error, as [`super::run`]'s.
pub fn reconstruct(
    source: &ScanSource,
    config: &PipelineConfig,
    observer: &mut dyn Observer,
) -> Result<Reconstruction, PipelineError> {
    let start = Instant::now();
    let mut ctx = Ctx::new(&Cache::disabled(), observer)?;
    let (oriented, model, model_key, resolved) = fit_stages(&mut ctx, source, config)?;
    let config = &resolved;
    let (mesh, _, polygonized) = polygonize_stage(
        &mut ctx,
        &model,
        &model_key,
        oriented.input_points(),
        oriented.input_normals(),
        config,
    )?;
    let embedded = polygonized.embedded;
    let export_params = ExportParams {
        formats: Vec::new(),
        ..config.export.clone()
    };
    ctx.observer.stage_started("export");
    let export_start = Instant::now();
    let out = export::export(
        &model,
        &mesh,
        embedded,
        oriented.input_points(),
        oriented.colours.as_deref(),
        &export_params,
    )?;
    drop(mesh);
    let export_report = out.report();
    ctx.finish(
        "export",
        "none",
        export_start,
        None,
        export_report.clone().into(),
    );
    let figures = export_figures(&mut ctx, &model, export_report);
    let input = source.name();
    let mut report = run_report(input, ctx, &model, config, figures, Vec::new());
    report.seconds = start.elapsed().as_secs_f64();
    Ok(Reconstruction {
        mesh: out.surface,
        model,
        report,
    })
}
