//! Nearest rotations of 1,000,000 random 3x3 matrices (and of near-rotations, the common case
//! in the elastic model).

use criterion::{criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

use _core::polar::{polar3, Mat3};

fn polar(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let random: Vec<Mat3> = (0..1_000_000)
        .map(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)))
        .collect();
    let near_identity: Vec<Mat3> = (0..1_000_000)
        .map(|_| {
            std::array::from_fn(
                |i| if i % 4 == 0 { 1.0 } else { 0.0 } + 0.05 * rng.random_range(-1.0..1.0),
            )
        })
        .collect();
    let mut out = vec![[0.0; 9]; 1_000_000];
    let mut group = c.benchmark_group("polar3_1e6");
    group.sample_size(20);
    group.bench_function("random", |b| {
        b.iter(|| polar3(black_box(&random), &mut out, None).unwrap())
    });
    group.bench_function("near_identity", |b| {
        b.iter(|| polar3(black_box(&near_identity), &mut out, None).unwrap())
    });
    group.finish();
}

criterion_group!(benches, polar);
criterion_main!(benches);
