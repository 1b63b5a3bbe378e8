//! [`ImplicitFunction`] for [`ImplicitPolynomial`]: point values and gradients by fixed-degree
//! kernels, and enclosures on boxes by the polynomial's local Taylor expansion.
//!
//! Invariants: the enclosures hold for the floating-point values [`ImplicitFunction::value`]
//! computes (see below), and every kernel performs the same IEEE operations in the same order on
//! every CPU, so values do not depend on the instruction set chosen at run time.
//!
//! # Bounds for polynomials: the Taylor (centred) form
//!
//! For a box with centre c and half-widths h (in the polynomial's normalized coordinates q), the
//! polynomial is re-expanded around c in local coordinates t ∈ [−1, 1]³, q = c + h ⊙ t:
//!
//! ```text
//! f(c + h ⊙ t) = Σ_α b_α t^α,    b_α = (∂^α f(c) / α!) · h^α
//! ```
//!
//! by three one-dimensional Taylor shifts (synthetic division, O(n²) per line of coefficients).
//! Over the cube, a monomial t^α with all exponents even ranges over [0, 1], any other over
//! [−1, 1], so f ∈ b₀ + Σ_{α≠0} b_α·range(t^α). This is the centred form of interval analysis
//! (Moore, Kearfott & Cloud, *Introduction to Interval Analysis*, 2009, §6.4): its overestimation
//! shrinks like h² instead of h, which is what makes the octree adaptive — only cells within about
//! one cell of the zero set survive, so the number of cells grows 4× per level, not 8×. The
//! derivatives' enclosures come from the same coefficients. A rounding margin of
//! 8(n + 3)·ε_mach·Σ|a_α|·(|c| + h)^α (the magnitude of every term the evaluation can add) widens
//! each interval, so the enclosure also holds for the floating-point values.

use super::{Enclosure, GridValues, ImplicitFunction};
use crate::cloud::Aabb;
use crate::poly::ImplicitPolynomial;

/// Highest degree evaluated on stack buffers; higher degrees fall back to allocating paths.
const STACK_DEGREE: usize = 14;

/// Calls `$body` (a generic function taking the degree as its first argument) with the degree
/// as a literal for degrees up to [`INLINE_DEGREE`], so that each arm is compiled for its own
/// constant degree, and with the runtime degree above.
macro_rules! with_constant_degree {
    ($n:expr, $body:ident ( $($arg:expr),* )) => {
        match $n {
            0 => $body(0, $($arg),*),
            1 => $body(1, $($arg),*),
            2 => $body(2, $($arg),*),
            3 => $body(3, $($arg),*),
            4 => $body(4, $($arg),*),
            5 => $body(5, $($arg),*),
            6 => $body(6, $($arg),*),
            7 => $body(7, $($arg),*),
            8 => $body(8, $($arg),*),
            n => $body(n, $($arg),*),
        }
    };
}

/// Defines `$name`, which runs `$body` for the degree `n` ([`with_constant_degree`]) compiled
/// twice: for the baseline target and, on x86-64, for AVX2, chosen at run time by the CPU's
/// features (one cached check). Both versions perform the same IEEE operations in the same
/// order: Rust never fuses a multiply and an add into an FMA, and without fast-math the
/// compiler vectorizes only where the order of every sum is kept, so wider lanes change the
/// speed, not the bits (the kernels' hash in `tools/polygonize_kernels.rs` is the same).
macro_rules! with_avx2 {
    ($(#[$doc:meta])* fn $name:ident(n: usize $(, $arg:ident: $ty:ty)*) -> $ret:ty => $body:ident) => {
        $(#[$doc])*
        #[inline]
        fn $name(n: usize $(, $arg: $ty)*) -> $ret {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2")]
                fn avx2(n: usize $(, $arg: $ty)*) -> $ret {
                    with_constant_degree!(n, $body($($arg),*))
                }
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: `avx2` needs only the AVX2 instructions, which this CPU has
                    // (checked just above).
                    return unsafe { avx2(n $(, $arg)*) };
                }
            }
            with_constant_degree!(n, $body($($arg),*))
        }
    };
}

with_avx2! {
    /// [`value_gradient_of`] for any degree.
    fn value_gradient_any(n: usize, coefficients: &[f64], q: [f64; 3]) -> (f64, [f64; 3]) => value_gradient_of
}

with_avx2! {
    /// [`expand`] for any degree.
    fn expand_any(
        n: usize,
        coefficients: &[f64],
        dense: &mut [f64],
        center: [f64; 3],
        half_width: [f64; 3]
    ) -> (f64, [f64; 3]) => expand
}

