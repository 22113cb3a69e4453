//! Tests of [`crate::mls`].

use super::*;
use crate::SpatialHash;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The SPEC 4.2 identities hold to this, with gradients made dimensionless by the support.
const IDENTITY_ATOL: f64 = 1e-10;

/// Neighbours as `elastocap.mls_shape_functions` builds them: the node, then its k - 1
/// nearest; support 1.1 times the farthest.
fn neighbourhoods<const D: usize>(points: &[[f64; D]], k: usize) -> (Vec<u32>, Vec<f64>) {
    let knn = SpatialHash::new(points).unwrap().knn(None, k - 1).unwrap();
    let mut neighbors = Vec::with_capacity(points.len() * k);
    let mut support = Vec::with_capacity(points.len());
    for p in 0..points.len() {
        neighbors.push(p as u32);
        neighbors.extend(
            knn.indices[p * (k - 1)..(p + 1) * (k - 1)]
                .iter()
                .map(|&i| i as u32),
        );
        support.push(1.1 * knn.distances[(p + 1) * (k - 1) - 1]);
    }
    (neighbors, support)
}

fn random_cloud<const D: usize>(seed: u64, n: usize, stretch: [f64; D]) -> Vec<[f64; D]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| std::array::from_fn(|a| stretch[a] * rng.random_range(0.0..1.0)))
        .collect()
}

fn grid_cloud<const D: usize>(side: usize) -> Vec<[f64; D]> {
    (0..side.pow(D as u32))
        .map(|mut c| {
            std::array::from_fn(|_| {
                let v = (c % side) as f64 / side as f64;
                c /= side;
                v
            })
        })
        .collect()
}

/// Largest violation of the four identities over all nodes.
fn identity_error<const D: usize>(
    points: &[[f64; D]],
    neighbors: &[u32],
    s: &ShapeFunctions<D>,
) -> f64 {
    let k = s.k;
    let mut worst = 0.0f64;
    for p in 0..points.len() {
        let mut sum_phi = 0.0;
        let mut sum_phi_x = [0.0; D];
        let mut sum_grad = [0.0; D];
        let mut sum_grad_x = [[0.0; D]; D];
        for c in 0..k {
            let i = neighbors[p * k + c] as usize;
            let (phi, grad) = (s.phi[p * k + c], s.grad[p * k + c]);
            sum_phi += phi;
            for a in 0..D {
                sum_phi_x[a] += phi * points[i][a];
                sum_grad[a] += grad[a] * s.support[p];
                for b in 0..D {
                    sum_grad_x[a][b] += grad[a] * points[i][b];
                }
            }
        }
        worst = worst.max((sum_phi - 1.0).abs());
        for a in 0..D {
            worst = worst.max((sum_phi_x[a] - points[p][a]).abs());
            worst = worst.max(sum_grad[a].abs());
            for (b, &value) in sum_grad_x[a].iter().enumerate() {
                let identity = if a == b { 1.0 } else { 0.0 };
                worst = worst.max((value - identity).abs());
            }
        }
    }
    worst
}

/// Estimated reciprocal condition number of node `p`'s moment matrix at support `ddm`.
fn rcond_at<const D: usize, const M: usize>(
    points: &[[f64; D]],
    row: &[u32],
    p: usize,
    ddm: f64,
) -> f64 {
    let mut a = SMatrix::<f64, M, M>::zeros();
    for &i in row {
        let offset = std::array::from_fn(|c| points[i as usize][c] - points[p][c]);
        let (basis, w, _) = basis_and_weight::<D, M>(offset, ddm);
        a += basis * basis.transpose() * w;
    }
    Moments::factor(&a).1
}

/// Smallest [`rcond_at`] over all nodes.
fn smallest_rcond<const D: usize, const M: usize>(
    points: &[[f64; D]],
    neighbors: &[u32],
    k: usize,
    support: &[f64],
) -> f64 {
    (0..points.len())
        .map(|p| rcond_at::<D, M>(points, &neighbors[p * k..(p + 1) * k], p, support[p]))
        .fold(f64::INFINITY, f64::min)
}

