//! The fit's linear system, accumulated in one streaming pass: radial normalization (paper 2.2),
//! the 3L layers (5.5), the moments that make up MᵀM and Mᵀb, and the ridge matrix D (6.18).
//!
//! Every entry of MᵀM is a moment: (MᵀM)_{lm} = Σ_rows m_l(q) m_m(q) = Σ_rows q^{e_l + e_m}, a
//! monomial of degree ≤ 2n. So instead of the 3N×c matrix M the pass accumulates the
//! C(2n+3, 3) moments Σ x^a y^b z^c over the rows (969 at n = 8 against c² = 27,225 Gram entries)
//! and the c weighted moments Σ b_row q^e that make Mᵀb, plus β_r = Σ_t |p̂_t|^{2r} over the
//! data points. Memory is O(moments), independent of N.
//!
//! ```text
//! points ─▶ fixed chunks of 2,048 points ─(rayon, 32 chunks at a time)─▶ per-chunk moments
//!        ─▶ summed in chunk order (deterministic for any thread count) ─▶ MᵀM, Mᵀb, β
//! ```
//!
//! Inside a chunk the rows are processed in blocks of 256 in structure-of-arrays form: for each
//! (a, b) the product x^a y^b is formed once for the block and dotted with four powers z^c at a
//! time. With AVX2 + FMA (detected at run time) the dot products use fused multiply-adds;
//! otherwise the same eight-lane order with separate multiplies and adds. Either way the result
//! is the same for any thread count on a given CPU; the two kernels differ in the last bits.
//!
//! With AVX-512 (detected at run time) a third kernel gives bit for bit the sums of the AVX2 +
//! FMA one, in a quarter of the instructions: one 8-lane register holds the eight lanes of a
//! sum (the same fused multiply-adds in the same order), a tile of 3 (a, b) pairs × up to 8
//! powers z^c keeps its sums in registers while each power table is loaded once, and the eight
//! sums of a row of the tile are reduced together by a transpose whose additions are the
//! scalar pairwise ((l₀ + l₁) + (l₂ + l₃)) + ((l₄ + l₅) + (l₆ + l₇)).

use rayon::prelude::*;

use crate::cloud::OrientedCloud;
use crate::poly::{exponents, monomial_index, n_coefficients};

/// Rows per structure-of-arrays block.
const BLOCK: usize = 256;
/// Points per chunk (the unit of parallel work and of the fixed reduction order).
const CHUNK_POINTS: usize = 2048;
/// Chunks processed in parallel before their sums are added (in order) to the total; bounds
/// memory independently of N.
const CHUNKS_PER_BATCH: usize = 32;

/// Radial normalization p̂ = (p − center)/scale (paper 2.2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Normalization {
    /// The centroid μ of the data points.
    pub center: [f64; 3],
    /// The mean distance s of the data points to μ.
    pub scale: f64,
}

impl Normalization {
    /// Centroid and mean radial distance, both summed in fixed chunks in a fixed order.
    pub(crate) fn of(points: &[[f64; 3]]) -> Normalization {
        let n = points.len().max(1) as f64;
        let sums: Vec<[f64; 3]> = points
            .par_chunks(CHUNK_POINTS)
            .map(|chunk| {
                let mut s = [0.0; 3];
                for p in chunk {
                    for a in 0..3 {
                        s[a] += p[a];
                    }
                }
                s
            })
            .collect();
        let mut center = [0.0; 3];
        for s in &sums {
            for a in 0..3 {
                center[a] += s[a];
            }
        }
        let center = center.map(|c| c / n);
        let dists: Vec<f64> = points
            .par_chunks(CHUNK_POINTS)
            .map(|chunk| {
                chunk
                    .iter()
                    .map(|p| {
                        let d = [0, 1, 2].map(|a| p[a] - center[a]);
                        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
                    })
                    .sum::<f64>()
            })
            .collect();
        let scale = dists.iter().sum::<f64>() / n;
        Normalization { center, scale }
    }

