//! Stage `polygonize`: an implicit model (f < 0 inside, f > 0 outside) + a region →
//! [`TriangleMesh`] of its zero set, by an adaptive octree.
//!
//! Input: any [`ImplicitFunction`] — an [`ImplicitPolynomial`] directly, or a later piecewise
//! model — and the meshing region (input coordinates). Output: [`Polygonized`], a mesh in input
//! coordinates with unit normals from the analytic gradient and triangles wound counter-clockwise
//! seen from outside, plus counts of the work done.
//!
//! Invariants: the mesh is a 2-manifold whose boundary edges lie only on the region's boundary
//! (where the zero set leaves the region, the mesh is cut and [`crate::mesh::check`] reports the
//! boundary edges); step 5 removes the crossings the projection and the collapses make, so that
//! no triangle crosses another away from their shared vertices and edges (when one survives
//! every fallback of the simplified mesh, the collapses are made again without the vertices
//! around it, and failing that the mesh is made without collapses); a crossing
//! that survives there too is counted by [`crate::mesh::check`]; every vertex satisfies
//! |f|/|∇f| ≤ 10⁻⁷ × the region's diagonal unless ∇f vanishes there or step 5 had to fall back
//! to its linear position (reported in [`Polygonized::max_projection_residual`]); the output is
//! byte-identical for any number of threads. With [`PolygonizeParams::fit_chords`] the
//! vertices are then moved off the zero set by a share ([`PolygonizeParams::chord_share`],
//! default a quarter) of the facets' chord error (step 6), keeping the triangles and the
//! absence of crossings. With [`PolygonizeParams::refine`] the curved edges are first split at
//! their midpoint on the zero set (step 7), keeping the topology, the winding and the absence
//! of crossings.
//!
//! # Algorithm
//!
//! 1. **Octree** (`octree`): starting from the region, a cell is discarded when a guaranteed
//!    enclosure of f over it (the centred Taylor form, [`crate::implicit`]) excludes 0, so no piece of
//!    the zero set is ever lost between samples; otherwise it is split until level `depth`, and
//!    beyond that, up to `depth + guard_levels`, while Plantinga & Vegter's normal-variation test
//!    on the gradient enclosure fails (the topology guard). Only cells near the zero set survive,
//!    so the work grows about 4× per level, not 8×. A level-`depth` cell is a cube whose side is
//!    the region's longest side / 2^depth, shrunk by less than 2× along a shorter axis so that
//!    the cells end exactly on the region's faces. With data points
//!    ([`polygonize_with_data`], [`PolygonizeParams::data_levels`] > 0), only the cells that
//!    hold a data point are split down to `depth`; the others stay leaves up to `data_levels`
//!    levels above it, so the mesh is as fine as before where the data is and coarser between
//!    far-apart points (fewer triangles at the same Chamfer distance; CHANGELOG.md). With the data's
//!    normals too, a cell whose data (with its neighbours' at that level) has nearly one normal
//!    is not split either: planar parts are meshed at the coarse level, curved parts and edges
//!    at `depth` (far fewer triangles on flat parts at nearly the same accuracy; CHANGELOG.md).
//! 2. **Extraction** (`extract`): marching tetrahedra over a tetrahedralization of the surface
//!    leaves that conforms across levels (Kuhn tetrahedra in regular leaves, a cone from the
//!    centre over a shared face tiling in leaves next to finer ones). It yields a watertight
//!    2-manifold with consistent winding by construction, which is why it was chosen over dual
//!    contouring (which needs vertex splitting and still can self-intersect) and dual marching
//!    cubes (which needs a balanced octree and its own manifold case tables).
//! 3. **Simplification** (`simplify`, [`Simplification::EdgeCollapse`] by default): marching
//!    tetrahedra over 6 Kuhn tetrahedra per cell puts vertices on face and body diagonals too,
//!    which gives about 3× the triangles of marching cubes, many of them slivers. Half-edge
//!    collapses of the short edges, each allowed only under the link condition (so the topology,
//!    the boundary and the winding are kept exactly) and geometric checks (normal turn, new edge
//!    length ≤ 1.2 cells, no worse shape), remove about half the vertices before they are
//!    projected; the surviving vertices are original ones, so they are projected exactly as
//!    before. Of the options weighed, this one was chosen because it keeps every guarantee by a
//!    local, checkable condition: marching cubes in regular leaves (with the tetrahedra only in
//!    transition leaves) needs a case table whose face polygons match the neighbours' Kuhn
//!    diagonals across every leaf face, or cracks open at the transitions; SnapMC-style snapping
//!    of lattice values to 0 creates zero vertices and zero faces whose manifold handling is
//!    case by case. The collapse pass works on any conforming output, including the transition
//!    leaves.
//! 4. **Vertices**: one per surviving crossed lattice edge, placed at the root of f on that edge
//!    (inverse quadratic interpolation, Illinois regula falsi as the fallback) and then
//!    projected by Newton steps along ∇f; normal ∇f/|∇f|.
//! 5. **Crossings**: the Newton steps leave the lattice edge (by up to a few cells where ∇f
//!    turns, as in thin parts and the blended local fits of `--mode detail`) and can push a
//!    triangle through a neighbouring one (111–118 crossing triangles on the shared bunny in
//!    `--mode detail` at depth 7 and 8 before this step). The marching-tetrahedra mesh with its
//!    vertices on their edges has none (it is embedded by construction: each triangle lies in
//!    its own tetrahedron), nor had the collapsed mesh on the positions the collapses were
//!    judged on (on the bunny). So the triangles that cross another are found with the exact
//!    test of `crate::mesh::intersecting_triangles`, their vertices are put back at the root
//!    of f on their own lattice edge, and the pairs around the moved vertices are tested again;
//!    a crossing that remains (a collapse judged on the linearly interpolated positions) sends
//!    its vertices to that linear position. Few vertices move (about 160 of 250 000 on the
//!    bunny at depth 8), all still on their edges. Should a crossing survive even that (an edge
//!    collapse made it on the very positions it was judged on: the teapot of ../shared/data at
//!    level 7 everywhere, where spout and handle meet the body; the six bunny scans of
//!    `bun.conf`), the collapses are made again with the vertices within 3 rings of the
//!    crossing triangles pinned, so the mesh there is the one without collapses, whose
//!    vertices on their lattice edges cannot cross ([`Polygonized::pinned_vertices`]: 65 on
//!    `bun.conf`); if a crossing survives that too, the whole mesh is made without collapses,
//!    at about twice the triangles ([`Polygonized::simplified`] is then false).
//!
//! 6. **Chords** (`chords`, [`PolygonizeParams::fit_chords`], `--fit-chords`): each vertex
//!    moves along its normal a quarter of the way to the position where the flat facets would
//!    straddle the curved surface in the least-squares sense instead of lying under it (at most
//!    5% of its edges' length; the vertices stay near the zero set, the facets' mean error
//!    falls by a quarter). These are the positions step 5 tests first: a vertex of a crossing
//!    triangle goes back to its projection before its other fallbacks, so one exact test of
//!    the whole mesh covers both steps.
//! 7. **Split edges** (`refine`, [`PolygonizeParams::refine`], `--refine`): before step 6, the
//!    edges whose arc strays from their chord by more than a share of the finest cells' side
//!    (estimated from their length and their ends' normals) and by more than the data's median
//!    distance from the zero set are split at their midpoint, projected onto the zero set, one
//!    triangle into two or four; step 5 tests the new vertices as the others, their last
//!    fallback the midpoint of their edge's ends, where the split triangle's pieces lie in its
//!    plane. Dense points (a level finer than the mesh, which sample the facets' interiors):
//!    a lower Chamfer distance for a quarter more CPU (docs/defaults.md, "Refined edges").
//!
//! Determinism: the octree visits children in a fixed order and concatenates their results;
//! leaves and edges are processed in fixed-size chunks collected in order; the simplification
//! sweeps fixed chunks, each sequentially in a fixed order; a vertex is placed (step 4) as soon
//! as the simplification knows it survives, overlapping the sweeps, and its placement depends
//! on its lattice edge alone; vertices are ordered by their lattice edge, triangles by leaf.
//!
//! ```
//! use stablesurf::polygonize::{polygonize, PolygonizeParams};
//! use stablesurf::{Aabb, ImplicitPolynomial};
//! // The unit sphere x² + y² + z² − 1 = 0.
//! let mut coefficients = vec![0.0; 10];
//! coefficients[0] = -1.0;
//! for l in [4, 7, 9] {
//!     coefficients[l] = 1.0;
//! }
//! let sphere = ImplicitPolynomial { degree: 2, coefficients, center: [0.0; 3], scale: 1.0 };
//! let region = Aabb { min: [-1.5; 3], max: [1.5; 3] };
//! let out = polygonize(&sphere, &region, &PolygonizeParams { depth: 4, ..Default::default() })?;
//! let report = stablesurf::mesh::check(&out.mesh);
//! assert!(report.watertight);
//! assert_eq!(report.euler_characteristic, 2);
//! # Ok::<(), stablesurf::polygonize::PolygonizeError>(())
//! ```

