//! The exact distance evaluator: an [`ImplicitPolynomial`] and a region → [`ExactDistance`], the
//! Euclidean distance from a point to the polynomial's zero set (seed samples of the zero set in a
//! k-d tree, then Newton's method on the closest-point conditions; see the module docs of
//! [`crate::distance`]), and the polynomial [`Evaluator`] (f, ∇f, Hessian, the first-order
//! Taubin distance) that both distance methods use.

use rayon::prelude::*;

use super::{check_region, DistanceError, MAX_DEGREE};
use crate::cloud::Aabb;
use crate::numerics::point_tree::PointTree;
use crate::poly::{n_coefficients, ImplicitPolynomial};
use crate::vec3::{dist, dist2};

/// Seed-grid cells along the longest side of the grown region (exact method).
const SEED_CELLS: usize = 64;
/// Margin added on each side of the region for the seed grid, as a fraction of its longest side.
const SEED_MARGIN: f64 = 0.25;
/// Nearest seeds looked up per pixel (exact method).
const N_NEAREST: usize = 8;
/// At most this many of them start a Newton refinement.
const N_REFINE: usize = 3;
/// A point is on the zero set when |f|/|∇f| is below this, in normalized units.
const ON_SURFACE_TOL: f64 = 1e-10;
/// A Newton step of the closest-point search below this (normalized units, relative to
/// 1 + |x|∞) is the last one: the point after it is exact to about its square (≈ 1e-10), and
/// the distance, second order in the tangential error, far more (f32 output keeps 6e-8).
const NEWTON_FINAL_STEP: f64 = 1e-5;
/// A Newton step of the closest-point search below this (normalized units, relative to
/// 1 + |x|∞), and short enough for [`NEWTON_PROJECT_AREA`], is followed by one projection onto
/// f = 0 along ∇f (updated to first order with the step's Hessian) instead of another Newton
/// step. Such a step of length s leaves an error of about K·s² (K of order 10 on the models
/// measured), mostly along the normal, which the projection removes; the tangential rest e
/// changes the distance d by about e²/(2d), and the point is checked on the surface as always.
const NEWTON_PROJECT_STEP: f64 = 1e-3;
/// The projection of [`NEWTON_PROJECT_STEP`] is taken only when s² < this × d (normalized
/// units): with K up to about 100 the distance then moves by less than 1e-8 of itself, below the
/// float32 output's step, near the surface as far from it (`cargo run --release --features tools
/// --example slice_diff` compares the slices with and without the shortcut).
const NEWTON_PROJECT_AREA: f64 = 1e-6;

/// The exact distance to the zero set: samples of the zero set in a k-d tree, refined per query
/// by Newton's method on the closest-point conditions (see the module docs).
#[derive(Debug)]
pub struct ExactDistance {
    pub(super) eval: Evaluator,
    /// Zero-set samples in normalized coordinates.
    seeds: Vec<[f64; 3]>,
    tree: PointTree,
    /// Seed-grid cell size, normalized units.
    pub(super) cell: f64,
}

impl ExactDistance {
    /// Samples the zero set of `poly` over `region` grown by 25%.
    ///
    /// # Errors
    /// [`DistanceError::InvalidPolynomial`], [`DistanceError::InvalidRegion`], or
    /// [`DistanceError::NoSurface`] when no zero set crosses the grown region.
    pub fn new(poly: &ImplicitPolynomial, region: &Aabb) -> Result<Self, DistanceError> {
        check_region(region)?;
        Self::with_evaluator(Evaluator::new(poly)?, region)
    }

    pub(super) fn with_evaluator(eval: Evaluator, region: &Aabb) -> Result<Self, DistanceError> {
        let longest = (0..3)
            .map(|a| region.max[a] - region.min[a])
            .fold(0.0, f64::max);
        let margin = SEED_MARGIN * longest;
        // The seed grid in normalized coordinates.
        let lo = eval.normalize(region.min.map(|c| c - margin));
        let hi = eval.normalize(region.max.map(|c| c + margin));
        let cell = (longest + 2.0 * margin) / eval.scale / SEED_CELLS as f64;
        let n = [0, 1, 2].map(|a| (((hi[a] - lo[a]) / cell).ceil() as usize).max(1));
        let node = |i: usize, j: usize, k: usize| {
            [
                lo[0] + i as f64 * cell,
                lo[1] + j as f64 * cell,
                lo[2] + k as f64 * cell,
            ]
        };
        // f at every node, one z layer per task.
        let values: Vec<Vec<f64>> = (0..=n[2])
            .into_par_iter()
            .map(|k| {
                let mut layer = Vec::with_capacity((n[0] + 1) * (n[1] + 1));
                for j in 0..=n[1] {
                    // The nodes of a line along x share y and z: f's inner sums once per line.
                    let line = eval.line(node(0, j, k));
                    for i in 0..=n[0] {
                        layer.push(eval.value_on_line(&line, node(i, j, k)));
                    }
                }
                layer
            })
            .collect();
        let at = |i: usize, j: usize, k: usize| values[k][j * (n[0] + 1) + i];
        // A seed on every grid edge whose end values differ in sign, projected onto f = 0.
        let seeds: Vec<[f64; 3]> = (0..=n[2])
            .into_par_iter()
            .map(|k| {
                let mut out = Vec::new();
                for j in 0..=n[1] {
                    for i in 0..=n[0] {
                        let fa = at(i, j, k);
                        let a = node(i, j, k);
                        let neighbours = [
                            (i < n[0]).then(|| (node(i + 1, j, k), at(i + 1, j, k))),
                            (j < n[1]).then(|| (node(i, j + 1, k), at(i, j + 1, k))),
                            (k < n[2]).then(|| (node(i, j, k + 1), at(i, j, k + 1))),
                        ];
                        for (b, fb) in neighbours.into_iter().flatten() {
                            if (fa < 0.0) == (fb < 0.0) || !fa.is_finite() || !fb.is_finite() {
                                continue;
                            }
                            let t = fa / (fa - fb);
                            let start = [0, 1, 2].map(|c| a[c] + t * (b[c] - a[c]));
                            if let Some(x) = eval.project(start, 2.0 * cell) {
                                out.push(x);
                            }
                        }
                    }
                }
                out
            })
            .flatten_iter()
            .collect();
        if seeds.is_empty() {
            return Err(DistanceError::NoSurface);
        }
        let tree = PointTree::new(&seeds)
            .ok_or_else(|| DistanceError::InvalidPolynomial("cannot index the zero set".into()))?;
        Ok(ExactDistance {
            eval,
            seeds,
            tree,
            cell,
        })
    }

