//! Automatic κ for 3LRR: the grid 0, 1e-8 … 1 (four steps a decade) and the two rules.
//!
//! Input: the accumulated system (MᵀM, Mᵀb, D), the normalization and the data. Output: the
//! chosen κ, its coefficients, and warnings. Every grid value reuses the same MᵀM; only κD changes.
//!
//! The rules and the order of the checks are here; the parts they use are their own modules:
//! [`pieces`] (the connected pieces of the data), [`zero_set`] (the coarse zero set in a box,
//! meshed or from a sign grid) and [`certificate`] (exact sign proofs far from the data).
//!
//! - `paper` (section 6.3): the smallest grid κ whose leading form H_n is positive on the unit
//!   sphere.
//! - `stable`: the smallest grid κ such that
//!   - (a) H_n is positive at that κ and at every larger grid value (positivity is not
//!     monotone in κ, so a lone positive value between negative ones is rejected);
//!   - (b) a containment radius R exists: on |p̂| = r, f ≥ H_min·rⁿ − Σ_{k<n} ‖H_k‖·r^k, so the
//!     zero set lies in |p̂| < R (reported);
//!   - (c) the zero set, meshed coarsely in the normalized box [−1.6, 1.6]³, has one component
//!     per connected piece of the data, each within 0.2 of the data (its closest point: a
//!     closed zero set must bridge holes in the data, such as a part cut away, so not all of it
//!     can be near the data);
//!   - (d) in [−4, 4]³, and in [−R, R]³ when R is larger, it has no other component and does
//!     not touch the box.
//!
//!   (c) and (d) mesh with the polygonize stage (depth 6); if that stage cannot run, a uniform
//!   grid of 64³ cells stands in (the 26-connected components of the cells whose corners change
//!   sign), and the diagnostics say so.
//!
//! If no grid value qualifies, κ = 1e-2 is used and flagged.
//!
//! Cost. Grid values are solved (and their leading-form minima found) only where a rule looks:
//! `stable` walks down from κ = 1 and stops at the first non-positive leading form, `paper`
//! walks up from 0 and stops at the first positive one. The candidates of (b)–(d) are then tried
//! from the smallest up, and each stops at its first failing check, cheapest first:
//! - when R > 4, f is sampled at fixed points with 4 ≤ |p̂|∞ ≤ R (a log-polar probe, a few
//!   thousand values); f < 0 there proves that the zero set reaches |p̂|∞ ≥ 4 (f > 0 beyond R on
//!   the ray through that point), so it touches [−4, 4]³ or has a component outside it: (d)
//!   fails without any mesh;
//! - (c) on the inner mesh (the marching-tetrahedra mesh as extracted: the checks need its
//!   components and its vertices, which the edge collapses of the stage's default would not
//!   change in topology, only thin out);
//! - (d) in [−4, 4]³: when the inner mesh stays off the inner box's faces, the sign of f on the
//!   shell between the boxes decides, if it can be established: f > 0 there (certified by the
//!   frustum enclosures of `far_sign`, else by the box enclosures of `shell_sign`) means
//!   both boxes hold the same zero set, which (c) accepted; f < 0 at a point of the shell means
//!   the zero set reaches the shell (along the ray) without crossing the inner box's faces, so
//!   it is a further component or touches the outer box: (d) fails. Otherwise [−4, 4]³ is
//!   meshed;
//! - (d) in [−R, R]³ (R > 4) is meshed. When the Bernstein bounds of `far_positive` prove
//!   f > 0 from box norm 4 out to R (and `far_sign` from 1.6 to 4, when it can), the mesher
//!   skips the octree cells whose neighbourhood lies there (`FarCulled`): the mesh is the
//!   same, vertex for vertex, for a fraction of the work (the octree of a large box otherwise
//!   spends most of its time far out, where the Taylor enclosures are loose), and this mesh then
//!   runs right after the probe, before (c), being the cheapest decisive check (on the bunny
//!   it rejects κ = 1.8e-2 … 5.6e-2 on its own).
//!
//! Each solve and check is logged with its wall time at the `trace` level of the `log` crate
//! (target `stablesurf::fit::kappa`), a profiling aid that changes no decision.
//!
//! The shortcuts decide the same question as the meshes they replace, from the exact zero set;
//! over the κ study (108 cases, both rules) and on the bunny they give the same κ as meshing
//! everything.
//!
//! "Connected pieces of the data": the components of the graph joining data points closer than
//! 0.2 (normalized units, the same tolerance as (c)) among their 12 nearest neighbours, on at
//! most 20,000 points taken at a fixed stride. Data closer than 0.2 can be bridged by a zero set
//! that stays within 0.2 of the data, so it fairly counts as one piece.

