//! The detail model's types: what the fit is asked ([`DetailParams`]), what it makes
//! ([`MpuModel`] of [`MpuCell`]s) and what it measured ([`DetailDiagnostics`]).

use super::*;

/// Whether cells get MPU's auxiliary off-surface rows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum AuxiliaryPoints {
    /// The cell's centre and its 8 corners, each kept where its 6 nearest data points agree on
    /// its side (the default).
    #[default]
    CentreAndCorners,
    /// None (for comparison: without them, empty-space cells may extrapolate with either sign).
    None,
}

/// How the normals constrain each local fit (see `local.rs`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum LocalConstraints {
    /// Rows ∇Q = n at every point beside Q = 0 (Tasdizen, Tarel & Cooper 2000): met exactly by
    /// a quadric on a sphere. With estimated normals it fits the bunny's points less closely
    /// than the 3L rows (CHANGELOG.md).
    Gradient,
    /// The paper's 3L rows Q(p ± εn) = ±ε with ε = [`DetailParams::epsilon`] (the default). On
    /// curved patches their least-squares compromise moves the zero set outward; each local fit
    /// is therefore re-centred on its data, weighted by the blend weight (`local.rs`, step 4).
    #[default]
    ThreeLevels,
}

/// Parameters of the detail fit. Lengths are relative to the diagonal of the data's bounding
/// box unless stated otherwise.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DetailParams {
    /// Degree of the local polynomials: 2, 3 or 4 (grown cells use 2 at most). Default 2.
    pub degree: u32,
    /// A cell is split while the largest |Q|/|∇Q| over its ball's points exceeds this fraction
    /// of the data diagonal. Default 6.5e-4: a looser tolerance costs accuracy, a tighter
    /// one CPU for little accuracy (docs/defaults.md, "Detail mode's split tolerance").
    pub tolerance: f64,
    /// The tolerance used instead of `tolerance` for the cells of levels ≥ `max_depth − 2`
    /// (the deepest three), where few points remain per cell and a tighter fit is cheap.
    /// Default 6.5e-4, equal to `tolerance`: one tolerance throughout (the command line's
    /// `--tolerance T` sets this to min(1e-3, T)).
    pub finest_tolerance: f64,
    /// Deepest octree level (the root cube is level 0). Default 7: a level-7 cell is about a
    /// cell of the finest meshing level of `run` (7; the root cube is 1.2× the data's largest
    /// extent, the meshing region 1.2× each extent). Finer fits add little the mesh can show,
    /// while on a noisy or misregistered scan the split test keeps failing at the noise until
    /// the balls run out of points (the merged views of `bun.conf` grew four times the cells at
    /// level 8 for no gain; CHANGELOG.md). `run --depth D` raises it to D.
    pub max_depth: u32,
    /// How the normals enter the local fits. Default [`LocalConstraints::ThreeLevels`].
    #[serde(default)]
    pub constraints: LocalConstraints,
    /// Offset of the 3L layers, in each ball's normalized units (mean radius of its points),
    /// used with [`LocalConstraints::ThreeLevels`]. Default 0.3.
    pub epsilon: f64,
    /// Ridge weight κ of every local fit (relative, as in the global fit). Default 1e-2.
    pub kappa: f64,
    /// Ball radius as a multiple of the cell's diagonal (Ohtake et al.'s α). Default 0.75.
    pub support: f64,
    /// Auxiliary off-surface rows. Default: centre and corners.
    pub auxiliary: AuxiliaryPoints,
    /// The fit reads every `stride`-th point along the Z-order curve: a spatially even subset
    /// that keeps the scan's relative density, for points far finer than the cells the fit
    /// needs (each ball's rows, error measure and neighbour scans cost per point). Default 1:
    /// every point. `run` sets it from the points per cell of the mesh
    /// (`crate::polygonize::fit_stride`).
    #[serde(default = "one")]
    pub stride: u32,
    /// With `degree` 2: a cell of level `max_depth` (not grown) whose quadric misses the split
    /// tolerance is fitted again as a cubic over the same rows, and the cubic is kept when its
    /// largest error over the ball is smaller. Default false; `run` sets it where it picks a
    /// stride above 1 from the data (points far finer than the mesh,
    /// `crate::polygonize::fit_stride`): there the deepest cells hold relief a quadric cannot
    /// follow, and the stride pays for the cubics.
    #[serde(default)]
    pub refit_deepest: bool,
    /// The standard deviation of the points across their surface that the fit averages
    /// instead of following, as a fraction of the diagonal (`run` sets it to the measured
    /// noise × `--smooth`, [`crate::normals::estimate_noise`]). Default 0: the data is taken
    /// as exact. Above 0, five things change:
    /// - the normals' signs are first checked against the empty space around the points: a
    ///   normal whose line meets the space outside a closed object sooner on its inner side is
    ///   turned ([`DetailDiagnostics::exterior_flipped`] counts them; `exterior.rs`);
    /// - a cell is split while the root mean square of |Q|/|∇Q| over its ball's points exceeds
    ///   √((`NOISE_MARGIN`·σ)² + tolerance²), the scatter that noise σ and a shape error at the
    ///   tolerance give together, instead of while the largest exceeds the tolerance (the
    ///   largest of n Gaussian residuals is about σ·√(2 ln n): a cell of noisy points split
    ///   down to the deepest level, where each quadric follows the noise of a few points);
    /// - every fit holds at least c·(σ/tolerance)² points (c the local fit's coefficients, at
    ///   most `NOISE_POINTS_PER_COEFFICIENT`·c): the least-squares fit of c unknowns to n
    ///   points scatters by about σ·√(c/n), so these average the noise down to the tolerance;
    ///   a cell with fewer is grown to them;
    /// - each fit is repeated once with its points' rows weighed by Tukey's biweight of their
    ///   residual (`ROBUST_CUTOFF`·σ), and without the points whose normal opposes the first
    ///   fit's gradient, so that outliers and patches of flipped normals do not pull the
    ///   surface;
    /// - the whole octree is fitted a second time with the first blend's unit gradients as the
    ///   normals ([`DetailDiagnostics::reoriented_normals`] counts the ones that flipped).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub noise: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// A noisy cell's residuals may scatter by this many σ before it is split (see
