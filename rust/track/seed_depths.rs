//! The seeding's depth search along a seed's ray: the ray's first run through the visual
//! hull (where the front surface lies) found on a coarse grid of depths across the rig,
//! then sampled finely; the fine samples and which of them lie in the hull are what the
//! correlation along the seed's line scores (`elastocap.tracking.seeding`).
//!
//! The numbers are numpy's (`_hull_depths` before "seedfast1", benches/README.md): a
//! sample is `origin + depth * dir` (a product then a sum, no fusing), the fine depths
//! `near + (far - near) * fraction`, and the hull test is [`super::seed_hull`]'s. Two
//! shortcuts change no answer: the coarse grid is tested only until its first run ends
//! (numpy tested all of it, ~half the coarse samples lie beyond the run), and a ray that
//! never enters the hull has no fine samples tested (numpy tested them, then cleared them).

use super::seed_hull::{hull_fill, HullView};

/// Coarse samples tested per pass before looking for the run's end.
const BLOCK: usize = 8;

/// The ray's depths and hull.
#[derive(Debug, Clone, Copy)]
pub struct DepthGrid<'a> {
    /// Coarse depths along the ray, increasing (K >= 2).
    pub coarse: &'a [f64],
    /// The fine grid's fractions of the run, 0 to 1 (D).
    pub fractions: &'a [f64],
    /// The coarse grid's step (the run is widened by it on both ends).
    pub step: f64,
    /// The cameras that bound the hull.
    pub views: &'a [HullView<'a>],
    /// How many of them must see a sample for it to be in the hull.
    pub min_seen: usize,
}

/// One ray's fine samples (`fine`, D) and whether each lies in the hull (`inside`, D; all
/// false when no coarse sample does). `pts` and `hull` are scratch; `first` the hull test's
/// view to try first.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn search(
    origin: [f64; 3],
    dir: [f64; 3],
    grid: &DepthGrid<'_>,
    first: &mut usize,
    pts: &mut Vec<[f64; 3]>,
    hull: &mut Vec<bool>,
    fine: &mut [[f64; 3]],
    inside: &mut [bool],
) {
    let k = grid.coarse.len();
    let at = |depth: f64| -> [f64; 3] { std::array::from_fn(|a| origin[a] + depth * dir[a]) };
    hull.clear();
    let (mut enter, mut leave) = (None, None);
    while hull.len() < k && leave.is_none() {
        let (start, stop) = (hull.len(), (hull.len() + BLOCK).min(k));
        pts.clear();
        pts.extend(grid.coarse[start..stop].iter().map(|&c| at(c)));
        hull.resize(stop, false);
        hull_fill(
            pts,
            grid.views,
            grid.min_seen,
            first,
            &mut hull[start..stop],
        );
        for (i, &h) in hull.iter().enumerate().skip(start) {
            if h && enter.is_none() {
                enter = Some(i);
            } else if !h && enter.is_some() {
                leave = Some(i);
                break;
            }
        }
    }
    // numpy's argmax of an all-false row is 0 and its run's last index K - 1.
    let near = grid.coarse[enter.unwrap_or(0)] - grid.step;
    let far = grid.coarse[leave.map_or(k - 1, |e| e - 1)] + grid.step;
    for (f, &fraction) in fine.iter_mut().zip(grid.fractions) {
        *f = at(near + (far - near) * fraction);
    }
    if enter.is_some() {
        hull_fill(fine, grid.views, grid.min_seen, first, inside);
    } else {
        inside.fill(false);
    }
}

#[inline(always)]
fn search_all(
    origins: &[[f64; 3]],
    dirs: &[[f64; 3]],
    grid: &DepthGrid<'_>,
    fine: &mut [[f64; 3]],
    inside: &mut [bool],
) {
    let d = grid.fractions.len();
    let (mut pts, mut hull) = (
        Vec::with_capacity(BLOCK),
        Vec::with_capacity(grid.coarse.len()),
    );
    let mut first = 0;
    for (((&o, &dir), f), i) in origins
        .iter()
        .zip(dirs)
        .zip(fine.chunks_exact_mut(d))
        .zip(inside.chunks_exact_mut(d))
    {
        search(o, dir, grid, &mut first, &mut pts, &mut hull, f, i);
    }
}

/// The depth search of rays `origins`, `dirs` (M each; finite directions): their fine
/// samples into `fine` (M x D, ray-major) and whether each lies in the hull into `inside`
/// (M x D).
pub fn hull_depths(
    origins: &[[f64; 3]],
    dirs: &[[f64; 3]],
    grid: &DepthGrid<'_>,
    fine: &mut [[f64; 3]],
    inside: &mut [bool],
) {
    let m = origins.len();
    let d = grid.fractions.len();
    assert!(
        grid.coarse.len() >= 2,
        "a coarse grid of two depths at least"
    );
    assert!(
        dirs.len() == m && fine.len() == m * d && inside.len() == m * d,
        "one row per ray"
    );
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has AVX2 and FMA.
        unsafe { hull_depths_wide(origins, dirs, grid, fine, inside) };
        return;
    }
    search_all(origins, dirs, grid, fine, inside);
}