fn check_cloud<const D: usize, const M: usize>(points: &[[f64; D]], k: usize) {
    let (neighbors, support) = neighbourhoods(points, k);
    let s = shape_functions::<D, M>(points, &neighbors, k, &support).unwrap();
    assert_eq!(s.repaired, 0, "a well-sampled cloud needs no repair");
    assert_eq!(s.support, support);
    let error = identity_error(points, &neighbors, &s);
    assert!(error < IDENTITY_ATOL, "identities violated by {error:e}");
    // Every neighbour inside c * r_k carries weight.
    for p in 0..points.len() {
        for &i in &neighbors[p * k..(p + 1) * k] {
            let offset = std::array::from_fn(|c| points[i as usize][c] - points[p][c]);
            let (_, w, _) = basis_and_weight::<D, M>(offset, support[p]);
            assert!(w > 0.0, "neighbour {i} of node {p} has zero weight");
        }
    }
    // Well-sampled neighbourhoods, boundary nodes included, sit far above the threshold.
    let rcond = smallest_rcond::<D, M>(points, &neighbors, k, &support);
    assert!(rcond > 10.0 * RCOND_MIN, "smallest rcond {rcond:e}");
}

#[test]
fn spline_is_continuous_with_its_derivative() {
    for r in [0.5, 1.0] {
        let (below, above) = (cubic_spline(r - 1e-12), cubic_spline(r + 1e-12));
        assert!((below.0 - above.0).abs() < 1e-10 && (below.1 - above.1).abs() < 1e-10);
    }
    for r in [0.1, 0.3, 0.6, 0.9] {
        let h = 1e-6;
        let fd = (cubic_spline(r + h).0 - cubic_spline(r - h).0) / (2.0 * h);
        assert!((fd - cubic_spline(r).1).abs() < 1e-8);
    }
    assert_eq!(cubic_spline(1.5), (0.0, 0.0));
}

#[test]
fn identities_on_random_clouds() {
    for seed in 0..3 {
        check_cloud::<2, 3>(&random_cloud(seed, 400, [1.0, 1.0]), 12);
        check_cloud::<3, 4>(&random_cloud(seed, 800, [1.0, 1.0, 1.0]), 20);
    }
}

#[test]
fn identities_on_regular_grids() {
    check_cloud::<2, 3>(&grid_cloud(15), 9);
    check_cloud::<2, 3>(&grid_cloud(15), 12);
    check_cloud::<3, 4>(&grid_cloud(8), 20);
    check_cloud::<3, 4>(&grid_cloud(8), 27);
}

#[test]
fn identities_on_anisotropic_clouds() {
    for seed in 10..13 {
        check_cloud::<2, 3>(&random_cloud(seed, 400, [10.0, 1.0]), 12);
        check_cloud::<3, 4>(&random_cloud(seed, 800, [1.0, 10.0, 1.0]), 20);
    }
}

/// A 3x3 patch in the plane z = 0 and two points above and below it at height `h`; every
/// node lists all 11 points, with support 1.1 times the in-plane half-diagonal.
fn patch_with_poles(h: f64) -> (Vec<[f64; 3]>, Vec<u32>, Vec<f64>) {
    let mut points: Vec<[f64; 3]> = (0..9)
        .map(|c| [(c % 3) as f64 - 1.0, (c / 3) as f64 - 1.0, 0.0])
        .collect();
    points.swap(0, 4); // node 0 at the centre
    points.extend([[0.0, 0.0, h], [0.0, 0.0, -h]]);
    let n = points.len();
    let neighbors = (0..n).flat_map(|_| 0..n as u32).collect();
    (points, neighbors, vec![1.1 * 2f64.sqrt(); n])
}