mod chords;
mod depth;
mod extract;
mod grid;
mod octree;
mod refine;
pub(crate) mod simplify;

pub use crate::implicit::ImplicitFunction;
pub(crate) use depth::fit_stride;
pub use depth::{DataResolution, DATA_DEPTH_MAX, DATA_DEPTH_MIN};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::cloud::Aabb;
use crate::mesh::TriangleMesh;
#[cfg(doc)]
use crate::poly::ImplicitPolynomial;

use grid::Grid;

/// Largest `depth + guard_levels` supported.
pub(crate) const MAX_LEVEL: u32 = Grid::MAX_CAP;

/// Projection tolerance: |f|/|∇f| at a vertex, as a fraction of the region's diagonal.
const PROJECTION_TOLERANCE: f64 = 1e-7;

/// Errors of the polygonize stage.
#[derive(Debug, thiserror::Error)]
pub enum PolygonizeError {
    /// The region is empty, flat or not finite; pass a box with min < max on every axis.
    #[error("the meshing region must be finite with min < max on every axis, got min {min:?} and max {max:?}: pass --bounds xmin,ymin,zmin,xmax,ymax,zmax")]
    InvalidRegion {
        /// The region's smallest corner.
        min: [f64; 3],
        /// The region's largest corner.
        max: [f64; 3],
    },
    /// `depth` is 0 or `depth + guard_levels` exceeds `MAX_LEVEL`; lower one of them.
    #[error("depth {depth} with {guard_levels} guard levels is out of range: depth must be at least 1 and depth + guard levels at most {max}, change --depth")]
    InvalidDepth {
        /// The requested depth.
        depth: u32,
        /// The requested guard levels.
        guard_levels: u32,
        /// The largest allowed total, `MAX_LEVEL`.
        max: u32,
    },
    /// The model is malformed (wrong number of coefficients, non-finite numbers, scale ≤ 0);
    /// fix the model file.
    #[error("the model cannot be meshed: {0}")]
    InvalidModel(String),
    /// The data points given to [`polygonize_with_data`] and their normals differ in number.
    #[error("invalid meshing data: {0}")]
    InvalidData(String),
    /// [`PolygonizeParams::chord_share`] is not in (0, 1].
    #[error("the chord share {0} is out of range: give a share in (0, 1]")]
    InvalidChordShare(f64),
    /// [`PolygonizeParams::refine`] is not finite and > 0.
    #[error("the refinement's sagitta {0} is out of range: give a finite share > 0")]
    InvalidRefine(f64),
}

