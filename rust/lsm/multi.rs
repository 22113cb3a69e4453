//! One point matched into every search image, and the joint covariance of all of them.
//!
//! Without a coupling constraint the normal equations of different search images do not
//! share unknowns, so each image is solved on its own (8 unknowns). The estimates are still
//! correlated: every search image is matched against the same noisy template. With
//! $e_s = n_T - r_{1s} n_s$ the residual noise of image $s$ and $K_s = M_s G_s^\top$ the
//! estimator's linear map (`sandwich`), $\mathrm{Cov}(\hat p_s, \hat p_t) = \sigma_T^2 M_s
//! G_s^\top G_t M_t^\top$ for $s \ne t$, where $\sigma_T^2$, the template's share of the noise, is estimated
//! from the correlation of the residuals of different search images.

use super::dense::{product, product_transposed, MAX};
use super::gauss_newton::{match_image, work_len, Line, Outcome, State};
use super::sample::TemplatePatch;
use super::types::{ImageView, MatchOptions, Stage, Status, PARAMETERS};

const U: usize = MAX;
/// Least total weight of a weighted template patch: twice the unknowns of a search image.
const MIN_WEIGHT: f64 = 2.0 * U as f64;

/// Per-worker scratch, reused from point to point.
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    patch: TemplatePatch,
    samples: Vec<f32>,
    residuals: Vec<f32>,
    work: Vec<f32>,
    outcomes: Vec<Outcome>,
    /// Per search image: `L_s M_s`, the estimator's map to the parameters.
    maps: Vec<[[f64; U]; U]>,
    estimated: Vec<usize>,
}

/// What one point's match writes: per search image `s`, entry `s` of each slice; the
/// covariance is the point's `8S x 8S` block.
pub(crate) struct PointOutput<'a> {
    pub status: &'a mut [u8],
    pub affine: &'a mut [[f64; 6]],
    pub radiometry: &'a mut [[f64; 2]],
    pub sigma0: &'a mut [f64],
    pub correlation: &'a mut [f64],
    pub iterations: &'a mut [u32],
    pub covariance: &'a mut [f64],
    pub stage: &'a mut [Stage],
}

