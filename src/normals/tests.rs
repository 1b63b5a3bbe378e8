//! Unit tests of `normals`.

use super::test_support::fibonacci_sphere;
use super::*;

#[test]
fn source_names_round_trip() {
    for s in [
        NormalSource::Auto,
        NormalSource::Crust,
        NormalSource::Pca,
        NormalSource::Mesh,
        NormalSource::Input,
    ] {
        assert_eq!(s.as_str().parse::<NormalSource>().unwrap(), s);
    }
    assert!("poles".parse::<NormalSource>().is_err());
}

/// 200 points of the unit sphere (a Fibonacci spiral), then for each of `n` faces three
/// more points whose corners coincide (even faces) or lie on one line (odd faces), with the
/// faces over them.
fn sphere_with_degenerate_faces(n: usize) -> PointCloud {
    let m = 200;
    let mut points = fibonacci_sphere(m);
    let mut triangles = Vec::new();
    for f in 0..n {
        let p = points[f % m];
        let step = if f % 2 == 0 { 0.0 } else { 1.0 / 64.0 };
        let base = points.len() as u32;
        for k in 0..3 {
            let t = k as f64 * step;
            points.push([p[0] + t, p[1] + 2.0 * t, p[2] + 3.0 * t]);
        }
        triangles.push([base, base + 1, base + 2]);
    }
    PointCloud {
        points,
        triangles,
        ..Default::default()
    }
}

#[test]
fn auto_turns_to_the_crust_when_every_face_is_degenerate() {
    let cloud = sphere_with_degenerate_faces(500);
    let out = estimate_normals(&cloud, &NormalsParams::default()).unwrap();
    assert_eq!(out.source_used, NormalSource::Crust);
    assert!(
        out.warnings[0].contains("all 500 faces are degenerate")
            && out.warnings[0].contains("crust"),
        "{:?}",
        out.warnings
    );
    // The sphere's own points get outward normals.
    for (p, n) in out.cloud.points.iter().zip(&out.cloud.normals).take(200) {
        assert!(vec3::dot(p, n) > 0.5, "{p:?} {n:?}");
    }
}

#[test]
fn auto_fits_planes_to_noisy_points_and_says_why() {
    // A sphere of 20,000 points moved along their radius by noise of σ = 0.02, about 0.8
    // of their spacing: plane fits, with the measured noise in the note; without the
    // noise, the crust.
    let clean = fibonacci_sphere(20_000);
    assert_eq!(bare_points_source(&clean), (NormalSource::Crust, None));
    let mut rng = crate::numerics::Lcg::new(9);
    let noisy: Vec<[f64; 3]> = clean
        .iter()
        .map(|p| p.map(|c| c * (1.0 + 0.02 * rng.normal())))
        .collect();
    let (source, note) = bare_points_source(&noisy);
    assert_eq!(source, NormalSource::Pca);
    assert!(note.unwrap().contains("x their spacing"));
    let cloud = PointCloud {
        points: noisy,
        ..Default::default()
    };
    let out = estimate_normals(&cloud, &NormalsParams::default()).unwrap();
    assert_eq!(out.source_used, NormalSource::Pca);
    let outward = (out.cloud.points.iter().zip(&out.cloud.normals))
        .filter(|(p, n)| vec3::dot(p, n) > 0.0)
        .count();
    assert_eq!(outward, out.cloud.points.len());
}

#[test]
fn auto_takes_the_crust_up_to_its_limit_and_plane_fits_beyond() {
    assert_eq!(
        bare_points_source(&fibonacci_sphere(AUTO_CRUST_MAX)),
        (NormalSource::Crust, None)
    );
    let (source, note) = bare_points_source(&fibonacci_sphere(AUTO_CRUST_MAX + 1));
    assert_eq!(source, NormalSource::Pca);
    assert!(note.unwrap().contains("200001 points"));
    // End to end on a bare cloud just past the limit: plane fits, said in a warning, and
    // outward normals on a sphere (every one within 5° of the radial direction).
    let cloud = PointCloud {
        points: fibonacci_sphere(AUTO_CRUST_MAX + 1),
        ..Default::default()
    };
    let out = estimate_normals(&cloud, &NormalsParams::default()).unwrap();
    assert_eq!(out.source_used, NormalSource::Pca);
    assert!(
        out.warnings.iter().any(|w| w.contains("plane fits")),
        "{:?}",
        out.warnings
    );
    let cos5 = 5f64.to_radians().cos();
    for (p, n) in out.cloud.points.iter().zip(&out.cloud.normals) {
        assert!(vec3::dot(p, n) > cos5, "{p:?} {n:?}");
    }
}

#[test]
fn mesh_source_names_degenerate_faces() {
    let cloud = sphere_with_degenerate_faces(500);
    let params = NormalsParams {
        source: NormalSource::Mesh,
        ..Default::default()
    };
    let err = estimate_normals(&cloud, &params).unwrap_err();
    assert!(
        matches!(err, NormalsError::DegenerateFaces { n_faces: 500 }),
        "{err}"
    );
    assert!(err.to_string().contains("degenerate"), "{err}");
}

