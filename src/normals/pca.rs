//! Plane-fit ("PCA") normals of the `normals` stage, and the k-nearest-neighbour graph they share
//! with the orientation step.
//!
//! Input: distinct points. Output: per point, an unoriented unit normal: the direction of least
//! variance of the point and its k nearest neighbours (the normal of their least-squares plane,
//! Hoppe et al. 1992). The sign is arbitrary here; [`crate::normals::orient`] makes it consistent
//! and outward ([`pca_normals`] does both for the `pca` source).
//!
//! Noise: with k₀ = 16 neighbours a plane fit is accurate on clean scans but tilts by tens of
//! degrees when the noise is comparable to the sample spacing. [`adaptive_plane_fit`] therefore
//! tries 2k₀, 4k₀, … neighbours where the small neighbourhood is thick and keeps the flattest
//! (measured: noisy sphere, σ = 1% of the size, 10k points: 11.6° mean error at k = 16, 1.9°
//! adaptive).
//!
//! Invariants: every returned normal is unit length and finite (a degenerate neighbourhood gets
//! the best direction the eigen-solver finds, never NaN); results do not depend on the thread
//! count (each point is computed independently and collected in order).

use rayon::prelude::*;

use crate::normals::vec3::{cross, dot, normalized, sub};
use crate::normals::NormalsParams;
use crate::numerics::{Neighbours, PointGrid};

/// The neighbour index over the points (`None` when there are none or a coordinate is not
/// finite).
pub(crate) fn build_index(points: &[[f64; 3]]) -> Option<PointGrid> {
    PointGrid::new(points)
}

/// The `k` nearest neighbours of point `i` (itself excluded), nearest first, ties by index.
pub(crate) fn nearest(index: &PointGrid, points: &[[f64; 3]], i: usize, k: usize) -> Vec<u32> {
    index.nearest(points, i, k, 0.0, &mut Vec::new()).0
}

/// The k nearest neighbours of every point (the point itself excluded), nearest first, ties
/// by index.
pub(crate) fn knn(points: &[[f64; 3]], k: usize) -> Neighbours {
    knn_with_index(points, k).1
}

/// [`knn`], and the neighbour index it used (for [`adaptive_normals`]).
pub(crate) fn knn_with_index(points: &[[f64; 3]], k: usize) -> (Option<PointGrid>, Neighbours) {
    match build_index(points) {
        Some(index) => {
            let neighbours = index.all_nearest(points, k);
            (Some(index), neighbours)
        }
        None => (None, Neighbours::empty(points.len())),
    }
}

/// Normal of the least-squares plane through `centre` and `neighbours`.
pub(crate) fn plane_normal(points: &[[f64; 3]], centre: usize, neighbours: &[u32]) -> [f64; 3] {
    plane_fit(points, centre, neighbours).0
}

/// Normal of the least-squares plane through `centre` and `neighbours`, and the neighbourhood's
/// thickness: √(λ₀/λ₁), the spread across the plane over the spread along it.
pub(crate) fn plane_fit(points: &[[f64; 3]], centre: usize, neighbours: &[u32]) -> ([f64; 3], f64) {
    let idx = std::iter::once(centre as u32).chain(neighbours.iter().copied());
    let count = (neighbours.len() + 1) as f64;
    let mut mean = [0.0; 3];
    for i in idx.clone() {
        let p = points[i as usize];
        for a in 0..3 {
            mean[a] += p[a] / count;
        }
    }
    let mut cov = [[0.0; 3]; 3];
    for i in idx {
        let d = sub(&points[i as usize], &mean);
        for r in 0..3 {
            for c in 0..3 {
                cov[r][c] += d[r] * d[c];
            }
        }
    }
    fit_of_covariance(cov)
}

/// The upper triangle of a symmetric 3×3 matrix, row by row.
const MOMENT_PAIRS: [(usize, usize); 6] = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)];

