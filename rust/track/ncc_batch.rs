//! The correlation at candidate centres ([`super::ncc_at`]) of many templates across many
//! images in one parallel pass: the coarse-to-fine first step of a frame's young views
//! searches every camera's boxes at once, not one call (one parallel pass) per camera.

use rayon::prelude::*;

use super::ncc_at::ncc_at;
use crate::error::{Error, Result};
use crate::lsm::ImageView;

/// Row `i`: the template patch (side `size`) around `points[i]` in
/// `templates[cameras[i]]` correlated with the patch of `searches[cameras[i]]` around each
/// of the row's `K = candidates.len() / points.len()` candidates
/// (`candidates[i K..(i + 1) K]`), into `scores[i K..(i + 1) K]`; NaN where a patch leaves
/// its image or is flat. Each row is [`ncc_at`]'s, to the bit.
///
/// # Errors
/// [`Error::LengthMismatch`] when `templates` and `searches` differ in length, `cameras`
/// is not one per point, or `candidates` and `scores` are not `K` per point;
/// [`Error::IndexOutOfRange`] for a camera index beyond the images.
pub fn ncc_at_cameras(
    templates: &[ImageView<'_>],
    searches: &[ImageView<'_>],
    cameras: &[usize],
    points: &[[f64; 2]],
    candidates: &[[f64; 2]],
    size: usize,
    scores: &mut [f64],
) -> Result<()> {
    let n = points.len();
    if searches.len() != templates.len() {
        return Err(Error::LengthMismatch {
            argument: "searches",
            expected: templates.len(),
            got: searches.len(),
        });
    }
    if cameras.len() != n {
        return Err(Error::LengthMismatch {
            argument: "cameras",
            expected: n,
            got: cameras.len(),
        });
    }
    if let Some((row, &value)) = cameras
        .iter()
        .enumerate()
        .find(|&(_, &k)| k >= templates.len())
    {
        return Err(Error::IndexOutOfRange {
            argument: "cameras",
            row,
            value: value as i64,
            bound: templates.len(),
        });
    }
    if n == 0 {
        return Ok(());
    }
    let k = candidates.len() / n;
    for (argument, got) in [("candidates", candidates.len()), ("scores", scores.len())] {
        if got != n * k {
            return Err(Error::LengthMismatch {
                argument,
                expected: n * k,
                got,
            });
        }
    }
    if k == 0 {
        return Ok(());
    }
    scores.par_chunks_mut(k).enumerate().for_each(|(i, row)| {
        let c = cameras[i];
        ncc_at(
            &templates[c],
            points[i],
            &searches[c],
            &candidates[i * k..(i + 1) * k],
            size,
            row,
        )
    });
    Ok(())
}