mod certificate;
mod pieces;
mod zero_set;

use super::solve;
use super::system::{Normalization, System};
use super::FitError;
use crate::cloud::OrientedCloud;
use crate::poly::ImplicitPolynomial;
use certificate::{
    far_positive, far_probe_negative, far_sign, shell_sign, Shell, FAR_POSITIVE_RATIO,
};
use pieces::DataPieces;
use zero_set::{coarse_zero_set, coarse_zero_set_culled, CoarseZeroSet, Mesher};

/// The fallback κ when no grid value qualifies.
const FALLBACK_KAPPA: f64 = 1e-2;
/// Distance tolerance (normalized units) of the zero set to the data, rule (c).
const NEAR_DATA: f64 = 0.2;
/// Half side of the box of rule (c), normalized units.
const INNER_BOX: f64 = 1.6;
/// Minimum half side of the box of rule (d), normalized units.
const OUTER_BOX: f64 = 4.0;
/// Octree depth of the coarse meshes of (c) and (d).
const CHECK_DEPTH: u32 = 6;
/// Points used for the data pieces and the distance checks.
const MAX_CHECK_POINTS: usize = 20_000;

/// Logs `what` and the wall time since `start` at the `trace` level.
fn trace(start: std::time::Instant, what: std::fmt::Arguments) {
    log::trace!("{:>8.2} ms  {what}", start.elapsed().as_secs_f64() * 1e3);
}

/// [`coarse_zero_set`] in the box of half-side `half`, traced (as `name`) with its time, its
/// components and vertices, and whether it touches the box.
fn traced_zero_set(poly: &ImplicitPolynomial, half: f64, name: &str) -> (CoarseZeroSet, Mesher) {
    let t = std::time::Instant::now();
    let (zero_set, mesher) = coarse_zero_set(poly, half);
    trace(
        t,
        format_args!(
            "  {name} mesh: {} components, {} vertices, touches the box {}",
            zero_set.components.len(),
            zero_set.components.iter().map(Vec::len).sum::<usize>(),
            zero_set.touches_box
        ),
    );
    (zero_set, mesher)
}

/// The κ grid: 0, then 10^(−8 + i/4) for i = 0 … 32 (1e-8 … 1, four steps a decade).
pub(crate) fn kappa_grid() -> Vec<f64> {
    let mut grid = vec![0.0];
    grid.extend((0..=32).map(|i| 10f64.powf(-8.0 + i as f64 / 4.0)));
    grid
}

/// The chosen κ and what the selection found.
#[derive(Clone, Debug)]
pub(crate) struct Selection {
    pub kappa: f64,
    pub coefficients: Vec<f64>,
    pub warnings: Vec<String>,
    pub fallback: bool,
    pub zero_set_checked: bool,
}

/// One grid value's solve.
struct GridFit {
    kappa: f64,
    coefficients: Option<Vec<f64>>,
    leading_min: f64,
}