    /// Number of zero-set samples found.
    #[cfg(test)] // only the unit tests call it
    pub(crate) fn n_samples(&self) -> usize {
        self.seeds.len()
    }

    /// Signed distance from `p` (input coordinates) to the zero set, input units, negative where
    /// f < 0.
    #[cfg(test)] // only the unit tests call it
    pub(crate) fn distance(&self, p: [f64; 3]) -> f64 {
        self.distance_from(p, None, None, &mut NearSeeds::default())
            .0
    }

    /// [`Self::distance`] with an optional warm start: `warm` is a point of the zero set
    /// (normalized coordinates) near the expected closest point, typically the foot point of the
    /// neighbouring pixel. Newton's method is run from it first; its result bounds the seeds
    /// worth refining and, like a refined seed, covers the seeds within two cells of it. Returns
    /// the signed distance and the closest point found (normalized), to warm-start the next query.
    ///
    /// `line`, when given, caches f's inner sums on the line of `p` (see [`Evaluator::line`]);
    /// `near` holds the nearest seeds of the previous query, which bound this query's radius
    /// (the result is the same as without them, only found faster), and receives this query's.
    pub(super) fn distance_from(
        &self,
        p: [f64; 3],
        warm: Option<[f64; 3]>,
        line: Option<&Line>,
        near: &mut NearSeeds,
    ) -> (f64, Option<[f64; 3]>) {
        let q = self.eval.normalize(p);
        let f = match line {
            Some(line) => self.eval.value_on_line(line, q),
            None => self.eval.value(q),
        };
        if f == 0.0 {
            return (0.0, Some(q));
        }
        let mut best = f64::INFINITY;
        let mut foot = None;
        // Points whose Newton basin has been explored: the warm-start foot point and the seeds
        // refined so far.
        let mut refined = [[f64::NAN; 3]; N_REFINE + 1];
        let mut n_refined = 0;
        if let Some(x) = warm.and_then(|w| self.eval.closest_point(q, w)) {
            best = dist(q, x);
            foot = Some(x);
            refined[0] = x;
            n_refined = 1;
        }
        let k = N_NEAREST.min(self.seeds.len());
        // Only seeds within best + cell are used below, so a warm start bounds the search.
        // The previous query's k nearest seeds bound the k-th nearest distance here: a radius
        // just above that bound gives the same k nearest seeds (all within both radii), and
        // lets the tree prune far sooner.
        let mut radius2 = if best.is_finite() {
            (best + self.cell).powi(2)
        } else {
            f64::INFINITY
        };
        if near.len == k {
            let bound2 = near.items[..near.len]
                .iter()
                .map(|&i| dist2(q, self.seeds[i as usize]))
                .fold(0.0, f64::max)
                * (1.0 + 1e-9);
            if bound2 < radius2 {
                radius2 = bound2;
            }
        }
        let mut found = [(0.0, 0u32); N_NEAREST];
        let n_found = self.tree.nearest_n_within(q, radius2, &mut found[..k]);
        let nearest = &found[..n_found];
        near.len = n_found;
        for (slot, n) in near.items.iter_mut().zip(nearest) {
            *slot = n.1;
        }
        if let Some(n) = nearest.first()
            && n.0.sqrt() < best
        {
            best = n.0.sqrt();
            foot = Some(self.seeds[n.1 as usize]);
        }
        // Refine from the nearest seed, then from up to N_REFINE − 1 more that lie more than two
        // cells from every point explored so far (seeds that close share a Newton basin) and
        // whose own distance is below the best found plus a cell (the zero set within a cell of a
        // seed is at least its distance minus a cell away, so a farther seed cannot lead closer).
        let first_seed = n_refined;
        for n in nearest {
            if n_refined - first_seed == N_REFINE || n.0.sqrt() > best + self.cell {
                break;
            }
            let seed = self.seeds[n.1 as usize];
            if refined[..n_refined]
                .iter()
                .any(|r| dist(*r, seed) <= 2.0 * self.cell)
            {
                continue;
            }
            refined[n_refined] = seed;
            n_refined += 1;
            if let Some(x) = self.eval.closest_point(q, seed) {
                let d = dist(q, x);
                if d < best {
                    best = d;
                    foot = Some(x);
                }
            }
        }
        (best.copysign(f) * self.eval.scale, foot)
    }
}