/// Parameters of the polygonize stage.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PolygonizeParams {
    /// Octree depth near the surface: every cell the zero set may cross is refined to this level,
    /// whose cells have the region's longest side / 2^depth (at most; along a shorter axis they
    /// are shrunk by less than 2× to end on the region's faces). Default 7 (the README's depth
    /// table: on the scans of ../shared/data depth 8 gives the same topology and accuracy with
    /// 4× the triangles); at least 1.
    pub depth: u32,
    /// How many levels below `depth` the topology guard may refine cells where the gradient's
    /// direction may turn by 90° or more (near singular points, thin necks, tiny components).
    /// 0 disables the guard. Default 3; `depth + guard_levels` ≤ `MAX_LEVEL` (16).
    pub guard_levels: u32,
    /// How many levels coarser than `depth` the surface may stay in cells that hold no data
    /// point: the mesh has level `depth`'s resolution in the cells (of levels `depth − 1`,
    /// `depth − 2`, …) that hold a data point, and is up to 2^`data_levels` times coarser
    /// between far-apart points; with the data's normals, also where the data is flat. Used
    /// only by [`polygonize_with_data`] with data points;
    /// the coarse level is at least 1. Default 0 (the same level everywhere).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub data_levels: u32,
    /// What is done to the marching-tetrahedra mesh before its vertices are projected.
    /// Default [`Simplification::EdgeCollapse`].
    pub simplification: Simplification,
    /// Step 6: move the vertices off the zero set by [`chord_share`](Self::chord_share) (default
    /// a quarter) of the facets' chord error, towards a mesh that straddles the surface rather
    /// than lying under it where it curves (see `chords`; the triangles, the topology and the
    /// absence of crossings are kept). Default `false` (every vertex on the zero set); detail
    /// mode's `run` sets it (`--fit-chords`, `--no-fit-chords`).
    #[serde(default, skip_serializing_if = "is_false")]
    pub fit_chords: bool,
    /// With `fit_chords`, the share of the least-squares chord move step 6 makes, in (0, 1]
    /// (checked with or without `fit_chords`): 1 makes the facets' mean signed error over the
    /// area zero and puts the vertices outside by about as much; the default, [`CHORD_SHARE`]
    /// (a quarter), keeps the vertices within 1e-5 of the diagonal of a 20,000-point sphere or
    /// torus on average (see `chords`). Detail mode's `run` takes the whole move on points a
    /// level or more finer than the mesh ([`DataResolution::dense`]), which sample the facets'
    /// interiors.
    #[serde(
        default = "default_chord_share",
        skip_serializing_if = "is_default_chord_share"
    )]
    pub chord_share: f64,
    /// Step 7: split the edges whose estimated sagitta (h·|n_a − n_b|/8 for an edge of length
    /// h between vertices of normals n_a, n_b) exceeds this share of the finest cells' side and,
    /// with data points, their median distance |f|/|∇f| from the zero set (a sagitta below the
    /// data's own scatter does not show), at their midpoint projected onto the zero set (see
    /// `refine`; the topology, the winding and the absence of crossings are kept). `None` (the
    /// default): no split. Detail mode's `run` sets [`REFINE_SAGITTA`] on points a level or
    /// more finer than the mesh (`DataResolution::finer_than`), which sample the facets'
    /// interiors (`--refine`, `--no-refine`). When given, finite and > 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refine: Option<f64>,
}