    /// p̂ for an input point.
    pub(crate) fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| (p[a] - self.center[a]) / self.scale)
    }
}

/// Which rows the system has.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum Rows {
    /// Only the data points, no right-hand side (plain least squares, paper section 4).
    Data,
    /// The 3L layers p̂, p̂ + εn, p̂ − εn with targets 0, +ε, −ε (paper 5.5).
    ThreeLayers {
        /// Layer offset ε in normalized units.
        epsilon: f64,
    },
}

/// The accumulated system of one fit.
#[derive(Clone, Debug)]
pub(crate) struct System {
    /// Fit degree n.
    pub degree: u32,
    /// Moments Σ q^e over all rows for every e of degree ≤ 2n, in the paper's graded order.
    pub moments: Vec<f64>,
    /// Mᵀb in the paper's order (zero for [`Rows::Data`]).
    pub rhs: Vec<f64>,
    /// β_r = Σ_t |p̂_t|^{2r} over the data points, r = 0 … n.
    pub beta: Vec<f64>,
}

impl System {
    /// The Gram matrix MᵀM (c×c, row-major) assembled from the moments.
    pub(crate) fn gram(&self) -> Vec<f64> {
        let e = exponents(self.degree);
        let c = e.len();
        let mut g = vec![0.0; c * c];
        for l in 0..c {
            for m in l..c {
                let sum = [e[l][0] + e[m][0], e[l][1] + e[m][1], e[l][2] + e[m][2]];
                let v = self.moments[monomial_index(sum)];
                g[l * c + m] = v;
                g[m * c + l] = v;
            }
        }
        g
    }

    /// The diagonal of the ridge matrix D (6.18): D_ll = β_{i+j+k} / T_ll with the trinomial
    /// coefficient T_ll = (i+j+k)!/(i! j! k!).
    pub(crate) fn ridge_diagonal(&self) -> Vec<f64> {
        ridge_diagonal(self.degree, &self.beta)
    }
}

/// D_ll = β_{i+j+k} / T_ll for every monomial of degree ≤ `degree`.
pub(crate) fn ridge_diagonal(degree: u32, beta: &[f64]) -> Vec<f64> {
    exponents(degree)
        .iter()
        .map(|e| {
            let r = (e[0] + e[1] + e[2]) as usize;
            beta[r] / trinomial(*e)
        })
        .collect()
}

/// (i+j+k)!/(i! j! k!) as f64 (exact for the degrees used here).
fn trinomial(e: [u32; 3]) -> f64 {
    let mut t = 1.0;
    let mut n = 0.0;
    for &ei in &e {
        for m in 1..=ei {
            n += 1.0;
            t = t * n / m as f64;
        }
    }
    t.round()
}

/// Index layout of the per-chunk "tensor" accumulator: for a, then b, a contiguous run over c.
struct TensorLayout {
    max_degree: usize,
    /// (a, b, offset) with the run c = 0 ..= max_degree − a − b at `offset`.
    pairs: Vec<(usize, usize, usize)>,
    len: usize,
}

impl TensorLayout {
    fn new(max_degree: usize) -> TensorLayout {
        let mut pairs = Vec::new();
        let mut len = 0;
        for a in 0..=max_degree {
            for b in 0..=(max_degree - a) {
                pairs.push((a, b, len));
                len += max_degree - a - b + 1;
            }
        }
        TensorLayout {
            max_degree,
            pairs,
            len,
        }
    }

    /// Reorders tensor-layout sums into the paper's graded order.
    fn to_graded(&self, tensor: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; n_coefficients(self.max_degree as u32)];
        for &(a, b, offset) in &self.pairs {
            for c in 0..=(self.max_degree - a - b) {
                out[monomial_index([a as u32, b as u32, c as u32])] = tensor[offset + c];
            }
        }
        out
    }
}

/// Per-chunk partial sums.
struct Partial {
    moments: Vec<f64>,
    rhs: Vec<f64>,
    beta: Vec<f64>,
}

