//! The evaluation side of the `detail` stage: the partition-of-unity blend of the local fits, an
//! octree index from a point (or box) to the few balls that cover it, and the enclosures the
//! `polygonize` stage needs.
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
//! enclosures, the second is bounded by Σ maxᵢ|∇wᵢ| · Dᵢ / min W with interval bounds of wᵢ and
//! |∇wᵢ| from the box's distance range to each centre, where Dᵢ bounds |Qᵢ − f| on the box: f is
//! a convex combination of the Q_j, so |Qᵢ − f| ≤ |Qᵢ − Q_r| + max_j |Q_j − Q_r| for any
//! reference ball r (the one nearest the box centre), and each |Q_j − Q_r| is bounded through
//! the difference of the two quadrics' exact Taylor expansions at the box centre (and by
//! max hi − min lo, whichever is smaller). Where the local fits agree this is far tighter than
//! the value range alone, which lets the octree's mean-value test discard more cells. It is
//! guaranteed too; a box not fully covered by balls gets an unbounded gradient enclosure.
//!
//! Evaluation form. A local function of degree ≤ 2 is re-expanded once around its ball's centre
//! (10 coefficients in v = p − c, input units), so a point value needs no normalization; the
//! enclosures are computed from that same form, so they hold for the values computed. Degrees
//! 3 and 4 use the cell's polynomial.
//!
//! The index ([`BallIndex`]) is an octree over the cube bounding all balls whose leaves list the
//! balls meeting them; a point query descends to its leaf, a box query takes the union of the
//! leaves it meets (each ball once, in a fixed traversal order). It is rebuilt from the cells
//! alone (deterministic), so a decoded model evaluates bit-identically to the fitted one.

use crate::cloud::Aabb;
use crate::implicit::{Enclosure, ImplicitFunction};

use super::MpuCell;

/// A query-tree node stops splitting once it holds at most this many candidate balls.
const LEAF_BALLS: usize = 12;

/// A query-tree node also stops splitting once its side is at most this multiple of the
/// smallest radius among its balls (on the bunny: 2 gave about 30k leaves of about 27 balls,
/// built in a third of the time of 1 (170k leaves of 19), with the same meshing time).
const LEAF_SIDE: f64 = 2.0;

/// Deepest level of the query tree below its root cube.
const MAX_QUERY_DEPTH: u32 = 16;

/// One ball in the form the evaluation loops read: centre, radius and, for a local function of
/// degree ≤ 2, the quadric re-expanded around the ball's centre.
#[derive(Clone, Debug, PartialEq)]
struct Ball {
    /// Ball centre (input coordinates).
    center: [f64; 3],
    /// Radius².
    r2: f64,
    /// 1.5 / radius: the weight is b(k·|p − c|).
    k: f64,
    /// Support radius.
    radius: f64,
    /// For degree ≤ 2: Q(c + v) = q₀ + q₁vx + q₂vy + q₃vz + q₄vx² + q₅vxvy + q₆vxvz + q₇vy² +
    /// q₈vyvz + q₉vz² (the paper's monomial order in v = p − c, input units). Unused (zero)
    /// for higher degrees, which are evaluated through the cell's polynomial.
    quad: [f64; 10],
    /// Whether `quad` holds the local function (degree ≤ 2).
    is_quadric: bool,
}

impl Ball {
    fn new(cell: &MpuCell) -> Ball {
        let poly = &cell.poly;
        let c = cell.center;
        let is_quadric =
            poly.degree <= 2 && poly.coefficients.len() == crate::poly::n_coefficients(poly.degree);
        let mut quad = [0.0; 10];
        if is_quadric {
            // Value and gradient at the centre, and the second-order coefficients divided by s².
            let (v, g) = poly.value_gradient(c);
            quad[0] = v;
            quad[1..4].copy_from_slice(&g);
            if poly.degree == 2 {
                let s2 = poly.scale * poly.scale;
                for (slot, a) in quad.iter_mut().zip(&poly.coefficients).skip(4) {
                    *slot = a / s2;
                }
            }
        }
        Ball {
            center: c,
            r2: cell.radius * cell.radius,
            k: 1.5 / cell.radius,
            radius: cell.radius,
            quad,
            is_quadric,
        }
    }

