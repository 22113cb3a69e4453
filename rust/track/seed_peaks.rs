//! The seeding's choice along a seed's line: the best correlation among the line's samples
//! and the best other local maximum away from it (the uniqueness test of
//! `elastocap.tracking.seeding`: a repeated texture along the line makes a false match as
//! likely as the true one, so the best peak must stand out from every peak away from it).
//!
//! numpy's chain (`np.where(isfinite)`, `argmax`, a padded comparison with both neighbours,
//! the distance test, a masked `max`) ran over every (seed, sample) on one core between the
//! core's parallel calls; here it is one pass a line with the same comparisons, so the
//! answers are numpy's to the bit (benches/README.md, "seedpar1").

/// Which samples lie away from the best: farther than `Samples(w)` sample indices, or farther
/// than `Pixels(p)` pixels apart in the partner's image (`f64::hypot` of the offset, C's
/// `hypot` as numpy's).
#[derive(Debug, Clone, Copy)]
pub enum Away {
    /// More than this many samples apart.
    Samples(usize),
    /// More than this many pixels apart in the partner's image.
    Pixels(f64),
}

/// `(best, peak, second)` of one line's `scores` (D >= 1; NaN or infinite where a sample
/// was not scored): the first index of the largest finite score (0 when none is finite),
/// that score (-inf when none), and the largest finite local maximum (at least both
/// neighbours' scores, a missing neighbour counting -inf) lying [`Away`] from the best
/// (-inf when none). `uv` (D pixels in the partner) is read by `Away::Pixels` only.
pub fn line_peak(scores: &[f64], uv: &[[f64; 2]], away: Away) -> (usize, f64, f64) {
    let finite = |i: usize| {
        let s = scores[i];
        if s.is_finite() {
            s
        } else {
            f64::NEG_INFINITY
        }
    };
    let d = scores.len();
    let mut best = 0;
    for i in 1..d {
        if finite(i) > finite(best) {
            best = i;
        }
    }
    let peak = if d > 0 {
        finite(best)
    } else {
        f64::NEG_INFINITY
    };
    let mut second = f64::NEG_INFINITY;
    for i in 0..d {
        let s = finite(i);
        let before = if i > 0 {
            finite(i - 1)
        } else {
            f64::NEG_INFINITY
        };
        let after = if i + 1 < d {
            finite(i + 1)
        } else {
            f64::NEG_INFINITY
        };
        // numpy's `local` also requires the score finite: -inf is never a local maximum.
        if !(s.is_finite() && s >= before && s >= after) {
            continue;
        }
        let apart = match away {
            Away::Samples(w) => i.abs_diff(best) > w,
            Away::Pixels(p) => {
                let (du, dv) = (uv[i][0] - uv[best][0], uv[i][1] - uv[best][1]);
                du.hypot(dv) > p
            }
        };
        if apart && s > second {
            second = s;
        }
    }
    (best, peak, second)
}

#[cfg(test)]
#[path = "seed_peaks_tests.rs"]
mod tests;