/// Accumulates the system of a fit of degree `degree` over `cloud` (already validated: finite,
/// unit normals), in the normalization `norm`.
pub(crate) fn accumulate(
    cloud: &OrientedCloud,
    norm: &Normalization,
    degree: u32,
    rows: Rows,
) -> System {
    let n = degree as usize;
    let gram_layout = TensorLayout::new(2 * n);
    let rhs_layout = TensorLayout::new(n);
    let n_points = cloud.points.len();
    let mut total = Partial {
        moments: vec![0.0; gram_layout.len],
        rhs: vec![0.0; rhs_layout.len],
        beta: vec![0.0; n + 1],
    };
    let n_chunks = n_points.div_ceil(CHUNK_POINTS);
    let mut chunk_start = 0;
    while chunk_start < n_chunks {
        let chunk_end = (chunk_start + CHUNKS_PER_BATCH).min(n_chunks);
        let partials: Vec<Partial> = (chunk_start..chunk_end)
            .into_par_iter()
            .map(|chunk| {
                let lo = chunk * CHUNK_POINTS;
                let hi = (lo + CHUNK_POINTS).min(n_points);
                accumulate_chunk(cloud, lo..hi, norm, n, rows, &gram_layout, &rhs_layout)
            })
            .collect();
        for p in partials {
            for (t, v) in total.moments.iter_mut().zip(&p.moments) {
                *t += v;
            }
            for (t, v) in total.rhs.iter_mut().zip(&p.rhs) {
                *t += v;
            }
            for (t, v) in total.beta.iter_mut().zip(&p.beta) {
                *t += v;
            }
        }
        chunk_start = chunk_end;
    }
    System {
        degree,
        moments: gram_layout.to_graded(&total.moments),
        rhs: rhs_layout.to_graded(&total.rhs),
        beta: total.beta,
    }
}

/// Padding after each row of a power table, in f64: rows of exactly [`BLOCK`] f64 (2 KiB) would
/// put the same offset of every row in the same few L1 cache sets, and the kernels read a dozen
/// rows at the same offset at once.
const ROW_PAD: usize = 8;

/// One row of a power table: the block's values, then [`ROW_PAD`] unused f64.
#[derive(Clone, Copy)]
#[repr(C)]
struct PowerRow {
    values: [f64; BLOCK],
    _pad: [f64; ROW_PAD],
}

impl PowerRow {
    const ZERO: PowerRow = PowerRow {
        values: [0.0; BLOCK],
        _pad: [0.0; ROW_PAD],
    };
}

impl std::ops::Deref for PowerRow {
    type Target = [f64; BLOCK];
    fn deref(&self) -> &[f64; BLOCK] {
        &self.values
    }
}

impl std::ops::DerefMut for PowerRow {
    fn deref_mut(&mut self) -> &mut [f64; BLOCK] {
        &mut self.values
    }
}

/// Structure-of-arrays scratch for one block of rows.
struct BlockScratch {
    /// px[e][t] = x_t^e, e ≤ 2n (x⁰ is 0 for padding rows, so they contribute nothing).
    px: Vec<PowerRow>,
    py: Vec<PowerRow>,
    pz: Vec<PowerRow>,
    /// Row weights b (targets) for Mᵀb.
    w: [f64; BLOCK],
    xs: [f64; BLOCK],
    ys: [f64; BLOCK],
    zs: [f64; BLOCK],
    len: usize,
}

