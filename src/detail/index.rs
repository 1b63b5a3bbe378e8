//! The evaluation side of the `detail` stage: the partition-of-unity blend of the local fits, a
//! bounding-volume hierarchy from a point (or box) to the few balls that cover it, and the
//! enclosures the `polygonize` stage needs.
//!
//! Input: the cells of an [`MpuModel`](super::MpuModel) (ball centre, radius, local polynomial).
//! Output: f(p) = Σ wᵢ(p)Qᵢ(p) / Σ wᵢ(p), its gradient, and enclosures over boxes.
//!
//! Weights (Ohtake et al. 2003): wᵢ(p) = b(3|p − cᵢ|/(2Rᵢ)) with the quadratic B-spline
//!
//! ```text
//! b(t) = 3/4 − t²          0 ≤ t ≤ 1/2
//!      = (3/2 − t)²/2      1/2 ≤ t ≤ 3/2
//!      = 0                 t ≥ 3/2          (support: the ball |p − cᵢ| < Rᵢ; b is C¹)
//! ```
//!
//! Where no ball covers p (Σ w = 0, outside the root cube only: the leaves' balls cover it), f is
//! the constant [`MpuModel::diagonal`](super::MpuModel) (a definite "outside" sign), so the zero
//! set closes and no evaluation is ever NaN.
//!
//! Enclosures. At every p, f(p) is a convex combination of the Qᵢ(p) of the balls covering p, so
//! over a box f lies in [minᵢ loᵢ, maxᵢ hiᵢ] where (loᵢ, hiᵢ) is the guaranteed (centred Taylor
//! form) enclosure of Qᵢ over the box, taken over the balls that meet the box: this value
//! enclosure is guaranteed. The gradient is
//! ∇f = Σ wᵢ∇Qᵢ/W + Σ ∇wᵢ(Qᵢ − f)/W, W = Σ wᵢ; the first term lies in the hull of the ∇Qᵢ
//! enclosures, the second is bounded by Σ maxᵢ|∇wᵢ| · (max hi − min lo) / min W with interval
//! bounds of wᵢ and |∇wᵢ| from the box's distance range to each centre. It is also guaranteed,
//! but loose on boxes as large as the balls; there the topology guard simply refines. A box not
//! fully covered by balls gets an unbounded gradient enclosure.
//!
//! The index is a binary BVH over the balls' bounding boxes, split at the median centre along
//! the longest axis; it is rebuilt from the cells alone (deterministic), so a decoded model
//! evaluates bit-identically to the fitted one.

use crate::cloud::Aabb;
use crate::poly::ImplicitPolynomial;
use crate::polygonize::ImplicitFunction;

use super::MpuCell;

/// Balls per BVH leaf.
const LEAF_SIZE: usize = 4;

/// A node of the ball hierarchy.
#[derive(Clone, Debug, PartialEq)]
struct Node {
    /// Bounding box of every ball below this node.
    lo: [f64; 3],
    hi: [f64; 3],
    /// For a leaf: range `start..start + count` of [`BallIndex::order`]; for an inner node
    /// `count == 0` and the children are `start` and `start + 1`... stored as `left`, `right`.
    start: u32,
    count: u32,
    left: u32,
    right: u32,
}

/// A bounding-volume hierarchy from points and boxes to the balls that reach them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BallIndex {
    nodes: Vec<Node>,
    order: Vec<u32>,
}

impl BallIndex {
    /// Builds the index of `cells`' balls.
    pub fn new(cells: &[MpuCell]) -> BallIndex {
        let mut index = BallIndex {
            nodes: Vec::new(),
            order: (0..cells.len() as u32).collect(),
        };
        if !cells.is_empty() {
            let n = cells.len();
            index.build(cells, 0, n);
        }
        index
    }

    fn build(&mut self, cells: &[MpuCell], start: usize, end: usize) -> u32 {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        let mut clo = [f64::INFINITY; 3];
        let mut chi = [f64::NEG_INFINITY; 3];
        for &i in &self.order[start..end] {
            let c = &cells[i as usize];
            for a in 0..3 {
                lo[a] = lo[a].min(c.center[a] - c.radius);
                hi[a] = hi[a].max(c.center[a] + c.radius);
                clo[a] = clo[a].min(c.center[a]);
                chi[a] = chi[a].max(c.center[a]);
            }
        }
        let id = self.nodes.len() as u32;
        self.nodes.push(Node {
            lo,
            hi,
            start: start as u32,
            count: (end - start) as u32,
            left: 0,
            right: 0,
        });
        if end - start <= LEAF_SIZE {
            return id;
        }
        let axis = (0..3)
            .max_by(|&a, &b| (chi[a] - clo[a]).total_cmp(&(chi[b] - clo[b])))
            .unwrap_or(0);
        self.order[start..end].sort_by(|&x, &y| {
            cells[x as usize].center[axis]
                .total_cmp(&cells[y as usize].center[axis])
                .then(x.cmp(&y))
        });
        let mid = start + (end - start) / 2;
        let left = self.build(cells, start, mid);
        let right = self.build(cells, mid, end);
        let node = &mut self.nodes[id as usize];
        node.count = 0;
        node.left = left;
        node.right = right;
        id
    }

