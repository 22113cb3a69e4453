//! Keys' bicubic resampling of a warped patch in AVX2 registers, eight pixels at a time:
//! the positions, cells and weights as in [`super::resample`]'s portable loop, the 4x4
//! taps of each cell fetched as four rows of four pixels and transposed into registers.
//!
//! The portable loop computes the positions and weights of eight pixels in vector
//! registers but then blends each pixel's sixteen taps one lane at a time (sixteen scalar
//! loads, multiplies and adds per pixel): the search patches' resampling was over half of
//! the tracker's spatial matches (perf on a tracked frame of the 1024x768 capture). A
//! cell's row of four taps is contiguous in the image, so one 128-bit load fetches it; four
//! lanes' rows transposed give each tap of the row for all lanes in one register, and the
//! blend runs eight lanes at once. Every operation is the portable loop's, in the same
//! order and without fused multiply-adds (`0 + x` kept where it sums from zero), so the
//! samples are the same to the bit; a test checks that.

use std::arch::x86_64::{
    __m256, _mm256_add_epi32, _mm256_add_ps, _mm256_cvtepi32_ps, _mm256_cvttps_epi32,
    _mm256_loadu_ps, _mm256_max_ps, _mm256_min_ps, _mm256_mul_ps, _mm256_mullo_epi32,
    _mm256_set1_epi32, _mm256_set1_ps, _mm256_set_m128, _mm256_setzero_ps, _mm256_shuffle_ps,
    _mm256_storeu_ps, _mm256_storeu_si256, _mm256_sub_ps, _mm256_unpackhi_ps, _mm256_unpacklo_ps,
    _mm_loadu_ps,
};

use super::types::ImageView;

/// Bicubic samples of `image` under `x -> A x + b` at the offsets `dx, dy` (padded to a
/// multiple of eight, at least `out.len()`) into `out`, as
/// `super::resample::resample_with::<4, Cubic>` computes them. The caller has checked that
/// the warped patch lies at least one pixel inside the image (then every position is a
/// finite number within it; the clamps only catch rounding at the border), that the image
/// is at least 4x4 and has fewer than `2^31` pixels (the indices are `i32`).
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn bicubic_wide(
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
    debug_assert!(width >= 4 && height >= 4 && image.data.len() == width * height);
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
    // The portable loop's bounds of the first tap + 1: `lo = FIRST`, `hi = size - 4 + lo`.
    let lo = _mm256_set1_ps(1.0);
    let hi_u = _mm256_set1_ps((width - 4) as f32 + 1.0);
    let hi_v = _mm256_set1_ps((height - 4) as f32 + 1.0);
    let stride = _mm256_set1_epi32(width as i32);
    let first_tap = _mm256_set1_epi32(-(width as i32) - 1);
    // `x.clamp(lo, hi)` as Rust computes it for a number (see `super::gather`).
    let clamp = |x: __m256, lo: __m256, hi: __m256| _mm256_min_ps(hi, _mm256_max_ps(lo, x));
    let floor = |x: __m256| {
        _mm256_sub_ps(
            _mm256_cvtepi32_ps(_mm256_cvttps_epi32(_mm256_add_ps(x, bias))),
            bias,
        )
    };
    // Keys' weights (a = -1/2) as `Cubic::weights` evaluates them, term by term.
    let (half, one_half, two, two_half) = (
        _mm256_set1_ps(0.5),
        _mm256_set1_ps(1.5),
        _mm256_set1_ps(2.0),
        _mm256_set1_ps(2.5),
    );
    let (minus_half, minus_one_half) = (_mm256_set1_ps(-0.5), _mm256_set1_ps(-1.5));
    let weights = |t: __m256| {
        let t2 = _mm256_mul_ps(t, t);
        let t3 = _mm256_mul_ps(t2, t);
        [
            _mm256_sub_ps(
                _mm256_add_ps(_mm256_mul_ps(minus_half, t3), t2),
                _mm256_mul_ps(half, t),
            ),
            _mm256_add_ps(
                _mm256_sub_ps(_mm256_mul_ps(one_half, t3), _mm256_mul_ps(two_half, t2)),
                one,
            ),
            _mm256_add_ps(
                _mm256_add_ps(_mm256_mul_ps(minus_one_half, t3), _mm256_mul_ps(two, t2)),
                _mm256_mul_ps(half, t),
            ),
            _mm256_sub_ps(_mm256_mul_ps(half, t3), _mm256_mul_ps(half, t2)),
        ]
    };
    let data = image.data.as_ptr();
    let n = out.len();
    let mut first = [0i32; LANES];
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
        let iu = clamp(_mm256_add_ps(floor(u), bu), lo, hi_u);
        let iv = clamp(_mm256_add_ps(floor(v), bv), lo, hi_v);
        let tu = clamp(_mm256_sub_ps(u, _mm256_sub_ps(iu, bu)), zero, one);
        let tv = clamp(_mm256_sub_ps(v, _mm256_sub_ps(iv, bv)), zero, one);
        // The cell's first tap, `(iv - 1) * width + iu - 1`: whole numbers in
        // [1, width - 3] and [1, height - 3], exact in i32.
        let corner = _mm256_add_epi32(
            _mm256_add_epi32(
                _mm256_mullo_epi32(_mm256_cvttps_epi32(iv), stride),
                _mm256_cvttps_epi32(iu),
            ),
            first_tap,
        );
        // SAFETY: `first` holds eight i32.
        unsafe { _mm256_storeu_si256(first.as_mut_ptr().cast(), corner) };
        let (wu, wv) = (weights(tu), weights(tv));
        let mut value = zero;
        for (r, w) in wv.iter().enumerate() {
            let offset = r * width;
            // SAFETY: a cell's first tap lies at column <= width - 4 and row <= height - 4,
            // so its four rows of four taps lie within `image.data`.
            let row = |l: usize| unsafe { _mm_loadu_ps(data.add(first[l] as usize + offset)) };
            // Lanes l and l + 4 share a register (the in-lane shuffles below keep the two
            // halves apart): the transposed taps come out in lane order.
            let pair = |l: usize| -> __m256 { _mm256_set_m128(row(l + 4), row(l)) };
            let [p0, p1, p2, p3] = [pair(0), pair(1), pair(2), pair(3)];
            let (t0, t1) = (_mm256_unpacklo_ps(p0, p1), _mm256_unpackhi_ps(p0, p1));
            let (t2, t3) = (_mm256_unpacklo_ps(p2, p3), _mm256_unpackhi_ps(p2, p3));
            let taps = [
                _mm256_shuffle_ps::<0x44>(t0, t2),
                _mm256_shuffle_ps::<0xEE>(t0, t2),
                _mm256_shuffle_ps::<0x44>(t1, t3),
                _mm256_shuffle_ps::<0xEE>(t1, t3),
            ];
            let mut across = zero;
            for (c, tap) in taps.into_iter().enumerate() {
                across = _mm256_add_ps(across, _mm256_mul_ps(wu[c], tap));
            }
            value = _mm256_add_ps(value, _mm256_mul_ps(*w, across));
        }
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