/// The plane normal and thickness √(λ₀/λ₁) of a neighbourhood's covariance (any positive
/// multiple of it).
fn fit_of_covariance(cov: [[f64; 3]; 3]) -> ([f64; 3], f64) {
    let (normal, l0, l1) = smallest_eigen(cov);
    let thickness = if l1 > 0.0 {
        (l0.max(0.0) / l1).sqrt()
    } else {
        1.0
    };
    (normal, thickness)
}

/// Below this thickness a neighbourhood counts as clean and is never grown.
const CLEAN_THICKNESS: f64 = 0.05;

/// A plane fit whose neighbourhood grows where noise dominates (an adaptive choice of scale).
///
/// A neighbourhood of k₀ = `neighbours.len()` points thicker than 0.05 (thickness √(λ₀/λ₁),
/// the spread across the plane over the spread along it) is tried at 2k₀, 4k₀, … up to `max_k`
/// points, and the flattest one wins. Noise makes the thickness fall like 1/radius as the
/// neighbourhood grows, curvature or a nearby sheet make it rise, so the flattest scale is where
/// the two balance (Mitra & Nguyen 2003 choose the scale from the same trade-off). The small
/// neighbourhood is kept unless the flattest is at least 20% flatter. Returns the normal and the
/// number of neighbours used.
pub(crate) fn adaptive_plane_fit(
    index: &PointGrid,
    points: &[[f64; 3]],
    i: usize,
    neighbours: &[u32],
    max_k: usize,
    keys: &mut Vec<u128>,
    wide: &mut Vec<u32>,
) -> ([f64; 3], usize) {
    let (first_normal, first_thickness) = plane_fit(points, i, neighbours);
    let (mut normal, mut thickness) = (first_normal, first_thickness);
    let k0 = neighbours.len();
    if thickness <= CLEAN_THICKNESS || 2 * k0 > max_k || k0 == 0 {
        return (normal, k0);
    }
    // On a surface the number of neighbours grows like the squared radius: the first
    // neighbourhood's radius, scaled for max_k points with a margin, usually holds them all
    // (the radius only guides the search; the answer is the max_k nearest in any case).
    let r2 = neighbours.last().map_or(0.0, |&j| {
        let d = sub(&points[j as usize], &points[i]);
        dot(&d, &d)
    }) * 1.5
        * max_k as f64
        / k0 as f64;
    wide.clear();
    index.nearest_into(points, i, max_k, r2, keys, wide);
    // The fits of the prefixes 2k₀, 4k₀, … in one pass: the moments of the offsets from point i
    // (which is in every neighbourhood, at offset 0), and at each prefix the covariance
    // Σ d dᵀ − (Σ d)(Σ d)ᵀ / count. The offsets are of the neighbourhood's size, so the
    // subtraction loses no more than a digit.
    let mut best_k = k0;
    let mut k = 2 * k0;
    let (mut first, mut second) = ([0.0; 3], [0.0; 6]);
    let centre = points[i];
    for (used, &j) in wide.iter().enumerate() {
        if k > wide.len() {
            break;
        }
        let d = sub(&points[j as usize], &centre);
        for a in 0..3 {
            first[a] += d[a];
        }
        for (slot, (r, c)) in second.iter_mut().zip(MOMENT_PAIRS) {
            *slot += d[r] * d[c];
        }
        if used + 1 == k {
            let count = (k + 1) as f64;
            let mut cov = [[0.0; 3]; 3];
            for (&moment, (r, c)) in second.iter().zip(MOMENT_PAIRS) {
                let entry = moment - first[r] * first[c] / count;
                cov[r][c] = entry;
                cov[c][r] = entry;
            }
            let (n2, t2) = fit_of_covariance(cov);
            if t2 < thickness {
                normal = n2;
                thickness = t2;
                best_k = k;
            }
            k *= 2;
        }
    }
    // Curvature alone changes the thickness little from one scale to the next; only a clear
    // drop says that noise dominated the small neighbourhood.
    if thickness > 0.8 * first_thickness {
        return (first_normal, k0);
    }
    (normal, best_k)
}

