use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::efg::Csr;
use crate::Error;

/// A random SPD block matrix: a random symmetric pattern with random blocks, made
/// diagonally dominant per scalar row.
pub(super) fn random_spd<const B: usize>(n: usize, density: f64, seed: u64) -> BlockCsr<B> {
    random_banded_spd(n, n, density, seed)
}

/// As [`random_spd`], each row's off-diagonal blocks within `band` rows of the diagonal.
fn random_banded_spd<const B: usize>(
    n: usize,
    band: usize,
    density: f64,
    seed: u64,
) -> BlockCsr<B> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let adjacency: Vec<Vec<u32>> = (0..n)
        .map(|i| {
            (i.saturating_sub(band) as u32..i as u32)
                .filter(|_| rng.random_bool(density))
                .collect()
        })
        .collect();
    let mut m = BlockCsr::<B>::from_pattern(&adjacency).unwrap();
    let (indptr, indices) = (m.indptr().to_vec(), m.indices().to_vec());
    let blocks = m.blocks_mut();
    // Fill the lower triangle, mirror it into the upper.
    for i in 0..n {
        for at in indptr[i]..indptr[i + 1] {
            let j = indices[at] as usize;
            if j < i {
                let value: [[f64; B]; B] =
                    std::array::from_fn(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)));
                blocks[at] = value;
                let mirror = indptr[j]
                    + indices[indptr[j]..indptr[j + 1]]
                        .binary_search(&(i as u32))
                        .unwrap();
                blocks[mirror] = std::array::from_fn(|a| std::array::from_fn(|b| value[b][a]));
            }
        }
    }
    let csr = m.to_csr();
    let row_sums: Vec<f64> = (0..csr.size)
        .map(|r| {
            csr.data[csr.indptr[r]..csr.indptr[r + 1]]
                .iter()
                .map(|v| v.abs())
                .sum::<f64>()
        })
        .collect();
    for i in 0..n {
        let d = m.diagonal_block_mut(i);
        for a in 0..B {
            d[a][a] = row_sums[i * B + a] + 1.0;
        }
    }
    m
}

fn dense<const B: usize>(m: &BlockCsr<B>) -> nalgebra::DMatrix<f64> {
    let csr = m.to_csr();
    let mut d = nalgebra::DMatrix::zeros(csr.size, csr.size);
    for r in 0..csr.size {
        for at in csr.indptr[r]..csr.indptr[r + 1] {
            d[(r, csr.indices[at])] = csr.data[at];
        }
    }
    d
}

fn relative_error(x: &[f64], y: &[f64]) -> f64 {
    let diff: f64 = x.iter().zip(y).map(|(a, b)| (a - b) * (a - b)).sum();
    let norm: f64 = y.iter().map(|b| b * b).sum();
    (diff / norm).sqrt()
}

fn reference<const B: usize>(m: &BlockCsr<B>, rhs: &[f64]) -> Vec<f64> {
    let d = dense(m);
    d.cholesky()
        .unwrap()
        .solve(&nalgebra::DVector::from_column_slice(rhs))
        .as_slice()
        .to_vec()
}

fn check_solvers<const B: usize>(n: usize, density: f64, seed: u64) {
    let m = random_spd::<B>(n, density, seed);
    let mut rng = ChaCha8Rng::seed_from_u64(seed + 100);
    let rhs: Vec<f64> = (0..m.size()).map(|_| rng.random_range(-1.0..1.0)).collect();
    let expected = reference(&m, &rhs);

    let mut x = vec![0.0; m.size()];
    let mut jacobi = BlockJacobi::new(&m).unwrap();
    let status = Pcg::new()
        .solve(&m, &mut jacobi, &rhs, &mut x, 1e-12, 10 * m.size())
        .unwrap();
    assert!(status.converged, "{status:?}");
    assert!(status.relative_residual <= 1e-12);
    assert!(
        relative_error(&x, &expected) < 1e-9,
        "pcg {}",
        relative_error(&x, &expected)
    );

    let mut cholesky = SparseCholesky::analyse(&m).unwrap();
    cholesky.factorize(&m).unwrap();
    let mut y = vec![0.0; m.size()];
    cholesky.solve_into(&rhs, &mut y).unwrap();
    assert!(
        relative_error(&y, &expected) < 1e-10,
        "cholesky {}",
        relative_error(&y, &expected)
    );
}

#[test]
fn solvers_agree_with_dense_cholesky() {
    for seed in 0..4 {
        check_solvers::<3>(40, 0.1, seed);
        check_solvers::<2>(50, 0.2, seed);
        check_solvers::<3>(7, 1.0, seed);
        check_solvers::<2>(1, 0.0, seed);
    }
}

