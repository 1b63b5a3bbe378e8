//! The synthetic κ study: six shapes, sampled with exact normals, and an independent judge of
//! whether a fitted zero set is a "good fit". Used by `tools/kappa_study.rs` (the full table) and
//! by the reduced study in `tests/all/fit.rs`.
//!
//! Shapes (before normalization): sphere (radius 1), torus (R = 1, r = 0.4), an eight (the
//! peanut x⁴ − 1.5x² + y² + z² − 0.1 = 0), the heart (x² + 9/4 y² + z² − 1)³ − x²z³ − 9/80 y²z³ = 0,
//! a cube's surface ([−1, 1]³, sharp edges), and a twisted ellipsoid (semi-axes 1, 0.4, 1.5,
//! twisted about z by 0.8 rad per unit height). Variants: clean; Gaussian noise of variance
//! 0.0025 (σ = 0.05) per coordinate in normalized units; 15% of the points cut away (the
//! points with the largest x + 0.3y + 0.2z).
//!
//! The judge ([`assess`]) does not use the fit's own checks: it samples f on a uniform grid of
//! spacing 0.1 over the normalized box [−4, 4]³, labels the 6-connected components of grid cells
//! whose corners change sign, and calls a fit good when the leading form is positive on the unit
//! sphere, there is exactly one component, it comes within 0.2 of the data, and no cell on the
//! box's boundary changes sign.
//!
//! Sampling is deterministic (a fixed linear congruential generator), so the study is
//! reproducible.

use crate::cloud::OrientedCloud;
pub use crate::numerics::Lcg;
use crate::poly::ImplicitPolynomial;

/// A synthetic shape of the study.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    /// The unit sphere.
    Sphere,
    /// A torus, R = 1, r = 0.4.
    Torus,
    /// A peanut-shaped "eight".
    Eight,
    /// The heart surface.
    Heart,
    /// A cube's surface.
    Cube,
    /// A twisted ellipsoid.
    Twisted,
}

impl Shape {
    /// All six shapes.
    pub const ALL: [Shape; 6] = [
        Shape::Sphere,
        Shape::Torus,
        Shape::Eight,
        Shape::Heart,
        Shape::Cube,
        Shape::Twisted,
    ];

    /// A short name.
    pub fn name(&self) -> &'static str {
        match self {
            Shape::Sphere => "sphere",
            Shape::Torus => "torus",
            Shape::Eight => "eight",
            Shape::Heart => "heart",
            Shape::Cube => "cube",
            Shape::Twisted => "twisted",
        }
    }

    /// The implicit function (negative inside), except for the cube (sampled on its faces).
    fn implicit(&self, p: [f64; 3]) -> f64 {
        let [x, y, z] = p;
        match self {
            Shape::Sphere => x * x + y * y + z * z - 1.0,
            Shape::Torus => {
                let q = (x * x + y * y).sqrt() - 1.0;
                q * q + z * z - 0.16
            }
            Shape::Eight => x.powi(4) - 1.5 * x * x + y * y + z * z - 0.1,
            Shape::Heart => {
                let a = x * x + 2.25 * y * y + z * z - 1.0;
                a * a * a - x * x * z * z * z - 9.0 / 80.0 * y * y * z * z * z
            }
            Shape::Cube => x.abs().max(y.abs()).max(z.abs()) - 1.0,
            Shape::Twisted => {
                let t = 0.8 * z;
                let (s, c) = t.sin_cos();
                let u = c * x + s * y;
                let v = -s * x + c * y;
                u * u + v * v / 0.16 + z * z / 2.25 - 1.0
            }
        }
    }

    /// Half side of a box that contains the shape.
    fn extent(&self) -> f64 {
        match self {
            Shape::Twisted => 1.6,
            Shape::Torus => 1.5,
            _ => 1.3,
        }
    }
}

/// How the sample is degraded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Variant {
    /// Exact points.
    Clean,
    /// Gaussian noise of variance 0.0025 per coordinate, normalized units.
    Noisy,
    /// 15% of the points cut away.
    Cut,
}

impl Variant {
    /// All three variants.
    pub const ALL: [Variant; 3] = [Variant::Clean, Variant::Noisy, Variant::Cut];

