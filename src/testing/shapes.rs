//! Exact implicit polynomials of known topology, for tests, benches and demonstrations of the
//! `polygonize` stage.
//!
//! Input: shape parameters. Output: an [`ImplicitPolynomial`] with centre 0 and scale 1 (set
//! `center`/`scale` afterwards to place it: the surface then is center + scale · the shape).
//!
//! Invariants: every shape is negative inside and positive outside, and its zero set is a smooth
//! closed surface of the stated genus and number of components.

use std::collections::BTreeMap;

use crate::poly::{monomial_index, n_coefficients, ImplicitPolynomial};

/// A sparse polynomial: exponents → coefficient.
#[derive(Clone, Debug, Default)]
struct Sparse(BTreeMap<[u32; 3], f64>);

impl Sparse {
    fn term(c: f64, e: [u32; 3]) -> Sparse {
        Sparse(BTreeMap::from([(e, c)]))
    }

    fn from_terms(terms: &[(f64, [u32; 3])]) -> Sparse {
        let mut s = Sparse::default();
        for &(c, e) in terms {
            *s.0.entry(e).or_insert(0.0) += c;
        }
        s
    }

    fn add(&self, other: &Sparse) -> Sparse {
        let mut s = self.clone();
        for (&e, &c) in &other.0 {
            *s.0.entry(e).or_insert(0.0) += c;
        }
        s
    }

    fn mul(&self, other: &Sparse) -> Sparse {
        let mut s = Sparse::default();
        for (&ea, &ca) in &self.0 {
            for (&eb, &cb) in &other.0 {
                let e = [ea[0] + eb[0], ea[1] + eb[1], ea[2] + eb[2]];
                *s.0.entry(e).or_insert(0.0) += ca * cb;
            }
        }
        s
    }

    /// The polynomial with x replaced by x − t (a translation by +t along x).
    fn shifted_x(&self, t: f64) -> Sparse {
        let x_minus_t = Sparse::from_terms(&[(1.0, [1, 0, 0]), (-t, [0, 0, 0])]);
        let mut out = Sparse::default();
        for (&e, &c) in &self.0 {
            let mut term = Sparse::term(c, [0, e[1], e[2]]);
            for _ in 0..e[0] {
                term = term.mul(&x_minus_t);
            }
            out = out.add(&term);
        }
        out
    }

    fn into_polynomial(self) -> ImplicitPolynomial {
        let degree = self.0.keys().map(|e| e[0] + e[1] + e[2]).max().unwrap_or(0);
        let mut coefficients = vec![0.0; n_coefficients(degree)];
        for (e, c) in self.0 {
            coefficients[monomial_index(e)] += c;
        }
        ImplicitPolynomial {
            degree,
            coefficients,
            center: [0.0; 3],
            scale: 1.0,
        }
    }
}

/// x² + y² + z² − radius²: a sphere (genus 0, χ = 2).
fn sphere_sparse(radius: f64) -> Sparse {
    Sparse::from_terms(&[
        (1.0, [2, 0, 0]),
        (1.0, [0, 2, 0]),
        (1.0, [0, 0, 2]),
        (-radius * radius, [0, 0, 0]),
    ])
}

/// The sphere x² + y² + z² − radius² = 0 (degree 2, one component, χ = 2).
///
/// ```
/// let s = stablesurf::testing::shapes::sphere(2.0);
/// assert_eq!(s.eval([0.0, 2.0, 0.0]), 0.0);
/// ```
pub fn sphere(radius: f64) -> ImplicitPolynomial {
    sphere_sparse(radius).into_polynomial()
}

/// The torus (x² + y² + z² + R² − r²)² − 4R²(x² + y²) = 0 around the z axis, R = `major`,
/// r = `minor` < R (degree 4, genus 1, χ = 0).
///
/// ```
/// let t = stablesurf::testing::shapes::torus(1.0, 0.25);
/// assert!(t.eval([1.25, 0.0, 0.0]).abs() < 1e-12);
/// assert!(t.eval([1.0, 0.0, 0.0]) < 0.0);
/// ```
pub fn torus(major: f64, minor: f64) -> ImplicitPolynomial {
    torus_sparse(major, minor).into_polynomial()
}

fn torus_sparse(major: f64, minor: f64) -> Sparse {
    let (r2, s2) = (major * major, minor * minor);
    let inner = Sparse::from_terms(&[
        (1.0, [2, 0, 0]),
        (1.0, [0, 2, 0]),
        (1.0, [0, 0, 2]),
        (r2 - s2, [0, 0, 0]),
    ]);
    inner.mul(&inner).add(&Sparse::from_terms(&[
        (-4.0 * r2, [2, 0, 0]),
        (-4.0 * r2, [0, 2, 0]),
    ]))
}

/// A two-holed surface: (x⁴ − x² + y²)² + z² − 0.01 = 0, a tube around the figure-eight curve
/// y² = x² − x⁴ (degree 8, genus 2, χ = −2). It fits in [−1.1, 1.1] × [−0.6, 0.6] × [−0.1, 0.1].
///
/// ```
/// let g = stablesurf::testing::shapes::genus_two();
/// assert_eq!(g.degree, 8);
/// assert!(g.eval([0.5, 0.0, 0.0]) > 0.0); // inside a hole
/// assert!(g.eval([1.0, 0.0, 0.0]) < 0.0); // inside the tube
/// ```
pub fn genus_two() -> ImplicitPolynomial {
    let curve = Sparse::from_terms(&[(1.0, [4, 0, 0]), (-1.0, [2, 0, 0]), (1.0, [0, 2, 0])]);
    curve
        .mul(&curve)
        .add(&Sparse::from_terms(&[(1.0, [0, 0, 2]), (-0.01, [0, 0, 0])]))
        .into_polynomial()
}

/// Two disjoint spheres of radius `radius` centred at (±`offset`, 0, 0), as the product of their
/// equations (degree 4, two components, χ = 4). Needs `offset > radius`.
///
/// ```
/// let s = stablesurf::testing::shapes::two_spheres(1.0, 0.5);
/// assert!(s.eval([1.5, 0.0, 0.0]).abs() < 1e-12);
/// assert!(s.eval([0.0, 0.0, 0.0]) > 0.0);
/// ```
pub fn two_spheres(offset: f64, radius: f64) -> ImplicitPolynomial {
    let a = sphere_sparse(radius).shifted_x(offset);
    let b = sphere_sparse(radius).shifted_x(-offset);
    a.mul(&b).into_polynomial()
}

/// Two linked tori as the product of their equations (degree 8, two components of genus 1,
/// χ = 0): one of radii (1, 0.3) around the z axis, the other of the same radii around the y
/// axis, centred at (1, 0, 0). It fits in [−1.4, 2.4] × [−1.4, 1.4] × [−1.4, 1.4].
///
/// ```
/// let t = stablesurf::testing::shapes::linked_tori();
/// assert_eq!(t.degree, 8);
/// assert!(t.eval([-1.3, 0.0, 0.0]).abs() < 1e-9);
/// ```
pub fn linked_tori() -> ImplicitPolynomial {
    let a = torus_sparse(1.0, 0.3);
    // The same torus with its axis along y: swap the exponents of y and z, then move it by +1
    // along x.
    let mut b = Sparse::default();
    for (&e, &c) in &a.0 {
        b.0.insert([e[0], e[2], e[1]], c);
    }
    a.mul(&b.shifted_x(1.0)).into_polynomial()
}
