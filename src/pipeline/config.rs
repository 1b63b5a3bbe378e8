//! What a run is asked to do ([`PipelineConfig`]) and what it does once its data are known
//! ([`ResolvedConfig`]): the data-driven settings are resolved here, once.
//!
//! Input: a config and the oriented points (with their measured noise). Output: every stage's
//! params, final.
//!
//! A setting the data may choose is a [`Setting`]: `Auto` lets [`PipelineConfig::resolve`]
//! choose it from the points, `Fixed(x)` is what a flag or a Python argument asks for (the
//! command line and the Python package only ever set `Fixed`). The stages after the normals
//! take a [`ResolvedConfig`], which holds no `Auto`.
//!
//! Worked example, a new data-driven default: give the rule a function in the module of the
//! stage it serves (as [`polygonize::fit_stride`] for the detail fit's stride), add a
//! `Setting` field here, and one arm in [`PipelineConfig::resolve`] that calls the rule when
//! the setting is `Auto`. A flag for it, if any, sets `Fixed`.

use crate::detail::DetailParams;
use crate::export::ExportParams;
use crate::finish::FinishParams;
use crate::fit::FitParams;
use crate::normals::{NoiseEstimate, NormalsParams};
use crate::outliers::OutlierParams;
use crate::polygonize::{self, PolygonizeParams};
use crate::trim::{TrimMode, TrimParams};

use super::{Keep, Mode};

/// A setting chosen from the data unless it is fixed.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Setting<T> {
    /// Chosen by `PipelineConfig::resolve` from the points (in detail mode; in global mode
    /// the stage's own default).
    #[default]
    Auto,
    /// This value, whatever the data.
    Fixed(T),
}

impl<T: Copy> Setting<T> {
    /// The fixed value, or `auto` computed.
    pub fn or_else(self, auto: impl FnOnce() -> T) -> T {
        match self {
            Setting::Auto => auto(),
            Setting::Fixed(x) => x,
        }
    }

    /// Whether the data choose it.
    pub fn is_auto(&self) -> bool {
        matches!(self, Setting::Auto)
    }
}

/// Everything that decides what `run` computes and writes, before the data are seen.
#[derive(Clone, Debug)]
pub struct PipelineConfig {
    /// Global or detail model.
    pub mode: Mode,
    /// Which points are left out as outliers before the normals ([`crate::outliers`]).
    pub outliers: OutlierParams,
    /// Normals stage parameters.
    pub normals: NormalsParams,
    /// Fit stage parameters (global mode).
    pub fit: FitParams,
    /// Detail fit parameters (detail mode). Its `tolerance` and `stride` are the starting
    /// points of [`PipelineConfig::tolerance`] and [`PipelineConfig::fit_stride`].
    pub detail: DetailParams,
    /// Polygonize stage parameters (see [`PipelineConfig::for_mode`]). Its `depth` and
    /// `refine` are what [`PipelineConfig::depth`] and [`PipelineConfig::refine`] fall back to.
    pub polygonize: PolygonizeParams,
    /// The meshing depth. `Auto`, in detail mode: the depth of the points' spacing
    /// ([`polygonize::DataResolution`]: 6 or 7; `polygonize.depth` when the spacing cannot be
    /// measured), with the chords' whole least-squares move
    /// ([`PolygonizeParams::chord_share`] 1) on points a level or more finer than that mesh
    /// ([`polygonize::DataResolution::dense`]); in global mode, whose polynomial is meshed the
    /// same whatever the sampling, `polygonize.depth`. `Fixed(d)` (`--depth`): d, and the detail
    /// octree at least that deep.
    pub depth: Setting<u32>,
    /// Detail mode's split tolerance. `Auto`: `detail.tolerance`, cut by [`DENSE_TOLERANCE`]
    /// where the points are a level or more finer than the mesh. `Fixed(t)` (`--tolerance`): t.
    pub tolerance: Setting<f64>,
    /// The split of the mesh's curved edges ([`PolygonizeParams::refine`]). `Auto`, in detail
    /// mode: [`polygonize::REFINE_SAGITTA`] where the points are a level or more finer than
    /// the mesh's depth (`polygonize::DataResolution::finer_than`), else `polygonize.refine`;
    /// in global mode `polygonize.refine`. `Fixed` (`--refine`, `--no-refine`): that.
    pub refine: Setting<Option<f64>>,
    /// Detail mode's fit stride ([`DetailParams::stride`]). `Auto`: every k-th point where the
    /// points are far finer than the mesh's cells (`polygonize::fit_stride`), with the
    /// deepest cells' cubic refit; in global mode `detail.stride`. `Fixed(k)` (`--fit-stride`):
    /// k, without refits.
    pub fit_stride: Setting<u32>,
    /// The factor on the measured noise ([`crate::normals::estimate_noise`]) that detail
    /// mode's fit averages instead of following ([`DetailParams::noise`]; `--smooth`): 1 by
    /// default, 0 fits the points as exact (interpolates them), 2 smooths at twice the measured
    /// noise. Points that are not noisy (`NoiseEstimate::is_noisy`) are fitted as exact
    /// whatever the factor ([`smoothing`]).
    pub smooth: f64,
    /// The finish stage's params: components kept, trim and decimation (see
    /// [`PipelineConfig::for_mode`]).
    pub finish: FinishParams,
    /// The export stage's params: formats, slices, glTF options, units, up axis and volumes.
    pub export: ExportParams,
}

