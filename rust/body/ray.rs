//! The silhouette ray search of SPEC 6: the point `x*` of a ray `o + s r` (s >= 0) where
//! the field is largest, by a 1-D search over candidate peaks followed by safeguarded
//! Newton steps on `φ(s) = F(o + s r)`.
//!
//! Along a ray each ball's `d_i` is exactly quadratic in s: `d_i(s) = m_i + c_i (s - p_i)^2`
//! (`q = q0 + s q1`, `p = -q0·q1 / |q1|²`, `c = |q1|²`, `m = |q0 + p q1|²`). The search
//! therefore runs on three numbers per ball, with no 3-D work after setting them up.

use nalgebra::Vector3;

use super::fastexp::exp_neg;
use super::field::{Field, BOUND};

/// The maximum of the field along one ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayMaximum {
    /// Ray parameter of the maximum (in units of the ray direction's length).
    pub s: f64,
    /// The maximising point `x*` (world).
    pub point: Vector3<f64>,
    /// `F(x*)`, summed over the balls that the ray passes within `|q| <= BOUND` of.
    pub value: f64,
    /// False when the ray passes no ball within `|q| <= BOUND` in front of its origin:
    /// then `value` is 0 and `point` is the origin.
    pub hit: bool,
}

/// One ball's `d(s) = m + c (s - p)^2` along the ray.
#[derive(Debug, Clone, Copy)]
struct Quadratic {
    m: f64,
    c: f64,
    p: f64,
}

/// `(φ, φ', φ'')` at `s`.
fn along(balls: &[Quadratic], s: f64) -> (f64, f64, f64) {
    let (mut f, mut slope, mut curvature) = (0.0, 0.0, 0.0);
    for b in balls {
        let t = s - b.p;
        let e = exp_neg(-2.0 * (b.m + b.c * t * t));
        let dd = 2.0 * b.c * t;
        f += e;
        slope -= 2.0 * e * dd;
        curvature += e * (4.0 * dd * dd - 4.0 * b.c);
    }
    (f, slope, curvature)
}

/// The maximum of the field along `origin + s direction`, `s >= 0`.
///
/// Candidates are each met ball's own peak along the ray and the midpoints between
/// neighbouring peaks; Newton steps, limited to half the narrowest met ball's extent along
/// the ray and backtracked when they descend, climb from the best candidate to the
/// stationary point `φ'(s*) = 0`.
pub fn ray_maximum(
    field: &Field<'_>,
    origin: &Vector3<f64>,
    direction: &Vector3<f64>,
) -> RayMaximum {
    ray_maximum_over(field, None, origin, direction, None)
}

/// Ball `i`'s `d(s)` along the ray and `|q0|²` (at the origin).
fn quadratic(
    field: &Field<'_>,
    i: usize,
    origin: &Vector3<f64>,
    direction: &Vector3<f64>,
) -> (Quadratic, f64) {
    let ball = &field.balls[i];
    let q0 = ball.to_q * (origin - ball.world_centre);
    let q1 = ball.to_q * direction;
    let c = q1.norm_squared();
    let p = -q0.dot(&q1) / c;
    let m = (q0 + p * q1).norm_squared();
    (Quadratic { m, c, p }, q0.norm_squared())
}

/// The balls (ascending) that the ray passes within `|q| <= BOUND + margin` of.
pub fn ray_near_balls(
    field: &Field<'_>,
    origin: &Vector3<f64>,
    direction: &Vector3<f64>,
    margin: f64,
) -> Vec<u16> {
    let reach = (BOUND + margin) * (BOUND + margin);
    (0..field.balls.len())
        .filter(|&i| {
            let (b, q0) = quadratic(field, i, origin, direction);
            b.m <= reach && (b.p >= 0.0 || q0 <= reach)
        })
        .map(|i| i as u16)
        .collect()
}

/// [`ray_maximum`] over the balls in `subset` (or all); with `start`, the 1-D search is
/// skipped and Newton climbs from there (a warm start from the previous state's `s*`).
pub fn ray_maximum_over(
    field: &Field<'_>,
    subset: Option<&[u16]>,
    origin: &Vector3<f64>,
    direction: &Vector3<f64>,
    start: Option<f64>,
) -> RayMaximum {
    let mut met: Vec<Quadratic> = Vec::with_capacity(16);
    let mut step_limit = f64::INFINITY;
    let all: Vec<u16>;
    let indices = match subset {
        Some(s) => s,
        None => {
            all = (0..field.balls.len() as u16).collect();
            &all
        }
    };
    for &i in indices {
        let (Quadratic { m, c, p }, q0) = quadratic(field, i as usize, origin, direction);
        // Skip balls the ray never comes near, and balls wholly behind the origin.
        if m > BOUND * BOUND || (p < 0.0 && q0 > BOUND * BOUND) {
            continue;
        }
        met.push(Quadratic { m, c, p });
        // |q| changes by 1 over 1/sqrt(c) in s: half of that is a safe Newton step.
        step_limit = step_limit.min(0.5 / c.sqrt());
    }
    if met.is_empty() {
        return RayMaximum {
            s: 0.0,
            point: *origin,
            value: 0.0,
            hit: false,
        };
    }
    // Only balls whose own peak is within a factor 1e-3 of the strongest are candidates:
    // the others still add to φ but cannot host its maximum on their own, and evaluating
    // every candidate costs k evaluations of k terms.
    let strongest = met.iter().map(|b| b.m).fold(f64::INFINITY, f64::min);
    let mut peaks: Vec<f64> = match start {
        Some(s) => vec![s.max(0.0)],
        None => met
            .iter()
            .filter(|b| b.m <= strongest + 3.5)
            .map(|b| b.p.max(0.0))
            .collect(),
    };
    peaks.sort_by(f64::total_cmp);
    let midpoints: Vec<f64> = peaks.windows(2).map(|w| 0.5 * (w[0] + w[1])).collect();
    let (mut s, mut phi) = peaks
        .iter()
        .chain(&midpoints)
        .map(|&s| (s, along(&met, s).0))
        .fold((0.0, f64::NEG_INFINITY), |best, c| {
            if c.1 > best.1 {
                c
            } else {
                best
            }
        });
    for _ in 0..100 {
        let (_, slope, curvature) = along(&met, s);
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
            phi = along(&met, s).0;
            // Quadratic convergence: the next step would be ~1e-20 of the scale.
            if step.abs() <= 1e-10 * step_limit {
                break;
            }
            continue;
        }
        let mut accepted = false;
        for _ in 0..40 {
            let value = along(&met, s + step).0;
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
        point: origin + s * direction,
        value: phi,
        hit: true,
    }
}
