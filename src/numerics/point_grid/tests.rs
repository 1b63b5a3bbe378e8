//! Unit tests of `numerics::point_grid`.

use super::*;
use crate::numerics::point_tree::PointTree;
use crate::vec3::dist2;

/// The k nearest by brute force: all (distance, index) keys sorted.
fn brute(points: &[[f64; 3]], i: usize, k: usize) -> Vec<u32> {
    let mut keys: Vec<u128> = points
        .iter()
        .enumerate()
        .map(|(j, p)| {
            let d = sub(*p, points[i]);
            order_key(d[0] * d[0] + d[1] * d[1] + d[2] * d[2], j as u32)
        })
        .collect();
    keys.sort_unstable();
    keys.into_iter()
        .map(|key| key as u32)
        .filter(|&j| j as usize != i)
        .take(k)
        .collect()
}

fn lcg(seed: &mut u64) -> f64 {
    *seed = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (*seed >> 11) as f64 / (1u64 << 53) as f64
}

/// `n` random points on the unit sphere.
fn random_sphere(n: usize, seed: &mut u64) -> Vec<[f64; 3]> {
    (0..n)
        .map(|_| {
            let (u, v) = (lcg(seed), lcg(seed));
            let z = 2.0 * u - 1.0;
            let r = (1.0 - z * z).sqrt();
            let a = std::f64::consts::TAU * v;
            [r * a.cos(), r * a.sin(), z]
        })
        .collect()
}

/// `n` random points filling the box [0, 1] × [0, 2] × [0, 0.5].
fn random_box(n: usize, seed: &mut u64) -> Vec<[f64; 3]> {
    (0..n)
        .map(|_| [lcg(seed), 2.0 * lcg(seed), 0.5 * lcg(seed)])
        .collect()
}

/// The unit lattice of `side`³ points: many exactly equal distances.
fn lattice(side: usize) -> Vec<[f64; 3]> {
    (0..side.pow(3))
        .map(|i| {
            [
                (i % side) as f64,
                (i / side % side) as f64,
                (i / side / side) as f64,
            ]
        })
        .collect()
}

/// A `side` × `side` lattice of spacing 0.1 in the plane z = 3 (one axis flat).
fn plane(side: usize) -> Vec<[f64; 3]> {
    (0..side * side)
        .map(|i| [(i % side) as f64 * 0.1, (i / side) as f64 * 0.1, 3.0])
        .collect()
}

#[test]
fn nearest_is_exact_on_surfaces_clouds_lattices_and_outliers() {
    let mut seed = 7;
    let mut sphere = random_sphere(1500, &mut seed);
    // A far outlier and a dense clump: cells far from uniform.
    sphere.push([40.0, -3.0, 7.0]);
    for t in 0..50 {
        sphere.push([0.2 + 1e-4 * t as f64, 0.1, 0.97]);
    }
    let cloud = random_box(1000, &mut seed);
    // A lattice: many exactly equal distances, so the ties decide.
    let lattice = lattice(9);
    // A plane (one axis flat) and a line.
    let plane = plane(20);
    let line: Vec<[f64; 3]> = (0..100).map(|i| [i as f64, 0.0, 0.0]).collect();
    for points in [&sphere, &cloud, &lattice, &plane, &line] {
        let grid = PointGrid::new(points).unwrap();
        for k in [1, 16, 128] {
            let all = grid.all_nearest(points, k);
            let mut keys = Vec::new();
            // Every 7th point, and the last 60 (the outliers and the clump).
            let checked = (0..points.len())
                .step_by(7)
                .chain(points.len().saturating_sub(60)..points.len());
            for i in checked {
                let expected = brute(points, i, k);
                assert_eq!(all.row(i), expected, "all_nearest, point {i}, k {k}");
                for hint2 in [1e-12, 0.3, 1e9] {
                    let (list, _) = grid.nearest(points, i, k, hint2, &mut keys);
                    assert_eq!(list, expected, "point {i}, k {k}, hint {hint2}");
                }
            }
        }
    }
}

#[test]
fn order_key_orders_as_total_cmp_then_index() {
    let values = [
        0.0,
        -0.0,
        1e-300,
        0.5,
        0.5,
        2.0,
        f64::INFINITY,
        -1.0,
        f64::NAN,
    ];
    let pairs: Vec<(f64, u32)> = values
        .iter()
        .enumerate()
        .flat_map(|(i, &d)| [(d, i as u32), (d, 100 - i as u32)])
        .collect();
    for a in &pairs {
        for b in &pairs {
            let expected = a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
            assert_eq!(order_key(a.0, a.1).cmp(&order_key(b.0, b.1)), expected);
        }
    }
}

#[test]
fn fewer_points_than_asked_gives_all_of_them() {
    let points = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]];
    let grid = PointGrid::new(&points).unwrap();
    let (list, _) = grid.nearest(&points, 0, 16, 0.0, &mut Vec::new());
    assert_eq!(list, vec![1, 2]);
    let one = [[5.0, 5.0, 5.0]];
    let grid = PointGrid::new(&one).unwrap();
    let all = grid.all_nearest(&one, 4);
    assert_eq!((all.len(), all.stride(), all.row(0)), (1, 0, &[][..]));
    let all = PointGrid::new(&points).unwrap().all_nearest(&points, 16);
    assert_eq!((all.len(), all.stride()), (3, 2));
    assert_eq!(
        [all.row(0), all.row(1), all.row(2)],
        [[1, 2], [0, 2], [0, 1]]
    );
    assert!(PointGrid::new(&[]).is_none());
    assert!(PointGrid::new(&[[f64::NAN, 0.0, 0.0]]).is_none());
}

