//! Many patches across many camera pairs in one call: the spatial matches of a tracked
//! frame (re-tie, re-acquisition, confirmation) gathered into one parallel batch.
//!
//! The tracker matches a point's patch from its reference camera into each other camera
//! that should see it: per frame ~80-100 camera pairs of a few dozen patches each. Called
//! pair by pair, the call's fixed cost dominates and rayon has too few patches to split
//! (speed1's profile: 0.36 CPU s a frame over ~99 calls, the frame on one core). Here the
//! frame's images are passed once and every patch names its own reference and target
//! image; the patches run in parallel. Each patch is matched by exactly the code the
//! per-pair call runs for a point with one search image ([`super::multi::match_point`]),
//! and no patch reads another's state, so a patch's result is bit-identical to the one
//! [`super::match_staged_patches`] gives it in its own pair's call.

use rayon::prelude::*;

use super::multi::{match_point, PointOutput, Scratch};
use super::types::{ImageView, MatchOptions, MatchOutput, Stage, PARAMETERS};
use super::validate_options;
use crate::error::{check_finite, Error, Result};

/// Matches patch `i`, around `points[i]` in image `cameras[i][0]`, into image
/// `cameras[i][1]` started at `starts[i]` (row-major 2x3, see [`MatchOutput`]), in parallel
/// over patches, weighing the template by `weights[cameras[i][0]]` where given.
///
/// `images[c]` is `None` for a camera no patch uses. Results go to `out` as for
/// [`super::match_patches`] with one search image (so `out.covariance` holds `64` entries per
/// patch) and to `stages` (one per patch).
///
/// # Errors
/// As [`super::match_staged_patches`] for the options, images, weights, points and starts;
/// [`Error::IndexOutOfRange`] for a camera index beyond `images`, [`Error::InvalidOption`]
/// for one naming a `None` image, [`Error::WrongLength`] for a reference's weights of
/// another size than its image, [`Error::LengthMismatch`] for
/// `weights`, `cameras` or `starts` not matching `images` / `points`.
#[allow(clippy::too_many_arguments)]
pub fn match_pair_patches(
    images: &[Option<ImageView<'_>>],
    weights: Option<&[Option<ImageView<'_>>]>,
    cameras: &[[usize; 2]],
    points: &[[f64; 2]],
    starts: &[[f64; 6]],
    options: &MatchOptions,
    out: MatchOutput<'_>,
    stages: &mut [Stage],
) -> Result<()> {
    validate_options(options)?;
    validate(images, weights, cameras, points, starts, &out, stages)?;
    let block = PARAMETERS * PARAMETERS;
    // Rayon splits the patches adaptively; each worker keeps one scratch across the
    // patches it runs, as the per-pair call does across its points.
    out.status
        .par_iter_mut()
        .zip(out.affine.par_iter_mut())
        .zip(out.radiometry.par_iter_mut())
        .zip(out.sigma0.par_iter_mut())
        .zip(out.correlation.par_iter_mut())
        .zip(out.iterations.par_iter_mut())
        .zip(out.covariance.par_chunks_mut(block))
        .zip(stages.par_iter_mut())
        .enumerate()
        .for_each_init(
            Scratch::default,
            |scratch,
             (
                i,
                (
                    (
                        (((((status, affine), radiometry), sigma0), correlation), iterations),
                        covariance,
                    ),
                    stage,
                ),
            )| {
                let [r, k] = cameras[i];
                // Checked by `validate`: both images exist.
                let (Some(template), Some(search)) = (&images[r], &images[k]) else {
                    return;
                };
                let weight = weights.and_then(|w| w[r].as_ref());
                match_point(
                    template,
                    weight,
                    points[i],
                    std::slice::from_ref(search),
                    std::slice::from_ref(&starts[i]),
                    None,
                    options,
                    scratch,
                    PointOutput {
                        status: std::slice::from_mut(status),
                        affine: std::slice::from_mut(affine),
                        radiometry: std::slice::from_mut(radiometry),
                        sigma0: std::slice::from_mut(sigma0),
                        correlation: std::slice::from_mut(correlation),
                        iterations: std::slice::from_mut(iterations),
                        covariance,
                        stage: std::slice::from_mut(stage),
                    },
                );
            },
        );
    Ok(())
}

fn validate(
    images: &[Option<ImageView<'_>>],
    weights: Option<&[Option<ImageView<'_>>]>,
    cameras: &[[usize; 2]],
    points: &[[f64; 2]],
    starts: &[[f64; 6]],
    out: &MatchOutput<'_>,
    stages: &[Stage],
) -> Result<()> {
    for image in images.iter().flatten() {
        let expected = image.width.saturating_mul(image.height);
        if image.width < 2 || image.height < 2 || image.data.len() != expected {
            return Err(Error::WrongLength {
                argument: "images",
                expected: expected.max(4),
                got: image.data.len(),
            });
        }
    }
    if let Some(weights) = weights {
        if weights.len() != images.len() {
            return Err(Error::LengthMismatch {
                argument: "weights",
                expected: images.len(),
                got: weights.len(),
            });
        }
    }
    let n = points.len();
    for (argument, got) in [("cameras", cameras.len()), ("initial", starts.len())] {
        if got != n {
            return Err(Error::LengthMismatch {
                argument,
                expected: n,
                got,
            });
        }
    }
    let camera = |row: usize, index: usize| -> Result<&ImageView<'_>> {
        match images.get(index) {
            None => Err(Error::IndexOutOfRange {
                argument: "cameras",
                row,
                value: index as i64,
                bound: images.len(),
            }),
            Some(None) => Err(Error::InvalidOption {
                argument: "cameras",
                value: index as f64,
                expected: "indices of images given (not None)",
            }),
            Some(Some(image)) => Ok(image),
        }
    };
    for (row, &[r, k]) in cameras.iter().enumerate() {
        let template = camera(row, r)?;
        camera(row, k)?;
        if let Some(w) = weights.and_then(|w| w[r].as_ref()) {
            let expected = template.width * template.height;
            if w.width != template.width || w.height != template.height || w.data.len() != expected
            {
                return Err(Error::WrongLength {
                    argument: "weights",
                    expected,
                    got: w.data.len(),
                });
            }
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
    for (expected, got) in [
        (n, out.status.len()),
        (n, out.affine.len()),
        (n, out.radiometry.len()),
        (n, out.sigma0.len()),
        (n, out.correlation.len()),
        (n, out.iterations.len()),
        (n * PARAMETERS * PARAMETERS, out.covariance.len()),
        (n, stages.len()),
    ] {
        if expected != got {
            return Err(Error::OutputSize { expected, got });
        }
    }
    Ok(())
}
