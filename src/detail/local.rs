//! The local fit of the `detail` stage: one low-degree 3LRR polynomial on the points of one ball.
//!
//! Input: the points and unit outward normals that fall in a ball, optional auxiliary
//! off-surface points with target values, a degree (≤ 4), the kind of normal constraint
//! ([`Constraints`]: gradient rows, or the 3L layers at ±ε) and κ. Output: an
//! [`ImplicitPolynomial`] in input coordinates that is close to a signed distance near the data
//! (negative inside), and the largest data residual |Q|/|∇Q| in the ball.
//!
//! Method (Sahin & Unel 2008, sections 2.2, 5.5 and 6.6, applied locally as Ohtake et al.,
//! *Multi-level partition of unity implicits*, SIGGRAPH 2003, apply their local quadrics):
//!
//! 0. The points fitted: the ball's points, or when it holds more than [`SUBSAMPLE_ABOVE`] an
//!    even subsample of [`SUBSAMPLE_POINTS`] of them ([`even_subsample`]: the parameter and its
//!    reason are there). The error that decides a split is measured over all of them.
//! 1. Local radial normalization: μ the centroid of the fitted points, s their mean distance
//!    to μ; every point is mapped to p̂ = (p − μ)/s.
//! 2. Rows: p̂ with target 0, and the normal constraint, by default
//!    ([`Constraints::Gradient`], the gradient constraints of Tasdizen, Tarel & Cooper,
//!    *Improving the stability of algebraic curves for applications*, IEEE TIP 2000) the three rows ∇Q̂(p̂) = n, linear in the coefficients like the
//!    value rows; or the paper's 3L rows ([`Constraints::ThreeLevels`]) p̂ + εn (target +ε) and
//!    p̂ − εn (target −ε). The 3L targets cannot be met on a curved patch (on a sphere of radius
//!    ρ the quadric through the data with unit gradient takes ε + ε²/(2ρ) at p̂ + εn), and the
//!    least-squares compromise moves the zero set outward (by s·(√(1 + 2ε²/3) − 1) for a whole
//!    sphere), until step 4 removes it. Gradient rows are met exactly by the quadric
//!    (|q − c|² − ρ²)/(2ρ), so they leave no such bias. Each
//!    auxiliary point q adds the row q̂ with target t/s, t its estimated signed distance in
//!    input units.
//!    With gradient rows, MᵀM and Mᵀb of a cubic or quartic are assembled from the points'
//!    moments (sums of the monomials of degree ≤ 2n, and of the normals times those of degree
//!    < n; [`gradient_normal_equations`]) instead of one rank-one update per row: the same
//!    sums in another order, and fewer operations per point (the quadric keeps its packed
//!    10 × 10 updates, which were as fast).
//! 3. Ridge regression with the Euclidean-invariant diagonal D of the paper (6.18), β computed
//!    over the ball's data points: a = (MᵀM + κD)⁻¹Mᵀb, solved by Cholesky (c ≤ 35 unknowns,
//!    and κD > 0 keeps the system positive definite). With gradient rows the constant term is
//!    not penalized (D₀₀ = 0; the value rows, whose constant monomial is 1, keep the system
//!    positive definite): the ridge then shrinks only the shape terms and the constant stays
//!    free to make the residuals of the value rows sum to zero. Penalizing it too pulled the
//!    zero set inward (a whole sphere's quadric (|q|² − 1)/2 shrinks its constant more than its
//!    x², y², z² terms, held by the gradient rows).
//! 4. Re-centred: a constant c is subtracted so that the mean of Q̂/|∇Q̂| over the ball's data
//!    points, weighted by the cell's blend weight b(1.5·|p − c|/r), is 0. Two things shift the
//!    zero set by a constant otherwise. The 3L compromise above, and the auxiliary rows, which
//!    ask for signed distances at the cell's centre and corners that a low-degree polynomial
//!    with unit gradient at the data cannot take far from it; they keep their role, the sign of Q away from the data. The
//!    blend weight matters where the local polynomial cannot follow the surface (a quadric on a
//!    torus): its error then changes sign across the ball, and the mean that counts is the one
//!    the blend sees, near the cell's centre (`tools/detail_bias.rs` measures the offset).
//! 5. Carried to input units: Q(p) = s·Q̂((p − μ)/s), then divided by the mean |∇Q| over the
//!    ball's points so that |∇Q| ≈ 1 on the data and Q is close to a signed distance there; this
//!    rescaling does not move the zero set, it only balances the blend.
//!
//! Invariants: the returned polynomial has finite coefficients and scale > 0; a system that
//! cannot be solved returns `None` (never a panic).