with_avx2! {
    /// [`term_ranges`] for any degree.
    fn term_ranges_any(n: usize, b: &[f64]) -> ((f64, f64), [(f64, f64); 3]) => term_ranges
}

with_avx2! {
    /// [`grid_values_of`] for any degree.
    fn grid_values_any(n: usize, b: &[f64], t: &[[f64; 2]; 3]) -> [f64; 8] => grid_values_of
}

impl ImplicitFunction for ImplicitPolynomial {
    fn value(&self, p: [f64; 3]) -> f64 {
        let n = self.degree as usize;
        if n > STACK_DEGREE || self.coefficients.len() != crate::poly::n_coefficients(self.degree) {
            return self.eval(p);
        }
        let q = normalized(self, p);
        with_constant_degree!(n, monomial_dot(&self.coefficients, q))
    }

    fn value_gradient(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let n = self.degree as usize;
        if n > STACK_DEGREE || self.coefficients.len() != crate::poly::n_coefficients(self.degree) {
            return self.eval_gradient(p);
        }
        let q = normalized(self, p);
        let (f, g) = value_gradient_any(n, &self.coefficients, q);
        (f, g.map(|c| c / self.scale))
    }

    fn bounds_on_box(&self, b: &Aabb) -> (f64, f64) {
        self.with_taylor(b, |t| t.bounds().0)
            .unwrap_or((f64::NEG_INFINITY, f64::INFINITY))
    }

    fn gradient_bounds_on_box(&self, b: &Aabb) -> [(f64, f64); 3] {
        self.enclosure_on_box(b).gradient
    }

    fn enclosure_on_box(&self, b: &Aabb) -> Enclosure {
        self.with_taylor(b, |t| self.enclosure_of(t))
            .unwrap_or(UNBOUNDED)
    }

    fn enclosure_and_grid_values(
        &self,
        b: &Aabb,
        axes: &[[f64; 2]; 3],
    ) -> (Enclosure, Option<GridValues>) {
        self.with_taylor(b, |t| self.enclosure_and_values_of(t, axes))
            .unwrap_or((UNBOUNDED, None))
    }

    fn validate(&self) -> Result<(), String> {
        let expected = crate::poly::n_coefficients(self.degree);
        if self.coefficients.len() != expected {
            return Err(format!(
                "degree {} needs {expected} coefficients, the model has {}",
                self.degree,
                self.coefficients.len()
            ));
        }
        if self.coefficients.iter().any(|a| !a.is_finite()) {
            return Err("the model has a non-finite coefficient".into());
        }
        if !(self.scale > 0.0 && self.scale.is_finite())
            || self.center.iter().any(|c| !c.is_finite())
        {
            return Err(format!(
                "the normalization needs a finite centre and a scale > 0, got centre {:?} and scale {}",
                self.center, self.scale
            ));
        }
        Ok(())
    }
}

/// The enclosure of a malformed model or box: nothing excluded.
const UNBOUNDED: Enclosure = Enclosure {
    value: (f64::NEG_INFINITY, f64::INFINITY),
    gradient: [(f64::NEG_INFINITY, f64::INFINITY); 3],
    value_error: f64::INFINITY,
};

impl ImplicitPolynomial {
    /// The enclosure and the grid values of
    /// [`ImplicitFunction::enclosure_and_grid_values`] from a local expansion.
    fn enclosure_and_values_of(
        &self,
        t: &LocalTaylor,
        axes: &[[f64; 2]; 3],
    ) -> (Enclosure, Option<GridValues>) {
        let enclosure = self.enclosure_of(t);
        // Local coordinates of the grid: q = c + h ⊙ t.
        let local = [0, 1, 2].map(|a| {
            axes[a].map(|x| ((x - self.center[a]) / self.scale - t.center[a]) / t.half_width[a])
        });
        let values = t.grid_values(&local);
        let grid = (local
            .iter()
            .flatten()
            .all(|v| v.is_finite() && v.abs() <= 1.0 + 1e-9)
            && values.iter().all(|v| v.is_finite()))
        .then_some(GridValues {
            values,
            // The shifted coefficients carry at most `value_margin` of rounding (the enclosure
            // relies on that too); nested Horner on |t| ≤ 1 adds at most γ_(6n)·Σ|b_α| ≤
            // γ_(6n)·Σ|a_α|(|c| + h)^α, below another `value_margin`; the rounding of t itself
            // moves f by at most about 2n·ε·Σ|a_α|(|c| + h)^α, below a third.
            error: 3.0 * t.value_margin,
        });
        (enclosure, grid)
    }

