//! Resampling of the search image (and of sub-pixel template points): bilinear or Keys'
//! bicubic, eight patch pixels at a time, compiled for AVX2+FMA when the CPU has them.
//!
//! Pixel `(u, v)` = (column, row), pixel centres at integers. Search coordinates are split
//! into an integer base (the patch centre's floor) and small `f32` offsets, so single
//! precision keeps ~1e-6 px however large the image.

use super::sample::TemplatePatch;
use super::types::{ImageView, Interpolation};

/// Whether the square of half-width `h` around the origin, mapped by `x -> A x + b`
/// (`linear = [[a11, a12], [a21, a22]]` scaled by `h` already), lies inside the image
/// where the interpolation is defined without padding: `0 <= u <= width - 1` for bilinear,
/// `1 <= u <= width - 2` for bicubic, likewise `v`. The image of a square is a
/// parallelogram, so its corners decide.
pub(crate) fn inside(
    image: &ImageView<'_>,
    b: [f64; 2],
    linear: [[f64; 2]; 2],
    interpolation: Interpolation,
) -> bool {
    let margin = match interpolation {
        Interpolation::Bilinear => 0.0,
        Interpolation::Bicubic => 1.0,
    };
    let du = linear[0][0].abs() + linear[0][1].abs() + margin;
    let dv = linear[1][0].abs() + linear[1][1].abs() + margin;
    let (w, h) = ((image.width - 1) as f64, (image.height - 1) as f64);
    // Written so that NaN fails.
    b[0] - du >= 0.0 && b[0] + du <= w && b[1] - dv >= 0.0 && b[1] + dv <= h
}

/// Bilinear sample at `base + offset` (`base` integral, `offset` small); the caller has
/// checked that the point lies inside. Indices are clamped so that rounding at the very
/// border cannot read outside.
#[inline(always)]
pub(crate) fn bilinear(image: &ImageView<'_>, base: [f64; 2], offset: [f32; 2]) -> f32 {
    let fu = floor(offset[0]);
    let fv = floor(offset[1]);
    let iu = base[0] as isize + fu as isize;
    let iv = base[1] as isize + fv as isize;
    let mut tu = offset[0] - fu;
    let mut tv = offset[1] - fv;
    let max_u = image.width as isize - 2;
    let max_v = image.height as isize - 2;
    let iu = if iu < 0 {
        tu = 0.0;
        0
    } else if iu > max_u {
        tu = 1.0;
        max_u
    } else {
        iu
    } as usize;
    let iv = if iv < 0 {
        tv = 0.0;
        0
    } else if iv > max_v {
        tv = 1.0;
        max_v
    } else {
        iv
    } as usize;
    let row = iv * image.width + iu;
    let d = image.data;
    let (p00, p01) = (d[row], d[row + 1]);
    let (p10, p11) = (d[row + image.width], d[row + image.width + 1]);
    let top = p00 + tu * (p01 - p00);
    let bottom = p10 + tu * (p11 - p10);
    top + tv * (bottom - top)
}

/// `x.floor()` for the small offsets of a patch (|x| < 2^14), without a libm call: a
/// float-to-int cast truncates, which is the floor for non-negative numbers.
#[inline(always)]
fn floor(x: f32) -> f32 {
    const BIAS: f32 = 16384.0;
    ((x + BIAS) as i32) as f32 - BIAS
}

/// Keys' cubic convolution (a = -1/2) at `base + offset`, from the 4x4 neighbourhood; the
/// caller has checked that the point lies at least one pixel inside. Indices are clamped
/// as in [`bilinear`].
#[inline(always)]
pub(crate) fn bicubic(image: &ImageView<'_>, base: [f64; 2], offset: [f32; 2]) -> f32 {
    let (iu, wu) = cubic_cell(base[0], offset[0], image.width);
    let (iv, wv) = cubic_cell(base[1], offset[1], image.height);
    cubic_blend(image, iu, iv, wu, wv)
}

/// One axis of [`bicubic`]: the cell's index (its second tap) and the taps' weights at
/// `base + offset` along an axis of `size` pixels. A grid of samples on whole-pixel steps
/// (the template patch) computes them once per column and once per row.
#[inline(always)]
pub(crate) fn cubic_cell(base: f64, offset: f32, size: usize) -> (usize, [f32; 4]) {
    let f = floor(offset);
    let i = (base as isize + f as isize).clamp(1, size as isize - 3) as usize;
    let t = (offset - f).clamp(0.0, 1.0);
    let t2 = t * t;
    let t3 = t2 * t;
    (
        i,
        [
            -0.5 * t3 + t2 - 0.5 * t,
            1.5 * t3 - 2.5 * t2 + 1.0,
            -1.5 * t3 + 2.0 * t2 + 0.5 * t,
            0.5 * t3 - 0.5 * t2,
        ],
    )
}

