//! One evaluation of the richer model at a state: its residuals and, with the Jacobian's
//! columns (the search image's or the template's gradients, see the parent module), the
//! normal equations and the weighted correlation.

use super::super::resample::{bicubic, bilinear};
use super::super::sample::TemplatePatch;
use super::super::types::{ImageView, Interpolation, Warp};
use super::model::{warp, Layout, RichState, R};

/// The sums of one evaluation of the model at a state.
pub(super) struct Evaluation {
    /// `J^T J` (upper and lower), `J` the model's derivative (rows scaled by root weights).
    pub normal: [[f64; R]; R],
    /// `J^T e`.
    pub gradient: [f64; R],
    /// `e^T e`.
    pub square: f64,
    /// Weighted normalised cross-correlation of the template and the model `G S(W)`.
    pub correlation: f64,
}

/// Half the step of the central differences that give the search image's gradients,
/// pixels: close to the derivative on the capture's smooth texture.
const DIFF: f32 = 0.5;

/// Evaluates the model at `s`: residuals `T - offset - G S(W)` (root-weighted) into
/// `residuals`, and with `jacobian` the normal equations. `None` when a warped point (with
/// the gradients' reach) leaves the image.
pub(super) fn evaluate(
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
            // x -> x / (1 + p . xi): the template-side change -x (dp . xi).
            warp_columns(
                &mut row,
                layout.warp,
                [tx, ty],
                [dx, dy],
                1.0,
                [xi, eta],
                || -(tx * dx + ty * dy),
            );
        } else {
            let su = f64::from(
                sample(base, [off[0] + DIFF, off[1]]) - sample(base, [off[0] - DIFF, off[1]]),
            ) / (2.0 * f64::from(DIFF));
            let sv = f64::from(
                sample(base, [off[0], off[1] + DIFF]) - sample(base, [off[0], off[1] - DIFF]),
            ) / (2.0 * f64::from(DIFF));
            let (gu, gv) = (g * su, g * sv);
            // d/dp (A x / d) = -A x xi / d^2 (eta for p2).
            warp_columns(
                &mut row,
                layout.warp,
                [gu, gv],
                [dx, dy],
                d,
                [xi, eta],
                || -(gu * lin[0] + gv * lin[1]) / (d * d),
            );
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

/// The geometric columns of a Jacobian row from the image gradient `g` (search pixels'
/// worth, either side's): the shift, the linear part (`g x^T / d`), and the extra warp
/// terms; `along` gives the projective terms' common factor (each side its own).
#[inline(always)]
fn warp_columns(
    row: &mut [f64; R],
    warp: Warp,
    g: [f64; 2],
    x: [f64; 2],
    d: f64,
    [xi, eta]: [f64; 2],
    along: impl FnOnce() -> f64,
) {
    row[0] = g[0];
    row[1] = g[1];
    row[2] = g[0] * x[0] / d;
    row[3] = g[0] * x[1] / d;
    row[4] = g[1] * x[0] / d;
    row[5] = g[1] * x[1] / d;
    match warp {
        Warp::Affine => {}
        Warp::Projective => {
            let along = along();
            row[6] = along * xi;
            row[7] = along * eta;
        }
        Warp::Quadratic => {
            let m = [xi * xi, xi * eta, eta * eta];
            for k in 0..3 {
                row[6 + k] = g[0] * m[k];
                row[9 + k] = g[1] * m[k];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    //! The Jacobian columns against finite differences of the model.
    use super::super::model::{apply, Layout, RichState, R};
    use super::*;
    use crate::lsm::types::ExtraModel;

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
