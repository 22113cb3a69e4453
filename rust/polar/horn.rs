//! The quaternion route to the nearest rotation: Horn's 4x4 matrix, its largest eigenvalue
//! by Halley's iteration on the characteristic quartic, and its eigenvector by inverse
//! iteration with a 4x4 $L D L^\top$ factor.

use super::Mat3;

/// Horn's matrix: $q^\top N q = \operatorname{tr}(R(q)^\top A)$ with $q = (w, x, y, z)$.
pub(super) fn horn_matrix(a: &Mat3) -> [[f64; 4]; 4] {
    let [a00, a01, a02, a10, a11, a12, a20, a21, a22] = *a;
    [
        [a00 + a11 + a22, a21 - a12, a02 - a20, a10 - a01],
        [a21 - a12, a00 - a11 - a22, a01 + a10, a02 + a20],
        [a02 - a20, a01 + a10, -a00 + a11 - a22, a12 + a21],
        [a10 - a01, a02 + a20, a12 + a21, -a00 - a11 + a22],
    ]
}

/// `a / |a|_F`, computed without overflow or underflow (through `a / max|a_ij|`), or `None`
/// for the zero matrix.
pub(super) fn unit_frobenius(a: &Mat3) -> Option<Mat3> {
    let largest = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if largest == 0.0 {
        return None;
    }
    // A reciprocal, not nine divisions; 1 / largest cannot overflow unless `largest` is
    // subnormal, where dividing is exact enough and rare.
    let b = if largest >= f64::MIN_POSITIVE {
        let inv = 1.0 / largest;
        a.map(|v| v * inv)
    } else {
        a.map(|v| v / largest)
    };
    let inv_norm = 1.0 / b.iter().map(|v| v * v).sum::<f64>().sqrt();
    Some(b.map(|v| v * inv_norm))
}

pub(super) fn det3(a: &Mat3) -> f64 {
    a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6])
        + a[2] * (a[3] * a[7] - a[4] * a[6])
}

pub(super) fn det4(n: &[[f64; 4]; 4]) -> f64 {
    // Laplace expansion by 2x2 minors of the first two rows.
    let s0 = n[0][0] * n[1][1] - n[1][0] * n[0][1];
    let s1 = n[0][0] * n[1][2] - n[1][0] * n[0][2];
    let s2 = n[0][0] * n[1][3] - n[1][0] * n[0][3];
    let s3 = n[0][1] * n[1][2] - n[1][1] * n[0][2];
    let s4 = n[0][1] * n[1][3] - n[1][1] * n[0][3];
    let s5 = n[0][2] * n[1][3] - n[1][2] * n[0][3];
    let c5 = n[2][2] * n[3][3] - n[3][2] * n[2][3];
    let c4 = n[2][1] * n[3][3] - n[3][1] * n[2][3];
    let c3 = n[2][1] * n[3][2] - n[3][1] * n[2][2];
    let c2 = n[2][0] * n[3][3] - n[3][0] * n[2][3];
    let c1 = n[2][0] * n[3][2] - n[3][0] * n[2][2];
    let c0 = n[2][0] * n[3][1] - n[3][0] * n[2][1];
    s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0
}

/// Largest eigenvalue of Horn's matrix of `a` (with $\|a\|_F = 1$).
///
/// $p(\lambda) = \det(N - \lambda I) = \lambda^4 - 2\|A\|_F^2 \lambda^2 - 8 \det(A) \lambda + \det N$.
/// Halley's iteration from the bound $\sqrt 3 \ge \sigma_1 + \sigma_2 + \sigma_3$ decreases
/// onto the largest root, as every root is real (about four steps, against seven for
/// Newton's). The inverse iteration that follows needs $\lambda$ to about $10^{-12}$ only.
pub(super) fn largest_horn_eigenvalue(a: &Mat3, n: &[[f64; 4]; 4]) -> (f64, f64) {
    let c2 = -2.0;
    let c1 = -8.0 * det3(a);
    let c0 = det4(n);
    let mut lambda = 3f64.sqrt();
    for _ in 0..100 {
        let l2 = lambda * lambda;
        let p = (l2 + c2) * l2 + c1 * lambda + c0;
        let dp = (4.0 * l2 + 2.0 * c2) * lambda + c1;
        if p <= 0.0 || dp <= 0.0 {
            break; // on (or, by rounding, just past) the root
        }
        let ddp = 12.0 * l2 + 2.0 * c2;
        let step = 2.0 * p * dp / (2.0 * dp * dp - p * ddp);
        if step.is_nan() || step <= 0.0 {
            break;
        }
        lambda -= step;
        if step <= 1e-13 {
            break;
        }
    }
    let slope = (4.0 * lambda * lambda + 2.0 * c2) * lambda + c1;
    (lambda, slope)
}

