//! One point matched into one search image, outside a batch: the frame step's per-view
//! pipeline (`crate::track`) runs its box search, forward match and forward-backward check
//! of one view in one go, inside its own parallel pass over every camera's views, instead
//! of a batch (a parallel pass, and the checks of every start) per stage and camera.
//!
//! The match is [`super::match_weighted_patches`]'s of that point, to the bit: the same
//! [`match_point`] with one search image; the checks of the batch's inputs are made here
//! per point ([`match_single`]) and, for the options and images, once by the caller
//! ([`check_options`], [`check_image`]).

use super::multi::{match_point, PointOutput, Scratch};
use super::types::{ImageView, MatchOptions, Stage, PARAMETERS};
use crate::error::{Error, Result};

/// What the step reads of one match.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Single {
    /// [`super::Status`] code.
    pub status: u8,
    /// Final affine map, `[a11, a12, u, a21, a22, v]` ([`super::MatchOutput`]).
    pub affine: [f64; 6],
    /// Normalised cross-correlation of the template and the resampled search patch.
    pub correlation: f64,
    /// Covariance of the matched centre `(u, v)`, `[uu, uv, vu, vv]`, pixels squared.
    pub covariance: [f64; 4],
}

/// Per-worker scratch of [`match_single`].
#[derive(Debug, Default)]
pub(crate) struct SingleScratch {
    point: Scratch,
    covariance: Vec<f64>,
}

/// The options' ranges, as every batch checks them ([`super::match_patches`]'s errors).
///
/// # Errors
/// [`Error::InvalidOption`] for an option out of range.
pub(crate) fn check_options(options: &MatchOptions) -> Result<()> {
    super::validate_options(options)
}

/// An image the matcher can read: at least 2x2, its data `width * height` values (a batch's
/// check of its template and search images).
///
/// # Errors
/// [`Error::WrongLength`] otherwise.
pub(crate) fn check_image(argument: &'static str, image: &ImageView<'_>) -> Result<()> {
    let expected = image.width.saturating_mul(image.height);
    if image.width < 2 || image.height < 2 || image.data.len() != expected {
        return Err(Error::WrongLength {
            argument,
            expected: expected.max(4),
            got: image.data.len(),
        });
    }
    Ok(())
}

/// The template patch around `point` (weighed by `weights`, of the template's size, when
/// given) matched into `search` from the affine map `start`: what
/// [`super::match_weighted_patches`] reports for that point, with the options checked by
/// [`check_options`] and the images by [`check_image`] beforehand (the weights' size by
/// the caller).
///
/// # Errors
/// [`Error::NonFinite`] for a non-finite point (argument `points`) or start (`initial`),
/// [`Error::InvalidOption`] for a start whose linear part has no positive determinant:
/// the batch's errors, `row` the caller's.
#[allow(clippy::too_many_arguments)]
pub(crate) fn match_single(
    template: &ImageView<'_>,
    weights: Option<&ImageView<'_>>,
    point: [f64; 2],
    search: &ImageView<'_>,
    start: [f64; 6],
    options: &MatchOptions,
    row: usize,
    scratch: &mut SingleScratch,
) -> Result<Single> {
    if !point.iter().all(|v| v.is_finite()) {
        return Err(Error::NonFinite {
            argument: "points",
            row,
        });
    }
    if !start.iter().all(|v| v.is_finite()) {
        return Err(Error::NonFinite {
            argument: "initial",
            row,
        });
    }
    let det = start[0] * start[4] - start[1] * start[3];
    if !(det > 0.0) {
        return Err(Error::InvalidOption {
            argument: "initial",
            value: det,
            expected: "affine maps whose linear part has a positive determinant",
        });
    }
    let (mut status, mut affine, mut radiometry) = ([0u8], [[0.0; 6]], [[0.0; 2]]);
    let (mut sigma0, mut correlation, mut iterations) = ([0.0], [0.0], [0u32]);
    let mut stage = [Stage::NONE];
    scratch.covariance.resize(PARAMETERS * PARAMETERS, 0.0);
    match_point(
        template,
        weights,
        point,
        std::slice::from_ref(search),
        std::slice::from_ref(&start),
        None,
        options,
        &mut scratch.point,
        PointOutput {
            status: &mut status,
            affine: &mut affine,
            radiometry: &mut radiometry,
            sigma0: &mut sigma0,
            correlation: &mut correlation,
            iterations: &mut iterations,
            covariance: &mut scratch.covariance,
            stage: &mut stage,
        },
    );
    let c = &scratch.covariance;
    Ok(Single {
        status: status[0],
        affine: affine[0],
        correlation: correlation[0],
        covariance: [c[0], c[1], c[PARAMETERS], c[PARAMETERS + 1]],
    })
}
