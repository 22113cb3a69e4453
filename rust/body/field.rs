//! The metaball field `F(x) = Σ_i exp(-2 d_i(x))` at one state: value, gradient and
//! Hessian in x, and the derivative with respect to every state parameter (SPEC 6).
//!
//! Ball i of part b: `y = R_b^T (x - o_b)` in the part frame, `q = (y - c ∘ s) / (r ∘ s)`
//! with `s = (w t_i, d t_i, l)` (the part's width, depth and length coefficients, and the
//! ball's section `t_i = 1 + (τ - 1) k_i` from the part's taper τ), `d = |q|^2`.

use nalgebra::{Matrix3, Vector3};

use super::fastexp::exp_neg;
use super::skeleton::{Pose, Skeleton, DEPTH, LENGTH, SHAPE_PER_PART, TAPER, WIDTH};

/// Entries of a part's compact derivative ([`Field::part_derivatives_over`]): moment (3),
/// force (3), then the derivatives by the part's own length, width, depth and taper.
pub const PART_TERMS: usize = 6 + SHAPE_PER_PART;

/// Beyond `|q| = BOUND` a ball contributes less than `exp(-2 BOUND^2)` (1.4e-10 at 3.4):
/// used to cull balls off a ray and, with [`Cutoff`], to drop negligible Jacobian terms.
pub const BOUND: f64 = 3.4;

/// Balls with `|q| > JACOBIAN_BOUND` (contribution below exp(-2 · 2.8²) = 1.6e-7) are left
/// out of [`Cutoff::Bounded`] Jacobian rows, which then touch fewer parts. Measured: 2.2
/// (6e-5) made linearisation ~25% faster but sent one noisy recovery (seed 3 of
/// `test_recovery_with_noise_and_outliers`) to a 5-degree local minimum; 2.8 does not.
pub const JACOBIAN_BOUND: f64 = 2.8;

/// Which balls enter derivative sums.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Cutoff {
    /// Every ball, however small its contribution (the exact derivative).
    Exact,
    /// Balls with `d_i <= JACOBIAN_BOUND^2` only (the value still sums every ball): terms
    /// below ~1.6e-7 are dropped, which keeps the Jacobian rows sparse (a far part's
    /// parameters get no entry).
    Bounded,
}

/// One ball placed in the world at one state.
#[derive(Debug, Clone, Copy)]
pub struct PlacedBall {
    /// Part index.
    pub part: usize,
    /// World-to-part rotation is `rotation^T`.
    pub rotation: Matrix3<f64>,
    /// Part frame origin (world).
    pub origin: Vector3<f64>,
    /// Unscaled centre and radii (part frame).
    pub centre: Vector3<f64>,
    /// Unscaled radii.
    pub radii: Vector3<f64>,
    /// Scale `(w t, d t, l)` of the ball.
    pub scale: Vector3<f64>,
    /// `∂s/∂w = t`, `∂s/∂d = t`, `∂s/∂τ = (w k, d k, 0)`: the first entry is `t`, the
    /// other two `w k` and `d k`.
    pub shape_rates: Vector3<f64>,
    /// World centre of the scaled ellipsoid.
    pub world_centre: Vector3<f64>,
    /// Radius of the sphere outside which `|q| > BOUND`.
    pub bound_radius: f64,
    /// Reciprocal scaled radii `1 / (r ∘ s)`.
    pub inv_radii: Vector3<f64>,
    /// World to `q`: `diag(1 / (r ∘ s)) R^T`, so `q = to_q (x - world_centre)` (no
    /// division nor transpose in the inner loops).
    pub to_q: Matrix3<f64>,
}

/// Per-ball quantities at a point.
#[derive(Debug, Clone, Copy)]
pub struct BallTerm {
    /// `exp(-2 d)`.
    pub value: f64,
    /// `d`.
    pub d: f64,
    /// `q` (part frame).
    pub q: Vector3<f64>,
}