/// The nearest seeds (indices) found by the previous query of a row.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct NearSeeds {
    items: [u32; N_NEAREST],
    len: usize,
}

/// Σ col[k]·zp[k]: one innermost column of the nested form, summed in order.
#[inline]
fn column_sum(col: &[f64], zp: &[f64]) -> f64 {
    let mut s0 = 0.0;
    for (a, z) in col.iter().zip(zp) {
        s0 += a * z;
    }
    s0
}

/// f's inner sums on a line of fixed y and z (normalized): `s[i][j] = Σ_k a_ijk z^k` and
/// `fi[i] = Σ_j y^j s[i][j]`, so that f on the line costs n + 1 products per point, with the
/// same operations in the same order as [`Evaluator::value`] (hence the same bits).
#[derive(Clone, Debug)]
pub(super) struct Line {
    y: f64,
    z: f64,
    /// `s[i][j]`, in the nested column order.
    s: Vec<f64>,
    /// `fi[i]` at `y`.
    fi: Vec<f64>,
}

/// The polynomial as a list of non-zero terms, evaluated with its derivatives in normalized
/// coordinates without allocating.
#[derive(Clone, Debug)]
pub(super) struct Evaluator {
    /// Coefficients a_ijk ordered by i, then j, then k (k = 0 ..= n − i − j): the polynomial is
    /// evaluated as Σ_i x^i Σ_j y^j Σ_k a_ijk z^k, with the derivatives carried along, which
    /// takes about a third of the multiplications of a term-by-term sum.
    nested: Vec<f64>,
    /// The same coefficients for [`LANES`] consecutive i side by side, which the point kernels
    /// read: for each group g (i = 4g … 4g + 3), for j = 0 ..= n − 4g, for k = 0 ..= n − 4g − j,
    /// the entry holds a_(i,j,k) of each i, zero where i + j + k > n. Each lane computes the
    /// column sums Σ_k a_ijk z^k of its own i in the nested form's order (the zeros come last
    /// in a column, and a zero term adds nothing to a sum that starts at +0), four columns per
    /// vector operation.
    lanes: Vec<[f64; LANES]>,
    degree: usize,
    center: [f64; 3],
    scale: f64,
}

/// Values of i evaluated side by side by the point kernels ([`Evaluator::lanes`]).
const LANES: usize = 4;

/// Length of a power table: t^e is stored at e + 2, with two zeros in front so the derivative
/// lookups t^(e−1), t^(e−2) need no branch.
const TABLE: usize = MAX_DEGREE as usize + 3;
/// Table length used up to degree 10 (the usual fits), a quarter of [`TABLE`].
const SHORT_TABLE: usize = 13;

impl Evaluator {
    pub(super) fn new(poly: &ImplicitPolynomial) -> Result<Self, DistanceError> {
        let bad = |m: String| Err(DistanceError::InvalidPolynomial(m));
        if poly.degree > MAX_DEGREE {
            return bad(format!("degree {} exceeds {MAX_DEGREE}", poly.degree));
        }
        if poly.coefficients.len() != n_coefficients(poly.degree) {
            return bad(format!(
                "degree {} needs {} coefficients, found {}",
                poly.degree,
                n_coefficients(poly.degree),
                poly.coefficients.len()
            ));
        }
        if !poly
            .coefficients
            .iter()
            .chain(&poly.center)
            .all(|c| c.is_finite())
        {
            return bad("a coefficient or the centre is not finite".into());
        }
        if !(poly.scale.is_finite() && poly.scale > 0.0) {
            return bad(format!("the scale is {}, it must be > 0", poly.scale));
        }
        let n = poly.degree as usize;
        // Position of a_ijk in the nested order.
        let column = |i: usize, j: usize| -> usize {
            // Columns before i: Σ_{i' < i} Σ_{j ≤ n − i'} (n − i' − j + 1); before j within i.
            let before_i: usize = (0..i).map(|a| (n - a + 1) * (n - a + 2) / 2).sum();
            let before_j: usize = (0..j).map(|b| n - i - b + 1).sum();
            before_i + before_j
        };
        let mut nested = vec![0.0; poly.coefficients.len()];
        for (e, &a) in crate::poly::exponents(poly.degree)
            .into_iter()
            .zip(&poly.coefficients)
        {
            let [i, j, k] = e.map(|x| x as usize);
            nested[column(i, j) + k] = a;
        }
        let mut lanes = Vec::new();
        for i0 in (0..=n).step_by(LANES) {
            for j in 0..=n - i0 {
                for k in 0..=n - i0 - j {
                    lanes.push(std::array::from_fn(|l| {
                        let i = i0 + l;
                        if i + j + k <= n {
                            nested[column(i, j) + k]
                        } else {
                            0.0
                        }
                    }));
                }
            }
        }
        Ok(Evaluator {
            nested,
            lanes,
            degree: poly.degree as usize,
            center: poly.center,
            scale: poly.scale,
        })
    }

