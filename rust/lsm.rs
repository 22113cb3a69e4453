//! Least-squares matching (Gruen 1985; SPEC 7): a template patch around a point of the
//! template image is found in one or several search images by Gauss-Newton on
//! $\sum_x (T(x) - r_0 - r_1 S(A x + b))^2$, with an affine map $(A, b)$ (6 unknowns), gain
//! $r_1$ and offset $r_0$ per search image, bilinear resampling, and optionally the
//! matched centre $b$ held on a line (the epipolar line of the point: multi-photo
//! geometrically constrained matching, Gruen & Baltsavias 1988) as a hard or soft
//! constraint. It stops when the centre's update is below `tolerance` (0.01 px).
//!
//! Every match reports a [`Status`], $\sigma_0$, the normalised cross-correlation, the
//! iterations, and the joint covariance of all search images' parameters (with the cross
//! terms the shared template induces, for forward intersection). A bad patch never makes
//! the batch fail: it gets its status.
//!
//! Submodules: `sample` (template patch and gradients), `resample` (bilinear and bicubic
//! resampling), `normal` (normal equations from patch sums), `gauss_newton` (one search
//! image; `line` its epipolar constraint), `sandwich` (its covariance under noisy template
//! gradients), `rich` (second-order warp terms and a gain gradient after convergence, an
//! option), `multi` (all search images of a point, joint covariance), `pairs` (many patches
//! across many camera pairs in one parallel call), `single` (one point into one search image,
//! outside a batch: the frame step's per-view pipeline), `dense` (Cholesky and inverses of small
//! systems), `types` (options, status, outputs).

#[cfg(target_arch = "x86_64")]
mod cubic;
#[cfg(all(test, target_arch = "x86_64"))]
mod cubic_tests;
mod dense;
mod dots;
#[cfg(target_arch = "x86_64")]
mod gather;
mod gauss_newton;
mod line;
mod multi;
mod normal;
mod pairs;
#[cfg(test)]
mod pairs_tests;
mod resample;
mod rich;
mod sample;
mod sandwich;
mod single;
#[cfg(test)]
mod tests;
mod types;

pub use pairs::match_pair_patches;
pub(crate) use resample::wide;
pub(crate) use single::{check_image, check_options, match_single, SingleScratch};
pub use types::{
    ExtraModel, ImageView, Interpolation, MatchOptions, MatchOutput, Refined, Stage, Status, Warp,
    PARAMETERS,
};

use rayon::prelude::*;

use crate::error::{check_finite, Error, Result};
use multi::{match_point, PointOutput, Scratch};

