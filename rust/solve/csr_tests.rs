//! The upper triangle read straight from scalar CSR arrays (`Pcg::solve_csr_parts`) against
//! the path through a full [`BlockCsr`]: the same blocks (float64 and float32), the same
//! errors, the same solution to rounding.

use super::tests::{efg_stiffness, random_spd};
use super::upper::Upper;
use super::*;
use crate::efg::Csr;
use crate::Error;

/// Drops the scalar entries below `cut` in magnitude (off the diagonal), so that some blocks
/// are partial and some diagonal blocks lose entries.
fn thinned(csr: &Csr, cut: f64) -> Csr {
    let (mut indptr, mut indices, mut data) = (vec![0], Vec::new(), Vec::new());
    for r in 0..csr.size {
        for at in csr.indptr[r]..csr.indptr[r + 1] {
            if csr.data[at].abs() >= cut || csr.indices[at] == r {
                indices.push(csr.indices[at]);
                data.push(csr.data[at]);
            }
        }
        indptr.push(indices.len());
    }
    Csr {
        size: csr.size,
        indptr,
        indices,
        data,
    }
}

fn narrow(v: &[usize]) -> Vec<i32> {
    v.iter().map(|&i| i as i32).collect()
}

fn check_same_upper<const B: usize>(csr: &Csr) {
    // The upper triangle of the block matrix, row by row.
    let matrix = BlockCsr::<B>::from_csr(csr).unwrap();
    let (mut indptr, mut indices, mut blocks) = (vec![0], Vec::new(), Vec::new());
    for i in 0..matrix.len() {
        for at in matrix.indptr()[i]..matrix.indptr()[i + 1] {
            if matrix.indices()[at] as usize >= i {
                indices.push(matrix.indices()[at]);
                blocks.push(matrix.blocks()[at]);
            }
        }
        indptr.push(indices.len());
    }
    let mut loaded = Upper::<B>::default();
    loaded.load(&matrix);
    let direct =
        Upper::<B>::from_csr_parts(csr.size, &csr.indptr, &csr.indices, &csr.data).unwrap();
    let (p, i) = (narrow(&csr.indptr), narrow(&csr.indices));
    let narrow_direct = Upper::<B>::from_csr_parts(csr.size, &p, &i, &csr.data).unwrap();
    for upper in [&direct, &narrow_direct] {
        let got = upper.parts();
        assert_eq!(got.0, indptr);
        assert_eq!(got.1, indices);
        assert_eq!(got.2, blocks, "blocks differ");
        // The float32 copy, when there is one, is the one `load` makes, pad included.
        assert_eq!(got.3, loaded.parts().3);
    }
    let single: Vec<f32> = blocks
        .as_flattened()
        .as_flattened()
        .iter()
        .map(|&v| v as f32)
        .collect();
    if !loaded.parts().3.is_empty() {
        assert_eq!(&loaded.parts().3[..single.len()], &single[..]);
    } else {
        assert_eq!(loaded.parts().2, blocks);
    }
}

#[test]
fn upper_from_csr_equals_the_block_matrix_path() {
    let (efg, _, _) = efg_stiffness();
    check_same_upper::<3>(&efg);
    check_same_upper::<3>(&thinned(&efg, 0.05));
    let random3 = random_spd::<3>(400, 0.03, 11).to_csr();
    check_same_upper::<3>(&random3);
    check_same_upper::<3>(&thinned(&random3, 0.5));
    let random2 = random_spd::<2>(300, 0.05, 12).to_csr();
    check_same_upper::<2>(&random2);
    check_same_upper::<2>(&thinned(&random2, 0.5));
}

#[test]
fn csr_solve_is_the_block_matrix_solve() {
    let csr = random_spd::<3>(3000, 0.005, 13).to_csr();
    let rhs: Vec<f64> = (0..csr.size).map(|i| (i as f64 * 0.37).cos()).collect();
    let matrix = BlockCsr::<3>::from_csr(&csr).unwrap();
    let mut jacobi = BlockJacobi::new(&matrix).unwrap();
    let mut pcg = Pcg::new();
    let mut expected = vec![0.0; csr.size];
    let status = pcg
        .solve(&matrix, &mut jacobi, &rhs, &mut expected, 1e-10, 1000)
        .unwrap();
    let (p, i) = (narrow(&csr.indptr), narrow(&csr.indices));
    let mut x = vec![0.0; csr.size];
    let direct = Pcg::<3>::new()
        .solve_csr_parts(csr.size, &p, &i, &csr.data, &rhs, &mut x, 1e-10, 1000)
        .unwrap();
    // The same iterations; the exact products (true residuals) of the block-matrix path
    // come from the full matrix where the upper triangle is held in float32 alone, so the
    // sums differ in their last bits.
    assert!(status.converged && direct.converged);
    assert_eq!(direct.iterations, status.iterations);
    let scale = expected.iter().map(|v| v.abs()).fold(0.0, f64::max);
    assert!(x
        .iter()
        .zip(&expected)
        .all(|(a, b)| (a - b).abs() <= 1e-12 * scale));
}