/// [`DetailParams::noise`]): the root mean square of n residuals of noise σ varies by about
/// σ/√(2n) between balls, and the measured σ is a median over the scan. A larger margin
/// rounds the shape away, a smaller one opens handles through thin parts under strong noise
/// (docs/defaults.md, "Noise").
pub(crate) const NOISE_MARGIN: f64 = 1.1;

/// The most points per coefficient a noisy fit asks for (see [`DetailParams::noise`]), so
/// that a ball stays local under strong noise: more reach across a face's features, fewer
/// left strong noise unaveraged enough to open the surface (docs/defaults.md, "Noise").
pub(crate) const NOISE_POINTS_PER_COEFFICIENT: f64 = 24.0;

/// Tukey's biweight cut-off of a noisy fit's robust reweighting, in σ.
pub(crate) const ROBUST_CUTOFF: f64 = 4.0;

/// 1, the default of [`DetailParams::stride`] in a serialized params record without it.
fn one() -> u32 {
    1
}

impl Default for DetailParams {
    fn default() -> Self {
        DetailParams {
            degree: 2,
            tolerance: 6.5e-4,
            finest_tolerance: 6.5e-4,
            max_depth: 7,
            constraints: LocalConstraints::ThreeLevels,
            epsilon: 0.3,
            kappa: 1e-2,
            support: 0.75,
            auxiliary: AuxiliaryPoints::CentreAndCorners,
            stride: 1,
            refit_deepest: false,
            noise: 0.0,
        }
    }
}

impl DetailParams {
    /// These params with the split tolerance `tolerance` (a fraction of the diagonal): the
    /// finest cells split down to `tolerance` or 1e-3, whichever is smaller (`--tolerance`).
    pub(crate) fn with_tolerance(self, tolerance: f64) -> DetailParams {
        DetailParams {
            tolerance,
            finest_tolerance: tolerance.min(1e-3),
            ..self
        }
    }
}

/// Errors of the detail fit.
#[derive(Debug, thiserror::Error)]
pub enum DetailError {
    /// Too few points for one local fit; use a denser scan or the global mode.
    #[error("detail mode needs at least {min} points, the cloud has {n_points}")]
    TooFewPoints {
        /// Points given.
        n_points: usize,
        /// Points needed.
        min: usize,
    },
    /// The cloud has a NaN or infinite coordinate or normal (or a normal that is not unit
    /// length); clean the scan or re-estimate the normals.
    #[error("point {index} has a non-finite coordinate or a normal that is not unit length")]
    NonFinite {
        /// Index of the first bad point.
        index: usize,
    },
    /// The points and normals differ in number.
    #[error("{n_points} points but {n_normals} normals")]
    LengthMismatch {
        /// Points.
        n_points: usize,
        /// Normals.
        n_normals: usize,
    },
    /// All points coincide.
    #[error("all points coincide: the data has no extent")]
    Degenerate,
    /// A parameter is out of range; the message names it and its range.
    #[error("invalid parameter: {0}")]
    InvalidParams(String),
    /// A local system could not be solved (only with κ = 0 on degenerate balls); raise --kappa.
    #[error("the local fit of a level-{level} cell at {center:?} failed: raise kappa")]
    LocalFit {
        /// The cell's level.
        level: u32,
        /// The cell's centre.
        center: [f64; 3],
    },
}