    /// A short name.
    pub fn name(&self) -> &'static str {
        match self {
            Variant::Clean => "clean",
            Variant::Noisy => "noisy",
            Variant::Cut => "cut",
        }
    }
}

/// `n_points` points on `shape` with exact unit outward normals, degraded by `variant`.
pub fn sample(shape: Shape, variant: Variant, n_points: usize, seed: u64) -> OrientedCloud {
    let mut rng = Lcg::new(seed ^ (shape as u64) << 8);
    let mut cloud = OrientedCloud::default();
    let target = if variant == Variant::Cut {
        n_points * 100 / 85
    } else {
        n_points
    };
    if shape == Shape::Cube {
        while cloud.points.len() < target {
            let face = (rng.uniform() * 6.0) as usize % 6;
            let (axis, sign) = (face / 2, if face.is_multiple_of(2) { 1.0 } else { -1.0 });
            let mut p = [
                2.0 * rng.uniform() - 1.0,
                2.0 * rng.uniform() - 1.0,
                2.0 * rng.uniform() - 1.0,
            ];
            p[axis] = sign;
            let mut n = [0.0; 3];
            n[axis] = sign;
            cloud.points.push(p);
            cloud.normals.push(n);
        }
    } else {
        let h = 1e-6;
        let grad = |p: [f64; 3]| {
            [0, 1, 2].map(|a| {
                let (mut lo, mut hi) = (p, p);
                lo[a] -= h;
                hi[a] += h;
                (shape.implicit(hi) - shape.implicit(lo)) / (2.0 * h)
            })
        };
        // Uniform-ish sampling: random points in a shell around the surface, projected by Newton
        // steps, then accepted with probability ∝ 1/|∇f| (the density of |f| < δ shells).
        let e = shape.extent();
        let mut attempts = 0usize;
        while cloud.points.len() < target && attempts < target * 400 {
            attempts += 1;
            let mut p = [0, 1, 2].map(|_| e * (2.0 * rng.uniform() - 1.0));
            let f0 = shape.implicit(p);
            let g0 = grad(p);
            let g0n = (g0[0] * g0[0] + g0[1] * g0[1] + g0[2] * g0[2]).sqrt();
            if g0n == 0.0 || (f0 / g0n).abs() > 0.05 {
                continue;
            }
            let mut ok = false;
            for _ in 0..30 {
                let f = shape.implicit(p);
                let g = grad(p);
                let gg = g[0] * g[0] + g[1] * g[1] + g[2] * g[2];
                if gg == 0.0 {
                    break;
                }
                p = [0, 1, 2].map(|a| p[a] - f * g[a] / gg);
                if (f.abs() / gg.sqrt()) < 1e-12 {
                    ok = true;
                    break;
                }
            }
            if !ok {
                continue;
            }
            let g = grad(p);
            let gn = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
            if gn == 0.0 || !gn.is_finite() {
                continue;
            }
            cloud.points.push(p);
            cloud.normals.push(g.map(|c| c / gn));
        }
    }
    match variant {
        Variant::Clean => {}
        Variant::Noisy => {
            let norm = crate::fit::Normalization::of(&cloud.points);
            let sigma = 0.05 * norm.scale;
            for p in cloud.points.iter_mut() {
                for c in p.iter_mut() {
                    *c += sigma * rng.normal();
                }
            }
        }
        Variant::Cut => cloud = cut_away(&cloud),
    }
    cloud
}

/// The [`Variant::Cut`] degradation: `cloud` without the 15% of its points with the largest
/// x + 0.3y + 0.2z (weights dropped).
pub fn cut_away(cloud: &OrientedCloud) -> OrientedCloud {
    let key = |p: &[f64; 3]| p[0] + 0.3 * p[1] + 0.2 * p[2];
    let mut keys: Vec<f64> = cloud.points.iter().map(key).collect();
    keys.sort_by(f64::total_cmp);
    let threshold = keys
        .get((keys.len() * 85 / 100).min(keys.len().saturating_sub(1)))
        .copied()
        .unwrap_or(f64::INFINITY);
    let (points, normals) = cloud
        .points
        .iter()
        .zip(&cloud.normals)
        .filter(|(p, _)| key(p) < threshold)
        .map(|(p, n)| (*p, *n))
        .unzip();
    OrientedCloud {
        points,
        normals,
        weights: None,
    }
}