/// Below this slope $p'(\lambda_1) = \prod_{i > 1} (\lambda_1 - \lambda_i)$ the top eigenvalue
/// is nearly double ($\sigma_2 + \operatorname{sign}(\det A)\,\sigma_3 \approx 0$: nearly rank
/// one, or a reflection with equal small singular values): the quartic then fixes it only
/// to about $\sqrt{\varepsilon}$, too coarse for inverse iteration to separate the two top
/// eigenvectors, and the Jacobi method takes over.
pub(super) const NEARLY_DOUBLE: f64 = 1e-3;

/// Solves $B y = b$ for the 4x4 symmetric positive definite $B$ by $L D L^\top$,
/// flooring pivots at `floor` (B is nearly singular on purpose: inverse iteration).
pub(super) struct Ldlt4 {
    l: [[f64; 4]; 4],
    inv_d: [f64; 4],
}

impl Ldlt4 {
    pub(super) fn new(b: &[[f64; 4]; 4], floor: f64) -> Self {
        let mut l = [[0.0; 4]; 4];
        let mut d = [0.0; 4];
        let mut inv_d = [0.0; 4];
        for j in 0..4 {
            let mut dj = b[j][j];
            for k in 0..j {
                dj -= l[j][k] * l[j][k] * d[k];
            }
            d[j] = dj.max(floor);
            inv_d[j] = 1.0 / d[j];
            l[j][j] = 1.0;
            for i in j + 1..4 {
                let mut v = b[i][j];
                for k in 0..j {
                    v -= l[i][k] * l[j][k] * d[k];
                }
                l[i][j] = v * inv_d[j];
            }
        }
        Ldlt4 { l, inv_d }
    }

    pub(super) fn solve(&self, b: [f64; 4]) -> [f64; 4] {
        let mut y = b;
        for i in 0..4 {
            for k in 0..i {
                y[i] -= self.l[i][k] * y[k];
            }
        }
        for (yi, inv) in y.iter_mut().zip(self.inv_d) {
            *yi *= inv;
        }
        for i in (0..4).rev() {
            for k in i + 1..4 {
                y[i] -= self.l[k][i] * y[k];
            }
        }
        y
    }
}

pub(super) fn normalized(v: [f64; 4]) -> [f64; 4] {
    let s = 1.0 / (v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3]).sqrt();
    v.map(|x| x * s)
}

pub(super) fn quaternion_to_matrix(q: &[f64; 4]) -> Mat3 {
    let [w, x, y, z] = *q;
    [
        w * w + x * x - y * y - z * z,
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        w * w - x * x + y * y - z * z,
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        w * w - x * x - y * y + z * z,
    ]
}

/// The rotation of the top eigenvector of `n` by two steps of inverse iteration on
/// $B = (\lambda + \delta) I - N$.
///
/// `lambda` approaches $\lambda_1$ from above but may undershoot it by the rounding of the
/// quartic, about $10^{-14} / p'(\lambda_1)$: the shift $\delta$ covers that, so $B$ stays
/// positive definite with smallest eigenvalue $\mu_1 \le \mu_{max} = 10^{-13} + 2 \cdot
/// 10^{-14} / p'$, small against the gap $\ge p'(\lambda_1) / 8$.
///
/// A basis vector $e_j$ is a good start when its component $|v_{1j}|$ along the top
/// eigenvector is not small; one always has $|v_{1j}| \ge 1/2$. The first step tells:
/// $\|B^{-1} e_j\| \ge |v_{1j}| / \mu_{max}$, while the other eigenvectors contribute at
/// most $8 / p'$. Starts are tried by decreasing diagonal of $N$ (usually the first is
/// accepted) until one has $|v_{1j}| \gtrsim 0.1$.
#[inline(always)]
pub(super) fn rotation_by_inverse_iteration(n: &[[f64; 4]; 4], lambda: f64, slope: f64) -> Mat3 {
    let delta = 1e-13 + 1e-14 / slope;
    let mu_max = 1e-13 + 2e-14 / slope;
    let mut b = n.map(|row| row.map(|v| -v));
    for (i, row) in b.iter_mut().enumerate() {
        row[i] += lambda + delta;
    }
    let factor = Ldlt4::new(&b, delta * 1e-3);
    let norm2 = |y: &[f64; 4]| y.iter().map(|v| v * v).sum::<f64>();
    let mut order = [0usize, 1, 2, 3];
    order.swap(0, largest_diagonal(n));
    let mut first = [0.0; 4];
    for &j in &order {
        let y = factor.solve(std::array::from_fn(|i| (i == j) as u8 as f64));
        if norm2(&y) > norm2(&first) {
            first = y;
        }
        if norm2(&first) * mu_max * mu_max >= 0.01 {
            break;
        }
    }
    // Each solve scales by at most 1 / delta <= 1e13: two stay far from overflow.
    quaternion_to_matrix(&normalized(factor.solve(first)))
}

fn largest_diagonal(n: &[[f64; 4]; 4]) -> usize {
    (1..4).fold(0, |j, i| if n[i][i] > n[j][j] { i } else { j })
}
