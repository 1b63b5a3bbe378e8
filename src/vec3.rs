//! Small `[f64; 3]` vector helpers shared by every stage (no stage of its own).
//!
//! Points, normals and gradients are plain `[f64; 3]` arrays throughout the crate (the
//! artifacts store them that way, so nothing is converted at stage borders); these are the few
//! operations on them that several modules need. Each is the textbook formula written out in a
//! fixed order, so every caller gets the same bits for the same arguments.

/// `a − b`.
#[inline]
pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a · b`, summed x, y, z in that order.
#[inline]
pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a × b` (right-handed).
#[inline]
pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Euclidean length `|a|`.
#[inline]
pub(crate) fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// Area of the triangle `(a, b, c)`: `|(b − a) × (c − a)| / 2`.
#[inline]
pub(crate) fn triangle_area(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    0.5 * norm(cross(sub(b, a), sub(c, a)))
}

/// Squared Euclidean distance between two points (the crate's one copy).
pub(crate) fn dist2(a: [f64; 3], b: [f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// Euclidean distance between two points.
pub(crate) fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    dist2(a, b).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cross_is_right_handed_and_orthogonal() {
        let (x, y) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        assert_eq!(cross(x, y), [0.0, 0.0, 1.0]);
        let (a, b) = ([0.3, -1.7, 2.2], [4.1, 0.6, -0.9]);
        let c = cross(a, b);
        assert!(dot(c, a).abs() <= 1e-12 && dot(c, b).abs() <= 1e-12);
        assert_eq!(norm(sub([4.0, 6.0, 3.0], [1.0, 2.0, 3.0])), 5.0);
    }
}
