//! The linear system of the elastic fitting (SPEC 5, step 4) at the paper's size: EFG
//! stiffness of 2,465 jittered-grid nodes (k = 20) plus anisotropic 3x3 blocks on the
//! boundary nodes, $(K + D) x = f$. Block-Jacobi PCG cold and warm, Cholesky analysis,
//! factorisation and solve, and CG preconditioned by the factor of a nearby matrix.
//!
//! `SOLVE_SCALING=1 cargo bench --bench solve -- scaling` adds one solve per solver at
//! 1k to 64k nodes (slow: it builds every model).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

use _core::efg::{Material, NodalElasticity, Plane};
use _core::mls::shape_functions;
use _core::solve::{BlockCsr, BlockJacobi, Pcg, SparseCholesky};
use _core::SpatialHash;

const K: usize = 20;
const TOLERANCE: f64 = 1e-8;

/// Stiffness, surface nodes, their 3x3 blocks, right-hand side.
type System = (BlockCsr<3>, Vec<u32>, Vec<[[f64; 3]; 3]>, Vec<f64>);

/// The fitting system of `n` nodes: the first `n` points of a jittered cubic grid (unit
/// spacing, unit volumes), its stiffness, and on the nodes of the grid's outer layer the
/// blocks `s (0.3 I + g g^T)` with `g` a random unit vector and `s` the mean diagonal of K,
/// shaped like the anisotropic surface metric (SPEC 5, step 2); plus a right-hand side.
pub fn fitting_system(n: usize, seed: u64) -> System {
    let side = (n as f64).cbrt().ceil() as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let cells: Vec<[usize; 3]> = (0..n)
        .map(|i| [i % side, (i / side) % side, i / (side * side)])
        .collect();
    let points: Vec<[f64; 3]> = cells
        .iter()
        .map(|c| std::array::from_fn(|a| c[a] as f64 + rng.random_range(-0.3..0.3)))
        .collect();
    let layers = n.div_ceil(side * side);
    let knn = SpatialHash::new(&points).unwrap().knn(None, K - 1).unwrap();
    let mut neighbors = Vec::with_capacity(n * K);
    let mut support = Vec::with_capacity(n);
    for p in 0..n {
        neighbors.push(p as u32);
        neighbors.extend(
            knn.indices[p * (K - 1)..(p + 1) * (K - 1)]
                .iter()
                .map(|&i| i as u32),
        );
        support.push(1.1 * knn.distances[(p + 1) * (K - 1) - 1]);
    }
    let shapes = shape_functions::<3, 4>(&points, &neighbors, K, &support).unwrap();
    let volumes = vec![1.0; n];
    let material = Material {
        youngs: 1.0,
        poisson: 0.3,
        plane: Plane::Strain,
    };
    let stiffness = NodalElasticity::<3>::new(&neighbors, K, &shapes.grad, &volumes, &material)
        .unwrap()
        .stiffness();
    let matrix = BlockCsr::<3>::from_csr(&stiffness).unwrap();
    let scale = (0..n)
        .map(|i| (0..3).map(|a| matrix.diagonal_block(i)[a][a]).sum::<f64>())
        .sum::<f64>()
        / (3 * n) as f64;
    let surface: Vec<u32> = (0..n as u32)
        .filter(|&i| {
            let c = cells[i as usize];
            c.contains(&0) || c[0] == side - 1 || c[1] == side - 1 || c[2] + 1 >= layers
        })
        .collect();
    let blocks: Vec<[[f64; 3]; 3]> = surface
        .iter()
        .map(|_| {
            let g: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
            std::array::from_fn(|a| {
                std::array::from_fn(|b| {
                    scale * (0.3 * f64::from(u8::from(a == b)) + g[a] * g[b] / (norm * norm))
                })
            })
        })
        .collect();
    let rhs: Vec<f64> = (0..3 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
    (matrix, surface, blocks, rhs)
}

fn assemble(
    stiffness: &BlockCsr<3>,
    surface: &[u32],
    blocks: &[[[f64; 3]; 3]],
    beta: f64,
) -> BlockCsr<3> {
    let mut a = stiffness.zeros_like();
    stiffness.scale_into(1.0, &mut a).unwrap();
    a.add_diagonal_blocks(beta, surface, blocks).unwrap();
    a
}

fn solve(c: &mut Criterion) {
    let (stiffness, surface, blocks, rhs) = fitting_system(2465, 7);
    let a = assemble(&stiffness, &surface, &blocks, 1.0);
    let size = a.size();
    let csr = a.to_csr();
    let mut pcg = Pcg::new();
    let mut jacobi = BlockJacobi::new(&a).unwrap();
    let mut exact = vec![0.0; size];
    let status = pcg
        .solve(&a, &mut jacobi, &rhs, &mut exact, 1e-12, 100 * size)
        .unwrap();
    let perturbed: Vec<f64> = {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let norm = exact.iter().map(|v| v * v).sum::<f64>().sqrt() / (size as f64).sqrt();
        exact
            .iter()
            .map(|v| v + 1e-3 * norm * rng.random_range(-1.0..1.0))
            .collect()
    };
    let mut cholesky = SparseCholesky::analyse(&a).unwrap();
    cholesky.factorize(&a).unwrap();
    // The next iteration's matrix: the surface blocks 20% stronger.
    let next = assemble(&stiffness, &surface, &blocks, 1.2);
    let mut x = vec![0.0; size];
    let cold = pcg
        .solve(&a, &mut jacobi, &rhs, &mut x, TOLERANCE, 100 * size)
        .unwrap();
    x.copy_from_slice(&perturbed);
    let warm = pcg
        .solve(&a, &mut jacobi, &rhs, &mut x, TOLERANCE, 100 * size)
        .unwrap();
    x.fill(0.0);
    let chol_pcg = pcg
        .solve(&next, &mut cholesky, &rhs, &mut x, TOLERANCE, 100 * size)
        .unwrap();
    eprintln!(
        "n = 2465: {} surface nodes, {} blocks, factor {} entries (supernodal: {}); \
         PCG iterations: reference {} , cold {}, warm {}, Cholesky-preconditioned {}",
        surface.len(),
        a.blocks().len(),
        cholesky.factor_len(),
        cholesky.is_supernodal(),
        status.iterations,
        cold.iterations,
        warm.iterations,
        chol_pcg.iterations
    );

    let mut group = c.benchmark_group("solve_2465_nodes_k20");
    group.sample_size(20);
    group.bench_function("matvec", |b| {
        let mut y = vec![0.0; size];
        b.iter(|| a.mul_into(black_box(&rhs), &mut y).unwrap())
    });
    group.bench_function("from_csr", |b| {
        b.iter(|| BlockCsr::<3>::from_csr(black_box(&csr)).unwrap())
    });
    group.bench_function("assemble_scale_plus_blocks", |b| {
        let mut out = stiffness.zeros_like();
        b.iter(|| {
            stiffness.scale_into(1.0, &mut out).unwrap();
            out.add_diagonal_blocks(1.0, &surface, &blocks).unwrap();
        })
    });
    group.bench_function("pcg_block_jacobi_cold", |b| {
        b.iter(|| {
            x.fill(0.0);
            jacobi.update(&a).unwrap();
            pcg.solve(
                &a,
                &mut jacobi,
                black_box(&rhs),
                &mut x,
                TOLERANCE,
                100 * size,
            )
            .unwrap()
        })
    });
    group.bench_function("pcg_block_jacobi_warm", |b| {
        b.iter(|| {
            x.copy_from_slice(&perturbed);
            jacobi.update(&a).unwrap();
            pcg.solve(
                &a,
                &mut jacobi,
                black_box(&rhs),
                &mut x,
                TOLERANCE,
                100 * size,
            )
            .unwrap()
        })
    });
    group.bench_function("cholesky_analyse", |b| {
        b.iter(|| SparseCholesky::analyse(black_box(&a)).unwrap())
    });
    group.bench_function("cholesky_factorize", |b| {
        b.iter(|| cholesky.factorize(black_box(&a)).unwrap())
    });
    group.bench_function("cholesky_solve", |b| {
        b.iter(|| cholesky.solve_into(black_box(&rhs), &mut x).unwrap())
    });
    group.bench_function("pcg_cholesky_preconditioned_next_matrix", |b| {
        b.iter(|| {
            x.fill(0.0);
            pcg.solve(
                &next,
                &mut cholesky,
                black_box(&rhs),
                &mut x,
                TOLERANCE,
                100 * size,
            )
            .unwrap()
        })
    });
    group.finish();
}

fn scaling(c: &mut Criterion) {
    if std::env::var_os("SOLVE_SCALING").is_none() {
        return;
    }
    let mut group = c.benchmark_group("solve_scaling");
    group.sample_size(10);
    for n in [1000, 2465, 4000, 16000, 64000] {
        let (stiffness, surface, blocks, rhs) = fitting_system(n, 7);
        let a = assemble(&stiffness, &surface, &blocks, 1.0);
        let mut x = vec![0.0; a.size()];
        let mut pcg = Pcg::new();
        let mut jacobi = BlockJacobi::new(&a).unwrap();
        let status = pcg
            .solve(&a, &mut jacobi, &rhs, &mut x, TOLERANCE, 100 * a.size())
            .unwrap();
        eprintln!("n = {n}: block-Jacobi PCG {} iterations", status.iterations);
        group.bench_with_input(BenchmarkId::new("pcg_block_jacobi_cold", n), &n, |b, _| {
            b.iter(|| {
                x.fill(0.0);
                jacobi.update(&a).unwrap();
                pcg.solve(&a, &mut jacobi, &rhs, &mut x, TOLERANCE, 100 * a.size())
                    .unwrap()
            })
        });
        if n <= 4000 {
            let mut cholesky = SparseCholesky::analyse(&a).unwrap();
            eprintln!("n = {n}: Cholesky factor {} entries", cholesky.factor_len());
            group.bench_with_input(
                BenchmarkId::new("cholesky_factorize_and_solve", n),
                &n,
                |b, _| {
                    b.iter(|| {
                        cholesky.factorize(&a).unwrap();
                        cholesky.solve_into(&rhs, &mut x).unwrap()
                    })
                },
            );
            group.bench_with_input(BenchmarkId::new("cholesky_solve", n), &n, |b, _| {
                b.iter(|| cholesky.solve_into(&rhs, &mut x).unwrap())
            });
        }
    }
    group.finish();
}

criterion_group!(benches, solve, scaling);
criterion_main!(benches);
