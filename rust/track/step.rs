//! One frame of every camera: predict, search the box, refine by temporal least-squares
//! matching, check forward-backward. One parallel pass (rayon) over every camera's seeded
//! views, in image order, each view's stages run one after the other by the worker that
//! takes it ([`super::step_view`]).
//!
//! The pass was one per stage and camera (the box searches, then a batch of forward
//! matches through [`crate::lsm::match_weighted_patches`], then one of backward matches:
//! with the batches' checks, some 50 fork-joins per call of 8 cameras). Every view's
//! stages read only that view's inputs and the images, so the views' results are those
//! of the staged passes to the bit; the stages' checks of their inputs are made per view,
//! the checks of the options and images once.

use rayon::prelude::*;

use super::flags::Flag;
use super::step_view::{track_view, View, ViewScratch};
use crate::error::{Error, Result};
use crate::lsm::{check_image, check_options, ImageView, Interpolation, MatchOptions};

/// Gauss-Newton iterations of the forward-backward check's match (started at the inverse
/// of the forward map).
const BACKWARD_ITERATIONS: usize = 5;

/// Rows of an image band of the views' order ([`track_cameras`]): about a view's window
/// (a 15 px patch and a box of radius 6 span 27 rows).
const BAND: f64 = 32.0;

/// Most views a worker takes at once (about a millisecond of work). Rayon's own split of
/// one pass stops at a few pieces per thread: on a shared machine a worker descheduled in
/// the middle of a quarter of the frame's views kept the other waiting (the staged passes
/// waited at each stage instead); pieces this small are stolen by the idle one.
const LEAF: usize = 16;

/// Options of the temporal step, the same for every point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackOptions {
    /// Least-squares matching (its `size` is also the box search's patch side).
    pub matching: MatchOptions,
    /// Half-side of the search box around the prediction, whole pixels.
    pub radius: usize,
    /// Least normalised cross-correlation of the box search's peak and of the final
    /// least-squares match.
    pub min_correlation: f64,
    /// Largest distance between the start and the forward-backward match, pixels.
    pub forward_backward: f64,
    /// Whether the box search weighs the template by the previous frame's weights (the
    /// ones the forward match gets; [`super::weighted_ncc`]); without weights, or a
    /// template whose weights are all 1, the search is the plain one either way.
    pub weighted_box: bool,
}

impl Default for TrackOptions {
    fn default() -> Self {
        Self {
            matching: MatchOptions {
                max_iterations: 15,
                ..MatchOptions::default()
            },
            radius: 4,
            min_correlation: 0.8,
            forward_backward: 0.3,
            weighted_box: false,
        }
    }
}

/// Where one camera's step writes, indexed by point.
#[derive(Debug)]
pub struct CameraStep<'a> {
    /// Tracked position `(u, v)`, pixels; NaN where not tracked.
    pub positions: &'a mut [[f64; 2]],
    /// [`Flag`] codes.
    pub flags: &'a mut [u8],
    /// Covariance of the position, `[uu, uv, vu, vv]`, pixels squared (NaN where not
    /// tracked).
    pub covariance: &'a mut [[f64; 4]],
    /// Correlation of the least-squares match (NaN where it did not run).
    pub correlation: &'a mut [f64],
}

fn invalid(argument: &'static str, value: f64, expected: &'static str) -> Error {
    Error::InvalidOption {
        argument,
        value,
        expected,
    }
}

/// One camera's images for the step: `previous` and `current` frame, and, when given,
/// per-pixel weights of each (see [`track_cameras`]).
#[derive(Debug, Clone, Copy)]
pub struct CameraFrames<'a> {
    /// The previous frame's grey image (the templates).
    pub previous: ImageView<'a>,
    /// The current frame's grey image (the search).
    pub current: ImageView<'a>,
    /// The weights of `previous` and `current`, each of its image's size (0 to 1).
    pub weights: Option<[ImageView<'a>; 2]>,
}