/// The config a run's stages after the normals take: every data-driven setting resolved
/// ([`PipelineConfig::resolve`]).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ResolvedConfig {
    /// Global or detail model.
    pub mode: Mode,
    /// Fit stage parameters (global mode).
    pub fit: FitParams,
    /// Detail fit parameters (detail mode), final.
    pub detail: DetailParams,
    /// Polygonize stage parameters, final.
    pub polygonize: PolygonizeParams,
    /// The finish stage's params, final (the trim's noise included).
    pub finish: FinishParams,
    /// The export stage's params.
    pub export: ExportParams,
}

impl PipelineConfig {
    /// The defaults of a `mode` run, the ones `stablesurf run --mode MODE` starts from: every
    /// stage's `…Params::default()`, every data-driven setting `Auto`, 16 distance slices of
    /// 128² along z, every output format, and per mode:
    ///
    /// | mode   | topology guard | components kept     | trim         | slice distance |
    /// |--------|----------------|---------------------|--------------|----------------|
    /// | global | 3 levels       | all (the model's)   | off          | exact          |
    /// | detail | none           | data ([`Keep::Data`]) | on (support) | mesh           |
    ///
    /// A polynomial's zero set is the model, so all of it is kept. A detail model's blend
    /// extrapolates past the data (it can close a blob in empty space), so the pieces and the
    /// parts of the surface the data does not support are left out; its loose gradient
    /// enclosure cannot pass the topology guard's test (it would refine nearly everywhere), and
    /// only the distance to the mesh is defined for it.
    ///
    /// ```
    /// use stablesurf::distance::DistanceMethod;
    /// use stablesurf::pipeline::{Keep, Mode, PipelineConfig};
    /// let detail = PipelineConfig::for_mode(Mode::Detail);
    /// assert_eq!(detail.mode, Mode::Detail);
    /// assert_eq!(detail.finish.keep, Keep::Data);
    /// assert_eq!(detail.export.slices.method, DistanceMethod::Mesh);
    /// assert_eq!(PipelineConfig::for_mode(Mode::Global).polygonize.guard_levels, 3);
    /// ```
    pub fn for_mode(mode: Mode) -> PipelineConfig {
        let global = PipelineConfig {
            mode: Mode::Global,
            outliers: OutlierParams::default(),
            normals: NormalsParams::default(),
            fit: FitParams::default(),
            detail: DetailParams::default(),
            polygonize: PolygonizeParams::default(),
            depth: Setting::Auto,
            tolerance: Setting::Auto,
            refine: Setting::Auto,
            fit_stride: Setting::Auto,
            smooth: 1.0,
            finish: FinishParams {
                trim: TrimParams::off(),
                ..FinishParams::default()
            },
            export: ExportParams::default(),
        };
        match mode {
            Mode::Global => global,
            Mode::Detail => PipelineConfig {
                mode: Mode::Detail,
                polygonize: PolygonizeParams {
                    guard_levels: 0,
                    data_levels: 2,
                    fit_chords: true,
                    ..global.polygonize
                },
                finish: FinishParams {
                    keep: Keep::Data,
                    trim: TrimParams::default(),
                    decimate: None,
                },
                export: ExportParams {
                    slices: crate::distance::SliceParams {
                        method: crate::distance::DistanceMethod::Mesh,
                        ..global.export.slices
                    },
                    ..global.export
                },
                ..global
            },
        }
    }