/// Matches the template patch around each of `points` into every search image, in
/// parallel over points.
///
/// `starts[p * S + s]` is the start map of point `p` in search image `s` (row-major 2x3,
/// see [`MatchOutput`]); `lines`, when given, holds `[a, b, c]` per point and search image
/// with the matched centre on `a u + b v + c = 0` (a row that is not finite or has
/// `a = b = 0` leaves that match unconstrained). Results go to `out`, indexed the same way.
///
/// # Errors
/// [`Error::InvalidOption`] for options out of range, [`Error::Empty`] for no search
/// images, [`Error::WrongLength`] for an image whose data does not match its size or is
/// smaller than 2x2, [`Error::LengthMismatch`] for starts or lines
/// of the wrong length, [`Error::NonFinite`] for a non-finite point or start, and
/// [`Error::InvalidOption`] for a start map whose linear part has no positive determinant,
/// and [`Error::OutputSize`] for output buffers of the wrong length.
pub fn match_patches(
    template: &ImageView<'_>,
    points: &[[f64; 2]],
    searches: &[ImageView<'_>],
    starts: &[[f64; 6]],
    lines: Option<&[[f64; 3]]>,
    options: &MatchOptions,
    out: MatchOutput<'_>,
) -> Result<()> {
    match_weighted_patches(
        template, None, points, searches, starts, lines, options, out,
    )
}

/// [`match_patches`] by weighted least squares: `weights` (the template's size) gives each
/// template pixel a weight in `[0, 1]` (read bilinearly at the patch's pixels; values
/// outside are clamped), $\sum_x w(x) (T(x) - r_0 - r_1 S(A x + b))^2$. A silhouette mask
/// as weights makes a patch on the edge of a moving body match the body alone, not the
/// background in its corner. The normal equations, $\sigma_0$ (redundancy `sum w - 8`),
/// the correlation (weighted means and spreads) and the texture measure are all weighted;
/// a patch whose weights are all 1 is matched exactly as without weights, one whose total
/// weight is below 16 reports [`Status::LowTexture`]. The covariance of a weighted patch is
/// $\sigma_0^2 (G^\top W G)^{-1}$ (no sandwich: the template is taken noise-free).
///
/// # Errors
/// As [`match_patches`], and [`Error::WrongLength`] for weights whose size differs from the
/// template's.
#[allow(clippy::too_many_arguments)]
pub fn match_weighted_patches(
    template: &ImageView<'_>,
    weights: Option<&ImageView<'_>>,
    points: &[[f64; 2]],
    searches: &[ImageView<'_>],
    starts: &[[f64; 6]],
    lines: Option<&[[f64; 3]]>,
    options: &MatchOptions,
    out: MatchOutput<'_>,
) -> Result<()> {
    let mut stages = vec![Stage::NONE; out.status.len()];
    match_staged_patches(
        template,
        weights,
        points,
        searches,
        starts,
        lines,
        options,
        out,
        &mut stages,
    )
}

/// [`match_weighted_patches`] that also reports, per point and search image, what the
/// richer stage did and the affine centre it started from (`stages`, indexed as the
/// outputs; [`Stage::NONE`] where `options.extra` is off).
///
/// # Errors
/// As [`match_weighted_patches`], and [`Error::OutputSize`] for `stages` of the wrong
/// length.
#[allow(clippy::too_many_arguments)]
pub fn match_staged_patches(
    template: &ImageView<'_>,
    weights: Option<&ImageView<'_>>,
    points: &[[f64; 2]],
    searches: &[ImageView<'_>],
    starts: &[[f64; 6]],
    lines: Option<&[[f64; 3]]>,
    options: &MatchOptions,
    out: MatchOutput<'_>,
    stages: &mut [Stage],
) -> Result<()> {
    validate(template, points, searches, starts, lines, options, &out)?;
    if stages.len() != out.status.len() {
        return Err(Error::OutputSize {
            expected: out.status.len(),
            got: stages.len(),
        });
    }
    if let Some(w) = weights {
        let expected = template.width * template.height;
        if w.width != template.width || w.height != template.height || w.data.len() != expected {
            return Err(Error::WrongLength {
                argument: "weights",
                expected,
                got: w.data.len(),
            });
        }
    }
    let s = searches.len();
    let block = PARAMETERS * PARAMETERS * s * s;
    out.status
        .par_chunks_mut(s)
        .zip(out.affine.par_chunks_mut(s))
        .zip(out.radiometry.par_chunks_mut(s))
        .zip(out.sigma0.par_chunks_mut(s))
        .zip(out.correlation.par_chunks_mut(s))
        .zip(out.iterations.par_chunks_mut(s))
        .zip(out.covariance.par_chunks_mut(block))
        .zip(stages.par_chunks_mut(s))
        .enumerate()
        .for_each_init(
            Scratch::default,
            |scratch,
             (
                p,
                (
                    (
                        (((((status, affine), radiometry), sigma0), correlation), iterations),
                        covariance,
                    ),
                    stage,
                ),
            )| {
                match_point(
                    template,
                    weights,
                    points[p],
                    searches,
                    &starts[p * s..(p + 1) * s],
                    lines.map(|l| &l[p * s..(p + 1) * s]),
                    options,
                    scratch,
                    PointOutput {
                        status,
                        affine,
                        radiometry,
                        sigma0,
                        correlation,
                        iterations,
                        covariance,
                        stage,
                    },
                );
            },
        );
    Ok(())
}

fn validate(
    template: &ImageView<'_>,
    points: &[[f64; 2]],
    searches: &[ImageView<'_>],
    starts: &[[f64; 6]],
    lines: Option<&[[f64; 3]]>,
    options: &MatchOptions,
    out: &MatchOutput<'_>,
) -> Result<()> {
    validate_options(options)?;
    validate_shapes(template, points, searches, starts, lines, out)
}

/// The options' ranges (shared with [`match_pair_patches`]).
fn validate_options(options: &MatchOptions) -> Result<()> {
    let option = |argument, value: f64, ok: bool, expected| {
        if ok {
            Ok(())
        } else {
            Err(Error::InvalidOption {
                argument,
                value,
                expected,
            })
        }
    };
    let size = options.size;
    option(
        "size",
        size as f64,
        size >= 3 && size % 2 == 1 && size <= 255,
        "an odd integer from 3 to 255",
    )?;
    option(
        "max_iterations",
        options.max_iterations as f64,
        options.max_iterations >= 1,
        "at least 1",
    )?;
    for (argument, value) in [
        ("tolerance", options.tolerance),
        ("max_shift", options.max_shift),
    ] {
        option(
            argument,
            value,
            value > 0.0 && value.is_finite(),
            "a positive finite number",
        )?;
    }
    option(
        "max_scale",
        options.max_scale,
        options.max_scale > 1.0 && options.max_scale.is_finite(),
        "a finite number above 1",
    )?;
    for (argument, value) in [
        ("min_texture", options.min_texture),
        ("line_sigma", options.line_sigma),
    ] {
        option(
            argument,
            value,
            value >= 0.0 && value.is_finite(),
            "a finite number >= 0",
        )?;
    }
    let extra = &options.extra;
    for (argument, value) in [
        ("extra.warp_sigma", extra.warp_sigma),
        ("extra.gain_sigma", extra.gain_sigma),
    ] {
        option(
            argument,
            value,
            value >= 0.0 && value.is_finite(),
            "a finite number >= 0 (0: no prior)",
        )?;
    }
    option(
        "extra.skip_correlation",
        extra.skip_correlation,
        !extra.skip_correlation.is_nan(),
        "a number (infinite: never skipped)",
    )?;
    Ok(())
}

fn validate_shapes(
    template: &ImageView<'_>,
    points: &[[f64; 2]],
    searches: &[ImageView<'_>],
    starts: &[[f64; 6]],
    lines: Option<&[[f64; 3]]>,
    out: &MatchOutput<'_>,
) -> Result<()> {
    if searches.is_empty() {
        return Err(Error::Empty {
            argument: "search_images",
            needed: 1,
        });
    }
    for (argument, image) in std::iter::once(("template", template))
        .chain(searches.iter().map(|image| ("search_images", image)))
    {
        let expected = image.width.saturating_mul(image.height);
        if image.width < 2 || image.height < 2 || image.data.len() != expected {
            return Err(Error::WrongLength {
                argument,
                expected: expected.max(4),
                got: image.data.len(),
            });
        }
    }
    let pairs = points.len() * searches.len();
    if starts.len() != pairs {
        return Err(Error::LengthMismatch {
            argument: "initial",
            expected: pairs,
            got: starts.len(),
        });
    }
    if let Some(lines) = lines {
        if lines.len() != pairs {
            return Err(Error::LengthMismatch {
                argument: "epipolar",
                expected: pairs,
                got: lines.len(),
            });
        }
    }
    check_finite("points", points)?;
    check_finite("initial", starts)?;
    if let Some(m) = starts.iter().find(|m| !(m[0] * m[4] - m[1] * m[3] > 0.0)) {
        return Err(Error::InvalidOption {
            argument: "initial",
            value: m[0] * m[4] - m[1] * m[3],
            expected: "affine maps whose linear part has a positive determinant",
        });
    }
    let block = PARAMETERS * PARAMETERS * searches.len() * searches.len();
    for (expected, got) in [
        (pairs, out.status.len()),
        (pairs, out.affine.len()),
        (pairs, out.radiometry.len()),
        (pairs, out.sigma0.len()),
        (pairs, out.correlation.len()),
        (pairs, out.iterations.len()),
        (points.len() * block, out.covariance.len()),
    ] {
        if expected != got {
            return Err(Error::OutputSize { expected, got });
        }
    }
    Ok(())
}
