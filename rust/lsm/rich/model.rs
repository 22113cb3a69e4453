//! The richer model's unknowns (see the parent module): the state, where each unknown sits
//! in a step, the warp, a step's update, the prior's weights and the run-away check.

use super::super::line::degenerate;
use super::super::types::{ExtraModel, MatchOptions, Warp};

/// Most unknowns: shift 2, linear part 4, quadratic terms 6, gain, offset, gain slopes 2.
pub(crate) const R: usize = 16;

/// The richer model's estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct RichState {
    /// Linear part `[a11, a12, a21, a22]`.
    pub a: [f64; 4],
    /// Centre, search pixels.
    pub b: [f64; 2],
    /// Extra warp terms: `[p1, p2]` (projective) or `[q_u (3), q_v (3)]` (quadratic).
    pub warp: [f64; 6],
    /// `[g0, g_x, g_y]`.
    pub gain: [f64; 3],
    pub offset: f64,
}

/// Where each unknown sits in the step: `[b (2), A (4), extra warp, g0, offset, slopes]`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Layout {
    pub warp: Warp,
    pub extra: usize,
    pub slopes: bool,
    /// The template-side Jacobian and composed update (`ExtraModel::template_jacobian`).
    pub template_side: bool,
    /// Number of unknowns.
    pub unknowns: usize,
}

impl Layout {
    pub fn new(model: &ExtraModel) -> Self {
        let extra = match model.warp {
            Warp::Affine => 0,
            Warp::Projective => 2,
            Warp::Quadratic => 6,
        };
        let slopes = model.gain_gradient;
        Self {
            warp: model.warp,
            extra,
            slopes,
            template_side: model.template_jacobian,
            unknowns: 8 + extra + if slopes { 2 } else { 0 },
        }
    }
    pub fn gain(&self) -> usize {
        6 + self.extra
    }
    pub fn offset(&self) -> usize {
        7 + self.extra
    }
    pub fn slope(&self) -> usize {
        8 + self.extra
    }
}

/// The warped position of template offset `(dx, dy)` and, for the Jacobian, the linear
/// part's divisor `d` (1 but for the projective warp) and `A x`.
#[inline(always)]
pub(super) fn warp(
    s: &RichState,
    layout: &Layout,
    dx: f64,
    dy: f64,
    h: f64,
) -> ([f64; 2], f64, [f64; 2]) {
    let lin = [s.a[0] * dx + s.a[1] * dy, s.a[2] * dx + s.a[3] * dy];
    let (xi, eta) = (dx / h, dy / h);
    match layout.warp {
        Warp::Affine => ([s.b[0] + lin[0], s.b[1] + lin[1]], 1.0, lin),
        Warp::Projective => {
            let d = 1.0 + s.warp[0] * xi + s.warp[1] * eta;
            ([s.b[0] + lin[0] / d, s.b[1] + lin[1] / d], d, lin)
        }
        Warp::Quadratic => {
            let m = [xi * xi, xi * eta, eta * eta];
            let q = &s.warp;
            (
                [
                    s.b[0] + lin[0] + q[0] * m[0] + q[1] * m[1] + q[2] * m[2],
                    s.b[1] + lin[1] + q[3] * m[0] + q[4] * m[1] + q[5] * m[2],
                ],
                1.0,
                lin,
            )
        }
    }
}

/// The prior's weight per unknown (0 where none): the residual variance over the prior's
/// variance, in the units of each unknown.
pub(super) fn prior(
    s: &RichState,
    layout: &Layout,
    model: &ExtraModel,
    variance: f64,
    h: f64,
) -> [f64; R] {
    let mut lambda = [0.0; R];
    if !(variance > 0.0) {
        return lambda;
    }
    if model.warp_sigma > 0.0 {
        let sigma = match layout.warp {
            Warp::Affine => f64::INFINITY,
            // A relative change `p` of the divisor moves the patch's edge by about
            // `p h |A|` pixels.
            Warp::Projective => {
                let det = (s.a[0] * s.a[3] - s.a[1] * s.a[2]).abs();
                model.warp_sigma / (h * det.sqrt()).max(1e-9)
            }
            Warp::Quadratic => model.warp_sigma,
        };
        for k in 6..6 + layout.extra {
            lambda[k] = variance / (sigma * sigma);
        }
    }
    if layout.slopes && model.gain_sigma > 0.0 {
        let sigma = model.gain_sigma * s.gain[0].abs().max(1e-9);
        for k in layout.slope()..layout.slope() + 2 {
            lambda[k] = variance / (sigma * sigma);
        }
    }
    lambda
}