/// Picks κ by `rule`.
pub(crate) fn select(
    sys: &System,
    gram: &[f64],
    ridge: &[f64],
    norm: &Normalization,
    cloud: &OrientedCloud,
    rule: super::KappaRule,
) -> Result<Selection, FitError> {
    let degree = sys.degree;
    // Solves and leading-form minima are computed lazily, only where the rule looks: the stable
    // rule walks down from κ = 1 and stops at the first non-positive value (rule (a)), the paper
    // rule walks up from 0 and stops at the first positive one.
    let kappas = kappa_grid();
    let solve_at = |i: usize| {
        let kappa = kappas[i];
        let coefficients = solve::solve_ridge(gram, &sys.rhs, ridge, kappa)
            .ok()
            .map(|s| s.coefficients);
        let leading_min = coefficients.as_ref().map_or(f64::NAN, |a| {
            unit_poly(degree, a).leading_form_extrema().min
        });
        GridFit {
            kappa,
            coefficients,
            leading_min,
        }
    };
    let positive = |g: &GridFit| g.coefficients.is_some() && g.leading_min > 0.0;
    let mut grid: Vec<Option<GridFit>> = (0..kappas.len()).map(|_| None).collect();
    let mut warnings = Vec::new();
    let mut zero_set_checked = false;
    let mut mesher = None;
    let chosen = match rule {
        super::KappaRule::Paper => {
            let mut chosen = None;
            for (i, slot) in grid.iter_mut().enumerate() {
                let g = solve_at(i);
                let ok = positive(&g);
                *slot = Some(g);
                if ok {
                    chosen = Some(i);
                    break;
                }
            }
            chosen
        }
        super::KappaRule::Stable => {
            // (a): positive here and at every larger grid value. The walk is sequential; the
            // data's pieces, which the checks of (c) need, are indexed beside it.
            let (mut candidates, pieces) = rayon::join(
                || {
                    let mut candidates = Vec::new();
                    for i in (0..kappas.len()).rev() {
                        let t = std::time::Instant::now();
                        let g = solve_at(i);
                        trace(
                            t,
                            format_args!("solve kappa {:.1e} min {:.3e}", kappas[i], g.leading_min),
                        );
                        let ok = positive(&g);
                        grid[i] = Some(g);
                        if !ok {
                            break;
                        }
                        candidates.push(i);
                    }
                    candidates
                },
                || {
                    let t = std::time::Instant::now();
                    let pieces = DataPieces::new(cloud, norm);
                    trace(t, format_args!("data pieces"));
                    pieces
                },
            );
            candidates.reverse();
            let mut chosen = None;
            for &i in &candidates {
                let Some(fit_i) = grid[i].as_ref() else {
                    continue;
                };
                let Some(coefficients) = fit_i.coefficients.as_ref() else {
                    continue;
                };
                let poly = unit_poly(degree, coefficients);
                // (b): certified containment radius.
                let Some(radius) = poly.containment_radius_with(fit_i.leading_min) else {
                    continue;
                };
                let Some(pieces) = pieces.as_ref() else {
                    warnings.push("kappa rule stable: the data could not be indexed, so the zero-set checks (c)/(d) were skipped".to_string());
                    chosen = Some(i);
                    break;
                };
                let t = std::time::Instant::now();
                let (pass, used) = zero_set_check(&poly, radius, pieces);
                trace(
                    t,
                    format_args!(
                        "candidate kappa {:.1e} R {radius:.2} pass {pass}",
                        kappas[i]
                    ),
                );
                zero_set_checked = true;
                if used.is_some() {
                    mesher = used;
                }
                if pass {
                    chosen = Some(i);
                    break;
                }
            }
            if mesher == Some(Mesher::SignGrid) {
                warnings.push(format!(
                    "kappa rule stable: the polygonize stage could not run, so the zero-set checks (c)/(d) used a uniform sign-change grid of {} cells per side instead of the adaptive mesh",
                    1u32 << CHECK_DEPTH
                ));
            }
            chosen
        }
    };
    match chosen.and_then(|i| grid[i].as_ref()) {
        Some(g) => {
            let coefficients = g.coefficients.clone().unwrap_or_default();
            Ok(Selection {
                kappa: g.kappa,
                coefficients,
                warnings,
                fallback: false,
                zero_set_checked,
            })
        }
        None => {
            let solution =
                solve::solve_ridge(gram, &sys.rhs, ridge, FALLBACK_KAPPA).map_err(|e| match e {
                    solve::SolveFailure::NotPositiveDefinite { column } => {
                        FitError::SingularSystem {
                            kappa: FALLBACK_KAPPA,
                            column,
                            n_coefficients: sys.rhs.len(),
                        }
                    }
                    solve::SolveFailure::NoConvergence => FitError::NoConvergence,
                })?;
            warnings.push(format!(
                "no kappa on the grid 0, 1e-8 … 1 satisfied the {} rule; fell back to kappa = {FALLBACK_KAPPA}: check the result, or try another --degree",
                rule.as_str()
            ));
            Ok(Selection {
                kappa: FALLBACK_KAPPA,
                coefficients: solution.coefficients,
                warnings,
                fallback: true,
                zero_set_checked,
            })
        }
    }
}