/// Plane-fit normals with the adaptive neighbourhood, in parallel; also returns, per point,
/// whether its neighbourhood had to grow (the data is noisy at the k₀ scale there). `index` is
/// the one `neighbours` came from ([`knn_with_index`]).
pub(crate) fn adaptive_normals(
    points: &[[f64; 3]],
    index: Option<&PointGrid>,
    neighbours: &Neighbours,
    max_k: usize,
) -> (Vec<[f64; 3]>, Vec<bool>) {
    let Some(index) = index else {
        return (
            (0..points.len())
                .map(|i| plane_normal(points, i, neighbours.row(i)))
                .collect(),
            vec![false; points.len()],
        );
    };
    let fits: Vec<([f64; 3], bool)> = (0..points.len())
        .into_par_iter()
        .map_init(
            || (Vec::new(), Vec::new()),
            |(keys, wide), i| {
                let near = neighbours.row(i);
                let (n, k) = adaptive_plane_fit(index, points, i, near, max_k, keys, wide);
                (n, k > near.len())
            },
        )
        .collect();
    fits.into_iter().unzip()
}

/// Unit eigenvector of the smallest eigenvalue, that eigenvalue and the middle one, of the
/// symmetric 3×3 matrix `a` (a covariance: positive semi-definite).
///
/// Closed form (Smith 1961): with q = tr(a)/3, p = √(tr((a − qI)²)/6) and B = (a − qI)/p, the
/// eigenvalues are q + 2p·cos(φ + 2πk/3), φ = acos(det(B)/2)/3; the smallest is k = 1, and its
/// eigenvector the largest of the cross products of two rows of a − λ₀I (a rank-2 matrix
/// whose rows span the plane orthogonal to it), computed twice: from the angle form's λ₀, then
/// from that vector's Rayleigh quotient, which restores the digits the angle form loses near a
/// double λ₁ = λ₂ (a disc-like neighbourhood, the common case). λ₀ is then exact to about
/// ε·λ₂, the vector to about ε·λ₂/(λ₁ − λ₀), λ₁ to about √ε·λ₂ when λ₁ ≈ λ₂ (it only enters
/// the thickness ratio). On curved, thin neighbourhoods it agrees with cyclic Jacobi rotations
/// to 1e-10 rad (unit test) at a fraction of their cost (the 1M-point torus's `pca` normals:
/// CPU −8%). A diagonal matrix, or a smallest eigenvalue of multiplicity two or three (a
/// line-like or degenerate neighbourhood, where any vector of its eigenspace is a valid
/// answer), gets an axis or a vector orthogonal to the matrix's largest row.
fn smallest_eigen(a: [[f64; 3]; 3]) -> ([f64; 3], f64, f64) {
    let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    let diag = [a[0][0], a[1][1], a[2][2]];
    let scale = diag.iter().map(|d| d.abs()).sum::<f64>();
    let q = (diag[0] + diag[1] + diag[2]) / 3.0;
    let shifted = diag.map(|d| d - q);
    let p = ((shifted.iter().map(|d| d * d).sum::<f64>() + 2.0 * off) / 6.0).sqrt();
    if !(off.sqrt() > 1e-15 * scale && p > 0.0 && p.is_finite()) {
        // Diagonal (to working precision), all three eigenvalues equal, or not finite.
        let mut best = 0;
        for i in 1..3 {
            if diag[i] < diag[best] {
                best = i;
            }
        }
        let middle = (0..3)
            .filter(|&i| i != best)
            .map(|i| diag[i])
            .fold(f64::INFINITY, f64::min);
        let mut e = [0.0; 3];
        e[best] = 1.0;
        return (e, diag[best], if middle.is_finite() { middle } else { 0.0 });
    }
    let b = |r: usize, c: usize| {
        if r == c {
            shifted[r] / p
        } else {
            a[r][c] / p
        }
    };
    let det = b(0, 0) * (b(1, 1) * b(2, 2) - b(1, 2) * b(1, 2))
        - b(0, 1) * (b(0, 1) * b(2, 2) - b(1, 2) * b(0, 2))
        + b(0, 2) * (b(0, 1) * b(1, 2) - b(1, 1) * b(0, 2));
    let phi = (0.5 * det).clamp(-1.0, 1.0).acos() / 3.0;
    let largest = q + 2.0 * p * phi.cos();
    let smallest = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    // The vector from a − λ₀I, then once more from its Rayleigh quotient (see above).
    let first = null_vector(a, smallest);
    let refined = rayleigh(a, first);
    let e = null_vector(a, refined);
    let smallest = rayleigh(a, e);
    let middle = 3.0 * q - largest - smallest;
    (e, smallest, middle)
}