    /// The enclosures of f and ∇f (input coordinates) from a local expansion.
    fn enclosure_of(&self, t: &LocalTaylor) -> Enclosure {
        let (value, derivatives) = t.bounds();
        let mut gradient = [(f64::NEG_INFINITY, f64::INFINITY); 3];
        for (axis, slot) in gradient.iter_mut().enumerate() {
            let per_t = self.scale * t.half_width[axis];
            if per_t > 0.0 && per_t.is_finite() {
                let (lo, hi) = derivatives[axis];
                *slot = (lo / per_t, hi / per_t);
            }
        }
        Enclosure {
            value,
            gradient,
            value_error: t.value_margin,
        }
    }
}

/// (p − center)/scale, written out so that it inlines in the hot loops.
#[inline]
fn normalized(f: &ImplicitPolynomial, p: [f64; 3]) -> [f64; 3] {
    [
        (p[0] - f.center[0]) / f.scale,
        (p[1] - f.center[1]) / f.scale,
        (p[2] - f.center[2]) / f.scale,
    ]
}

/// Number of monomials of degree ≤ n in three variables.
const fn n_monomials(n: usize) -> usize {
    (n + 1) * (n + 2) * (n + 3) / 6
}

/// f and its gradient with respect to q (normalized coordinates) of the degree-`n` polynomial
/// `coefficients` (graded order) at `q`: per block of equal (i, s = j + k), the dot products of
/// the coefficients with y^j z^k and its y and z derivatives, then x^i and its derivative
/// applied. Inlined with a constant `n` ([`with_constant_degree`]), so the loops have constant
/// bounds.
#[inline(always)]
fn value_gradient_of(n: usize, coefficients: &[f64], q: [f64; 3]) -> (f64, [f64; 3]) {
    // Buffers of the degree's own size: zeroing the 120 rows of degree 14 cost more than the
    // sums of a low degree (a local cubic's evaluation spent half its time in that memset).
    match n {
        0..=4 => value_gradient_sized::<15>(n, coefficients, q),
        5..=8 => value_gradient_sized::<45>(n, coefficients, q),
        _ => value_gradient_sized::<YZ_LEN>(n, coefficients, q),
    }
}

/// [`value_gradient_of`] with buffers of `L` ≥ (n + 1)(n + 2)/2 rows.
#[inline(always)]
fn value_gradient_sized<const L: usize>(
    n: usize,
    coefficients: &[f64],
    q: [f64; 3],
) -> (f64, [f64; 3]) {
    let coefficients = &coefficients[..n_monomials(n)];
    // px[e + 1] = x^e, px[0] = 0 (the x^(−1) of a derivative's zero term).
    let mut px = [0.0; STACK_DEGREE + 2];
    fill_powers(&mut px[1..=n + 1], q[0]);
    let n_yz = (n + 1) * (n + 2) / 2;
    let mut yz = [0.0; L];
    fill_yz(&mut yz[..n_yz], q[1], q[2], n);
    // Per y^j z^k: [y^j z^k, ∂/∂y, ∂/∂z, 0], so that the three dot products of a block run as
    // one multiply-add on four lanes (each lane the same operations as a separate sum). The
    // derivatives are ∂(y^j z^k)/∂y = j y^(j−1) z^k and ∂/∂z = k y^j z^(k−1), from the degree
    // s − 1 row.
    let mut terms = [[0.0; 4]; L];
    let mut row = 0;
    for s in 0..=n {
        for k in 0..=s {
            let j = s - k;
            let below = row - s; // start of the degree s − 1 row
            let slot = &mut terms[row + k];
            slot[0] = yz[row + k];
            if j > 0 {
                slot[1] = j as f64 * yz[below + k];
            }
            if k > 0 {
                slot[2] = k as f64 * yz[below + k - 1];
            }
        }
        row += s + 1;
    }
    let terms = &terms[..n_yz];
    // [f, ∂f/∂y, ∂f/∂z, ∂f/∂x], each summed block by block in the graded order.
    let mut sums = [0.0; 4];
    let mut offset = 0;
    for r in 0..=n {
        let mut start = 0;
        for s in 0..=r {
            let i = r - s;
            let mut v = [0.0; 4];
            for (&a, m) in coefficients[offset + start..=offset + start + s]
                .iter()
                .zip(&terms[start..=start + s])
            {
                for t in 0..4 {
                    v[t] += a * m[t];
                }
            }
            start += s + 1;
            let (p, dp) = (px[i + 1], i as f64 * px[i]);
            let factor = [p, p, p, dp];
            let block = [v[0], v[1], v[2], v[0]];
            for t in 0..4 {
                sums[t] += factor[t] * block[t];
            }
        }
        offset += start;
    }
    (sums[0], [sums[3], sums[1], sums[2]])
}

