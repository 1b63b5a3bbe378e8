//! Certificates of the sign of a candidate polynomial far from the data, for rule (d) of the
//! stable κ rule: a log-polar probe of point values (a negative value proves that the zero set
//! reaches out there), Bernstein bounds on frustums of the cube's faces (proving f > 0 from one
//! box norm out to another), and an octree of Taylor-form enclosures on a shell between boxes.
//!
//! Input: a polynomial in normalized coordinates and the radii. Output: a [`Shell`] verdict or a
//! yes/no answer; every verdict is exact (a point value or a guaranteed bound) and does not
//! depend on the thread count.

use crate::cloud::Aabb;
use crate::implicit::ImplicitFunction;
use crate::poly::ImplicitPolynomial;

/// What [`shell_sign`] established about f on a shell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Shell {
    /// f > 0 on the whole shell (certified by enclosures).
    Positive,
    /// f < 0 at some point of the shell (a point value).
    Negative,
    /// Neither within the refinement limits.
    Unknown,
}

/// Patches per face side and radial steps per doubling of [`far_probe_negative`].
pub(super) const PROBE_PATCHES: usize = 24;
/// Radial samples per doubling of the box norm in [`far_probe_negative`].
pub(super) const PROBE_STEPS_PER_OCTAVE: usize = 8;

/// Whether f (normalized coordinates) is negative at one of a fixed set of sample points with
/// box norm |p|∞ in [s_lo, s_hi]: on each face of the cube |q|∞ = 1 the centres of a
/// `PROBE_PATCHES`² grid of patches, scaled by box norms spaced geometrically (eight a doubling)
/// from s_lo to s_hi. A negative sample is a proof (a point value); none proves nothing.
///
/// The value at p = s·q is f(s·q) = Σ_k s^k H_k(q): the forms H_k are evaluated once per
/// direction q (from [`FaceForms`]) and each radius costs one Horner step per degree, about 40×
/// less than evaluating f afresh. The verdict is that of the plain point values
/// ([`ImplicitPolynomial::eval_many`]): a radial value is trusted only when it is farther from 0
/// than `PROBE_MARGIN` × Σ_k s^k Σ|a_e q^e| (both evaluations differ from the exact value by a
/// few hundred units of rounding of that sum at most), and the rare sample closer to 0 is
/// evaluated as before.
pub(super) fn far_probe_negative(poly: &ImplicitPolynomial, s_lo: f64, s_hi: f64) -> bool {
    use rayon::prelude::*;
    if !(s_lo > 0.0 && s_hi > s_lo && s_hi.is_finite()) {
        return false;
    }
    let steps = ((s_hi / s_lo).log2() * PROBE_STEPS_PER_OCTAVE as f64)
        .ceil()
        .max(1.0) as usize;
    let ratio = (s_hi / s_lo).powf(1.0 / steps as f64);
    let radii: Vec<f64> = (0..=steps).map(|j| s_lo * ratio.powi(j as i32)).collect();
    let forms = FaceForms::new(poly);
    let side = forms.degree + 1;
    (0..6 * PROBE_PATCHES).into_par_iter().any(|row| {
        let face = row / PROBE_PATCHES;
        let i = row % PROBE_PATCHES;
        let axis = face / 2;
        let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
        let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
        let (b, c) = (b.min(c), b.max(c));
        let step = 2.0 / PROBE_PATCHES as f64;
        let u = -1.0 + (i as f64 + 0.5) * step;
        let mut pu = vec![1.0; side];
        let mut pv = vec![1.0; side];
        for e in 1..side {
            pu[e] = pu[e - 1] * u;
        }
        let mut h = vec![0.0; side];
        let mut a = vec![0.0; side];
        let mut unsure = Vec::new();
        for j in 0..PROBE_PATCHES {
            let v = -1.0 + (j as f64 + 0.5) * step;
            for e in 1..side {
                pv[e] = pv[e - 1] * v;
            }
            for (k, form) in forms.forms[face].iter().enumerate() {
                let (mut hk, mut ak) = (0.0, 0.0);
                for iu in 0..=k {
                    for jv in 0..=(k - iu) {
                        let t = form[iu * side + jv] * pu[iu] * pv[jv];
                        hk += t;
                        ak += t.abs();
                    }
                }
                h[k] = hk;
                a[k] = ak;
            }
            for &s in &radii {
                let (mut f, mut m) = (0.0, 0.0);
                for (hk, ak) in h.iter().zip(&a).rev() {
                    f = f * s + hk;
                    m = m * s + ak;
                }
                if f < -PROBE_MARGIN * m {
                    return true;
                }
                if f.abs() <= PROBE_MARGIN * m || !f.is_finite() {
                    let mut p = [0.0; 3];
                    p[axis] = sign * s;
                    p[b] = u * s;
                    p[c] = v * s;
                    unsure.push(p);
                }
            }
        }
        if unsure.is_empty() {
            return false;
        }
        let mut values = vec![0.0; unsure.len()];
        poly.eval_many(&unsure, &mut values);
        values.iter().any(|&f| f < 0.0)
    })
}

