//! [`reconstruct`]: `run`'s stages in memory, without the cache or any file, for the Python
//! package and library users.

use std::time::Instant;

use crate::cache::Cache;

use super::{
    finish_stage, fit_stages, mesh_figures, polygonize_stage, run_report, Ctx, Model, Observer,
    PipelineConfig, PipelineError, RunReport, ScanSource,
};

/// What [`reconstruct`] makes: the mesh `run` writes, the model it is meshed from, and the
/// report `run` would write beside them.
#[derive(Clone, Debug)]
pub struct Reconstruction {
    /// The mesh as `run` writes it (`mesh.ply`), after the component filter, the trim and the
    /// decimation, in input coordinates, with unit vertex normals.
    pub mesh: crate::mesh::TriangleMesh,
    /// The fitted model.
    pub model: Model,
    /// What `run` would write as `report.json` (no file is listed: none is made).
    pub report: RunReport,
}

/// What [`super::run`] computes, in memory and without the cache: the same stages with the same
/// functions and params (import, outliers, normals, fit or detail, polygonize, finish), so the
/// mesh is the one `run` writes for the same source and config. No file is encoded or written
/// (`config.export` is not used). The input of the Python package's `reconstruct`.
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
    let (mesh, mesh_key, polygonized) = polygonize_stage(
        &mut ctx,
        &model,
        &model_key,
        oriented.input_points(),
        oriented.input_normals(),
        config,
    )?;
    let (finished, _, finish_report) = finish_stage(
        &mut ctx,
        &model,
        &mesh,
        &mesh_key,
        polygonized.embedded,
        oriented.input_points(),
        oriented.colours.as_deref(),
        config,
    )?;
    drop(mesh);
    let figures = mesh_figures(&mut ctx, &model, finish_report);
    let input = source.name();
    let mut report = run_report(input, ctx, &model, config, figures, Vec::new());
    report.seconds = start.elapsed().as_secs_f64();
    Ok(Reconstruction {
        mesh: finished.mesh,
        model,
        report,
    })
}