/// `-∂q_a/∂s_a` at `q`: with `y_a = (c_a + q_a r_a) s_a` (unscaled centre and radii),
/// `q_a = (y_a - c_a s_a) / (r_a s_a)` gives `∂q_a/∂s_a = -y_a / (r_a s_a²)
/// = -(c_a + q_a r_a) / (r_a s_a)`.
#[inline]
fn shape_slope(ball: &PlacedBall, q: &Vector3<f64>) -> Vector3<f64> {
    (ball.centre + q.component_mul(&ball.radii)).component_mul(&ball.inv_radii)
}

/// `∂f/∂(l, w, d, τ)` of one ball's term `f = exp(-2 d)` from `dd = ∂d/∂s` (per scaled axis).
#[inline]
fn shape_terms(ball: &PlacedBall, f: f64, dd: &Vector3<f64>) -> [f64; SHAPE_PER_PART] {
    let r = &ball.shape_rates;
    let mut out = [0.0; SHAPE_PER_PART];
    out[LENGTH] = -2.0 * f * dd.z;
    out[WIDTH] = -2.0 * f * dd.x * r.x;
    out[DEPTH] = -2.0 * f * dd.y * r.x;
    out[TAPER] = -2.0 * f * (dd.x * r.y + dd.y * r.z);
    out
}

/// The field of one model at one state.
#[derive(Debug, Clone)]
pub struct Field<'a> {
    /// The model.
    pub skeleton: &'a Skeleton,
    /// Its forward kinematics.
    pub pose: Pose,
    /// The balls placed in the world.
    pub balls: Vec<PlacedBall>,
}

impl<'a> Field<'a> {
    /// Places every ball at `pose`.
    pub fn new(skeleton: &'a Skeleton, pose: Pose) -> Self {
        let balls = skeleton
            .balls
            .iter()
            .enumerate()
            .map(|(i, ball)| {
                let (part, k) = (pose.coefficients[ball.part], skeleton.taper_weight[i]);
                let t = 1.0 + (pose.taper[ball.part] - 1.0) * k;
                let scale = Vector3::new(part.x * t, part.y * t, part.z);
                let centre = Vector3::from(ball.centre);
                let radii = Vector3::from(ball.radii);
                let rotation = pose.rotation[ball.part];
                let origin = pose.origin[ball.part];
                let inv_radii = radii.component_mul(&scale).map(|v| 1.0 / v);
                PlacedBall {
                    part: ball.part,
                    rotation,
                    origin,
                    centre,
                    radii,
                    scale,
                    shape_rates: Vector3::new(t, part.x * k, part.y * k),
                    world_centre: origin + rotation * centre.component_mul(&scale),
                    bound_radius: BOUND * radii.component_mul(&scale).max(),
                    inv_radii,
                    to_q: Matrix3::from_diagonal(&inv_radii) * rotation.transpose(),
                }
            })
            .collect();
        Self {
            skeleton,
            pose,
            balls,
        }
    }

    /// The term of ball `ball` at `x`.
    #[inline]
    pub fn term(ball: &PlacedBall, x: &Vector3<f64>) -> BallTerm {
        let q = ball.to_q * (x - ball.world_centre);
        let d = q.norm_squared();
        BallTerm {
            value: exp_neg(-2.0 * d),
            d,
            q,
        }
    }

    /// `F(x)`.
    pub fn value(&self, x: &Vector3<f64>) -> f64 {
        self.value_over(x, None)
    }

    /// `F(x)` over the balls in `subset` (ascending ball indices), or all of them.
    pub fn value_over(&self, x: &Vector3<f64>, subset: Option<&[u16]>) -> f64 {
        match subset {
            None => self.balls.iter().map(|b| Self::term(b, x).value).sum(),
            Some(subset) => subset
                .iter()
                .map(|&i| Self::term(&self.balls[i as usize], x).value)
                .sum(),
        }
    }

