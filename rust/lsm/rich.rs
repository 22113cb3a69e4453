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

mod evaluate;
mod model;

use super::dense::{general_inverse, product, product_transposed, Cholesky, MAX};
use super::gauss_newton::{Outcome, State};
use super::multi::to_parameters;
use super::normal::Sums;
use super::sample::TemplatePatch;
use super::types::{ImageView, MatchOptions, Stage, Status};
use evaluate::evaluate;
use model::{apply, prior, ran_away, unknowns, Layout, RichState, R};

const U: usize = MAX;

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
    let Some(cofactor) = covariance(&chol.inverse(), &s, &layout) else {
        return Outcome::failed(Status::Diverged, to_state(&s), taken);
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
        stage: Stage::NONE,
    }
}

/// The covariance block of `[u, v, a11, a12, a21, a22, g0, offset]` from the inverse of
/// the richer (regularised) normal matrix, in the affine path's step coordinates; `None`
/// when the linear part cannot be inverted.
fn covariance(inverse: &[[f64; R]; R], s: &RichState, layout: &Layout) -> Option<[[f64; U]; U]> {
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
    Some(if layout.template_side {
        block
    } else {
        let back = general_inverse(&to_parameters(s.a))?;
        product_transposed(&product(&back, &block), &back)
    })
}