/// The exponent of x and the index of y^j z^k in the [`fill_yz`] table of each monomial, in the
/// graded order (the first `n_monomials(n)` entries are those of degree ≤ n, for any n ≤
/// [`STACK_DEGREE`]).
const MONOMIAL_TABLE: [(u8, u8); n_monomials(STACK_DEGREE)] = {
    let mut table = [(0, 0); n_monomials(STACK_DEGREE)];
    let mut l = 0;
    let mut r = 0;
    while r <= STACK_DEGREE {
        let mut s = 0;
        while s <= r {
            let mut k = 0;
            while k <= s {
                table[l] = ((r - s) as u8, (s * (s + 1) / 2 + k) as u8);
                l += 1;
                k += 1;
            }
            s += 1;
        }
        r += 1;
    }
    table
};

/// Σ a_α q^α for a degree-`n` polynomial (graded order, `coefficients.len()` ≥
/// `n_monomials(n)`): each monomial is x^i times an entry of the y^j z^k table
/// ([`MONOMIAL_TABLE`]), multiplied by its coefficient and added to one of four independent
/// partial sums (monomial l to sum l mod 4), so the additions pipeline instead of forming one
/// long dependent chain. Inlined with a constant `n` ([`with_constant_degree`]).
#[inline(always)]
fn monomial_dot(n: usize, coefficients: &[f64], q: [f64; 3]) -> f64 {
    // A y^j z^k table of the degree's own size, as in `value_gradient_of` (zeroing 128 entries
    // for a low degree's 15 cost as much as its sums).
    match n {
        0..=4 => monomial_dot_sized::<16>(n, coefficients, q),
        5..=8 => monomial_dot_sized::<64>(n, coefficients, q),
        _ => monomial_dot_sized::<128>(n, coefficients, q),
    }
}

/// [`monomial_dot`] with a y^j z^k table of `L` entries, a power of two ≥ (n + 1)(n + 2)/2.
#[inline(always)]
fn monomial_dot_sized<const L: usize>(n: usize, coefficients: &[f64], q: [f64; 3]) -> f64 {
    // Tables padded to a power of two, so that the masked indices below need no checks (every
    // index is below the mask, which changes none).
    let mut px = [0.0; 16];
    fill_powers(&mut px[..=n], q[0]);
    // y^j z^k for j + k = s, at s(s+1)/2 + k: the same order as the coefficients inside every
    // degree block.
    let mut yz = [0.0; L];
    let n_yz = (n + 1) * (n + 2) / 2;
    fill_yz(&mut yz[..n_yz], q[1], q[2], n);
    let l = n_monomials(n);
    let (table, coefficients) = (&MONOMIAL_TABLE[..l], &coefficients[..l]);
    let term =
        |(i, yzk): (u8, u8), a: f64| a * (px[usize::from(i) & 15] * yz[usize::from(yzk) & (L - 1)]);
    let mut partial = [0.0; 4];
    for (index, a) in table.chunks_exact(4).zip(coefficients.chunks_exact(4)) {
        for t in 0..4 {
            partial[t] += term(index[t], a[t]);
        }
    }
    let tail = l - l % 4;
    for (t, (&index, &a)) in table[tail..].iter().zip(&coefficients[tail..]).enumerate() {
        partial[t] += term(index, a);
    }
    (partial[0] + partial[1]) + (partial[2] + partial[3])
}

/// Length of the y^j z^k table for degrees up to [`STACK_DEGREE`].
const YZ_LEN: usize = (STACK_DEGREE + 1) * (STACK_DEGREE + 2) / 2;

/// `out[s(s+1)/2 + k] = y^(s−k) z^k` for s ≤ n.
#[inline(always)]
fn fill_yz(out: &mut [f64], y: f64, z: f64, n: usize) {
    let mut row = 0;
    for s in 0..=n {
        if s == 0 {
            out[0] = 1.0;
        } else {
            let below = row - s;
            // y^(s−k) z^k = y · (y^(s−1−k) z^k) for k < s, and z · z^(s−1) for k = s.
            for k in 0..s {
                out[row + k] = y * out[below + k];
            }
            out[row + s] = z * out[below + s - 1];
        }
        row += s + 1;
    }
}