impl BlockScratch {
    /// An empty scratch for a fit of degree `n`: power tables up to 2n (z's padded for the
    /// last group of four dot products).
    fn new(n: usize) -> BlockScratch {
        BlockScratch {
            px: vec![PowerRow::ZERO; 2 * n + 1],
            py: vec![PowerRow::ZERO; 2 * n + 1],
            pz: vec![PowerRow::ZERO; 2 * n + Z_PADDING],
            w: [0.0; BLOCK],
            xs: [0.0; BLOCK],
            ys: [0.0; BLOCK],
            zs: [0.0; BLOCK],
            len: 0,
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn accumulate_chunk(
    cloud: &OrientedCloud,
    range: std::ops::Range<usize>,
    norm: &Normalization,
    n: usize,
    rows: Rows,
    gram_layout: &TensorLayout,
    rhs_layout: &TensorLayout,
) -> Partial {
    let two_n = 2 * n;
    let mut partial = Partial {
        moments: vec![0.0; gram_layout.len],
        rhs: vec![0.0; rhs_layout.len],
        beta: vec![0.0; n + 1],
    };
    let mut scratch = BlockScratch::new(n);
    let use_fma = fma_available();
    let use_avx512 = use_fma && avx512_available();
    let flush = |scratch: &mut BlockScratch, partial: &mut Partial| {
        if scratch.len == 0 {
            return;
        }
        // The power tables and the sums, both compiled for the widest vectors the CPU has.
        #[cfg(target_arch = "x86_64")]
        if use_avx512 {
            // SAFETY: only called when the CPU reports AVX-512F.
            unsafe {
                fill_powers_avx512(scratch, two_n);
                accumulate_block_avx512(scratch, n, gram_layout, rhs_layout, partial);
            }
            scratch.len = 0;
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if use_fma {
            // SAFETY: only called when the CPU reports AVX2 and FMA.
            unsafe {
                fill_powers_avx2(scratch, two_n);
                accumulate_block_fma(scratch, n, gram_layout, rhs_layout, partial);
            }
            scratch.len = 0;
            return;
        }
        let _ = use_fma;
        fill_powers(scratch, two_n);
        accumulate_block::<PortableDots>(scratch, n, gram_layout, rhs_layout, partial);
        scratch.len = 0;
    };
    for t in range {
        let q = norm.apply(cloud.points[t]);
        // β_r over the data points.
        let r2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
        let mut pw = 1.0;
        for b in partial.beta.iter_mut() {
            *b += pw;
            pw *= r2;
        }
        let push = |scratch: &mut BlockScratch, partial: &mut Partial, p: [f64; 3], w: f64| {
            let i = scratch.len;
            scratch.xs[i] = p[0];
            scratch.ys[i] = p[1];
            scratch.zs[i] = p[2];
            scratch.w[i] = w;
            scratch.len += 1;
            if scratch.len == BLOCK {
                flush(scratch, partial);
            }
        };
        push(&mut scratch, &mut partial, q, 0.0);
        if let Rows::ThreeLayers { epsilon } = rows {
            let nrm = cloud.normals[t];
            let outer = [0, 1, 2].map(|a| q[a] + epsilon * nrm[a]);
            let inner = [0, 1, 2].map(|a| q[a] - epsilon * nrm[a]);
            push(&mut scratch, &mut partial, outer, epsilon);
            push(&mut scratch, &mut partial, inner, -epsilon);
        }
    }
    flush(&mut scratch, &mut partial);
    partial
}

fn fma_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the CPU has AVX-512F (the kernel of [`accumulate_block_avx512`]).
fn avx512_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Powers of z past 2n in the block's table: the last group of four sums of a run in
/// [`add_dots`] is padded with them and their sums dropped.
const Z_PADDING: usize = 4;

/// (a, b) pairs of one AVX-512 tile: 3 × 8 sums in registers (of 32), plus the three products
/// x^a y^b and the power of z being multiplied.
#[cfg(target_arch = "x86_64")]
const TILE_PAIRS: usize = 3;

/// [`fill_powers`] compiled for AVX-512 (the same products, eight at a time).
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn fill_powers_avx512(s: &mut BlockScratch, two_n: usize) {
    fill_powers(s, two_n);
}

/// [`fill_powers`] compiled for AVX2 (the same products, four at a time).
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn fill_powers_avx2(s: &mut BlockScratch, two_n: usize) {
    fill_powers(s, two_n);
}

/// Power tables of the block; padding rows get x⁰ = 0 so every product involving them is 0.
/// Each entry is one product of two doubles, so the tables are the same whatever the vector
/// width the loops are compiled for (`accumulate_chunk` picks the widest at run time).
#[inline(always)]
fn fill_powers(s: &mut BlockScratch, two_n: usize) {
    for t in 0..BLOCK {
        let live = if t < s.len { 1.0 } else { 0.0 };
        s.px[0][t] = live;
        s.py[0][t] = 1.0;
        s.pz[0][t] = 1.0;
        if t >= s.len {
            s.xs[t] = 0.0;
            s.ys[t] = 0.0;
            s.zs[t] = 0.0;
            s.w[t] = 0.0;
        }
    }
    for e in 1..=two_n {
        for t in 0..BLOCK {
            s.px[e][t] = s.px[e - 1][t] * s.xs[t];
            s.py[e][t] = s.py[e - 1][t] * s.ys[t];
        }
    }
    for e in 1..s.pz.len() {
        for t in 0..BLOCK {
            s.pz[e][t] = s.pz[e - 1][t] * s.zs[t];
        }
    }
}

/// The dot products of one block: a portable version and an AVX2+FMA one.
trait Dots {
    /// Four dot products of `x` at once.
    fn dot4(x: &[f64; BLOCK], ys: [&[f64; BLOCK]; 4]) -> [f64; 4];
}

/// Portable dot products: eight independent lanes, a fixed pairwise sum of the lanes.
struct PortableDots;

impl Dots for PortableDots {
    #[inline(always)]
    fn dot4(x: &[f64; BLOCK], ys: [&[f64; BLOCK]; 4]) -> [f64; 4] {
        dot4(x, ys)
    }
}

/// AVX2+FMA dot products (fused multiply-add, so the last bits differ from [`PortableDots`];
/// each is deterministic on its own).
#[cfg(target_arch = "x86_64")]
struct FmaDots;

#[cfg(target_arch = "x86_64")]
impl Dots for FmaDots {
    #[inline(always)]
    fn dot4(x: &[f64; BLOCK], ys: [&[f64; BLOCK]; 4]) -> [f64; 4] {
        // SAFETY: FmaDots is only used inside `accumulate_block_fma`, which requires AVX2 + FMA.
        unsafe { dot4_fma(x, ys) }
    }
}

/// Four dot products with eight 4-wide accumulators (two per output), then a fixed reduction.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline]
unsafe fn dot4_fma(x: &[f64; BLOCK], ys: [&[f64; BLOCK]; 4]) -> [f64; 4] {
    use std::arch::x86_64::*;
    let mut acc = [[_mm256_setzero_pd(); 2]; 4];
    for i in 0..BLOCK / 8 {
        // SAFETY: i * 8 + 4 + 4 ≤ BLOCK, so every load is in bounds.
        let (x0, x1) = unsafe {
            (
                _mm256_loadu_pd(x.as_ptr().add(i * 8)),
                _mm256_loadu_pd(x.as_ptr().add(i * 8 + 4)),
            )
        };
        for k in 0..4 {
            // SAFETY: as above.
            let (y0, y1) = unsafe {
                (
                    _mm256_loadu_pd(ys[k].as_ptr().add(i * 8)),
                    _mm256_loadu_pd(ys[k].as_ptr().add(i * 8 + 4)),
                )
            };
            acc[k][0] = _mm256_fmadd_pd(x0, y0, acc[k][0]);
            acc[k][1] = _mm256_fmadd_pd(x1, y1, acc[k][1]);
        }
    }
    let mut out = [0.0; 4];
    for k in 0..4 {
        let mut lanes = [0.0; 8];
        // SAFETY: `lanes` holds eight f64.
        unsafe {
            _mm256_storeu_pd(lanes.as_mut_ptr(), acc[k][0]);
            _mm256_storeu_pd(lanes.as_mut_ptr().add(4), acc[k][1]);
        }
        out[k] = ((lanes[0] + lanes[1]) + (lanes[2] + lanes[3]))
            + ((lanes[4] + lanes[5]) + (lanes[6] + lanes[7]));
    }
    out
}

/// [`accumulate_block`] with AVX2 + FMA dot products.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn accumulate_block_fma(
    s: &BlockScratch,
    n: usize,
    gram_layout: &TensorLayout,
    rhs_layout: &TensorLayout,
    partial: &mut Partial,
) {
    accumulate_block::<FmaDots>(s, n, gram_layout, rhs_layout, partial);
}

/// [`accumulate_block`] with AVX-512, bit for bit the sums of [`accumulate_block_fma`] (see the
/// module docs): for each a, the pairs (a, b) in tiles of [`TILE_PAIRS`] consecutive b, each
/// tile against the powers z^c in groups of eight and one of the rest.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn accumulate_block_avx512(
    s: &BlockScratch,
    n: usize,
    gram_layout: &TensorLayout,
    rhs_layout: &TensorLayout,
    partial: &mut Partial,
) {
    for (max_degree, layout, out, weighted) in [
        (2 * n, gram_layout, &mut partial.moments, false),
        (n, rhs_layout, &mut partial.rhs, true),
    ] {
        let mut pair = 0;
        for a in 0..=max_degree {
            let m = max_degree - a;
            let mut b0 = 0;
            while b0 <= m {
                let rows = (m + 1 - b0).min(TILE_PAIRS);
                let tile = Tile {
                    a,
                    b0,
                    m,
                    pairs: &layout.pairs[pair..pair + rows],
                    weighted,
                };
                let longest = m - b0 + 1;
                // Groups of eight powers, then one of the rest, over the tile's longest run
                // (its other rows, one power shorter each, drop the sums past their ends).
                let mut c0 = 0;
                while c0 < longest {
                    let group = (longest - c0).min(8);
                    // SAFETY: AVX-512F as this function; the tile's runs lie inside `out`, its
                    // powers inside the tables (c ≤ m ≤ 2n).
                    unsafe { tile_group(rows, group, s, &tile, c0, out) };
                    c0 += group;
                }
                pair += rows;
                b0 += rows;
            }
        }
    }
}

/// One tile of [`accumulate_block_avx512`]: the pairs (a, b₀ + r), r < R, whose runs of
/// powers c = 0 ..= m − b are added to `out` at their layout offsets, a group of powers at a
/// time ([`tile_group`]).
#[cfg(target_arch = "x86_64")]
struct Tile<'a> {
    a: usize,
    b0: usize,
    m: usize,
    /// The layout entries (a, b, offset) of the tile's pairs.
    pairs: &'a [(usize, usize, usize)],
    /// Whether the products are weighted by the row targets (Mᵀb) or not (the moments).
    weighted: bool,
}

/// [`tile_sums`] for `rows` pairs and `group` powers (both run-time), dispatched to the
/// instance whose registers hold exactly those sums.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn tile_group(
    rows: usize,
    group: usize,
    s: &BlockScratch,
    tile: &Tile<'_>,
    c0: usize,
    out: &mut [f64],
) {
    macro_rules! dispatch {
        ($($r:literal, $c:literal);*) => {
            match (rows, group, tile.weighted) {
                // SAFETY: AVX-512F as this function.
                $(
                    ($r, $c, false) => unsafe { tile_sums::<$r, $c, false>(s, tile, c0, out) },
                    ($r, $c, true) => unsafe { tile_sums::<$r, $c, true>(s, tile, c0, out) },
                )*
                _ => unreachable!("a tile has 1 to {TILE_PAIRS} pairs and 1 to 8 powers"),
            }
        };
    }
    dispatch!(
        3, 8; 3, 7; 3, 6; 3, 5; 3, 4; 3, 3; 3, 2; 3, 1;
        2, 8; 2, 7; 2, 6; 2, 5; 2, 4; 2, 3; 2, 2; 2, 1;
        1, 8; 1, 7; 1, 6; 1, 5; 1, 4; 1, 3; 1, 2; 1, 1
    );
}

