//! Gauss-Newton for one search image (SPEC 7): minimise
//! $\sum_x (T(x) - r_0 - r_1 S(A x + b))^2$ over the affine map $(A, b)$, gain $r_1$ and
//! offset $r_0$, optionally with the matched centre $b$ on a line.
//!
//! The update is composed on the template side: $A x + b \to A((I + D) x + d) + b$. Its
//! Jacobian $r_1 \nabla S^\top A\,[x, 1]$ equals $\nabla T^\top [x, 1]$ where the match
//! fits (the patches agree up to gain and offset), so the template's gradients stand in for
//! the resampled search patch's: the geometric 6x6 block of the normal equations is then
//! constant, and an iteration costs one bilinear resampling and nine dot products. The
//! residual is exact, so a fit that matches is still a fixed point.

use super::dense::{Cholesky, MAX};
use super::line::degenerate;
pub(crate) use super::line::Line;
use super::normal::Sums;
use super::resample::{sample_search, sample_search_ring};
use super::rich::refine;
use super::sample::{dot, TemplatePatch};
use super::sandwich::{meat, sandwich, sensitivity};
use super::types::{ImageView, MatchOptions, Refined, Stage, Status};

/// Unknowns per search image: `[d_u, d_v, D11, D12, D21, D22, gain, offset]`.
const U: usize = MAX;
/// The unknowns of the shift-only stage.
const SHIFT_ONLY: [usize; 4] = [0, 1, 6, 7];
const ALL: [usize; 8] = [0, 1, 2, 3, 4, 5, 6, 7];

/// The estimate: affine map `[a11, a12, a21, a22]`, centre `b`, gain, offset.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct State {
    pub a: [f64; 4],
    pub b: [f64; 2],
    pub gain: f64,
    pub offset: f64,
}

impl State {
    /// From a row-major 2x3 map `[a11, a12, u, a21, a22, v]`, gain 1 and offset 0.
    pub fn from_affine(m: [f64; 6]) -> Self {
        Self {
            a: [m[0], m[1], m[3], m[4]],
            b: [m[2], m[5]],
            gain: 1.0,
            offset: 0.0,
        }
    }

    /// The row-major 2x3 map.
    pub fn affine(&self) -> [f64; 6] {
        [
            self.a[0], self.a[1], self.b[0], self.a[2], self.a[3], self.b[1],
        ]
    }

    /// Applies a step `[d_u, d_v, D11, D12, D21, D22, gain, offset]`; returns the length
    /// of the centre's move, search pixels, and the largest change of an entry of the
    /// linear part `A` (search pixels per template pixel).
    fn apply(&mut self, step: &[f64; U]) -> (f64, f64) {
        let [a11, a12, a21, a22] = self.a;
        let [du, dv, d11, d12, d21, d22, dgain, doffset] = *step;
        let shift = [a11 * du + a12 * dv, a21 * du + a22 * dv];
        self.b = [self.b[0] + shift[0], self.b[1] + shift[1]];
        let a = [
            a11 * (1.0 + d11) + a12 * d21,
            a11 * d12 + a12 * (1.0 + d22),
            a21 * (1.0 + d11) + a22 * d21,
            a21 * d12 + a22 * (1.0 + d22),
        ];
        let linear = (0..4).map(|i| (a[i] - self.a[i]).abs()).fold(0.0, f64::max);
        self.a = a;
        self.gain += dgain;
        self.offset += doffset;
        (shift[0].hypot(shift[1]), linear)
    }
}

/// The result of matching one search image.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Outcome {
    pub status: Status,
    pub state: State,
    pub iterations: u32,
    pub sigma0: f64,
    pub correlation: f64,
    /// The covariance over `sigma_0^2`, in step coordinates: the sandwich
    /// `M (G^T G) M^T` (see `sandwich`; `(G^T G)^-1` when the widened patch leaves the
    /// image), constrained where a line applies.
    pub cofactor: [[f64; U]; U],
    /// The estimator's map `M` (a step is `M G^T e`), for the cross-image covariance.
    pub map: [[f64; U]; U],
    /// The sums at the final state (the cross-image covariance needs them).
    pub sums: Sums,
    /// What the richer stage did, and the affine centre it started from.
    pub stage: Stage,
}

impl Outcome {
    pub(crate) fn failed(status: Status, state: State, iterations: u32) -> Self {
        Self {
            status,
            state,
            iterations,
            sigma0: f64::NAN,
            correlation: f64::NAN,
            cofactor: [[f64::NAN; U]; U],
            map: [[f64::NAN; U]; U],
            sums: Sums::default(),
            stage: Stage::NONE,
        }
    }

