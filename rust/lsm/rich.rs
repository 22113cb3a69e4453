//! The richer model of a converged match (issue 15; benches/README.md "track27", "lsm28"):
//! $\sum_x w(x) (T(x) - r_0 - G(x) S(W(x)))^2$ with a warp $W$ that has second-order terms
//! (projective or quadratic, [`Warp`]) and a gain $G(x) = g_0 + g_x \xi + g_y \eta$ that
//! varies across the patch ($\xi = x / h$, $\eta = y / h$, $h$ the half-width).
//!
//! Why: on a curved surface that turns (a limb), the template's texture is mapped into the
//! search image by a map whose compression varies across the 15 px patch, and its shading
//! varies across it. The affine + gain least squares then settles 0.1-0.5 px from the
//! material point (track27: a turning plane is matched at the truth, a turning 10 cm
//! cylinder is not). Every extra term vanishes at the template point, so the matched
//! centre is still `b`, the material point's position.
//!
//! Staged: the extra unknowns are freed only after the affine match has converged (a
//! settled centre and shape; on a smooth 7 cm texture the second-order terms are barely
//! observable from far). Two Jacobians: the search image's own gradients at the warped
//! points (central differences half a pixel apart), the update added (its fixed point is
//! the least-squares optimum), or the template's gradients with the update composed on the
//! template side (the affine loop's choice, `gauss_newton`; its fixed point is the optimum
//! where the model fits). A zero-mean prior (Tikhonov) on the extra terms, as
//! pseudo-observations weighted by the residual variance, keeps a poorly conditioned patch
//! from trading the centre against them; with `fallback` a match the richer model cannot
//! settle keeps its affine result (measured in benches/README.md, "lsm28": on oblique views
//! the richer model often does not converge within its iterations).

use super::dense::{general_inverse, product, product_transposed, Cholesky, MAX};
use super::gauss_newton::{Outcome, State};
use super::line::degenerate;
use super::multi::to_parameters;
use super::normal::Sums;
use super::resample::{bicubic, bilinear};
use super::sample::TemplatePatch;
use super::types::{ExtraModel, ImageView, Interpolation, MatchOptions, Status, Warp};

/// Most unknowns: shift 2, linear part 4, quadratic terms 6, gain, offset, gain slopes 2.
pub(crate) const R: usize = 16;
const U: usize = MAX;

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
    warp: Warp,
    extra: usize,
    slopes: bool,
    /// The template-side Jacobian and composed update (`ExtraModel::template_jacobian`).
    template_side: bool,
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
    fn gain(&self) -> usize {
        6 + self.extra
    }
    fn offset(&self) -> usize {
        7 + self.extra
    }
    fn slope(&self) -> usize {
        8 + self.extra
    }
}