/// The judge's verdict on one fit.
#[derive(Clone, Debug, PartialEq)]
pub struct Assessment {
    /// Whether it is a good fit (all of the following).
    pub good: bool,
    /// Leading form positive on the unit sphere.
    pub positive: bool,
    /// Components of the sign-change cells in [−4, 4]³.
    pub components: usize,
    /// The (single) component comes within 0.2 of the data.
    pub near_data: bool,
    /// Some sign change on the box's boundary.
    pub touches_box: bool,
}

/// Judges the zero set of `poly` against the data (see the module docs).
pub fn assess(poly: &ImplicitPolynomial, cloud: &OrientedCloud) -> Assessment {
    let positive = poly.degree.is_multiple_of(2) && poly.leading_form_extrema().min > 0.0;
    let half: f64 = 4.0;
    let step: f64 = 0.1;
    let nv = (2.0 * half / step).round() as usize + 1;
    let nc = nv - 1;
    let unit = ImplicitPolynomial {
        center: [0.0; 3],
        scale: 1.0,
        ..poly.clone()
    };
    let values = unit.eval_grid([-half; 3], [step; 3], [nv, nv, nv]);
    let vid = |i: usize, j: usize, k: usize| i + nv * (j + nv * k);
    let cid = |i: usize, j: usize, k: usize| i + nc * (j + nc * k);
    let mut surface = vec![false; nc * nc * nc];
    let mut touches_box = false;
    for k in 0..nc {
        for j in 0..nc {
            for i in 0..nc {
                let mut pos = false;
                let mut neg = false;
                for (di, dj, dk) in [
                    (0, 0, 0),
                    (1, 0, 0),
                    (0, 1, 0),
                    (1, 1, 0),
                    (0, 0, 1),
                    (1, 0, 1),
                    (0, 1, 1),
                    (1, 1, 1),
                ] {
                    let v = values[vid(i + di, j + dj, k + dk)];
                    pos |= v > 0.0;
                    neg |= v <= 0.0;
                }
                if pos && neg {
                    surface[cid(i, j, k)] = true;
                    if i == 0 || j == 0 || k == 0 || i == nc - 1 || j == nc - 1 || k == nc - 1 {
                        touches_box = true;
                    }
                }
            }
        }
    }
    // 6-connected components by flood fill.
    let mut label = vec![u32::MAX; surface.len()];
    let mut components = 0usize;
    let mut comp_cells: Vec<Vec<usize>> = Vec::new();
    let mut stack = Vec::new();
    for start in 0..surface.len() {
        if !surface[start] || label[start] != u32::MAX {
            continue;
        }
        label[start] = components as u32;
        stack.push(start);
        let mut cells = Vec::new();
        while let Some(c) = stack.pop() {
            cells.push(c);
            let (i, j, k) = (c % nc, (c / nc) % nc, c / (nc * nc));
            let mut visit = |ii: usize, jj: usize, kk: usize| {
                let d = cid(ii, jj, kk);
                if surface[d] && label[d] == u32::MAX {
                    label[d] = components as u32;
                    stack.push(d);
                }
            };
            if i > 0 {
                visit(i - 1, j, k);
            }
            if i + 1 < nc {
                visit(i + 1, j, k);
            }
            if j > 0 {
                visit(i, j - 1, k);
            }
            if j + 1 < nc {
                visit(i, j + 1, k);
            }
            if k > 0 {
                visit(i, j, k - 1);
            }
            if k + 1 < nc {
                visit(i, j, k + 1);
            }
        }
        comp_cells.push(cells);
        components += 1;
    }
    let mut near_data = false;
    if components == 1 {
        let data: Vec<[f64; 3]> = cloud.points.iter().map(|p| poly.normalize(*p)).collect();
        if let Some(tree) = crate::numerics::point_tree::PointTree::new(&data) {
            let reach = 0.2 + 0.5 * step * 3f64.sqrt();
            near_data = comp_cells[0].iter().any(|&c| {
                let (i, j, k) = (c % nc, (c / nc) % nc, c / (nc * nc));
                let q = [i, j, k].map(|t| -half + (t as f64 + 0.5) * step);
                tree.nearest(q).0.sqrt() <= reach
            });
        }
    }
    Assessment {
        good: positive && components == 1 && near_data && !touches_box,
        positive,
        components,
        near_data,
        touches_box,
    }
}