/// The polynomial in normalized coordinates (centre 0, scale 1).
fn unit_poly(degree: u32, coefficients: &[f64]) -> ImplicitPolynomial {
    ImplicitPolynomial {
        degree,
        coefficients: coefficients.to_vec(),
        center: [0.0; 3],
        scale: 1.0,
    }
}

/// Rules (c) and (d) on coarse meshes of the zero set of `poly` (normalized coordinates), with
/// certificates standing in for the meshes of (d) where they decide the same question exactly.
/// Also returns the mesher used, if any mesh was made.
fn zero_set_check(
    poly: &ImplicitPolynomial,
    radius: f64,
    data: &DataPieces,
) -> (bool, Option<Mesher>) {
    // (d), beyond [−4, 4]³ first, because a probe there is cheap: f < 0 at a point p with
    // |p|∞ ≥ 4 means the zero set reaches |p|∞ ≥ 4 (f > 0 beyond R along the ray through p),
    // so it touches [−4, 4]³ or has a component outside it, in [−R, R]³: (d) fails.
    let t = std::time::Instant::now();
    if radius > OUTER_BOX && far_probe_negative(poly, OUTER_BOX, radius) {
        trace(t, format_args!("  probe negative"));
        return (false, None);
    }
    trace(t, format_args!("  probe"));
    // (d) in [−R, R]³ when R > 4: a coarse mesh (the fixed box is checked on its own below,
    // because a coarse mesh of a large [−R, R]³ can miss a small stray piece). When f > 0 is
    // certified from box norm 4 out to R, the mesher skips the far cells ([`FarCulled`]: the
    // same mesh for a fraction of the work), from 1.6 when the shell between the boxes is
    // positive too; that mesh then goes first, being the cheapest. (Every check must pass, so
    // their order changes the cost, never the outcome.) The shell's sign is kept for (d) in
    // [−4, 4]³ below.
    let large_box_fails = |positive_beyond: Option<f64>| {
        let t = std::time::Instant::now();
        let (outer, used) = coarse_zero_set_culled(poly, radius, positive_beyond);
        trace(
            t,
            format_args!(
                "  R mesh: {} components touches {}",
                outer.components.len(),
                outer.touches_box
            ),
        );
        (
            outer.touches_box || outer.components.len() != data.n_pieces,
            used,
        )
    };
    let mut early_shell = None;
    let mut large_box_done = false;
    if radius > OUTER_BOX {
        let t = std::time::Instant::now();
        if far_positive(poly, OUTER_BOX, radius, FAR_POSITIVE_RATIO) {
            let shell = far_sign(poly, INNER_BOX, OUTER_BOX);
            early_shell = Some(shell);
            let beyond = if shell == Shell::Positive {
                INNER_BOX
            } else {
                OUTER_BOX
            };
            trace(
                t,
                format_args!("  far_positive 4..R, far_sign {shell:?}: beyond {beyond}"),
            );
            // f < 0 at a point p of the shell while f > 0 on the inner box's faces: the
            // region {f < 0} around p cannot reach into the inner box, so the zero set bounding
            // it lies outside the box and is a component besides those (c) would count there,
            // or (c) fails: both ways a check fails, and no mesh is needed (on the bunny this
            // rejects the small κ values that the large box's mesh would).
            if shell == Shell::Negative && far_sign(poly, INNER_BOX, INNER_BOX) == Shell::Positive {
                trace(
                    t,
                    format_args!("  inner faces positive: a component outside"),
                );
                return (false, None);
            }
            let (fails, used) = large_box_fails(Some(beyond));
            large_box_done = true;
            if fails {
                return (false, Some(used));
            }
        } else {
            trace(t, format_args!("  far_positive 4..R: not proved"));
        }
    }
    // (c): in the inner box, one component per data piece, each within NEAR_DATA of the data
    // (its closest point; a closed zero set must bridge holes in the data, so not every point
    // can be near it).
    let (inner, mesher) = traced_zero_set(poly, INNER_BOX, "inner");
    let t = std::time::Instant::now();
    if inner.components.len() != data.n_pieces {
        return (false, Some(mesher));
    }
    let near_enough = NEAR_DATA + inner.slack;
    if data.n_pieces == 1 {
        // One piece: every data point carries its label, so only the distance matters, and
        // the first vertex near enough settles it (most are).
        let near = inner
            .components
            .iter()
            .all(|component| component.iter().any(|p| data.nearest(*p).0 <= near_enough));
        if !near {
            return (false, Some(mesher));
        }
    } else {
        let mut piece_seen = vec![false; data.n_pieces];
        for component in &inner.components {
            let closest = component
                .iter()
                .map(|p| data.nearest(*p))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            match closest {
                Some((dist, piece)) if dist <= near_enough => {
                    match piece_seen.get_mut(piece as usize) {
                        Some(seen) if !*seen => *seen = true,
                        _ => return (false, Some(mesher)),
                    }
                }
                _ => return (false, Some(mesher)),
            }
        }
    }
    trace(t, format_args!("  (c) distances"));
    // (d) in [−4, 4]³: nothing else and no contact with the box. When the inner mesh stays off
    // the inner box's faces, the shell between the boxes decides it: f > 0 there (certified by
    // [`far_sign`], or by the box enclosures of [`shell_sign`] when that fails) means the
    // [−4, 4]³ zero set is the inner one, which (c) accepted; f < 0 at a point of the shell
    // means the zero set reaches the shell along the ray through it, and since it cannot cross
    // the inner box's faces, that is a further component or contact with the outer box: (d)
    // fails. Otherwise [−4, 4]³ is meshed.
    let mut outer_shell = Shell::Unknown;
    if !inner.touches_box {
        let t = std::time::Instant::now();
        outer_shell = match early_shell {
            Some(shell) => shell,
            None => far_sign(poly, INNER_BOX, OUTER_BOX.min(radius)),
        };
        trace(t, format_args!("  far_sign {outer_shell:?}"));
        if outer_shell == Shell::Unknown {
            let t = std::time::Instant::now();
            outer_shell = shell_sign(poly, OUTER_BOX, INNER_BOX);
            trace(t, format_args!("  shell_sign {outer_shell:?}"));
        }
        if outer_shell == Shell::Negative {
            return (false, Some(mesher));
        }
    }
    let mut mesher = mesher;
    if outer_shell != Shell::Positive {
        let (outer, used) = traced_zero_set(poly, OUTER_BOX, "outer");
        mesher = used;
        if outer.touches_box || outer.components.len() != data.n_pieces {
            return (false, Some(mesher));
        }
    }
    if radius > OUTER_BOX && !large_box_done {
        let (fails, used) = large_box_fails(None);
        mesher = used;
        if fails {
            return (false, Some(mesher));
        }
    }
    (true, Some(mesher))
}