fn same_error<const B: usize>(csr: &Csr) {
    let full = BlockCsr::<B>::from_csr(csr).map(|_| ()).unwrap_err();
    let direct = Upper::<B>::from_csr_parts(csr.size, &csr.indptr, &csr.indices, &csr.data)
        .map(|_| ())
        .unwrap_err();
    assert_eq!(format!("{full:?}"), format!("{direct:?}"));
}

#[test]
fn csr_errors_are_the_block_matrix_errors() {
    let csr = |size, indptr: Vec<usize>, indices: Vec<usize>, data: Vec<f64>| Csr {
        size,
        indptr,
        indices,
        data,
    };
    same_error::<3>(&csr(4, vec![0, 1, 2, 3, 4], vec![0, 1, 2, 3], vec![1.0; 4]));
    same_error::<2>(&csr(
        4,
        vec![0, 2, 3, 4, 5],
        vec![0, 2, 1, 2, 3],
        vec![1.0; 5],
    ));
    same_error::<2>(&csr(2, vec![0, 2, 3], vec![1, 0, 1], vec![1.0; 3]));
    same_error::<2>(&csr(2, vec![0, 1, 2], vec![0, 1], vec![1.0, f64::NAN]));
    same_error::<2>(&csr(2, vec![0, 1, 2], vec![0, 5], vec![1.0, 1.0]));
    same_error::<2>(&csr(2, vec![0, 2, 1], vec![0, 1], vec![1.0, 1.0]));
    // Asymmetric and non-finite: non-finite is reported first by both.
    same_error::<2>(&csr(
        4,
        vec![0, 2, 3, 4, 5],
        vec![0, 2, 1, 2, 3],
        vec![1.0, 1.0, 1.0, f64::INFINITY, 1.0],
    ));
    // The lower triangle's values are checked too.
    let mut nan_lower = random_spd::<3>(50, 0.2, 14).to_csr();
    let at = nan_lower.indptr[100] + 1;
    nan_lower.data[at] = f64::NAN;
    same_error::<3>(&nan_lower);
    let negative: Vec<i32> = vec![0, -1];
    assert!(matches!(
        Pcg::<2>::new().solve_csr_parts(
            2,
            &[0, 1, 2],
            &negative,
            &[1.0, 1.0],
            &[1.0; 2],
            &mut [0.0; 2],
            1e-8,
            10
        ),
        Err(Error::SparsePattern { .. })
    ));
    let indefinite = csr(
        4,
        vec![0, 1, 2, 3, 4],
        vec![0, 1, 2, 3],
        vec![1.0, 1.0, -1.0, 1.0],
    );
    let failure = Pcg::<2>::new().solve_csr_parts(
        4,
        &indefinite.indptr,
        &indefinite.indices,
        &indefinite.data,
        &[1.0; 4],
        &mut [0.0; 4],
        1e-8,
        10,
    );
    assert!(
        matches!(failure, Err(Error::NotPositiveDefinite { row: 2, .. })),
        "{failure:?}"
    );
}

/// `||b - A x|| / ||b||` in float64 from the full matrix.
fn true_residual<const B: usize>(matrix: &BlockCsr<B>, rhs: &[f64], x: &[f64]) -> f64 {
    let mut ax = vec![0.0; rhs.len()];
    matrix.mul_into(x, &mut ax).unwrap();
    let r: f64 = rhs.iter().zip(&ax).map(|(b, a)| (b - a) * (b - a)).sum();
    (r / rhs.iter().map(|b| b * b).sum::<f64>()).sqrt()
}

#[test]
fn float32_products_reach_the_float64_tolerance() {
    // Beyond float32's own precision (~6e-8): the refinement cycles must get there.
    for tolerance in [1e-8, 1e-12] {
        let matrix = random_spd::<3>(3000, 0.005, 15);
        let rhs: Vec<f64> = (0..matrix.size())
            .map(|i| (i as f64 * 0.37).cos())
            .collect();
        let mut upper = Upper::<3>::default();
        upper.load(&matrix);
        if super::upper::avx2() {
            assert!(
                upper.inexact_inner(),
                "no float32 copy where the AVX2 kernel runs"
            );
        }
        let mut x = vec![0.0; matrix.size()];
        let mut jacobi = BlockJacobi::new(&matrix).unwrap();
        let status = Pcg::new()
            .solve(&matrix, &mut jacobi, &rhs, &mut x, tolerance, 1000)
            .unwrap();
        let residual = true_residual(&matrix, &rhs, &x);
        assert!(
            status.converged && residual <= tolerance,
            "{status:?}, true {residual:e}"
        );
        assert!((status.relative_residual - residual).abs() <= 1e-3 * residual);
    }
}