use crate::implicit::ImplicitFunction;
use crate::numerics::cholesky;
use crate::poly::{exponents, monomial_index, n_coefficients, ImplicitPolynomial};
use crate::vec3;
use crate::vec3::dist;

/// One auxiliary off-surface point: its position (input coordinates) and target value (an
/// estimate of its signed distance, input units).
pub(crate) type AuxPoint = ([f64; 3], f64);

/// How the normals enter a local fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Constraints {
    /// Rows ∇Q̂(p̂) = n (weight 1 each, like the value rows).
    Gradient,
    /// The paper's 3L rows at p̂ ± εn with targets ±ε (ε in normalized units).
    ThreeLevels(f64),
}

/// The weight of each fitted point's rows: its confidence (the cloud's, by point index) times
/// its robust weight (by position among the fitted points), each 1 when absent.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct RowWeights<'a> {
    /// Per point of the cloud.
    pub confidence: Option<&'a [f32]>,
    /// Per fitted point, in the order given.
    pub robust: Option<&'a [f64]>,
}

impl RowWeights<'_> {
    /// The weight of the `j`-th fitted point, point `i` of the cloud. Without robust weights
    /// it is the confidence's own bits (1 without confidences).
    #[inline]
    fn of(&self, j: usize, i: u32) -> f64 {
        let c = self.confidence.map_or(1.0, |c| f64::from(c[i as usize]));
        match self.robust {
            Some(r) => c * r[j],
            None => c,
        }
    }
}

/// A fitted local polynomial and how well it matches its ball's data.
pub(crate) struct LocalFit {
    /// The local function, ≈ signed distance in input units.
    pub poly: ImplicitPolynomial,
    /// Largest |Q(p)|/|∇Q(p)| over the data points the caller asked to measure, input units.
    pub max_error: f64,
    /// Root mean square of |Q(p)|/|∇Q(p)| over the same points (over those measured before the
    /// stop, when the measure stopped early), input units.
    pub rms_error: f64,
}

/// The monomials of degree ≤ `n` (≤ 8: a fit's degree ≤ 4, or its moments of degree ≤ 8) at `q`
/// in the paper's order (see [`crate::poly`]).
pub(crate) fn monomials(n: usize, q: [f64; 3], out: &mut [f64]) {
    let mut px = [1.0; 9];
    let mut py = [1.0; 9];
    let mut pz = [1.0; 9];
    for e in 1..=n {
        px[e] = px[e - 1] * q[0];
        py[e] = py[e - 1] * q[1];
        pz[e] = pz[e - 1] * q[2];
    }
    let mut l = 0;
    for r in 0..=n {
        for s in 0..=r {
            for k in 0..=s {
                out[l] = px[r - s] * py[s - k] * pz[k];
                l += 1;
            }
        }
    }
}

/// The gradients of the monomials of degree ≤ `n` at `q`, in the paper's order: `out[a][l]` is
/// ∂m_l/∂q_a (the tests' reference for the gradient rows the moments sum).
#[cfg(test)]
pub(crate) fn monomial_gradients(n: usize, q: [f64; 3], out: &mut [[f64; 35]; 3]) {
    let mut pw = [[1.0; 5]; 3];
    for (a, p) in pw.iter_mut().enumerate() {
        for e in 1..=n {
            p[e] = p[e - 1] * q[a];
        }
    }
    // d/dq of q^e: e·q^(e−1), 0 for e = 0.
    let d = |a: usize, e: usize| if e == 0 { 0.0 } else { e as f64 * pw[a][e - 1] };
    let mut l = 0;
    for r in 0..=n {
        for s in 0..=r {
            for k in 0..=s {
                let e = [r - s, s - k, k];
                out[0][l] = d(0, e[0]) * pw[1][e[1]] * pw[2][e[2]];
                out[1][l] = pw[0][e[0]] * d(1, e[1]) * pw[2][e[2]];
                out[2][l] = pw[0][e[0]] * pw[1][e[1]] * d(2, e[2]);
                l += 1;
            }
        }
    }
}