    /// Q at the offset `v` = p − centre (quadrics only).
    #[inline(always)]
    fn quad_value(&self, v: [f64; 3]) -> f64 {
        let q = &self.quad;
        q[0] + v[0] * (q[1] + q[4] * v[0] + q[5] * v[1] + q[6] * v[2])
            + v[1] * (q[2] + q[7] * v[1] + q[8] * v[2])
            + v[2] * (q[3] + q[9] * v[2])
    }

    /// ∇Q at the offset `v` (quadrics only).
    #[inline(always)]
    fn quad_gradient(&self, v: [f64; 3]) -> [f64; 3] {
        let q = &self.quad;
        [
            q[1] + 2.0 * q[4] * v[0] + q[5] * v[1] + q[6] * v[2],
            q[2] + q[5] * v[0] + 2.0 * q[7] * v[1] + q[8] * v[2],
            q[3] + q[6] * v[0] + q[8] * v[1] + 2.0 * q[9] * v[2],
        ]
    }
}

/// A node of the query tree: a leaf (`children == 0`) lists the balls that meet its cube in
/// `BallIndex::lists[start..start + len]`; an inner node's eight children are stored
/// contiguously from `children`, in the order of their octant bits (x = 1, y = 2, z = 4).
#[derive(Clone, Debug, PartialEq)]
struct Node {
    children: u32,
    start: u32,
    len: u32,
}

/// An index from points and boxes to the balls that reach them: an octree over the cube that
/// bounds all balls, whose leaves list (in increasing cell order) every ball meeting their
/// cube. A node is split while it lists more than `LEAF_BALLS` balls and its side exceeds
/// `LEAF_SIDE` times the smallest of their radii, so near the surface a leaf is one or two
/// finest cells wide and lists a few dozen balls, of which about ten contain any given point.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct BallIndex {
    balls: Vec<Ball>,
    nodes: Vec<Node>,
    lists: Vec<u32>,
    origin: [f64; 3],
    side: f64,
}

impl BallIndex {
    /// Builds the index of `cells`' balls.
    pub(crate) fn new(cells: &[MpuCell]) -> BallIndex {
        let balls: Vec<Ball> = cells.iter().map(Ball::new).collect();
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for b in &balls {
            for a in 0..3 {
                lo[a] = lo[a].min(b.center[a] - b.radius);
                hi[a] = hi[a].max(b.center[a] + b.radius);
            }
        }
        let side = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        let mut index = BallIndex {
            balls,
            nodes: Vec::new(),
            lists: Vec::new(),
            origin: lo,
            side,
        };
        if index.balls.is_empty() || !(side > 0.0 && side.is_finite()) {
            index.side = 0.0;
            return index;
        }
        index.nodes.push(Node {
            children: 0,
            start: 0,
            len: 0,
        });
        let all: Vec<u32> = (0..index.balls.len() as u32).collect();
        index.fill(0, lo, side, 0, all);
        index
    }