    fn with_stage(self, stage: Stage) -> Self {
        Self { stage, ..self }
    }
}

/// How the line enters a step: hard (exactly on it) or soft (weight `w` on the
/// pseudo-observation of the distance).
#[derive(Debug, Clone, Copy)]
enum Constraint {
    Hard([f64; U], f64),
    Soft([f64; U], f64, f64),
}

/// Solves the normal equations restricted to `free`, with the line's constraint;
/// `None` when singular.
fn solve(
    normal: &[[f64; U]; U],
    gradient: &[f64; U],
    free: &[usize],
    constraint: Option<Constraint>,
) -> Option<[f64; U]> {
    let m = free.len();
    let mut a = [[0.0; U]; U];
    let mut r = [0.0; U];
    let mut c = [0.0; U];
    for (i, &fi) in free.iter().enumerate() {
        r[i] = gradient[fi];
        for (j, &fj) in free.iter().enumerate() {
            a[i][j] = normal[fi][fj];
        }
    }
    let mut hard = None;
    match constraint {
        Some(Constraint::Soft(cf, h, w)) => {
            for (i, &fi) in free.iter().enumerate() {
                r[i] += w * cf[fi] * h;
                for (j, &fj) in free.iter().enumerate() {
                    a[i][j] += w * cf[fi] * cf[fj];
                }
            }
        }
        Some(Constraint::Hard(cf, h)) => {
            for (i, &fi) in free.iter().enumerate() {
                c[i] = cf[fi];
            }
            hard = Some(h);
        }
        None => {}
    }
    let chol = Cholesky::new(&a, m)?;
    let mut x = chol.solve(&r);
    if let Some(h) = hard {
        let y = chol.solve(&c);
        let cy: f64 = (0..m).map(|i| c[i] * y[i]).sum();
        let cx: f64 = (0..m).map(|i| c[i] * x[i]).sum();
        if !(cy > 0.0) {
            return None;
        }
        let t = (h - cx) / cy;
        for i in 0..m {
            x[i] += t * y[i];
        }
    }
    let mut step = [0.0; U];
    for (i, &fi) in free.iter().enumerate() {
        step[fi] = x[i];
    }
    Some(step)
}

/// Matches the template patch into one search image from `start` (row-major 2x3 map).
/// `samples` and `residuals` are scratch of the patch's length, `work` of
/// [`work_len`]; on return `residuals` holds `T - offset - gain S` at the final state when
/// the outcome has an estimate.
pub(crate) fn match_image(
    patch: &TemplatePatch,
    image: &ImageView<'_>,
    start: [f64; 6],
    line: Option<Line>,
    options: &MatchOptions,
    samples: &mut [f32],
    residuals: &mut [f32],
    work: &mut [f32],
) -> Outcome {
    let mut state = State::from_affine(start);
    let start_a = state.a;
    if let Some(line) = line {
        let d = line.signed_distance(state.b);
        state.b = [
            state.b[0] - d * line.normal[0],
            state.b[1] - d * line.normal[1],
        ];
    }
    let start_b = state.b;
    let n = patch.weight_total;
    let hard = options.line_sigma == 0.0;
    let mut shift_only = options.shift_only_iterations > 0;
    let mut status = Status::MaxIterations;
    let mut iterations = 0u32;
    for it in 0..options.max_iterations {
        if shift_only && it >= options.shift_only_iterations {
            shift_only = false;
        }
        if !sample_search(
            image,
            state.a,
            state.b,
            patch,
            options.interpolation,
            samples,
        ) {
            return Outcome::failed(Status::LeftImage, state, iterations);
        }
        patch.weigh_samples(samples);
        let sums = Sums::new(patch, samples);
        let normal = sums.normal(patch);
        let gradient = sums.gradient(patch, &state);
        let free: &[usize] = if shift_only { &SHIFT_ONLY } else { &ALL };
        let constraint = line.map(|line| {
            let (c, h) = line.on_step(&state);
            if hard {
                Constraint::Hard(c, h)
            } else {
                let variance = sums.residual_square(patch, &state) / (n - free.len() as f64);
                let w = variance.max(0.0) / (options.line_sigma * options.line_sigma);
                Constraint::Soft(c, h, w)
            }
        });
        let Some(step) = solve(&normal, &gradient, free, constraint) else {
            return Outcome::failed(Status::LowTexture, state, iterations);
        };
        let (shift, linear) = state.apply(&step);
        iterations = it as u32 + 1;
        let moved = (state.b[0] - start_b[0]).hypot(state.b[1] - start_b[1]);
        if !(moved <= options.max_shift)
            || !(state.gain > 0.0)
            || !state.offset.is_finite()
            || degenerate(state.a, start_a, options.max_scale)
        {
            return Outcome::failed(Status::Diverged, state, iterations);
        }
        // The centre's update alone (SPEC 7) can be small by chance while the shape is
        // still far off (a first full step after the shift-only ones): the linear part
        // must have settled too, to the same tolerance per template pixel.
        if shift < options.tolerance && !(linear >= options.tolerance) {
            if shift_only {
                shift_only = false;
            } else {
                status = Status::Converged;
                break;
            }
        }
    }
    // The richer model (off by default) from the converged affine match; not with a line
    // (the temporal match it is for has none).
    if status == Status::Converged && options.extra.iterations > 0 && line.is_none() {
        // The affine match's own outcome first: its centre is reported beside the richer
        // one (a caller that smooths the richer model's departure from it needs no second
        // match), and its correlation decides whether the richer stage is worth running.
        let affine = finish(
            patch, image, state, line, options, status, iterations, samples, residuals, work,
        );
        let converged = affine.status == Status::Converged;
        let centre = if converged { state.b } else { [f64::NAN; 2] };
        let stage = |refined| Stage {
            affine: centre,
            refined,
        };
        if converged && affine.correlation >= options.extra.skip_correlation {
            return affine.with_stage(stage(Refined::Skipped));
        }
        // The richer stage overwrites the residuals; the affine ones are kept for the
        // fallback (the cross-image covariance reads them). `work` is free after `finish`.
        let n = residuals.len();
        work[..n].copy_from_slice(residuals);
        let refined = refine(
            patch, image, state, start_a, start_b, options, iterations, residuals,
        );
        if refined.status == Status::Converged || !options.extra.fallback {
            return refined.with_stage(stage(Refined::Reported));
        }
        residuals.copy_from_slice(&work[..n]);
        return affine.with_stage(stage(Refined::FellBack));
    }
    finish(
        patch, image, state, line, options, status, iterations, samples, residuals, work,
    )
}

