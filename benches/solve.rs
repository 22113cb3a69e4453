//! The linear system of the elastic fitting (SPEC 5, step 4) at the paper's size: the
//! elastic model's stiffness (EFG, k = 20, with its stabilising consistency penalty) of
//! 2,465 jittered-grid nodes plus anisotropic 3x3 blocks on the boundary nodes,
//! $(K + D) x = f$. Block-Jacobi and two-level PCG cold and warm, Cholesky analysis,
//! factorisation and solve, and CG preconditioned by the factor of a nearby matrix.
//!
//! `SOLVE_SCALING=1 cargo bench --bench solve -- scaling` adds one solve per solver at
//! 1k to 64k nodes (slow: it builds every model).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

use _core::efg::{Material, Plane};
use _core::elastic::{ElasticModel, Rotation, RotationFit};
use _core::solve::{BlockCsr, BlockJacobi, Pcg, SparseCholesky, TwoLevel, STRENGTH};

const K: usize = 20;
const TOLERANCE: f64 = 1e-8;

/// The consistency penalty of `python/elastocap/elastic.py`'s default.
const STABILIZATION: f64 = 0.1;

/// Stiffness, surface nodes, their 3x3 blocks, right-hand side, node positions.
type System = (
    BlockCsr<3>,
    Vec<u32>,
    Vec<[[f64; 3]; 3]>,
    Vec<f64>,
    Vec<[f64; 3]>,
);

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
    let material = Material {
        youngs: 1.0,
        poisson: 0.3,
        plane: Plane::Strain,
    };
    let model = ElasticModel::<3>::new(
        points.clone(),
        K,
        vec![1.0; n],
        &material,
        Rotation::Rhs,
        RotationFit::Gradient,
    )
    .unwrap()
    .with_stabilization(STABILIZATION)
    .unwrap();
    let pattern = model.pattern();
    let rows: Vec<&[u32]> = pattern
        .indptr
        .windows(2)
        .map(|w| &pattern.indices[w[0]..w[1]])
        .collect();
    let mut matrix = BlockCsr::<3>::from_pattern(&rows).unwrap();
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    model
        .system_blocks(&vec![identity; n], matrix.blocks_mut())
        .unwrap();
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
    (matrix, surface, blocks, rhs, points)
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
    let (stiffness, surface, blocks, rhs, points) = fitting_system(2465, 7);
    let a = assemble(&stiffness, &surface, &blocks, 1.0);
    let size = a.size();
    let mut two_level = TwoLevel::new(&a, &points, STRENGTH).unwrap();
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
    let two_cold = pcg
        .solve(&a, &mut two_level, &rhs, &mut x, TOLERANCE, 100 * size)
        .unwrap();
    x.copy_from_slice(&perturbed);
    let two_warm = pcg
        .solve(&a, &mut two_level, &rhs, &mut x, TOLERANCE, 100 * size)
        .unwrap();
    x.fill(0.0);
    let chol_pcg = pcg
        .solve(&next, &mut cholesky, &rhs, &mut x, TOLERANCE, 100 * size)
        .unwrap();
    eprintln!(
        "n = 2465: {} surface nodes, {} blocks, factor {} entries (supernodal: {}); \
         PCG iterations: reference {} , cold {}, warm {}, Cholesky-preconditioned {}; \
         two-level ({} aggregates, {} coarse unknowns) cold {}, warm {}",
        surface.len(),
        a.blocks().len(),
        cholesky.factor_len(),
        cholesky.is_supernodal(),
        status.iterations,
        cold.iterations,
        warm.iterations,
        chol_pcg.iterations,
        two_level.aggregates(),
        two_level.coarse_size(),
        two_cold.iterations,
        two_warm.iterations
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
    // The path of `elastocap.conjugate_gradient` from Python: scipy's int32 CSR arrays read
    // straight into the upper triangle, then block-Jacobi PCG.
    let indptr32: Vec<i32> = csr.indptr.iter().map(|&v| v as i32).collect();
    let indices32: Vec<i32> = csr.indices.iter().map(|&v| v as i32).collect();
    // With no iterations: the conversion and the Jacobi blocks alone.
    for (name, cap) in [
        ("csr_arrays_to_upper", 0),
        ("pcg_from_csr_arrays_cold", 100 * size),
    ] {
        group.bench_function(name, |b| {
            b.iter(|| {
                x.fill(0.0);
                Pcg::<3>::new()
                    .solve_csr_parts(
                        size,
                        &indptr32,
                        &indices32,
                        black_box(&csr.data),
                        &rhs,
                        &mut x,
                        TOLERANCE,
                        cap,
                    )
                    .unwrap()
            })
        });
    }
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
    group.bench_function("two_level_setup", |b| {
        b.iter(|| TwoLevel::new(black_box(&a), &points, STRENGTH).unwrap())
    });
    group.bench_function("two_level_update", |b| {
        b.iter(|| {
            two_level.set_positions(&points).unwrap();
            two_level.update(black_box(&a)).unwrap()
        })
    });
    // One solve of a fitting iteration: new rigid modes and coarse matrix, then PCG.
    group.bench_function("pcg_two_level_cold", |b| {
        b.iter(|| {
            x.fill(0.0);
            two_level.set_positions(&points).unwrap();
            two_level.update(&a).unwrap();
            pcg.solve(
                &a,
                &mut two_level,
                black_box(&rhs),
                &mut x,
                TOLERANCE,
                100 * size,
            )
            .unwrap()
        })
    });
    group.bench_function("pcg_two_level_warm", |b| {
        b.iter(|| {
            x.copy_from_slice(&perturbed);
            two_level.set_positions(&points).unwrap();
            two_level.update(&a).unwrap();
            pcg.solve(
                &a,
                &mut two_level,
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
        let (stiffness, surface, blocks, rhs, points) = fitting_system(n, 7);
        let a = assemble(&stiffness, &surface, &blocks, 1.0);
        let mut x = vec![0.0; a.size()];
        let mut pcg = Pcg::new();
        let mut jacobi = BlockJacobi::new(&a).unwrap();
        let status = pcg
            .solve(&a, &mut jacobi, &rhs, &mut x, TOLERANCE, 100 * a.size())
            .unwrap();
        let mut two_level = TwoLevel::new(&a, &points, STRENGTH).unwrap();
        x.fill(0.0);
        let two = pcg
            .solve(&a, &mut two_level, &rhs, &mut x, TOLERANCE, 100 * a.size())
            .unwrap();
        eprintln!(
            "n = {n}: PCG iterations block-Jacobi {}, two-level {} ({} coarse unknowns)",
            status.iterations,
            two.iterations,
            two_level.coarse_size()
        );
        group.bench_with_input(BenchmarkId::new("pcg_two_level_cold", n), &n, |b, _| {
            b.iter(|| {
                x.fill(0.0);
                two_level.set_positions(&points).unwrap();
                two_level.update(&a).unwrap();
                pcg.solve(&a, &mut two_level, &rhs, &mut x, TOLERANCE, 100 * a.size())
                    .unwrap()
            })
        });
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