/// The sagitta, as a share of the finest cells' side, above which step 7 splits an edge when
/// asked for (docs/defaults.md, "Refined edges").
pub const REFINE_SAGITTA: f64 = 0.015;

/// The default share of the least-squares chord move (see `chords`): a quarter.
pub const CHORD_SHARE: f64 = 0.25;

fn default_chord_share() -> f64 {
    CHORD_SHARE
}

fn is_default_chord_share(share: &f64) -> bool {
    *share == CHORD_SHARE
}

impl PolygonizeParams {
    /// The share of the chord move step 6 makes, or `None` without `fit_chords`.
    pub(crate) fn chords(&self) -> Option<f64> {
        self.fit_chords.then_some(self.chord_share)
    }
}

fn is_false(b: &bool) -> bool {
    !*b
}

/// Post-processing of the extracted mesh (see the module docs, step 3).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Simplification {
    /// The marching-tetrahedra mesh as extracted: one vertex per crossed lattice edge, about 3×
    /// the triangles of marching cubes, many of them slivers.
    None,
    /// Topology-safe half-edge collapses of the short edges (link condition, normal-turn,
    /// edge-length and shape checks): the same topology, boundary and vertex guarantees with
    /// fewer, better-shaped triangles.
    #[default]
    EdgeCollapse,
}

impl Default for PolygonizeParams {
    fn default() -> Self {
        PolygonizeParams {
            depth: 7,
            guard_levels: 3,
            data_levels: 0,
            simplification: Simplification::EdgeCollapse,
            fit_chords: false,
            chord_share: CHORD_SHARE,
            refine: None,
        }
    }
}

/// The stage's result.
#[derive(Clone, Debug, Default)]
pub struct Polygonized {
    /// The extracted mesh.
    pub mesh: TriangleMesh,
    /// Number of function evaluations spent: point values, value-and-gradient evaluations, and
    /// box enclosures (of the value, or of value and gradient together), each counted once.
    /// Placements computed ahead for vertices a later collapse removes are not counted, so the
    /// count does not depend on the scheduling; when the mesh is made again without collapses
    /// (step 5), the first attempt's placements and the repeated extraction are counted too.
    pub evaluations: u64,
    /// Number of surface leaves (octree cells the zero set may cross) that were triangulated.
    pub cells: usize,
    /// Number of cells the topology guard split below `depth`.
    pub guard_splits: u64,
    /// Deepest level among the surface leaves (`depth` when the guard split nothing; 0 when there
    /// is no surface leaf).
    pub max_level: u32,
    /// Whether the mesh is the simplified one: `false` when [`Simplification::None`] was asked
    /// for, or when a crossing survived the repair of the simplified mesh and the mesh without
    /// collapses was made instead (see the module docs, step 5).
    pub simplified: bool,
    /// Vertices the collapses were made again without (step 5's local fallback: those around
    /// a crossing that survived the repair of the simplified mesh); 0 when none was needed
    /// or when the mesh without collapses was made instead.
    pub pinned_vertices: usize,
    /// Largest |f|/|∇f| over the vertices, divided by the region's diagonal (0 for an empty
    /// mesh; infinite if a vertex sits where ∇f = 0 and f ≠ 0).
    pub max_projection_residual: f64,
    /// Vertices step 7 added, splitting the curved edges ([`PolygonizeParams::refine`]); 0
    /// without it.
    pub refined_vertices: usize,
    /// Whether the exact test of step 5 (`crate::mesh::intersecting_triangles`) found no
    /// triangle crossing another in the final mesh: its last round tested every pair that could
    /// have changed, or a full test ran. `false` only when a crossing survived every fallback.
    pub embedded: bool,
}

