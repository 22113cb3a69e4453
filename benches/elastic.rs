//! Building the element-free model (SPEC 4.1-4.3): neighbours, MLS shape functions, rest
//! gradients and rotation weights (`ElasticModel::new`), then the stiffness pattern and
//! blocks; at the paper's Dance size (2,465 nodes, k = 20) and scaled up to 64k nodes.
//! Also one rotation update and one matrix-free product, the per-iteration kernels.
//! `ELASTIC_SCALING=1` adds the other sizes (slow).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

use _core::efg::{Material, Plane};
use _core::elastic::{ElasticModel, Rotation, RotationFit};

const K: usize = 20;
const MATERIAL: Material = Material {
    youngs: 1.0,
    poisson: 0.3,
    plane: Plane::Strain,
};

/// The first `n` points of a jittered cubic grid (spacing 1, jitter +-0.3), filled layer by
/// layer: a box-shaped body with `n` nodes.
fn nodes(n: usize) -> Vec<[f64; 3]> {
    let side = (n as f64).cbrt().ceil() as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    (0..n)
        .map(|i| {
            let c = [i % side, (i / side) % side, i / (side * side)];
            std::array::from_fn(|a| c[a] as f64 + rng.random_range(-0.3..0.3))
        })
        .collect()
}

fn build(rest: &[[f64; 3]]) -> ElasticModel<3> {
    ElasticModel::new(
        rest.to_vec(),
        K,
        vec![1.0; rest.len()],
        &MATERIAL,
        Rotation::Rhs,
        RotationFit::Gradient,
    )
    .unwrap()
    // The consistency penalty of the Python default (its blocks are built with the
    // stiffness, on first use).
    .with_stabilization(0.1)
    .unwrap()
}

fn elastic(c: &mut Criterion) {
    let mut group = c.benchmark_group("elastic_build_k20");
    group.sample_size(10);
    let sizes: &[usize] = if std::env::var_os("ELASTIC_SCALING").is_some() {
        &[1_000, 2_465, 4_000, 16_000, 64_000]
    } else {
        &[2_465]
    };
    for &n in sizes {
        let rest = nodes(n);
        group.bench_with_input(BenchmarkId::new("model", n), &rest, |b, rest| {
            b.iter(|| build(black_box(rest)))
        });
        group.bench_with_input(
            BenchmarkId::new("model_and_stiffness", n),
            &rest,
            |b, rest| {
                b.iter(|| {
                    let model = build(black_box(rest));
                    let pattern = model.pattern();
                    let mut blocks = vec![[[0.0; 3]; 3]; pattern.nnz()];
                    let eye = vec![[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]; rest.len()];
                    model.system_blocks(&eye, &mut blocks).unwrap();
                    blocks.len()
                })
            },
        );
    }
    group.finish();

    let rest = nodes(2_465);
    let model = build(&rest);
    let bent: Vec<[f64; 3]> = rest
        .iter()
        .map(|p| {
            let a = 0.05 * p[2];
            [
                p[0] * a.cos() - p[1] * a.sin(),
                p[0] * a.sin() + p[1] * a.cos(),
                p[2],
            ]
        })
        .collect();
    let rotations = model.rotations(&bent).unwrap();
    let mut group = c.benchmark_group("elastic_iteration_2465_k20");
    group.bench_function("rotations", |b| {
        b.iter(|| model.rotations(black_box(&bent)).unwrap())
    });
    group.bench_function("rhs", |b| {
        b.iter(|| model.rhs(black_box(&rotations)).unwrap())
    });
    group.bench_function("matrix_free_product", |b| {
        b.iter(|| model.apply(&rotations, black_box(&bent)).unwrap())
    });
    group.finish();
}

criterion_group!(benches, elastic);
criterion_main!(benches);