    /// The stages' params for these points: `cloud` all the oriented points (the input's and
    /// any the normals stage added), `input` the input's alone, `noise` their measured noise.
    ///
    /// - the meshing depth, tolerance, edge split and fit stride of their `Setting`s;
    /// - the detail octree at least as deep as a meshing depth asked for;
    /// - in detail mode, the noise the fit averages ([`DetailParams::noise`], [`smoothing`] of
    ///   the measured noise at [`PipelineConfig::smooth`]), which the trim's support takes too.
    ///
    /// The data's resolution is measured on the input points in the detail model's region
    /// (their box grown by 10% per side); the stride on every point of `cloud`.
    pub(crate) fn resolve(
        &self,
        cloud: &[[f64; 3]],
        input: &[[f64; 3]],
        noise: Option<&NoiseEstimate>,
    ) -> ResolvedConfig {
        let detail_mode = self.mode == Mode::Detail;
        let mut detail = self.detail.clone();
        let mut polygonize = self.polygonize.clone();
        let mut finish = self.finish.clone();
        if let Setting::Fixed(depth) = self.depth {
            polygonize.depth = depth;
            // The octree as fine as the mesh's finest cells.
            detail.max_depth = detail.max_depth.max(depth);
        } else if !detail_mode {
            detail.max_depth = detail.max_depth.max(polygonize.depth);
        }
        if let Setting::Fixed(t) = self.tolerance {
            detail = detail.with_tolerance(t);
        }
        if let Setting::Fixed(refine) = self.refine {
            polygonize.refine = refine;
        }
        if let Setting::Fixed(stride) = self.fit_stride {
            detail.stride = stride;
        }
        let data_box = crate::cloud::Aabb::from_points(cloud);
        let region = data_box.map(|b| b.grown(0.1));
        let any_auto = self.depth.is_auto() || self.tolerance.is_auto() || self.refine.is_auto();
        if detail_mode {
            let data = region
                .as_ref()
                .filter(|_| any_auto)
                .and_then(|r| polygonize::DataResolution::of(input, r));
            if let Some(data) = data {
                if self.depth.is_auto() {
                    polygonize.depth = data.depth();
                    if data.dense() && polygonize.fit_chords {
                        polygonize.chord_share = 1.0;
                    }
                }
                if self.tolerance.is_auto() && data.dense() {
                    let t = detail.tolerance * DENSE_TOLERANCE;
                    detail = detail.with_tolerance(t);
                }
                if self.refine.is_auto() && data.finer_than(polygonize.depth) {
                    polygonize.refine = Some(polygonize::REFINE_SAGITTA);
                }
            }
            if self.fit_stride.is_auto()
                && let Some(region) = &region
            {
                detail.stride = polygonize::fit_stride(cloud, region, polygonize.depth);
                detail.refit_deepest = detail.stride > 1;
            }
            if let (Some(noise), Some(data_box)) = (noise, data_box) {
                detail.noise = smoothing(noise, data_box.diagonal(), self.smooth, &detail);
                if finish.trim.mode == TrimMode::Support {
                    finish.trim.noise = detail.noise;
                }
            }
        }
        ResolvedConfig {
            mode: self.mode,
            fit: self.fit.clone(),
            detail,
            polygonize,
            finish,
            export: self.export.clone(),
        }
    }
}

impl Default for PipelineConfig {
    /// The defaults of the default mode ([`Mode::Global`]): `PipelineConfig::for_mode(Mode::default())`.
    fn default() -> Self {
        PipelineConfig::for_mode(Mode::default())
    }
}

/// Detail mode's split tolerance on dense points
/// ([`polygonize::DataResolution::dense`]) is this share of the default: the points then pin
/// the surface more tightly than the default asks, and after the chords the fit's error is
/// most of the distance to them (docs/defaults.md, "Detail mode's split tolerance").
pub const DENSE_TOLERANCE: f64 = 0.27;

/// Noise below this share of the split tolerance is not smoothed: the largest of a few
/// hundred Gaussian residuals is about 3–4 σ, so below a quarter of the tolerance noise alone
/// does not fail a cell's split test, and the fit of exact data stands.
pub(crate) const NOISE_FLOOR: f64 = 0.25;

