//! The noise level of a scan, measured: the scatter of its points across their local surface.
//!
//! Input: points (no normals needed). Output: a [`NoiseEstimate`], the median over a spatially
//! even sample of the points of each one's local estimate, with the 10% and 90% quantiles of
//! those estimates (how the noise varies from region to region).
//!
//! Method, at each sample point: its K nearest neighbours, K = 24, 48, 96, … up to
//! [`MAX_NEIGHBOURS`]; their principal frame (the least-variance direction as the height axis);
//! a quadric height field h(u, v) fitted to them by least squares, which takes the surface's
//! curvature out of the residuals; σ_K = √(RSS / (K − 6)), the residuals' standard deviation
//! with the fit's 6 unknowns discounted. The ball of K nearest points cuts the noisy slab
//! around the surface where its radius R is not large against σ: a point at height w is found
//! on a disc of squared radius R² − w², which weights the Gaussian by R² − w² and shrinks the
//! measured variance to σ²(R² − 3σ²)/(R² − σ²). The smallest K with R ≥ 4σ_K is taken (most
//! local: the least curvature left for the quadric), and the shrinkage is undone by solving
//! that relation for σ. On clean, smooth samples σ is of the order of the quadric's error at
//! K = 24 (a tiny share of the spacing); where the noise is larger than the spacing, K grows
//! until the ball spans the slab.
//!
//! The median makes the figure robust to the minority of samples on creases, edges and
//! thin parts, where a quadric does not fit at any scale.
//!
//! Invariants: the result depends only on the points (fixed sample, fixed order, sequential
//! reductions over results collected in order), not on the thread count.

use nalgebra::{Matrix3, SymmetricEigen};
use rayon::prelude::*;

use crate::numerics::{cholesky, PointGrid};

/// Points sampled for the estimate: every k-th along the grid's order, at most this many.
const SAMPLES: usize = 4096;

/// A larger cloud is measured on every k-th of its points, at most this many: a local fit
/// needs a few hundred points across the noise, not the scan's full density, and the
/// neighbour grid of ten million points would cost more than the estimate.
const POINTS_MAX: usize = 250_000;

/// The first neighbourhood's size; each next scale doubles it.
const FIRST_NEIGHBOURS: usize = 24;

/// The largest neighbourhood tried (its estimate is kept even when its ball is still thin).
pub(crate) const MAX_NEIGHBOURS: usize = 768;

/// The ball's radius must reach this many σ for the estimate at that scale to be kept.
const REACH_IN_SIGMAS: f64 = 4.0;

/// The measured noise of a cloud (input units).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NoiseEstimate {
    /// The median of the samples' estimates of the standard deviation of the points across the
    /// surface.
    pub sigma: f64,
    /// The 10% quantile of the samples' estimates (the cleaner regions).
    pub sigma_low: f64,
    /// The 90% quantile of the samples' estimates (the noisier regions).
    pub sigma_high: f64,
    /// The median distance from a sample to its nearest other point (the sampling's scale;
    /// of a cloud thinned for the estimate, that distance over √k for every k-th point kept).
    pub spacing: f64,
    /// The median number of neighbours the samples' estimates used.
    pub neighbours: usize,
    /// Samples measured.
    pub samples: usize,
}

/// Noise above this share of the points' spacing is noise to average rather than shape to
/// follow ([`NoiseEstimate::is_noisy`]). Below it the figure is mostly the surface's own relief
/// at the scale of a few spacings, which a quadric over 24 points does not take out; the
/// clean and noisy samples this threshold separates are in docs/defaults.md, "Noise".
pub(crate) const NOISY_SPACING: f64 = 0.5;

impl NoiseEstimate {
    /// Whether σ exceeds [`NOISY_SPACING`] × the spacing: the points scatter across their
    /// surface by more than half the distance between neighbours.
    pub(crate) fn is_noisy(&self) -> bool {
        self.relative_to_spacing() > NOISY_SPACING
    }

    /// σ over the sample spacing: below about 0.3 the points sit on their surface to within a
    /// fraction of their spacing (a clean scan); above 1 each point's neighbours are scattered
    /// across the surface further than they are spread along it.
    pub fn relative_to_spacing(&self) -> f64 {
        if self.spacing > 0.0 {
            self.sigma / self.spacing
        } else {
            0.0
        }
    }
}