/// `out[e] = t^e`.
#[inline(always)]
fn fill_powers(out: &mut [f64], t: f64) {
    let mut v = 1.0;
    for slot in out.iter_mut() {
        *slot = v;
        v *= t;
    }
}

/// Highest degree whose local expansion is kept on the stack (a dense 9×9×9 array) and computed
/// by code specialised for its degree (constant loop bounds, no bounds checks); higher degrees
/// use the same code on a heap buffer.
const INLINE_DEGREE: usize = 8;

/// Length of the inline dense array.
const INLINE_LEN: usize = (INLINE_DEGREE + 1) * (INLINE_DEGREE + 1) * (INLINE_DEGREE + 1);

/// A polynomial re-expanded around a box centre in local coordinates t ∈ [−1, 1]³.
struct LocalTaylor {
    degree: usize,
    /// Dense coefficients b_(i,j,k) at `(i·(n+1) + j)·(n+1) + k`, zero where i + j + k > n:
    /// the first (n+1)³ entries for n ≤ [`INLINE_DEGREE`], else in `heap`.
    inline: [f64; INLINE_LEN],
    /// The coefficients for n > [`INLINE_DEGREE`] (empty otherwise).
    heap: Vec<f64>,
    /// Centre of the box in normalized coordinates.
    center: [f64; 3],
    /// Half-widths of the box in normalized coordinates.
    half_width: [f64; 3],
    /// Rounding margin for the value.
    value_margin: f64,
    /// Rounding margins for ∂f/∂t_axis.
    derivative_margin: [f64; 3],
}

impl ImplicitPolynomial {
    /// `use_it` applied to the local Taylor expansion of f over the box `b`, or `None` for a
    /// malformed model or box. The expansion (a 5.8 kB array for degree 8) is built in place
    /// and lent, never returned by value, so it is not copied on its way to its users.
    #[inline]
    fn with_taylor<R>(&self, b: &Aabb, use_it: impl FnOnce(&LocalTaylor) -> R) -> Option<R> {
        let n = self.degree as usize;
        if self.coefficients.len() != crate::poly::n_coefficients(self.degree) {
            return None;
        }
        let center = self.normalize(b.center());
        let half_width = [0, 1, 2].map(|a| 0.5 * (b.max[a] - b.min[a]) / self.scale);
        if center.iter().chain(&half_width).any(|v| !v.is_finite()) {
            return None;
        }
        let m = n + 1;
        let mut t = LocalTaylor {
            degree: n,
            inline: [0.0; INLINE_LEN],
            heap: Vec::new(),
            center,
            half_width,
            value_margin: 0.0,
            derivative_margin: [0.0; 3],
        };
        let dense: &mut [f64] = if n <= INLINE_DEGREE {
            &mut t.inline[..m * m * m]
        } else {
            t.heap = vec![0.0; m * m * m];
            &mut t.heap
        };
        let (magnitude, derivative_magnitude) =
            expand_any(n, &self.coefficients, dense, center, half_width);
        let gamma = 8.0 * (n as f64 + 3.0) * f64::EPSILON;
        t.value_margin = gamma * magnitude;
        t.derivative_margin = [0, 1, 2].map(|a| gamma * derivative_magnitude[a] * half_width[a]);
        Some(use_it(&t))
    }
}