/// Length of the scratch `match_image` needs beside samples and residuals: the widened
/// patch (padded) and six columns over the patch.
pub(crate) fn work_len(size: usize) -> usize {
    (size + 2).pow(2).div_ceil(8) * 8 + 6 * size * size
}

/// Precision and fit quality at the final state.
#[allow(clippy::too_many_arguments)]
fn finish(
    patch: &TemplatePatch,
    image: &ImageView<'_>,
    state: State,
    line: Option<Line>,
    options: &MatchOptions,
    status: Status,
    iterations: u32,
    samples: &mut [f32],
    residuals: &mut [f32],
    work: &mut [f32],
) -> Outcome {
    let size = patch.size;
    let (ring, columns) = work.split_at_mut((size + 2).pow(2).div_ceil(8) * 8);
    // The sandwich models the unweighted estimator's noise: a weighted patch gets
    // `(G^T W G)^-1`, the template taken noise-free.
    let widened = options.sandwich
        && !patch.weighted()
        && sample_search_ring(image, state.a, state.b, patch, options.interpolation, ring);
    if widened {
        for r in 0..size {
            let from = (r + 1) * (size + 2) + 1;
            samples[r * size..(r + 1) * size].copy_from_slice(&ring[from..from + size]);
        }
    } else if !sample_search(
        image,
        state.a,
        state.b,
        patch,
        options.interpolation,
        samples,
    ) {
        return Outcome::failed(Status::LeftImage, state, iterations);
    }
    patch.weigh_samples(samples);
    let sums = Sums::new(patch, samples);
    // Residuals, and the correlation from centred values: small numbers, so single
    // precision sums lose nothing that matters.
    let (gain, offset) = (state.gain as f32, state.offset as f32);
    let total = patch.weight_total;
    let (mean_t, mean_s) = (
        (patch.value_sum / total) as f32,
        (sums.search / total) as f32,
    );
    let (square, correlation) = if patch.weighted() {
        weighted_fit(patch, samples, residuals, [gain, offset], [mean_t, mean_s])
    } else {
        plain_fit(patch, samples, residuals, [gain, offset], [mean_t, mean_s])
    };
    let mut normal = sums.normal(patch);
    let n = total;
    let mut redundancy = n - U as f64;
    let mut pseudo = 0.0;
    let mut hard_c = None;
    let mut soft = None;
    if let Some(line) = line {
        redundancy += 1.0;
        let (c, _) = line.on_step(&state);
        if options.line_sigma == 0.0 {
            hard_c = Some(c);
        } else {
            let w = square / (n - U as f64) / (options.line_sigma * options.line_sigma);
            let d = line.signed_distance(state.b);
            pseudo = w * d * d;
            soft = Some((c, w));
        }
    }
    let sigma0 = ((square + pseudo) / redundancy).sqrt();
    let mut sandwiched = widened.then(|| {
        let b = sensitivity(patch, &sums, state.gain, ring, columns);
        // The template's share of the residual variance, the two images' noise taken equal.
        let share = 1.0 / (1.0 + state.gain * state.gain);
        (b, meat(&b, &normal, share))
    });
    if let Some((c, w)) = soft {
        let (b, m) = match sandwiched.as_mut() {
            Some((b, m)) => (Some(b), Some(m)),
            None => (None, None),
        };
        for x in std::iter::once(&mut normal).chain(b).chain(m) {
            for i in 0..U {
                for j in 0..U {
                    x[i][j] += w * c[i] * c[j];
                }
            }
        }
    }
    let Some(chol) = Cholesky::new(&normal, U) else {
        return Outcome::failed(Status::LowTexture, state, iterations);
    };
    let (cofactor, map) = match sandwiched.and_then(|(b, m)| sandwich(&b, &m, hard_c)) {
        Some(both) => both,
        None => {
            let mut cofactor = chol.inverse();
            if let Some(c) = hard_c {
                let y = chol.solve(&c);
                let cy: f64 = (0..U).map(|i| c[i] * y[i]).sum();
                for i in 0..U {
                    for j in 0..U {
                        cofactor[i][j] -= y[i] * y[j] / cy;
                    }
                }
            }
            (cofactor, cofactor)
        }
    };
    Outcome {
        status,
        state,
        iterations,
        sigma0,
        correlation,
        cofactor,
        map,
        sums,
        stage: Stage::NONE,
    }
}