/// Applies a step; returns the centre's move and the largest change of the other
/// geometric unknowns, both in search pixels at the patch's edge or per template pixel.
/// A template-side step is composed: `W(x) -> W(x + delta(x))`, to first order `A delta`
/// added to the map (`delta = d + D x + P m(x)`, or `-x (dp . xi)` for the projective
/// terms).
pub(super) fn apply(s: &mut RichState, step: &[f64; R], layout: &Layout, h: f64) -> (f64, f64) {
    let before = *s;
    let a = s.a;
    let map = |u: f64, v: f64| [a[0] * u + a[1] * v, a[2] * u + a[3] * v];
    if layout.template_side {
        let shift = map(step[0], step[1]);
        s.b = [s.b[0] + shift[0], s.b[1] + shift[1]];
        let [d11, d12, d21, d22] = [step[2], step[3], step[4], step[5]];
        s.a = [
            a[0] * (1.0 + d11) + a[1] * d21,
            a[0] * d12 + a[1] * (1.0 + d22),
            a[2] * (1.0 + d11) + a[3] * d21,
            a[2] * d12 + a[3] * (1.0 + d22),
        ];
        match layout.warp {
            Warp::Affine => {}
            Warp::Projective => {
                s.warp[0] += step[6];
                s.warp[1] += step[7];
            }
            Warp::Quadratic => {
                for k in 0..3 {
                    let q = map(step[6 + k], step[9 + k]);
                    s.warp[k] += q[0];
                    s.warp[3 + k] += q[1];
                }
            }
        }
    } else {
        s.b[0] += step[0];
        s.b[1] += step[1];
        for k in 0..4 {
            s.a[k] += step[2 + k];
        }
        for k in 0..layout.extra {
            s.warp[k] += step[6 + k];
        }
    }
    let mut change: f64 = 0.0;
    for k in 0..4 {
        change = change.max((s.a[k] - before.a[k]).abs());
    }
    let scale = match layout.warp {
        Warp::Projective => h * (s.a[0] * s.a[3] - s.a[1] * s.a[2]).abs().sqrt(),
        _ => 1.0,
    };
    for k in 0..layout.extra {
        change = change.max((s.warp[k] - before.warp[k]).abs() * scale);
    }
    s.gain[0] += step[layout.gain()];
    s.offset += step[layout.offset()];
    if layout.slopes {
        s.gain[1] += step[layout.slope()];
        s.gain[2] += step[layout.slope() + 1];
    }
    ((s.b[0] - before.b[0]).hypot(s.b[1] - before.b[1]), change)
}

/// Whether the state ran away: besides the affine checks, a gain that is not positive
/// somewhere on the patch, a quadratic term that moves the edge by half the patch, or a
/// projective divisor that gets near zero on the patch.
pub(super) fn ran_away(
    s: &RichState,
    start_a: [f64; 4],
    start_b: [f64; 2],
    options: &MatchOptions,
    h: f64,
) -> bool {
    let moved = (s.b[0] - start_b[0]).hypot(s.b[1] - start_b[1]);
    let low_gain = s.gain[0] - s.gain[1].abs() - s.gain[2].abs();
    let warp = match options.extra.warp {
        Warp::Affine => true,
        Warp::Projective => s.warp[0].abs() + s.warp[1].abs() < 0.5,
        Warp::Quadratic => s.warp.iter().all(|q| q.abs() < 0.5 * h),
    };
    !(moved <= options.max_shift)
        || !(low_gain > 0.0)
        || !s.offset.is_finite()
        || !warp
        || degenerate(s.a, start_a, options.max_scale)
}

/// The unknowns' current values in step order (the prior pulls the extra ones to 0).
pub(super) fn unknowns(s: &RichState, layout: &Layout) -> [f64; R] {
    let mut x = [0.0; R];
    x[..2].copy_from_slice(&s.b);
    x[2..6].copy_from_slice(&s.a);
    x[6..6 + layout.extra].copy_from_slice(&s.warp[..layout.extra]);
    if layout.template_side && layout.warp == Warp::Quadratic {
        // The step's `P` is in template pixels (`Q = A P`): the prior pulls `A^-1 Q` to 0.
        let [a11, a12, a21, a22] = s.a;
        let det = a11 * a22 - a12 * a21;
        for k in 0..3 {
            let (qu, qv) = (s.warp[k], s.warp[3 + k]);
            x[6 + k] = (a22 * qu - a12 * qv) / det;
            x[9 + k] = (-a21 * qu + a11 * qv) / det;
        }
    }
    x[layout.gain()] = s.gain[0];
    x[layout.offset()] = s.offset;
    if layout.slopes {
        x[layout.slope()] = s.gain[1];
        x[layout.slope() + 1] = s.gain[2];
    }
    x
}