/// Fills `dense` ((n+1)³ entries, zero) with the local expansion of the degree-`n` polynomial
/// `coefficients` (graded order) around `center` with half-widths `half_width`, and returns the
/// magnitudes Σ|a_α|(|c| + h)^α of its terms and of the terms of each derivative (for the
/// rounding margins). Inlined into [`with_constant_degree`]'s arms, so `n` is a constant there.
#[inline(always)]
fn expand(
    n: usize,
    coefficients: &[f64],
    dense: &mut [f64],
    center: [f64; 3],
    half_width: [f64; 3],
) -> (f64, [f64; 3]) {
    let m = n + 1;
    let dense = &mut dense[..m * m * m];
    let coefficients = &coefficients[..m * (m + 1) * (m + 2) / 6];
    // Magnitude Σ|a_α|(|c| + h)^α of the terms, and of the terms of each derivative, for the
    // rounding margin. `reach[e + 1][a]` = (|c_a| + h_a)^e.
    let mut reach_inline = [[0.0; 3]; INLINE_DEGREE + 2];
    let mut reach_heap = Vec::new();
    let reach: &mut [[f64; 3]] = if m < reach_inline.len() {
        &mut reach_inline[..m + 1]
    } else {
        reach_heap.resize(m + 1, [0.0; 3]);
        &mut reach_heap
    };
    for a in 0..3 {
        let r = center[a].abs() + half_width[a];
        let mut v = 1.0;
        for row in reach.iter_mut().skip(1) {
            row[a] = v;
            v *= r;
        }
    }
    let mut magnitude = 0.0;
    let mut derivative_magnitude = [0.0; 3];
    let mut l = 0;
    for r in 0..=n {
        for s in 0..=r {
            for k in 0..=s {
                let (i, j) = (r - s, s - k);
                let a = coefficients[l];
                l += 1;
                dense[(i * m + j) * m + k] = a;
                let a = a.abs();
                let (ri, rj, rk) = (reach[i + 1][0], reach[j + 1][1], reach[k + 1][2]);
                magnitude += a * ri * rj * rk;
                if i > 0 {
                    derivative_magnitude[0] += a * i as f64 * reach[i][0] * rj * rk;
                }
                if j > 0 {
                    derivative_magnitude[1] += a * j as f64 * ri * reach[j][1] * rk;
                }
                if k > 0 {
                    derivative_magnitude[2] += a * k as f64 * ri * rj * reach[k][2];
                }
            }
        }
    }
    // Shift and scale along each axis: for every line of coefficients along `axis` (the other
    // two exponents fixed, their sum e), p(x) ↦ p(c + h·x) by synthetic division, whose step q
    // only changes a line with n − e ≥ q + 1. The steps run over all lines at once (the line
    // innermost), so consecutive updates are independent and pipeline; each line still sees
    // exactly its own sequence of updates.
    // Along x and y the lines are laid out so that whole rows of `m` coefficients (x: the
    // planes i = q, all rows j) can be updated as contiguous slices, which vectorizes. The
    // extra entries such a row update touches are exactly the ones outside the polynomial
    // (i + j + k > n, zero, never read as anything but zero) or ones whose update reads such a
    // zero, so every coefficient gets the same value as with the line-by-line loop — provided
    // the factors c and h^q are finite, which keeps the zeros zero (else that loop is used).
    let powers_finite = half_width.iter().all(|h| h.powi(n as i32).is_finite());
    let strides = [m * m, m, 1];
    for axis in 0..3 {
        let (c, h) = (center[axis], half_width[axis]);
        if axis < 2 && powers_finite {
            shift_rows(n, axis, c, h, dense);
            continue;
        }
        let st = strides[axis];
        let (o1, o2) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let (s1, s2) = (strides[o1], strides[o2]);
        if c != 0.0 {
            for i in 0..n {
                for q in (i..n).rev() {
                    // Lines with e1 + e2 ≤ n − q − 1.
                    let room = n - q - 1;
                    for e1 in 0..=room {
                        let base = e1 * s1 + q * st;
                        for e2 in 0..=room - e1 {
                            let at = base + e2 * s2;
                            dense[at] += c * dense[at + st];
                        }
                    }
                }
            }
        }
        let mut hp = 1.0;
        for q in 0..=n {
            let room = n - q;
            for e1 in 0..=room {
                let base = e1 * s1 + q * st;
                for e2 in 0..=room - e1 {
                    dense[base + e2 * s2] *= hp;
                }
            }
            hp *= h;
        }
    }
    (magnitude, derivative_magnitude)
}

/// The shift p(x) ↦ p(c + h·x) along `axis` (0 or 1) of [`expand`], by whole rows: step q of
/// the synthetic division updates the entries at position q on `axis` from those at q + 1, for
/// x all the rows j ≤ n − q − 1 of plane q (one contiguous block), for y the row (i, q) of
/// every plane i ≤ n − q − 1; then position q is scaled by h^q the same way.
#[inline(always)]
fn shift_rows(n: usize, axis: usize, c: f64, h: f64, dense: &mut [f64]) {
    let m = n + 1;
    let plane = m * m;
    if c != 0.0 {
        for i in 0..n {
            for q in (i..n).rev() {
                let room = n - q - 1;
                if axis == 0 {
                    let (low, high) = dense.split_at_mut((q + 1) * plane);
                    let len = (room + 1) * m;
                    let target = &mut low[q * plane..q * plane + len];
                    for (t, s) in target.iter_mut().zip(&high[..len]) {
                        *t += c * *s;
                    }
                } else {
                    for e1 in 0..=room {
                        let base = e1 * plane + q * m;
                        let (low, high) = dense.split_at_mut(base + m);
                        for (t, s) in low[base..].iter_mut().zip(&high[..m]) {
                            *t += c * *s;
                        }
                    }
                }
            }
        }
    }
    let mut hp = 1.0;
    for q in 0..=n {
        let room = n - q;
        if axis == 0 {
            for t in &mut dense[q * plane..q * plane + (room + 1) * m] {
                *t *= hp;
            }
        } else {
            for e1 in 0..=room {
                let base = e1 * plane + q * m;
                for t in &mut dense[base..base + m] {
                    *t *= hp;
                }
            }
        }
        hp *= h;
    }
}