fn is_zero(n: &u32) -> bool {
    *n == 0
}

/// Meshes the zero set of `function` inside `region` (input coordinates), at level
/// `params.depth` everywhere (`params.data_levels` is not used: there is no data).
///
/// `function` is any [`ImplicitFunction`]; pass an `&ImplicitPolynomial` for the global model.
///
/// # Errors
/// [`PolygonizeError::InvalidRegion`] for an empty, flat or non-finite region,
/// [`PolygonizeError::InvalidDepth`] for a depth out of range, and
/// [`PolygonizeError::InvalidModel`] for a malformed model.
pub fn polygonize<F: ImplicitFunction + ?Sized>(
    function: &F,
    region: &Aabb,
    params: &PolygonizeParams,
) -> Result<Polygonized, PolygonizeError> {
    polygonize_with_data(function, region, &[], None, params)
}

/// Meshes the zero set of `function` inside `region` as [`polygonize`] does, at level
/// `params.depth` near the `data` points and up to `params.data_levels` levels coarser away
/// from them (when `data` is empty or `data_levels` is 0: at `depth` everywhere). The coarse
/// level is `depth − data_levels`, at least 1. With `normals` (one unit normal per data
/// point), the cells where the data is flat stay coarse too: planar parts get large triangles,
/// curved parts and edges the level `depth` (see [`PolygonizeParams::data_levels`]).
///
/// # Errors
/// As [`polygonize`]; [`PolygonizeError::InvalidData`] when `normals` and `data` differ in
/// length.
pub fn polygonize_with_data<F: ImplicitFunction + ?Sized>(
    function: &F,
    region: &Aabb,
    data: &[[f64; 3]],
    normals: Option<&[[f64; 3]]>,
    params: &PolygonizeParams,
) -> Result<Polygonized, PolygonizeError> {
    if let Some(normals) = normals
        && normals.len() != data.len()
    {
        return Err(PolygonizeError::InvalidData(format!(
            "{} data points but {} normals; give one normal per point",
            data.len(),
            normals.len()
        )));
    }
    let valid_region = (0..3).all(|a| {
        region.min[a].is_finite() && region.max[a].is_finite() && region.min[a] < region.max[a]
    });
    if !valid_region {
        return Err(PolygonizeError::InvalidRegion {
            min: region.min,
            max: region.max,
        });
    }
    let cap = params.depth.checked_add(params.guard_levels);
    if params.depth == 0 || cap.is_none_or(|c| c > MAX_LEVEL) {
        return Err(PolygonizeError::InvalidDepth {
            depth: params.depth,
            guard_levels: params.guard_levels,
            max: MAX_LEVEL,
        });
    }
    if !(params.chord_share > 0.0 && params.chord_share <= 1.0) {
        return Err(PolygonizeError::InvalidChordShare(params.chord_share));
    }
    if let Some(share) = params.refine
        && !(share > 0.0 && share.is_finite())
    {
        return Err(PolygonizeError::InvalidRefine(share));
    }
    function.validate().map_err(PolygonizeError::InvalidModel)?;
    let coarse = if data.is_empty() {
        params.depth
    } else {
        params.depth.saturating_sub(params.data_levels).max(1)
    };
    let grid = Grid::new(*region, coarse, params.depth + params.guard_levels);
    let data_cells =
        (coarse < params.depth).then(|| octree::DataCells::new(&grid, data, normals, params.depth));

    let tree = octree::build(function, &grid, data_cells.as_ref());
    let (edges, end_values, triangles, extraction_evaluations) =
        extract::triangulate(function, &grid, &tree);
    let diagonal = region.diagonal();
    let tolerance = PROJECTION_TOLERANCE * diagonal;
    let chords = params.chords();
    let longest = (0..3)
        .map(|a| region.max[a] - region.min[a])
        .fold(0.0, f64::max);
    // Step 7's sagitta in input units: the share of the finest cells' side, and at least the
    // data's own scatter about the zero set, below which a facet's sagitta does not show.
    let mut scatter_evaluations = 0;
    let refine = params.refine.map(|share| {
        let cell = longest / f64::from(1u32 << params.depth);
        let (scatter, spent) = data_scatter(function, data);
        scatter_evaluations = spent;
        (share * cell).max(scatter)
    });
    let mut simplified = params.simplification == Simplification::EdgeCollapse;
    let mut done = place_and_repair(
        function,
        &grid,
        &edges,
        &end_values,
        triangles,
        params.simplification,
        &[],
        tolerance,
        chords,
        refine,
    );
    let mut spent_before = 0;
    let mut pinned_vertices = 0;
    if done.crossings_left && simplified {
        // A crossing survived every fallback position: an edge collapse made it on the very
        // positions it was judged on. First the collapses are made again with the vertices
        // around the crossing pinned (never removed, never moved onto: PIN_RINGS rings of the
        // marching-tetrahedra mesh around the crossing triangles' vertices), so the mesh there
        // stays the one without collapses, which is embedded by construction (each triangle
        // lies in its own tetrahedron), and everywhere else keeps its collapses. Should a
        // crossing survive that too, the whole mesh is made without collapses, whose repair
        // of step 5 ends without crossings (short of degenerate triangles, which
        // `mesh::check` would still count).
        // The extraction is deterministic, so it is run again here rather than its triangles
        // kept (a copy) on every run for this rare case.
        let (_, _, triangles, again) = extract::triangulate(function, &grid, &tree);
        spent_before = again + done.vertices.iter().map(|v| v.evaluations).sum::<u64>();
        let pinned = pin_around(&done.stuck, &triangles, edges.len(), PIN_RINGS);
        pinned_vertices = pinned.iter().filter(|&&p| p).count();
        let retry = triangles.clone();
        done = place_and_repair(
            function,
            &grid,
            &edges,
            &end_values,
            triangles,
            Simplification::EdgeCollapse,
            &pinned,
            tolerance,
            chords,
            refine,
        );
        if done.crossings_left {
            spent_before += done.vertices.iter().map(|v| v.evaluations).sum::<u64>();
            simplified = false;
            pinned_vertices = 0;
            done = place_and_repair(
                function,
                &grid,
                &edges,
                &end_values,
                retry,
                Simplification::None,
                &[],
                tolerance,
                chords,
                refine,
            );
        }
    }
    let Repaired {
        vertices,
        mesh,
        crossings_left,
        added,
        ..
    } = done;
    let max_residual = vertices.iter().map(|v| v.residual).fold(0.0, f64::max);
    Ok(Polygonized {
        mesh,
        evaluations: tree.evaluations
            + extraction_evaluations
            + spent_before
            + scatter_evaluations
            + vertices.iter().map(|v| v.evaluations).sum::<u64>(),
        simplified,
        pinned_vertices,
        cells: tree.leaves.len(),
        guard_splits: tree.guard_splits,
        max_level: tree.leaves.iter().map(|c| c.level).max().unwrap_or(0),
        max_projection_residual: max_residual / diagonal,
        refined_vertices: added,
        embedded: !crossings_left,
    })
}

