//! The core's one vocabulary of small fixed-size linear algebra: `D`-vectors as `[f64; D]`
//! and row-major `D x D` matrices as `[[f64; D]; D]` (the blocks of the block-sparse
//! matrices), for `D` = 2, 3 (and any other size the const generics allow).
//!
//! Plain arrays rather than nalgebra's `SVector` / `SMatrix`: they are the storage of every
//! block matrix, position list and kernel lane in the core (and of the numpy buffers), so no
//! conversion is needed at any call site; and every function sums in index order, so a
//! result is bitwise the same wherever the function is called (the fits' outputs did not
//! change when the five hand-written helper sets were replaced by this module). nalgebra
//! stays where a decomposition is needed (MLS moment Cholesky, the body model's rotations).

/// A `D`-vector.
pub type Vector<const D: usize> = [f64; D];

/// A row-major `D x D` matrix: `m[row][column]`.
pub type Matrix<const D: usize> = [[f64; D]; D];

/// The identity matrix.
#[inline]
pub fn identity<const D: usize>() -> Matrix<D> {
    std::array::from_fn(|r| std::array::from_fn(|c| if r == c { 1.0 } else { 0.0 }))
}

/// $a \cdot b$, summed in index order.
#[inline]
pub fn dot<const D: usize>(a: &Vector<D>, b: &Vector<D>) -> f64 {
    (0..D).map(|i| a[i] * b[i]).sum()
}

/// $a - b$.
#[inline]
pub fn sub<const D: usize>(a: &Vector<D>, b: &Vector<D>) -> Vector<D> {
    std::array::from_fn(|i| a[i] - b[i])
}

/// $a \times b$.
#[inline]
pub fn cross(a: &Vector<3>, b: &Vector<3>) -> Vector<3> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// $|a - b|^2$.
#[inline]
pub fn distance2<const D: usize>(a: &Vector<D>, b: &Vector<D>) -> f64 {
    let d = sub(a, b);
    dot(&d, &d)
}

/// $|a - b|$.
#[inline]
pub fn distance<const D: usize>(a: &Vector<D>, b: &Vector<D>) -> f64 {
    distance2(a, b).sqrt()
}

/// `v / |v|`, or zero for a zero vector.
#[inline]
pub fn unit<const D: usize>(v: &Vector<D>) -> Vector<D> {
    let norm = dot(v, v).sqrt();
    if norm > 0.0 {
        v.map(|x| x / norm)
    } else {
        [0.0; D]
    }
}

/// $M v$.
#[inline]
pub fn mat_vec<const D: usize>(m: &Matrix<D>, v: &Vector<D>) -> Vector<D> {
    std::array::from_fn(|r| dot(&m[r], v))
}

/// $A B$.
#[inline]
pub fn mat_mul<const D: usize>(a: &Matrix<D>, b: &Matrix<D>) -> Matrix<D> {
    std::array::from_fn(|r| std::array::from_fn(|c| (0..D).map(|t| a[r][t] * b[t][c]).sum()))
}

/// $A^\top$.
#[inline]
pub fn transpose<const D: usize>(a: &Matrix<D>) -> Matrix<D> {
    std::array::from_fn(|r| std::array::from_fn(|c| a[c][r]))
}

/// $A - B$.
#[inline]
pub fn mat_sub<const D: usize>(a: &Matrix<D>, b: &Matrix<D>) -> Matrix<D> {
    std::array::from_fn(|r| std::array::from_fn(|c| a[r][c] - b[r][c]))
}

/// $A \mathrel{+}= s B$.
#[inline]
pub fn add_scaled<const D: usize>(a: &mut Matrix<D>, b: &Matrix<D>, s: f64) {
    for (row, other) in a.iter_mut().zip(b) {
        for (value, x) in row.iter_mut().zip(other) {
            *value += s * x;
        }
    }
}

/// $v^\top M v$.
#[inline]
pub fn quadratic_form<const D: usize>(m: &Matrix<D>, v: &Vector<D>) -> f64 {
    dot(v, &mat_vec(m, v))
}