    /// Makes node `id` (cube `[min, min + side]³` at `depth`) a leaf listing `candidates`, or
    /// splits it.
    fn fill(&mut self, id: usize, min: [f64; 3], side: f64, depth: u32, candidates: Vec<u32>) {
        let smallest = candidates
            .iter()
            .map(|&i| self.balls[i as usize].radius)
            .fold(f64::INFINITY, f64::min);
        if candidates.len() <= LEAF_BALLS
            || depth >= MAX_QUERY_DEPTH
            || side <= LEAF_SIDE * smallest
        {
            self.nodes[id] = Node {
                children: 0,
                start: self.lists.len() as u32,
                len: candidates.len() as u32,
            };
            self.lists.extend_from_slice(&candidates);
            return;
        }
        let first = self.nodes.len();
        self.nodes[id].children = first as u32;
        for _ in 0..8 {
            self.nodes.push(Node {
                children: 0,
                start: 0,
                len: 0,
            });
        }
        let half = 0.5 * side;
        // A little slack so that a point the query sends to a child on a rounding boundary is
        // still covered by the child's list.
        let pad = 1e-9 * side;
        // A ball goes to each child (the closed cube grown by `pad`) it meets: its squared
        // distance to the cube, summed over the axes, is below r². Along an axis the gap takes
        // one of two values (lower or upper half), so the 8 children's sums reuse 6 terms.
        // The octants each ball meets (one bit each), then each child's list at its exact size.
        let masks: Vec<u8> = candidates
            .iter()
            .map(|&i| {
                let b = &self.balls[i as usize];
                let gap2 = [0, 1, 2].map(|a| {
                    [min[a], min[a] + half].map(|cmin| {
                        let (lo, hi) = (cmin - pad, cmin + half + pad);
                        let d = (lo - b.center[a]).max(b.center[a] - hi).max(0.0);
                        d * d
                    })
                });
                let mut mask = 0u8;
                for octant in 0..8 {
                    let mut d2 = 0.0;
                    for (a, g) in gap2.iter().enumerate() {
                        d2 += g[(octant >> a) & 1];
                    }
                    if d2 < b.r2 {
                        mask |= 1 << octant;
                    }
                }
                mask
            })
            .collect();
        let mut counts = [0usize; 8];
        for &mask in &masks {
            for (octant, count) in counts.iter_mut().enumerate() {
                *count += usize::from((mask >> octant) & 1);
            }
        }
        let mut subs: [Vec<u32>; 8] = counts.map(Vec::with_capacity);
        for (&i, &mask) in candidates.iter().zip(&masks) {
            for (octant, sub) in subs.iter_mut().enumerate() {
                if (mask >> octant) & 1 == 1 {
                    sub.push(i);
                }
            }
        }
        drop(candidates);
        for (octant, sub) in subs.into_iter().enumerate() {
            let cmin = child_min(min, half, octant);
            self.fill(first + octant, cmin, half, depth + 1, sub);
        }
    }

