//! The cyclic Jacobi eigenvalue method on symmetric 4x4 matrices: the robust fallback of
//! the quaternion route when the top eigenvalue is nearly double.

use super::horn::normalized;

/// Eigenvector of the largest eigenvalue of a symmetric 4x4 matrix by the cyclic Jacobi
/// method: slower than the quartic route but backward stable whatever the eigenvalue gaps.
pub(super) fn top_eigenvector_jacobi(n: &[[f64; 4]; 4]) -> [f64; 4] {
    let mut a = *n;
    let mut v = [[0.0; 4]; 4];
    for (i, row) in v.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    let scale: f64 = n.iter().flatten().map(|x| x * x).sum();
    for _ in 0..64 {
        let off: f64 = (0..4)
            .flat_map(|p| (p + 1..4).map(move |q| (p, q)))
            .map(|(p, q)| a[p][q] * a[p][q])
            .sum();
        if off <= 1e-34 * scale {
            break;
        }
        for p in 0..3 {
            for q in p + 1..4 {
                if a[p][q] == 0.0 {
                    continue;
                }
                let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
                let t = if theta.abs() > 1e150 {
                    0.5 / theta
                } else {
                    theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
                };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for row in a.iter_mut() {
                    let (x, y) = (row[p], row[q]);
                    row[p] = c * x - s * y;
                    row[q] = s * x + c * y;
                }
                let (row_p, row_q) = (a[p], a[q]);
                for k in 0..4 {
                    a[p][k] = c * row_p[k] - s * row_q[k];
                    a[q][k] = s * row_p[k] + c * row_q[k];
                }
                for row in v.iter_mut() {
                    let (x, y) = (row[p], row[q]);
                    row[p] = c * x - s * y;
                    row[q] = s * x + c * y;
                }
            }
        }
    }
    let top = (1..4).fold(0, |j, i| if a[i][i] > a[j][j] { i } else { j });
    normalized(std::array::from_fn(|i| v[i][top]))
}