/// Relative distance from 0 (of the sum of the terms' magnitudes) beyond which
/// [`far_probe_negative`] trusts the sign of its radial evaluation: far above the rounding of
/// either evaluation of a polynomial of degree ≤ 20 (a few hundred units of 1.1e-16).
pub(super) const PROBE_MARGIN: f64 = 1e-9;

/// Deepest subdivision level of [`far_sign`].
pub(super) const FAR_MAX_LEVEL: u32 = 10;
/// Most cells [`far_sign`] examines on one level before it gives up.
pub(super) const FAR_MAX_CELLS: usize = 20_000;

/// The homogeneous parts H_k of a polynomial (normalized coordinates) restricted to the six
/// faces of the cube |q|∞ = 1: on the face q_a = σ, H_k(q) is a polynomial in the other two
/// coordinates (u, v), stored densely by (i, j) for u^i v^j, i + j ≤ k.
pub(super) struct FaceForms {
    pub(super) degree: usize,
    /// `forms[face][k][i * (degree + 1) + j]`, face = 2·axis + (σ < 0).
    pub(super) forms: Vec<Vec<Vec<f64>>>,
    /// The same forms for k ≥ 1 in groups of [`FORM_LANES`] side by side, which
    /// [`FaceForms::lower_bounds`] reads: `groups[face][g][i * (top + 1) + j]` holds the
    /// coefficient of u^i v^j of H_k, k = 1 + 4g + lane, for i + j ≤ top = 4 + 4g (zero where
    /// i + j > k or k > degree).
    pub(super) groups: Vec<Vec<Vec<[f64; FORM_LANES]>>>,
    /// [`bernstein_ratios`] of the degree.
    pub(super) bernstein: Vec<f64>,
}

/// Face forms processed side by side by [`FaceForms::lower_bounds`].
pub(super) const FORM_LANES: usize = 4;

impl FaceForms {
    pub(super) fn new(poly: &ImplicitPolynomial) -> FaceForms {
        let n = poly.degree as usize;
        let side = n + 1;
        let exps = crate::poly::exponents(poly.degree);
        let mut forms = vec![vec![vec![0.0; side * side]; n + 1]; 6];
        for (face, per_face) in forms.iter_mut().enumerate() {
            let axis = face / 2;
            let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
            let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
            let (b, c) = (b.min(c), b.max(c));
            for (e, &coef) in exps.iter().zip(&poly.coefficients) {
                let k = (e[0] + e[1] + e[2]) as usize;
                let s = if e[axis] % 2 == 1 { sign } else { 1.0 };
                if let Some(form) = per_face.get_mut(k) {
                    form[e[b] as usize * side + e[c] as usize] += s * coef;
                }
            }
        }
        let groups = forms
            .iter()
            .map(|per_face| {
                (1..=n)
                    .step_by(FORM_LANES)
                    .map(|k0| {
                        let top = k0 + FORM_LANES - 1;
                        let side_g = top + 1;
                        let mut group = vec![[0.0; FORM_LANES]; side_g * side_g];
                        for (lane, form) in per_face.iter().skip(k0).take(FORM_LANES).enumerate() {
                            let k = k0 + lane;
                            for i in 0..=k {
                                for j in 0..=k - i {
                                    group[i * side_g + j][lane] = form[i * side + j];
                                }
                            }
                        }
                        group
                    })
                    .collect()
            })
            .collect();
        FaceForms {
            degree: n,
            forms,
            groups,
            bernstein: bernstein_ratios(n),
        }
    }

