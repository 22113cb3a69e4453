//! The articulated metaball body model of SPEC 6: skeleton, field, silhouette ray search,
//! observations for the sparse Levenberg-Marquardt fit.
//!
//! # State layout (the one place it is defined)
//! - `shape`, shared by all frames, `2 P` values: `[l_0, w_0, l_1, w_1, …]`, the length and
//!   width coefficient of each part (1 = the model as described).
//! - `motion`, per frame, `6 + A` values: root translation `t` (3, metres), root angles
//!   `(α, β, γ)` with root rotation `Rot_z(α) Rot_y(β) Rot_x(γ)` (radians), then the joint
//!   angles of each part's axes in part order (radians).
//! - Jacobians put a frame's motion columns first and the shape columns after them.

pub mod fastexp;
pub mod field;
pub mod fit;
pub mod normal;
pub mod observe;
pub mod ray;
pub mod skeleton;
#[cfg(test)]
mod tests;

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::error::check_finite;
use crate::Result;
pub use field::{Cutoff, Field};
pub use ray::{ray_maximum, RayMaximum};
pub use skeleton::{Metaball, PartSpec, Skeleton};

/// `F`, `∇F` and `∇²F` (row-major 3x3) per point.
pub type FieldSamples = (Vec<f64>, Vec<[f64; 3]>, Vec<[f64; 9]>);

/// `F`, `∇F` and `∇²F` at each point (world) for one state.
///
/// # Errors
/// Those of [`Skeleton::pose`], and [`crate::Error::NonFinite`] for points with NaN.
pub fn field_at(
    skeleton: &Skeleton,
    shape: &[f64],
    motion: &[f64],
    points: &[[f64; 3]],
) -> Result<FieldSamples> {
    check_finite("points", points)?;
    let field = Field::new(skeleton, skeleton.pose(shape, motion)?);
    let out: Vec<(f64, [f64; 3], [f64; 9])> = points
        .par_iter()
        .map(|p| {
            let (f, g, h) = field.value_gradient_hessian(&Vector3::from(*p));
            // nalgebra stores column-major; the Hessian is symmetric so the order is moot.
            (f, g.into(), std::array::from_fn(|k| h[k]))
        })
        .collect();
    Ok(unzip3(out))
}

fn unzip3<A, B, C>(v: Vec<(A, B, C)>) -> (Vec<A>, Vec<B>, Vec<C>) {
    let mut a = Vec::with_capacity(v.len());
    let mut b = Vec::with_capacity(v.len());
    let mut c = Vec::with_capacity(v.len());
    for (x, y, z) in v {
        a.push(x);
        b.push(y);
        c.push(z);
    }
    (a, b, c)
}

/// `F` alone at each point (world), each ball cut at `|q| <= BOUND` (a sphere test first):
/// the values marching cubes needs for a skin mesh, without the gradient and Hessian.
///
/// # Errors
/// As [`field_at`].
pub fn field_values(
    skeleton: &Skeleton,
    shape: &[f64],
    motion: &[f64],
    points: &[[f64; 3]],
) -> Result<Vec<f64>> {
    check_finite("points", points)?;
    let field = Field::new(skeleton, skeleton.pose(shape, motion)?);
    Ok(points
        .par_iter()
        .with_min_len(1024)
        .map(|p| {
            let x = Vector3::from(*p);
            field
                .balls
                .iter()
                .filter(|b| (x - b.world_centre).norm_squared() <= b.bound_radius * b.bound_radius)
                .map(|b| Field::term(b, &x).value)
                .sum()
        })
        .collect())
}

/// `F` at each point and the dense Jacobian `∂F/∂(motion, shape)` at fixed points,
/// `N x (n_motion + 2 P)` row-major.
///
/// # Errors
/// As [`field_at`].
pub fn state_jacobian(
    skeleton: &Skeleton,
    shape: &[f64],
    motion: &[f64],
    points: &[[f64; 3]],
    cutoff: Cutoff,
) -> Result<(Vec<f64>, Vec<f64>)> {
    check_finite("points", points)?;
    let field = Field::new(skeleton, skeleton.pose(shape, motion)?);
    let width = skeleton.n_motion + skeleton.n_shape();
    let mut jacobian = vec![0.0; points.len() * width];
    let values = points
        .par_iter()
        .zip(jacobian.par_chunks_mut(width.max(1)))
        .map(|(p, row)| field.state_derivative(&Vector3::from(*p), cutoff, row))
        .collect();
    Ok((values, jacobian))
}

/// The field maximum along each ray `origins[i] + s directions[i]`, `s >= 0`, and the
/// Jacobian of that maximum with respect to the state (envelope theorem: the partial
/// derivative at fixed `x*`, since `∇F · r = 0` there). Rays that miss get value 0, a zero
/// Jacobian row and `hit = false`.
///
/// Returns `(s, points, values, hit, jacobian)`.
///
/// # Errors
/// As [`field_at`]; [`crate::Error::NonFinite`] for NaN rays, [`crate::Error::BadRay`]
/// for zero directions.
#[allow(clippy::type_complexity)]
pub fn ray_jacobian(
    skeleton: &Skeleton,
    shape: &[f64],
    motion: &[f64],
    origins: &[[f64; 3]],
    directions: &[[f64; 3]],
) -> Result<(Vec<f64>, Vec<[f64; 3]>, Vec<f64>, Vec<bool>, Vec<f64>)> {
    check_rays(origins, directions)?;
    let field = Field::new(skeleton, skeleton.pose(shape, motion)?);
    let width = skeleton.n_motion + skeleton.n_shape();
    let mut jacobian = vec![0.0; origins.len() * width];
    let found: Vec<RayMaximum> = origins
        .par_iter()
        .zip(directions)
        .zip(jacobian.par_chunks_mut(width.max(1)))
        .map(|((o, r), row)| {
            let m = ray_maximum(&field, &Vector3::from(*o), &Vector3::from(*r));
            if m.hit {
                field.state_derivative(&m.point, Cutoff::Exact, row);
            }
            m
        })
        .collect();
    Ok((
        found.iter().map(|m| m.s).collect(),
        found.iter().map(|m| m.point.into()).collect(),
        found.iter().map(|m| m.value).collect(),
        found.iter().map(|m| m.hit).collect(),
        jacobian,
    ))
}

/// Whether each ray meets the skin: `max_s F(o + s r) >= threshold` (a silhouette mask).
///
/// # Errors
/// As [`ray_jacobian`].
pub fn ray_inside(
    skeleton: &Skeleton,
    shape: &[f64],
    motion: &[f64],
    origins: &[[f64; 3]],
    directions: &[[f64; 3]],
    threshold: f64,
) -> Result<Vec<bool>> {
    check_rays(origins, directions)?;
    let field = Field::new(skeleton, skeleton.pose(shape, motion)?);
    Ok(origins
        .par_iter()
        .zip(directions)
        .map(|(o, r)| {
            ray_maximum(&field, &Vector3::from(*o), &Vector3::from(*r)).value >= threshold
        })
        .collect())
}

pub(crate) fn check_rays(origins: &[[f64; 3]], directions: &[[f64; 3]]) -> Result<()> {
    check_finite("origins", origins)?;
    check_finite("directions", directions)?;
    if origins.len() != directions.len() {
        return Err(crate::Error::WrongLength {
            argument: "directions",
            expected: origins.len(),
            got: directions.len(),
        });
    }
    if let Some(row) = directions.iter().position(|r| r.iter().all(|v| *v == 0.0)) {
        return Err(crate::Error::BadRay { row });
    }
    Ok(())
}
