//! Trilinear sampling of a scalar field on a voxel grid, with its gradient.
//!
//! Voxel `[i, j, k]` is centred at `origin + spacing * (i, j, k)` (DESIGN conventions).
//! Outside the grid a sample is the value at the nearest point of the grid box plus the
//! distance to the box (SPEC 3), so a signed distance field stays a distance bound there.

use rayon::prelude::*;

use crate::error::{check_finite, Error, Result};

/// A read-only scalar field on a voxel grid, C-ordered `(nx, ny, nz)`.
pub struct GridField<'a> {
    values: &'a [f64],
    shape: [usize; 3],
    origin: [f64; 3],
    spacing: f64,
}

impl<'a> GridField<'a> {
    /// Wraps `values` of a grid.
    ///
    /// # Errors
    /// [`Error::GridShape`] when `values` does not hold `shape` voxels, a side is empty,
    /// or `spacing` is not positive and finite; [`Error::NonFinite`] for a non-finite origin.
    pub fn new(
        values: &'a [f64],
        shape: [usize; 3],
        origin: [f64; 3],
        spacing: f64,
    ) -> Result<Self> {
        let voxels = shape.iter().try_fold(1usize, |t, &s| t.checked_mul(s));
        if voxels != Some(values.len())
            || values.is_empty()
            || !(spacing.is_finite() && spacing > 0.0)
        {
            return Err(Error::GridShape {
                voxels: values.len(),
                shape,
                spacing: [spacing; 3],
            });
        }
        check_finite("origin", &[origin])?;
        Ok(GridField {
            values,
            shape,
            origin,
            spacing,
        })
    }

    fn at(&self, i: usize, j: usize, k: usize) -> f64 {
        self.values[(i * self.shape[1] + j) * self.shape[2] + k]
    }

    /// Value and gradient (world units) at `p`.
    pub fn sample(&self, p: &[f64; 3]) -> (f64, [f64; 3]) {
        let mut cell = [0usize; 3];
        let mut t = [0.0; 3];
        let mut outside = [0.0; 3];
        for a in 0..3 {
            let last = (self.shape[a] - 1) as f64;
            let u = (p[a] - self.origin[a]) / self.spacing;
            let c = u.clamp(0.0, last);
            outside[a] = (u - c) * self.spacing;
            // Lower corner of the interpolation cell; a one-voxel side has no cell.
            let i0 = (c.floor() as usize).min(self.shape[a].saturating_sub(2));
            cell[a] = i0;
            t[a] = if self.shape[a] > 1 {
                c - i0 as f64
            } else {
                0.0
            };
        }
        let next = |a: usize| {
            if self.shape[a] > 1 {
                cell[a] + 1
            } else {
                cell[a]
            }
        };
        let (i0, j0, k0) = (cell[0], cell[1], cell[2]);
        let (i1, j1, k1) = (next(0), next(1), next(2));
        let c000 = self.at(i0, j0, k0);
        let c001 = self.at(i0, j0, k1);
        let c010 = self.at(i0, j1, k0);
        let c011 = self.at(i0, j1, k1);
        let c100 = self.at(i1, j0, k0);
        let c101 = self.at(i1, j0, k1);
        let c110 = self.at(i1, j1, k0);
        let c111 = self.at(i1, j1, k1);
        let [tx, ty, tz] = t;
        let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
        let c00 = lerp(c000, c001, tz);
        let c01 = lerp(c010, c011, tz);
        let c10 = lerp(c100, c101, tz);
        let c11 = lerp(c110, c111, tz);
        let c0 = lerp(c00, c01, ty);
        let c1 = lerp(c10, c11, ty);
        let value = lerp(c0, c1, tx);
        // Derivatives of the interpolant; zero along an axis where p was clamped.
        let inside_axis = |a: usize| {
            if outside[a] == 0.0 && self.shape[a] > 1 {
                1.0 / self.spacing
            } else {
                0.0
            }
        };
        let mut gradient = [
            (c1 - c0) * inside_axis(0),
            (lerp(lerp(c010, c011, tz), lerp(c110, c111, tz), tx)
                - lerp(lerp(c000, c001, tz), lerp(c100, c101, tz), tx))
                * inside_axis(1),
            (lerp(lerp(c001, c011, ty), lerp(c101, c111, ty), tx)
                - lerp(lerp(c000, c010, ty), lerp(c100, c110, ty), tx))
                * inside_axis(2),
        ];
        let distance = outside.iter().map(|o| o * o).sum::<f64>().sqrt();
        if distance > 0.0 {
            for a in 0..3 {
                gradient[a] += outside[a] / distance;
            }
        }
        (value + distance, gradient)
    }
}