    pub(super) fn normalize(&self, p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| (p[a] - self.center[a]) / self.scale)
    }

    /// Power tables of the three coordinates (see [`TABLE`]) up to degree `n`, `T ≥ n + 3` long.
    #[inline(always)]
    fn powers<const T: usize>(n: usize, q: [f64; 3]) -> [[f64; T]; 3] {
        let mut t = [[0.0; T]; 3];
        for a in 0..3 {
            let mut v = 1.0;
            for e in 0..=n {
                t[a][e + 2] = v;
                v *= q[a];
            }
        }
        t
    }

    /// 1, z, z², … z^degree (the rest of the table zero).
    #[inline]
    fn z_powers(&self, z: f64) -> [f64; TABLE] {
        let mut zp = [0.0; TABLE];
        let mut v = 1.0;
        for p in zp.iter_mut().take(self.degree + 1) {
            *p = v;
            v *= z;
        }
        zp
    }

    /// f at the normalized point `q`.
    fn value(&self, q: [f64; 3]) -> f64 {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2")]
            fn avx2(e: &Evaluator, q: [f64; 3]) -> f64 {
                e.value_by_degree(q)
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: `avx2` needs only the AVX2 instructions, which this CPU has (checked
                // just above).
                return unsafe { avx2(self, q) };
            }
        }
        self.value_by_degree(q)
    }

    /// [`Self::value`] with the degree as a constant where it is at most 8 and the power table
    /// sized to the degree, as [`Self::derivatives_by_degree`]; the same operations in the same
    /// order for every degree, so the same bits.
    #[inline(always)]
    fn value_by_degree(&self, q: [f64; 3]) -> f64 {
        match self.degree {
            1 => self.value_with::<SHORT_TABLE>(1, q),
            2 => self.value_with::<SHORT_TABLE>(2, q),
            3 => self.value_with::<SHORT_TABLE>(3, q),
            4 => self.value_with::<SHORT_TABLE>(4, q),
            5 => self.value_with::<SHORT_TABLE>(5, q),
            6 => self.value_with::<SHORT_TABLE>(6, q),
            7 => self.value_with::<SHORT_TABLE>(7, q),
            8 => self.value_with::<SHORT_TABLE>(8, q),
            n if n + 3 <= SHORT_TABLE => self.value_with::<SHORT_TABLE>(n, q),
            n => self.value_with::<TABLE>(n, q),
        }
    }

    /// f at `q` for degree `n` (= `self.degree`) with power tables of length `T > n`: the column
    /// sums s_ij = Σ_k a_ijk z^k and the row sums fi = Σ_j y^j s_ij of four i at a time
    /// ([`Evaluator::lanes`]), then f = Σ_i x^i fi, each sum in the nested form's order.
    #[inline(always)]
    fn value_with<const T: usize>(&self, n: usize, q: [f64; 3]) -> f64 {
        let mut zp = [0.0; T];
        let mut yp = [0.0; T];
        let (mut vz, mut vy) = (1.0, 1.0);
        for e in 0..=n {
            zp[e] = vz;
            yp[e] = vy;
            vz *= q[2];
            vy *= q[1];
        }
        let mut rows = self.lanes.as_slice();
        let (mut f, mut xi) = (0.0, 1.0);
        for i0 in (0..=n).step_by(LANES) {
            // fi = Σ_j y^j Σ_k a_ijk z^k, one lane per i.
            let mut fi = [0.0; LANES];
            for (j, &yj) in yp.iter().enumerate().take(n - i0 + 1) {
                let (col, rest) = rows.split_at(n - i0 - j + 1);
                rows = rest;
                let mut s0 = [0.0; LANES];
                for (a, &zk) in col.iter().zip(&zp) {
                    for l in 0..LANES {
                        s0[l] += a[l] * zk;
                    }
                }
                for l in 0..LANES {
                    fi[l] += yj * s0[l];
                }
            }
            for &fi in fi.iter().take(n + 1 - i0) {
                f += xi * fi;
                xi *= q[0];
            }
        }
        f
    }

    /// The inner sums of f on the line through `q` along x (see [`Line`]).
    pub(super) fn line(&self, q: [f64; 3]) -> Line {
        let n = self.degree;
        let zp = self.z_powers(q[2]);
        let mut columns = self.nested.as_slice();
        let mut s = Vec::with_capacity((n + 1) * (n + 2) / 2);
        let mut fi = Vec::with_capacity(n + 1);
        for i in 0..=n {
            let (mut sum, mut yj) = (0.0, 1.0);
            for j in 0..=n - i {
                let (col, rest) = columns.split_at(n - i - j + 1);
                columns = rest;
                let s0 = column_sum(col, &zp);
                s.push(s0);
                sum += yj * s0;
                yj *= q[1];
            }
            fi.push(sum);
        }
        Line {
            y: q[1],
            z: q[2],
            s,
            fi,
        }
    }

    /// f at `q`, bit for bit [`Self::value`], from the sums of the line through `q` when `q`
    /// shares its z (and possibly its y) with `line`.
    fn value_on_line(&self, line: &Line, q: [f64; 3]) -> f64 {
        if q[2].to_bits() != line.z.to_bits() {
            return self.value(q);
        }
        let n = self.degree;
        let (mut f, mut xi) = (0.0, 1.0);
        if q[1].to_bits() == line.y.to_bits() {
            for &fi in &line.fi {
                f += xi * fi;
                xi *= q[0];
            }
            return f;
        }
        let mut sums = line.s.as_slice();
        for i in 0..=n {
            let (row, rest) = sums.split_at(n - i + 1);
            sums = rest;
            let (mut fi, mut yj) = (0.0, 1.0);
            for &s0 in row {
                fi += yj * s0;
                yj *= q[1];
            }
            f += xi * fi;
            xi *= q[0];
        }
        f
    }

    /// Power tables of the three coordinates with their first and second derivatives:
    /// `[t^e, e·t^(e−1), e(e−1)·t^(e−2)]` at index e for each axis, the three side by side so
    /// the inner loops read one row per exponent.
    #[inline(always)]
    fn derivative_powers<const T: usize>(n: usize, q: [f64; 3]) -> [[[f64; 3]; T]; 3] {
        let t = Self::powers::<T>(n, q);
        let mut d = [[[0.0; 3]; T]; 3];
        for a in 0..3 {
            for (e, row) in d[a].iter_mut().enumerate().take(n + 1) {
                let ef = e as f64;
                *row = [t[a][e + 2], ef * t[a][e + 1], ef * (ef - 1.0) * t[a][e]];
            }
        }
        d
    }

    /// f and ∇f at the normalized point `q`.
    fn gradient(&self, q: [f64; 3]) -> (f64, [f64; 3]) {
        let (f, g, _) = self.derivatives::<false>(q);
        (f, g)
    }

    /// f, ∇f and the Hessian at the normalized point `q`.
    fn hessian(&self, q: [f64; 3]) -> (f64, [f64; 3], [[f64; 3]; 3]) {
        self.derivatives::<true>(q)
    }

    /// f, ∇f and, when `HESSIAN`, the Hessian (zero otherwise) at the normalized point `q`.
    ///
    /// Compiled for the baseline target and, on x86-64, for AVX2 too, picked at run time (one
    /// cached check), and for each degree up to 8 with the loop bounds as constants. Every
    /// version performs the same IEEE operations in the same order (Rust never contracts a
    /// multiply and an add into an FMA, and without fast-math the compiler vectorizes only where
    /// the order of every sum is kept), so they differ in speed, not in bits.
    #[inline]
    fn derivatives<const HESSIAN: bool>(&self, q: [f64; 3]) -> (f64, [f64; 3], [[f64; 3]; 3]) {
        #[cfg(target_arch = "x86_64")]
        {
            #[target_feature(enable = "avx2")]
            fn avx2<const HESSIAN: bool>(
                e: &Evaluator,
                q: [f64; 3],
            ) -> (f64, [f64; 3], [[f64; 3]; 3]) {
                e.derivatives_by_degree::<HESSIAN>(q)
            }
            if std::arch::is_x86_feature_detected!("avx2") {
                // SAFETY: `avx2` needs only the AVX2 instructions, which this CPU has (checked
                // just above).
                return unsafe { avx2::<HESSIAN>(self, q) };
            }
        }
        self.derivatives_by_degree::<HESSIAN>(q)
    }

    /// [`Self::derivatives`] with the degree as a constant where it is at most 8, and tables
    /// sized to the degree (short ones are cheaper to clear and keep in cache).
    #[inline(always)]
    fn derivatives_by_degree<const HESSIAN: bool>(
        &self,
        q: [f64; 3],
    ) -> (f64, [f64; 3], [[f64; 3]; 3]) {
        match self.degree {
            1 => self.derivatives_with::<SHORT_TABLE, HESSIAN>(1, q),
            2 => self.derivatives_with::<SHORT_TABLE, HESSIAN>(2, q),
            3 => self.derivatives_with::<SHORT_TABLE, HESSIAN>(3, q),
            4 => self.derivatives_with::<SHORT_TABLE, HESSIAN>(4, q),
            5 => self.derivatives_with::<SHORT_TABLE, HESSIAN>(5, q),
            6 => self.derivatives_with::<SHORT_TABLE, HESSIAN>(6, q),
            7 => self.derivatives_with::<SHORT_TABLE, HESSIAN>(7, q),
            8 => self.derivatives_with::<SHORT_TABLE, HESSIAN>(8, q),
            n if n + 3 <= SHORT_TABLE => self.derivatives_with::<SHORT_TABLE, HESSIAN>(n, q),
            n => self.derivatives_with::<TABLE, HESSIAN>(n, q),
        }
    }

    /// [`Self::derivatives`] for degree `n` (= `self.degree`) with tables of length
    /// `T ≥ n + 3`, four i at a time as [`Self::value_with`]. The second-order sums are compiled
    /// out when `HESSIAN` is false; f and ∇f are summed in the same order either way.
    // i and j index three derivative tables each and size the columns: plain ranges read best.
    #[allow(clippy::needless_range_loop)]
    #[inline(always)]
    fn derivatives_with<const T: usize, const HESSIAN: bool>(
        &self,
        n: usize,
        q: [f64; 3],
    ) -> (f64, [f64; 3], [[f64; 3]; 3]) {
        let [x, y, z] = Self::derivative_powers::<T>(n, q);
        let mut rows = self.lanes.as_slice();
        let (mut f, mut g, mut h) = (0.0, [0.0; 3], [[0.0; 3]; 3]);
        for i0 in (0..=n).step_by(LANES) {
            // t_ab = Σ_j y^(a)_j s^(b)_ij with s^(b)_ij = Σ_k a_ijk z^(b)_k, one lane per i.
            let zero = [0.0; LANES];
            let (mut t00, mut t10, mut t01) = (zero, zero, zero);
            let (mut t20, mut t02, mut t11) = (zero, zero, zero);
            for j in 0..=n - i0 {
                let (col, rest) = rows.split_at(n - i0 - j + 1);
                rows = rest;
                let (mut s0, mut s1, mut s2) = (zero, zero, zero);
                for (a, zk) in col.iter().zip(&z) {
                    for l in 0..LANES {
                        s0[l] += a[l] * zk[0];
                        s1[l] += a[l] * zk[1];
                        if HESSIAN {
                            s2[l] += a[l] * zk[2];
                        }
                    }
                }
                let [y0, y1, y2] = y[j];
                for l in 0..LANES {
                    t00[l] += y0 * s0[l];
                    t10[l] += y1 * s0[l];
                    t01[l] += y0 * s1[l];
                    if HESSIAN {
                        t20[l] += y2 * s0[l];
                        t02[l] += y0 * s2[l];
                        t11[l] += y1 * s1[l];
                    }
                }
            }
            for l in 0..LANES.min(n + 1 - i0) {
                let [x0, x1, x2] = x[i0 + l];
                f += x0 * t00[l];
                g[0] += x1 * t00[l];
                g[1] += x0 * t10[l];
                g[2] += x0 * t01[l];
                if HESSIAN {
                    h[0][0] += x2 * t00[l];
                    h[1][1] += x0 * t20[l];
                    h[2][2] += x0 * t02[l];
                    h[0][1] += x1 * t10[l];
                    h[0][2] += x1 * t01[l];
                    h[1][2] += x0 * t11[l];
                }
            }
        }
        (h[1][0], h[2][0], h[2][1]) = (h[0][1], h[0][2], h[1][2]);
        (f, g, h)
    }

    /// Taubin's distance at the input point `p`, input units, clamped to ±`clamp`.
    pub(super) fn taubin(&self, p: [f64; 3], clamp: f64) -> f64 {
        let (f, g) = self.gradient(self.normalize(p));
        if f == 0.0 {
            return 0.0;
        }
        let norm = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        let d = f / norm * self.scale;
        if d.is_nan() {
            clamp.copysign(f)
        } else {
            d.clamp(-clamp, clamp)
        }
    }

    /// Newton steps x ← x − f ∇f/|∇f|² from `start` onto f = 0; `None` when they do not converge
    /// or wander farther than `max_move` (normalized units).
    fn project(&self, start: [f64; 3], max_move: f64) -> Option<[f64; 3]> {
        let mut x = start;
        for _ in 0..30 {
            let (f, g) = self.gradient(x);
            let g2 = g[0] * g[0] + g[1] * g[1] + g[2] * g[2];
            if !(g2 > 0.0 && g2.is_finite()) {
                return None;
            }
            if f.abs() / g2.sqrt() < ON_SURFACE_TOL {
                return (dist(x, start) <= max_move).then_some(x);
            }
            x = [0, 1, 2].map(|a| x[a] - f * g[a] / g2);
        }
        None
    }

    /// The closest point to `q` on f = 0 near the surface point `start`: Newton's method on
    /// x − q + λ∇f(x) = 0, f(x) = 0 with step halving on the residual; `None` when it fails.
    fn closest_point(&self, q: [f64; 3], start: [f64; 3]) -> Option<[f64; 3]> {
        let residual = |x: [f64; 3], lambda: f64| {
            let (f, g, h) = self.hessian(x);
            let r = [
                x[0] - q[0] + lambda * g[0],
                x[1] - q[1] + lambda * g[1],
                x[2] - q[2] + lambda * g[2],
                f,
            ];
            (r, f, g, h)
        };
        let norm2 = |r: &[f64; 4]| r.iter().map(|c| c * c).sum::<f64>();
        let mut x = start;
        let (f0, mut g, mut h) = self.hessian(x);
        let g2 = g[0] * g[0] + g[1] * g[1] + g[2] * g[2];
        if !(g2.is_finite() && g2 > 0.0) {
            return None;
        }
        let mut lambda = ((q[0] - x[0]) * g[0] + (q[1] - x[1]) * g[1] + (q[2] - x[2]) * g[2]) / g2;
        let mut r = [0, 1, 2, 3].map(|a| {
            if a < 3 {
                x[a] - q[a] + lambda * g[a]
            } else {
                f0
            }
        });
        for _ in 0..40 {
            // Converged to rounding: stop before a step that cannot reduce the residual.
            let gn = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
            let rx = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
            if r[3].abs() <= 1e-14 * gn && rx <= 1e-12 * (1.0 + dist(q, x)) {
                break;
            }
            let mut jac = [[0.0; 5]; 4];
            for a in 0..3 {
                for b in 0..3 {
                    jac[a][b] = lambda * h[a][b] + if a == b { 1.0 } else { 0.0 };
                }
                jac[a][3] = g[a];
                jac[3][a] = g[a];
                jac[a][4] = -r[a];
            }
            jac[3][4] = -r[3];
            let step = solve4(jac)?;
            let scale = 1.0 + x.iter().map(|c| c.abs()).fold(0.0, f64::max);
            let size = step[..3].iter().map(|c| c.abs()).fold(0.0, f64::max);
            if size < 1e-14 * scale {
                break;
            }
            // Newton converges quadratically: after a step this small the new point is exact to
            // about its square (far below the f32 output), so it only needs the on-surface check.
            if size < NEWTON_FINAL_STEP * scale {
                let xt = [0, 1, 2].map(|a| x[a] + step[a]);
                let ft = self.value(xt);
                if ft.abs() / gn < ON_SURFACE_TOL && xt.iter().all(|c| c.is_finite()) {
                    return Some(xt);
                }
            }
            // A short step lands within about its square of the closest point, and that error
            // is mostly along the normal; one projection along ∇f fixes it (the distance is
            // second order in the tangential error that remains): two values of f instead of
            // the Hessian at the new point and one more step. See NEWTON_PROJECT_STEP.
            if size < NEWTON_PROJECT_STEP * scale && size * size < NEWTON_PROJECT_AREA * dist(q, x)
            {
                let xt = [0, 1, 2].map(|a| x[a] + step[a]);
                let ft = self.value(xt);
                // ∇f at xt to first order, from the Hessian at x.
                let gt = [0, 1, 2].map(|a| g[a] + (0..3).map(|b| h[a][b] * step[b]).sum::<f64>());
                let gt2 = gt[0] * gt[0] + gt[1] * gt[1] + gt[2] * gt[2];
                let xp = [0, 1, 2].map(|a| xt[a] - ft * gt[a] / gt2);
                let fp = self.value(xp);
                if fp.abs() / gn < ON_SURFACE_TOL && xp.iter().all(|c| c.is_finite()) {
                    return Some(xp);
                }
            }
            // Halve the step until the residual decreases.
            let old = norm2(&r);
            let mut t = 1.0;
            let mut accepted = false;
            for _ in 0..8 {
                let xt = [0, 1, 2].map(|a| x[a] + t * step[a]);
                let lt = lambda + t * step[3];
                let (rt, _, gt, ht) = residual(xt, lt);
                if norm2(&rt) < old || norm2(&rt) == 0.0 {
                    (x, lambda, r, g, h) = (xt, lt, rt, gt, ht);
                    accepted = true;
                    break;
                }
                t *= 0.5;
            }
            if !accepted {
                break;
            }
        }
        let gn = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        let on_surface = r[3].abs() / gn < ON_SURFACE_TOL;
        (on_surface && x.iter().all(|c| c.is_finite())).then_some(x)
    }
}