/// Matches the template patch around `point` into every search image.
#[allow(clippy::too_many_arguments)]
pub(crate) fn match_point(
    template: &ImageView<'_>,
    weights: Option<&ImageView<'_>>,
    point: [f64; 2],
    searches: &[ImageView<'_>],
    starts: &[[f64; 6]],
    lines: Option<&[[f64; 3]]>,
    options: &MatchOptions,
    scratch: &mut Scratch,
    out: PointOutput<'_>,
) {
    let s_count = searches.len();
    let n = options.size * options.size;
    let template_status = scratch.template(template, weights, point, options, s_count);
    scratch.outcomes.clear();
    for (s, image) in searches.iter().enumerate() {
        let line = lines.and_then(|l| Line::new(l[s]));
        let outcome = scratch.search(template_status, image, starts[s], line, options, s);
        out.status[s] = outcome.status as u8;
        out.affine[s] = outcome.state.affine();
        out.radiometry[s] = [outcome.state.gain, outcome.state.offset];
        out.sigma0[s] = outcome.sigma0;
        out.correlation[s] = outcome.correlation;
        out.iterations[s] = outcome.iterations;
        out.stage[s] = outcome.stage;
        scratch.outcomes.push(outcome);
    }
    joint_covariance(scratch, n, out.covariance);
}

impl Scratch {
    /// Samples (and weighs) the template patch around `point` and sizes the buffers for
    /// `searches` search images; the status every search image reports without a match
    /// when the patch cannot be matched, `None` when it can. The patch depends on nothing
    /// else, so the patches of one point matched into several search images share it
    /// (`super::pairs` samples it once for all of a point's target cameras).
    pub(crate) fn template(
        &mut self,
        template: &ImageView<'_>,
        weights: Option<&ImageView<'_>>,
        point: [f64; 2],
        options: &MatchOptions,
        searches: usize,
    ) -> Option<Status> {
        let size = options.size;
        let n = size * size;
        self.samples.resize(n * searches, 0.0);
        self.residuals.resize(n * searches, 0.0);
        self.work.resize(work_len(size), 0.0);
        if !self
            .patch
            .sample(template, point, size, options.interpolation)
        {
            Some(Status::LeftImage)
        } else if weights.is_some_and(|w| !(self.patch.weigh(w, point) > MIN_WEIGHT)) {
            // Fewer weighted pixels than unknowns (and a margin): nothing to fit.
            Some(Status::LowTexture)
        } else if !(self.patch.weakest_gradient() >= options.min_texture) {
            Some(Status::LowTexture)
        } else {
            None
        }
    }

    /// Matches the sampled template patch (`template` gave `template_status`) into
    /// `image` from `start`, with search image `s`'s slices of the samples and residuals.
    pub(crate) fn search(
        &mut self,
        template_status: Option<Status>,
        image: &ImageView<'_>,
        start: [f64; 6],
        line: Option<Line>,
        options: &MatchOptions,
        s: usize,
    ) -> Outcome {
        let n = options.size * options.size;
        match template_status {
            Some(status) => Outcome {
                status,
                state: State::from_affine(start),
                iterations: 0,
                sigma0: f64::NAN,
                correlation: f64::NAN,
                cofactor: [[f64::NAN; U]; U],
                map: [[f64::NAN; U]; U],
                sums: Default::default(),
                stage: Stage::NONE,
            },
            None => match_image(
                &self.patch,
                image,
                start,
                line,
                options,
                &mut self.samples[s * n..(s + 1) * n],
                &mut self.residuals[s * n..(s + 1) * n],
                &mut self.work,
            ),
        }
    }
}

/// The `8 x 8` covariance block of one search image's own parameters:
/// `sigma_0^2 L C L^T` with `C` the cofactor in step coordinates and `L` the step ->
/// parameter map ([`to_parameters`]); meaningful where the outcome has an estimate.
pub(crate) fn own_block(outcome: &Outcome) -> [[f64; U]; U] {
    let ls = to_parameters(outcome.state.a);
    let v = outcome.sigma0 * outcome.sigma0;
    let mut c = product_transposed(&product(&ls, &outcome.cofactor), &ls);
    c.iter_mut().flatten().for_each(|x| *x *= v);
    c
}

/// The step -> parameter map of one search image: `[d, D, gain, offset]` to
/// `[u, v, a11, a12, a21, a22, gain, offset]` at the map `a` (`Δb = A d`, `ΔA = A D`).
pub(crate) fn to_parameters(a: [f64; 4]) -> [[f64; U]; U] {
    let [a11, a12, a21, a22] = a;
    let mut l = [[0.0; U]; U];
    l[0][0] = a11;
    l[0][1] = a12;
    l[1][0] = a21;
    l[1][1] = a22;
    // ΔA = A D, D = [[D11, D12], [D21, D22]] at step indices 2, 3, 4, 5.
    l[2][2] = a11;
    l[2][4] = a12;
    l[3][3] = a11;
    l[3][5] = a12;
    l[4][2] = a21;
    l[4][4] = a22;
    l[5][3] = a21;
    l[5][5] = a22;
    l[6][6] = 1.0;
    l[7][7] = 1.0;
    l
}

/// Writes the `8S x 8S` covariance: NaN rows and columns for images without an estimate.
fn joint_covariance(scratch: &mut Scratch, n: usize, covariance: &mut [f64]) {
    let s_count = scratch.outcomes.len();
    let width = PARAMETERS * s_count;
    covariance.fill(f64::NAN);
    scratch.maps.clear();
    scratch.estimated.clear();
    for (s, o) in scratch.outcomes.iter().enumerate() {
        scratch
            .maps
            .push(product(&to_parameters(o.state.a), &o.map));
        if o.status.has_estimate() {
            scratch.estimated.push(s);
        }
    }
    let scratch = &*scratch;
    let (outcomes, maps, estimated) = (&scratch.outcomes, &scratch.maps, &scratch.estimated);
    let redundancy = scratch.patch.weight_total - U as f64;
    // The template's noise variance: residuals of two search images share only it.
    let mut template_variance = 0.0;
    let mut pairs = 0usize;
    let mut cap = f64::INFINITY;
    for (i, &s) in estimated.iter().enumerate() {
        cap = cap.min(outcomes[s].sigma0 * outcomes[s].sigma0);
        for &t in &estimated[i + 1..] {
            let (rs, rt) = (
                &scratch.residuals[s * n..(s + 1) * n],
                &scratch.residuals[t * n..(t + 1) * n],
            );
            let shared: f64 = rs.iter().zip(rt).map(|(&a, &b)| a as f64 * b as f64).sum();
            template_variance += shared / redundancy;
            pairs += 1;
        }
    }
    if pairs > 0 {
        template_variance = (template_variance / pairs as f64).clamp(0.0, cap);
    }
    for &s in estimated.iter() {
        let ms = maps[s];
        for &t in estimated.iter() {
            let block = if s == t {
                own_block(&outcomes[s])
            } else {
                let mt = maps[t];
                let cross = cross_normal(scratch, s, t, n);
                let mut c = product_transposed(&product(&ms, &cross), &mt);
                c.iter_mut().flatten().for_each(|x| *x *= template_variance);
                c
            };
            for i in 0..U {
                let row = (PARAMETERS * s + i) * width + PARAMETERS * t;
                covariance[row..row + U].copy_from_slice(&block[i]);
            }
        }
    }
}

/// `G_s^T G_t`: the rows of `G_s` are `[g (6), S_s, 1]` with the template's gradient
/// columns `g` shared by every search image.
fn cross_normal(scratch: &Scratch, s: usize, t: usize, n: usize) -> [[f64; U]; U] {
    let patch = &scratch.patch;
    let (os, ot) = (&scratch.outcomes[s].sums, &scratch.outcomes[t].sums);
    let (ss, st) = (
        &scratch.samples[s * n..(s + 1) * n],
        &scratch.samples[t * n..(t + 1) * n],
    );
    let mut m = [[0.0; U]; U];
    for k in 0..6 {
        m[k][..6].copy_from_slice(&patch.geo_normal[k * 6..k * 6 + 6]);
        m[k][6] = ot.geo_search[k];
        m[k][7] = patch.geo_sum[k];
        m[6][k] = os.geo_search[k];
        m[7][k] = patch.geo_sum[k];
    }
    m[6][6] = ss.iter().zip(st).map(|(&a, &b)| a as f64 * b as f64).sum();
    m[6][7] = os.search;
    m[7][6] = ot.search;
    m[7][7] = patch.weight_total;
    m
}