/// Residuals `T - offset - gain S` into `residuals`; their sum of squares and the
/// normalised cross-correlation of the patches (centred values: small numbers, so single
/// precision sums lose nothing that matters).
fn plain_fit(
    patch: &TemplatePatch,
    samples: &[f32],
    residuals: &mut [f32],
    [gain, offset]: [f32; 2],
    [mean_t, mean_s]: [f32; 2],
) -> (f64, f64) {
    for ((e, &s), &t) in residuals.iter_mut().zip(samples.iter()).zip(&patch.value) {
        *e = t - offset - gain * s;
    }
    let square = dot(residuals, residuals);
    let mut lanes = [[0.0f32; 8]; 3];
    let (cs, rs) = samples.as_chunks::<8>();
    let (ct, rt) = patch.value.as_chunks::<8>();
    for (s, t) in cs.iter().zip(ct) {
        for l in 0..8 {
            let (s, t) = (s[l] - mean_s, t[l] - mean_t);
            lanes[0][l] += s * t;
            lanes[1][l] += s * s;
            lanes[2][l] += t * t;
        }
    }
    let [mut st, mut ss, mut tt] = lanes.map(|lane| lane.iter().map(|&x| x as f64).sum::<f64>());
    for (&s, &t) in rs.iter().zip(rt) {
        let (s, t) = ((s - mean_s) as f64, (t - mean_t) as f64);
        st += s * t;
        ss += s * s;
        tt += t * t;
    }
    (square, st / (ss * tt).sqrt())
}

/// [`plain_fit`] of a weighted patch: `samples` and the template's values are scaled by
/// the root weights `r`, so the residual is `r (T - offset - gain S)` and the correlation
/// the weighted one, `sum w (S - mean_S)(T - mean_T)` over the weighted spreads, with
/// weighted means.
fn weighted_fit(
    patch: &TemplatePatch,
    samples: &[f32],
    residuals: &mut [f32],
    [gain, offset]: [f32; 2],
    [mean_t, mean_s]: [f32; 2],
) -> (f64, f64) {
    let (mut st, mut ss, mut tt) = (0.0f64, 0.0f64, 0.0f64);
    for (((e, &s), &t), &r) in residuals
        .iter_mut()
        .zip(samples.iter())
        .zip(&patch.value)
        .zip(&patch.root_weight)
    {
        *e = t - offset * r - gain * s;
        let (s, t) = ((s - r * mean_s) as f64, (t - r * mean_t) as f64);
        st += s * t;
        ss += s * s;
        tt += t * t;
    }
    (dot(residuals, residuals), st / (ss * tt).sqrt())
}