    /// Lower bounds of H_k, k = 0 … n, on the patch (u, v) ∈ [uc ± w] × [vc ± w] of `face`:
    /// the Taylor expansion at the patch centre, each non-constant term bounded by its absolute
    /// value at the half width (a centred form, exact for the constant term), less a rounding
    /// margin.
    ///
    /// The forms are shifted four at a time, one lane each ([`FaceForms::groups`]), with the
    /// steps of the group's top degree: a form of lower degree k gets extra steps only where its
    /// entries are zero (i + j > k), which add zero to a coefficient that is not −0 (it starts
    /// at +0) and leave it bit for bit unchanged, so every bound is the one of the form's own
    /// steps.
    pub(super) fn lower_bounds(&self, face: usize, uc: f64, vc: f64, w: f64) -> Vec<f64> {
        let n = self.degree;
        let mut out = Vec::with_capacity(n + 1);
        // H_0 is a constant: no shift, nothing spread.
        let h0 = self.forms[face][0][0];
        out.push(h0 - 0.0 - 1e-12 * (h0.abs() + h0.abs()));
        let mut d = Vec::new();
        for (g, group) in self.groups[face].iter().enumerate() {
            let k0 = 1 + g * FORM_LANES;
            let top = k0 + FORM_LANES - 1;
            let side = top + 1;
            d.clear();
            d.extend_from_slice(group);
            // Taylor shift in u (for each power j of v), then in v (for each power i of u).
            for j in 0..=top {
                let m = top - j;
                for i in 0..m {
                    for t in (i..m).rev() {
                        let next = d[(t + 1) * side + j];
                        for (a, b) in d[t * side + j].iter_mut().zip(next) {
                            *a += uc * b;
                        }
                    }
                }
            }
            for i in 0..=top {
                let m = top - i;
                for jj in 0..m {
                    for t in (jj..m).rev() {
                        let next = d[i * side + t + 1];
                        for (a, b) in d[i * side + t].iter_mut().zip(next) {
                            *a += vc * b;
                        }
                    }
                }
            }
            let mut spread = [0.0; FORM_LANES];
            let mut magnitude = d[0].map(f64::abs);
            let mut wi = 1.0;
            for i in 0..=top {
                let mut wij = wi;
                for j in 0..=(top - i) {
                    let entry = d[i * side + j];
                    for lane in 0..FORM_LANES {
                        if i + j > 0 {
                            spread[lane] += entry[lane].abs() * wij;
                        }
                        magnitude[lane] += entry[lane].abs();
                    }
                    wij *= w;
                }
                wi *= w;
            }
            for lane in 0..FORM_LANES.min(n + 1 - k0) {
                out.push(d[0][lane] - spread[lane] - 1e-12 * magnitude[lane]);
            }
        }
        out
    }
}

/// The factors C(i, j) / C(n, j) (i, j ≤ n, row-major) that turn power-basis coefficients on
/// [0, 1] into Bernstein ones, for [`positive_on_interval`].
pub(super) fn bernstein_ratios(n: usize) -> Vec<f64> {
    let binom = |a: usize, b: usize| -> f64 {
        let mut r = 1.0;
        for t in 0..b {
            r = r * (a - t) as f64 / (t + 1) as f64;
        }
        r
    };
    let mut ratios = vec![0.0; (n + 1) * (n + 1)];
    for i in 0..=n {
        for j in 0..=i {
            ratios[i * (n + 1) + j] = binom(i, j) / binom(n, j);
        }
    }
    ratios
}

/// Whether Σ_k c_k s^k > 0 for every s in [s0, s1] (0 < s0 ≤ s1), by the Bernstein
/// coefficients on that interval: all positive proves it (the polynomial is a convex
/// combination of them); otherwise the answer is "not proved". `ratios` are
/// [`bernstein_ratios`] of the degree `c.len() − 1`.
pub(super) fn positive_on_interval(c: &[f64], ratios: &[f64], s0: f64, s1: f64) -> bool {
    let n = c.len().saturating_sub(1);
    let mut g = c.to_vec();
    // Taylor shift by s0, then scale by h = s1 − s0: g(t) = Σ c_k (s0 + h t)^k.
    for i in 0..n {
        for t in (i..n).rev() {
            g[t] += s0 * g[t + 1];
        }
    }
    let h = s1 - s0;
    let mut hp = 1.0;
    for gj in g.iter_mut() {
        *gj *= hp;
        hp *= h;
    }
    // Power basis on [0, 1] to Bernstein: b_i = Σ_{j ≤ i} C(i, j) / C(n, j) g_j.
    let magnitude: f64 = g.iter().map(|v| v.abs()).sum();
    (0..=n).all(|i| {
        let row = &ratios[i * (n + 1)..=i * (n + 1) + i];
        let b: f64 = row.iter().zip(&g).map(|(r, gj)| r * gj).sum();
        b.is_finite() && b > 1e-12 * magnitude
    })
}