/// One leaf of the MPU octree: a ball and its local function.
#[derive(Clone, Debug, PartialEq)]
pub struct MpuCell {
    /// Ball centre (the octree cell's centre), input coordinates.
    pub center: [f64; 3],
    /// Support radius of the cell's weight, input units: 0.75·√3·(cell side), so the balls of
    /// the leaves cover the root cube.
    pub radius: f64,
    /// Radius of the ball whose points were fitted: `radius`, or larger for a grown cell (the
    /// distance to its N_min-th nearest point); `radius` for an empty ball, which has no fit
    /// of its own.
    pub fit_radius: f64,
    /// Octree level of the cell (0 = root cube).
    pub level: u32,
    /// Whether the ball was grown to reach enough points, or held too few for its folded normals
    /// (see `FOLD_MIN_POINTS`), or held no point and took its parent's function; such cells are
    /// never split, and the first two have degree ≤ 2.
    pub grown: bool,
    /// The local fit, with its own centre/scale normalization, scaled so that it is close to a
    /// signed distance in input units near its data (negative inside).
    pub poly: ImplicitPolynomial,
}

/// What the detail fit did and how well the blend matches the data.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DetailDiagnostics {
    /// Data points.
    pub points: usize,
    /// Leaf cells (balls in the blend).
    pub cells: usize,
    /// Octree cells fitted, leaves and split cells together.
    pub fitted_cells: usize,
    /// Leaves whose ball was grown.
    pub grown_cells: usize,
    /// Deepest level reached.
    pub depth_reached: u32,
    /// Auxiliary rows kept (their 6 neighbours agreed in sign).
    pub auxiliary_kept: usize,
    /// Auxiliary candidates dropped (neighbours disagreed).
    pub auxiliary_dropped: usize,
    /// Largest |f|/|∇f| of the blend over the data points, relative to the diagonal (over
    /// every k-th point of a cloud of more than `crate::measure::ACCURACY_POINTS`, as the
    /// export's accuracy).
    pub max_residual: f64,
    /// Mean |f|/|∇f| of the blend over the data points (sampled as `max_residual`), relative
    /// to the diagonal.
    pub mean_residual: f64,
    /// Largest local error max |Qᵢ|/|∇Qᵢ| over the leaves that were not grown, relative to the
    /// diagonal (the split criterion's figure).
    pub max_local_error: f64,
    /// Noisy data ([`DetailParams::noise`] above 0): the fitted points whose given normal
    /// pointed against the first fit's gradient, which replaced every normal for the second.
    #[serde(default, skip_serializing_if = "is_zero_count")]
    pub reoriented_normals: usize,
    /// Noisy data: the normals turned before the first fit to face the nearer empty space
    /// around the points along their line (`exterior.rs`).
    #[serde(default, skip_serializing_if = "is_zero_count")]
    pub exterior_flipped: usize,
}

fn is_zero_count(v: &usize) -> bool {
    *v == 0
}

/// The detail model: the leaves of the MPU octree and an index for fast evaluation.
#[derive(Clone, Debug, PartialEq)]
pub struct MpuModel {
    /// The meshing region: the data box grown by 10% per side (input coordinates).
    pub region: Aabb,
    /// The root cube of the octree (input coordinates).
    pub root: Aabb,
    /// Diagonal of the data's bounding box (input units); also the value of f where no ball
    /// reaches.
    pub diagonal: f64,
    /// The leaves, in depth-first octree order.
    pub cells: Vec<MpuCell>,
    /// What the fit did.
    pub diagnostics: DetailDiagnostics,
    /// Ball hierarchy over `cells` (derived: rebuild it with [`MpuModel::new`] after editing
    /// `cells`).
    pub(crate) index: BallIndex,
}

impl MpuModel {
    /// Assembles a model from its parts and builds the evaluation index.
    pub(crate) fn new(
        region: Aabb,
        root: Aabb,
        diagonal: f64,
        cells: Vec<MpuCell>,
        diagnostics: DetailDiagnostics,
    ) -> MpuModel {
        let index = BallIndex::new(&cells);
        MpuModel {
            region,
            root,
            diagonal,
            cells,
            diagnostics,
            index,
        }
    }
}

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn detail_params_with_tolerance() {
        use crate::DetailParams;
        let coarse = DetailParams::default().with_tolerance(0.01);
        assert_eq!((coarse.tolerance, coarse.finest_tolerance), (0.01, 1e-3));
        let d = DetailParams::default();
        assert_eq!(d.clone().with_tolerance(d.tolerance), d);
    }
}