    /// The balls (ascending indices) with `|q| <= BOUND + margin` at `x`: the ones that
    /// can matter there while the state moves by less than `margin` radii.
    pub fn near_balls(&self, x: &Vector3<f64>, margin: f64) -> Vec<u16> {
        let reach = (BOUND + margin) * (BOUND + margin);
        (0..self.balls.len())
            .filter(|&i| Self::term(&self.balls[i], x).d <= reach)
            .map(|i| i as u16)
            .collect()
    }

    /// `(F, ∇F, ∇²F)` at `x` (world).
    pub fn value_gradient_hessian(&self, x: &Vector3<f64>) -> (f64, Vector3<f64>, Matrix3<f64>) {
        let mut f = 0.0;
        let mut g = Vector3::zeros();
        let mut h = Matrix3::zeros();
        for ball in &self.balls {
            let t = Self::term(ball, x);
            let r = ball.radii.component_mul(&ball.scale);
            // ∇d = 2 R (q / r), ∇²d = 2 R diag(1/r²) R^T; ∇f = -2 f ∇d,
            // ∇²f = f (4 ∇d ∇d^T - 2 ∇²d).
            let grad_d = ball.rotation * (2.0 * t.q.component_div(&r));
            let inv_r2 = Vector3::new(1.0 / (r.x * r.x), 1.0 / (r.y * r.y), 1.0 / (r.z * r.z));
            let hess_d =
                ball.rotation * Matrix3::from_diagonal(&(2.0 * inv_r2)) * ball.rotation.transpose();
            f += t.value;
            g -= 2.0 * t.value * grad_d;
            h += t.value * (4.0 * grad_d * grad_d.transpose() - 2.0 * hess_d);
        }
        (f, g, h)
    }

    /// `F(x)` and `∂F/∂θ` at fixed `x`, written densely into `row` (length
    /// `n_motion + n_shape`, motion first), which is zeroed first.
    ///
    /// Moving a part by a twist with velocity `v(x)` changes its field at a fixed point by
    /// `-∇F_b · v`; a length, width or depth coefficient also moves every descendant's frame
    /// (offsets scale) and reshapes the part's own balls.
    pub fn state_derivative(&self, x: &Vector3<f64>, cutoff: Cutoff, row: &mut [f64]) -> f64 {
        self.state_derivative_over(x, None, cutoff, row)
    }

    /// [`Field::state_derivative`] over the balls in `subset` (ascending), or all.
    pub fn state_derivative_over(
        &self,
        x: &Vector3<f64>,
        subset: Option<&[u16]>,
        cutoff: Cutoff,
        row: &mut [f64],
    ) -> f64 {
        let n_motion = self.skeleton.n_motion;
        row.iter_mut().for_each(|v| *v = 0.0);
        let mut f = 0.0;
        // Balls are sorted by part: ∇F_b is summed over a run of one part's balls, then
        // spread over the parameters that move the part.
        let mut current: Option<usize> = None;
        let mut grad = Vector3::zeros();
        let mut visit = |ball: &PlacedBall,
                         row: &mut [f64],
                         current: &mut Option<usize>,
                         grad: &mut Vector3<f64>| {
            let t = Self::term(ball, x);
            f += t.value;
            if cutoff == Cutoff::Bounded && t.d > JACOBIAN_BOUND * JACOBIAN_BOUND {
                return;
            }
            let b = ball.part;
            if *current != Some(b) {
                if let Some(previous) = *current {
                    self.spread(previous, grad, x, row);
                }
                *current = Some(b);
                *grad = Vector3::zeros();
            }
            *grad -= ball.rotation * (4.0 * t.value * t.q.component_mul(&ball.inv_radii));
            // ∂q_a/∂s_a = -y_a / (r_a s_a²) with r_a unscaled; ∂f/∂s = -2 f Σ 2 q_a ∂q_a/∂s.
            let dq = -shape_slope(ball, &t.q);
            let dd = 2.0 * t.q.component_mul(&dq);
            let at = n_motion + SHAPE_PER_PART * b;
            let own = shape_terms(ball, t.value, &dd);
            for (c, v) in own.iter().enumerate() {
                row[at + c] += v;
            }
        };
        match subset {
            None => {
                for ball in &self.balls {
                    visit(ball, row, &mut current, &mut grad);
                }
            }
            Some(subset) => {
                for &i in subset {
                    visit(&self.balls[i as usize], row, &mut current, &mut grad);
                }
            }
        }
        if let Some(previous) = current {
            self.spread(previous, &grad, x, row);
        }
        f
    }

