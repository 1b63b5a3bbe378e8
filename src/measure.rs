//! Accuracy measures between point sets and meshes (used by the pipeline's report and the tools).
//!
//! Input: points and a [`TriangleMesh`]. Output: distances in input units.
//!
//! The point-to-mesh distance is exact per candidate triangle (closest point on a triangle,
//! Ericson, *Real-Time Collision Detection*, 5.1.5); candidates are the triangles around the
//! mesh vertex nearest to the query (a k-d tree), which finds the true nearest triangle whenever
//! it shares a vertex with the nearest vertex — true for the well-shaped meshes polygonize makes,
//! and an upper bound on the distance otherwise.

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::mesh::{TriangleMesh, VertexTriangles};

/// Summary of distances from a point set to a surface.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DistanceSummary {
    /// Mean distance, input units.
    pub mean: f64,
    /// Root mean square distance, input units.
    pub rms: f64,
    /// Largest distance, input units.
    pub max: f64,
    /// `mean` divided by the reference bounding-box diagonal.
    pub mean_relative: f64,
    /// `max` divided by the reference bounding-box diagonal.
    pub max_relative: f64,
}

impl DistanceSummary {
    /// Summarizes `distances`, relative figures against `diagonal`.
    pub fn from_distances(distances: &[f64], diagonal: f64) -> DistanceSummary {
        if distances.is_empty() {
            return DistanceSummary::default();
        }
        let n = distances.len() as f64;
        let mean = distances.iter().sum::<f64>() / n;
        let rms = (distances.iter().map(|d| d * d).sum::<f64>() / n).sqrt();
        let max = distances.iter().copied().fold(0.0, f64::max);
        let rel = |v: f64| if diagonal > 0.0 { v / diagonal } else { 0.0 };
        DistanceSummary {
            mean,
            rms,
            max,
            mean_relative: rel(mean),
            max_relative: rel(max),
        }
    }
}

/// Closest point to `p` on the triangle `(a, b, c)`.
pub fn closest_point_on_triangle(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> [f64; 3] {
    let sub = |u: [f64; 3], v: [f64; 3]| [u[0] - v[0], u[1] - v[1], u[2] - v[2]];
    let dot = |u: [f64; 3], v: [f64; 3]| u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
    let lerp =
        |u: [f64; 3], d: [f64; 3], t: f64| [u[0] + t * d[0], u[1] + t * d[1], u[2] + t * d[2]];
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return lerp(a, ab, d1 / (d1 - d3));
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return lerp(a, ac, d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return lerp(b, sub(c, b), (d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    [0, 1, 2].map(|k| a[k] + ab[k] * v + ac[k] * w)
}

/// Distance from each point to the mesh (see the module docs for the candidate set).
/// Returns an empty vector when the mesh has no triangles.
pub fn point_to_mesh_distances(points: &[[f64; 3]], mesh: &TriangleMesh) -> Vec<f64> {
    if mesh.triangles.is_empty() {
        return Vec::new();
    }
    let around = VertexTriangles::new(mesh.positions.len(), &mesh.triangles);
    let Ok(tree) = ImmutableKdTree::<f64, 3>::new_from_slice(&mesh.positions) else {
        return Vec::new();
    };
    points
        .par_iter()
        .map(|&p| {
            let nearest = tree
                .query(&p)
                .nearest_one::<SquaredEuclidean<f64>>()
                .execute();
            let v = nearest.item as usize;
            let mut best = nearest.distance.sqrt();
            for &ti in around.of(v) {
                let [a, b, c] = mesh.triangles[ti as usize].map(|i| mesh.positions[i as usize]);
                let q = closest_point_on_triangle(p, a, b, c);
                let d =
                    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
                best = best.min(d);
            }
            best
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_point_regions() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let q = closest_point_on_triangle([0.2, 0.2, 1.0], a, b, c);
        assert!((q[0] - 0.2).abs() < 1e-15 && (q[1] - 0.2).abs() < 1e-15 && q[2] == 0.0);
        assert_eq!(closest_point_on_triangle([-1.0, -1.0, 0.0], a, b, c), a);
        assert_eq!(
            closest_point_on_triangle([0.5, -1.0, 0.0], a, b, c),
            [0.5, 0.0, 0.0]
        );
        let q = closest_point_on_triangle([1.0, 1.0, 0.0], a, b, c);
        assert!((q[0] - 0.5).abs() < 1e-15 && (q[1] - 0.5).abs() < 1e-15);
    }

    #[test]
    fn distance_to_a_square_made_of_two_triangles() {
        let mesh = TriangleMesh {
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            normals: vec![[0.0, 0.0, 1.0]; 4],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        let d = point_to_mesh_distances(&[[0.3, 0.6, 0.25], [2.0, 0.5, 0.0]], &mesh);
        assert!((d[0] - 0.25).abs() < 1e-12);
        assert!((d[1] - 1.0).abs() < 1e-12);
        let s = DistanceSummary::from_distances(&d, 2.0);
        assert!((s.mean - 0.625).abs() < 1e-12 && (s.max_relative - 0.5).abs() < 1e-12);
    }
}