    /// The balls that hold `p` (of its leaf's list, in order), each with its index, p − centre
    /// and |p − centre|².
    #[inline]
    fn holding(&self, p: [f64; 3]) -> impl Iterator<Item = (usize, &Ball, [f64; 3], f64)> + '_ {
        self.leaf_list(p).iter().filter_map(move |&i| {
            let b = &self.balls[i as usize];
            let v = [p[0] - b.center[0], p[1] - b.center[1], p[2] - b.center[2]];
            let d2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
            // Written so that a NaN distance is kept, as the blend sums it.
            if d2 >= b.r2 {
                None
            } else {
                Some((i as usize, b, v, d2))
            }
        })
    }

    /// The list of balls of the leaf that holds `p` (empty outside the indexed cube).
    #[inline]
    fn leaf_list(&self, p: [f64; 3]) -> &[u32] {
        let side = self.side;
        if self.nodes.is_empty()
            || (0..3).any(|a| !(p[a] >= self.origin[a] && p[a] <= self.origin[a] + side))
        {
            return &[];
        }
        let mut min = self.origin;
        let mut half = 0.5 * side;
        let mut node = &self.nodes[0];
        while node.children != 0 {
            let mut octant = 0;
            for a in 0..3 {
                if p[a] >= min[a] + half {
                    octant |= 1 << a;
                    min[a] += half;
                }
            }
            node = &self.nodes[node.children as usize + octant];
            half *= 0.5;
        }
        &self.lists[node.start as usize..(node.start + node.len) as usize]
    }

    /// Fills `scratch.found` with every ball (cell index) listed by a leaf that meets the box
    /// `b`, each once, in the order of a fixed traversal.
    fn collect_near_box(&self, b: &Aabb, scratch: &mut Scratch) {
        scratch.found.clear();
        if self.nodes.is_empty() {
            return;
        }
        if scratch.stamps.len() < self.balls.len() {
            scratch.stamps.resize(self.balls.len(), 0);
        }
        scratch.generation = scratch.generation.wrapping_add(1);
        if scratch.generation == 0 {
            scratch.stamps.iter_mut().for_each(|s| *s = 0);
            scratch.generation = 1;
        }
        let generation = scratch.generation;
        // Depth-first (at most 7 pending siblings per level), on a stack kept in the scratch.
        // A node is pushed only when the box meets it (the root tested here, a child before
        // its push).
        if (0..3).any(|a| b.max[a] < self.origin[a] || b.min[a] > self.origin[a] + self.side) {
            return;
        }
        let stack = &mut scratch.stack;
        stack.clear();
        stack.push((0, self.origin, self.side));
        while let Some((id, min, side)) = stack.pop() {
            let node = &self.nodes[id as usize];
            if node.children == 0 {
                for &i in &self.lists[node.start as usize..(node.start + node.len) as usize] {
                    let stamp = &mut scratch.stamps[i as usize];
                    if *stamp != generation {
                        *stamp = generation;
                        scratch.found.push(i);
                    }
                }
            } else {
                // Only the children the box meets (the root's test, per axis for the lower and
                // the upper half), in the same order as pushing all eight and testing each.
                let half = 0.5 * side;
                let meets = [0, 1, 2].map(|a| {
                    let mid = min[a] + half;
                    [
                        !(b.max[a] < min[a] || b.min[a] > min[a] + half),
                        !(b.max[a] < mid || b.min[a] > mid + half),
                    ]
                });
                for octant in (0..8usize).rev() {
                    if (0..3).all(|a| meets[a][(octant >> a) & 1]) {
                        stack.push((
                            node.children + octant as u32,
                            child_min(min, half, octant),
                            half,
                        ));
                    }
                }
            }
        }
    }
}