    /// `F(x)` and, for each part with a ball in the sum (ascending parts), its compact
    /// derivative `z_b = ((x - reference) × ∇F_b, ∇F_b, ∂F/∂l_b, ∂F/∂w_b, ∂F/∂d_b)` (balls cut
    /// as in [`Field::state_derivative_over`]). The Jacobian row is `Σ_b E_b^T z_b` with
    /// [`super::normal::PartMap`]'s `E_b`, which depends on the pose only: the normal
    /// matrix can then be accumulated from 9-vectors per part instead of full rows.
    pub fn part_derivatives_over(
        &self,
        x: &Vector3<f64>,
        subset: Option<&[u16]>,
        cutoff: Cutoff,
        reference: &Vector3<f64>,
        out: &mut Vec<(usize, [f64; PART_TERMS])>,
    ) -> f64 {
        out.clear();
        let mut f = 0.0;
        let mut visit = |ball: &PlacedBall| {
            let t = Self::term(ball, x);
            f += t.value;
            if cutoff == Cutoff::Bounded && t.d > JACOBIAN_BOUND * JACOBIAN_BOUND {
                return;
            }
            // Balls are sorted by part, so one part's balls form one run.
            if out.last().map(|e| e.0) != Some(ball.part) {
                out.push((ball.part, [0.0; PART_TERMS]));
            }
            let z = &mut out.last_mut().expect("pushed above").1;
            let grad = ball.rotation * (-4.0 * t.value * t.q.component_mul(&ball.inv_radii));
            let dq = -shape_slope(ball, &t.q);
            let dd = 2.0 * t.q.component_mul(&dq);
            z[3] += grad.x;
            z[4] += grad.y;
            z[5] += grad.z;
            let own = shape_terms(ball, t.value, &dd);
            z[6..].iter_mut().zip(own).for_each(|(a, v)| *a += v);
        };
        match subset {
            None => self.balls.iter().for_each(&mut visit),
            Some(subset) => subset.iter().for_each(|&i| visit(&self.balls[i as usize])),
        }
        let arm = x - reference;
        for (_, z) in out.iter_mut() {
            let moment = arm.cross(&Vector3::new(z[3], z[4], z[5]));
            z[0] = moment.x;
            z[1] = moment.y;
            z[2] = moment.z;
        }
        f
    }

    /// Adds `-∇F_b · v_k(x)` for every motion parameter k and offset coefficient j that
    /// moves part b.
    fn spread(&self, b: usize, grad: &Vector3<f64>, x: &Vector3<f64>, row: &mut [f64]) {
        let n_motion = self.skeleton.n_motion;
        for &k in &self.skeleton.motion_of_part[b] {
            row[k] -= grad.dot(&self.pose.twists[k].velocity(x));
        }
        for (j, u) in &self.pose.offset_derivatives[b] {
            row[n_motion + j] -= grad.dot(u);
        }
    }

    /// Index of the part contributing most to `F(x)`, and that contribution.
    pub fn strongest_part(&self, x: &Vector3<f64>) -> (usize, f64) {
        let mut per_part = vec![0.0; self.skeleton.n_parts()];
        for ball in &self.balls {
            per_part[ball.part] += Self::term(ball, x).value;
        }
        per_part
            .iter()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |best, (b, &v)| {
                if v > best.1 {
                    (b, v)
                } else {
                    best
                }
            })
    }
}