/// What one octree cell of [`far_sign`] or [`shell_sign`] settles about f.
pub(super) enum Verdict {
    /// f > 0 on the cell (certified) or the cell is outside the region: dropped.
    Drop,
    /// f < 0 at a point of the cell.
    Negative,
    /// Neither: refine.
    Split,
}

/// The shell's sign once a level's verdicts are in: negative as soon as one cell is; at the
/// last level positive only if every cell was dropped, else unknown; `None` to refine further.
pub(super) fn level_outcome(verdicts: &[Verdict], last_level: bool) -> Option<Shell> {
    if verdicts.iter().any(|v| matches!(v, Verdict::Negative)) {
        return Some(Shell::Negative);
    }
    if !last_level {
        return None;
    }
    Some(if verdicts.iter().all(|v| matches!(v, Verdict::Drop)) {
        Shell::Positive
    } else {
        Shell::Unknown
    })
}

/// A frustum of the shell between |p̂|∞ = s₀ and s₁: face, patch centre u, v, patch half width,
/// radial interval s₀, s₁.
pub(super) type Frustum = (usize, f64, f64, f64, f64, f64);

/// The starting frustums of the shell s_lo ≤ |p̂|∞ ≤ s_hi: each whole face of the cube, its
/// radial range cut where s doubles (a flat frustum per face when s_lo = s_hi: the surface of
/// the cube |p̂|∞ = s_lo).
pub(super) fn whole_faces(s_lo: f64, s_hi: f64) -> Vec<Frustum> {
    let mut cells = Vec::new();
    for face in 0..6 {
        if s_hi == s_lo {
            cells.push((face, 0.0, 0.0, 1.0, s_lo, s_lo));
            continue;
        }
        let mut s0 = s_lo;
        while s0 < s_hi {
            let s1 = (2.0 * s0).min(s_hi);
            cells.push((face, 0.0, 0.0, 1.0, s0, s1));
            s0 = s1;
        }
    }
    cells
}