/// eᵀae for the unit vector `e`.
fn rayleigh(a: [[f64; 3]; 3], e: [f64; 3]) -> f64 {
    (0..3)
        .map(|r| e[r] * (0..3).map(|c| a[r][c] * e[c]).sum::<f64>())
        .sum()
}

/// A unit vector of the null space of a − λI (λ an eigenvalue of the symmetric `a`): the
/// largest cross product of two of its rows, or, when the rows are parallel (λ of multiplicity
/// two), a vector orthogonal to the largest row ([0, 0, 1] when a − λI is 0).
fn null_vector(a: [[f64; 3]; 3], lambda: f64) -> [f64; 3] {
    let rows = [0, 1, 2].map(|r| {
        let mut row = a[r];
        row[r] -= lambda;
        row
    });
    let candidates = [
        cross(&rows[0], &rows[1]),
        cross(&rows[0], &rows[2]),
        cross(&rows[1], &rows[2]),
    ];
    let mut best = (0.0, [0.0; 3]);
    for c in candidates {
        let n2 = dot(&c, &c);
        if n2 > best.0 {
            best = (n2, c);
        }
    }
    let r = rows.into_iter().fold(
        [0.0; 3],
        |m, r| if dot(&r, &r) > dot(&m, &m) { r } else { m },
    );
    let r2 = dot(&r, &r);
    // Rows parallel to within 1e-6 rad: λ is (nearly) double and the cross products are
    // rounding noise; any vector orthogonal to the largest row is then exact.
    let e = if best.0 > 1e-12 * r2 * r2 && best.0.is_finite() {
        best.1
    } else {
        let mut axis = [0.0; 3];
        let k = (0..3)
            .min_by(|&i, &j| r[i].abs().total_cmp(&r[j].abs()))
            .unwrap_or(2);
        axis[k] = 1.0;
        cross(&r, &axis)
    };
    normalized(&e).unwrap_or([0.0, 0.0, 1.0])
}

