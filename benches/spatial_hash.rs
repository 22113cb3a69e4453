//! k-nearest and radius queries of the spatial hash: build + query, 100,000 points, k = 20,
//! on a uniform cube, a sphere surface and clusters with outliers.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use std::hint::black_box;

use _core::SpatialHash;

mod clouds;

fn knn(c: &mut Criterion) {
    let mut group = c.benchmark_group("knn_build_and_query_k20");
    group.sample_size(20);
    for (name, points) in [
        ("uniform", clouds::uniform(100_000, 1)),
        ("sphere", clouds::sphere(100_000, 2)),
        ("clustered", clouds::clustered(100_000, 3)),
    ] {
        group.bench_with_input(BenchmarkId::from_parameter(name), &points, |b, p| {
            b.iter(|| {
                SpatialHash::new(black_box(p))
                    .unwrap()
                    .knn(None, 20)
                    .unwrap()
            })
        });
    }
    group.finish();
}

fn radius(c: &mut Criterion) {
    let points = clouds::uniform(100_000, 4);
    let index = SpatialHash::new(&points).unwrap();
    c.bench_function("radius_query_uniform_avg20", |b| {
        // About 20 neighbours per point: 100,000 * 4/3 pi r^3 = 20.
        b.iter(|| index.radius_neighbors(None, black_box(0.0363)).unwrap())
    });
}

criterion_group!(benches, knn, radius);
criterion_main!(benches, split_benches);

fn split(c: &mut Criterion) {
    let points = clouds::uniform(100_000, 1);
    c.bench_function("split/build_uniform", |b| {
        b.iter(|| SpatialHash::new(black_box(&points)).unwrap())
    });
    let index = SpatialHash::new(&points).unwrap();
    for k in [1, 5, 20] {
        c.bench_function(&format!("split/query_uniform_k{k}"), |b| {
            b.iter(|| index.knn(None, k).unwrap())
        });
    }
}
criterion_group!(split_benches, split);