/// Fits a local polynomial of degree `degree` (≤ 4) to the points `ball` (indices into
/// `points`/`normals`) and the auxiliary rows `aux`. `fallback_scale` is used as s when the
/// points all coincide. The error is measured over `measure` (indices); the measure stops as
/// soon as it exceeds `stop_above` (then `max_error` is only known to exceed it: a caller that
/// splits such a cell needs no more), so pass `f64::INFINITY` for the exact largest error.
#[allow(clippy::too_many_arguments)]
pub(crate) fn fit_local(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    ball: &[u32],
    measure: &[u32],
    stop_above: f64,
    aux: &[AuxPoint],
    degree: u32,
    constraints: Constraints,
    kappa: f64,
    fallback_scale: f64,
    blend: Option<([f64; 3], f64)>,
    weights: RowWeights<'_>,
) -> Option<LocalFit> {
    if ball.is_empty() || degree > 4 {
        return None;
    }
    let n = degree as usize;
    let c = n_coefficients(degree);
    // 1. Local radial normalization.
    let mut mu = [0.0; 3];
    for &i in ball {
        let p = points[i as usize];
        for a in 0..3 {
            mu[a] += p[a];
        }
    }
    let inv = 1.0 / ball.len() as f64;
    mu = mu.map(|v| v * inv);
    let mut s = 0.0;
    for &i in ball {
        s += dist(points[i as usize], mu);
    }
    s *= inv;
    if !(s > 1e-12 * fallback_scale && s.is_finite()) {
        s = fallback_scale;
    }
    if !(s > 0.0 && s.is_finite()) {
        return None;
    }
    let norm = |p: [f64; 3]| [0, 1, 2].map(|a| (p[a] - mu[a]) / s);
    if n == 2 && c == 10 {
        return fit_quadric(
            points,
            normals,
            ball,
            measure,
            stop_above,
            aux,
            constraints,
            kappa,
            (mu, s),
            blend,
            weights,
        );
    }

    // 2. Normal equations MᵀM (upper triangle, row-major c×c) and Mᵀb.
    let mut ata = [0.0; 35 * 35];
    let mut atb = [0.0; 35];
    let mut beta = [0.0; 5];
    let mut mon = [0.0; 35];
    // Each row weighted by `w` (the point's row weight; 1 for the auxiliary rows). w·mᵢ is mᵢ
    // exactly when w = 1, so a cloud without weights gives the same bits as unweighted rows.
    let add_row =
        |m: &[f64; 35], target: f64, w: f64, ata: &mut [f64; 35 * 35], atb: &mut [f64; 35]| {
            for i in 0..c {
                let mi = w * m[i];
                if mi == 0.0 {
                    continue;
                }
                atb[i] += mi * target;
                let row = &mut ata[i * c..i * c + c];
                for j in i..c {
                    row[j] += mi * m[j];
                }
            }
        };
    // With gradient rows, the rows' normal equations come from the points' moments (see
    // [`gradient_normal_equations`]): 84 + 30 sums a point at degree 3, 165 + 60 at degree 4,
    // against 4 rank-one updates of a 20 × 20 or 35 × 35 matrix.
    let mut moments = [0.0; MOMENTS_MAX];
    let mut normal_moments = [[0.0; 20]; 3];
    let mut all_monomials = [0.0; MOMENTS_MAX];
    let (all, lower) = (n_coefficients(2 * degree), n_coefficients(degree - 1));
    for (j, &i) in ball.iter().enumerate() {
        let q = norm(points[i as usize]);
        let nv = normals[i as usize];
        let w = weights.of(j, i);
        let r2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
        let mut pw = 1.0;
        for b in beta.iter_mut().take(n + 1) {
            *b += pw;
            pw *= r2;
        }
        match constraints {
            Constraints::Gradient => {
                monomials(2 * n, q, &mut all_monomials);
                for (sum, m) in moments[..all].iter_mut().zip(&all_monomials) {
                    *sum += w * m;
                }
                for (sums, &nc) in normal_moments.iter_mut().zip(&nv) {
                    let wn = w * nc;
                    for (sum, m) in sums[..lower].iter_mut().zip(&all_monomials) {
                        *sum += wn * m;
                    }
                }
            }
            Constraints::ThreeLevels(epsilon) => {
                monomials(n, q, &mut mon);
                add_row(&mon, 0.0, w, &mut ata, &mut atb);
                monomials(n, [0, 1, 2].map(|a| q[a] + epsilon * nv[a]), &mut mon);
                add_row(&mon, epsilon, w, &mut ata, &mut atb);
                monomials(n, [0, 1, 2].map(|a| q[a] - epsilon * nv[a]), &mut mon);
                add_row(&mon, -epsilon, w, &mut ata, &mut atb);
            }
        }
    }
    if constraints == Constraints::Gradient {
        gradient_normal_equations(n, &moments, &normal_moments, &mut ata, &mut atb);
    }
    let aux_w = aux_weight(ball, measure);
    for &(p, t) in aux {
        monomials(n, norm(p), &mut mon);
        add_row(&mon, t / s, aux_w, &mut ata, &mut atb);
    }
    // 3. Ridge term κD, D_ll = β_{|α|}/T_α (paper 6.18).
    let mut l = 0;
    for (r, &beta_r) in beta.iter().enumerate().take(n + 1) {
        for s_ in 0..=r {
            for k in 0..=s_ {
                let (i, j) = (r - s_, s_ - k);
                let t = factorial(r) / (factorial(i) * factorial(j) * factorial(k));
                // The constant term is left out with gradient rows (see step 3 above).
                if l > 0 || !matches!(constraints, Constraints::Gradient) {
                    ata[l * c + l] += kappa * beta_r / t;
                }
                l += 1;
            }
        }
    }
    let a = cholesky_solve(&mut ata[..c * c], &mut atb[..c], c)?;

    // 4. Input units, unit gradient on the data.
    let coefficients: Vec<f64> = a.iter().map(|v| v * s).collect();
    let mut poly = ImplicitPolynomial {
        degree,
        coefficients,
        center: mu,
        scale: s,
    };
    // Re-centring, and the mean |∇Q| for the rescaling.
    let (shift, gsum) = recentring(points, ball, blend, weights, |i| {
        poly.value_gradient(points[i as usize])
    });
    poly.coefficients[0] -= shift;
    let gmean = gsum * inv;
    if gmean > 1e-3 && gmean.is_finite() {
        for v in poly.coefficients.iter_mut() {
            *v /= gmean;
        }
    }
    if poly.coefficients.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let (max_error, rms_error) = measure_errors(measure, stop_above, |i| {
        let (f, g) = poly.value_gradient(points[i as usize]);
        let gn = vec3::norm(g);
        if gn > 0.0 {
            f.abs() / gn
        } else {
            f64::INFINITY
        }
    });
    Some(LocalFit {
        poly,
        max_error,
        rms_error,
    })
}

