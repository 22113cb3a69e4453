//! The template patch's values, gradients and value sums against the single loop they
//! were computed in before the sums were split from it, bit for bit.

use super::TemplatePatch;
use crate::lsm::types::{ImageView, Interpolation};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The loop `TemplatePatch::sample` ran before: values, the six geometric columns and the
/// two `f64` sums in one pass over the widened grid `border` (`(size + 2)^2`).
fn one_loop(patch: &TemplatePatch) -> (Vec<f32>, Vec<f32>, f64, f64) {
    let (size, m) = (patch.size, patch.size + 2);
    let n = size * size;
    let (mut value, mut geo) = (vec![0.0f32; n], vec![0.0f32; 6 * n]);
    let (mut sum_value, mut sum_square) = (0.0f64, 0.0f64);
    for r in 0..size {
        for c in 0..size {
            let i = r * size + c;
            let at = |rr: usize, cc: usize| patch.border[rr * m + cc];
            let t = at(r + 1, c + 1);
            let gx = 0.5 * (at(r + 1, c + 2) - at(r + 1, c));
            let gy = 0.5 * (at(r + 2, c + 1) - at(r, c + 1));
            let (dx, dy) = (patch.dx[i], patch.dy[i]);
            value[i] = t;
            let row = [gx, gy, gx * dx, gx * dy, gy * dx, gy * dy];
            for (k, g) in row.into_iter().enumerate() {
                geo[k * n + i] = g;
            }
            sum_value += t as f64;
            sum_square += (t as f64) * (t as f64);
        }
    }
    (value, geo, sum_value, sum_square)
}

fn bits(x: &[f32]) -> Vec<u32> {
    x.iter().map(|v| v.to_bits()).collect()
}

#[test]
fn split_values_gradients_and_sums_equal_the_single_loop_to_the_bit() {
    // Noise over several magnitudes (so that the f64 sums' order shows in their last
    // bits), odd sizes whose rows are not whole vectors, every sampling path (pixel
    // centres, the unwarped bilinear rows, bicubic), one patch reused across sizes.
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let (w, h) = (61usize, 47usize);
    let data: Vec<f32> = (0..w * h)
        .map(|i| rng.random_range(-3.0f32..300.0) * if i % 7 == 0 { 1e-3 } else { 1.0 })
        .collect();
    let image = ImageView {
        data: &data,
        width: w,
        height: h,
    };
    let mut patch = TemplatePatch::default();
    let mut checked = 0;
    for size in [3usize, 5, 9, 15, 17, 21] {
        for case in 0..200 {
            let interpolation = if case % 2 == 0 {
                Interpolation::Bilinear
            } else {
                Interpolation::Bicubic
            };
            let mut centre = [
                rng.random_range(0.0..w as f64),
                rng.random_range(0.0..h as f64),
            ];
            if case % 5 == 0 {
                centre = [centre[0].floor(), centre[1].floor()];
            }
            if !patch.sample(&image, centre, size, interpolation) {
                continue;
            }
            let (value, geo, sum_value, sum_square) = one_loop(&patch);
            assert_eq!(bits(&patch.value), bits(&value), "values, size {size}");
            assert_eq!(bits(&patch.geo), bits(&geo), "gradients, size {size}");
            assert_eq!(patch.value_sum.to_bits(), sum_value.to_bits());
            assert_eq!(patch.value_square.to_bits(), sum_square.to_bits());
            checked += 1;
        }
    }
    assert!(checked > 600, "only {checked} patches inside the image");
}
