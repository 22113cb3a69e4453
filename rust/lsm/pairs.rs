//! Many patches across many camera pairs in one call: the spatial matches of a tracked
//! frame (re-tie, re-acquisition, confirmation) gathered into one parallel batch.
//!
//! The tracker matches a point's patch from its reference camera into each other camera
//! that should see it: per frame ~80-100 camera pairs of a few dozen patches each. Called
//! pair by pair, the call's fixed cost dominates and rayon has too few patches to split
//! (speed1's profile: 0.36 CPU s a frame over ~99 calls, the frame on one core). Here the
//! frame's images are passed once and every patch names its own reference and target
//! image; the patches run in parallel.
//!
//! Patches with the same reference camera and the same point (to the bit) share their
//! template: it is sampled (and weighed) once and matched into each of their targets
//! (re-acquisition and confirmation match a point into ~1.5-1.8 targets on average). Each
//! patch is matched by exactly the code the per-pair call runs for a point with one search
//! image ([`super::multi::match_point`]: the template patch, then the search image), and
//! no patch reads another's state, so a patch's result is bit-identical to the one
//! [`super::match_staged_patches`] gives it in its own pair's call.

use rayon::prelude::*;

use super::multi::{own_block, Scratch};
use super::types::{ImageView, MatchOptions, MatchOutput, Stage, PARAMETERS};
use super::validate_options;
use crate::error::{check_finite, Error, Result};

/// One patch's results, gathered per template group and scattered to the outputs.
#[derive(Debug, Clone, Copy)]
struct PatchResult {
    status: u8,
    affine: [f64; 6],
    radiometry: [f64; 2],
    sigma0: f64,
    correlation: f64,
    iterations: u32,
    covariance: [f64; PARAMETERS * PARAMETERS],
    stage: Stage,
}

impl Default for PatchResult {
    fn default() -> Self {
        Self {
            status: 0,
            affine: [0.0; 6],
            radiometry: [0.0; 2],
            sigma0: 0.0,
            correlation: 0.0,
            iterations: 0,
            covariance: [f64::NAN; PARAMETERS * PARAMETERS],
            stage: Stage::NONE,
        }
    }
}

/// Matches patch `i`, around `points[i]` in image `cameras[i][0]`, into image
/// `cameras[i][1]` started at `starts[i]` (row-major 2x3, see [`MatchOutput`]), in parallel
/// over the patches' templates, weighing the template by `weights[cameras[i][0]]` where
/// given.
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
    // The patches in template order: by reference camera and point (bits), each group of
    // equal keys one template. A stable sort keeps a group's patches in input order.
    let key = |i: usize| {
        (
            cameras[i][0],
            points[i][0].to_bits(),
            points[i][1].to_bits(),
        )
    };
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by_key(|&i| key(i));
    let mut results = vec![PatchResult::default(); order.len()];
    let mut groups: Vec<(&[usize], &mut [PatchResult])> = Vec::new();
    let (mut rest_order, mut rest) = (order.as_slice(), results.as_mut_slice());
    while let Some(&first) = rest_order.first() {
        let len = rest_order
            .iter()
            .take_while(|&&i| key(i) == key(first))
            .count();
        let (group, tail) = rest_order.split_at(len);
        let (slots, others) = std::mem::take(&mut rest).split_at_mut(len);
        groups.push((group, slots));
        (rest_order, rest) = (tail, others);
    }
    // Rayon splits the groups adaptively; each worker keeps one scratch across the
    // templates it runs, as the per-pair call does across its points.
    groups
        .into_par_iter()
        .for_each_init(Scratch::default, |scratch, (group, slots)| {
            let [r, _] = cameras[group[0]];
            // Checked by `validate`: every image named exists.
            let Some(template) = &images[r] else {
                return;
            };
            let weight = weights.and_then(|w| w[r].as_ref());
            let template_status = scratch.template(template, weight, points[group[0]], options, 1);
            for (&i, slot) in group.iter().zip(slots.iter_mut()) {
                let Some(search) = &images[cameras[i][1]] else {
                    return;
                };
                let outcome = scratch.search(template_status, search, starts[i], None, options, 0);
                // One search image: the joint covariance is the image's own block, NaN
                // without an estimate.
                let mut covariance = [f64::NAN; PARAMETERS * PARAMETERS];
                if outcome.status.has_estimate() {
                    for (row, values) in covariance
                        .chunks_exact_mut(PARAMETERS)
                        .zip(own_block(&outcome))
                    {
                        row.copy_from_slice(&values);
                    }
                }
                *slot = PatchResult {
                    status: outcome.status as u8,
                    affine: outcome.state.affine(),
                    radiometry: [outcome.state.gain, outcome.state.offset],
                    sigma0: outcome.sigma0,
                    correlation: outcome.correlation,
                    iterations: outcome.iterations,
                    covariance,
                    stage: outcome.stage,
                };
            }
        });
    let block = PARAMETERS * PARAMETERS;
    for (&i, result) in order.iter().zip(&results) {
        out.status[i] = result.status;
        out.affine[i] = result.affine;
        out.radiometry[i] = result.radiometry;
        out.sigma0[i] = result.sigma0;
        out.correlation[i] = result.correlation;
        out.iterations[i] = result.iterations;
        out.covariance[i * block..(i + 1) * block].copy_from_slice(&result.covariance);
        stages[i] = result.stage;
    }
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