#[test]
fn csr_round_trip_and_product() {
    let m = random_spd::<3>(30, 0.2, 7);
    let csr = m.to_csr();
    let back = BlockCsr::<3>::from_csr(&csr).unwrap();
    assert!(back.same_pattern(&m));
    assert_eq!(back.blocks(), m.blocks());
    let x: Vec<f64> = (0..m.size()).map(|i| (i as f64).sin()).collect();
    let mut y = vec![0.0; m.size()];
    m.mul_into(&x, &mut y).unwrap();
    let expected = dense(&m) * nalgebra::DVector::from_column_slice(&x);
    assert!(relative_error(&y, expected.as_slice()) < 1e-14);
}

#[test]
fn partial_blocks_and_missing_diagonal_are_filled_with_zeros() {
    // 4x4 scalar, B = 2: only (0, 3) and (3, 0) off the diagonal blocks' scalars.
    let csr = Csr {
        size: 4,
        indptr: vec![0, 2, 3, 3, 4],
        indices: vec![0, 3, 1, 0],
        data: vec![2.0, 1.0, 3.0, 1.0],
    };
    let m = BlockCsr::<2>::from_csr(&csr).unwrap();
    assert_eq!(m.indptr(), &[0, 2, 4]);
    assert_eq!(m.indices(), &[0, 1, 0, 1]);
    assert_eq!(m.blocks()[1], [[0.0, 1.0], [0.0, 0.0]]);
    assert_eq!(*m.diagonal_block(1), [[0.0, 0.0], [0.0, 0.0]]);
}

#[test]
fn bad_input_is_an_error() {
    let csr = Csr {
        size: 4,
        indptr: vec![0, 1, 2, 3, 4],
        indices: vec![0, 1, 2, 3],
        data: vec![1.0; 4],
    };
    assert!(matches!(
        BlockCsr::<3>::from_csr(&csr),
        Err(Error::BlockSize {
            size: 4,
            block: 3,
            ..
        })
    ));
    let asymmetric = Csr {
        size: 4,
        indptr: vec![0, 2, 3, 4, 5],
        indices: vec![0, 2, 1, 2, 3],
        data: vec![1.0; 5],
    };
    assert!(matches!(
        BlockCsr::<2>::from_csr(&asymmetric),
        Err(Error::SparsePattern { row: 0, .. })
    ));
    let unsorted = Csr {
        size: 2,
        indptr: vec![0, 2, 3],
        indices: vec![1, 0, 1],
        data: vec![1.0; 3],
    };
    assert!(matches!(
        BlockCsr::<2>::from_csr(&unsorted),
        Err(Error::SparsePattern { row: 0, .. })
    ));
    let nan = Csr {
        size: 2,
        indptr: vec![0, 1, 2],
        indices: vec![0, 1],
        data: vec![1.0, f64::NAN],
    };
    assert!(matches!(
        BlockCsr::<2>::from_csr(&nan),
        Err(Error::NonFinite { row: 1, .. })
    ));
    // Indefinite: diag(1, 1, -1, 1) passes nothing.
    let indefinite = Csr {
        size: 4,
        indptr: vec![0, 1, 2, 3, 4],
        indices: vec![0, 1, 2, 3],
        data: vec![1.0, 1.0, -1.0, 1.0],
    };
    let m = BlockCsr::<2>::from_csr(&indefinite).unwrap();
    let mut cholesky = SparseCholesky::analyse(&m).unwrap();
    let failure = cholesky.factorize(&m);
    assert!(
        matches!(failure, Err(Error::NotPositiveDefinite { row: 2, .. })),
        "{failure:?}"
    );
    assert!(matches!(
        cholesky.solve_into(&[1.0; 4], &mut [0.0; 4]),
        Err(Error::NotFactorized)
    ));
    assert!(matches!(
        BlockJacobi::new(&m),
        Err(Error::NotPositiveDefinite { row: 2, .. })
    ));
}