impl LocalTaylor {
    /// The dense coefficients ((n+1)³ entries).
    fn coefficients(&self) -> &[f64] {
        if self.degree <= INLINE_DEGREE {
            let m = self.degree + 1;
            &self.inline[..m * m * m]
        } else {
            &self.heap
        }
    }

    /// Enclosures of f and of ∂f/∂t_axis (local coordinates) over the box, in one pass.
    fn bounds(&self) -> ((f64, f64), [(f64, f64); 3]) {
        let (value, derivatives) = term_ranges_any(self.degree, self.coefficients());
        let value = (value.0 - self.value_margin, value.1 + self.value_margin);
        let derivatives = [0, 1, 2].map(|a| {
            let (lo, hi) = derivatives[a];
            (
                lo - self.derivative_margin[a],
                hi + self.derivative_margin[a],
            )
        });
        (value, derivatives)
    }

    /// Σ b_α t^α at the 8 points of the grid `t` (point i at `t[a][(i >> a) & 1]` on axis a),
    /// by nested Horner: per (i, j) the z polynomial at both z values, then y, then x — about
    /// 4 multiply-adds per coefficient for all 8 points instead of 8 full evaluations.
    fn grid_values(&self, t: &[[f64; 2]; 3]) -> [f64; 8] {
        grid_values_any(self.degree, self.coefficients(), t)
    }
}

/// The ranges of Σ b_α t^α and of its three partial derivatives over t ∈ [−1, 1]³, without
/// rounding margins, from the dense degree-`n` coefficients `b` (each range the sum of the
/// ranges of its terms, added in the order (i, j, k)). Inlined with a constant `n`.
#[inline(always)]
fn term_ranges(n: usize, b: &[f64]) -> ((f64, f64), [(f64, f64); 3]) {
    let m = n + 1;
    let b = &b[..m * m * m];
    let mut value = (0.0, 0.0);
    let mut derivatives = [(0.0, 0.0); 3];
    for i in 0..=n {
        for j in 0..=n - i {
            for k in 0..=n - i - j {
                let b = b[(i * m + j) * m + k];
                if b == 0.0 {
                    continue;
                }
                let e = [i, j, k];
                accumulate(&mut value.0, &mut value.1, b, e);
                for axis in 0..3 {
                    if e[axis] > 0 {
                        let mut ed = e;
                        ed[axis] -= 1;
                        let slot = &mut derivatives[axis];
                        accumulate(&mut slot.0, &mut slot.1, b * e[axis] as f64, ed);
                    }
                }
            }
        }
    }
    (value, derivatives)
}

/// [`LocalTaylor::grid_values`] on the dense degree-`n` coefficients `b`. Inlined with a
/// constant `n`.
#[inline(always)]
fn grid_values_of(n: usize, b: &[f64], t: &[[f64; 2]; 3]) -> [f64; 8] {
    let m = n + 1;
    let b = &b[..m * m * m];
    // per_x[i][yb·2 + zb] = Σ_(j,k) b_ijk ty^j tz^k.
    let mut per_x_inline = [[0.0; 4]; INLINE_DEGREE + 1];
    let mut per_x_heap = Vec::new();
    let per_x: &mut [[f64; 4]] = if m <= per_x_inline.len() {
        &mut per_x_inline[..m]
    } else {
        per_x_heap.resize(m, [0.0; 4]);
        &mut per_x_heap
    };
    for (i, slot) in per_x.iter_mut().enumerate() {
        let mut yz = [0.0; 4];
        for j in (0..=n - i).rev() {
            let base = (i * m + j) * m;
            let mut z = [0.0; 2];
            for k in (0..=n - i - j).rev() {
                let b = b[base + k];
                z = [z[0] * t[2][0] + b, z[1] * t[2][1] + b];
            }
            for yb in 0..2 {
                for zb in 0..2 {
                    yz[yb * 2 + zb] = yz[yb * 2 + zb] * t[1][yb] + z[zb];
                }
            }
        }
        *slot = yz;
    }
    let mut out = [0.0; 8];
    for (p, slot) in out.iter_mut().enumerate() {
        let (xb, yb, zb) = (p & 1, (p >> 1) & 1, (p >> 2) & 1);
        let mut v = 0.0;
        for row in per_x.iter().rev() {
            v = v * t[0][xb] + row[yb * 2 + zb];
        }
        *slot = v;
    }
    out
}

