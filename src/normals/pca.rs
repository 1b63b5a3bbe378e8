//! Plane-fit ("PCA") normals of the `normals` stage, and the k-nearest-neighbour graph they share
//! with the orientation step.
//!
//! Input: distinct points. Output: per point, an unoriented unit normal: the direction of least
//! variance of the point and its k nearest neighbours (the normal of their least-squares plane,
//! Hoppe et al. 1992). The sign is arbitrary here; [`crate::normals::orient`] makes it consistent
//! and outward.
//!
//! Invariants: every returned normal is unit length and finite (a degenerate neighbourhood gets
//! the best direction the eigen-solver finds, never NaN); results do not depend on the thread
//! count (each point is computed independently and collected in order).

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;

use crate::normals::vec3::{dot, normalized, sub};
use crate::normals::NormalsParams;

/// The k nearest neighbours of every point (the point itself excluded), nearest first.
pub fn knn(points: &[[f64; 3]], k: usize) -> Vec<Vec<u32>> {
    let k = k.min(points.len().saturating_sub(1));
    if k == 0 {
        return vec![Vec::new(); points.len()];
    }
    let Ok(tree) = ImmutableKdTree::<f64, 3>::new_from_slice(points) else {
        return vec![Vec::new(); points.len()];
    };
    let Some(qty) = std::num::NonZeroUsize::new(k + 1) else {
        return vec![Vec::new(); points.len()];
    };
    points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let mut found = tree.query(p).nearest_n::<SquaredEuclidean<f64>>(qty).execute();
            // Sort by (distance, index) so that ties are broken the same way on every run.
            found.sort_by(|a, b| a.distance.total_cmp(&b.distance).then(a.item.cmp(&b.item)));
            found
                .into_iter()
                .map(|r| r.item)
                .filter(|&j| j as usize != i)
                .take(k)
                .collect()
        })
        .collect()
}

/// Normal of the least-squares plane through `centre` and `neighbours`.
pub fn plane_normal(points: &[[f64; 3]], centre: usize, neighbours: &[u32]) -> [f64; 3] {
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
    smallest_eigenvector(cov)
}

/// Unit eigenvector of the smallest eigenvalue of a symmetric 3×3 matrix (cyclic Jacobi).
pub fn smallest_eigenvector(mut a: [[f64; 3]; 3]) -> [f64; 3] {
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
    normalized(&e).unwrap_or([0.0, 0.0, 1.0])
}

/// Unoriented plane-fit normals for all points with their k nearest neighbours.
pub fn unoriented_normals(points: &[[f64; 3]], neighbours: &[Vec<u32>]) -> Vec<[f64; 3]> {
    (0..points.len())
        .into_par_iter()
        .map(|i| plane_normal(points, i, &neighbours[i]))
        .collect()
}

/// The `pca` source: plane fits, oriented consistently and outward.
pub fn pca_normals(points: &[[f64; 3]], params: &NormalsParams) -> Vec<[f64; 3]> {
    let neighbours = knn(points, params.k_neighbours);
    let mut normals = unoriented_normals(points, &neighbours);
    crate::normals::orient::orient_outward(points, &mut normals, &[], &neighbours);
    normals
}

/// Cosine of the angle between two unit vectors, clamped (helper for tests and callers).
pub fn abs_cos(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    dot(a, b).abs().min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobi_finds_smallest_axis() {
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
}