/// The degree-2 case of [`fit_local`] after the normalization (μ, s): the same rows, ridge and
/// scaling, written for 10 unknowns (packed upper triangle, no zero fills of a 35 × 35 system)
/// and with the error measured in normalized coordinates, where |Q|/|∇Q| = s·|Q̂(q)|/|∇Q̂(q)|.
#[allow(clippy::too_many_arguments)]
fn fit_quadric(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    ball: &[u32],
    measure: &[u32],
    stop_above: f64,
    aux: &[AuxPoint],
    constraints: Constraints,
    kappa: f64,
    (mu, s): ([f64; 3], f64),
    blend: Option<([f64; 3], f64)>,
    weights: RowWeights<'_>,
) -> Option<LocalFit> {
    let norm = |p: [f64; 3]| [0, 1, 2].map(|a| (p[a] - mu[a]) / s);
    let mut ata = [0.0; 55];
    let mut atb = [0.0; 10];
    let mut beta = [0.0; 3];
    for (j, &i) in ball.iter().enumerate() {
        let q = norm(points[i as usize]);
        let nv = normals[i as usize];
        let w = weights.of(j, i);
        let r2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
        beta[0] += 1.0;
        beta[1] += r2;
        beta[2] += r2 * r2;
        let m0 = quadric_monomials(q);
        add_packed(&mut ata, &m0, w);
        match constraints {
            Constraints::Gradient => {
                // ∇Q̂(q) = n: the gradients of 1, x, y, z, x², xy, xz, y², yz, z².
                let [x, y, z] = q;
                let gx = [0.0, 1.0, 0.0, 0.0, 2.0 * x, y, z, 0.0, 0.0, 0.0];
                let gy = [0.0, 0.0, 1.0, 0.0, 0.0, x, 0.0, 2.0 * y, z, 0.0];
                let gz = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, x, 0.0, y, 2.0 * z];
                add_packed(&mut ata, &gx, w);
                add_packed(&mut ata, &gy, w);
                add_packed(&mut ata, &gz, w);
                for l in 0..10 {
                    atb[l] += w * (gx[l] * nv[0] + gy[l] * nv[1] + gz[l] * nv[2]);
                }
            }
            Constraints::ThreeLevels(epsilon) => {
                let m1 = quadric_monomials([0, 1, 2].map(|a| q[a] + epsilon * nv[a]));
                add_packed(&mut ata, &m1, w);
                let m2 = quadric_monomials([0, 1, 2].map(|a| q[a] - epsilon * nv[a]));
                add_packed(&mut ata, &m2, w);
                for l in 0..10 {
                    atb[l] += w * (m1[l] * epsilon + m2[l] * -epsilon);
                }
            }
        }
    }
    let aux_w = aux_weight(ball, measure);
    for &(p, t) in aux {
        let m = quadric_monomials(norm(p));
        add_packed(&mut ata, &m, aux_w);
        let target = aux_w * t / s;
        for l in 0..10 {
            atb[l] += m[l] * target;
        }
    }
    // Ridge κD with D_ll = β_{|α|}/T_α (paper 6.18): T is 1 for 1, x, y, z, x², y², z² and 2
    // for xy, xz, yz.
    const DEGREE_OF: [usize; 10] = [0, 1, 1, 1, 2, 2, 2, 2, 2, 2];
    const MULTINOMIAL: [f64; 10] = [1.0, 1.0, 1.0, 1.0, 1.0, 2.0, 2.0, 1.0, 2.0, 1.0];
    let mut full = [0.0; 100];
    let mut k = 0;
    for i in 0..10 {
        for j in i..10 {
            full[i * 10 + j] = ata[k];
            k += 1;
        }
        if i > 0 || !matches!(constraints, Constraints::Gradient) {
            full[i * 10 + i] += kappa * beta[DEGREE_OF[i]] / MULTINOMIAL[i];
        }
    }
    let mut a = cholesky_solve(&mut full, &mut atb, 10)?;
    // Step 4's re-centring, and the mean |∇Q| over the fitted points for the rescaling (input
    // units, before it: ∇ₚQ = ∇_qQ̂).
    let (shift, gsum) = recentring(points, ball, blend, weights, |i| {
        quadric_value_gradient(&a, norm(points[i as usize]))
    });
    a[0] -= shift;
    // The largest |Q|/|∇Q| over the measured points, which the rescaling leaves unchanged.
    let value_gradient = |i: u32| {
        let (v, g) = quadric_value_gradient(&a, norm(points[i as usize]));
        (v, vec3::norm(g))
    };
    let (max_error, rms_error) = measure_errors(measure, stop_above, |i| {
        let (v, gn) = value_gradient(i);
        if gn > 0.0 {
            s * v.abs() / gn
        } else {
            f64::INFINITY
        }
    });
    let gmean = gsum / ball.len() as f64;
    let rescale = if gmean > 1e-3 && gmean.is_finite() {
        s / gmean
    } else {
        s
    };
    let coefficients: Vec<f64> = a.iter().map(|v| v * rescale).collect();
    if coefficients.iter().any(|v| !v.is_finite()) {
        return None;
    }
    Some(LocalFit {
        poly: ImplicitPolynomial {
            degree: 2,
            coefficients,
            center: mu,
            scale: s,
        },
        max_error,
        rms_error,
    })
}