/// A field the fitting can pull towards: value and gradient at a point of `D` dimensions.
pub trait Field<const D: usize>: Sync {
    /// Value and gradient (world units) at `p`.
    fn value_and_gradient(&self, p: &[f64; D]) -> (f64, [f64; D]);
}

impl Field<3> for GridField<'_> {
    fn value_and_gradient(&self, p: &[f64; 3]) -> (f64, [f64; 3]) {
        self.sample(p)
    }
}

/// A 2-D field is a grid one voxel thick along z, sampled in its plane $z = $ origin$_z$.
impl Field<2> for GridField<'_> {
    fn value_and_gradient(&self, p: &[f64; 2]) -> (f64, [f64; 2]) {
        let (v, g) = self.sample(&[p[0], p[1], self.origin[2]]);
        (v, [g[0], g[1]])
    }
}

/// Samples `field` at every point in parallel: values, and gradients when asked.
///
/// # Errors
/// [`Error::NonFinite`] for non-finite points; [`Error::OutputSize`] for outputs of the
/// wrong length.
pub fn sample_points(
    field: &GridField<'_>,
    points: &[[f64; 3]],
    values: &mut [f64],
    gradients: Option<&mut [[f64; 3]]>,
) -> Result<()> {
    check_finite("points", points)?;
    if values.len() != points.len() {
        return Err(Error::OutputSize {
            expected: points.len(),
            got: values.len(),
        });
    }
    match gradients {
        Some(g) => {
            if g.len() != points.len() {
                return Err(Error::OutputSize {
                    expected: points.len(),
                    got: g.len(),
                });
            }
            values
                .par_iter_mut()
                .zip(g.par_iter_mut())
                .zip(points.par_iter())
                .for_each(|((v, g), p)| {
                    (*v, *g) = field.sample(p);
                });
        }
        None => values
            .par_iter_mut()
            .zip(points.par_iter())
            .for_each(|(v, p)| *v = field.sample(p).0),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reproduces_a_linear_field_and_its_gradient() {
        let shape = [4, 5, 6];
        let (origin, h) = ([1.0, -2.0, 0.5], 0.25);
        let f = |x: [f64; 3]| 2.0 * x[0] - 3.0 * x[1] + 0.5 * x[2] + 1.0;
        let mut values = vec![0.0; 120];
        for i in 0..4 {
            for j in 0..5 {
                for k in 0..6 {
                    values[(i * 5 + j) * 6 + k] = f([
                        origin[0] + h * i as f64,
                        origin[1] + h * j as f64,
                        origin[2] + h * k as f64,
                    ]);
                }
            }
        }
        let field = GridField::new(&values, shape, origin, h).unwrap();
        let p = [1.3, -1.7, 1.2];
        let (v, g) = field.sample(&p);
        assert!((v - f(p)).abs() < 1e-12);
        for (a, want) in [2.0, -3.0, 0.5].iter().enumerate() {
            assert!((g[a] - want).abs() < 1e-12);
        }
        // Outside: the value at the box plus the distance to it.
        let (v, g) = field.sample(&[0.0, -1.7, 1.2]);
        assert!((v - (f([1.0, -1.7, 1.2]) + 1.0)).abs() < 1e-12);
        assert!((g[0] + 1.0).abs() < 1e-12);
    }
}