/// [`bicubic`]'s blend of the 4x4 taps around column `iu`, row `iv` with the weights
/// `wu` across and `wv` down.
#[inline(always)]
pub(crate) fn cubic_blend(
    image: &ImageView<'_>,
    iu: usize,
    iv: usize,
    wu: [f32; 4],
    wv: [f32; 4],
) -> f32 {
    let d = image.data;
    let mut value = 0.0;
    for (r, w) in wv.iter().enumerate() {
        let row = (iv + r - 1) * image.width + iu - 1;
        let p = &d[row..row + 4];
        value += w * (wu[0] * p[0] + wu[1] * p[1] + wu[2] * p[2] + wu[3] * p[3]);
    }
    value
}

/// Resamples the search image under `x -> A x + b` at the template's offsets into `out`;
/// false (and `out` untouched) when the warped patch leaves the image.
pub(crate) fn sample_search(
    image: &ImageView<'_>,
    a: [f64; 4],
    b: [f64; 2],
    patch: &TemplatePatch,
    interpolation: Interpolation,
    out: &mut [f32],
) -> bool {
    let h = (patch.size / 2) as f64;
    if !inside(
        image,
        b,
        [[a[0] * h, a[1] * h], [a[2] * h, a[3] * h]],
        interpolation,
    ) {
        return false;
    }
    resample_at(image, a, b, &patch.dx, &patch.dy, out, interpolation);
    true
}

/// Resamples the search image under `x -> A x + b` on the template's grid widened by one
/// pixel on every side (`(size + 2)^2` samples, row by row, into `out`): central
/// differences of it are the warped search patch's gradients in template coordinates.
/// False (and `out` untouched) when the widened patch leaves the image.
pub(crate) fn sample_search_ring(
    image: &ImageView<'_>,
    a: [f64; 4],
    b: [f64; 2],
    patch: &TemplatePatch,
    interpolation: Interpolation,
    out: &mut [f32],
) -> bool {
    let h = (patch.size / 2 + 1) as f64;
    if !inside(
        image,
        b,
        [[a[0] * h, a[1] * h], [a[2] * h, a[3] * h]],
        interpolation,
    ) {
        return false;
    }
    resample_at(
        image,
        a,
        b,
        &patch.ring_dx,
        &patch.ring_dy,
        out,
        interpolation,
    );
    true
}

/// Resamples at the offsets `dx, dy` (padded to a multiple of eight, at least `out.len()`).
fn resample_at(
    image: &ImageView<'_>,
    a: [f64; 4],
    b: [f64; 2],
    dx: &[f32],
    dy: &[f32],
    out: &mut [f32],
    interpolation: Interpolation,
) {
    #[cfg(target_arch = "x86_64")]
    if wide() {
        // SAFETY: `wide` checked that the CPU has AVX2 and FMA.
        unsafe { resample_wide(image, a, b, dx, dy, out, interpolation) };
        return;
    }
    resample(image, a, b, dx, dy, out, interpolation);
}

/// Whether the CPU runs [`resample_wide`] (AVX2 and FMA, detected once; cached by std).
#[cfg(target_arch = "x86_64")]
#[inline]
pub(crate) fn wide() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// [`resample`] compiled for AVX2 and FMA: the eight-lane position and weight arithmetic
/// vectorises in one register, and `floor` and the clamps become single instructions
/// (the portable build targets SSE2). About half the time of an iteration. Bilinear
/// resampling gathers the cells' pixels in vector registers ([`super::gather`]), bicubic
/// loads each cell's rows of taps and transposes them into registers ([`super::cubic`]).
///
/// # Safety
/// The CPU must have AVX2 and FMA ([`wide`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn resample_wide(
    image: &ImageView<'_>,
    a: [f64; 4],
    b: [f64; 2],
    dx: &[f32],
    dy: &[f32],
    out: &mut [f32],
    interpolation: Interpolation,
) {
    if image.data.len() <= i32::MAX as usize {
        match interpolation {
            Interpolation::Bilinear => {
                // SAFETY: this function runs on CPUs with AVX2 and FMA; the caller checked
                // that the patch lies inside the image, and the image's pixels are
                // indexable by i32.
                unsafe { super::gather::bilinear_wide(image, a, b, dx, dy, out) };
                return;
            }
            Interpolation::Bicubic if image.width >= 4 && image.height >= 4 => {
                // SAFETY: as above, the patch one pixel inside the image.
                unsafe { super::cubic::bicubic_wide(image, a, b, dx, dy, out) };
                return;
            }
            Interpolation::Bicubic => {}
        }
    }
    resample(image, a, b, dx, dy, out, interpolation);
}

