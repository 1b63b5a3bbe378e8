//! Stage `normals`: [`PointCloud`] → [`Normals`] (an [`OrientedCloud`] with unit outward normals).
//!
//! Input: a scan's points, optionally with the file's normals and triangles. Output: the same
//! points in the same order (duplicates kept, each given the normal of its first occurrence), each
//! with a unit normal pointing out of the object, plus the crust triangulation when it was used.
//!
//! Invariants: `cloud.points == input.points`; every normal is finite and unit length; the output
//! depends only on the input and [`NormalsParams`] (not on the thread count).
//!
//! # Method (Sahin & Unel 2008, sections 5.1 and 5.2)
//!
//! ```text
//! points ─dedupe─▶ Delaunay(P) ─poles─▶ Delaunay(P ∪ poles) ─faces with 3 samples─▶ crust
//!        crust fans ─right-hand rule, area-weighted─▶ point normals (plane fit where ill-structured)
//!        ─MST propagation over 1 − |nᵢ·nⱼ|─▶ consistent signs ─farthest points vote─▶ outward
//! ```
//!
//! 1. `crust`: the crust of Amenta, Bern & Kamvysselis (1998): the Voronoi poles of each sample
//!    (the farthest vertex of its Voronoi cell, and the farthest on the other side), the Delaunay
//!    tetrahedralization (`delaunay`) of the samples and the poles, and the triangles whose three
//!    vertices are samples.
//! 2. Each sample's incident crust triangles are aligned (by the right-hand rule along a planar
//!    fan, or with the Voronoi pole vector where sliver tetrahedra make the fan non-planar) and
//!    summed with Max's (1999) weights. An ill-structured fan (empty, triangles more than
//!    [`NormalsParams::max_fan_angle_deg`] apart, or on data that is noisy at the fan's scale) is
//!    replaced by the normal of the least-squares plane through the point and its neighbours
//!    (`pca`): [`NormalsParams::k_neighbours`] of them, grown up to
//!    [`NormalsParams::max_k_neighbours`] where that makes the neighbourhood clearly flatter
//!    (noise).
//! 3. `orient`: signs are made consistent by propagation along a minimum spanning tree of the
//!    neighbour graph (crust edges, then k-nearest-neighbour edges) weighted by 1 − |nᵢ·nⱼ|
//!    (Hoppe et al. 1992), the robust form of the paper's "reference normal, dot product test,
//!    repeat from each aligned point". Each connected piece is then turned outward: at the point
//!    farthest from any centre the outward normal points away from that centre, and the farthest
//!    points of the piece vote.
//!
//! The other sources ([`NormalSource`]) skip steps 1–2: `pca` uses the adaptive plane fits everywhere, `mesh`
//! the area-weighted normals of the file's faces after making their winding consistent, `input`
//! the file's normals.

pub(crate) mod crust;
pub(crate) mod delaunay;
pub(crate) mod faces;
mod noise;
pub(crate) mod orient;
pub(crate) mod pca;

pub use noise::{estimate_noise, NoiseEstimate};

use std::borrow::Cow;
use std::str::FromStr;

use rayon::prelude::*;

use crate::cloud::{OrientedCloud, PointCloud};

/// Most points `auto` gives crust normals when the cloud has neither normals nor faces; a larger
/// cloud gets plane fits (`pca`). The crust's two tetrahedralizations grow to gigabytes and
/// about a minute a million points, plane fits to a tenth of that memory and seconds, and on
/// dense data the two give the same surface (figures in CHANGELOG.md and docs/ARCHITECTURE.md).
pub(crate) const AUTO_CRUST_MAX: usize = 200_000;