/// The inverse of a symmetric positive definite matrix by Cholesky,
/// $M^{-1} = L^{-\top} L^{-1}$; `Err(pivot)` at the first pivot that is not positive
/// (relative to the matrix's own scale: a pivot lost to rounding is not) or not finite.
#[inline]
pub fn spd_inverse<const D: usize>(m: &Matrix<D>) -> Result<Matrix<D>, usize> {
    let mut l = [[0.0; D]; D];
    for j in 0..D {
        let d = m[j][j] - (0..j).map(|t| l[j][t] * l[j][t]).sum::<f64>();
        if d.is_nan() || d <= 1e-14 * m[j][j].abs() || d.is_infinite() {
            return Err(j);
        }
        l[j][j] = d.sqrt();
        for i in j + 1..D {
            l[i][j] = (m[i][j] - (0..j).map(|t| l[i][t] * l[j][t]).sum::<f64>()) / l[j][j];
        }
    }
    // L^{-1}, lower triangular, by forward substitution on the identity.
    let mut inv_l = [[0.0; D]; D];
    for i in 0..D {
        let mut row = [0.0; D];
        for (c, value) in row.iter_mut().enumerate().take(i + 1) {
            let identity = if i == c { 1.0 } else { 0.0 };
            *value = (identity - (c..i).map(|t| l[i][t] * inv_l[t][c]).sum::<f64>()) / l[i][i];
        }
        inv_l[i] = row;
    }
    let mut inverse = [[0.0; D]; D];
    for a in 0..D {
        for b in 0..D {
            inverse[a][b] = (a.max(b)..D).map(|t| inv_l[t][a] * inv_l[t][b]).sum();
        }
    }
    Ok(inverse)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn products_agree_with_nalgebra() {
        let a = [[2.0, -1.0, 0.5], [0.3, 4.0, -2.0], [1.5, 0.0, 3.0]];
        let b = [[1.0, 2.0, -0.5], [0.0, -1.0, 2.5], [3.0, 0.25, 1.0]];
        let v = [0.7, -1.3, 2.0];
        let na = |m: &Matrix<3>| nalgebra::Matrix3::from_fn(|r, c| m[r][c]);
        let nv = nalgebra::Vector3::from(v);
        let ab = na(&a) * na(&b);
        let av = na(&a) * nv;
        let m = mat_mul(&a, &b);
        let mv = mat_vec(&a, &v);
        for r in 0..3 {
            assert!((mv[r] - av[r]).abs() < 1e-14);
            for c in 0..3 {
                assert!((m[r][c] - ab[(r, c)]).abs() < 1e-14);
                assert_eq!(transpose(&a)[r][c], a[c][r]);
            }
        }
        let w = [1.0, 0.5, -2.0];
        let x = cross(&v, &w);
        let nx = nv.cross(&nalgebra::Vector3::from(w));
        assert!((0..3).all(|i| (x[i] - nx[i]).abs() < 1e-14));
        assert!((quadratic_form(&a, &v) - nv.dot(&(na(&a) * nv))).abs() < 1e-13);
        assert!((distance(&v, &w) - (nv - nalgebra::Vector3::from(w)).norm()).abs() < 1e-14);
        assert_eq!(unit(&[0.0; 3]), [0.0; 3]);
        assert!((dot(&unit(&v), &unit(&v)) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn spd_inverse_inverts_and_names_the_failing_pivot() {
        let m = [[4.0, 1.0, 0.5], [1.0, 3.0, -0.2], [0.5, -0.2, 2.0]];
        let inv = spd_inverse(&m).unwrap();
        let p = mat_mul(&m, &inv);
        let eye = identity::<3>();
        for (row, eye_row) in p.iter().zip(&eye) {
            for (value, expected) in row.iter().zip(eye_row) {
                assert!((value - expected).abs() < 1e-14);
            }
        }
        assert_eq!(spd_inverse(&[[1.0, 2.0], [2.0, 1.0]]), Err(1));
        assert_eq!(spd_inverse(&[[f64::NAN, 0.0], [0.0, 1.0]]), Err(0));
    }
}