/// The largest and the root mean square of `error(i)` over `measure`, stopping after the first
/// error above `stop_above` (the root mean square is then over the points measured so far).
fn measure_errors(measure: &[u32], stop_above: f64, error: impl Fn(u32) -> f64) -> (f64, f64) {
    let (mut max, mut sum2, mut count) = (0.0f64, 0.0, 0usize);
    for &i in measure {
        let e = error(i);
        max = max.max(e);
        sum2 += e * e;
        count += 1;
        if max > stop_above {
            break;
        }
    }
    (max, (sum2 / count.max(1) as f64).sqrt())
}

/// The weight of the auxiliary rows: the fitted points over the measured ones (1 when the
/// ball is fitted whole). The rows of an [`even_subsample`] stand for the whole ball, so the
/// auxiliary rows keep the share they have among all its rows; at weight 1 they outweighed a
/// subsample of a dense ball and pulled its zero set off the data (CHANGELOG.md).
fn aux_weight(ball: &[u32], measure: &[u32]) -> f64 {
    if measure.len() > ball.len() && !ball.is_empty() {
        ball.len() as f64 / measure.len() as f64
    } else {
        1.0
    }
}

/// A ball holding more points than this is fitted on [`even_subsample`] of them, the error
/// being still measured over all of them.
pub(crate) const SUBSAMPLE_ABOVE: usize = 1024;

/// The points a subsampled ball's fit uses. A local fit has at most 35 unknowns (10 for the
/// default quadric), while a dense scan puts tens of thousands of points in the balls of the
/// upper levels, each adding three rows: without a cap the cost of a fit grows with the points
/// per ball for no gain in the fit (its measurement on a 1M-point torus is in CHANGELOG.md).
pub(crate) const SUBSAMPLE_POINTS: usize = 512;

/// A deterministic, spatially even subsample of `ball` (indices of points in Z order, listed in
/// increasing order, as the detail fit keeps them): [`SUBSAMPLE_POINTS`] points taken at an
/// even stride through the list, so one from each run of consecutive points along the Z-order
/// curve, and each such run is a compact patch of the ball. Like the whole ball, the subsample
/// follows the scan's density. `ball` itself when it is no larger.
pub(crate) fn even_subsample(ball: &[u32]) -> Vec<u32> {
    let n = ball.len();
    if n <= SUBSAMPLE_POINTS {
        return ball.to_vec();
    }
    (0..SUBSAMPLE_POINTS)
        .map(|j| ball[(j * n + n / 2) / SUBSAMPLE_POINTS])
        .collect()
}