#[test]
fn coplanar_neighbourhood_is_repaired_when_enlarging_reaches_off_plane_points() {
    // The poles at z = +-2 lie beyond the centre's support (r_z = 1.29), so its weighted
    // neighbours are coplanar; two enlargements (r_z = 0.82) bring them in.
    let (points, neighbors, support) = patch_with_poles(2.0);
    let rcond = rcond_at::<3, 4>(&points, &neighbors[..11], 0, support[0]);
    assert!(
        rcond < 1e-12,
        "the centre's weighted neighbourhood is coplanar: {rcond:e}"
    );
    let s = shape_functions::<3, 4>(&points, &neighbors, 11, &support).unwrap();
    assert!(s.repaired >= 1);
    assert!((s.support[0] - support[0] * ENLARGEMENT * ENLARGEMENT).abs() < 1e-12);
    assert!(
        s.phi[9] > 0.0 && s.phi[10] > 0.0,
        "the poles now carry weight"
    );
    let error = identity_error(&points, &neighbors, &s);
    assert!(error < IDENTITY_ATOL, "identities violated by {error:e}");
}

#[test]
fn coplanar_cloud_is_an_error_naming_the_node() {
    let (points, neighbors, support) = patch_with_poles(0.0);
    let err = shape_functions::<3, 4>(&points, &neighbors, 11, &support).unwrap_err();
    match err {
        Error::IllConditioned {
            node,
            rcond,
            support: last,
        } => {
            assert_eq!(node, 0);
            assert!(rcond < RCOND_MIN);
            assert!((last - support[0] * ENLARGEMENT.powi(MAX_ENLARGEMENTS as i32)).abs() < 1e-12);
        }
        other => panic!("expected IllConditioned, got {other:?}"),
    }
    // Collinear in 2-D likewise.
    let line: Vec<[f64; 2]> = (0..6).map(|i| [i as f64, 2.0 * i as f64]).collect();
    let neighbors: Vec<u32> = (0..6).flat_map(|_| 0..6u32).collect();
    let err = shape_functions::<2, 3>(&line, &neighbors, 6, &[10.0; 6]).unwrap_err();
    assert!(matches!(err, Error::IllConditioned { node: 0, .. }));
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let points = grid_cloud::<2>(4);
    let (neighbors, support) = neighbourhoods(&points, 5);
    let run = |pts: &[[f64; 2]], nb: &[u32], k: usize, s: &[f64]| {
        shape_functions::<2, 3>(pts, nb, k, s).unwrap_err()
    };
    assert!(matches!(
        run(&points, &neighbors[..32], 2, &support),
        Error::NotEnoughNeighbours {
            found: 2,
            needed: 3
        }
    ));
    assert!(matches!(
        run(&points, &neighbors[..75], 5, &support),
        Error::LengthMismatch {
            argument: "neighbors",
            ..
        }
    ));
    assert!(matches!(
        run(&points, &neighbors, 5, &support[1..]),
        Error::LengthMismatch {
            argument: "support",
            ..
        }
    ));
    let mut bad = neighbors.clone();
    bad[7] = 16;
    assert!(matches!(
        run(&points, &bad, 5, &support),
        Error::NeighborIndex {
            row: 1,
            column: 2,
            index: 16,
            n: 16
        }
    ));
    let mut bad = neighbors.clone();
    bad[5] = 0; // row 1 without node 1
    assert!(matches!(
        run(&points, &bad, 5, &support),
        Error::SelfNotNeighbour { node: 1 }
    ));
    let mut bad = support.clone();
    bad[3] = 0.0;
    assert!(matches!(
        run(&points, &neighbors, 5, &bad),
        Error::InvalidSupport { node: 3, .. }
    ));
    bad[3] = f64::NAN;
    assert!(matches!(
        run(&points, &neighbors, 5, &bad),
        Error::InvalidSupport { node: 3, .. }
    ));
    let mut bad = points.clone();
    bad[2][1] = f64::INFINITY;
    assert!(matches!(
        run(&bad, &neighbors, 5, &support),
        Error::NonFinite {
            argument: "points",
            row: 2
        }
    ));
    assert!(matches!(run(&[], &[], 5, &[]), Error::Empty { .. }));
    let mut phi = vec![0.0; 3];
    let err =
        shape_functions_into::<2, 3>(&points, &neighbors, 5, &support, &mut phi, &mut [], &mut [])
            .unwrap_err();
    assert!(matches!(err, Error::OutputSize { .. }));
}
