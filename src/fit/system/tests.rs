//! Unit tests of `fit::system`.

use super::*;

/// A block of `len` rows for degree `n`: row t at `row(t)` = (x, y, z, w), powers filled.
fn test_block(n: usize, len: usize, row: impl Fn(usize) -> [f64; 4]) -> BlockScratch {
    let mut s = BlockScratch::new(n);
    s.len = len;
    for t in 0..len {
        [s.xs[t], s.ys[t], s.zs[t], s.w[t]] = row(t);
    }
    fill_powers(&mut s, 2 * n);
    s
}

/// Zero moments and right-hand side for degree `n`, with their layouts.
fn zero_partial(n: usize) -> (TensorLayout, TensorLayout, Partial) {
    let (gram_layout, rhs_layout) = (TensorLayout::new(2 * n), TensorLayout::new(n));
    let partial = Partial {
        moments: vec![0.0; gram_layout.len],
        rhs: vec![0.0; rhs_layout.len],
        beta: vec![],
    };
    (gram_layout, rhs_layout, partial)
}

#[test]
fn portable_and_fma_kernels_agree() {
    let n = 4;
    let s = test_block(n, 50, |t| {
        let u = t as f64 * 0.37;
        let w = if t % 3 == 1 { 0.05 } else { -0.05 };
        [u.sin(), (1.7 * u).cos(), (0.3 * u).sin() * 1.4, w]
    });
    let (gram_layout, rhs_layout, mut portable) = zero_partial(n);
    accumulate_block::<PortableDots>(&s, n, &gram_layout, &rhs_layout, &mut portable);
    if !fma_available() {
        return;
    }
    let mut fused = zero_partial(n).2;
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU reports AVX2 and FMA.
    unsafe {
        accumulate_block_fma(&s, n, &gram_layout, &rhs_layout, &mut fused)
    };
    for (a, b) in portable
        .moments
        .iter()
        .zip(&fused.moments)
        .chain(portable.rhs.iter().zip(&fused.rhs))
    {
        assert!((a - b).abs() <= 1e-13 * (1.0 + a.abs()), "{a} vs {b}");
    }
    #[cfg(target_arch = "x86_64")]
    if avx512_available() {
        // The AVX-512 kernel gives the FMA kernel's sums bit for bit, at the fit's degree
        // and at this one.
        for n in [n, 8] {
            let s = test_block(n, 61, |t| {
                let u = t as f64 * 0.53;
                [
                    1.3 * u.cos(),
                    (0.9 * u).sin() - 0.2,
                    (1.1 * u).cos() * 0.8,
                    [0.0, 0.05, -0.05][t % 3],
                ]
            });
            let (gram_layout, rhs_layout, mut fused) = zero_partial(n);
            let mut wide = zero_partial(n).2;
            // SAFETY: the CPU reports AVX2, FMA and AVX-512F.
            unsafe {
                accumulate_block_fma(&s, n, &gram_layout, &rhs_layout, &mut fused);
                accumulate_block_avx512(&s, n, &gram_layout, &rhs_layout, &mut wide);
                // Twice, so that the sums are added to nonzero totals as well.
                accumulate_block_fma(&s, n, &gram_layout, &rhs_layout, &mut fused);
                accumulate_block_avx512(&s, n, &gram_layout, &rhs_layout, &mut wide);
            }
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(
                bits(&fused.moments),
                bits(&wide.moments),
                "moments, n = {n}"
            );
            assert_eq!(bits(&fused.rhs), bits(&wide.rhs), "rhs, n = {n}");
        }
    }
}

#[test]
fn trinomials() {
    assert_eq!(trinomial([2, 0, 0]), 1.0);
    assert_eq!(trinomial([1, 1, 0]), 2.0);
    assert_eq!(trinomial([1, 1, 1]), 6.0);
    assert_eq!(trinomial([2, 2, 2]), 90.0);
}

#[test]
fn degree_two_ridge_matches_design() {
    let beta = [3.0, 5.0, 7.0];
    let d = ridge_diagonal(2, &beta);
    assert_eq!(d, vec![3.0, 5.0, 5.0, 5.0, 7.0, 3.5, 3.5, 7.0, 3.5, 7.0]);
}

#[test]
fn moments_match_explicit_gram() {
    // A few points; compare the moment-assembled Gram matrix and Mᵀb with explicit rows.
    let points: Vec<[f64; 3]> = (0..150)
        .map(|i| {
            let t = i as f64 * 0.37;
            [
                t.sin() * 2.0 + 1.0,
                (1.3 * t).cos() - 0.5,
                (0.7 * t).sin() * 1.5,
            ]
        })
        .collect();
    let normals: Vec<[f64; 3]> = points
        .iter()
        .map(|p| {
            let n = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            p.map(|c| c / n)
        })
        .collect();
    let cloud = OrientedCloud {
        points,
        normals,
        weights: None,
    };
    let norm = Normalization::of(&cloud.points);
    let eps = 0.05;
    let sys = accumulate(&cloud, &norm, 3, Rows::ThreeLayers { epsilon: eps });
    let g = sys.gram();
    let e = exponents(3);
    let c = e.len();
    let mono = |q: [f64; 3], ex: [u32; 3]| {
        q[0].powi(ex[0] as i32) * q[1].powi(ex[1] as i32) * q[2].powi(ex[2] as i32)
    };
    let mut g_ref = vec![0.0; c * c];
    let mut r_ref = vec![0.0; c];
    for (p, nrm) in cloud.points.iter().zip(&cloud.normals) {
        let q = norm.apply(*p);
        for (t, w) in [(0.0, 0.0), (eps, eps), (-eps, -eps)] {
            let row = [0, 1, 2].map(|a| q[a] + t * nrm[a]);
            for l in 0..c {
                r_ref[l] += w * mono(row, e[l]);
                for m in 0..c {
                    g_ref[l * c + m] += mono(row, e[l]) * mono(row, e[m]);
                }
            }
        }
    }
    for i in 0..c * c {
        assert!(
            (g[i] - g_ref[i]).abs() <= 1e-10 * g_ref[i].abs().max(1.0),
            "gram entry {i}"
        );
    }
    for (l, (&got, &want)) in sys.rhs.iter().zip(&r_ref).enumerate() {
        assert!(
            (got - want).abs() <= 1e-12 * want.abs().max(1.0),
            "rhs entry {l}"
        );
    }
    assert_eq!(sys.beta[0], 150.0);
}