    /// Calls `visit` with the index of every cell whose box-of-ball contains `p` (a superset of
    /// the balls containing it), in a fixed order.
    #[inline]
    fn for_each_near_point(&self, p: [f64; 3], mut visit: impl FnMut(usize)) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = [0u32; 64];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let node = &self.nodes[stack[top] as usize];
            if (0..3).any(|a| p[a] < node.lo[a] || p[a] > node.hi[a]) {
                continue;
            }
            if node.count > 0 {
                for &i in &self.order[node.start as usize..(node.start + node.count) as usize] {
                    visit(i as usize);
                }
            } else if top + 2 <= stack.len() {
                stack[top] = node.right;
                stack[top + 1] = node.left;
                top += 2;
            }
        }
    }

    /// Calls `visit` with every cell whose box-of-ball meets the box `b`, in a fixed order.
    fn for_each_near_box(&self, b: &Aabb, mut visit: impl FnMut(usize)) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = vec![0u32];
        while let Some(id) = stack.pop() {
            let node = &self.nodes[id as usize];
            if (0..3).any(|a| b.max[a] < node.lo[a] || b.min[a] > node.hi[a]) {
                continue;
            }
            if node.count > 0 {
                for &i in &self.order[node.start as usize..(node.start + node.count) as usize] {
                    visit(i as usize);
                }
            } else {
                stack.push(node.right);
                stack.push(node.left);
            }
        }
    }
}

/// The quadratic B-spline b(t) and its derivative.
#[inline]
fn bspline(t: f64) -> (f64, f64) {
    if t <= 0.5 {
        (0.75 - t * t, -2.0 * t)
    } else if t < 1.5 {
        let u = 1.5 - t;
        (0.5 * u * u, -u)
    } else {
        (0.0, 0.0)
    }
}

/// Largest |b'(t)| over t ∈ [t0, t1].
fn bspline_slope_max(t0: f64, t1: f64) -> f64 {
    if t0 >= 1.5 {
        0.0
    } else if t1 <= 0.5 {
        2.0 * t1
    } else if t0 >= 0.5 {
        1.5 - t0
    } else {
        1.0
    }
}

/// Distance range from `c` to the points of box `b`.
fn distance_range(c: [f64; 3], b: &Aabb) -> (f64, f64) {
    let (mut near, mut far) = (0.0, 0.0);
    for ((&ca, &lo), &hi) in c.iter().zip(&b.min).zip(&b.max) {
        let d = (lo - ca).max(ca - hi).max(0.0);
        near += d * d;
        let f = (ca - lo).abs().max((hi - ca).abs());
        far += f * f;
    }
    (near.sqrt(), far.sqrt())
}

/// f(p) for the blend of `cells`, with the constant `outside` where no ball reaches.
#[inline]
pub(crate) fn blend_value(cells: &[MpuCell], index: &BallIndex, outside: f64, p: [f64; 3]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    index.for_each_near_point(p, |i| {
        let c = &cells[i];
        let d2 = (p[0] - c.center[0]).powi(2)
            + (p[1] - c.center[1]).powi(2)
            + (p[2] - c.center[2]).powi(2);
        if d2 >= c.radius * c.radius {
            return;
        }
        let (w, _) = bspline(1.5 * d2.sqrt() / c.radius);
        if w > 0.0 {
            num += w * c.poly.value(p);
            den += w;
        }
    });
    if den > 0.0 {
        num / den
    } else {
        outside
    }
}