/// [`hull_depths`] compiled for AVX2 and FMA (the hull test's four lanes and fused
/// rotation, [`super::seed_hull`]).
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn hull_depths_wide(
    origins: &[[f64; 3]],
    dirs: &[[f64; 3]],
    grid: &DepthGrid<'_>,
    fine: &mut [[f64; 3]],
    inside: &mut [bool],
) {
    search_all(origins, dirs, grid, fine, inside);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::DIST_LEN;
    use crate::track::{hull_inside, HullCamera};

    /// The search written as numpy did it: every coarse sample tested, the run found by
    /// its first entry and first exit, every fine sample tested, then cleared without a run.
    fn plain(origin: [f64; 3], dir: [f64; 3], grid: &DepthGrid<'_>) -> (Vec<[f64; 3]>, Vec<bool>) {
        let at = |depth: f64| -> [f64; 3] { std::array::from_fn(|a| origin[a] + depth * dir[a]) };
        let pts: Vec<[f64; 3]> = grid.coarse.iter().map(|&c| at(c)).collect();
        let mut hull = vec![false; pts.len()];
        hull_inside(&pts, grid.views, grid.min_seen, &mut hull);
        let k = hull.len();
        let first = hull.iter().position(|&h| h).unwrap_or(0);
        let run: Vec<bool> = (0..k)
            .map(|i| i >= first && hull[first..=i].iter().all(|&h| h))
            .collect();
        let last = k - 1 - run.iter().rev().position(|&r| r).unwrap_or(0);
        let near = grid.coarse[first] - grid.step;
        let far = grid.coarse[last] + grid.step;
        let fine: Vec<[f64; 3]> = grid
            .fractions
            .iter()
            .map(|&f| at(near + (far - near) * f))
            .collect();
        let mut inside = vec![false; fine.len()];
        hull_inside(&fine, grid.views, grid.min_seen, &mut inside);
        let any = hull.iter().any(|&h| h);
        (fine, inside.into_iter().map(|i| i && any).collect())
    }

    #[test]
    fn the_shortcuts_change_no_sample_and_no_answer() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let (w, h) = (80usize, 60usize);
        // Two cameras on either side of a ball at the origin, masks of two discs (the
        // ray can leave the hull and enter it again: only the first run counts).
        let discs = |cx: f64| -> Vec<bool> {
            (0..w * h)
                .map(|i| {
                    let (u, v) = ((i % w) as f64, (i / w) as f64);
                    (u - cx).hypot(v - 30.0) < 9.0 || (u - cx - 22.0).hypot(v - 30.0) < 6.0
                })
                .collect()
        };
        let masks = [discs(30.0), discs(28.0)];
        let camera = HullCamera {
            k: [[70.0, 0.0, 40.0], [0.0, 70.0, 30.0], [0.0, 0.0, 1.0]],
            dist: [0.0; DIST_LEN],
            width: w,
            height: h,
        };
        let mut lens = camera;
        lens.dist[0] = -0.05;
        let views = [
            HullView {
                r: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                t: [0.0, 0.0, 5.0],
                camera,
                mask: &masks[0],
            },
            HullView {
                r: [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]],
                t: [0.0, 0.0, 5.0],
                camera: lens,
                mask: &masks[1],
            },
        ];
        let coarse: Vec<f64> = (0..120).map(|i| 0.5 + 9.0 * i as f64 / 119.0).collect();
        let fractions: Vec<f64> = (0..96).map(|i| i as f64 / 95.0).collect();
        let grid = DepthGrid {
            coarse: &coarse,
            fractions: &fractions,
            step: coarse[1] - coarse[0],
            views: &views,
            min_seen: 2,
        };
        // Rays from a third camera's centre (-5, 0, 0)... through points about the ball.
        let m = 400;
        let origins = vec![[0.0, 0.0, -5.0]; m];
        let dirs: Vec<[f64; 3]> = (0..m)
            .map(|_| {
                let target = [
                    rng.random_range(-1.5..2.5),
                    rng.random_range(-0.8..0.8),
                    0.0,
                ];
                let d: [f64; 3] = [target[0], target[1], 5.0];
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                [d[0] / n, d[1] / n, d[2] / n]
            })
            .collect();
        let mut fine = vec![[0.0; 3]; m * 96];
        let mut inside = vec![false; m * 96];
        hull_depths(&origins, &dirs, &grid, &mut fine, &mut inside);
        let (mut entered, mut missed) = (0, 0);
        for r in 0..m {
            let (want_fine, want_inside) = plain(origins[r], dirs[r], &grid);
            assert_eq!(&fine[r * 96..(r + 1) * 96], &want_fine[..], "ray {r}");
            assert_eq!(&inside[r * 96..(r + 1) * 96], &want_inside[..], "ray {r}");
            if want_inside.iter().any(|&i| i) {
                entered += 1;
            } else {
                missed += 1;
            }
        }
        assert!(
            entered > 50 && missed > 50,
            "{entered} rays in the hull, {missed} not"
        );
    }
}
