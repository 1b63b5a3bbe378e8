//! The monomial basis of the polynomials, in the paper's order (Sahin & Unel 2008, 2.1 and
//! 6.16): the number of coefficients of a degree, the exponents of each position and the
//! position of each exponent.
//!
//! Input: a degree or an exponent triple. Output: counts, exponents and 0-based positions; degree
//! by degree, inside degree r by s = j + k, inside that by k.

/// Number of monomials of degree ≤ `degree` in three variables: (n+1)(n+2)(n+3)/6.
///
/// ```
/// assert_eq!(stablesurf::poly::n_coefficients(2), 10);
/// assert_eq!(stablesurf::poly::n_coefficients(8), 165);
/// ```
pub fn n_coefficients(degree: u32) -> usize {
    let n = degree as usize;
    (n + 1) * (n + 2) * (n + 3) / 6
}

/// Exponents `[i, j, k]` of every monomial of degree ≤ `degree`, in the paper's order.
pub(crate) fn exponents(degree: u32) -> Vec<[u32; 3]> {
    let mut out = Vec::with_capacity(n_coefficients(degree));
    for r in 0..=degree {
        for s in 0..=r {
            for k in 0..=s {
                out.push([r - s, s - k, k]);
            }
        }
    }
    out
}

/// 0-based position of the monomial x^i y^j z^k in the paper's order.
///
/// ```
/// assert_eq!(stablesurf::poly::monomial_index([0, 1, 1]), 8);
/// ```
pub fn monomial_index(e: [u32; 3]) -> usize {
    let (j, k) = (e[1] as usize, e[2] as usize);
    let s = j + k;
    let r = e[0] as usize + s;
    k + s * (s + 1) / 2 + r * (r + 1) * (r + 2) / 6
}

/// Number of monomials of degree exactly k.
pub(super) fn n_monomials_of_degree(k: u32) -> usize {
    let k = k as usize;
    (k + 1) * (k + 2) / 2
}

/// Exponents of the l-th monomial (0-based) for a polynomial of degree ≤ `max_degree`.
pub(super) fn exponent_of(l: usize, max_degree: usize) -> Option<[u32; 3]> {
    let mut base = 0;
    for r in 0..=max_degree {
        let count = (r + 1) * (r + 2) / 2;
        if l < base + count {
            let mut rem = l - base;
            for s in 0..=r {
                if rem <= s {
                    let k = rem;
                    return Some([(r - s) as u32, (s - k) as u32, k as u32]);
                }
                rem -= s + 1;
            }
        }
        base += count;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_matches_paper_formula() {
        for n in 0..=14 {
            let e = exponents(n);
            assert_eq!(e.len(), n_coefficients(n));
            for (l, &ex) in e.iter().enumerate() {
                assert_eq!(monomial_index(ex), l, "degree {n}, exponent {ex:?}");
            }
        }
    }
}

#[cfg(test)]
mod examples {
    //! The examples of this module's crate-internal items: they were doctests, which can only use
    //! the public API.

    #[test]
    fn exponents() {
        let e = crate::poly::exponents(2);
        assert_eq!(e[4], [2, 0, 0]); // x²
        assert_eq!(e[8], [0, 1, 1]); // yz
    }
}