/// f(p) and ∇f(p) for the blend of `cells`.
pub(crate) fn blend_value_gradient(
    cells: &[MpuCell],
    index: &BallIndex,
    outside: f64,
    p: [f64; 3],
) -> (f64, [f64; 3]) {
    let (mut num, mut den) = (0.0, 0.0);
    let mut dnum = [0.0; 3];
    let mut dden = [0.0; 3];
    index.for_each_near_point(p, |i| {
        let c = &cells[i];
        let v = [0, 1, 2].map(|a| p[a] - c.center[a]);
        let d2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
        if d2 >= c.radius * c.radius {
            return;
        }
        let d = d2.sqrt();
        let (w, dw_dt) = bspline(1.5 * d / c.radius);
        if w <= 0.0 {
            return;
        }
        let (q, gq) = c.poly.value_gradient(p);
        // ∇w = b'(t)·(3/(2R))·(p − c)/|p − c| (0 at the centre, where b'(0) = 0).
        let gw = if d > 0.0 {
            let k = dw_dt * 1.5 / (c.radius * d);
            v.map(|x| k * x)
        } else {
            [0.0; 3]
        };
        num += w * q;
        den += w;
        for a in 0..3 {
            dnum[a] += gw[a] * q + w * gq[a];
            dden[a] += gw[a];
        }
    });
    if den > 0.0 {
        let f = num / den;
        (f, [0, 1, 2].map(|a| (dnum[a] - f * dden[a]) / den))
    } else {
        (outside, [0.0; 3])
    }
}

/// Value and gradient enclosures of the blend over the box `b` (see the module docs).
pub(crate) fn blend_enclosure(
    cells: &[MpuCell],
    index: &BallIndex,
    outside: f64,
    b: &Aabb,
) -> crate::polygonize::function::Enclosure {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut glo = [f64::INFINITY; 3];
    let mut ghi = [f64::NEG_INFINITY; 3];
    let mut w_min = 0.0;
    let mut slope_sum = 0.0;
    let mut error: f64 = 0.0;
    let mut any = false;
    index.for_each_near_box(b, |i| {
        let c = &cells[i];
        let (near, far) = distance_range(c.center, b);
        if near >= c.radius {
            return;
        }
        any = true;
        let k = 1.5 / c.radius;
        w_min += bspline((far * k).min(1.5)).0;
        slope_sum += bspline_slope_max(near * k, far * k) * k;
        let e = enclosure_of(&c.poly, b);
        lo = lo.min(e.value.0);
        hi = hi.max(e.value.1);
        error = error.max(e.value_error);
        for a in 0..3 {
            glo[a] = glo[a].min(e.gradient[a].0);
            ghi[a] = ghi[a].max(e.gradient[a].1);
        }
    });
    let unbounded = [(f64::NEG_INFINITY, f64::INFINITY); 3];
    if !any {
        return crate::polygonize::function::Enclosure {
            value: (outside, outside),
            gradient: [(0.0, 0.0); 3],
            value_error: 0.0,
        };
    }
    // Rounding of the weighted mean: a few ulps of the largest magnitude involved.
    let magnitude = lo.abs().max(hi.abs());
    let value_error = error + 64.0 * f64::EPSILON * magnitude;
    if w_min <= 0.0 {
        // Part of the box may be uncovered, where f jumps to `outside`.
        return crate::polygonize::function::Enclosure {
            value: (lo.min(outside), hi.max(outside)),
            gradient: unbounded,
            value_error,
        };
    }
    let spread = (hi - lo) * slope_sum / w_min * (1.0 + 1e-9);
    let gradient = [0, 1, 2].map(|a| (glo[a] - spread, ghi[a] + spread));
    crate::polygonize::function::Enclosure {
        value: (lo - value_error, hi + value_error),
        gradient: if spread.is_finite() {
            gradient
        } else {
            unbounded
        },
        value_error,
    }
}