/// Adds the sums of one group of a [`Tile`] of R pairs to `out`: the powers c0 … c0 + C − 1,
/// R × C 8-lane accumulators over the block's rows, then [`reduce8`] per pair.
///
/// # Safety
/// The CPU must support AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn tile_sums<const R: usize, const C: usize, const WEIGHTED: bool>(
    s: &BlockScratch,
    tile: &Tile<'_>,
    c0: usize,
    out: &mut [f64],
) {
    use std::arch::x86_64::*;
    // Every table row the loop reads, looked up (and bounds-checked) once: the loop itself is
    // loads and arithmetic only, so its R × C sums stay in registers.
    let xa = s.px[tile.a].as_ptr();
    let w = s.w.as_ptr();
    let ys: [*const f64; R] = std::array::from_fn(|r| s.py[tile.b0 + r].as_ptr());
    let zs: [*const f64; C] = std::array::from_fn(|k| s.pz[c0 + k].as_ptr());
    let mut acc = [[_mm512_setzero_pd(); 8]; R];
    for i in (0..BLOCK).step_by(8) {
        // SAFETY: i + 8 ≤ BLOCK and every pointer starts a row of BLOCK f64, so every load is
        // in bounds.
        unsafe {
            let x = _mm512_loadu_pd(xa.add(i));
            let xy: [__m512d; R] = std::array::from_fn(|r| {
                let v = _mm512_mul_pd(x, _mm512_loadu_pd(ys[r].add(i)));
                if WEIGHTED {
                    _mm512_mul_pd(v, _mm512_loadu_pd(w.add(i)))
                } else {
                    v
                }
            });
            for (k, zk) in zs.iter().enumerate() {
                let z = _mm512_loadu_pd(zk.add(i));
                for (sums, &x) in acc.iter_mut().zip(&xy) {
                    sums[k] = _mm512_fmadd_pd(x, z, sums[k]);
                }
            }
        }
    }
    for (r, acc) in acc.iter().enumerate() {
        let (_, b, offset) = tile.pairs[r];
        let len = tile.m - b + 1;
        if c0 >= len {
            continue;
        }
        let sums = reduce8(acc);
        let at = offset + c0;
        if C == 8 && len - c0 >= 8 {
            let run = &mut out[at..at + 8];
            // SAFETY: `run` holds eight f64.
            unsafe {
                let v = _mm512_add_pd(_mm512_loadu_pd(run.as_ptr()), sums);
                _mm512_storeu_pd(run.as_mut_ptr(), v);
            }
        } else {
            let mut lanes = [0.0; 8];
            // SAFETY: `lanes` holds eight f64.
            unsafe { _mm512_storeu_pd(lanes.as_mut_ptr(), sums) };
            let end = offset + len.min(c0 + C);
            for (o, v) in out[at..end].iter_mut().zip(lanes) {
                *o += v;
            }
        }
    }
}

