//! Criterion benches of the `polygonize` stage on degree-8 models (the speed target: a degree-8
//! model at depth 8 in under 1 s on a 2-core machine).
//!
//! Run: `cargo bench --bench polygonize`.

use criterion::{criterion_group, criterion_main, Criterion};

use stablesurf::polygonize::{polygonize, PolygonizeParams};
use stablesurf::testing::shapes;
use stablesurf::Aabb;

fn bench_degree_eight(c: &mut Criterion) {
    let mut group = c.benchmark_group("polygonize");
    group.sample_size(10);
    let cases = [
        (
            "genus_two_deg8",
            shapes::genus_two(),
            Aabb {
                min: [-1.2, -0.7, -0.2],
                max: [1.2, 0.7, 0.2],
            },
        ),
        (
            "linked_tori_deg8",
            shapes::linked_tori(),
            Aabb {
                min: [-1.4, -1.4, -1.4],
                max: [2.4, 1.4, 1.4],
            },
        ),
    ];
    for (name, f, region) in &cases {
        for depth in [7, 8] {
            let params = PolygonizeParams {
                depth,
                ..PolygonizeParams::default()
            };
            group.bench_function(format!("{name}/depth={depth}"), |b| {
                b.iter(|| polygonize(f, region, &params).expect("valid input"))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench_degree_eight);
criterion_main!(benches);