/// The sign of f (normalized coordinates) on the points whose box norm |p|∞ lies in
/// [s_lo, s_hi] (0 < s_lo; s_lo = s_hi gives the cube's surface, whose frustums are flat and
/// split across only; an empty range is positive): each point is p = s·q with q on a face of
/// the cube |q|∞ = 1, and f(s·q) = Σ_k s^k H_k(q), so lower bounds of each H_k on a patch of a
/// face give a polynomial in s below f on the whole frustum (patch × [s0, s1]), which is
/// positive when its Bernstein coefficients are. Frustums not proved positive are split (the patch in four, the
/// radial interval in two, geometrically) level by level, and the first frustum whose centre
/// has f < 0 stops the search. The patches are exact in s, which is why this proves f > 0 far
/// from the data where the box enclosures of [`shell_sign`] cannot (f grows like sⁿ there, and
/// the box forms lose that cancellation). The verdict does not depend on the thread count.
pub(super) fn far_sign(poly: &ImplicitPolynomial, s_lo: f64, s_hi: f64) -> Shell {
    use rayon::prelude::*;
    if !(s_lo > 0.0 && s_hi.is_finite()) {
        return Shell::Unknown;
    }
    if s_hi < s_lo {
        return Shell::Positive;
    }
    if poly.coefficients.iter().any(|c| !c.is_finite()) {
        return Shell::Unknown;
    }
    let forms = FaceForms::new(poly);
    let mut cells = whole_faces(s_lo, s_hi);
    for level in 0..=FAR_MAX_LEVEL {
        if cells.is_empty() {
            return Shell::Positive;
        }
        if cells.len() > FAR_MAX_CELLS {
            return Shell::Unknown;
        }
        let by_bernstein = std::sync::atomic::AtomicUsize::new(0);
        let verdicts: Vec<Verdict> = cells
            .par_iter()
            .map(|&(face, uc, vc, w, s0, s1)| {
                let lower = forms.lower_bounds(face, uc, vc, w);
                if positive_on_interval(&lower, &forms.bernstein, s0, s1) {
                    by_bernstein.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    return Verdict::Drop;
                }
                let axis = face / 2;
                let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
                let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
                let (b, c) = (b.min(c), b.max(c));
                // The frustum's bounding box, and the Taylor-form enclosure of f on it: second
                // order, so it also proves f > 0 near a shallow positive minimum, where the
                // per-degree bounds above (first order in the patch size) cannot.
                let span = |lo: f64, hi: f64| {
                    let v = [lo * s0, lo * s1, hi * s0, hi * s1];
                    (
                        v.iter().copied().fold(f64::INFINITY, f64::min),
                        v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                    )
                };
                let mut bmin = [0.0; 3];
                let mut bmax = [0.0; 3];
                let (lo_a, hi_a) = if sign > 0.0 { (s0, s1) } else { (-s1, -s0) };
                bmin[axis] = lo_a;
                bmax[axis] = hi_a;
                (bmin[b], bmax[b]) = span(uc - w, uc + w);
                (bmin[c], bmax[c]) = span(vc - w, vc + w);
                let (lo, _) = poly.bounds_on_box(&Aabb {
                    min: bmin,
                    max: bmax,
                });
                if lo > 0.0 {
                    return Verdict::Drop;
                }
                let s = (s0 * s1).sqrt();
                let mut p = [0.0; 3];
                p[axis] = sign * s;
                p[b] = uc * s;
                p[c] = vc * s;
                if poly.value(p) < 0.0 {
                    Verdict::Negative
                } else {
                    Verdict::Split
                }
            })
            .collect();
        log::trace!("      far_sign {s_lo:.2}..{s_hi:.2} level {level}: {} frustums, {} by bernstein, {} split", cells.len(), by_bernstein.into_inner(), verdicts.iter().filter(|v| matches!(v, Verdict::Split)).count());
        if let Some(shell) = level_outcome(&verdicts, level == FAR_MAX_LEVEL) {
            return shell;
        }
        cells = cells
            .iter()
            .zip(&verdicts)
            .filter(|(_, v)| matches!(v, Verdict::Split))
            .flat_map(|(&(face, uc, vc, w, s0, s1), _)| {
                // Split so that the frustums stay about as wide as they are deep: the patch
                // (tangential extent 2w·s) in four, the radial interval in two, or both.
                let sm = (s0 * s1).sqrt();
                let tangential = 2.0 * w * sm;
                let radial = s1 - s0;
                let split_patch = tangential > 0.75 * radial;
                let split_radial = radial > 0.75 * tangential;
                let h = if split_patch { 0.5 * w } else { w };
                let patches: Vec<(f64, f64)> = if split_patch {
                    vec![
                        (uc - h, vc - h),
                        (uc + h, vc - h),
                        (uc - h, vc + h),
                        (uc + h, vc + h),
                    ]
                } else {
                    vec![(uc, vc)]
                };
                let radials: Vec<(f64, f64)> = if split_radial {
                    vec![(s0, sm), (sm, s1)]
                } else {
                    vec![(s0, s1)]
                };
                let mut children = Vec::with_capacity(8);
                for &(a, b) in &radials {
                    for &(u, v) in &patches {
                        children.push((face, u, v, h, a, b));
                    }
                }
                children
            })
            .collect();
    }
    Shell::Unknown
}

/// [`far_positive`]'s frustums are split across while wider than this times their depth: long
/// thin frustums suit it, since its bound is exact along the rays and loose only across them.
pub(super) const FAR_POSITIVE_RATIO: f64 = 0.25;