/// The eight lane sums of eight accumulators, as one vector (lane k the sum of `acc[k]`), each
/// ((l₀ + l₁) + (l₂ + l₃)) + ((l₄ + l₅) + (l₆ + l₇)) as [`dot4_fma`] forms it: the same
/// additions of the same operands, done eight at a time after transposing.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
fn reduce8(acc: &[std::arch::x86_64::__m512d; 8]) -> std::arch::x86_64::__m512d {
    use std::arch::x86_64::*;
    // Pairs of neighbouring lanes: s01 = [A0 l0+l1, A1 l0+l1, A0 l2+l3, A1 l2+l3, …].
    let pair =
        |x: __m512d, y: __m512d| _mm512_add_pd(_mm512_unpacklo_pd(x, y), _mm512_unpackhi_pd(x, y));
    let (s01, s23) = (pair(acc[0], acc[1]), pair(acc[2], acc[3]));
    let (s45, s67) = (pair(acc[4], acc[5]), pair(acc[6], acc[7]));
    // Pairs of pairs: the 128-bit blocks (two sums each) 0 and 2 of x and of y, added to
    // blocks 1 and 3: the sums of l0..l3 and of l4..l7.
    const EVEN: i32 = 0b10_00_10_00;
    const ODD: i32 = 0b11_01_11_01;
    let quad = |x: __m512d, y: __m512d| {
        _mm512_add_pd(
            _mm512_shuffle_f64x2::<EVEN>(x, y),
            _mm512_shuffle_f64x2::<ODD>(x, y),
        )
    };
    // t0123 = [A0A1 (l0..l3), A0A1 (l4..l7), A2A3 (l0..l3), A2A3 (l4..l7)], likewise t4567.
    let (t0123, t4567) = (quad(s01, s23), quad(s45, s67));
    // The two halves: [A0A1, A2A3, A4A5, A6A7] of (l0..l3) plus the same of (l4..l7).
    quad(t0123, t4567)
}

