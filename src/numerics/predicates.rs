//! Exact geometric predicates: `orient3d` and `insphere` (Shewchuk's adaptive exact predicates,
//! the `robust` crate) behind a semi-static filter that takes the sign wherever Shewchuk's own
//! first stage would have.
//!
//! Input: point coordinates. Output: the determinant's sign, never wrong because of rounding (the
//! value is the filter's or the exact predicate's). Used by the normals stage's Delaunay
//! tetrahedralization and by the mesh's exact intersection tests.

#[inline]
fn c3(p: &[f64; 3]) -> robust::Coord3D<f64> {
    robust::Coord3D {
        x: p[0],
        y: p[1],
        z: p[2],
    }
}

/// Shewchuk's exact orientation: positive when `d` lies below the plane of `a, b, c`.
///
/// A semi-static filter decides first (the usual first stage of fast exact predicates, e.g.
/// CGAL's static filters): the determinant is evaluated exactly as Shewchuk's first stage
/// evaluates it, and its sign is taken when it exceeds his error bound with the permanent
/// replaced by an upper bound from the largest coordinate differences (the permanent is a sum
/// of 6 products of one x, one y and one z difference). Whenever the filter decides, Shewchuk's
/// first stage would have returned this same value; otherwise his full adaptive predicate runs.
#[inline(always)]
pub fn orient3d(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3]) -> f64 {
    let adx = a[0] - d[0];
    let bdx = b[0] - d[0];
    let cdx = c[0] - d[0];
    let ady = a[1] - d[1];
    let bdy = b[1] - d[1];
    let cdy = c[1] - d[1];
    let adz = a[2] - d[2];
    let bdz = b[2] - d[2];
    let cdz = c[2] - d[2];
    let det = adz * (bdx * cdy - cdx * bdy)
        + bdz * (cdx * ady - adx * cdy)
        + cdz * (adx * bdy - bdx * ady);
    let mx = adx.abs().max(bdx.abs()).max(cdx.abs());
    let my = ady.abs().max(bdy.abs()).max(cdy.abs());
    let mz = adz.abs().max(bdz.abs()).max(cdz.abs());
    let bound = O3D_SEMI_STATIC * (mx * my * mz);
    if bound > SEMI_STATIC_MIN && (det > bound || -det > bound) {
        return det;
    }
    orient3d_exact(a, b, c, d)
}

/// Shewchuk's error bound coefficient for orient3d's first stage, (7 + 56ε)ε with ε = 2⁻⁵³.
const O3D_ERRBOUND_A: f64 = (7.0 + 56.0 * f64::EPSILON / 2.0) * f64::EPSILON / 2.0;
/// [`O3D_ERRBOUND_A`] times the 6 products of the permanent, with a margin of 10⁻⁴ for the
/// rounding of both the permanent and this bound.
const O3D_SEMI_STATIC: f64 = O3D_ERRBOUND_A * 6.0 * 1.0001;
/// Shewchuk's error bound coefficient for insphere's first stage, (16 + 224ε)ε.
const ISP_ERRBOUND_A: f64 = (16.0 + 224.0 * f64::EPSILON / 2.0) * f64::EPSILON / 2.0;
/// [`ISP_ERRBOUND_A`] times the 24 products (x·y·z·lift) of the permanent, with a margin.
const ISP_SEMI_STATIC: f64 = ISP_ERRBOUND_A * 24.0 * 1.0001;
/// Below this the filter's bound may have lost accuracy to underflow: the exact predicate
/// decides.
const SEMI_STATIC_MIN: f64 = 1e-200;

#[inline(never)]
fn orient3d_exact(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3]) -> f64 {
    robust::orient3d(c3(a), c3(b), c3(c), c3(d))
}

/// Shewchuk's exact insphere: positive when `e` is inside the sphere of the positive tet `a..d`.
///
/// Filtered as [`orient3d`] is: the determinant is evaluated as Shewchuk's first stage
/// evaluates it, and its bound uses the permanent's upper bound 24·mx·my·mz·(mx² + my² + mz²)
/// (4 lifted terms of 6 products each) from the largest coordinate differences.
#[inline(always)]
pub fn insphere(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3], e: &[f64; 3]) -> f64 {
    let aex = a[0] - e[0];
    let bex = b[0] - e[0];
    let cex = c[0] - e[0];
    let dex = d[0] - e[0];
    let aey = a[1] - e[1];
    let bey = b[1] - e[1];
    let cey = c[1] - e[1];
    let dey = d[1] - e[1];
    let aez = a[2] - e[2];
    let bez = b[2] - e[2];
    let cez = c[2] - e[2];
    let dez = d[2] - e[2];
    let ab = aex * bey - bex * aey;
    let bc = bex * cey - cex * bey;
    let cd = cex * dey - dex * cey;
    let da = dex * aey - aex * dey;
    let ac = aex * cey - cex * aey;
    let bd = bex * dey - dex * bey;
    let abc = aez * bc - bez * ac + cez * ab;
    let bcd = bez * cd - cez * bd + dez * bc;
    let cda = cez * da + dez * ac + aez * cd;
    let dab = dez * ab + aez * bd + bez * da;
    let alift = aex * aex + aey * aey + aez * aez;
    let blift = bex * bex + bey * bey + bez * bez;
    let clift = cex * cex + cey * cey + cez * cez;
    let dlift = dex * dex + dey * dey + dez * dez;
    let det = (dlift * abc - clift * dab) + (blift * cda - alift * bcd);
    let mx = aex.abs().max(bex.abs()).max(cex.abs()).max(dex.abs());
    let my = aey.abs().max(bey.abs()).max(cey.abs()).max(dey.abs());
    let mz = aez.abs().max(bez.abs()).max(cez.abs()).max(dez.abs());
    let bound = ISP_SEMI_STATIC * (mx * my * mz) * (mx * mx + my * my + mz * mz);
    if bound > SEMI_STATIC_MIN && (det > bound || -det > bound) {
        return det;
    }
    insphere_exact(a, b, c, d, e)
}

#[inline(never)]
fn insphere_exact(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], d: &[f64; 3], e: &[f64; 3]) -> f64 {
    robust::insphere(c3(a), c3(b), c3(c), c3(d), c3(e))
}