/// Measures the noise of `points` (distinct or not; coincident points are measured as one
/// sample each). `None` when there are fewer than 25 points or a
/// coordinate is not finite.
///
/// ```
/// use stablesurf::normals::estimate_noise;
/// use stablesurf::testing::study::Lcg;
/// // A unit sphere of 20,000 points, moved along their radius by Gaussian noise of σ = 0.01.
/// let mut rng = Lcg::new(3);
/// let points: Vec<[f64; 3]> = (0..20_000)
///     .map(|_| {
///         let d = [rng.normal(), rng.normal(), rng.normal()];
///         let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
///         let s = (1.0 + 0.01 * rng.normal()) / r;
///         d.map(|c| c * s)
///     })
///     .collect();
/// let noise = estimate_noise(&points).unwrap();
/// assert!((noise.sigma / 0.01 - 1.0).abs() < 0.15, "{}", noise.sigma);
/// ```
pub fn estimate_noise(points: &[[f64; 3]]) -> Option<NoiseEstimate> {
    if points.len() <= FIRST_NEIGHBOURS {
        return None;
    }
    let thin = points.len().div_ceil(POINTS_MAX);
    let thinned: Vec<[f64; 3]>;
    let points = if thin > 1 {
        thinned = points.iter().step_by(thin).copied().collect();
        &thinned[..]
    } else {
        points
    };
    let grid = PointGrid::new(points)?;
    let step = points.len().div_ceil(SAMPLES);
    let samples: Vec<usize> = grid
        .order()
        .iter()
        .step_by(step)
        .map(|&i| i as usize)
        .collect();
    let max_k = MAX_NEIGHBOURS.min(points.len() - 1);
    let per_sample: Vec<Option<(f64, f64, usize)>> = samples
        .par_iter()
        .map_init(
            || (Vec::new(), Vec::new()),
            |(keys, near), &i| {
                near.clear();
                grid.nearest_into(points, i, max_k, 0.0, keys, near);
                sample_estimate(points, i, near)
            },
        )
        .collect();
    let mut sigmas = Vec::with_capacity(per_sample.len());
    let mut spacings = Vec::with_capacity(per_sample.len());
    let mut ks = Vec::with_capacity(per_sample.len());
    for (sigma, spacing, k) in per_sample.into_iter().flatten() {
        sigmas.push(sigma);
        spacings.push(spacing);
        ks.push(k);
    }
    if sigmas.is_empty() {
        return None;
    }
    let quantile = |v: &mut Vec<f64>, q: f64| {
        v.sort_by(f64::total_cmp);
        v[((v.len() - 1) as f64 * q).round() as usize]
    };
    ks.sort_unstable();
    Some(NoiseEstimate {
        sigma: quantile(&mut sigmas, 0.5),
        sigma_low: quantile(&mut sigmas, 0.1),
        sigma_high: quantile(&mut sigmas, 0.9),
        // Thinned by k, the points lie √k times as far apart on a surface.
        spacing: quantile(&mut spacings, 0.5) / (thin as f64).sqrt(),
        neighbours: ks[ks.len() / 2],
        samples: sigmas.len(),
    })
}

/// One sample's estimate: σ, its spacing (distance to its nearest other point) and the number
/// of neighbours used; `near` lists its nearest points, nearest first.
fn sample_estimate(points: &[[f64; 3]], i: usize, near: &[u32]) -> Option<(f64, f64, usize)> {
    let centre = points[i];
    let offset = |j: u32| {
        let p = points[j as usize];
        [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]]
    };
    let spacing = near
        .iter()
        .map(|&j| norm(offset(j)))
        .find(|&d| d > 0.0)
        .unwrap_or(0.0);
    let mut k = FIRST_NEIGHBOURS;
    let mut last = None;
    while k <= near.len() {
        let ball = &near[..k];
        let radius = norm(offset(ball[k - 1]));
        if let Some(measured) = quadric_scatter(points, centre, ball) {
            last = Some((unshrink(measured, radius), k));
            if radius >= REACH_IN_SIGMAS * measured {
                break;
            }
        }
        if k == near.len() {
            break;
        }
        k = (2 * k).min(near.len());
    }
    last.map(|(sigma, k)| (sigma, spacing, k))
}

/// σ from the standard deviation `measured` in a ball of radius `radius`: the root of
/// measured² = σ²(R² − 3σ²)/(R² − σ²) below R/√3 (see the module docs); `measured` itself when
/// the relation has no root (a ball too thin for the correction to be trusted).
fn unshrink(measured: f64, radius: f64) -> f64 {
    let (e, r2) = (measured * measured, radius * radius);
    let b = r2 + e;
    let disc = b * b - 12.0 * e * r2;
    if disc.is_nan() || disc < 0.0 || r2 <= 0.0 {
        return measured;
    }
    // The smaller root of 3x² − bx + e·R² = 0, written to avoid cancellation.
    let x = 2.0 * e * r2 / (b + disc.sqrt());
    x.sqrt()
}