/// Adds the block's moments to `partial`.
#[inline(always)]
fn accumulate_block<D: Dots>(
    s: &BlockScratch,
    n: usize,
    gram_layout: &TensorLayout,
    rhs_layout: &TensorLayout,
    partial: &mut Partial,
) {
    let two_n = 2 * n;
    let mut pxy = [0.0; BLOCK];
    let mut wxy = [0.0; BLOCK];
    let mut rhs_pair = 0;
    for &(a, b, offset) in &gram_layout.pairs {
        let (xa, yb) = (&s.px[a], &s.py[b]);
        for t in 0..BLOCK {
            pxy[t] = xa[t] * yb[t];
        }
        let run = &mut partial.moments[offset..=offset + two_n - a - b];
        add_dots::<D>(&pxy, &s.pz, run);
        if a + b <= n {
            debug_assert_eq!(rhs_layout.pairs[rhs_pair].0, a);
            let rhs_offset = rhs_layout.pairs[rhs_pair].2;
            rhs_pair += 1;
            for t in 0..BLOCK {
                wxy[t] = pxy[t] * s.w[t];
            }
            let run = &mut partial.rhs[rhs_offset..=rhs_offset + n - a - b];
            add_dots::<D>(&wxy, &s.pz, run);
        }
    }
}