/// Errors of the normals stage.
#[derive(Debug, thiserror::Error)]
pub enum NormalsError {
    /// Fewer distinct points than a surface needs.
    #[error("the cloud has {n_points} distinct points, at least {min} are needed")]
    TooFewPoints {
        /// Distinct points found.
        n_points: usize,
        /// Minimum required.
        min: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error("point {index} has a non-finite coordinate; remove it from the input")]
    NonFinitePoint {
        /// Index of the first bad point.
        index: usize,
    },
    /// All points lie on one line.
    #[error("all points lie on one line, so they bound no surface; use a 3D scan")]
    Collinear,
    /// All points lie in one plane.
    #[error("all points lie in one plane, so they bound no volume; use a 3D scan")]
    Coplanar,
    /// More points than the 32-bit indices allow.
    #[error("the cloud has {n_points} points, more than this stage supports; subsample it")]
    TooManyPoints {
        /// Points in the input.
        n_points: usize,
    },
    /// `--normals input` on a file without normals.
    #[error("the input has no normals; choose another normal source (crust, pca or mesh)")]
    NoInputNormals,
    /// The number of normals does not match the number of points.
    #[error("the input has {n_normals} normals for {n_points} points; fix the file or choose another normal source")]
    NormalCountMismatch {
        /// Normals in the input.
        n_normals: usize,
        /// Points in the input.
        n_points: usize,
    },
    /// `--normals mesh` on a file without faces.
    #[error("the input has no faces; choose another normal source (crust or pca)")]
    NoMeshFaces,
    /// `--normals mesh` on a file whose faces all have zero area (corners that coincide or lie
    /// on one line).
    #[error("all {n_faces} faces of the input are degenerate (their corners coincide or lie on one line), so they give no normals; choose another normal source (crust or pca)")]
    DegenerateFaces {
        /// Faces in the input.
        n_faces: usize,
    },
    /// A triangle refers to a point that does not exist.
    #[error("triangle {index} refers to a point index out of range; fix the file or choose another normal source")]
    BadTriangle {
        /// Index of the first bad triangle.
        index: usize,
    },
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    InvalidParams(String),
}

/// Where the normals come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum NormalSource {
    /// `input` when the file has normals, else `mesh` when it has faces (not all degenerate),
    /// else `crust` for at most `AUTO_CRUST_MAX` points and `pca` for more or for noisy
    /// points (`NoiseEstimate::is_noisy`) (with a warning when the faces were all degenerate,
    /// the cloud is too large for the crust or the noise too strong for it; falling back to
    /// `pca` with a warning where the crust fails).
    #[default]
    Auto,
    /// Crust (Voronoi/Delaunay) triangulation, paper section 5.
    Crust,
    /// k-nearest-neighbour plane fits.
    Pca,
    /// The input mesh's own faces.
    Mesh,
    /// The file's normals.
    Input,
}

impl NormalSource {
    /// The name used on the command line: `auto`, `crust`, `pca`, `mesh` or `input`.
    ///
    /// ```
    /// use stablesurf::normals::NormalSource;
    /// assert_eq!(NormalSource::Crust.as_str(), "crust");
    /// assert_eq!("pca".parse::<NormalSource>().unwrap(), NormalSource::Pca);
    /// ```
    pub fn as_str(self) -> &'static str {
        match self {
            NormalSource::Auto => "auto",
            NormalSource::Crust => "crust",
            NormalSource::Pca => "pca",
            NormalSource::Mesh => "mesh",
            NormalSource::Input => "input",
        }
    }
}

impl std::fmt::Display for NormalSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for NormalSource {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(NormalSource::Auto),
            "crust" => Ok(NormalSource::Crust),
            "pca" => Ok(NormalSource::Pca),
            "mesh" => Ok(NormalSource::Mesh),
            "input" => Ok(NormalSource::Input),
            other => Err(format!(
                "unknown normal source `{other}`; expected auto, crust, pca, mesh or input"
            )),
        }
    }
}

/// Parameters of the normals stage.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NormalsParams {
    /// Where the normals come from. Default: [`NormalSource::Auto`].
    pub source: NormalSource,
    /// Neighbours (besides the point itself) used by the plane fits and by the orientation
    /// graph. Default 16; raise it (24–48) for noisy scans.
    pub k_neighbours: usize,
    /// Largest neighbourhood of a plane fit. Where the data is noisy at the scale of
    /// `k_neighbours` points, plane fits double their neighbourhood while that makes them
    /// flatter, up to this many points (and such points use the plane fit, not the crust fan).
    /// Default 128; set it equal to `k_neighbours` for fixed neighbourhoods.
    pub max_k_neighbours: usize,
    /// Largest angle, in degrees, between a crust triangle's normal and the mean normal of the
    /// fan around a point before that fan counts as ill-structured (replaced by a plane fit).
    /// Default 40.
    pub max_fan_angle_deg: f64,
    /// With normals from a mesh's faces, add points with their face's normal on triangles that
    /// are large against the mesh's median edge (`faces::surface_samples`), after the input
    /// points. Default true.
    #[serde(default = "yes")]
    pub surface_samples: bool,
    /// The sensor's position in the input's coordinates: every normal, whatever its source, is
    /// turned to face it (n flipped where n·(v − p) < 0). Default `None` (left out of the cache
    /// key then, so keys of runs without it are unchanged). Without it, a cloud of registered
    /// scans ([`PointCloud::scans`], from an E57 file or a PCD's `VIEWPOINT`) turns each
    /// point's normal to face its own scan's scanner instead.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub viewpoint: Option<[f64; 3]>,
}