/// The detail fit's [`DetailParams::noise`] for the measured `noise` of points whose box has
/// the diagonal `diagonal`, at the factor `smooth`: `smooth`·σ over the diagonal, or 0 where
/// the points are not noisy (`NoiseEstimate::is_noisy`: what a clean scan measures is its
/// surface's own relief) or that is below `NOISE_FLOOR` × the split tolerance.
///
/// ```
/// use stablesurf::pipeline::smoothing;
/// use stablesurf::{DetailParams, NoiseEstimate};
/// let d = DetailParams::default(); // tolerance 6.5e-4
/// let noise = NoiseEstimate { sigma: 2.5e-3, spacing: 3e-3, ..Default::default() };
/// assert_eq!(smoothing(&noise, 1.0, 1.0, &d), 2.5e-3);
/// assert_eq!(smoothing(&noise, 1.0, 2.0, &d), 5e-3);
/// assert_eq!(smoothing(&noise, 1.0, 0.0, &d), 0.0); // --smooth 0: exact data
/// let clean = NoiseEstimate { spacing: 1e-2, ..noise };
/// assert_eq!(smoothing(&clean, 1.0, 1.0, &d), 0.0); // a quarter of the spacing
/// ```
pub fn smoothing(noise: &NoiseEstimate, diagonal: f64, smooth: f64, detail: &DetailParams) -> f64 {
    let s = smooth * noise.sigma / diagonal;
    if noise.is_noisy() && s.is_finite() && s > NOISE_FLOOR * detail.tolerance {
        s
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The resolved config of `config` for a square grid of n × n points spaced 1 / (n − 1)
    /// on the unit square.
    fn on_grid(config: &PipelineConfig, n: usize) -> ResolvedConfig {
        let step = 1.0 / (n - 1) as f64;
        let points: Vec<[f64; 3]> = (0..n * n)
            .map(|i| [(i % n) as f64 * step, (i / n) as f64 * step, 0.0])
            .collect();
        config.resolve(&points, &points, None)
    }

    #[test]
    fn an_asked_meshing_depth_deepens_the_detail_octree_and_the_default_keeps_it() {
        let default = PipelineConfig::for_mode(Mode::Detail);
        assert!(default.depth.is_auto());
        assert_eq!(
            on_grid(&default, 100).detail.max_depth,
            DetailParams::default().max_depth
        );
        for (depth, expected) in [(6, 7), (7, 7), (8, 8), (11, 11)] {
            let asked = PipelineConfig {
                depth: Setting::Fixed(depth),
                ..default.clone()
            };
            let resolved = on_grid(&asked, 100);
            assert_eq!(resolved.detail.max_depth, expected, "--depth {depth}");
            assert_eq!(resolved.polygonize.depth, depth);
        }
    }

    /// Points 1000 to the side (log₂(1.2 · 999) ≈ 10.2 levels, 3.2 finer than depth 7) and 400
    /// to the side (≈ 8.9) get depth 7, the dense tolerance and the chords' whole move; 150 to
    /// the side (≈ 7.5) and 100 (≈ 6.9) depth 7, the default tolerance and share; the facets are
    /// fitted in every case; a tolerance or a depth asked for is kept, with the default share.
    /// The curved edges are split where the points are a level finer than the depth meshed.
    #[test]
    fn dense_points_get_the_dense_tolerance_and_the_whole_chord_move() {
        let default = PipelineConfig::for_mode(Mode::Detail);
        let tolerance = DetailParams::default().tolerance;
        for n in [1000, 400] {
            let dense = on_grid(&default, n);
            assert_eq!(dense.polygonize.depth, 7);
            assert!(dense.polygonize.fit_chords);
            assert_eq!(dense.polygonize.chord_share, 1.0);
            assert_eq!(dense.detail.tolerance, tolerance * DENSE_TOLERANCE);
            assert_eq!(dense.detail.finest_tolerance, tolerance * DENSE_TOLERANCE);
            assert_eq!(dense.polygonize.refine, Some(polygonize::REFINE_SAGITTA));
        }

        for n in [150, 100] {
            let resolved = on_grid(&default, n);
            assert_eq!(resolved.polygonize.depth, 7);
            assert!(resolved.polygonize.fit_chords);
            assert_eq!(resolved.polygonize.chord_share, polygonize::CHORD_SHARE);
            assert_eq!(resolved.detail, DetailParams::default());
            assert_eq!(resolved.polygonize.refine, None);
        }

        let asked = PipelineConfig {
            tolerance: Setting::Fixed(tolerance),
            depth: Setting::Fixed(8),
            ..default.clone()
        };
        let kept = on_grid(&asked, 1000);
        assert_eq!(kept.polygonize.depth, 8);
        assert!(kept.polygonize.fit_chords);
        assert_eq!(kept.polygonize.chord_share, polygonize::CHORD_SHARE);
        assert_eq!(kept.detail.tolerance, tolerance);
        assert_eq!(kept.detail.max_depth, 8);
        // Split edges follow the depth meshed: points 10.2 levels fine are a level finer than
        // depth 8's cells; 280 to the side (log₂(1.2 · 279) ≈ 8.4) are a level finer than depth
        // 7's, not depth 8's.
        assert_eq!(kept.polygonize.refine, Some(polygonize::REFINE_SAGITTA));
        assert_eq!(
            on_grid(&default, 280).polygonize.refine,
            Some(polygonize::REFINE_SAGITTA)
        );
        assert_eq!(on_grid(&asked, 280).polygonize.refine, None);
        let refine_asked = PipelineConfig {
            refine: Setting::Fixed(None),
            ..default.clone()
        };
        assert_eq!(on_grid(&refine_asked, 1000).polygonize.refine, None);

        // Each setting alone: a depth asked for keeps the default share and still cuts the
        // tolerance; a tolerance asked for keeps the data's share.
        let depth_asked = PipelineConfig {
            depth: Setting::Fixed(7),
            ..default.clone()
        };
        let resolved = on_grid(&depth_asked, 1000);
        assert_eq!(resolved.polygonize.chord_share, polygonize::CHORD_SHARE);
        assert_eq!(resolved.detail.tolerance, tolerance * DENSE_TOLERANCE);
        let tolerance_asked = PipelineConfig {
            tolerance: Setting::Fixed(tolerance),
            ..default.clone()
        };
        let resolved = on_grid(&tolerance_asked, 1000);
        assert_eq!(resolved.polygonize.chord_share, 1.0);
        assert_eq!(resolved.detail.tolerance, tolerance);
        // Without the chords the share is left at its default.
        let mut no_chords = default.clone();
        no_chords.polygonize.fit_chords = false;
        let resolved = on_grid(&no_chords, 1000);
        assert!(!resolved.polygonize.fit_chords);
        assert_eq!(resolved.polygonize.chord_share, polygonize::CHORD_SHARE);
    }

    /// Points 1000 to the side over a region of side 1.2: cells of depth 7 (1.2 / 128) hold
    /// about (9.37)² ≈ 88 points, fitted every ⌊85 / 3⌋ = 28th (85 the integer mean) with the
    /// deepest cells' cubic refit; 400 to the side (≈ 14 a cell) every 4th; 250 (≈ 5.4) every
    /// one, without refits. A stride asked for is kept, without refits, and the stride follows
    /// the depth meshed (depth 8: ≈ 22 a cell, every 7th). Global mode keeps its own.
    #[test]
    fn far_finer_points_are_fitted_at_a_stride() {
        let default = PipelineConfig::for_mode(Mode::Detail);
        let resolved = on_grid(&default, 1000);
        assert_eq!(resolved.detail.stride, 28);
        assert!(resolved.detail.refit_deepest);
        assert_eq!(on_grid(&default, 400).detail.stride, 4);
        let every = on_grid(&default, 250);
        assert_eq!(every.detail.stride, 1);
        assert!(!every.detail.refit_deepest);
        let asked = PipelineConfig {
            fit_stride: Setting::Fixed(5),
            ..default.clone()
        };
        let kept = on_grid(&asked, 1000);
        assert_eq!(kept.detail.stride, 5);
        assert!(!kept.detail.refit_deepest);
        assert_eq!(on_grid(&asked, 100).detail.stride, 5);
        let deeper = PipelineConfig {
            depth: Setting::Fixed(8),
            ..default.clone()
        };
        assert_eq!(on_grid(&deeper, 1000).detail.stride, 7);
        let global = PipelineConfig::for_mode(Mode::Global);
        assert_eq!(on_grid(&global, 1000).detail.stride, 1);
        assert_eq!(on_grid(&global, 1000).polygonize.depth, 7);
    }
}
