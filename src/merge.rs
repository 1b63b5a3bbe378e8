//! Stage `merge`: oriented views of one object, each in its own frame, with their poses → one
//! [`OrientedCloud`] in the common frame.
//!
//! Input: each view's [`OrientedCloud`] (normals already estimated in the view's own frame, from
//! its range grid, viewpoint or estimate) and its [`Pose`]. Output: the points and normals of
//! every view moved into the common frame (p ↦ R(q)ᵀ·p + t, n ↦ R(q)ᵀ·n, the Stanford `.conf`
//! convention), concatenated in view order, with each view's confidence weights (1 for a view
//! without them; `None` when no view has any).
//!
//! Deterministic: the output depends only on the views' order and contents. The transforms are
//! nalgebra's `Isometry3<f64>` built from a `UnitQuaternion`; the artifact stays plain arrays.

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::cloud::OrientedCloud;

/// Where a view sits in the common frame: p ↦ R(q)ᵀ·p + t.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// t.
    pub translation: [f64; 3],
    /// q = (qx, qy, qz, qw), normalised before use (must not be zero).
    pub rotation: [f64; 4],
}

impl Pose {
    /// The identity: the view is already in the common frame.
    pub(crate) const IDENTITY: Pose = Pose {
        translation: [0.0; 3],
        rotation: [0.0, 0.0, 0.0, 1.0],
    };

    /// The pose as an isometry: rotation R(q)ᵀ = R(q⁻¹), then translation t.
    pub(crate) fn isometry(&self) -> Isometry3<f64> {
        let [x, y, z, w] = self.rotation;
        let q = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
        let [tx, ty, tz] = self.translation;
        Isometry3::from_parts(Translation3::new(tx, ty, tz), q.inverse())
    }

    /// Points moved into the common frame, the isometry built once for all of them.
    ///
    /// ```
    /// use stablesurf::merge::Pose;
    /// let pose = Pose { translation: [1.0, 2.0, 3.0], rotation: [0.0, 0.0, 0.0, 1.0] };
    /// assert_eq!(pose.apply_all(&[[0.0; 3], [1.0, 0.0, 0.0]]), [[1.0, 2.0, 3.0], [2.0, 2.0, 3.0]]);
    /// // A quarter turn about z: R(q) takes x to y, so R(q)ᵀ takes y to x.
    /// let h = std::f64::consts::FRAC_1_SQRT_2;
    /// let pose = Pose { translation: [0.0, 0.0, 1.0], rotation: [0.0, 0.0, h, h] };
    /// let p = pose.apply_all(&[[0.0, 1.0, 0.0]])[0];
    /// assert!((p[0] - 1.0).abs() < 1e-12 && p[1].abs() < 1e-12 && (p[2] - 1.0).abs() < 1e-12);
    /// ```
    pub fn apply_all(&self, points: &[[f64; 3]]) -> Vec<[f64; 3]> {
        let iso = self.isometry();
        points
            .iter()
            .map(|p| {
                let q = iso * Point3::from(*p);
                [q.x, q.y, q.z]
            })
            .collect()
    }
}

/// The views moved into the common frame and concatenated (see the module docs).
pub fn merge_views(views: &[(&OrientedCloud, Pose)]) -> OrientedCloud {
    let total: usize = views.iter().map(|(c, _)| c.points.len()).sum();
    let any_weights = views.iter().any(|(c, _)| c.weights.is_some());
    let mut out = OrientedCloud {
        points: Vec::with_capacity(total),
        normals: Vec::with_capacity(total),
        weights: any_weights.then(|| Vec::with_capacity(total)),
    };
    for (cloud, pose) in views {
        let iso = pose.isometry();
        for (p, n) in cloud.points.iter().zip(&cloud.normals) {
            let q = iso * Point3::from(*p);
            let m = iso.rotation * Vector3::from(*n);
            out.points.push([q.x, q.y, q.z]);
            out.normals.push([m.x, m.y, m.z]);
        }
        if let Some(w) = out.weights.as_mut() {
            match &cloud.weights {
                Some(given) => w.extend_from_slice(given),
                None => w.extend(std::iter::repeat_n(1.0, cloud.points.len())),
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_move_and_keep_their_weights() {
        let a = OrientedCloud {
            points: vec![[1.0, 0.0, 0.0]],
            normals: vec![[1.0, 0.0, 0.0]],
            weights: Some(vec![0.5]),
        };
        let b = OrientedCloud {
            points: vec![[0.0, 1.0, 0.0]],
            normals: vec![[0.0, 1.0, 0.0]],
            weights: None,
        };
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let turn = Pose {
            translation: [0.0, 0.0, 2.0],
            rotation: [0.0, 0.0, h, h],
        };
        let m = merge_views(&[(&a, Pose::IDENTITY), (&b, turn)]);
        assert_eq!(m.points[0], [1.0, 0.0, 0.0]);
        assert!((m.points[1][0] - 1.0).abs() < 1e-12 && (m.points[1][2] - 2.0).abs() < 1e-12);
        assert!((m.normals[1][0] - 1.0).abs() < 1e-12 && m.normals[1][2].abs() < 1e-12);
        assert_eq!(m.weights, Some(vec![0.5, 1.0]));
        let none = merge_views(&[(&b, Pose::IDENTITY)]);
        assert_eq!(none.weights, None);
    }
}