fn yes() -> bool {
    true
}

impl Default for NormalsParams {
    fn default() -> Self {
        NormalsParams {
            source: NormalSource::Auto,
            k_neighbours: 16,
            max_k_neighbours: 128,
            max_fan_angle_deg: 40.0,
            surface_samples: true,
            viewpoint: None,
        }
    }
}

/// The stage's result: the oriented cloud plus what was done.
#[derive(Clone, Debug, Default)]
pub struct Normals {
    /// Points with unit outward normals.
    pub cloud: OrientedCloud,
    /// The source actually used (never `Auto`).
    pub source_used: NormalSource,
    /// The crust triangulation when the crust was used (indices into the points).
    pub crust_triangles: Vec<[u32; 3]>,
    /// Messages for the user (for example a fallback from crust to pca).
    pub warnings: Vec<String>,
    /// Points added on large faces ([`NormalsParams::surface_samples`]), at the end of the cloud.
    pub surface_samples: usize,
}

/// Estimates unit outward normals.
///
/// # Errors
/// Fewer than 5 distinct points, a non-finite coordinate, all points on a line or in a plane,
/// or a source that the input cannot serve (`input` without normals, `mesh` without faces or
/// with degenerate faces only).
///
/// ```
/// use stablesurf::normals::{estimate_normals, NormalSource, NormalsParams};
/// use stablesurf::PointCloud;
/// // 200 points on the unit sphere (a Fibonacci spiral).
/// let n = 200;
/// let points: Vec<[f64; 3]> = (0..n)
///     .map(|i| {
///         let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
///         let r = (1.0 - z * z).sqrt();
///         let a = i as f64 * 2.399_963_229_728_653;
///         [r * a.cos(), r * a.sin(), z]
///     })
///     .collect();
/// let cloud = PointCloud { points: points.clone(), ..Default::default() };
/// let params = NormalsParams { source: NormalSource::Crust, ..Default::default() };
/// let out = estimate_normals(&cloud, &params).unwrap();
/// for (p, n) in points.iter().zip(&out.cloud.normals) {
///     assert!(p[0] * n[0] + p[1] * n[1] + p[2] * n[2] > 0.95); // outward, close to radial
/// }
/// ```
pub fn estimate_normals(
    cloud: &PointCloud,
    params: &NormalsParams,
) -> Result<Normals, NormalsError> {
    estimate(Cow::Borrowed(cloud), params)
}

/// [`estimate_normals`] of a cloud given away: the result holds the cloud's own arrays (its
/// points, and its normals normalized in place when they are the source), so no array of the
/// cloud's size is copied.
///
/// # Errors
/// As [`estimate_normals`].
pub fn estimate_normals_owned(
    cloud: PointCloud,
    params: &NormalsParams,
) -> Result<Normals, NormalsError> {
    estimate(Cow::Owned(cloud), params)
}

/// The source `auto` takes for `points` without normals or faces: the crust, or plane fits
/// (`pca`) beyond [`AUTO_CRUST_MAX`] points or on noisy points ([`NoiseEstimate::is_noisy`]),
/// with the note that says so. The crust interpolates the points, so on noisy ones its fans
/// follow the noise (and most of them fall back to plane fits anyway): plane fits give as good
/// a surface in a sixth of the time (docs/defaults.md, "Noise").
fn bare_points_source(points: &[[f64; 3]]) -> (NormalSource, Option<String>) {
    let n = points.len();
    if n > AUTO_CRUST_MAX {
        let note = format!(
            "{n} points without normals or faces: normals from k-nearest plane fits (pca); the crust (--normals crust) costs about a minute and 4 GB a million points, so auto uses it up to {AUTO_CRUST_MAX} points"
        );
        return (NormalSource::Pca, Some(note));
    }
    match estimate_noise(points) {
        Some(noise) if noise.is_noisy() => {
            let note = format!(
                "points without normals or faces, with noise measured at {:.2} x their spacing: normals from plane fits (pca), since the crust (--normals crust) would follow the noise above {} x",
                noise.relative_to_spacing(),
                noise::NOISY_SPACING
            );
            (NormalSource::Pca, Some(note))
        }
        _ => (NormalSource::Crust, None),
    }
}

