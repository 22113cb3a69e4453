//! The element-free model's kernels at the paper's size (2,465 nodes, k = 20, SPEC 4.1):
//! MLS shape functions at the nodes, stiffness assembly, and a matrix-free force evaluation.

use criterion::{criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

use _core::efg::{BlockPattern, Material, NodalElasticity, Plane};
use _core::mls::shape_functions;
use _core::SpatialHash;

const K: usize = 20;

/// A jittered 14 x 14 x 13 grid (2,548 nodes), neighbour lists with the node first, and
/// supports 1.1 times the k-th neighbour distance.
fn model() -> (Vec<[f64; 3]>, Vec<u32>, Vec<f64>) {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let points: Vec<[f64; 3]> = (0..14 * 14 * 13)
        .map(|i| {
            let c = [i % 14, (i / 14) % 14, i / 196];
            std::array::from_fn(|a| c[a] as f64 + rng.random_range(-0.3..0.3))
        })
        .collect();
    let knn = SpatialHash::new(&points).unwrap().knn(None, K - 1).unwrap();
    let mut neighbors = Vec::with_capacity(points.len() * K);
    let mut support = Vec::with_capacity(points.len());
    for p in 0..points.len() {
        neighbors.push(p as u32);
        neighbors.extend(
            knn.indices[p * (K - 1)..(p + 1) * (K - 1)]
                .iter()
                .map(|&i| i as u32),
        );
        support.push(1.1 * knn.distances[(p + 1) * (K - 1) - 1]);
    }
    (points, neighbors, support)
}

fn efg(c: &mut Criterion) {
    let (points, neighbors, support) = model();
    let shapes = shape_functions::<3, 4>(&points, &neighbors, K, &support).unwrap();
    let volumes = vec![1.0; points.len()];
    let material = Material {
        youngs: 1.0,
        poisson: 0.3,
        plane: Plane::Strain,
    };
    let elasticity =
        NodalElasticity::<3>::new(&neighbors, K, &shapes.grad, &volumes, &material).unwrap();
    let displacement: Vec<[f64; 3]> = points
        .iter()
        .map(|p| [0.01 * p[1], -0.02 * p[2], 0.005 * p[0]])
        .collect();
    let mut group = c.benchmark_group("efg_2548_nodes_k20");
    group.sample_size(20);
    group.bench_function("mls_shape_functions", |b| {
        b.iter(|| shape_functions::<3, 4>(black_box(&points), &neighbors, K, &support).unwrap())
    });
    group.bench_function("stiffness_assembly", |b| {
        b.iter(|| black_box(&elasticity).stiffness())
    });
    group.bench_function("stiffness_pattern", |b| {
        b.iter(|| BlockPattern::new(black_box(&neighbors), K, points.len()))
    });
    let pattern = BlockPattern::new(&neighbors, K, points.len());
    let mut blocks = vec![[[0.0; 3]; 3]; pattern.nnz()];
    group.bench_function("stiffness_blocks", |b| {
        b.iter(|| {
            pattern.assemble(
                black_box(&shapes.grad),
                &volumes,
                elasticity.lame(),
                None,
                None,
                &mut blocks,
            )
        })
    });
    group.bench_function("forces_matrix_free", |b| {
        b.iter(|| elasticity.forces(black_box(&displacement)).unwrap())
    });
    group.finish();
}

criterion_group!(benches, efg);
criterion_main!(benches);
