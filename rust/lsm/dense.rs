//! Small dense systems (8 unknowns, 16 for the richer model): Cholesky of symmetric positive definite ones,
//! solves and inverses, and a general inverse, on fixed-size arrays, so an iteration
//! allocates nothing.

/// Largest system handled.
pub(crate) const MAX: usize = 8;

/// A symmetric positive definite matrix of order `m <= N` factorised as `L L^T` (`N` is
/// `MAX` for a match's unknowns, more for the richer model's, `rich`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Cholesky<const N: usize> {
    l: [[f64; N]; N],
    m: usize,
}

impl<const N: usize> Cholesky<N> {
    /// Factorises the leading `m x m` block of `a`; `None` when a pivot is not positive
    /// relative to the diagonal (numerically singular: `pivot <= 1e-12 * a_ii`).
    pub fn new(a: &[[f64; N]; N], m: usize) -> Option<Self> {
        let mut l = [[0.0; N]; N];
        for j in 0..m {
            let mut d = a[j][j];
            for k in 0..j {
                d -= l[j][k] * l[j][k];
            }
            // Written so that NaN fails too.
            if !(d > 1e-12 * a[j][j].abs()) || !d.is_finite() {
                return None;
            }
            let d = d.sqrt();
            l[j][j] = d;
            for i in j + 1..m {
                let mut s = a[i][j];
                for k in 0..j {
                    s -= l[i][k] * l[j][k];
                }
                l[i][j] = s / d;
            }
        }
        Some(Self { l, m })
    }

    /// `A^-1 b` for the first `m` entries of `b`.
    pub fn solve(&self, b: &[f64; N]) -> [f64; N] {
        let (l, m) = (&self.l, self.m);
        let mut x = *b;
        for i in 0..m {
            let mut s = x[i];
            for k in 0..i {
                s -= l[i][k] * x[k];
            }
            x[i] = s / l[i][i];
        }
        for i in (0..m).rev() {
            let mut s = x[i];
            for k in i + 1..m {
                s -= l[k][i] * x[k];
            }
            x[i] = s / l[i][i];
        }
        x
    }

    /// `A^-1` (the leading `m x m` block; the rest zero).
    ///
    /// The solves of `A x = e_j` for every column `j` at once: row `i` of all the columns
    /// in one pass (a loop over the columns, which vectorises), where a solve per column
    /// ran `2 m` dependent divisions one column after the other. Each column sees the
    /// operations of [`Self::solve`] in the same order, so every entry has the same bits
    /// (the columns past `m`, solved from zeros, stay `+0`: `0 - l 0` and `0 / l` with the
    /// positive, finite pivots of a factor are `+0`).
    pub fn inverse(&self) -> [[f64; N]; N] {
        let (l, m) = (&self.l, self.m);
        // x[i][j]: entry i of column j, from the identity's columns.
        let mut x = [[0.0; N]; N];
        for (i, row) in x.iter_mut().enumerate().take(m) {
            row[i] = 1.0;
        }
        for i in 0..m {
            let mut s = x[i];
            for k in 0..i {
                let (lik, xk) = (l[i][k], &x[k]);
                for (s, &v) in s.iter_mut().zip(xk) {
                    *s -= lik * v;
                }
            }
            let d = l[i][i];
            for (out, &s) in x[i].iter_mut().zip(&s) {
                *out = s / d;
            }
        }
        for i in (0..m).rev() {
            let mut s = x[i];
            for k in i + 1..m {
                let (lki, xk) = (l[k][i], &x[k]);
                for (s, &v) in s.iter_mut().zip(xk) {
                    *s -= lki * v;
                }
            }
            let d = l[i][i];
            for (out, &s) in x[i].iter_mut().zip(&s) {
                *out = s / d;
            }
        }
        x
    }

    /// [`Self::inverse`] one column's solve after the other (what it ran before; the
    /// tests' reference).
    #[cfg(test)]
    pub fn inverse_by_columns(&self) -> [[f64; N]; N] {
        let mut inv = [[0.0; N]; N];
        for j in 0..self.m {
            let mut e = [0.0; N];
            e[j] = 1.0;
            let column = self.solve(&e);
            for i in 0..self.m {
                inv[i][j] = column[i];
            }
        }
        inv
    }
}

/// The inverse of a general (not symmetric) 8x8 matrix by Gauss-Jordan elimination with
/// partial pivoting; `None` when a pivot is below `1e-12` of its column's largest entry
/// (numerically singular) or not finite.
pub(crate) fn general_inverse(a: &[[f64; MAX]; MAX]) -> Option<[[f64; MAX]; MAX]> {
    let mut m = *a;
    let mut inv = [[0.0; MAX]; MAX];
    for (i, row) in inv.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    let scale: [f64; MAX] =
        std::array::from_fn(|j| (0..MAX).map(|i| a[i][j].abs()).fold(0.0, f64::max));
    for j in 0..MAX {
        let p = (j..MAX)
            .max_by(|&x, &y| m[x][j].abs().total_cmp(&m[y][j].abs()))
            .unwrap_or(j);
        // Written so that NaN fails too.
        if !(m[p][j].abs() > 1e-12 * scale[j]) || !m[p][j].is_finite() {
            return None;
        }
        m.swap(j, p);
        inv.swap(j, p);
        let d = 1.0 / m[j][j];
        for k in 0..MAX {
            m[j][k] *= d;
            inv[j][k] *= d;
        }
        for i in 0..MAX {
            if i != j {
                let f = m[i][j];
                if f != 0.0 {
                    for k in 0..MAX {
                        m[i][k] -= f * m[j][k];
                        inv[i][k] -= f * inv[j][k];
                    }
                }
            }
        }
    }
    Some(inv)
}