/// The residuals' standard deviation of the quadric height field fitted to `ball` (offsets
/// from `centre`) in its principal frame, with the fit's 6 unknowns discounted.
fn quadric_scatter(points: &[[f64; 3]], centre: [f64; 3], ball: &[u32]) -> Option<f64> {
    let k = ball.len();
    if k <= 6 {
        return None;
    }
    let d: Vec<[f64; 3]> = ball
        .iter()
        .map(|&j| {
            let p = points[j as usize];
            [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]]
        })
        .collect();
    let mut mean = [0.0; 3];
    for q in &d {
        for a in 0..3 {
            mean[a] += q[a] / k as f64;
        }
    }
    let mut cov: Matrix3<f64> = Matrix3::zeros();
    for q in &d {
        for r in 0..3 {
            for c in 0..3 {
                cov[(r, c)] += (q[r] - mean[r]) * (q[c] - mean[c]);
            }
        }
    }
    let eigen = SymmetricEigen::new(cov);
    let mut axes: Vec<usize> = (0..3).collect();
    axes.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let axis = |a: usize| {
        let v = eigen.eigenvectors.column(axes[a]);
        [v[0], v[1], v[2]]
    };
    let (w_axis, u_axis, v_axis) = (axis(0), axis(2), axis(1));
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    // Scaled so the normal equations are well conditioned whatever the units.
    let scale = eigen.eigenvalues[axes[2]].sqrt() / (k as f64).sqrt();
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    let rows: Vec<([f64; 6], f64)> = d
        .iter()
        .map(|q| {
            let c = [q[0] - mean[0], q[1] - mean[1], q[2] - mean[2]];
            let (u, v, w) = (
                dot(c, u_axis) / scale,
                dot(c, v_axis) / scale,
                dot(c, w_axis),
            );
            ([1.0, u, v, u * u, u * v, v * v], w)
        })
        .collect();
    let mut ata = [0.0; 36];
    let mut atb = [0.0; 6];
    for (m, w) in &rows {
        for r in 0..6 {
            atb[r] += m[r] * w;
            for c in 0..=r {
                ata[r * 6 + c] += m[r] * m[c];
            }
        }
    }
    let trace: f64 = (0..6).map(|r| ata[r * 7]).sum();
    cholesky::factor(&mut ata, 6, 1e-12 * trace).ok()?;
    cholesky::solve(&ata, 6, &mut atb);
    let rss: f64 = rows
        .iter()
        .map(|(m, w)| {
            let fit: f64 = m.iter().zip(&atb).map(|(a, b)| a * b).sum();
            (w - fit) * (w - fit)
        })
        .sum();
    Some((rss / (k - 6) as f64).sqrt())
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::numerics::Lcg;

    /// `n` points of a 2 × 2 square in z = 0 (or of a sphere of radius 1 when `sphere`), moved
    /// across it by Gaussian noise of `sigma`.
    fn noisy(n: usize, sigma: f64, sphere: bool, seed: u64) -> Vec<[f64; 3]> {
        let mut rng = Lcg::new(seed);
        (0..n)
            .map(|_| {
                if sphere {
                    let d = [rng.normal(), rng.normal(), rng.normal()];
                    let r = norm(d);
                    let s = (1.0 + sigma * rng.normal()) / r;
                    d.map(|c| c * s)
                } else {
                    let u = 2.0 * rng.uniform() - 1.0;
                    let v = 2.0 * rng.uniform() - 1.0;
                    [u, v, sigma * rng.normal()]
                }
            })
            .collect()
    }

    #[test]
    fn the_added_noise_is_measured_within_fifteen_percent() {
        // Spacing of 20k points on the unit sphere: about 0.025; σ from a fifth of it to
        // four times it.
        for (sigma, sphere) in [
            (0.005, true),
            (0.01, true),
            (0.02, true),
            (0.05, true),
            (0.01, false),
            (0.04, false),
        ] {
            let noise = estimate_noise(&noisy(20_000, sigma, sphere, 11)).unwrap();
            let ratio = noise.sigma / sigma;
            assert!(
                (0.85..=1.15).contains(&ratio),
                "sigma {sigma} sphere {sphere}: measured {} ({ratio:.3}x), k {}",
                noise.sigma,
                noise.neighbours
            );
            assert!(noise.sigma_low <= noise.sigma && noise.sigma <= noise.sigma_high);
        }
    }

    #[test]
    fn clean_curved_samples_measure_almost_no_noise() {
        let points = noisy(20_000, 0.0, true, 5);
        let noise = estimate_noise(&points).unwrap();
        assert!(noise.relative_to_spacing() < 0.01, "{noise:?}");
    }

    #[test]
    fn the_estimate_does_not_depend_on_the_thread_count() {
        let points = noisy(5_000, 0.01, true, 2);
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| estimate_noise(&points));
        assert_eq!(one, estimate_noise(&points));
    }
}