/// The EFG stiffness of a jittered 5 x 5 x 4 grid (k = 20) and its neighbour lists.
pub(super) fn efg_stiffness() -> (Csr, Vec<u32>, usize) {
    use crate::efg::{Material, NodalElasticity, Plane};
    const K: usize = 20;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let points: Vec<[f64; 3]> = (0..100)
        .map(|i| {
            let c = [i % 5, (i / 5) % 5, i / 25];
            std::array::from_fn(|a| c[a] as f64 + rng.random_range(-0.3..0.3))
        })
        .collect();
    let knn = crate::SpatialHash::new(&points)
        .unwrap()
        .knn(None, K - 1)
        .unwrap();
    let mut neighbors = Vec::new();
    let mut support = Vec::new();
    for p in 0..points.len() {
        neighbors.push(p as u32);
        neighbors.extend(
            knn.indices[p * (K - 1)..(p + 1) * (K - 1)]
                .iter()
                .map(|&i| i as u32),
        );
        support.push(1.1 * knn.distances[(p + 1) * (K - 1) - 1]);
    }
    let shapes = crate::mls::shape_functions::<3, 4>(&points, &neighbors, K, &support).unwrap();
    let volumes = vec![1.0; points.len()];
    let material = Material {
        youngs: 1.0,
        poisson: 0.3,
        plane: Plane::Strain,
    };
    let k = NodalElasticity::<3>::new(&neighbors, K, &shapes.grad, &volumes, &material)
        .unwrap()
        .stiffness();
    (k, neighbors, K)
}

#[test]
fn neighbourhood_pattern_is_the_stiffness_pattern() {
    let (k, neighbors, nk) = efg_stiffness();
    let stiffness = BlockCsr::<3>::from_csr(&k).unwrap();
    let pattern = BlockCsr::<3>::from_neighborhoods(stiffness.len(), &neighbors, nk).unwrap();
    assert!(pattern.same_pattern(&stiffness));
    assert!(pattern.blocks().iter().all(|b| *b == [[0.0; 3]; 3]));
    // Round trip through scalar CSR keeps every entry.
    assert_eq!(stiffness.to_csr(), k);
}

#[test]
fn assembly_in_place_matches_a_fresh_matrix() {
    let (k, _, _) = efg_stiffness();
    let stiffness = BlockCsr::<3>::from_csr(&k).unwrap();
    let nodes = [0u32, 7, 7, 42];
    let blocks = [[[1.0, 0.5, 0.0], [0.5, 2.0, 0.0], [0.0, 0.0, 3.0]]; 4];
    let mut out = stiffness.zeros_like();
    for _ in 0..2 {
        stiffness.scale_into(2.5, &mut out).unwrap();
        out.add_diagonal_blocks(0.1, &nodes, &blocks).unwrap();
    }
    let mut expected = k.clone();
    expected.data.iter_mut().for_each(|v| *v *= 2.5);
    let mut fresh = BlockCsr::<3>::from_csr(&expected).unwrap();
    for (&i, m) in nodes.iter().zip(&blocks) {
        let d = fresh.diagonal_block_mut(i as usize);
        for a in 0..3 {
            for b in 0..3 {
                d[a][b] += 0.1 * m[a][b];
            }
        }
    }
    assert_eq!(out.blocks(), fresh.blocks());
    // A matrix of another pattern is refused; so are bad nodes and blocks.
    let mut other = random_spd::<3>(stiffness.len(), 0.01, 1);
    assert!(matches!(
        stiffness.scale_into(1.0, &mut other),
        Err(Error::PatternMismatch { .. })
    ));
    assert!(matches!(
        out.add_diagonal_blocks(1.0, &[100], &blocks[..1]),
        Err(Error::NodeIndex { index: 100, .. })
    ));
    assert!(matches!(
        out.add_diagonal_blocks(1.0, &[1, 2], &blocks[..1]),
        Err(Error::VectorLength { .. })
    ));
    let mut cholesky = SparseCholesky::analyse(&out).unwrap();
    assert!(matches!(
        cholesky.factorize(&other),
        Err(Error::PatternMismatch { .. })
    ));
}

#[test]
fn symmetric_closure_of_an_adjacency() {
    let m = BlockCsr::<2>::from_pattern(&[vec![2u32], vec![], vec![]]).unwrap();
    assert_eq!(m.indptr(), &[0, 2, 3, 5]);
    assert_eq!(m.indices(), &[0, 2, 1, 0, 2]);
    assert!(matches!(
        BlockCsr::<2>::from_pattern(&[vec![3u32]]),
        Err(Error::NodeIndex { index: 3, .. })
    ));
}