/// The normals stage on a borrowed or an owned cloud (an owned one's arrays are reused).
fn estimate(
    mut cloud: Cow<'_, PointCloud>,
    params: &NormalsParams,
) -> Result<Normals, NormalsError> {
    if params.k_neighbours < 3 || params.k_neighbours > 1000 {
        return Err(NormalsError::InvalidParams(format!(
            "k_neighbours is {}, choose a value between 3 and 1000",
            params.k_neighbours
        )));
    }
    if params.max_k_neighbours < params.k_neighbours || params.max_k_neighbours > 4096 {
        return Err(NormalsError::InvalidParams(format!(
            "max_k_neighbours is {}, choose a value between k_neighbours ({}) and 4096",
            params.max_k_neighbours, params.k_neighbours
        )));
    }
    if !(params.max_fan_angle_deg > 0.0 && params.max_fan_angle_deg <= 180.0) {
        return Err(NormalsError::InvalidParams(format!(
            "max_fan_angle_deg is {}, choose a value in (0, 180]",
            params.max_fan_angle_deg
        )));
    }
    if let Some(v) = params
        .viewpoint
        .filter(|v| !v.iter().all(|c| c.is_finite()))
    {
        return Err(NormalsError::InvalidParams(format!(
            "the viewpoint {v:?} is not finite; give three finite coordinates"
        )));
    }
    if cloud.points.len() >= (u32::MAX / 4) as usize {
        return Err(NormalsError::TooManyPoints {
            n_points: cloud.points.len(),
        });
    }
    delaunay::check_spans_3d(&cloud.points)?;
    let has_input_normals = cloud.normals.as_ref().is_some_and(|n| !n.is_empty());
    // Why `auto` took plane fits instead of the crust, when it did.
    let mut auto_note = None;
    let mut source = match params.source {
        NormalSource::Auto => {
            if has_input_normals {
                NormalSource::Input
            } else if !cloud.triangles.is_empty() {
                NormalSource::Mesh
            } else {
                let (source, note) = bare_points_source(&cloud.points);
                auto_note = note;
                source
            }
        }
        s => s,
    };
    // The given normals: taken from an owned cloud (before the points are borrowed below),
    // borrowed from a borrowed one.
    let given: Option<Cow<'_, [[f64; 3]]>> = match (source, &mut cloud) {
        (NormalSource::Input, Cow::Owned(c)) => c.normals.take().map(Cow::Owned),
        (NormalSource::Input, Cow::Borrowed(c)) => {
            let c: &PointCloud = c;
            c.normals.as_deref().map(Cow::Borrowed)
        }
        _ => None,
    };
    let dedup = Dedup::new(&cloud.points);
    let mut warnings = Vec::new();
    // The faces, remapped to the distinct points, when they are the source. Faces whose
    // corners all coincide or lie on one line give no normal: if every face is such, `auto`
    // turns to the crust and `mesh` says so.
    let mut faces = Vec::new();
    if source == NormalSource::Mesh {
        faces = dedup.remap_triangles(&cloud.triangles)?;
        if !faces.is_empty() && !faces.iter().any(|t| has_area(&dedup.unique, t)) {
            if params.source != NormalSource::Auto {
                return Err(NormalsError::DegenerateFaces {
                    n_faces: faces.len(),
                });
            }
            (source, auto_note) = bare_points_source(&cloud.points);
            warnings.push(format!(
                "all {} faces are degenerate (their corners coincide or lie on one line); normals from {} instead",
                faces.len(),
                if source == NormalSource::Crust { "the crust" } else { "plane fits" }
            ));
        }
    }
    warnings.extend(auto_note);
    let mut out = Normals {
        source_used: source,
        warnings,
        ..Default::default()
    };
    let mut samples = (Vec::new(), Vec::new());
    let unique_normals = match source {
        NormalSource::Crust | NormalSource::Auto => {
            match crust::crust_normals(&dedup.unique, params) {
                Ok(r) => {
                    out.warnings.extend(r.warnings);
                    out.crust_triangles = r
                        .triangles
                        .iter()
                        .map(|t| t.map(|v| dedup.first(v)))
                        .collect();
                    r.normals
                }
                Err(e) if params.source == NormalSource::Auto => {
                    out.warnings.push(format!(
                        "the crust failed ({e}); used pca plane fits instead"
                    ));
                    out.source_used = NormalSource::Pca;
                    pca::pca_normals(&dedup.unique, params)
                }
                Err(e) => return Err(e),
            }
        }
        NormalSource::Pca => pca::pca_normals(&dedup.unique, params),
        NormalSource::Mesh if cloud.range.is_some() => {
            // A range grid's triangles face the scanner by construction: keep their winding.
            let (normals, warnings) = faces::wound_normals(&dedup.unique, &faces, params);
            out.warnings.extend(warnings);
            normals
        }
        NormalSource::Mesh => {
            let mesh = faces::mesh_normals(&dedup.unique, &faces, params)?;
            out.warnings.extend(mesh.warnings);
            if params.surface_samples {
                samples = faces::surface_samples(&dedup.unique, &mesh.triangles);
            }
            mesh.normals
        }
        NormalSource::Input => {
            let given = given.ok_or(NormalsError::NoInputNormals)?;
            if given.is_empty() {
                return Err(NormalsError::NoInputNormals);
            }
            if given.len() != cloud.points.len() {
                return Err(NormalsError::NormalCountMismatch {
                    n_normals: given.len(),
                    n_points: cloud.points.len(),
                });
            }
            let unique_given = match &dedup.first {
                Some(first) => first.iter().map(|&i| given[i as usize]).collect(),
                None => given.into_owned(),
            };
            let (normals, warnings) = faces::input_normals(&dedup.unique, unique_given, params);
            out.warnings.extend(warnings);
            normals
        }
    };
    let mut normals = dedup.expand(unique_normals);
    drop(dedup);
    let n_input = cloud.points.len();
    let (mut points, cloud) = match cloud {
        Cow::Owned(mut c) => (std::mem::take(&mut c.points), Cow::Owned(c)),
        Cow::Borrowed(c) => (c.points.clone(), Cow::Borrowed(c)),
    };
    // Samples on large faces (a mesh, never a range grid) follow the input points.
    out.surface_samples = samples.0.len();
    points.extend(samples.0);
    normals.extend(samples.1);
    if let (None, Some(scans)) = (params.viewpoint, &cloud.scans) {
        // Each registered scan's points face their own scanner (the samples on faces that
        // follow the input points belong to no scan).
        let mut start = 0;
        for scan in scans {
            let end = (start + scan.n_points).min(n_input);
            toward_viewpoint(&points[start..end], &mut normals[start..end], scan.sensor);
            start = end;
        }
    }
    if let Some(v) = params.viewpoint {
        let flipped = toward_viewpoint(&points, &mut normals, v);
        if flipped > 0 {
            out.warnings.push(format!(
                "turned {flipped} of {} normals to face the viewpoint ({}, {}, {})",
                normals.len(),
                v[0],
                v[1],
                v[2]
            ));
        }
    }
    let weights = cloud
        .range
        .as_ref()
        .map(|r| confidence(&points[..n_input], &normals, r));
    out.cloud = OrientedCloud {
        points,
        normals,
        weights,
    };
    Ok(out)
}