/// At most this many data points measure their scatter about the zero set (step 7).
const SCATTER_SAMPLES: usize = 4096;

/// The median distance |f|/|∇f| of an even sample of the `data` points from the zero set of
/// `function` (0 without data), and the evaluations spent.
fn data_scatter<F: ImplicitFunction + ?Sized>(function: &F, data: &[[f64; 3]]) -> (f64, u64) {
    if data.is_empty() {
        return (0.0, 0);
    }
    let stride = data.len().div_ceil(SCATTER_SAMPLES).max(1);
    let mut distances: Vec<f64> = data
        .par_iter()
        .step_by(stride)
        .map(|&p| {
            let (value, gradient) = function.value_gradient(p);
            extract::residual(value, crate::vec3::norm(gradient))
        })
        .collect();
    let spent = distances.len() as u64;
    distances.retain(|d| d.is_finite());
    if distances.is_empty() {
        return (0.0, spent);
    }
    let middle = distances.len() / 2;
    (
        *distances.select_nth_unstable_by(middle, f64::total_cmp).1,
        spent,
    )
}

/// Steps 3–5 on the extracted triangles: simplification, vertex placement, and the repair of
/// crossings.
struct Repaired {
    vertices: Vec<extract::PlacedVertex>,
    mesh: TriangleMesh,
    /// Whether some triangle still crosses another with all its vertices at their last
    /// fallback position (when `false`, the exact test found no crossing in the final mesh).
    crossings_left: bool,
    /// The vertices (as lattice-edge indices) of the triangles still crossing another, sorted;
    /// empty when `crossings_left` is false.
    stuck: Vec<u32>,
    /// The vertices step 7 added (the last ones).
    added: usize,
}

/// Where step 5 has a vertex, in the order of its fallbacks (see [`place_and_repair`]).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Fallback {
    /// Off the zero set by a share of its chord error (step 6).
    Chord,
    /// Projected onto the zero set (step 4).
    Projected,
    /// At the root of f on its own lattice edge.
    EdgeRoot,
    /// At the linear interpolation on its lattice edge: the last fallback.
    Linear,
}

impl Fallback {
    fn next(self) -> Fallback {
        match self {
            Fallback::Chord => Fallback::Projected,
            Fallback::Projected => Fallback::EdgeRoot,
            Fallback::EdgeRoot | Fallback::Linear => Fallback::Linear,
        }
    }
}