/// Step 4's re-centring of a fit whose value and gradient at the ball's point `i` are
/// `value_gradient(i)`: the constant to subtract so that the weighted mean of f/|∇f| over the
/// ball becomes 0, and the sum of |∇f| over the ball (for the rescaling: the gradient does not
/// depend on the constant the shift moves).
///
/// Each point weighs its blend weight b(1.5·|p − c|/r) for the cell's weight centre c and
/// support radius r, times its row weight ([`RowWeights`]). Without a blend, or when no
/// point of the ball lies inside the support (a grown cell's far points), every blend weight is
/// 1: a second pass, rare. The shift is 0 when the weights sum to nothing or it is not finite.
fn recentring(
    points: &[[f64; 3]],
    ball: &[u32],
    blend: Option<([f64; 3], f64)>,
    weights: RowWeights<'_>,
    value_gradient: impl Fn(u32) -> (f64, [f64; 3]),
) -> (f64, f64) {
    let (mut vsum, mut wsum, mut bsum, mut gsum) = (0.0, 0.0, 0.0, 0.0);
    let blend_k = blend.map(|(c, r)| (c, 1.5 / r));
    for (j, &i) in ball.iter().enumerate() {
        let (v, g) = value_gradient(i);
        let gn = vec3::norm(g);
        gsum += gn;
        if let Some((centre, k)) = blend_k {
            let gn = gn.max(1e-12);
            let b = super::index::bspline(k * dist(points[i as usize], centre)).0;
            bsum += b;
            // × 1.0 is exact: a cloud without confidences gets the blend weight's own bits.
            let w = b * weights.of(j, i);
            vsum += w * v / gn;
            wsum += w / gn;
        }
    }
    if blend.is_none() || bsum <= 1e-9 {
        (vsum, wsum) = (0.0, 0.0);
        for (j, &i) in ball.iter().enumerate() {
            let (v, g) = value_gradient(i);
            let gn = vec3::norm(g).max(1e-12);
            let w = weights.of(j, i);
            vsum += w * v / gn;
            wsum += w / gn;
        }
    }
    let shift = if wsum > 0.0 && vsum.is_finite() {
        vsum / wsum
    } else {
        0.0
    };
    (shift, gsum)
}

/// The 10 monomials of degree ≤ 2 at `q` in the paper's order.
#[inline(always)]
fn quadric_monomials(q: [f64; 3]) -> [f64; 10] {
    let [x, y, z] = q;
    [1.0, x, y, z, x * x, x * y, x * z, y * y, y * z, z * z]
}

/// The value and gradient at `q` of the quadric with coefficients `a` in the order of
/// [`quadric_monomials`] (the value in Horner form).
#[inline(always)]
fn quadric_value_gradient(a: &[f64], q: [f64; 3]) -> (f64, [f64; 3]) {
    let v = a[0]
        + q[0] * (a[1] + a[4] * q[0] + a[5] * q[1] + a[6] * q[2])
        + q[1] * (a[2] + a[7] * q[1] + a[8] * q[2])
        + q[2] * (a[3] + a[9] * q[2]);
    let g = [
        a[1] + 2.0 * a[4] * q[0] + a[5] * q[1] + a[6] * q[2],
        a[2] + a[5] * q[0] + 2.0 * a[7] * q[1] + a[8] * q[2],
        a[3] + a[6] * q[0] + a[8] * q[1] + 2.0 * a[9] * q[2],
    ];
    (v, g)
}

/// Adds w·m·mᵀ to the packed upper triangle (row-major) of a 10 × 10 matrix (the same bits as
/// m·mᵀ when w = 1).
#[inline(always)]
fn add_packed(ata: &mut [f64; 55], m: &[f64; 10], w: f64) {
    let mut k = 0;
    for i in 0..10 {
        let mi = w * m[i];
        for mj in &m[i..] {
            ata[k] += mi * mj;
            k += 1;
        }
    }
}

/// The moments a local fit of degree ≤ 4 sums: the monomials of degree ≤ 8.
const MOMENTS_MAX: usize = 165;

