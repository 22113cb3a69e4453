//! One view of the frame step ([`super::step::track_cameras`]): the linear prediction, the
//! box search around it, the temporal least-squares match previous -> current from the
//! box's peak, and the forward-backward check (the current patch matched back into the
//! previous frame from the inverse of the forward map must land on the start), one after
//! the other; the first stage that fails gives the view its [`Flag`].

use super::flags::Flag;
use super::ncc::{box_search, BoxScratch};
use super::step::{CameraFrames, TrackOptions};
use crate::error::Result;
use crate::lsm::{match_single, MatchOptions, SingleScratch, Status};

/// One view's results (see [`super::step::CameraStep`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct View {
    /// [`Flag`] code.
    pub flag: u8,
    /// Tracked position `(u, v)`, pixels; NaN where not tracked.
    pub position: [f64; 2],
    /// Covariance of the position, `[uu, uv, vu, vv]`, pixels squared; NaN where not
    /// tracked.
    pub covariance: [f64; 4],
    /// Correlation of the forward match; NaN where not tracked.
    pub correlation: f64,
}

impl View {
    /// A view not tracked, for `flag`.
    pub(super) fn lost(flag: Flag) -> Self {
        Self {
            flag: flag as u8,
            position: [f64::NAN; 2],
            covariance: [f64::NAN; 4],
            correlation: f64::NAN,
        }
    }
}

/// Per-worker scratch of [`track_view`]: the box search's and each match's (the forward
/// and the backward match keep their own, as their batches did).
#[derive(Debug, Default)]
pub(super) struct ViewScratch {
    boxes: BoxScratch,
    forward: SingleScratch,
    backward: SingleScratch,
}

/// Whether a match's status carries an estimate (converged, or out of iterations).
fn has_estimate(status: u8) -> bool {
    status == Status::Converged as u8 || status == Status::MaxIterations as u8
}

/// Tracks the view at `last` (previous frame; NaN: not seeded) of `frames` into its
/// current frame, predicting `2 last - before` (`last` where `before` is NaN); `check` the
/// backward match's options, `row` the view's index in its camera (for errors).
///
/// # Errors
/// A match's errors for a non-finite or folded start ([`crate::lsm::match_patches`]'s).
pub(super) fn track_view(
    frames: &CameraFrames<'_>,
    last: [f64; 2],
    before: [f64; 2],
    options: &TrackOptions,
    check: &MatchOptions,
    row: usize,
    scratch: &mut ViewScratch,
) -> Result<View> {
    if !(last[0].is_finite() && last[1].is_finite()) {
        return Ok(View::lost(Flag::NotSeeded));
    }
    let prediction = if before[0].is_finite() && before[1].is_finite() {
        [2.0 * last[0] - before[0], 2.0 * last[1] - before[1]]
    } else {
        last
    };
    let box_weights = if options.weighted_box {
        frames.weights.as_ref().map(|w| &w[0])
    } else {
        None
    };
    let centre = match box_search(
        &frames.previous,
        last,
        &frames.current,
        prediction,
        options.matching.size,
        options.radius,
        box_weights,
        &mut scratch.boxes,
    ) {
        None => return Ok(View::lost(Flag::ImageBorder)),
        Some(best) if !(best.score >= options.min_correlation) => {
            return Ok(View::lost(Flag::LowCorrelation))
        }
        Some(best) => best.centre,
    };

    // Temporal least-squares matching, previous -> current, from the box's peak.
    let forward = match_single(
        &frames.previous,
        frames.weights.as_ref().map(|w| &w[0]),
        last,
        &frames.current,
        [1.0, 0.0, centre[0], 0.0, 1.0, centre[1]],
        &options.matching,
        row,
        &mut scratch.forward,
    )?;
    if forward.status == Status::LeftImage as u8 {
        return Ok(View::lost(Flag::ImageBorder));
    }
    if !has_estimate(forward.status) {
        return Ok(View::lost(Flag::MatchFailed));
    }
    if !(forward.correlation >= options.min_correlation) {
        return Ok(View::lost(Flag::LowCorrelation));
    }

    // Forward-backward: the current patch matched back into the previous frame, started
    // at the inverse of the forward map, must land on the start.
    let m = forward.affine;
    let det = m[0] * m[4] - m[1] * m[3];
    let backward = match_single(
        &frames.current,
        frames.weights.as_ref().map(|w| &w[1]),
        [m[2], m[5]],
        &frames.previous,
        [
            m[4] / det,
            -m[1] / det,
            last[0],
            -m[3] / det,
            m[0] / det,
            last[1],
        ],
        check,
        row,
        &mut scratch.backward,
    )?;
    let b = backward.affine;
    let miss = (b[2] - last[0]).hypot(b[5] - last[1]);
    if !has_estimate(backward.status) || !(miss <= options.forward_backward) {
        return Ok(View::lost(Flag::ForwardBackward));
    }
    Ok(View {
        flag: Flag::Tracked as u8,
        position: [m[2], m[5]],
        covariance: forward.covariance,
        correlation: forward.correlation,
    })
}