#[test]
fn float32_too_coarse_falls_back_to_float64() {
    // The EFG stiffness (six rigid modes) plus 1e-6 of its largest entry: condition ~1e7,
    // so the float32 copy's rounding (~6e-8 of the entries) is of the order of the smallest
    // eigenvalues. The solve must still reach the tolerance on the true residual.
    let (k, _, _) = efg_stiffness();
    let mut matrix = BlockCsr::<3>::from_csr(&k).unwrap();
    let shift = 1e-6 * k.data.iter().map(|v| v.abs()).fold(0.0, f64::max);
    for i in 0..matrix.len() {
        for a in 0..3 {
            matrix.diagonal_block_mut(i)[a][a] += shift;
        }
    }
    let rhs: Vec<f64> = (0..matrix.size())
        .map(|i| (i as f64 * 0.71).sin())
        .collect();
    let mut x = vec![0.0; matrix.size()];
    let mut jacobi = BlockJacobi::new(&matrix).unwrap();
    let status = Pcg::new()
        .solve(&matrix, &mut jacobi, &rhs, &mut x, 1e-8, 20_000)
        .unwrap();
    let residual = true_residual(&matrix, &rhs, &x);
    assert!(
        status.converged && residual <= 1e-8,
        "{status:?}, true {residual:e}"
    );
}

#[test]
fn symmetry_check_finds_the_first_asymmetric_row() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(16);
    for trial in 0..200 {
        let n = rng.random_range(1..30);
        // A symmetric pattern with the diagonal, then (in most trials) a few one-sided entries.
        let mut rows: Vec<Vec<u32>> = (0..n).map(|i| vec![i as u32]).collect();
        for i in 0..n {
            for j in 0..i {
                if rng.random_bool(0.2) {
                    rows[i].push(j as u32);
                    rows[j].push(i as u32);
                }
            }
        }
        for _ in 0..trial % 3 {
            let (i, j) = (rng.random_range(0..n), rng.random_range(0..n));
            rows[i].push(j as u32);
        }
        for row in &mut rows {
            row.sort_unstable();
            row.dedup();
        }
        let expected = (0..n).find(|&i| {
            rows[i]
                .iter()
                .any(|&j| !rows[j as usize].contains(&(i as u32)))
        });
        let got = super::block::asymmetric_row(n, |i| &rows[i]);
        assert_eq!(got, expected, "{rows:?}");
    }
}

#[test]
fn conjugate_gradient_csr_solves_with_each_preconditioner() {
    let matrix = random_spd::<3>(40, 0.2, 9);
    let csr = matrix.to_csr();
    let (p, i) = (narrow(&csr.indptr), narrow(&csr.indices));
    let parts = CsrParts {
        size: csr.size,
        indptr: &p,
        indices: &i,
        data: &csr.data,
    };
    let rhs: Vec<f64> = (0..csr.size).map(|r| (r as f64 * 0.37).sin()).collect();
    let nodes: Vec<[f64; 3]> = (0..40).map(|n| [n as f64, (n % 7) as f64, 0.5]).collect();
    let mut factor = SparseCholesky::<3>::from_csr_parts(&parts).unwrap();
    let exact = factor.solve(&rhs).unwrap();
    let choices = [
        CsrPreconditioner::BlockJacobi,
        CsrPreconditioner::TwoLevel(&nodes),
        CsrPreconditioner::Factor(&mut factor),
    ];
    for preconditioner in choices {
        let mut x = vec![0.0; csr.size];
        let status =
            conjugate_gradient_csr(&parts, &rhs, &mut x, 1e-12, 1000, preconditioner).unwrap();
        assert!(status.converged);
        let error = x
            .iter()
            .zip(&exact)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        let scale = exact.iter().map(|v| v.abs()).fold(0.0, f64::max);
        assert!(error <= 1e-9 * scale, "{error} vs {scale}");
    }
}

fn parts(c: &Csr) -> CsrParts<'_, usize> {
    CsrParts {
        size: c.size,
        indptr: &c.indptr,
        indices: &c.indices,
        data: &c.data,
    }
}

#[test]
fn factorize_csr_parts_refuses_another_pattern() {
    let first = random_spd::<2>(20, 0.3, 1).to_csr();
    let other = random_spd::<2>(20, 0.3, 2).to_csr();
    let mut factor = SparseCholesky::<2>::from_csr_parts(&parts(&first)).unwrap();
    assert!(matches!(
        factor.factorize_csr_parts(&parts(&other)),
        Err(Error::PatternMismatch { .. })
    ));
}