/// The normal equations of a degree-`n` fit's value rows (target 0) and gradient rows
/// (∇Q̂ = n) from the points' moments: `moments[l]` = Σ w·m_l(q) over the monomials of degree
/// ≤ 2n and `normal_moments[a][l]` = Σ w·n_a·m_l(q) over those of degree ≤ n − 1, in the order
/// of [`monomials`]. Adds to the upper triangle of `ata` (row-major c × c) and to `atb` the sums
/// the rows' rank-one updates make, in other order. With ∂_a(x^e) = e_a·x^(e − 1_a):
/// - MᵀM_ij = Σ w·(mᵢmⱼ + ∇mᵢ·∇mⱼ), where mᵢmⱼ = x^(eᵢ + eⱼ) and ∂_a mᵢ ∂_a mⱼ =
///   eᵢ_a eⱼ_a x^(eᵢ + eⱼ − 2·1_a);
/// - Mᵀb_l = Σ w·∇m_l·n = Σ_a e_l,a Σ w·n_a·x^(e_l − 1_a).
fn gradient_normal_equations(
    n: usize,
    moments: &[f64],
    normal_moments: &[[f64; 20]; 3],
    ata: &mut [f64],
    atb: &mut [f64],
) {
    let exponents = exponents(n as u32);
    let c = exponents.len();
    for (i, ei) in exponents.iter().enumerate() {
        for (j, ej) in exponents.iter().enumerate().skip(i) {
            let sum: [u32; 3] = [0, 1, 2].map(|a| ei[a] + ej[a]);
            let mut v = moments[monomial_index(sum)];
            for a in 0..3 {
                if ei[a] > 0 && ej[a] > 0 {
                    let mut e = sum;
                    e[a] -= 2;
                    v += f64::from(ei[a] * ej[a]) * moments[monomial_index(e)];
                }
            }
            ata[i * c + j] += v;
        }
        for a in 0..3 {
            if ei[a] > 0 {
                let mut e = *ei;
                e[a] -= 1;
                atb[i] += f64::from(ei[a]) * normal_moments[a][monomial_index(e)];
            }
        }
    }
}

fn factorial(k: usize) -> f64 {
    (1..=k).map(|v| v as f64).product()
}