#[cfg(test)]
mod tests {
    use super::certificate::*;
    use super::zero_set::*;
    use super::*;
    use crate::cloud::Aabb;

    #[test]
    fn sign_grid_counts_two_spheres() {
        // f = ((x − 1.5)² + y² + z² − 0.25)((x + 1.5)² + y² + z² − 0.25) > 0 far away: two
        // components, not touching the box [−4, 4]³.
        let poly = two_spheres([1.5, 0.0, 0.0], 0.5, [-1.5, 0.0, 0.0], 0.5);
        let zero_set = sign_grid_zero_set(&poly, 4.0, 64);
        assert_eq!(zero_set.components.len(), 2);
        assert!(!zero_set.touches_box);
        let (meshed, _) = coarse_zero_set(&poly, 4.0);
        assert_eq!(meshed.components.len(), 2);
        // The spheres reach |x| = 2: f < 0 in the shell outside (−1.6, 1.6)³, and f > 0 is
        // certified outside (−2.5, 2.5)³.
        assert_eq!(shell_sign(&poly, 4.0, 1.6), Shell::Negative);
        assert_eq!(shell_sign(&poly, 4.0, 2.5), Shell::Positive);
        // The frustum certificate agrees, out to a far radius, and so does the probe.
        assert_eq!(far_sign(&poly, 1.6, 4.0), Shell::Negative);
        assert_eq!(far_sign(&poly, 2.5, 50.0), Shell::Positive);
        assert!(far_probe_negative(&poly, 1.6, 4.0));
        assert!(!far_probe_negative(&poly, 2.5, 50.0));
    }

