//! Bilinear resampling of a warped patch in AVX2 registers, eight pixels at a time: the
//! positions, the cells and their weights as in [`super::resample`]'s portable loop, and
//! the four corner pixels of each cell fetched by vector gathers.
//!
//! The portable loop computes the eight positions in one register but converts each
//! cell's corner to an index and blends the four pixels one lane at a time (scalar
//! compares for Rust's saturating float-to-integer casts, four scalar loads and three
//! blends per sample): profiled at a third of the tracker's step. Here every operation is
//! the portable loop's, in the same order and without fused multiply-adds (`0 + x` kept
//! where it sums from zero), so the samples are the same to the bit; a test checks that.

use std::arch::x86_64::{
    __m128, __m256, __m256i, _mm256_add_epi32, _mm256_add_ps, _mm256_cvtepi32_ps,
    _mm256_cvttps_epi32, _mm256_loadu_ps, _mm256_max_ps, _mm256_min_ps, _mm256_mul_ps,
    _mm256_mullo_epi32, _mm256_set1_epi32, _mm256_set1_ps, _mm256_set_m128, _mm256_setzero_ps,
    _mm256_shuffle_ps, _mm256_storeu_ps, _mm256_storeu_si256, _mm256_sub_ps, _mm_castpd_ps,
    _mm_load_sd, _mm_loadh_pd,
};

use super::types::ImageView;

/// Bilinear samples of `image` under `x -> A x + b` at the offsets `dx, dy` (padded to a
/// multiple of eight, at least `out.len()`) into `out`, as
/// `super::resample::resample_with::<2, Linear>` computes them. The caller has checked
/// that the warped patch lies inside the image (then every position is a finite number
/// within the image; the clamps only catch rounding at the border) and that the image has
/// fewer than `2^31` pixels (the gathers' indices are `i32`).
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn bilinear_wide(
    image: &ImageView<'_>,
    a: [f64; 4],
    b: [f64; 2],
    offsets_x: &[f32],
    offsets_y: &[f32],
    out: &mut [f32],
) {
    const LANES: usize = 8;
    const BIAS: f32 = 16384.0;
    let (width, height) = (image.width, image.height);
    debug_assert!(width >= 2 && height >= 2 && image.data.len() == width * height);
    debug_assert!(image.data.len() <= i32::MAX as usize);
    let base = [b[0].floor(), b[1].floor()];
    let frac = [
        _mm256_set1_ps((b[0] - base[0]) as f32),
        _mm256_set1_ps((b[1] - base[1]) as f32),
    ];
    let [a11, a12, a21, a22] = a.map(|x| _mm256_set1_ps(x as f32));
    let (bu, bv) = (
        _mm256_set1_ps(base[0] as f32),
        _mm256_set1_ps(base[1] as f32),
    );
    let bias = _mm256_set1_ps(BIAS);
    let (zero, one) = (_mm256_setzero_ps(), _mm256_set1_ps(1.0));
    let hi_u = _mm256_set1_ps((width - 2) as f32);
    let hi_v = _mm256_set1_ps((height - 2) as f32);
    let stride = _mm256_set1_epi32(width as i32);
    // `x.clamp(lo, hi)` as Rust computes it for a number (not NaN): `x` itself when it
    // equals a bound, so a `-0.0` stays `-0.0` (`maxps` / `minps` return their second
    // operand on ties).
    let clamp = |x: __m256, lo: __m256, hi: __m256| _mm256_min_ps(hi, _mm256_max_ps(lo, x));
    // `x.floor()` of the portable loop for the small offsets of a patch: a biased
    // truncation (the bias keeps the argument positive, where truncation is the floor).
    let floor = |x: __m256| {
        _mm256_sub_ps(
            _mm256_cvtepi32_ps(_mm256_cvttps_epi32(_mm256_add_ps(x, bias))),
            bias,
        )
    };
    let data = image.data.as_ptr();
    let n = out.len();
    let mut start = 0;
    while start < n {
        let m = LANES.min(n - start);
        let dx: &[f32; LANES] = offsets_x[start..start + LANES].try_into().expect("padded");
        let dy: &[f32; LANES] = offsets_y[start..start + LANES].try_into().expect("padded");
        // SAFETY: `dx` and `dy` hold eight floats each.
        let (dx, dy) = unsafe { (_mm256_loadu_ps(dx.as_ptr()), _mm256_loadu_ps(dy.as_ptr())) };
        let u = _mm256_add_ps(
            _mm256_add_ps(frac[0], _mm256_mul_ps(a11, dx)),
            _mm256_mul_ps(a12, dy),
        );
        let v = _mm256_add_ps(
            _mm256_add_ps(frac[1], _mm256_mul_ps(a21, dx)),
            _mm256_mul_ps(a22, dy),
        );
        let iu = clamp(_mm256_add_ps(floor(u), bu), zero, hi_u);
        let iv = clamp(_mm256_add_ps(floor(v), bv), zero, hi_v);
        let tu = clamp(_mm256_sub_ps(u, _mm256_sub_ps(iu, bu)), zero, one);
        let tv = clamp(_mm256_sub_ps(v, _mm256_sub_ps(iv, bv)), zero, one);
        // Whole numbers in [0, width - 2] and [0, height - 2]: exact in i32.
        let first: __m256i = _mm256_add_epi32(
            _mm256_mullo_epi32(_mm256_cvttps_epi32(iv), stride),
            _mm256_cvttps_epi32(iu),
        );
        // SAFETY: `first` indexes a pixel of column <= width - 2 and row <= height - 2, so
        // it and its right, lower and diagonal neighbours lie within `image.data`.
        let [p00, p01, p10, p11] = unsafe { corners(data, first, width) };
        let (wu0, wv0) = (_mm256_sub_ps(one, tu), _mm256_sub_ps(one, tv));
        // The portable loop sums each row's taps and then the rows from zero.
        let across = |p0: __m256, p1: __m256| {
            _mm256_add_ps(
                _mm256_add_ps(zero, _mm256_mul_ps(wu0, p0)),
                _mm256_mul_ps(tu, p1),
            )
        };
        let value = _mm256_add_ps(
            _mm256_add_ps(zero, _mm256_mul_ps(wv0, across(p00, p01))),
            _mm256_mul_ps(tv, across(p10, p11)),
        );
        if m == LANES {
            // SAFETY: `out[start..start + 8]` is in bounds (m == 8).
            unsafe { _mm256_storeu_ps(out[start..start + LANES].as_mut_ptr(), value) };
        } else {
            let mut lanes = [0.0f32; LANES];
            // SAFETY: `lanes` holds eight floats.
            unsafe { _mm256_storeu_ps(lanes.as_mut_ptr(), value) };
            out[start..start + m].copy_from_slice(&lanes[..m]);
        }
        start += m;
    }
}