/// Solves the symmetric positive definite system whose upper triangle is in `a` (row-major
/// `c × c`) with right-hand side `b`, by Cholesky. `None` when it is not positive definite.
fn cholesky_solve(a: &mut [f64], b: &mut [f64], c: usize) -> Option<Vec<f64>> {
    // The factorization reads the lower triangle: mirror the upper one into it.
    for i in 0..c {
        for j in i + 1..c {
            a[j * c + i] = a[i * c + j];
        }
    }
    cholesky::factor(a, c, 0.0).ok()?;
    // `factor` accepts an infinite pivot; a local fit with one has failed.
    if (0..c).any(|i| !a[i * c + i].is_finite()) {
        return None;
    }
    cholesky::solve(a, c, b);
    Some(b.to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monomials_follow_the_paper_order() {
        let mut m = [0.0; 10];
        monomials(2, [2.0, 3.0, 5.0], &mut m);
        assert_eq!(m, [1.0, 2.0, 3.0, 5.0, 4.0, 6.0, 10.0, 9.0, 15.0, 25.0]);
    }

    /// `fit_local` over all of `points` (fitted and measured), with no stop, no auxiliary
    /// points, no blend and unit confidence.
    fn fit_all(
        points: &[[f64; 3]],
        normals: &[[f64; 3]],
        degree: u32,
        constraints: Constraints,
        kappa: f64,
    ) -> LocalFit {
        let idx: Vec<u32> = (0..points.len() as u32).collect();
        fit_local(
            points,
            normals,
            &idx,
            &idx,
            f64::INFINITY,
            &[],
            degree,
            constraints,
            kappa,
            1.0,
            None,
            RowWeights::default(),
        )
        .unwrap()
    }

    #[test]
    fn plane_patch_gives_signed_distance() {
        // Points on z = 0.5 with normals +z: Q ≈ z − 0.5 with unit gradient.
        let mut points = Vec::new();
        for i in 0..10 {
            for j in 0..10 {
                points.push([i as f64 * 0.1, j as f64 * 0.1, 0.5]);
            }
        }
        let normals = vec![[0.0, 0.0, 1.0]; points.len()];
        for constraints in [Constraints::Gradient, Constraints::ThreeLevels(0.3)] {
            let fit = fit_all(&points, &normals, 2, constraints, 1e-2);
            assert!(fit.max_error < 1e-6, "{}", fit.max_error);
            for p in [[0.4, 0.4, 0.6], [0.5, 0.3, 0.45]] {
                let v = fit.poly.eval(p);
                assert!((v - (p[2] - 0.5)).abs() < 1e-3, "{v}");
            }
        }
    }

    #[test]
    fn monomial_gradients_match_the_quadric_ones() {
        let mut g = [[0.0; 35]; 3];
        monomial_gradients(2, [2.0, 3.0, 5.0], &mut g);
        assert_eq!(
            &g[0][..10],
            &[0.0, 1.0, 0.0, 0.0, 4.0, 3.0, 5.0, 0.0, 0.0, 0.0]
        );
        assert_eq!(
            &g[1][..10],
            &[0.0, 0.0, 1.0, 0.0, 0.0, 2.0, 0.0, 6.0, 5.0, 0.0]
        );
        assert_eq!(
            &g[2][..10],
            &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 2.0, 0.0, 3.0, 10.0]
        );
        // Central differences at degree 4.
        let q = [0.3, -0.7, 0.4];
        monomial_gradients(4, q, &mut g);
        let (mut up, mut down) = ([0.0; 35], [0.0; 35]);
        for a in 0..3 {
            let mut qa = q;
            qa[a] += 1e-6;
            monomials(4, qa, &mut up);
            qa[a] -= 2e-6;
            monomials(4, qa, &mut down);
            for l in 0..35 {
                let fd = (up[l] - down[l]) / 2e-6;
                assert!((fd - g[a][l]).abs() < 1e-8, "{a} {l}: {fd} vs {}", g[a][l]);
            }
        }
    }

    #[test]
    fn the_moments_give_the_rows_normal_equations() {
        // Random points and unit normals, weights: the normal equations the moments assemble
        // are the sums of the value and gradient rows' rank-one updates, to rounding.
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let rows: Vec<([f64; 3], [f64; 3], f64)> = (0..50)
            .map(|_| {
                let q = [next(), next(), next()];
                let v = [next(), next(), next()];
                let n = v.map(|c| c / vec3::norm(v));
                (q, n, 0.5 + 0.5 * next().abs())
            })
            .collect();
        for n in 2..=4 {
            let c = n_coefficients(n as u32);
            let (mut ata, mut atb) = (vec![0.0; c * c], vec![0.0; c]);
            let (mut mon, mut grads) = ([0.0; 35], [[0.0; 35]; 3]);
            for &(q, nv, w) in &rows {
                monomials(n, q, &mut mon);
                monomial_gradients(n, q, &mut grads);
                for i in 0..c {
                    for j in i..c {
                        let g: f64 = (0..3).map(|a| grads[a][i] * grads[a][j]).sum();
                        ata[i * c + j] += w * (mon[i] * mon[j] + g);
                    }
                    atb[i] += w * (0..3).map(|a| grads[a][i] * nv[a]).sum::<f64>();
                }
            }
            let mut moments = [0.0; MOMENTS_MAX];
            let mut normal_moments = [[0.0; 20]; 3];
            let mut all = [0.0; MOMENTS_MAX];
            for &(q, nv, w) in &rows {
                monomials(2 * n, q, &mut all);
                for l in 0..n_coefficients(2 * n as u32) {
                    moments[l] += w * all[l];
                }
                for a in 0..3 {
                    for l in 0..n_coefficients(n as u32 - 1) {
                        normal_moments[a][l] += w * nv[a] * all[l];
                    }
                }
            }
            let (mut ata_m, mut atb_m) = (vec![0.0; c * c], vec![0.0; c]);
            gradient_normal_equations(n, &moments, &normal_moments, &mut ata_m, &mut atb_m);
            for i in 0..c {
                for j in i..c {
                    let (a, b) = (ata[i * c + j], ata_m[i * c + j]);
                    assert!(
                        (a - b).abs() <= 1e-12 * a.abs().max(1.0),
                        "{n} {i} {j}: {a} {b}"
                    );
                }
                assert!(
                    (atb[i] - atb_m[i]).abs() <= 1e-12 * atb[i].abs().max(1.0),
                    "{n} {i}"
                );
            }
        }
    }

    #[test]
    fn sphere_cap_has_no_offset_with_gradient_rows() {
        // A cap of the unit sphere: gradient rows give back the sphere, the 3L rows do not.
        let mut points = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                let (x, y) = (i as f64 * 0.04 - 0.4, j as f64 * 0.04 - 0.4);
                points.push([x, y, (1.0 - x * x - y * y).sqrt()]);
            }
        }
        let normals = points.clone();
        for degree in [2, 3] {
            let fit = fit_all(&points, &normals, degree, Constraints::Gradient, 1e-6);
            assert!(fit.max_error < 1e-5, "{degree}: {}", fit.max_error);
            let three = fit_all(
                &points,
                &normals,
                degree,
                Constraints::ThreeLevels(0.3),
                1e-6,
            );
            assert!(three.max_error > 1e-4, "{degree}: {}", three.max_error);
        }
    }
}