/// The warped position of template offset `(dx, dy)` and, for the Jacobian, the linear
/// part's divisor `d` (1 but for the projective warp) and `A x`.
#[inline(always)]
fn warp(s: &RichState, layout: &Layout, dx: f64, dy: f64, h: f64) -> ([f64; 2], f64, [f64; 2]) {
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

/// The sums of one evaluation of the model at a state.
struct Evaluation {
    /// `J^T J` (upper and lower), `J` the model's derivative (rows scaled by root weights).
    normal: [[f64; R]; R],
    /// `J^T e`.
    gradient: [f64; R],
    /// `e^T e`.
    square: f64,
    /// Weighted normalised cross-correlation of the template and the model `G S(W)`.
    correlation: f64,
}

/// Half the step of the central differences that give the search image's gradients,
/// pixels: close to the derivative on the capture's smooth texture.
const DIFF: f32 = 0.5;

/// Evaluates the model at `s`: residuals `T - offset - G S(W)` (root-weighted) into
/// `residuals`, and with `jacobian` the normal equations. `None` when a warped point (with
/// the gradients' reach) leaves the image.
fn evaluate(
    patch: &TemplatePatch,
    image: &ImageView<'_>,
    s: &RichState,
    layout: &Layout,
    interpolation: Interpolation,
    jacobian: bool,
    residuals: &mut [f32],
) -> Option<Evaluation> {
    let n = patch.len();
    let h = (patch.size / 2) as f64;
    let margin = match interpolation {
        Interpolation::Bilinear => 0.0,
        Interpolation::Bicubic => 1.0,
    } + f64::from(DIFF);
    let (w_max, h_max) = (
        (image.width - 1) as f64 - margin,
        (image.height - 1) as f64 - margin,
    );
    let sample = |base: [f64; 2], off: [f32; 2]| match interpolation {
        Interpolation::Bilinear => bilinear(image, base, off),
        Interpolation::Bicubic => bicubic(image, base, off),
    };
    let weighted = patch.weighted();
    let p = layout.unknowns;
    let mut normal = [[0.0; R]; R];
    let mut gradient = [0.0; R];
    let (mut square, mut wm, mut wmm, mut wmt) = (0.0, 0.0, 0.0, 0.0);
    let mut row = [0.0; R];
    for i in 0..n {
        let (dx, dy) = (f64::from(patch.dx[i]), f64::from(patch.dy[i]));
        let (at, d, lin) = warp(s, layout, dx, dy, h);
        // Written so that NaN fails.
        if !(at[0] >= margin && at[0] <= w_max && at[1] >= margin && at[1] <= h_max) {
            return None;
        }
        let base = [at[0].floor(), at[1].floor()];
        let off = [(at[0] - base[0]) as f32, (at[1] - base[1]) as f32];
        let value = f64::from(sample(base, off));
        let (xi, eta) = (dx / h, dy / h);
        let g = s.gain[0] + s.gain[1] * xi + s.gain[2] * eta;
        let r = if weighted {
            f64::from(patch.root_weight[i])
        } else {
            1.0
        };
        let t = f64::from(patch.value[i]);
        let model = s.offset + g * value;
        let e = t - r * model;
        residuals[i] = e as f32;
        square += e * e;
        // Weighted sums of the model for the correlation (`t` is already `r T`).
        wm += r * r * model;
        wmm += r * r * model * model;
        wmt += r * model * t;
        if !jacobian {
            continue;
        }
        if layout.template_side {
            // `G grad S A` from the template: `grad T = G grad S A + S grad G` where the
            // model fits. `geo` holds the root-weighted gradients.
            let unweigh = if r > 0.0 { 1.0 / r } else { 0.0 };
            let tx = f64::from(patch.geo[i]) * unweigh - value * s.gain[1] / h;
            let ty = f64::from(patch.geo[n + i]) * unweigh - value * s.gain[2] / h;
            row[0] = tx;
            row[1] = ty;
            row[2] = tx * dx;
            row[3] = tx * dy;
            row[4] = ty * dx;
            row[5] = ty * dy;
            match layout.warp {
                Warp::Affine => {}
                Warp::Projective => {
                    // x -> x / (1 + p . xi): the template-side change -x (dp . xi).
                    let along = -(tx * dx + ty * dy);
                    row[6] = along * xi;
                    row[7] = along * eta;
                }
                Warp::Quadratic => {
                    let m = [xi * xi, xi * eta, eta * eta];
                    for k in 0..3 {
                        row[6 + k] = tx * m[k];
                        row[9 + k] = ty * m[k];
                    }
                }
            }
        } else {
            let su = f64::from(
                sample(base, [off[0] + DIFF, off[1]]) - sample(base, [off[0] - DIFF, off[1]]),
            ) / (2.0 * f64::from(DIFF));
            let sv = f64::from(
                sample(base, [off[0], off[1] + DIFF]) - sample(base, [off[0], off[1] - DIFF]),
            ) / (2.0 * f64::from(DIFF));
            let (gu, gv) = (g * su, g * sv);
            row[0] = gu;
            row[1] = gv;
            row[2] = gu * dx / d;
            row[3] = gu * dy / d;
            row[4] = gv * dx / d;
            row[5] = gv * dy / d;
            match layout.warp {
                Warp::Affine => {}
                Warp::Projective => {
                    // d/dp (A x / d) = -A x xi / d^2 (eta for p2).
                    let along = -(gu * lin[0] + gv * lin[1]) / (d * d);
                    row[6] = along * xi;
                    row[7] = along * eta;
                }
                Warp::Quadratic => {
                    let m = [xi * xi, xi * eta, eta * eta];
                    for k in 0..3 {
                        row[6 + k] = gu * m[k];
                        row[9 + k] = gv * m[k];
                    }
                }
            }
        }
        row[layout.gain()] = value;
        row[layout.offset()] = 1.0;
        if layout.slopes {
            row[layout.slope()] = xi * value;
            row[layout.slope() + 1] = eta * value;
        }
        for k in 0..p {
            let x = row[k] * r;
            gradient[k] += x * e;
            for l in k..p {
                normal[k][l] += x * row[l] * r;
            }
        }
    }
    for k in 0..p {
        for l in 0..k {
            normal[k][l] = normal[l][k];
        }
    }
    let total = patch.weight_total;
    let (mean_t, mean_m) = (patch.value_sum / total, wm / total);
    let st = wmt - total * mean_m * mean_t;
    let ss = wmm - total * mean_m * mean_m;
    let tt = patch.value_square - total * mean_t * mean_t;
    Some(Evaluation {
        normal,
        gradient,
        square,
        correlation: st / (ss * tt).sqrt(),
    })
}

/// The prior's weight per unknown (0 where none): the residual variance over the prior's
/// variance, in the units of each unknown.
fn prior(s: &RichState, layout: &Layout, model: &ExtraModel, variance: f64, h: f64) -> [f64; R] {
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
fn apply(s: &mut RichState, step: &[f64; R], layout: &Layout, h: f64) -> (f64, f64) {
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
fn ran_away(
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

/// Refines a converged affine match (`state`) with the richer model of
/// `options.extra`; the outcome carries the richer model's centre and linear part as the
/// affine map, `g0` as the gain, its $\sigma_0$ (redundancy `sum w` minus the unknowns),
/// the correlation of the template with `G S(W)`, and the covariance of
/// `[u, v, A, g0, offset]` from the richer normal equations (prior included), in the step
/// coordinates the affine path reports. `residuals` gets the final residuals.
#[allow(clippy::too_many_arguments)]
pub(crate) fn refine(
    patch: &TemplatePatch,
    image: &ImageView<'_>,
    state: State,
    start_a: [f64; 4],
    start_b: [f64; 2],
    options: &MatchOptions,
    iterations: u32,
    residuals: &mut [f32],
) -> Outcome {
    let model = &options.extra;
    let layout = Layout::new(model);
    let h = (patch.size / 2) as f64;
    let p = layout.unknowns;
    let mut s = RichState {
        a: state.a,
        b: state.b,
        warp: [0.0; 6],
        gain: [state.gain, 0.0, 0.0],
        offset: state.offset,
    };
    let to_state = |s: &RichState| State {
        a: s.a,
        b: s.b,
        gain: s.gain[0],
        offset: s.offset,
    };
    let redundancy = patch.weight_total - p as f64;
    if !(redundancy >= 1.0) {
        // A masked patch whose total weight barely exceeds the affine match's floor (16)
        // leaves the richer model (up to 16 unknowns) no redundancy: no variance, no
        // covariance.
        return Outcome::failed(Status::LowTexture, state, iterations);
    }
    // The model at a state with the prior's weights on the normal matrix's diagonal: the
    // equations of each step and, at the end, of the covariance.
    let regularised = |s: &RichState, residuals: &mut [f32]| {
        let ev = evaluate(
            patch,
            image,
            s,
            &layout,
            options.interpolation,
            true,
            residuals,
        )?;
        let lambda = prior(s, &layout, model, ev.square / redundancy, h);
        let mut normal = ev.normal;
        for k in 0..p {
            normal[k][k] += lambda[k];
        }
        Some((ev, normal, lambda))
    };
    let mut status = Status::MaxIterations;
    let mut taken = iterations;
    for _ in 0..model.iterations {
        let Some((ev, normal, lambda)) = regularised(&s, residuals) else {
            return Outcome::failed(Status::LeftImage, to_state(&s), taken);
        };
        let mut gradient = ev.gradient;
        let current = unknowns(&s, &layout);
        for k in 0..p {
            gradient[k] -= lambda[k] * current[k];
        }
        let Some(chol) = Cholesky::new(&normal, p) else {
            return Outcome::failed(Status::LowTexture, to_state(&s), taken);
        };
        let step = chol.solve(&gradient);
        let (shift, change) = apply(&mut s, &step, &layout, h);
        taken += 1;
        if ran_away(&s, start_a, start_b, options, h) {
            return Outcome::failed(Status::Diverged, to_state(&s), taken);
        }
        if shift < options.tolerance && !(change >= options.tolerance) {
            status = Status::Converged;
            break;
        }
    }
    let Some((ev, normal, _)) = regularised(&s, residuals) else {
        return Outcome::failed(Status::LeftImage, to_state(&s), taken);
    };
    let sigma0 = (ev.square / redundancy).sqrt();
    let Some(chol) = Cholesky::new(&normal, p) else {
        return Outcome::failed(Status::LowTexture, to_state(&s), taken);
    };
    let inverse = chol.inverse();
    // The block of `[u, v, a11, a12, a21, a22, g0, offset]` (search-side: mapped back to
    // the affine path's step coordinates, `L^-1 C L^-T`, `L` its step -> parameter map).
    let index = [0, 1, 2, 3, 4, 5, layout.gain(), layout.offset()];
    let mut block = [[0.0; U]; U];
    for (i, &fi) in index.iter().enumerate() {
        for (j, &fj) in index.iter().enumerate() {
            block[i][j] = inverse[fi][fj];
        }
    }
    // A template-side step is already in those coordinates.
    let cofactor = if layout.template_side {
        block
    } else {
        let Some(back) = general_inverse(&to_parameters(s.a)) else {
            return Outcome::failed(Status::Diverged, to_state(&s), taken);
        };
        product_transposed(&product(&back, &block), &back)
    };
    Outcome {
        status,
        state: to_state(&s),
        iterations: taken,
        sigma0,
        correlation: ev.correlation,
        cofactor,
        map: cofactor,
        sums: Sums::default(),
    }
}

/// The unknowns' current values in step order (the prior pulls the extra ones to 0).
fn unknowns(s: &RichState, layout: &Layout) -> [f64; R] {
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

#[cfg(test)]
mod tests {
    //! The Jacobian columns against finite differences of the model.
    use super::*;

    fn image(width: usize, height: usize) -> Vec<f32> {
        // A smooth texture with a shading ramp, like the capture's (periods of tens of px).
        (0..width * height)
            .map(|i| {
                let (u, v) = ((i % width) as f32, (i / width) as f32);
                100.0 + 40.0 * (u / 7.3 + 0.4).sin() * (v / 5.9 + 1.1).sin() + 0.3 * u
            })
            .collect()
    }

    /// The model `r (offset + G S(W))` at every patch pixel, from `evaluate`'s residuals.
    fn model(
        patch: &TemplatePatch,
        view: &ImageView<'_>,
        s: &RichState,
        layout: &Layout,
    ) -> Vec<f64> {
        let mut e = vec![0.0f32; patch.len()];
        evaluate(
            patch,
            view,
            s,
            layout,
            Interpolation::Bicubic,
            false,
            &mut e,
        )
        .unwrap();
        (0..patch.len())
            .map(|i| f64::from(patch.value[i]) - f64::from(e[i]))
            .collect()
    }

    #[test]
    fn jacobian_columns_match_finite_differences() {
        let (w, hgt) = (80, 70);
        let data = image(w, hgt);
        let view = ImageView {
            data: &data,
            width: w,
            height: hgt,
        };
        let mut patch = TemplatePatch::default();
        assert!(patch.sample(&view, [40.3, 33.6], 15, Interpolation::Bicubic));
        for (warp, slopes) in [
            (Warp::Affine, true),
            (Warp::Projective, true),
            (Warp::Quadratic, true),
            (Warp::Quadratic, false),
        ] {
            let extra = ExtraModel {
                iterations: 5,
                warp,
                gain_gradient: slopes,
                ..ExtraModel::default()
            };
            let layout = Layout::new(&extra);
            let s = RichState {
                a: [1.05, 0.1, -0.07, 0.93],
                b: [40.8, 33.1],
                warp: match warp {
                    Warp::Projective => [0.05, -0.03, 0.0, 0.0, 0.0, 0.0],
                    _ => [0.3, -0.2, 0.1, 0.25, 0.05, -0.15],
                },
                gain: [
                    1.1,
                    if slopes { 0.05 } else { 0.0 },
                    if slopes { -0.04 } else { 0.0 },
                ],
                offset: 3.0,
            };
            let mut e = vec![0.0f32; patch.len()];
            let ev = evaluate(
                &patch,
                &view,
                &s,
                &layout,
                Interpolation::Bicubic,
                true,
                &mut e,
            )
            .unwrap();
            // Finite-difference columns of the model (central, in the unknowns' own step).
            let columns: Vec<Vec<f64>> = (0..layout.unknowns)
                .map(|k| {
                    let eps = 1e-3;
                    let mut step = [0.0; R];
                    step[k] = eps;
                    let (mut plus, mut minus) = (s, s);
                    apply(&mut plus, &step, &layout, 7.0);
                    step[k] = -eps;
                    apply(&mut minus, &step, &layout, 7.0);
                    let (mp, mm) = (
                        model(&patch, &view, &plus, &layout),
                        model(&patch, &view, &minus, &layout),
                    );
                    mp.iter()
                        .zip(&mm)
                        .map(|(a, b)| (a - b) / (2.0 * eps))
                        .collect()
                })
                .collect();
            let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
            for k in 0..layout.unknowns {
                // `J^T e` (signs included) and `J^T J` against the finite differences',
                // relative to the columns' lengths (the analytic gradients are central
                // differences half a pixel apart: ~1% off the interpolant's derivative on
                // this smooth texture).
                let fd_e = dot(
                    &columns[k],
                    &e.iter().map(|&x| f64::from(x)).collect::<Vec<_>>(),
                );
                let length = dot(&columns[k], &columns[k]).sqrt();
                let e_length = e.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>().sqrt();
                assert!(
                    (ev.gradient[k] - fd_e).abs() <= 0.03 * length * e_length,
                    "{warp:?} slopes {slopes}: unknown {k}: J^T e {} vs {fd_e}",
                    ev.gradient[k]
                );
                for l in 0..layout.unknowns {
                    let fd = dot(&columns[k], &columns[l]);
                    let scale = length * dot(&columns[l], &columns[l]).sqrt();
                    assert!(
                        (ev.normal[k][l] - fd).abs() <= 0.03 * scale,
                        "{warp:?} slopes {slopes}: J^T J [{k}][{l}] {} vs {fd}",
                        ev.normal[k][l]
                    );
                }
            }
        }
    }
}