#[test]
fn one_face_with_area_keeps_the_mesh_source() {
    let mut cloud = sphere_with_degenerate_faces(10);
    cloud.triangles.push([0, 1, 2]);
    let out = estimate_normals(&cloud, &NormalsParams::default()).unwrap();
    assert_eq!(out.source_used, NormalSource::Mesh);
}

#[test]
fn dedup_maps_twins_to_first_occurrence() {
    let pts = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [-0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 0.0, 0.0],
    ];
    let d = Dedup::new(&pts);
    assert_eq!(d.unique.len(), 3);
    assert_eq!(d.first, Some(vec![0, 1, 4]));
    assert_eq!(d.of_point, Some(vec![0, 1, 0, 1, 2]));
    assert_eq!(d.expand(vec!['a', 'b', 'c']), vec!['a', 'b', 'a', 'b', 'c']);
}

#[test]
fn dedup_agrees_with_a_quadratic_search_and_borrows_distinct_clouds() {
    // 3,000 points drawn from 40 values (each repeated many times, in scrambled order).
    let pts: Vec<[f64; 3]> = (0..3000u64)
        .map(|i| {
            let v = (i * 7919 % 40) as f64;
            [v, -v * 0.5, if v == 0.0 { -0.0 } else { 1.0 }]
        })
        .collect();
    let d = Dedup::new(&pts);
    let same = |a: &[f64; 3], b: &[f64; 3]| (0..3).all(|k| a[k] == b[k]);
    let first_of = |i: usize| (0..=i).find(|&j| same(&pts[j], &pts[i])).unwrap() as u32;
    let first: Vec<u32> = (0..pts.len())
        .filter(|&i| first_of(i) as usize == i)
        .map(|i| i as u32)
        .collect();
    assert_eq!(first.len(), 40);
    assert_eq!(d.first.as_ref(), Some(&first));
    let of_point = d.of_point.as_ref().unwrap();
    for i in 0..pts.len() {
        assert_eq!(first[of_point[i] as usize], first_of(i));
    }
    // Many buckets: 200,000 points, a third of them repeats of earlier ones (some as -0.0).
    let mut lcg = crate::numerics::Lcg::new(99);
    let mut next = || lcg.bits31();
    let mut pts: Vec<[f64; 3]> = Vec::new();
    for i in 0..200_000usize {
        let r = next();
        if i > 0 && r % 3 == 0 {
            let j = (next() as usize) % i;
            pts.push(pts[j].map(|c| if c == 0.0 { -c } else { c }));
        } else {
            pts.push([(r % 1000) as f64 * 0.5, (r / 1000 % 7) as f64, 0.0]);
        }
    }
    let d = Dedup::new(&pts);
    let mut seen = std::collections::HashMap::new();
    let mut first = Vec::new();
    let mut of_point = Vec::new();
    for (i, p) in pts.iter().enumerate() {
        let k = p.map(|c| (c + 0.0).to_bits());
        let u = *seen.entry(k).or_insert_with(|| {
            first.push(i as u32);
            first.len() as u32 - 1
        });
        of_point.push(u);
    }
    assert!(first.len() < pts.len() && bucket_bits(pts.len()) > 4);
    assert_eq!(d.first.as_ref(), Some(&first));
    assert_eq!(d.of_point.as_ref(), Some(&of_point));
    let unique: Vec<[f64; 3]> = first.iter().map(|&i| pts[i as usize]).collect();
    assert!(d
        .unique
        .iter()
        .zip(&unique)
        .all(|(a, b)| a.map(f64::to_bits) == b.map(f64::to_bits)));
    let distinct: Vec<[f64; 3]> = (0..500).map(|i| [i as f64, 0.0, 1.0]).collect();
    let d = Dedup::new(&distinct);
    assert!(matches!(d.unique, Cow::Borrowed(_)) && d.first.is_none() && d.of_point.is_none());
    assert_eq!(d.first(7), 7);
}

#[test]
fn an_owned_cloud_gives_the_same_normals_as_a_borrowed_one() {
    // Given normals of mixed length and sign, one zero (replaced by a plane fit), and
    // repeated points (the duplicate path): every source must agree bit for bit.
    let mut points = fibonacci_sphere(400);
    points.extend_from_within(10..20);
    let normals: Vec<[f64; 3]> = points
        .iter()
        .enumerate()
        .map(|(i, p)| match i {
            5 => [0.0; 3],
            _ if i % 7 == 0 => p.map(|c| -3.0 * c),
            _ => p.map(|c| 0.5 * c),
        })
        .collect();
    let cloud = PointCloud {
        points,
        normals: Some(normals),
        ..Default::default()
    };
    for source in [NormalSource::Input, NormalSource::Pca, NormalSource::Crust] {
        let params = NormalsParams {
            source,
            ..Default::default()
        };
        let borrowed = estimate_normals(&cloud, &params).unwrap();
        let owned = estimate_normals_owned(cloud.clone(), &params).unwrap();
        assert_eq!(borrowed.cloud, owned.cloud, "{source:?}");
        assert_eq!(borrowed.warnings, owned.warnings, "{source:?}");
        assert_eq!(borrowed.cloud.points, cloud.points, "{source:?}");
    }
}