/// run[c] += Σ_t x_t z_t^c for every c of the run, four at a time; the last group is padded
/// with the extra powers the table holds (their sums are dropped), which is cheaper than
/// single dot products that cannot hide the add latency.
#[inline(always)]
fn add_dots<D: Dots>(x: &[f64; BLOCK], pz: &[PowerRow], run: &mut [f64]) {
    let mut c = 0;
    while c < run.len() {
        let sums = D::dot4(x, [&pz[c], &pz[c + 1], &pz[c + 2], &pz[c + 3]]);
        for (k, v) in sums.into_iter().enumerate() {
            if let Some(acc) = run.get_mut(c + k) {
                *acc += v;
            }
        }
        c += 4;
    }
}

/// Four dot products of `x` with `ys` at once (x is loaded once per lane group; sixteen
/// independent accumulators hide the add latency). Each sum uses the same lane order and final
/// pairwise reduction as [`dot`], so results are identical whichever function computed them.
#[inline(always)]
fn dot4(x: &[f64; BLOCK], ys: [&[f64; BLOCK]; 4]) -> [f64; 4] {
    let mut lanes = [[0.0; 8]; 4];
    for i in 0..BLOCK / 8 {
        for k in 0..4 {
            for l in 0..8 {
                lanes[k][l] += x[i * 8 + l] * ys[k][i * 8 + l];
            }
        }
    }
    lanes.map(|v| ((v[0] + v[1]) + (v[2] + v[3])) + ((v[4] + v[5]) + (v[6] + v[7])))
}

#[cfg(test)]
mod tests;