    /// The product of two spheres' equations (centres `a`, `b`, radii `ra`, `rb`), a quartic.
    fn two_spheres(a: [f64; 3], ra: f64, b: [f64; 3], rb: f64) -> ImplicitPolynomial {
        let sphere = |c: [f64; 3], r: f64| {
            let mut q = vec![0.0; 10];
            q[0] = c.iter().map(|v| v * v).sum::<f64>() - r * r;
            for (axis, e) in [[1, 0, 0], [0, 1, 0], [0, 0, 1]].into_iter().enumerate() {
                q[crate::poly::monomial_index(e)] = -2.0 * c[axis];
                let mut sq = [0; 3];
                sq[axis] = 2;
                q[crate::poly::monomial_index(sq)] = 1.0;
            }
            q
        };
        let (qa, qb) = (sphere(a, ra), sphere(b, rb));
        let e2 = crate::poly::exponents(2);
        let mut coefficients = vec![0.0; crate::poly::n_coefficients(4)];
        for (l, el) in e2.iter().enumerate() {
            for (m, em) in e2.iter().enumerate() {
                let idx =
                    crate::poly::monomial_index([el[0] + em[0], el[1] + em[1], el[2] + em[2]]);
                coefficients[idx] += qa[l] * qb[m];
            }
        }
        ImplicitPolynomial {
            degree: 4,
            coefficients,
            center: [0.0; 3],
            scale: 1.0,
        }
    }

    #[test]
    fn far_checks_find_a_distant_piece_and_certify_its_absence() {
        // The unit sphere and a sphere of radius 0.5 centred at (0, −7, 3): the far piece has
        // box norms 6.5 … 7.5.
        let poly = two_spheres([0.0; 3], 1.0, [0.0, -7.0, 3.0], 0.5);
        let radius = poly.containment_radius().unwrap_or(f64::INFINITY);
        assert!(radius > 7.5, "containment radius {radius}");
        assert!(far_probe_negative(&poly, OUTER_BOX, radius));
        assert_eq!(far_sign(&poly, OUTER_BOX, radius), Shell::Negative);
        // Between the two pieces, and beyond the far one, f > 0 is certified.
        assert_eq!(far_sign(&poly, 1.2, 5.5), Shell::Positive);
        assert_eq!(far_sign(&poly, 8.0, radius.max(9.0)), Shell::Positive);
        assert!(!far_probe_negative(&poly, 1.2, 5.5));
        // An empty range is trivially positive; a non-finite one is not decided.
        assert_eq!(far_sign(&poly, 4.0, 3.0), Shell::Positive);
        assert_eq!(far_sign(&poly, 4.0, f64::INFINITY), Shell::Unknown);
    }