/// Solves a 4×4 system given as an augmented matrix (Gaussian elimination, partial pivoting).
fn solve4(mut m: [[f64; 5]; 4]) -> Option<[f64; 4]> {
    for col in 0..4 {
        let pivot = (col..4).max_by(|&a, &b| m[a][col].abs().total_cmp(&m[b][col].abs()))?;
        let size = m[pivot][col].abs();
        if !(size.is_finite() && size > 1e-300) {
            return None;
        }
        m.swap(col, pivot);
        let pivot_row = m[col];
        for row in m.iter_mut().skip(col + 1) {
            let factor = row[col] / pivot_row[col];
            for (x, p) in row.iter_mut().zip(&pivot_row).skip(col) {
                *x -= factor * p;
            }
        }
    }
    let mut x = [0.0; 4];
    for row in (0..4).rev() {
        let s: f64 = (row + 1..4).map(|c| m[row][c] * x[c]).sum();
        x[row] = (m[row][4] - s) / m[row][row];
    }
    x.iter().all(|c| c.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::super::tests::torus;
    use super::*;

    #[test]
    fn hessian_matches_finite_differences() {
        let t = torus(1.0, 0.4);
        let e = Evaluator::new(&t).unwrap();
        let q = [0.3, -0.7, 0.2];
        let (f, g, h) = e.hessian(q);
        assert!((f - t.eval(q)).abs() < 1e-12);
        let (_, g_ref) = t.eval_gradient(q);
        let step = 1e-6;
        for a in 0..3 {
            assert!((g[a] - g_ref[a]).abs() < 1e-12);
            let mut qp = q;
            let mut qm = q;
            qp[a] += step;
            qm[a] -= step;
            let (_, gp) = e.gradient(qp);
            let (_, gm) = e.gradient(qm);
            for b in 0..3 {
                assert!((h[a][b] - (gp[b] - gm[b]) / (2.0 * step)).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn exact_distance_to_torus_matches_analytic() {
        let (big, small) = (1.0, 0.4);
        let region = Aabb {
            min: [-1.6, -1.6, -0.6],
            max: [1.6, 1.6, 0.6],
        };
        let exact = ExactDistance::new(&torus(big, small), &region).unwrap();
        assert!(exact.n_samples() > 1000);
        for i in 0..400 {
            let t = i as f64;
            let p = [
                1.7 * (t * 0.37).sin(),
                1.7 * (t * 0.53).cos(),
                0.7 * (t * 0.29).sin(),
            ];
            let rho = (p[0] * p[0] + p[1] * p[1]).sqrt();
            let truth = ((rho - big).powi(2) + p[2] * p[2]).sqrt() - small;
            let d = exact.distance(p);
            assert!((d - truth).abs() < 1e-9, "p = {p:?}: {d} vs {truth}");
        }
    }

    /// f, ∇f and the Hessian summed column by column in the nested order, one term at a time:
    /// the definition the lane kernels must match bit for bit.
    // The exponents index three tables each: plain ranges read best.
    #[allow(clippy::needless_range_loop)]
    fn nested_reference(e: &Evaluator, q: [f64; 3]) -> (f64, [f64; 3], [[f64; 3]; 3]) {
        let n = e.degree;
        let pw = |t: f64| -> Vec<[f64; 3]> {
            let mut p = vec![0.0; n + 3];
            let mut v = 1.0;
            for e in 0..=n {
                p[e + 2] = v;
                v *= t;
            }
            (0..=n)
                .map(|e| {
                    let ef = e as f64;
                    [p[e + 2], ef * p[e + 1], ef * (ef - 1.0) * p[e]]
                })
                .collect()
        };
        let (x, y, z) = (pw(q[0]), pw(q[1]), pw(q[2]));
        let mut at = 0;
        let (mut f, mut g, mut h) = (0.0, [0.0; 3], [[0.0; 3]; 3]);
        for i in 0..=n {
            let mut t = [0.0; 6];
            for j in 0..=n - i {
                let mut s = [0.0; 3];
                for k in 0..=n - i - j {
                    for b in 0..3 {
                        s[b] += e.nested[at] * z[k][b];
                    }
                    at += 1;
                }
                t[0] += y[j][0] * s[0];
                t[1] += y[j][1] * s[0];
                t[2] += y[j][0] * s[1];
                t[3] += y[j][2] * s[0];
                t[4] += y[j][0] * s[2];
                t[5] += y[j][1] * s[1];
            }
            let [x0, x1, x2] = x[i];
            f += x0 * t[0];
            g[0] += x1 * t[0];
            g[1] += x0 * t[1];
            g[2] += x0 * t[2];
            h[0][0] += x2 * t[0];
            h[1][1] += x0 * t[3];
            h[2][2] += x0 * t[4];
            h[0][1] += x1 * t[1];
            h[0][2] += x1 * t[2];
            h[1][2] += x0 * t[5];
        }
        (h[1][0], h[2][0], h[2][1]) = (h[0][1], h[0][2], h[1][2]);
        (f, g, h)
    }

    #[test]
    fn lane_kernels_match_the_nested_sums_bit_for_bit() {
        let bits = |v: &[f64]| v.iter().map(|c| c.to_bits()).collect::<Vec<_>>();
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = move || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        // Degrees on both table sizes, some coefficients zero (as fits often have).
        for degree in [1, 2, 3, 4, 5, 7, 8, 9, 10, 11, 13] {
            let coefficients = (0..n_coefficients(degree))
                .map(|l| if l % 5 == 3 { 0.0 } else { next() })
                .collect();
            let poly = ImplicitPolynomial {
                degree,
                coefficients,
                center: [0.0; 3],
                scale: 1.0,
            };
            let e = Evaluator::new(&poly).unwrap();
            for _ in 0..20 {
                let q = [1.7 * next(), 1.7 * next(), 1.7 * next()];
                let (f, g, h) = e.hessian(q);
                let (rf, rg, rh) = nested_reference(&e, q);
                assert_eq!(bits(&[f]), bits(&[rf]), "degree {degree} at {q:?}");
                assert_eq!(bits(&g), bits(&rg), "degree {degree} at {q:?}");
                assert_eq!(bits(h.as_flattened()), bits(rh.as_flattened()));
                let (gf, gg) = e.gradient(q);
                assert_eq!(
                    bits(&[gf, gg[0], gg[1], gg[2]]),
                    bits(&[rf, rg[0], rg[1], rg[2]])
                );
                assert_eq!(e.value(q).to_bits(), rf.to_bits());
                // The line sums (nested order) give the same value off the line's y.
                let line = e.line([q[0], q[1] + 0.25, q[2]]);
                assert_eq!(e.value_on_line(&line, q).to_bits(), rf.to_bits());
            }
        }
    }
}
