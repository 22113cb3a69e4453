//! The silhouette ray search of SPEC 6: the point `x*` of a ray `o + s r` (s >= 0) where
//! the field is largest, by a 1-D search over candidate peaks followed by safeguarded
//! Newton steps on `φ(s) = F(o + s r)`.

use nalgebra::Vector3;

use super::field::{Field, PlacedBall};

/// The maximum of the field along one ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayMaximum {
    /// Ray parameter of the maximum (in units of the ray direction's length).
    pub s: f64,
    /// The maximising point `x*` (world).
    pub point: Vector3<f64>,
    /// `F(x*)`, summed over the balls whose bounding sphere the ray meets.
    pub value: f64,
    /// False when the ray meets no ball's bounding sphere in front of its origin: then
    /// `value` is 0 and `point` is the origin.
    pub hit: bool,
}

/// Value, slope and curvature of `φ` at `x`, over the balls in `hit`.
fn along(field: &Field<'_>, hit: &[usize], x: &Vector3<f64>, r: &Vector3<f64>) -> (f64, f64, f64) {
    let mut f = 0.0;
    let mut slope = 0.0;
    let mut curvature = 0.0;
    for &i in hit {
        let ball: &PlacedBall = &field.balls[i];
        let t = Field::term(ball, x);
        let radii = ball.radii.component_mul(&ball.scale);
        // In the part frame: d = |q|², dq/ds = R^T r / radii.
        let rq = (ball.rotation.transpose() * r).component_div(&radii);
        let dd = 2.0 * t.q.dot(&rq);
        let ddd = 2.0 * rq.norm_squared();
        f += t.value;
        slope += -2.0 * t.value * dd;
        curvature += t.value * (4.0 * dd * dd - 2.0 * ddd);
    }
    (f, slope, curvature)
}

/// The maximum of the field along `origin + s direction`, `s >= 0`.
///
/// Candidates are each met ball's own peak along the ray (d_i is quadratic in s, so its
/// minimiser is closed-form) and the midpoints between neighbouring peaks; Newton steps,
/// limited to half the smallest met radius and backtracked when they descend, climb from
/// the best candidate to the stationary point `φ'(s*) = 0`.
pub fn ray_maximum(field: &Field<'_>, origin: &Vector3<f64>, direction: &Vector3<f64>) -> RayMaximum {
    let rr = direction.norm_squared();
    let mut hit = Vec::new();
    let mut peaks = Vec::new();
    let mut step_limit = f64::INFINITY;
    for (i, ball) in field.balls.iter().enumerate() {
        // Ray-sphere test against the bounding sphere.
        let oc = origin - ball.world_centre;
        let b = oc.dot(direction) / rr;
        let c = (oc.norm_squared() - ball.bound_radius * ball.bound_radius) / rr;
        let disc = b * b - c;
        if disc < 0.0 || -b + disc.sqrt() < 0.0 {
            continue;
        }
        hit.push(i);
        let radii = ball.radii.component_mul(&ball.scale);
        let q0 = (ball.rotation.transpose() * (origin - ball.world_centre)).component_div(&radii);
        let q1 = (ball.rotation.transpose() * direction).component_div(&radii);
        peaks.push((-q0.dot(&q1) / q1.norm_squared()).max(0.0));
        step_limit = step_limit.min(0.5 * radii.min() / rr.sqrt());
    }
    if hit.is_empty() {
        return RayMaximum {
            s: 0.0,
            point: *origin,
            value: 0.0,
            hit: false,
        };
    }
    peaks.sort_by(f64::total_cmp);
    let mut candidates = peaks.clone();
    candidates.extend(peaks.windows(2).map(|w| 0.5 * (w[0] + w[1])));
    let at = |s: f64| origin + s * direction;
    let (mut s, mut phi) = candidates
        .iter()
        .map(|&s| (s, along(field, &hit, &at(s), direction).0))
        .fold((0.0, f64::NEG_INFINITY), |best, c| if c.1 > best.1 { c } else { best });
    for _ in 0..100 {
        let (_, slope, curvature) = along(field, &hit, &at(s), direction);
        let mut step = if curvature < 0.0 {
            -slope / curvature
        } else {
            step_limit * slope.signum()
        };
        step = step.clamp(-step_limit, step_limit);
        if s + step < 0.0 {
            step = -s;
        }
        // Close to the peak the value cannot resolve the step (it changes by ~φ'' δs², below
        // rounding), so a short Newton step is taken on the strength of the curvature alone.
        if curvature < 0.0 && step.abs() < 1e-3 * step_limit {
            s += step;
            phi = along(field, &hit, &at(s), direction).0;
            // Quadratic convergence: the next step would be ~1e-20 of the scale.
            if step.abs() <= 1e-10 * step_limit {
                break;
            }
            continue;
        }
        let mut accepted = false;
        for _ in 0..40 {
            let value = along(field, &hit, &at(s + step), direction).0;
            if value >= phi {
                s += step;
                phi = value;
                accepted = true;
                break;
            }
            step *= 0.5;
        }
        if !accepted || step.abs() <= 1e-14 * (1.0 + s.abs()) {
            break;
        }
    }
    RayMaximum {
        s,
        point: at(s),
        value: phi,
        hit: true,
    }
}