/// `a b` for 8x8 matrices.
pub(crate) fn product(a: &[[f64; MAX]; MAX], b: &[[f64; MAX]; MAX]) -> [[f64; MAX]; MAX] {
    let mut c = [[0.0; MAX]; MAX];
    for i in 0..MAX {
        for k in 0..MAX {
            let aik = a[i][k];
            if aik != 0.0 {
                for j in 0..MAX {
                    c[i][j] += aik * b[k][j];
                }
            }
        }
    }
    c
}

/// `a b^T` for 8x8 matrices.
pub(crate) fn product_transposed(
    a: &[[f64; MAX]; MAX],
    b: &[[f64; MAX]; MAX],
) -> [[f64; MAX]; MAX] {
    let mut c = [[0.0; MAX]; MAX];
    for i in 0..MAX {
        for j in 0..MAX {
            c[i][j] = (0..MAX).map(|k| a[i][k] * b[j][k]).sum();
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_and_inverts_a_spd_matrix() {
        let mut a = [[0.0; MAX]; MAX];
        for i in 0..MAX {
            for j in 0..MAX {
                a[i][j] = 1.0 / (1.0 + i as f64 + j as f64) + if i == j { 1.0 } else { 0.0 };
            }
        }
        let chol = Cholesky::new(&a, MAX).unwrap();
        let inv = chol.inverse();
        let identity = product(&a, &inv);
        for i in 0..MAX {
            for j in 0..MAX {
                let expected = if i == j { 1.0 } else { 0.0 };
                assert!((identity[i][j] - expected).abs() < 1e-12);
            }
        }
        let mut singular = a;
        singular[3] = singular[2];
        for row in singular.iter_mut() {
            row[3] = row[2];
        }
        assert!(Cholesky::new(&singular, MAX).is_none());
        let nan = [[f64::NAN; MAX]; MAX];
        assert!(Cholesky::new(&nan, MAX).is_none());
    }

    #[test]
    fn inverse_of_all_columns_at_once_equals_the_column_solves_to_the_bit() {
        // Random SPD matrices (B B^T + small diagonal) over several magnitudes, every order
        // 1-8 of the 8-wide factor (the match's 6 and 8 among them) and the richer model's
        // 16-wide one; the unused columns must stay +0 as before.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(59);
        fn check<const N: usize>(rng: &mut rand_chacha::ChaCha8Rng, m: usize) {
            let scale = 10f64.powi(rng.random_range(-6..7));
            let b: Vec<f64> = (0..m * m)
                .map(|_| rng.random_range(-1.0..1.0) * scale)
                .collect();
            let mut a = [[0.0; N]; N];
            for i in 0..m {
                for j in 0..m {
                    a[i][j] = (0..m).map(|k| b[i * m + k] * b[j * m + k]).sum::<f64>()
                        + if i == j { 1e-3 * scale * scale } else { 0.0 };
                }
            }
            let chol = Cholesky::new(&a, m).expect("positive definite");
            let (got, want) = (chol.inverse(), chol.inverse_by_columns());
            for i in 0..N {
                for j in 0..N {
                    assert_eq!(
                        got[i][j].to_bits(),
                        want[i][j].to_bits(),
                        "m {m} ({i}, {j})"
                    );
                }
            }
        }
        for _ in 0..200 {
            for m in 1..=MAX {
                check::<MAX>(&mut rng, m);
            }
            let m = rng.random_range(9..=16);
            check::<16>(&mut rng, m);
        }
    }

    #[test]
    fn inverts_a_general_matrix() {
        let mut a = [[0.0; MAX]; MAX];
        for i in 0..MAX {
            for j in 0..MAX {
                // Not symmetric, and a zero on the diagonal so that pivoting is needed.
                a[i][j] = ((3 * i + 7 * j) % 11) as f64 - 5.0 + if i == j { 0.5 } else { 0.0 };
            }
        }
        a[0][0] = 0.0;
        let inv = general_inverse(&a).unwrap();
        for (product, order) in [(product(&a, &inv), "a a^-1"), (product(&inv, &a), "a^-1 a")] {
            for i in 0..MAX {
                for j in 0..MAX {
                    let expected = if i == j { 1.0 } else { 0.0 };
                    assert!((product[i][j] - expected).abs() < 1e-10, "{order}");
                }
            }
        }
        let mut singular = a;
        singular[5] = singular[1];
        assert!(general_inverse(&singular).is_none());
        assert!(general_inverse(&[[f64::NAN; MAX]; MAX]).is_none());
    }
}