/// The `pca` source: adaptive plane fits, oriented consistently and outward.
pub(crate) fn pca_normals(points: &[[f64; 3]], params: &NormalsParams) -> Vec<[f64; 3]> {
    let (index, neighbours) = knn_with_index(points, params.k_neighbours);
    let (mut normals, _) =
        adaptive_normals(points, index.as_ref(), &neighbours, params.max_k_neighbours);
    drop(index);
    crate::normals::orient::orient_outward(points, &mut normals, &[], neighbours);
    normals
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Unit eigenvector of the smallest eigenvalue of a symmetric 3×3 matrix.
    fn smallest_eigenvector(a: [[f64; 3]; 3]) -> [f64; 3] {
        smallest_eigen(a).0
    }

    /// Cosine of the angle between two unit vectors, clamped.
    fn abs_cos(a: &[f64; 3], b: &[f64; 3]) -> f64 {
        dot(a, b).abs().min(1.0)
    }

    #[test]
    fn eigen_solver_finds_smallest_axis() {
        let e = smallest_eigenvector([[3.0, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 2.0]]);
        assert!((e[1].abs() - 1.0).abs() < 1e-12);
        // A rotated diagonal matrix: eigenvalues 1, 2, 4 with the smallest along (1, 1, 0)/√2.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let u = [[s, s, 0.0], [-s, s, 0.0], [0.0, 0.0, 1.0]];
        let d = [1.0, 2.0, 4.0];
        let mut m = [[0.0; 3]; 3];
        for r in 0..3 {
            for c in 0..3 {
                m[r][c] = (0..3).map(|k| u[k][r] * d[k] * u[k][c]).sum();
            }
        }
        let e = smallest_eigenvector(m);
        assert!((abs_cos(&e, &[s, s, 0.0]) - 1.0).abs() < 1e-12);
    }

    /// A deterministic stream of numbers in [−0.5, 0.5) (xorshift64).
    fn uniform(mut state: u64) -> impl FnMut() -> f64 {
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    /// The symmetric matrix with eigenvalues `d` along the rows of the rotation `u`.
    fn compose(u: [[f64; 3]; 3], d: [f64; 3]) -> [[f64; 3]; 3] {
        let mut m = [[0.0; 3]; 3];
        for r in 0..3 {
            for c in 0..3 {
                m[r][c] = (0..3).map(|k| u[k][r] * d[k] * u[k][c]).sum();
            }
        }
        m
    }

    /// A rotation from a unit quaternion (w, x, y, z) (rows: the rotated axes).
    fn rotation(w: f64, x: f64, y: f64, z: f64) -> [[f64; 3]; 3] {
        let n = (w * w + x * x + y * y + z * z).sqrt();
        let (w, x, y, z) = (w / n, x / n, y / n, z / n);
        [
            [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y + w * z),
                2.0 * (x * z - w * y),
            ],
            [
                2.0 * (x * y - w * z),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z + w * x),
            ],
            [
                2.0 * (x * z + w * y),
                2.0 * (y * z - w * x),
                1.0 - 2.0 * (x * x + y * y),
            ],
        ]
    }

    #[test]
    fn eigen_solver_matches_known_decompositions() {
        // Flat, thick, line-like and nearly isotropic neighbourhoods in many orientations: the
        // vector of the smallest eigenvalue within 1e-12 rad whenever λ₁ − λ₀ ≥ 1e-3·λ₂ (where
        // it is well defined), λ₀ within 1e-13·λ₂ and λ₁ within 1e-7·λ₂.
        let spectra = [
            [0.0, 1.0, 2.0],
            [1e-9, 0.7, 1.3],
            [1e-3, 0.5, 1.0],
            [0.2, 0.9, 1.0],
            [0.3, 0.301, 0.31],
            [0.5, 1.0, 1.0],
            [0.0, 0.0, 1.0],
            [2.0, 2.0, 2.0],
        ];
        let mut next = uniform(0x9e37_79b9_7f4a_7c15);
        for d in spectra {
            for _ in 0..200 {
                let u = rotation(next(), next(), next(), next());
                let (e, l0, l1) = smallest_eigen(compose(u, d));
                assert!((l0 - d[0]).abs() <= 1e-13 * d[2], "λ₀ {l0} for {d:?}");
                assert!((l1 - d[1]).abs() <= 1e-7 * d[2], "λ₁ {l1} for {d:?}");
                assert!((dot(&e, &e) - 1.0).abs() < 1e-14);
                if d[1] - d[0] >= 1e-3 * d[2] {
                    // |sin| of the angle to the true axis.
                    let c = cross(&e, &u[0]);
                    assert!(dot(&c, &c).sqrt() < 1e-12, "{e:?} vs {:?}", u[0]);
                } else if d[1] < d[2] {
                    // λ₀ = λ₁ < λ₂: any vector orthogonal to the largest axis.
                    assert!(abs_cos(&e, &u[2]) < 1e-9, "{e:?} not ⟂ {:?}", u[2]);
                }
            }
        }
        // Diagonal and zero matrices: an axis, never NaN.
        assert_eq!(
            smallest_eigen([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 3.0]]),
            ([0.0, 1.0, 0.0], 1.0, 2.0)
        );
        let (e, l0, _) = smallest_eigen([[0.0; 3]; 3]);
        assert!(e.iter().all(|c| c.is_finite()) && (dot(&e, &e) - 1.0).abs() < 1e-15 && l0 == 0.0);
    }

    /// The smallest eigenvalue's unit eigenvector, that eigenvalue and the middle one, by cyclic
    /// Jacobi rotations (the reference of the closed form).
    // Index loops read best for the 3×3 rotations.
    #[allow(clippy::needless_range_loop)]
    fn jacobi_reference(mut a: [[f64; 3]; 3]) -> ([f64; 3], f64, f64) {
        let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        for _sweep in 0..32 {
            let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
            let diag = a[0][0].abs() + a[1][1].abs() + a[2][2].abs();
            if off <= 1e-15 * diag || off == 0.0 || !off.is_finite() {
                break;
            }
            for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
                if a[p][q] == 0.0 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                // a ← Jᵀ a J with the rotation J in the (p, q) plane.
                for k in 0..3 {
                    let akp = a[k][p];
                    let akq = a[k][q];
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for k in 0..3 {
                    let apk = a[p][k];
                    let aqk = a[q][k];
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for row in &mut v {
                    let vp = row[p];
                    let vq = row[q];
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
        let mut best = 0;
        for i in 1..3 {
            if a[i][i] < a[best][best] {
                best = i;
            }
        }
        let e = [v[0][best], v[1][best], v[2][best]];
        let mut rest = [0usize, 1, 2]
            .into_iter()
            .filter(|&i| i != best)
            .map(|i| a[i][i]);
        let middle = match (rest.next(), rest.next()) {
            (Some(x), Some(y)) => x.min(y),
            _ => 0.0,
        };
        (
            normalized(&e).unwrap_or([0.0, 0.0, 1.0]),
            a[best][best],
            middle,
        )
    }

    /// Covariances of 17 points on random paraboloid patches (principal curvatures −2 … 2, patch
    /// width 0.05: thin, disc-like neighbourhoods as on a scanned surface): the same normal as the
    /// Jacobi reference within 1e-10 rad, λ₀ within 1e-14 of the in-plane spread, λ₁ within 1e-6.
    #[test]
    fn eigen_solver_agrees_with_jacobi_on_curved_neighbourhoods() {
        let mut next = uniform(0x2545_f491_4f6c_dd1d);
        let mut worst: f64 = 0.0;
        for _ in 0..2000 {
            let (k1, k2) = (4.0 * next(), 4.0 * next());
            let pts: Vec<[f64; 3]> = (0..17)
                .map(|_| {
                    let (u, v) = (0.05 * next(), 0.05 * next());
                    [u, v, 0.5 * (k1 * u * u + k2 * v * v)]
                })
                .collect();
            let mean = [0, 1, 2].map(|a| pts.iter().map(|p| p[a]).sum::<f64>() / 17.0);
            let mut cov = [[0.0; 3]; 3];
            for p in &pts {
                let d = sub(p, &mean);
                for r in 0..3 {
                    for c in 0..3 {
                        cov[r][c] += d[r] * d[c];
                    }
                }
            }
            let (e, l0, l1) = smallest_eigen(cov);
            let (f, m0, m1) = jacobi_reference(cov);
            let c = cross(&e, &f);
            worst = worst.max(dot(&c, &c).sqrt());
            assert!((l0 - m0).abs() < 1e-14 * cov[0][0].abs().max(cov[1][1].abs()));
            assert!((l1 - m1).abs() < 1e-6 * m1, "{l1} vs {m1}");
        }
        assert!(worst < 1e-10, "worst angle {worst}");
    }
}