/// Whether f > 0 is certified on the points with box norm in [s_lo, s_hi] (0 < s_lo < s_hi
/// finite) by the Bernstein test of [`far_sign`]'s face forms alone: no point values, no box
/// enclosures (a point value < 0 at a frustum's centre ends the search). A frustum not proved
/// positive is split across (the patch in four) while it is
/// wider than `ratio` times its depth, else along (the radial interval in two); `false` means
/// "not proved" (the refinement limits were reached). Used only as a certificate that lets the
/// mesher skip cells ([`FarCulled`]), so it may give up where [`far_sign`] would not.
pub(super) fn far_positive(poly: &ImplicitPolynomial, s_lo: f64, s_hi: f64, ratio: f64) -> bool {
    use rayon::prelude::*;
    if !(s_lo > 0.0 && s_hi.is_finite()) || poly.coefficients.iter().any(|c| !c.is_finite()) {
        return false;
    }
    let forms = FaceForms::new(poly);
    let mut cells = whole_faces(s_lo, s_hi);
    let mut total = 0usize;
    for level in 0..=2 * FAR_MAX_LEVEL {
        if cells.is_empty() {
            log::trace!("      far_positive {s_lo:.2}..{s_hi:.2} ratio {ratio}: {total} frustums, {level} levels");
            return true;
        }
        if cells.len() > 4 * FAR_MAX_CELLS {
            break;
        }
        total += cells.len();
        let negative = std::sync::atomic::AtomicBool::new(false);
        cells = cells
            .par_iter()
            .flat_map_iter(|&(face, uc, vc, w, s0, s1)| {
                let lower = forms.lower_bounds(face, uc, vc, w);
                let mut children = Vec::new();
                if positive_on_interval(&lower, &forms.bernstein, s0, s1) {
                    return children;
                }
                let sm = (s0 * s1).sqrt();
                // f < 0 at the frustum's centre: nothing to prove, stop early.
                let axis = face / 2;
                let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
                let (b, c) = (b.min(c), b.max(c));
                let mut p = [0.0; 3];
                p[axis] = if face.is_multiple_of(2) { sm } else { -sm };
                p[b] = uc * sm;
                p[c] = vc * sm;
                if poly.value(p) < 0.0 {
                    negative.store(true, std::sync::atomic::Ordering::Relaxed);
                    return children;
                }
                if 2.0 * w * sm > ratio * (s1 - s0) {
                    let h = 0.5 * w;
                    for (u, v) in [
                        (uc - h, vc - h),
                        (uc + h, vc - h),
                        (uc - h, vc + h),
                        (uc + h, vc + h),
                    ] {
                        children.push((face, u, v, h, s0, s1));
                    }
                } else {
                    children.push((face, uc, vc, w, s0, sm));
                    children.push((face, uc, vc, w, sm, s1));
                }
                children
            })
            .collect();
        if negative.into_inner() {
            break;
        }
    }
    log::trace!("      far_positive {s_lo:.2}..{s_hi:.2} ratio {ratio}: {total} frustums, gave up");
    false
}

/// Deepest level of [`shell_sign`]'s octree.
pub(super) const SHELL_MAX_LEVEL: u32 = 8;
/// Most cells [`shell_sign`] examines on one level before it gives up.
pub(super) const SHELL_MAX_CELLS: usize = 40_000;

/// The sign of f (normalized coordinates) on the shell [−outer, outer]³ minus the open box
/// (−hole, hole)³: an octree over the outer box, level by level, drops the cells inside the
/// hole and those whose guaranteed enclosure (the Taylor form of
/// [`ImplicitFunction::bounds_on_box`]) is positive, and stops at the first cell centre in the
/// shell where f < 0. The verdict does not depend on the thread count (each level is decided
/// as a whole).
pub(super) fn shell_sign(poly: &ImplicitPolynomial, outer: f64, hole: f64) -> Shell {
    use rayon::prelude::*;
    let mut cells: Vec<[f64; 3]> = vec![[0.0; 3]];
    let mut half = outer;
    for level in 0..=SHELL_MAX_LEVEL {
        if cells.is_empty() {
            return Shell::Positive;
        }
        if cells.len() > SHELL_MAX_CELLS {
            return Shell::Unknown;
        }
        let h = half;
        let verdicts: Vec<Verdict> = cells
            .par_iter()
            .map(|c| {
                let far = c.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                if far + h <= hole {
                    return Verdict::Drop;
                }
                let b = Aabb {
                    min: c.map(|v| v - h),
                    max: c.map(|v| v + h),
                };
                let (lo, _) = poly.bounds_on_box(&b);
                if lo > 0.0 {
                    return Verdict::Drop;
                }
                if far > hole && poly.value(*c) < 0.0 {
                    return Verdict::Negative;
                }
                Verdict::Split
            })
            .collect();
        if let Some(shell) = level_outcome(&verdicts, level == SHELL_MAX_LEVEL) {
            return shell;
        }
        let q = 0.5 * h;
        cells = cells
            .iter()
            .zip(&verdicts)
            .filter(|(_, v)| matches!(v, Verdict::Split))
            .flat_map(|(c, _)| {
                (0..8)
                    .map(move |k| [0, 1, 2].map(|a| c[a] + if (k >> a) & 1 == 1 { q } else { -q }))
            })
            .collect();
        half = q;
    }
    Shell::Unknown
}
