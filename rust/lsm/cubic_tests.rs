//! The AVX2 bicubic resampling ([`super::cubic`]) against the portable loop, bit for bit.

use super::resample::{inside, resample, wide};
use super::types::{ImageView, Interpolation};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Offsets of a `size x size` patch, row by row, zero-padded to a multiple of eight.
fn offsets(size: usize) -> (Vec<f32>, Vec<f32>) {
    let (n, half) = (size * size, (size / 2) as f32);
    let padded = n.div_ceil(8) * 8;
    let along = |f: fn(usize, usize) -> usize| -> Vec<f32> {
        (0..padded)
            .map(|i| if i < n { f(i, size) as f32 - half } else { 0.0 })
            .collect()
    };
    (along(|i, s| i % s), along(|i, s| i / s))
}

fn warp(rng: &mut ChaCha8Rng) -> [f64; 4] {
    let angle = rng.random_range(-40.0f64..40.0).to_radians();
    let scale = rng.random_range(0.7..1.4);
    let shear = rng.random_range(-0.2..0.2);
    let (c, s) = (angle.cos() * scale, angle.sin() * scale);
    [c, -s + shear, s, c]
}

#[test]
fn transposed_bicubic_samples_equal_the_portable_loop_to_the_bit() {
    // The tracker's results may not move with the CPU: random warps anywhere the patch
    // fits (15x15, the tracker's, its 17x17 ring and odd sizes whose last group of eight
    // is partial), many at the image border where the clamps act, centres on whole pixels
    // and just below them (where a position's rounding can reach the next cell).
    if !wide() {
        return;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(29);
    let (w, h) = (57usize, 43usize);
    // Noise, not a smooth texture: any misplaced tap or weight changes the value.
    let data: Vec<f32> = (0..w * h).map(|_| rng.random_range(-50.0..250.0)).collect();
    let image = ImageView {
        data: &data,
        width: w,
        height: h,
    };
    let mut checked = 0;
    for size in [3usize, 5, 11, 15, 17] {
        let (dx, dy) = offsets(size);
        let (n, half) = (size * size, (size / 2) as f64);
        let (mut want, mut got) = (vec![0.0f32; n], vec![0.0f32; n]);
        for case in 0..3000 {
            let a = if case % 4 == 0 {
                [1.0, 0.0, 0.0, 1.0]
            } else {
                warp(&mut rng)
            };
            let mut b = [rng.random_range(0.0..w as f64), rng.random_range(0.0..h as f64)];
            match case % 5 {
                0 => b = [b[0].round(), b[1].round()],
                1 => b = [b[0].round() - 1e-7, b[1].round() - 3e-8],
                _ => {}
            }
            let linear = [[a[0] * half, a[1] * half], [a[2] * half, a[3] * half]];
            if !inside(&image, b, linear, Interpolation::Bicubic) {
                continue;
            }
            resample(&image, a, b, &dx, &dy, &mut want, Interpolation::Bicubic);
            // SAFETY: `wide` checked the CPU; the patch lies one pixel inside the image.
            unsafe { super::cubic::bicubic_wide(&image, a, b, &dx, &dy, &mut got) };
            for i in 0..n {
                assert_eq!(
                    got[i].to_bits(),
                    want[i].to_bits(),
                    "size {size}, case {case}, a {a:?}, b {b:?}, pixel {i}: {} vs {}",
                    got[i],
                    want[i]
                );
            }
            checked += 1;
        }
        // The patch fits at the very border too: the identity at the corners.
        let e = half + 1.0;
        for b in [
            [e, e],
            [w as f64 - 1.0 - e, h as f64 - 1.0 - e],
            [e, h as f64 - 1.0 - e],
        ] {
            let a = [1.0, 0.0, 0.0, 1.0];
            resample(&image, a, b, &dx, &dy, &mut want, Interpolation::Bicubic);
            // SAFETY: as above.
            unsafe { super::cubic::bicubic_wide(&image, a, b, &dx, &dy, &mut got) };
            assert!(got.iter().zip(&want).all(|(g, x)| g.to_bits() == x.to_bits()));
            checked += 1;
        }
    }
    assert!(checked > 4000, "only {checked} warps fit");
}