/// Per-thread scratch space of the box queries.
#[derive(Default)]
struct Scratch {
    /// `stamps[i] == generation` when ball i was already found in this query.
    stamps: Vec<u32>,
    generation: u32,
    found: Vec<u32>,
    local: Vec<LocalBound>,
    /// The pending nodes of a box query: (node, lower corner, side).
    stack: Vec<(u32, [f64; 3], f64)>,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// The lower corner of child `octant` of the cube at `min` whose children have side `half`.
#[inline]
fn child_min(min: [f64; 3], half: f64, octant: usize) -> [f64; 3] {
    [0, 1, 2].map(|a| {
        if (octant >> a) & 1 == 1 {
            min[a] + half
        } else {
            min[a]
        }
    })
}

/// The quadratic B-spline b(t) and its derivative (the local fits' re-centring weighs the
/// ball's points by b too).
#[inline]
pub(super) fn bspline(t: f64) -> (f64, f64) {
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
    for (i, b, v, d2) in index.holding(p) {
        let (w, _) = bspline(b.k * d2.sqrt());
        if w > 0.0 {
            let q = if b.is_quadric {
                b.quad_value(v)
            } else {
                cells[i].poly.value(p)
            };
            num += w * q;
            den += w;
        }
    }
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
    for (i, b, v, d2) in index.holding(p) {
        let d = d2.sqrt();
        let (w, dw_dt) = bspline(b.k * d);
        if w <= 0.0 {
            continue;
        }
        let (q, gq) = if b.is_quadric {
            (b.quad_value(v), b.quad_gradient(v))
        } else {
            cells[i].poly.value_gradient(p)
        };
        // ∇w = b'(t)·k·(p − c)/|p − c| (0 at the centre, where b'(0) = 0).
        let gw = if d > 0.0 {
            let s = dw_dt * b.k / d;
            v.map(|x| s * x)
        } else {
            [0.0; 3]
        };
        num += w * q;
        den += w;
        for a in 0..3 {
            dnum[a] += gw[a] * q + w * gq[a];
            dden[a] += gw[a];
        }
    }
    if den > 0.0 {
        let f = num / den;
        (f, [0, 1, 2].map(|a| (dnum[a] - f * dden[a]) / den))
    } else {
        (outside, [0.0; 3])
    }
}

/// What the enclosure of the blend keeps of one ball that meets the box.
#[derive(Clone, Copy, Debug, Default)]
struct LocalBound {
    /// Σ-able bound of |∇wᵢ| on the box: max |b'| · k.
    slope: f64,
    /// For a quadric: Qᵢ(m + t) = v + g·t + tᵀHt/2 at the box centre m (H's upper triangle
    /// xx, xy, xz, yy, yz, zz), up to `margin` for rounding. Unused for higher degrees.
    v: f64,
    g: [f64; 3],
    hess: [f64; 6],
    margin: f64,
}

/// Value and gradient enclosures of the blend over the box `b` (see the module docs).
pub(crate) fn blend_enclosure(
    cells: &[MpuCell],
    index: &BallIndex,
    outside: f64,
    b: &Aabb,
) -> Enclosure {
    SCRATCH.with(|scratch| {
        let mut guard = scratch.borrow_mut();
        let scratch = &mut *guard;
        index.collect_near_box(b, scratch);
        let m = b.center();
        let h = [0, 1, 2].map(|a| 0.5 * (b.max[a] - b.min[a]));
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        let mut glo = [f64::INFINITY; 3];
        let mut ghi = [f64::NEG_INFINITY; 3];
        let mut w_min = 0.0;
        let mut error: f64 = 0.0;
        let mut all_quadrics = true;
        // The ball whose centre is nearest the box centre: the reference of the gradient bound.
        let mut reference = (f64::INFINITY, 0usize);
        scratch.local.clear();
        for &i in &scratch.found {
            let ball = &index.balls[i as usize];
            let (near, far) = distance_range(ball.center, b);
            if near >= ball.radius {
                continue;
            }
            let k = ball.k;
            w_min += bspline((far * k).min(1.5)).0;
            let slope = bspline_slope_max(near * k, far * k) * k;
            let (e, local) = if ball.is_quadric {
                let d2 = (0..3).map(|a| (m[a] - ball.center[a]).powi(2)).sum::<f64>();
                if d2 < reference.0 {
                    reference = (d2, scratch.local.len());
                }
                quadric_enclosure(ball, m, h)
            } else {
                all_quadrics = false;
                let e = cells[i as usize].poly.enclosure_on_box(b);
                (e, LocalBound::default())
            };
            lo = lo.min(e.value.0);
            hi = hi.max(e.value.1);
            error = error.max(e.value_error);
            for a in 0..3 {
                glo[a] = glo[a].min(e.gradient[a].0);
                ghi[a] = ghi[a].max(e.gradient[a].1);
            }
            scratch.local.push(LocalBound { slope, ..local });
        }
        let unbounded = [(f64::NEG_INFINITY, f64::INFINITY); 3];
        if scratch.local.is_empty() {
            return Enclosure {
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
            return Enclosure {
                value: (lo.min(outside), hi.max(outside)),
                gradient: unbounded,
                value_error,
            };
        }
        // |Qᵢ − f| ≤ min(hi − lo, |Qᵢ − Q_r| + max_j |Q_j − Q_r|) on the box (f is a convex
        // combination of the Q_j there), with |Qᵢ − Q_r| bounded through the difference of the
        // two Taylor expansions at the box centre.
        let width = hi - lo;
        let mut weighted = 0.0;
        if all_quadrics {
            let r = scratch.local[reference.1];
            let apart = |l: &LocalBound| {
                let mut d = (l.v - r.v).abs() + l.margin + r.margin;
                for ((gl, gr), ha) in l.g.iter().zip(&r.g).zip(&h) {
                    d += (gl - gr).abs() * ha;
                }
                let dh = [0, 1, 2, 3, 4, 5].map(|k| (l.hess[k] - r.hess[k]).abs());
                d += 0.5 * (dh[0] * h[0] * h[0] + dh[3] * h[1] * h[1] + dh[5] * h[2] * h[2])
                    + dh[1] * h[0] * h[1]
                    + dh[2] * h[0] * h[2]
                    + dh[4] * h[1] * h[2];
                d * (1.0 + 1e-12)
            };
            let spread_of_all = scratch.local.iter().map(apart).fold(0.0, f64::max);
            for l in &scratch.local {
                weighted += l.slope * width.min(apart(l) + spread_of_all);
            }
        } else {
            weighted = width * scratch.local.iter().map(|l| l.slope).sum::<f64>();
        }
        let spread = weighted / w_min * (1.0 + 1e-9);
        let gradient = [0, 1, 2].map(|a| (glo[a] - spread, ghi[a] + spread));
        Enclosure {
            value: (lo - value_error, hi + value_error),
            gradient: if spread.is_finite() {
                gradient
            } else {
                unbounded
            },
            value_error,
        }
    })
}

/// The enclosure of a ball's quadric over the box with centre `m` and half-widths `h`, and its
/// Taylor expansion there: the expansion is exact, Q(m + t) = Q(m) + ∇Q(m)·t + tᵀHt/2 with
/// |t_k| ≤ h_k, so the value is bounded term by term and the gradient ∇Q(m) + Ht by |H|h.
fn quadric_enclosure(ball: &Ball, m: [f64; 3], h: [f64; 3]) -> (Enclosure, LocalBound) {
    let q = &ball.quad;
    let v0 = [0, 1, 2].map(|a| m[a] - ball.center[a]);
    let hess = [
        [2.0 * q[4], q[5], q[6]],
        [q[5], 2.0 * q[7], q[8]],
        [q[6], q[8], 2.0 * q[9]],
    ];
    let v = ball.quad_value(v0);
    let g = ball.quad_gradient(v0);
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
        for n in k + 1..3 {
            let cross = (hess[k][n] * h[k] * h[n]).abs();
            lo -= cross;
            hi += cross;
        }
        let mut spread = 0.0;
        for n in 0..3 {
            spread += (hess[k][n] * h[n]).abs();
        }
        grad[k] = (g[k] - spread, g[k] + spread);
    }
    // Rounding, generously: every term of a point evaluation is at most
    // |q₀| + Σ|q_lin|·r + Σ|q_quad|·r² with r the largest |v_k| on the box, and the offset
    // v = p − c itself rounds by about ε·(|p| + |c|), which moves Q by |∇Q| times that.
    let r = (0..3).map(|k| v0[k].abs() + h[k]).fold(0.0, f64::max) * (1.0 + 1e-12);
    let lin_sum = q[1].abs() + q[2].abs() + q[3].abs();
    let quad_sum: f64 = q[4..].iter().map(|x| x.abs()).sum();
    let magnitude = q[0].abs() + lin_sum * r + quad_sum * r * r;
    let slope = lin_sum + 2.0 * quad_sum * r;
    let offset = ball.center.iter().map(|x| x.abs()).fold(0.0, f64::max) * 2.0 + r;
    let margin = 1e-13 * (magnitude + slope * offset);
    let gmargin = 1e-13 * (slope + 2.0 * quad_sum * offset);
    let enclosure = Enclosure {
        value: (lo - margin, hi + margin),
        gradient: grad.map(|(l, u)| (l - gmargin, u + gmargin)),
        value_error: margin,
    };
    let local = LocalBound {
        v,
        g,
        hess: [
            hess[0][0], hess[0][1], hess[0][2], hess[1][1], hess[1][2], hess[2][2],
        ],
        margin,
        ..LocalBound::default()
    };
    (enclosure, local)
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

    fn enclosure_on_box(&self, b: &Aabb) -> Enclosure {
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