/// Every query's grid answer, where it gives one, equals the k-d tree's and the brute
/// force's bit for bit; returns how many it answered.
fn check_nearest2(points: &[[f64; 3]], queries: &[[f64; 3]]) -> usize {
    let grid = PointGrid::for_nearest(points).expect("grid");
    let tree = PointTree::new(points).unwrap();
    let mut answered = 0;
    for q in queries {
        let brute = points
            .iter()
            .map(|p| dist2(*q, *p))
            .fold(f64::INFINITY, f64::min);
        assert_eq!(tree.nearest(*q).0.to_bits(), brute.to_bits());
        if let Some(d2) = grid.nearest2(*q) {
            assert_eq!(d2.to_bits(), brute.to_bits(), "query {q:?}");
            answered += 1;
        }
        // The nearest point's index: the smallest at that distance.
        if let Some((d2, item)) = grid.nearest_item(*q) {
            assert_eq!(d2.to_bits(), brute.to_bits(), "query {q:?}");
            let first = points.iter().position(|p| dist2(*q, *p) == brute);
            assert_eq!(Some(item as usize), first, "query {q:?}");
        }
        // The nearest positive distance and the points at the query.
        if let Some((d2, zeros)) = grid.nearest_positive2(*q) {
            let positive = points
                .iter()
                .map(|p| dist2(*q, *p))
                .filter(|&d| d > 0.0)
                .fold(f64::INFINITY, f64::min);
            assert_eq!(d2.to_bits(), positive.to_bits(), "query {q:?}");
            let at = points.iter().filter(|p| dist2(*q, **p) == 0.0).count();
            assert_eq!(zeros as usize, at, "query {q:?}");
        }
    }
    answered
}

#[test]
fn nearest_matches_the_tree_on_surfaces_clouds_duplicates_and_outliers() {
    let mut seed = 11;
    let mut sphere = random_sphere(4000, &mut seed);
    // Far outliers on every side, clamped into the grid's face cells.
    sphere.extend([[40.0, -3.0, 7.0], [-25.0, 0.0, 0.0], [0.1, 0.2, -90.0]]);
    let mut queries: Vec<[f64; 3]> = (0..1500)
        .map(|_| [0, 1, 2].map(|_| 2.6 * lcg(&mut seed) - 1.3))
        .collect();
    // Queries on the points, far outside, beyond the outliers and next to them.
    queries.extend(sphere.iter().step_by(97).copied());
    queries.extend([
        [100.0, 100.0, 100.0],
        [-1e6, 3.0, 0.0],
        [39.0, -3.0, 7.5],
        [0.0, 0.0, -89.0],
    ]);
    let answered = check_nearest2(&sphere, &queries);
    assert!(answered > queries.len() * 9 / 10, "{answered}");

    // A cloud filling its box, a lattice (many equal distances) and duplicate-heavy data.
    let cloud = random_box(3000, &mut seed);
    let lattice = lattice(10);
    let duplicates: Vec<[f64; 3]> = (0..3000)
        .map(|i| {
            let v = (i * 7919 % 50) as f64;
            [v * 0.1, (v * 0.37).sin(), 0.0]
        })
        .collect();
    // A plane (one axis flat) and a line.
    let plane = plane(30);
    let line: Vec<[f64; 3]> = (0..300).map(|i| [i as f64 * 0.5, 1.0, -2.0]).collect();
    for points in [&cloud, &lattice, &duplicates, &plane, &line] {
        let queries: Vec<[f64; 3]> = (0..800)
            .map(|j| {
                let p = points[j * 13 % points.len()];
                let s = if j % 4 == 0 { 20.0 } else { 0.3 };
                [0, 1, 2].map(|a| p[a] + s * (lcg(&mut seed) - 0.5))
            })
            .chain(points.iter().step_by(31).copied())
            .collect();
        let answered = check_nearest2(points, &queries);
        assert!(answered > queries.len() / 2, "{answered}");
        // Each point's nearest positive distance, `None` when k or more others coincide.
        let grid = PointGrid::new(points).unwrap();
        let of: Vec<u32> = (0..points.len() as u32).step_by(7).collect();
        for k in [1, 4, 8] {
            let got = grid.nearest_positive_of(points, &of, k);
            for (&i, d) in of.iter().zip(got) {
                let p = points[i as usize];
                let at = points.iter().filter(|q| dist2(p, **q) == 0.0).count() - 1;
                let positive = points
                    .iter()
                    .map(|q| dist2(p, *q))
                    .filter(|&d2| d2 > 0.0)
                    .fold(f64::INFINITY, f64::min);
                let expected = (at < k && positive.is_finite()).then(|| positive.sqrt());
                assert_eq!(d, expected, "point {i}, k {k}");
            }
        }
    }
    // A single point.
    assert_eq!(
        check_nearest2(&[[1.0, 2.0, 3.0]], &[[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]]),
        2
    );
}

#[test]
fn clustered_and_unusable_sets_are_declined() {
    // Nearly all points in one tiny clump, a few spread out: one cell would hold the clump.
    let mut seed = 5;
    let mut points: Vec<[f64; 3]> = (0..20_000)
        .map(|_| [0, 1, 2].map(|_| 1e-7 * lcg(&mut seed)))
        .collect();
    points.extend((0..4000).map(|_| [0, 1, 2].map(|_| lcg(&mut seed))));
    assert!(PointGrid::for_nearest(&points).is_none());
    assert!(PointGrid::for_nearest(&[]).is_none());
    assert!(PointGrid::for_nearest(&[[f64::NAN, 0.0, 0.0]]).is_none());
}