    #[test]
    fn cube_surface_sign_and_the_component_outside_the_inner_box() {
        // The unit sphere and a sphere of radius 0.5 centred at (2.5, 0, 0): f > 0 on the
        // surface |p|∞ = 1.6 (between them), f < 0 on the surface |p|∞ = 2.5 (inside the
        // second), and on |p|∞ = 1 the first sphere crosses the faces.
        let poly = two_spheres([0.0; 3], 1.0, [2.5, 0.0, 0.0], 0.5);
        assert_eq!(far_sign(&poly, INNER_BOX, INNER_BOX), Shell::Positive);
        assert_eq!(far_sign(&poly, 2.5, 2.5), Shell::Negative);
        assert_ne!(far_sign(&poly, 1.0, 1.0), Shell::Positive);
        // R > 4, f > 0 beyond 4, and f < 0 in the shell 1.6 … 4 with positive inner faces:
        // the check fails before any mesh (no mesher reported). The data, the unit sphere,
        // is one piece.
        let radius = poly.containment_radius().unwrap_or(f64::INFINITY);
        let cloud = crate::testing::study::sample(
            crate::testing::study::Shape::Sphere,
            crate::testing::study::Variant::Clean,
            3000,
            1,
        );
        let norm = Normalization {
            center: [0.0; 3],
            scale: 1.0,
        };
        let pieces = DataPieces::new(&cloud, &norm).expect("indexed");
        assert_eq!(pieces.n_pieces, 1);
        assert!(radius > OUTER_BOX && radius.is_finite(), "radius {radius}");
        assert!(far_positive(&poly, OUTER_BOX, radius, FAR_POSITIVE_RATIO));
        assert_eq!(zero_set_check(&poly, radius, &pieces), (false, None));
        // The meshes agree: [−R, R]³ holds two components, one more than the data's pieces.
        let (outer, _) = coarse_zero_set_culled(&poly, radius, Some(OUTER_BOX));
        assert_eq!(outer.components.len(), 2);
        assert!(!outer.touches_box);
    }

    /// The mesh of `poly` in [−half, half]³ with and without the far cells skipped.
    fn culled_and_plain(
        poly: &ImplicitPolynomial,
        half: f64,
        beyond: f64,
    ) -> (crate::mesh::TriangleMesh, crate::mesh::TriangleMesh) {
        use crate::polygonize::{polygonize, PolygonizeParams, Simplification};
        let region = Aabb {
            min: [-half; 3],
            max: [half; 3],
        };
        let params = PolygonizeParams {
            depth: CHECK_DEPTH,
            simplification: Simplification::None,
            ..Default::default()
        };
        let culled = FarCulled {
            poly,
            beyond,
            reach: 2.0 * half / f64::from(1u32 << CHECK_DEPTH),
        };
        let a = polygonize(&culled, &region, &params).map(|o| o.mesh);
        let b = polygonize(poly, &region, &params).map(|o| o.mesh);
        (a.unwrap_or_default(), b.unwrap_or_default())
    }