/// Rings of the marching-tetrahedra mesh around a surviving crossing whose vertices step 5's
/// local fallback pins.
const PIN_RINGS: usize = 3;

/// The vertices (lattice-edge indices, of `n` in all) within `rings` edges of `seeds` in the
/// marching-tetrahedra mesh `triangles`, as a mask.
fn pin_around(seeds: &[u32], triangles: &[[u32; 3]], n: usize, rings: usize) -> Vec<bool> {
    let mut pinned = vec![false; n];
    let mut front: Vec<u32> = seeds.to_vec();
    for &v in &front {
        pinned[v as usize] = true;
    }
    for _ in 0..rings {
        if front.is_empty() {
            break;
        }
        let in_front = {
            let mut mask = vec![false; n];
            for &v in &front {
                mask[v as usize] = true;
            }
            mask
        };
        let mut next = Vec::new();
        for t in triangles {
            if t.iter().any(|&v| in_front[v as usize]) {
                for &v in t {
                    if !pinned[v as usize] {
                        pinned[v as usize] = true;
                        next.push(v);
                    }
                }
            }
        }
        front = next;
    }
    pinned
}

#[allow(clippy::too_many_arguments)]
fn place_and_repair<F: ImplicitFunction + ?Sized>(
    function: &F,
    grid: &Grid,
    edges: &[extract::EdgeKey],
    end_values: &[[f64; 2]],
    triangles: Vec<[u32; 3]>,
    simplification: Simplification,
    pinned: &[bool],
    tolerance: f64,
    chords: Option<f64>,
    refine: Option<f64>,
) -> Repaired {
    // The output vertices, their triangles, and each vertex's crossed lattice edge.
    let (mut vertices, triangles, edge_of): (Vec<extract::PlacedVertex>, Vec<[u32; 3]>, Vec<u32>) =
        match simplification {
            Simplification::None => (
                extract::place_vertices(function, grid, edges, end_values, tolerance),
                triangles,
                (0..edges.len() as u32).collect(),
            ),
            Simplification::EdgeCollapse => {
                let (positions, sizes) = extract::approximate_vertices(grid, edges, end_values);
                // The surviving vertices are placed inside the simplification, as soon as each is
                // known to survive (see simplify::simplify).
                let place = |v: u32| {
                    let v = v as usize;
                    extract::place_vertex(function, grid, edges[v], end_values[v], tolerance)
                };
                let simplified = simplify::simplify(&positions, &sizes, triangles, pinned, &place);
                let mut index = vec![u32::MAX; edges.len()];
                let mut next = 0;
                for (slot, &keep) in index.iter_mut().zip(&simplified.keep) {
                    if keep {
                        *slot = next;
                        next += 1;
                    }
                }
                let triangles = simplified
                    .triangles
                    .par_iter()
                    .map(|t| t.map(|v| index[v as usize]))
                    .collect();
                let edge_of = (0..edges.len() as u32)
                    .filter(|&e| simplified.keep[e as usize])
                    .collect();
                (simplified.results, triangles, edge_of)
            }
        };
    let mut mesh = TriangleMesh {
        positions: vertices.iter().map(|v| v.position).collect(),
        normals: vertices.iter().map(|v| v.normal).collect(),
        triangles,
    };
    // Step 7, when asked for: the curved edges split, their new vertices (from index `coarse`
    // on) projected onto the zero set.
    let coarse = vertices.len();
    let mut parents: Vec<[u32; 2]> = Vec::new();
    if let Some(sagitta) = refine {
        let refined = refine::refine(function, &mesh, sagitta, tolerance);
        mesh.positions
            .extend(refined.vertices.iter().map(|v| v.position));
        mesh.normals
            .extend(refined.vertices.iter().map(|v| v.normal));
        mesh.triangles = refined.triangles;
        vertices.extend(refined.vertices);
        parents = refined.parents;
    }
    let parents_of = |v: usize| (v >= coarse).then(|| parents[v - coarse]);
    // Step 6 first, when asked for: the vertices start off the zero set by a share of their
    // chord error, and step 5 tests those positions.
    if let Some(share) = chords {
        mesh.positions = chords::chord_positions(&mesh, share);
    }
    // Step 5: the projection (step 4) moves vertices off their lattice edges, by up to a few
    // cells where ∇f turns, and can push a triangle through its neighbours. Every vertex of a
    // triangle that crosses another goes one fallback further: from its chord position (step 6)
    // back to its projection, then to its own lattice edge, at the root of f there (still on
    // the zero set); should a crossing remain with all its vertices there (an edge collapse
    // judged on the linearly interpolated positions), they go to that linear interpolation, the
    // geometry the collapses were checked on. Rounds repeat until no triangle crosses another
    // or every vertex involved is at its last fallback. Deterministic: the crossing test is
    // exact and each fallback position a function of the vertex's edge alone.
    let first = if chords.is_some() {
        Fallback::Chord
    } else {
        Fallback::Projected
    };
    let mut level = vec![first; vertices.len()];
    let mut changed: Option<Vec<bool>> = None;
    // Whether some round saw a crossing triangle with every vertex at its last fallback.
    let mut stuck = false;
    loop {
        // The first round tests every pair, the next ones only the pairs with a triangle whose
        // vertex moved (the others cannot have changed).
        let flags = crate::mesh::intersecting_triangles_among(&mesh, changed.as_deref());
        stuck |= flags
            .iter()
            .zip(&mesh.triangles)
            .any(|(&f, t)| f && t.iter().all(|&v| level[v as usize] == Fallback::Linear));
        let mut moved: Vec<u32> = flags
            .iter()
            .zip(&mesh.triangles)
            .filter(|&(&f, _)| f)
            .flat_map(|(_, t)| *t)
            .filter(|&v| level[v as usize] != Fallback::Linear)
            .collect();
        moved.sort_unstable();
        moved.dedup();
        if moved.is_empty() {
            break;
        }
        let placed: Vec<Option<extract::PlacedVertex>> = moved
            .par_iter()
            .map(|&v| {
                if v as usize >= coarse {
                    // A new vertex: back to its projection, then (below) to its edge's midpoint.
                    return None;
                }
                let e = edge_of[v as usize] as usize;
                let on_edge =
                    || extract::place_on_edge(function, grid, edges[e], end_values[e], tolerance);
                match level[v as usize] {
                    Fallback::Chord => None,
                    Fallback::Projected => Some(on_edge()),
                    Fallback::EdgeRoot | Fallback::Linear => Some(extract::place_linear(
                        function,
                        grid,
                        edges[e],
                        end_values[e],
                        on_edge(),
                    )),
                }
            })
            .collect();
        for (&v, p) in moved.iter().zip(placed) {
            let v = v as usize;
            if let Some(p) = p {
                let spent = vertices[v].evaluations + p.evaluations;
                vertices[v] = extract::PlacedVertex {
                    evaluations: spent,
                    ..p
                };
                mesh.normals[v] = p.normal;
            }
            // Back to the projection from the chord position, or to the new placement.
            mesh.positions[v] = vertices[v].position;
            level[v] = match (level[v], parents_of(v)) {
                (Fallback::Projected, Some(_)) => Fallback::Linear,
                (l, _) => l.next(),
            };
        }
        // The new vertices at their last fallback sit at the midpoint of their edge's ends,
        // wherever those are now: the pieces of a split triangle then lie in its plane.
        if !parents.is_empty() {
            let mut followed = Vec::new();
            for v in coarse..vertices.len() {
                if level[v] != Fallback::Linear {
                    continue;
                }
                let [a, b] = parents[v - coarse].map(|p| mesh.positions[p as usize]);
                let at = refine::midpoint(a, b);
                if at != mesh.positions[v] || vertices[v].position != at {
                    let (value, gradient) = function.value_gradient(at);
                    vertices[v].position = at;
                    vertices[v].residual = extract::residual(value, crate::vec3::norm(gradient));
                    vertices[v].evaluations += 1;
                    mesh.positions[v] = at;
                    followed.push(v as u32);
                }
            }
            if !followed.is_empty() {
                moved.extend(followed);
                moved.sort_unstable();
                moved.dedup();
            }
        }
        changed = Some(
            mesh.triangles
                .par_iter()
                .map(|t| t.iter().any(|&v| moved.binary_search(&v).is_ok()))
                .collect(),
        );
    }
    // A stuck crossing may have been resolved by a neighbour's later move: one full test says.
    let mut stuck_vertices = Vec::new();
    if stuck {
        let flags = crate::mesh::intersecting_triangles_among(&mesh, None);
        stuck_vertices = flags
            .iter()
            .zip(&mesh.triangles)
            .filter(|&(&f, _)| f)
            .flat_map(|(_, t)| {
                t.iter().flat_map(|&v| match parents_of(v as usize) {
                    Some(ends) => ends.to_vec(),
                    None => vec![v],
                })
            })
            .map(|v| edge_of[v as usize])
            .collect();
        stuck_vertices.sort_unstable();
        stuck_vertices.dedup();
    }
    Repaired {
        vertices,
        mesh,
        crossings_left: !stuck_vertices.is_empty(),
        stuck: stuck_vertices,
        added: parents.len(),
    }
}