/// Flips each normal `n` at `p` with n·(v − p) < 0, so that all face the viewpoint `v`.
/// Returns how many were flipped.
pub(crate) fn toward_viewpoint(
    points: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    v: [f64; 3],
) -> usize {
    let mut flipped = 0;
    for (p, n) in points.iter().zip(normals.iter_mut()) {
        if vec3::dot(n, &vec3::sub(&v, p)) < 0.0 {
            *n = n.map(|c| -c);
            flipped += 1;
        }
    }
    flipped
}

/// Smallest confidence a range sample gets (a zero would leave a local fit without rows).
pub(crate) const MIN_CONFIDENCE: f32 = 0.05;

/// Per point of a range scan, the confidence of its sample: the cosine between its normal and
/// the direction to the sensor (1 without a sensor) times its falloff near the scan's edge,
/// at least [`MIN_CONFIDENCE`].
pub(crate) fn confidence(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    range: &crate::cloud::RangeSurface,
) -> Vec<f32> {
    points
        .iter()
        .zip(normals)
        .enumerate()
        .map(|(i, (p, n))| {
            let cos = range.sensor.map_or(1.0, |s| {
                let d = vec3::sub(&s, p);
                let l = vec3::norm(&d) * vec3::norm(n);
                if l > 0.0 {
                    (vec3::dot(n, &d) / l).abs()
                } else {
                    1.0
                }
            });
            let falloff = range.falloff.get(i).copied().unwrap_or(1.0);
            (cos as f32 * falloff).max(MIN_CONFIDENCE)
        })
        .collect()
}

