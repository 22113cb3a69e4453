//! One frame of one camera: predict, search the box, refine by temporal least-squares
//! matching, check forward-backward. Parallel over points (rayon), the matching batched
//! through [`crate::lsm::match_patches`].

use rayon::prelude::*;

use super::flags::Flag;
use super::ncc::{box_search, BoxScratch};
use crate::error::{Error, Result};
use crate::lsm::{
    match_weighted_patches, ImageView, Interpolation, MatchOptions, MatchOutput, Status, PARAMETERS,
};

/// Gauss-Newton iterations of the forward-backward check's match (started at the inverse
/// of the forward map).
const BACKWARD_ITERATIONS: usize = 5;

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

/// Tracks the points at `last` (their positions in `previous`; NaN rows are not
/// tracked) into `current`, predicting linearly from `before` (the positions one frame
/// earlier; NaN rows predict no motion). `weights`, when given, are per-pixel weights of
/// `previous` and `current` (their silhouette masks, 0 to 1): the forward match weighs the
/// template patch by the previous frame's, the forward-backward check by the current
/// frame's, so a patch on the silhouette's edge follows the surface and not the
/// background in its corner (see [`crate::lsm::match_weighted_patches`]).
///
/// # Errors
/// [`Error::LengthMismatch`] when `before` or the outputs do not have one entry per point,
/// [`Error::InvalidOption`] for options out of range, and what
/// [`crate::lsm::match_patches`] reports for images or options.
pub fn track_camera(
    previous: &ImageView<'_>,
    current: &ImageView<'_>,
    last: &[[f64; 2]],
    before: &[[f64; 2]],
    weights: Option<[&ImageView<'_>; 2]>,
    options: &TrackOptions,
    out: CameraStep<'_>,
) -> Result<()> {
    let n = last.len();
    for (argument, got) in [
        ("before", before.len()),
        ("positions", out.positions.len()),
        ("flags", out.flags.len()),
        ("covariance", out.covariance.len()),
        ("correlation", out.correlation.len()),
    ] {
        if got != n {
            return Err(Error::LengthMismatch {
                argument,
                expected: n,
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
    out.positions.fill([f64::NAN; 2]);
    out.covariance.fill([f64::NAN; 4]);
    out.correlation.fill(f64::NAN);

    // Box search around the linear prediction.
    let box_weights = if options.weighted_box {
        weights.map(|w| w[0])
    } else {
        None
    };
    let searched: Vec<(u8, [f64; 2])> = (0..n)
        .into_par_iter()
        .map_init(BoxScratch::default, |scratch, p| {
            let x = last[p];
            if !(x[0].is_finite() && x[1].is_finite()) {
                return (Flag::NotSeeded as u8, x);
            }
            let b = before[p];
            let prediction = if b[0].is_finite() && b[1].is_finite() {
                [2.0 * x[0] - b[0], 2.0 * x[1] - b[1]]
            } else {
                x
            };
            match box_search(
                previous,
                x,
                current,
                prediction,
                size,
                options.radius,
                box_weights,
                scratch,
            ) {
                None => (Flag::ImageBorder as u8, x),
                Some(best) if !(best.score >= options.min_correlation) => {
                    (Flag::LowCorrelation as u8, x)
                }
                Some(best) => (Flag::Tracked as u8, best.centre),
            }
        })
        .collect();
    let active: Vec<usize> = (0..n)
        .filter(|&p| searched[p].0 == Flag::Tracked as u8)
        .collect();
    for (flag, &(code, _)) in out.flags.iter_mut().zip(&searched) {
        *flag = code;
    }
    if active.is_empty() {
        return Ok(());
    }

    // Temporal least-squares matching, previous -> current.
    let points: Vec<[f64; 2]> = active.iter().map(|&p| last[p]).collect();
    let starts: Vec<[f64; 6]> = active
        .iter()
        .map(|&p| {
            let c = searched[p].1;
            [1.0, 0.0, c[0], 0.0, 1.0, c[1]]
        })
        .collect();
    let forward = run_matches(
        previous,
        weights.map(|w| w[0]),
        &points,
        current,
        &starts,
        &options.matching,
    )?;

    // Forward-backward: the current patch matched back into the previous frame, started
    // at the inverse of the forward map, must land on the start.
    let (mut back_points, mut back_starts, mut back_of) = (Vec::new(), Vec::new(), Vec::new());
    for (k, &p) in active.iter().enumerate() {
        let status = forward.status[k];
        let code = if status == Status::LeftImage as u8 {
            Flag::ImageBorder
        } else if !matches!(status, s if s == Status::Converged as u8 || s == Status::MaxIterations as u8)
        {
            Flag::MatchFailed
        } else if !(forward.correlation[k] >= options.min_correlation) {
            Flag::LowCorrelation
        } else {
            let m = forward.affine[k];
            let det = m[0] * m[4] - m[1] * m[3];
            back_points.push([m[2], m[5]]);
            back_starts.push([
                m[4] / det,
                -m[1] / det,
                last[p][0],
                -m[3] / det,
                m[0] / det,
                last[p][1],
            ]);
            back_of.push(k);
            Flag::Tracked
        };
        out.flags[p] = code as u8;
    }
    if back_of.is_empty() {
        return Ok(());
    }
    // The check only has to land within `forward_backward` (tenths of a pixel) of the
    // start, from the inverse map, which is already within hundredths of it when the
    // forward match is right: bilinear resampling (its bias is hundredths of a pixel) and
    // a few iterations are enough, and cost a quarter of the forward match.
    // Its covariance is not used: no sandwich (a quarter of a match).
    let check = MatchOptions {
        max_iterations: options.matching.max_iterations.min(BACKWARD_ITERATIONS),
        interpolation: Interpolation::Bilinear,
        sandwich: false,
        ..options.matching
    };
    let backward = run_matches(
        current,
        weights.map(|w| w[1]),
        &back_points,
        previous,
        &back_starts,
        &check,
    )?;
    let block = PARAMETERS * PARAMETERS;
    for (j, &k) in back_of.iter().enumerate() {
        let p = active[k];
        let status = backward.status[j];
        let m = backward.affine[j];
        let miss = (m[2] - last[p][0]).hypot(m[5] - last[p][1]);
        let has_estimate =
            status == Status::Converged as u8 || status == Status::MaxIterations as u8;
        if !has_estimate || !(miss <= options.forward_backward) {
            out.flags[p] = Flag::ForwardBackward as u8;
            continue;
        }
        let f = forward.affine[k];
        out.positions[p] = [f[2], f[5]];
        let c = &forward.covariance[k * block..(k + 1) * block];
        out.covariance[p] = [c[0], c[1], c[PARAMETERS], c[PARAMETERS + 1]];
        out.correlation[p] = forward.correlation[k];
    }
    Ok(())
}

/// Flat results of one batch of single-search-image matches.
struct Batch {
    status: Vec<u8>,
    affine: Vec<[f64; 6]>,
    correlation: Vec<f64>,
    covariance: Vec<f64>,
}

fn run_matches(
    template: &ImageView<'_>,
    weights: Option<&ImageView<'_>>,
    points: &[[f64; 2]],
    search: &ImageView<'_>,
    starts: &[[f64; 6]],
    options: &MatchOptions,
) -> Result<Batch> {
    let m = points.len();
    let mut batch = Batch {
        status: vec![0; m],
        affine: vec![[0.0; 6]; m],
        correlation: vec![0.0; m],
        covariance: vec![0.0; m * PARAMETERS * PARAMETERS],
    };
    let mut radiometry = vec![[0.0; 2]; m];
    let mut sigma0 = vec![0.0; m];
    let mut iterations = vec![0u32; m];
    match_weighted_patches(
        template,
        weights,
        points,
        std::slice::from_ref(search),
        starts,
        None,
        options,
        MatchOutput {
            status: &mut batch.status,
            affine: &mut batch.affine,
            radiometry: &mut radiometry,
            sigma0: &mut sigma0,
            correlation: &mut batch.correlation,
            iterations: &mut iterations,
            covariance: &mut batch.covariance,
        },
    )?;
    Ok(batch)
}
