//! The upper triangle read straight from scalar CSR arrays (`Pcg::solve_csr_parts`) against
//! the path through a full [`BlockCsr`]: the same blocks, the same errors, the same solution
//! to the bit.

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
    let mut reference = Upper::<B>::default();
    reference.load(&BlockCsr::<B>::from_csr(csr).unwrap());
    let direct =
        Upper::<B>::from_csr_parts(csr.size, &csr.indptr, &csr.indices, &csr.data).unwrap();
    let (p, i) = (narrow(&csr.indptr), narrow(&csr.indices));
    let narrow_direct = Upper::<B>::from_csr_parts(csr.size, &p, &i, &csr.data).unwrap();
    let expected = reference.parts();
    for upper in [&direct, &narrow_direct] {
        let got = upper.parts();
        assert_eq!(got.0, expected.0);
        assert_eq!(got.1, expected.1);
        assert_eq!(got.2, expected.2, "blocks differ");
        assert!(got.3, "a pad lane is not zero");
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
    assert!(status.converged);
    assert_eq!(direct, status);
    assert_eq!(x, expected);
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