/// Whether triangle `t` (indices into `points`) has an area: its corners are distinct and not on
/// one line (the sine of its angle at the first corner above 1e-12, so that corners that are
/// collinear up to rounding count as collinear).
fn has_area(points: &[[f64; 3]], t: &[u32; 3]) -> bool {
    let [a, b, c] = t.map(|v| points[v as usize]);
    let (u, w) = (vec3::sub(&b, &a), vec3::sub(&c, &a));
    vec3::norm(&vec3::cross(&u, &w)) > 1e-12 * vec3::norm(&u) * vec3::norm(&w)
}

/// The distinct points of a cloud, in order of first occurrence. A cloud without repeated
/// points (the usual case, and the one that matters at scale) is borrowed as it is, with no
/// index maps.
struct Dedup<'a> {
    /// Distinct points.
    unique: Cow<'a, [[f64; 3]]>,
    /// For each distinct point, the index of its first occurrence in the input; `None` when
    /// every point is distinct (the identity).
    first: Option<Vec<u32>>,
    /// For each input point, its index in `unique`; `None` when every point is distinct.
    of_point: Option<Vec<u32>>,
}

impl<'a> Dedup<'a> {
    fn new(points: &'a [[f64; 3]]) -> Dedup<'a> {
        // `+ 0.0` turns -0.0 into 0.0 so that both compare equal, as they do as numbers.
        let key = |i: usize| points[i].map(|c| (c + 0.0).to_bits());
        let hashes: Vec<u64> = (0..points.len())
            .into_par_iter()
            .map(|i| mix(key(i)))
            .collect();
        // Equal points have equal hashes, so every group of twins falls into one bucket of the
        // hash's high bits. The buckets list their points in index order (a stable counting
        // sort), and each bucket is swept in that order through a small open-addressing table
        // of the points seen so far: a point equal to one in the table is a twin of it, which
        // is its first occurrence (a twin is never inserted).
        let bits = bucket_bits(points.len());
        let bucket = |h: u64| {
            if bits == 0 {
                0
            } else {
                (h >> (64 - bits)) as usize
            }
        };
        let mut start = vec![0u32; (1 << bits) + 1];
        for &h in &hashes {
            start[bucket(h) + 1] += 1;
        }
        for b in 0..1 << bits {
            start[b + 1] += start[b];
        }
        let mut order = vec![(0u64, 0u32); points.len()];
        let mut next = start.clone();
        for (i, &h) in hashes.iter().enumerate() {
            let slot = &mut next[bucket(h)];
            order[*slot as usize] = (h, i as u32);
            *slot += 1;
        }
        drop((next, hashes));
        // (point, its first occurrence) for every repeated point, in no particular order.
        let twins: Vec<(u32, u32)> = start
            .par_windows(2)
            .fold(
                || (Vec::<(u64, u32)>::new(), Vec::<(u32, u32)>::new()),
                |(mut table, mut twins), w| {
                    let members = &order[w[0] as usize..w[1] as usize];
                    let size = (2 * members.len()).next_power_of_two();
                    table.clear();
                    table.resize(size, (0, u32::MAX));
                    let mask = size - 1;
                    for &(h, i) in members {
                        let mut slot = h as usize & mask;
                        loop {
                            let (hj, j) = table[slot];
                            if j == u32::MAX {
                                table[slot] = (h, i);
                                break;
                            }
                            if hj == h && key(j as usize) == key(i as usize) {
                                twins.push((i, j));
                                break;
                            }
                            slot = (slot + 1) & mask;
                        }
                    }
                    (table, twins)
                },
            )
            .map(|(_, twins)| twins)
            .reduce(Vec::new, |mut a, b| {
                a.extend(b);
                a
            });
        drop((order, start));
        if twins.is_empty() {
            return Dedup {
                unique: Cow::Borrowed(points),
                first: None,
                of_point: None,
            };
        }
        let mut first_of: Vec<u32> = (0..points.len() as u32).collect();
        for (i, f) in twins {
            first_of[i as usize] = f;
        }
        let mut unique = Vec::new();
        let mut first = Vec::new();
        let mut of_point = vec![0u32; points.len()];
        for i in 0..points.len() {
            if first_of[i] as usize == i {
                of_point[i] = unique.len() as u32;
                unique.push(points[i]);
                first.push(i as u32);
            } else {
                of_point[i] = of_point[first_of[i] as usize];
            }
        }
        Dedup {
            unique: Cow::Owned(unique),
            first: Some(first),
            of_point: Some(of_point),
        }
    }

    /// The input index of distinct point `u`'s first occurrence.
    fn first(&self, u: u32) -> u32 {
        self.first.as_ref().map_or(u, |f| f[u as usize])
    }

    /// One value per input point from one value per distinct point.
    fn expand<T: Copy>(&self, per_unique: Vec<T>) -> Vec<T> {
        match &self.of_point {
            Some(of_point) => of_point.iter().map(|&u| per_unique[u as usize]).collect(),
            None => per_unique,
        }
    }

    fn remap_triangles(&self, triangles: &[[u32; 3]]) -> Result<Vec<[u32; 3]>, NormalsError> {
        triangles
            .iter()
            .enumerate()
            .map(|(index, t)| {
                let mut r = [0u32; 3];
                for k in 0..3 {
                    let v = t[k] as usize;
                    if v >= self.n_points() {
                        return Err(NormalsError::BadTriangle { index });
                    }
                    r[k] = self.of_point.as_ref().map_or(v as u32, |o| o[v]);
                }
                Ok(r)
            })
            .collect()
    }

    /// How many input points there are.
    fn n_points(&self) -> usize {
        self.of_point.as_ref().map_or(self.unique.len(), Vec::len)
    }
}

/// How many high bits of the hash number the buckets of [`Dedup::new`] for `n` points: about a
/// thousand points per bucket, so that each bucket's table stays in the cache.
fn bucket_bits(n: usize) -> u32 {
    (n / 1024).max(1).ilog2().min(16)
}

/// A 64-bit mix of a point's coordinate bits (equal points, equal values), for [`Dedup`].
fn mix(k: [u64; 3]) -> u64 {
    let mut h = 0x9e37_79b9_7f4a_7c15u64;
    for c in k {
        h = (h ^ c).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        h ^= h >> 31;
    }
    h.wrapping_mul(0x94d0_49bb_1331_11eb) ^ (h >> 29)
}

/// The crate's vector helpers ([`crate::vec3`]) by reference, as the submodules call them, with
/// the few more they need.
pub(crate) mod vec3 {
    #[inline]
    pub(crate) fn sub(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
        crate::vec3::sub(*a, *b)
    }
    #[inline]
    pub(crate) fn add(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
        [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
    }
    #[inline]
    pub(crate) fn scale(a: &[f64; 3], s: f64) -> [f64; 3] {
        [a[0] * s, a[1] * s, a[2] * s]
    }
    #[inline]
    pub(crate) fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
        crate::vec3::dot(*a, *b)
    }
    #[inline]
    pub(crate) fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
        crate::vec3::cross(*a, *b)
    }
    #[inline]
    pub(crate) fn norm(a: &[f64; 3]) -> f64 {
        crate::vec3::norm(*a)
    }
    /// `a` scaled to unit length, or `None` when it is zero or not finite.
    #[inline]
    pub(crate) fn normalized(a: &[f64; 3]) -> Option<[f64; 3]> {
        let l = norm(a);
        (l > 0.0 && l.is_finite()).then(|| scale(a, 1.0 / l))
    }
    /// Normal (not normalised, length twice the area) of triangle `a, b, c` by the right-hand rule.
    #[inline]
    pub(crate) fn triangle_normal(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3]) -> [f64; 3] {
        cross(&sub(b, a), &sub(c, a))
    }
}

/// Point sets for the tests of this stage's modules.
#[cfg(test)]
pub(crate) mod test_support {
    /// `n` points of the unit sphere along a Fibonacci spiral (golden-angle steps in longitude,
    /// equal steps in z).
    pub(crate) fn fibonacci_sphere(n: usize) -> Vec<[f64; 3]> {
        (0..n)
            .map(|i| {
                let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let a = i as f64 * 2.399_963_229_728_653;
                [r * a.cos(), r * a.sin(), z]
            })
            .collect()
    }
}

#[cfg(test)]
mod tests;