/// The enclosure of one local polynomial over a box: a closed form for degree ≤ 2 (its Taylor
/// expansion around the box centre is exact), the crate's centred form otherwise.
fn enclosure_of(poly: &ImplicitPolynomial, b: &Aabb) -> crate::polygonize::function::Enclosure {
    if poly.degree > 2 || poly.coefficients.len() != 10 {
        return poly.enclosure_on_box(b);
    }
    let c = b.center();
    let s = poly.scale;
    let a = &poly.coefficients;
    let q = poly.normalize(c);
    // Derivatives with respect to input coordinates: normalized ones divided by s (gradient)
    // and s² (Hessian).
    let hess = [
        [2.0 * a[4], a[5], a[6]],
        [a[5], 2.0 * a[7], a[8]],
        [a[6], a[8], 2.0 * a[9]],
    ]
    .map(|row| row.map(|v| v / (s * s)));
    let gq = [
        a[1] + 2.0 * a[4] * q[0] + a[5] * q[1] + a[6] * q[2],
        a[2] + a[5] * q[0] + 2.0 * a[7] * q[1] + a[8] * q[2],
        a[3] + a[6] * q[0] + a[8] * q[1] + 2.0 * a[9] * q[2],
    ];
    let g = gq.map(|v| v / s);
    let v = poly.value(c);
    let h = [0, 1, 2].map(|k| 0.5 * (b.max[k] - b.min[k]));
    // Q(c + t) = v + g·t + tᵀHt/2, |t_k| ≤ h_k.
    let mut lo = v;
    let mut hi = v;
    let mut grad = [(0.0, 0.0); 3];
    for k in 0..3 {
        let lin = g[k].abs() * h[k];
        lo -= lin;
        hi += lin;
        let diag = 0.5 * hess[k][k] * h[k] * h[k];
        if diag > 0.0 {
            hi += diag;
        } else {
            lo += diag;
        }
        for m in k + 1..3 {
            let cross = (hess[k][m] * h[k] * h[m]).abs();
            lo -= cross;
            hi += cross;
        }
        let mut spread = 0.0;
        for m in 0..3 {
            spread += (hess[k][m] * h[m]).abs();
        }
        grad[k] = (g[k] - spread, g[k] + spread);
    }
    // Rounding: every term of the evaluation is at most Σ|a_α|·(|q| + h/s)^α in magnitude;
    // a generous multiple of the unit roundoff of that covers all the rounding above.
    let reach = [0, 1, 2].map(|k| q[k].abs() + h[k] / s);
    let r1 = reach[0].max(reach[1]).max(reach[2]).max(1.0);
    let magnitude: f64 = a.iter().map(|x| x.abs()).sum::<f64>() * r1 * r1;
    let margin = 1e-13 * magnitude;
    let gmargin = 1e-13 * magnitude / s;
    crate::polygonize::function::Enclosure {
        value: (lo - margin, hi + margin),
        gradient: grad.map(|(l, u)| (l - gmargin, u + gmargin)),
        value_error: margin,
    }
}

impl ImplicitFunction for super::MpuModel {
    fn value(&self, p: [f64; 3]) -> f64 {
        blend_value(&self.cells, &self.index, self.diagonal, p)
    }

    fn value_gradient(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        blend_value_gradient(&self.cells, &self.index, self.diagonal, p)
    }

    fn bounds_on_box(&self, b: &Aabb) -> (f64, f64) {
        self.enclosure_on_box(b).value
    }

    fn gradient_bounds_on_box(&self, b: &Aabb) -> [(f64, f64); 3] {
        self.enclosure_on_box(b).gradient
    }

    fn enclosure_on_box(&self, b: &Aabb) -> crate::polygonize::function::Enclosure {
        blend_enclosure(&self.cells, &self.index, self.diagonal, b)
    }

    fn validate(&self) -> Result<(), String> {
        if !(self.diagonal > 0.0 && self.diagonal.is_finite()) {
            return Err(format!("the model's diagonal {} is not > 0", self.diagonal));
        }
        for (i, c) in self.cells.iter().enumerate() {
            if !(c.radius > 0.0 && c.radius.is_finite()) || c.center.iter().any(|v| !v.is_finite())
            {
                return Err(format!(
                    "cell {i} has a bad ball (centre {:?}, radius {})",
                    c.center, c.radius
                ));
            }
            c.poly.validate().map_err(|e| format!("cell {i}: {e}"))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bspline_is_a_partition_shape() {
        // C¹ at the knots and zero at the support's end.
        for t in [0.5, 1.5] {
            let (a, da) = bspline(t - 1e-9);
            let (b, db) = bspline(t + 1e-9);
            assert!((a - b).abs() < 1e-8 && (da - db).abs() < 1e-8);
        }
        assert_eq!(bspline(1.5).0, 0.0);
        assert_eq!(bspline(0.0), (0.75, 0.0));
        assert!((bspline_slope_max(0.0, 1.5) - 1.0).abs() < 1e-15);
        assert!((bspline_slope_max(0.1, 0.2) - 0.4).abs() < 1e-15);
    }

    #[test]
    fn distance_range_of_a_box() {
        let b = Aabb {
            min: [1.0, 0.0, 0.0],
            max: [2.0, 1.0, 1.0],
        };
        let (near, far) = distance_range([0.0, 0.0, 0.0], &b);
        assert!((near - 1.0).abs() < 1e-15);
        assert!((far - 6f64.sqrt()).abs() < 1e-15);
    }
}