/// Tracks the points at `last` (their positions in `previous`; NaN rows are not
/// tracked) into `current`, predicting linearly from `before` (the positions one frame
/// earlier; NaN rows predict no motion). `weights`, when given, are per-pixel weights of
/// `previous` and `current` (their silhouette masks, 0 to 1): the forward match weighs the
/// template patch by the previous frame's, the forward-backward check by the current
/// frame's, so a patch on the silhouette's edge follows the surface and not the
/// background in its corner (see [`crate::lsm::match_weighted_patches`]).
///
/// The one-camera case of [`track_cameras`].
///
/// # Errors
/// As [`track_cameras`].
pub fn track_camera(
    previous: &ImageView<'_>,
    current: &ImageView<'_>,
    last: &[[f64; 2]],
    before: &[[f64; 2]],
    weights: Option<[&ImageView<'_>; 2]>,
    options: &TrackOptions,
    out: CameraStep<'_>,
) -> Result<()> {
    let frames = CameraFrames {
        previous: *previous,
        current: *current,
        weights: weights.map(|[a, b]| [*a, *b]),
    };
    track_cameras(std::slice::from_ref(&frames), last, before, options, out)
}

/// [`track_camera`] of every camera in one parallel pass: `last`, `before` and the outputs
/// hold `N` views per camera, camera after camera (view `p` of camera `k` at `k N + p`),
/// camera `k` tracked from `cameras[k].previous` into `cameras[k].current` with its weights.
/// Each camera's results are [`track_camera`]'s of that camera alone, to the bit.
///
/// # Errors
/// [`Error::LengthMismatch`] when `last` does not hold the same number of views for every
/// camera, or `before` or the outputs do not have one entry per view,
/// [`Error::InvalidOption`] for options out of range, [`Error::WrongLength`] for an image
/// smaller than 2x2, whose data does not match its size, or weights of another size than
/// their image, and what the matching reports for a view's match
/// ([`crate::lsm::match_patches`]'s errors of a non-finite or folded start).
pub fn track_cameras(
    cameras: &[CameraFrames<'_>],
    last: &[[f64; 2]],
    before: &[[f64; 2]],
    options: &TrackOptions,
    out: CameraStep<'_>,
) -> Result<()> {
    let views = last.len();
    let c = cameras.len();
    // Views per camera (0 without cameras, where there must be no views either).
    let n = views.checked_div(c).unwrap_or(0);
    if n * c != views {
        return Err(Error::LengthMismatch {
            argument: "last",
            expected: n * c,
            got: views,
        });
    }
    for (argument, got) in [
        ("before", before.len()),
        ("positions", out.positions.len()),
        ("flags", out.flags.len()),
        ("covariance", out.covariance.len()),
        ("correlation", out.correlation.len()),
    ] {
        if got != views {
            return Err(Error::LengthMismatch {
                argument,
                expected: views,
                got,
            });
        }
    }
    if !(options.min_correlation >= -1.0 && options.min_correlation <= 1.0) {
        return Err(invalid(
            "min_correlation",
            options.min_correlation,
            "a number from -1 to 1",
        ));
    }
    if !(options.forward_backward > 0.0 && options.forward_backward.is_finite()) {
        return Err(invalid(
            "forward_backward",
            options.forward_backward,
            "a positive finite number",
        ));
    }
    if options.radius > 64 {
        return Err(invalid(
            "radius",
            options.radius as f64,
            "at most 64 pixels",
        ));
    }
    let size = options.matching.size;
    if size < 3 || size % 2 == 0 || size > 255 {
        return Err(invalid("size", size as f64, "an odd integer from 3 to 255"));
    }
    if views == 0 {
        return Ok(());
    }
    let check = backward_options(&options.matching);
    check_options(&options.matching)?;
    check_options(&check)?;
    for frames in cameras {
        check_image("template", &frames.previous)?;
        check_image("search_images", &frames.current)?;
        if let Some(weights) = &frames.weights {
            for (w, image) in weights.iter().zip([&frames.previous, &frames.current]) {
                if w.width != image.width || w.height != image.height {
                    return Err(Error::WrongLength {
                        argument: "weights",
                        expected: image.width * image.height,
                        got: w.data.len(),
                    });
                }
                check_image("weights", w)?;
            }
        }
    }
    // The seeded views in image order (camera, band of rows, column): each view reads a
    // window of about `size + 2 radius` rows of its images, which its neighbours in that
    // order read again while they are in cache (in the tracker's order, the points', the
    // windows jump across the image). The unseeded views need no pass.
    let mut order: Vec<(usize, usize, f64, usize)> = last
        .iter()
        .enumerate()
        .filter(|(_, x)| x[0].is_finite() && x[1].is_finite())
        .map(|(i, x)| (i / n, (x[1] / BAND).floor().max(0.0) as usize, x[0], i))
        .collect();
    order.par_sort_unstable_by(|a, b| (a.0, a.1).cmp(&(b.0, b.1)).then(a.2.total_cmp(&b.2)));
    let tracked = order
        .par_iter()
        .with_max_len(LEAF)
        .map_init(ViewScratch::default, |scratch, &(k, _, _, i)| {
            track_view(
                &cameras[k],
                last[i],
                before[i],
                options,
                &check,
                i % n,
                scratch,
            )
        })
        .collect::<Result<Vec<View>>>()?;
    let unseeded = View::lost(Flag::NotSeeded);
    out.positions.fill(unseeded.position);
    out.flags.fill(unseeded.flag);
    out.covariance.fill(unseeded.covariance);
    out.correlation.fill(unseeded.correlation);
    for (&(_, _, _, i), view) in order.iter().zip(&tracked) {
        out.positions[i] = view.position;
        out.flags[i] = view.flag;
        out.covariance[i] = view.covariance;
        out.correlation[i] = view.correlation;
    }
    Ok(())
}

/// The options of the forward-backward check's match.
///
/// The check only has to land within `forward_backward` (tenths of a pixel) of the
/// start, from the inverse map, which is already within hundredths of it when the
/// forward match is right: bilinear resampling (its bias is hundredths of a pixel) and
/// a few iterations are enough, and cost a quarter of the forward match.
/// Its covariance is not used: no sandwich (a quarter of a match).
fn backward_options(matching: &MatchOptions) -> MatchOptions {
    MatchOptions {
        max_iterations: matching.max_iterations.min(BACKWARD_ITERATIONS),
        interpolation: Interpolation::Bilinear,
        sandwich: false,
        ..*matching
    }
}