#[test]
fn pcg_cap_and_warm_start() {
    let m = random_spd::<3>(80, 0.1, 9);
    let rhs: Vec<f64> = (0..m.size()).map(|i| (i as f64 * 0.37).cos()).collect();
    let exact = reference(&m, &rhs);
    let mut jacobi = BlockJacobi::new(&m).unwrap();
    let mut pcg = Pcg::new();
    let mut x = vec![0.0; m.size()];
    let capped = pcg.solve(&m, &mut jacobi, &rhs, &mut x, 1e-14, 2).unwrap();
    assert!(!capped.converged && capped.iterations == 2 && capped.relative_residual > 1e-14);
    x.copy_from_slice(&exact);
    let warm = pcg
        .solve(&m, &mut jacobi, &rhs, &mut x, 1e-10, 100)
        .unwrap();
    assert!(warm.converged && warm.iterations <= 1, "{warm:?}");
}

fn check_upper_product<const B: usize>(n: usize, density: f64) {
    let m = random_spd::<B>(n, density, 4);
    let x: Vec<f64> = (0..m.size()).map(|i| (i as f64 * 0.71).sin()).collect();
    let mut full = vec![0.0; m.size()];
    m.mul_into(&x, &mut full).unwrap();
    let mut upper = super::upper::Upper::<B>::default();
    upper.load(&m);
    let mut half = vec![[0.0; B]; m.len()];
    for _ in 0..2 {
        if upper.has_exact() {
            upper.mul(x.as_chunks::<B>().0, &mut half);
            assert!(relative_error(half.as_flattened(), &full) < 1e-14);
        }
        // float32 blocks where the AVX2 kernel runs: ~1e-7 relative.
        upper.mul_inner(x.as_chunks::<B>().0, &mut half);
        let bound = if upper.inexact_inner() { 1e-6 } else { 1e-14 };
        assert!(relative_error(half.as_flattened(), &full) < bound);
    }
}

#[test]
fn upper_triangle_product_equals_the_full_one() {
    // Large enough for one task per thread, and small (one task).
    check_upper_product::<3>(3000, 0.01);
    check_upper_product::<2>(4000, 0.01);
    check_upper_product::<3>(30, 0.2);
}

#[test]
fn upper_product_of_a_band_adds_only_the_band() {
    // ~100,000 upper blocks: eight tasks, each touching its rows and the band after them.
    const BAND: usize = 40;
    let m = random_banded_spd::<3>(20_000, BAND, 0.1, 5);
    let x: Vec<f64> = (0..m.size()).map(|i| (i as f64 * 0.53).cos()).collect();
    let mut full = vec![0.0; m.size()];
    m.mul_into(&x, &mut full).unwrap();
    let product = |threads| {
        crate::ordered::in_pool(threads, || {
            let mut upper = super::upper::Upper::<3>::default();
            upper.load(&m);
            let (ranges, spans) = upper.tasks();
            assert_eq!(ranges.len(), 8);
            for (&(start, end), &(from, to)) in ranges.iter().zip(spans) {
                assert!(from == start && to >= end && to <= (end + BAND).min(m.len()));
            }
            let mut y = vec![[0.0; 3]; m.len()];
            if upper.has_exact() {
                upper.mul(x.as_chunks::<3>().0, &mut y);
                assert!(relative_error(y.as_flattened(), &full) < 1e-14);
            }
            upper.mul_inner(x.as_chunks::<3>().0, &mut y);
            let bound = if upper.inexact_inner() { 1e-6 } else { 1e-14 };
            assert!(relative_error(y.as_flattened(), &full) < bound);
            y
        })
    };
    let one = product(1);
    for threads in [2, 3] {
        let many = product(threads);
        assert!(one
            .as_flattened()
            .iter()
            .zip(many.as_flattened())
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }
}

#[test]
fn pcg_gives_the_same_bits_on_any_thread_count() {
    // Long enough for the parallel dot products (>= 2^16 scalars) and a product split into
    // several tasks (~140,000 upper blocks); 12 iterations, not converged, so every
    // iteration's rounding reaches the result.
    let m = random_spd::<3>(22_000, 5e-4, 12);
    let rhs: Vec<f64> = (0..m.size()).map(|i| (i as f64 * 0.37).cos()).collect();
    let solve = |threads| {
        crate::ordered::in_pool(threads, || {
            let mut jacobi = BlockJacobi::new(&m).unwrap();
            let mut x = vec![0.0; m.size()];
            let status = Pcg::new()
                .solve(&m, &mut jacobi, &rhs, &mut x, 1e-15, 12)
                .unwrap();
            (x, status)
        })
    };
    let (one, status) = solve(1);
    assert!(status.iterations == 12 && !status.converged, "{status:?}");
    for threads in [2, 3, 4] {
        let (many, many_status) = solve(threads);
        assert_eq!(status, many_status, "{threads} threads");
        assert!(
            one.iter()
                .zip(&many)
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "{threads} threads"
        );
    }
}