    #[test]
    fn skipping_certified_far_cells_keeps_the_mesh() {
        // Two spheres, the far one at box norms 6.5 … 7.5: f > 0 is certified beyond 8, and the
        // mesh of [−12, 12]³ is the same, vertex for vertex, when the mesher skips those cells.
        let poly = two_spheres([0.0; 3], 1.0, [0.0, -7.0, 3.0], 0.5);
        assert!(far_positive(&poly, 8.0, 12.0, FAR_POSITIVE_RATIO));
        assert!(!far_positive(&poly, 4.0, 12.0, FAR_POSITIVE_RATIO));
        let (culled, plain) = culled_and_plain(&poly, 12.0, 8.0);
        assert!(!plain.positions.is_empty());
        assert_eq!(culled, plain);
        // A degree-8 fit of the heart (automatic κ, normalized coordinates), meshed in
        // [−R, R]³ as rule (d) does, with f > 0 certified from box norm 4 to R.
        let cloud = crate::testing::study::sample(
            crate::testing::study::Shape::Heart,
            crate::testing::study::Variant::Clean,
            1500,
            1,
        );
        let params = crate::fit::FitParams {
            degree: 8,
            ..Default::default()
        };
        let model = crate::fit::fit(&cloud, &params).unwrap_or_else(|e| panic!("fit: {e}"));
        let poly = unit_poly(8, &model.polynomial.coefficients);
        let radius = poly.containment_radius().unwrap_or(0.0);
        assert!(radius > OUTER_BOX, "containment radius {radius}");
        assert!(far_positive(&poly, OUTER_BOX, radius, FAR_POSITIVE_RATIO));
        let (culled, plain) = culled_and_plain(&poly, radius, OUTER_BOX);
        assert!(!plain.positions.is_empty());
        assert_eq!(culled, plain);
    }

    #[test]
    fn bernstein_test_proves_positivity_only_when_true() {
        // (s − 2)² + 0.1 > 0 everywhere; (s − 2)² − 0.1 < 0 near s = 2.
        let plus = [4.1, -4.0, 1.0];
        let minus = [3.9, -4.0, 1.0];
        // (Bernstein coefficients prove positivity on a short enough interval only.)
        let ratios = bernstein_ratios(2);
        assert!(positive_on_interval(&plus, &ratios, 1.9, 2.1));
        assert!(!positive_on_interval(&minus, &ratios, 1.9, 2.1));
        // Away from its roots (2 ± 0.316) the second one is positive, and is proved so.
        assert!(positive_on_interval(&minus, &ratios, 2.5, 4.0));
        assert!(positive_on_interval(&minus, &ratios, 0.5, 1.5));
    }

    #[test]
    fn face_forms_bound_the_homogeneous_parts() {
        // Lower bounds of H_k on a patch are below H_k at sampled points of the patch.
        let poly = two_spheres([0.3, -0.2, 0.1], 1.0, [0.0, -7.0, 3.0], 0.5);
        let forms = FaceForms::new(&poly);
        let exps = crate::poly::exponents(4);
        for face in 0..6usize {
            let axis = face / 2;
            let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
            let (b, c) = ((axis + 1) % 3, (axis + 2) % 3);
            let (b, c) = (b.min(c), b.max(c));
            let (uc, vc, w) = (0.25, -0.5, 0.25);
            let lower = forms.lower_bounds(face, uc, vc, w);
            for iu in 0..=4 {
                for iv in 0..=4 {
                    let u = uc - w + 0.5 * w * iu as f64;
                    let v = vc - w + 0.5 * w * iv as f64;
                    let mut q = [0.0; 3];
                    q[axis] = sign;
                    q[b] = u;
                    q[c] = v;
                    for (k, lo) in lower.iter().enumerate() {
                        let h: f64 = exps
                            .iter()
                            .zip(&poly.coefficients)
                            .filter(|(e, _)| (e[0] + e[1] + e[2]) as usize == k)
                            .map(|(e, a)| {
                                a * q[0].powi(e[0] as i32)
                                    * q[1].powi(e[1] as i32)
                                    * q[2].powi(e[2] as i32)
                            })
                            .sum();
                        assert!(
                            *lo <= h + 1e-12,
                            "face {face} k {k}: bound {lo} > value {h}"
                        );
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn kappa_grid() {
        let g = crate::fit::kappa::kappa_grid();
        assert_eq!(g.len(), 34);
        assert_eq!(g[0], 0.0);
        assert!((g[1] - 1e-8).abs() < 1e-20 && (g[33] - 1.0).abs() < 1e-15);
    }
}