/// Adds the range of b·t^e over t ∈ [−1, 1]³ to the interval [lo, hi].
#[inline(always)]
fn accumulate(lo: &mut f64, hi: &mut f64, b: f64, e: [usize; 3]) {
    if e == [0, 0, 0] {
        *lo += b;
        *hi += b;
    } else if e.iter().all(|x| x % 2 == 0) {
        // t^e ∈ [0, 1]: b goes to hi when positive, else to lo. Written as selects (the sign of
        // b is unpredictable); adding +0 to the other end leaves it bit for bit unchanged (both
        // ends start at +0 and never become −0 under round-to-nearest), and a NaN b still goes
        // to lo.
        let up = b > 0.0;
        *hi += if up { b } else { 0.0 };
        *lo += if up { 0.0 } else { b };
    } else {
        *lo -= b.abs();
        *hi += b.abs();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poly::test_support::random_polynomial;

    /// A pseudo-random degree-`n` polynomial with a non-trivial normalization.
    fn random_poly(n: u32, seed: u64) -> ImplicitPolynomial {
        random_polynomial(n, seed, [0.3, -0.2, 0.5], 1.7)
    }

    #[test]
    fn fast_evaluation_matches_reference() {
        for n in [0, 1, 2, 5, 8] {
            let f = random_poly(n, 7 + n as u64);
            for p in [[0.1, 0.2, 0.3], [-1.5, 0.7, 2.0], [3.0, -2.0, 0.0]] {
                let reference = f.eval(p);
                let (rv, rg) = f.eval_gradient(p);
                let (v, g) = f.value_gradient(p);
                let tol = 1e-12 * (1.0 + reference.abs());
                assert!((f.value(p) - reference).abs() < tol, "degree {n}");
                assert!((v - rv).abs() < tol, "degree {n}");
                for a in 0..3 {
                    assert!(
                        (g[a] - rg[a]).abs() < 1e-11 * (1.0 + rg[a].abs()),
                        "degree {n}"
                    );
                }
            }
        }
    }

    #[test]
    fn bounds_enclose_samples_and_tighten_quadratically() {
        let f = random_poly(6, 3);
        let mut previous_excess = f64::INFINITY;
        for level in 0..6 {
            let h = 0.8 / f64::from(1u32 << level);
            let b = Aabb {
                min: [0.1, -0.3, 0.2],
                max: [0.1 + h, -0.3 + h, 0.2 + h],
            };
            let (lo, hi) = f.bounds_on_box(&b);
            let grads = f.gradient_bounds_on_box(&b);
            let enclosure = f.enclosure_on_box(&b);
            assert_eq!((enclosure.value, enclosure.gradient), ((lo, hi), grads));
            assert!(enclosure.value_error > 0.0 && enclosure.value_error < 1e-10);
            let (mut smin, mut smax) = (f64::INFINITY, f64::NEG_INFINITY);
            for ix in 0..=6 {
                for iy in 0..=6 {
                    for iz in 0..=6 {
                        let p = [ix, iy, iz].map(|i| i as f64 / 6.0);
                        let p = [0, 1, 2].map(|a| b.min[a] + p[a] * (b.max[a] - b.min[a]));
                        let (v, g) = f.value_gradient(p);
                        assert!(lo <= v && v <= hi, "value {v} outside [{lo}, {hi}]");
                        for a in 0..3 {
                            assert!(grads[a].0 <= g[a] && g[a] <= grads[a].1);
                        }
                        smin = smin.min(v);
                        smax = smax.max(v);
                    }
                }
            }
            // The centred form's overestimation shrinks about 4× per halving (quadratic).
            let excess = (hi - lo) - (smax - smin);
            if level >= 3 {
                assert!(
                    excess < 0.4 * previous_excess,
                    "level {level}: {excess} vs {previous_excess}"
                );
            }
            previous_excess = excess;
        }
    }
}