/// The four corners `[p00, p01, p10, p11]` of the eight cells whose upper-left pixels are
/// `first` (indices into `data`, rows of `width`): each cell's upper pair `(p00, p01)`
/// and lower pair `(p10, p11)` are adjacent floats, loaded as one 64-bit value each and
/// sorted into lanes by two shuffles per row. The same values as four gathers of eight
/// (what this replaced): on this machine's AMD cores a gather of eight floats cost more
/// than the sixteen 64-bit loads and their shuffles (perf: the gathers were two thirds
/// of the bilinear resampling, the largest kernel of the tracker's step).
///
/// # Safety
/// The CPU must have AVX2; every index of `first` plus `width + 1` must lie within the
/// image `data` points into.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn corners(data: *const f32, first: __m256i, width: usize) -> [__m256; 4] {
    let mut index = [0i32; 8];
    // SAFETY: `index` holds eight `i32`.
    unsafe { _mm256_storeu_si256(index.as_mut_ptr().cast(), first) };
    // Lanes `l` and `l + 1`'s pairs of the row `row` (0 upper, `width` lower) in one
    // 128-bit register: `[a_l, b_l, a_{l+1}, b_{l+1}]`.
    let two = |l: usize, row: usize| -> __m128 {
        // SAFETY: the caller's: `index[l] + row + 1` is within the image (non-negative:
        // the indices are of clamped cells).
        unsafe {
            let at = |k: usize| data.add(index[k] as usize + row).cast::<f64>();
            _mm_castpd_ps(_mm_loadh_pd(_mm_load_sd(at(l)), at(l + 1)))
        }
    };
    let rows = |row: usize| {
        // 128-bit halves: lanes 0-1 with 4-5 and 2-3 with 6-7, so that the in-lane
        // shuffle picks `a` (even) and `b` (odd) of lanes 0-3 below and 4-7 above.
        let (low, high) = (
            _mm256_set_m128(two(4, row), two(0, row)),
            _mm256_set_m128(two(6, row), two(2, row)),
        );
        (
            _mm256_shuffle_ps::<0b10_00_10_00>(low, high),
            _mm256_shuffle_ps::<0b11_01_11_01>(low, high),
        )
    };
    let ((p00, p01), (p10, p11)) = (rows(0), rows(width));
    [p00, p01, p10, p11]
}