/// A separable interpolation kernel of `TAPS` taps per axis, the first at `floor - FIRST`.
trait Kernel<const TAPS: usize> {
    const FIRST: i32;
    fn weights(t: f32) -> [f32; TAPS];
}

struct Linear;
impl Kernel<2> for Linear {
    const FIRST: i32 = 0;
    #[inline(always)]
    fn weights(t: f32) -> [f32; 2] {
        [1.0 - t, t]
    }
}

struct Cubic;
impl Kernel<4> for Cubic {
    const FIRST: i32 = 1;
    #[inline(always)]
    fn weights(t: f32) -> [f32; 4] {
        let t2 = t * t;
        let t3 = t2 * t;
        [
            -0.5 * t3 + t2 - 0.5 * t,
            1.5 * t3 - 2.5 * t2 + 1.0,
            -1.5 * t3 + 2.0 * t2 + 0.5 * t,
            0.5 * t3 - 0.5 * t2,
        ]
    }
}

/// Resamples eight pixels at a time: positions, floors and weights for all eight first
/// (straight-line arithmetic the compiler vectorises), then the taps.
#[inline(always)]
pub(super) fn resample(
    image: &ImageView<'_>,
    a: [f64; 4],
    b: [f64; 2],
    dx: &[f32],
    dy: &[f32],
    out: &mut [f32],
    interpolation: Interpolation,
) {
    match interpolation {
        Interpolation::Bilinear => resample_with::<2, Linear>(image, a, b, dx, dy, out),
        Interpolation::Bicubic => resample_with::<4, Cubic>(image, a, b, dx, dy, out),
    }
}

#[inline(always)]
fn resample_with<const TAPS: usize, K: Kernel<TAPS>>(
    image: &ImageView<'_>,
    a: [f64; 4],
    b: [f64; 2],
    offsets_x: &[f32],
    offsets_y: &[f32],
    out: &mut [f32],
) {
    const LANES: usize = 8;
    let base = [b[0].floor(), b[1].floor()];
    let frac = [(b[0] - base[0]) as f32, (b[1] - base[1]) as f32];
    let [a11, a12, a21, a22] = a.map(|x| x as f32);
    let width = image.width;
    // The first tap's index stays within [0, size - TAPS]: the caller checked that the
    // patch lies inside, so clamping only catches rounding at the very border, where the
    // recomputed fraction then reaches 0 or 1.
    let lo = K::FIRST as f32;
    let hi_u = (width - TAPS) as f32 + lo;
    let hi_v = (image.height - TAPS) as f32 + lo;
    let (bu, bv) = (base[0] as f32, base[1] as f32);
    let mut column = [0i32; LANES];
    let mut row = [0i32; LANES];
    let mut wu = [[0.0f32; TAPS]; LANES];
    let mut wv = [[0.0f32; TAPS]; LANES];
    let n = out.len();
    let mut start = 0;
    while start < n {
        let m = LANES.min(n - start);
        // All eight lanes (the offsets are padded): a fixed trip count vectorises.
        let dx: &[f32; LANES] = offsets_x[start..start + LANES].try_into().expect("padded");
        let dy: &[f32; LANES] = offsets_y[start..start + LANES].try_into().expect("padded");
        for l in 0..LANES {
            let u = frac[0] + a11 * dx[l] + a12 * dy[l];
            let v = frac[1] + a21 * dx[l] + a22 * dy[l];
            // Integral parts relative to the base are small: floor by a biased cast.
            let iu = (floor(u) + bu).clamp(lo, hi_u);
            let iv = (floor(v) + bv).clamp(lo, hi_v);
            // Integers below 2^24 are exact in f32, so the difference is too, and the
            // fraction keeps the offset's precision however large the image.
            let tu = (u - (iu - bu)).clamp(0.0, 1.0);
            let tv = (v - (iv - bv)).clamp(0.0, 1.0);
            // Whole numbers in [FIRST, 2^24) after the clamps, so the cast through i32 is
            // exact; a cast to usize has no vector instruction on x86 and split this loop
            // into scalar compares per lane (profiled: most of the resampling's time).
            column[l] = iu as i32 - K::FIRST;
            row[l] = iv as i32 - K::FIRST;
            wu[l] = K::weights(tu);
            wv[l] = K::weights(tv);
        }
        for l in 0..m {
            let first = row[l] as usize * width + column[l] as usize;
            let mut value = 0.0;
            for (r, w) in wv[l].iter().enumerate() {
                let at = first + r * width;
                let p = &image.data[at..at + TAPS];
                let mut across = 0.0;
                for c in 0..TAPS {
                    across += wu[l][c] * p[c];
                }
                value += w * across;
            }
            out[start + l] = value;
        }
        start += m;
    }
}
