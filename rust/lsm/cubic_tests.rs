//! The AVX2 bicubic resampling ([`super::cubic`]) against the portable loop, and the
//! template patch's bicubic grid against the per-sample path, bit for bit.

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
            let mut b = [
                rng.random_range(0.0..w as f64),
                rng.random_range(0.0..h as f64),
            ];
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
            assert!(got
                .iter()
                .zip(&want)
                .all(|(g, x)| g.to_bits() == x.to_bits()));
            checked += 1;
        }
    }
    assert!(checked > 4000, "only {checked} warps fit");
}

#[test]
fn template_grid_samples_equal_the_per_sample_bicubic_to_the_bit() {
    // The template patch's bicubic grid computes each column's and row's cell and weights
    // once: its values and gradients must be `bicubic`'s at every sample, whatever the
    // sub-pixel position (on whole pixels, just below them where a column's rounding can
    // reach the next cell, and anywhere), at the image's border too.
    use super::resample::bicubic;
    use super::sample::TemplatePatch;
    let mut rng = ChaCha8Rng::seed_from_u64(30);
    let (w, h) = (61usize, 47usize);
    let data: Vec<f32> = (0..w * h).map(|_| rng.random_range(-50.0..250.0)).collect();
    let image = ImageView {
        data: &data,
        width: w,
        height: h,
    };
    let mut patch = TemplatePatch::default();
    let mut checked = 0;
    for size in [3usize, 7, 15] {
        let reach = size / 2 + 1;
        let m = size + 2;
        for case in 0..2000 {
            let mut centre = [
                rng.random_range(0.0..w as f64),
                rng.random_range(0.0..h as f64),
            ];
            match case % 4 {
                0 => centre = [centre[0].round(), centre[1].round()],
                1 => centre = [centre[0].round() - 1e-7, centre[1].round() - 2e-7],
                2 => centre = [centre[0].round() + 1e-7, centre[1].round() - 5e-8],
                _ => {}
            }
            if !patch.sample(&image, centre, size, Interpolation::Bicubic) {
                continue;
            }
            let base = [centre[0].floor(), centre[1].floor()];
            let frac = [(centre[0] - base[0]) as f32, (centre[1] - base[1]) as f32];
            // The per-sample path's grid, as `sample` computed it before (the pixels
            // themselves on a pixel centre).
            let grid: Vec<f32> = (0..m * m)
                .map(|i| {
                    let (c, r) = (i % m, i / m);
                    if frac == [0.0, 0.0] {
                        let (u, v) = (base[0] as usize + c - reach, base[1] as usize + r - reach);
                        return data[v * w + u];
                    }
                    let offset = [
                        frac[0] + (c as f32 - reach as f32),
                        frac[1] + (r as f32 - reach as f32),
                    ];
                    bicubic(&image, base, offset)
                })
                .collect();
            let n = size * size;
            for i in 0..n {
                let (r, c) = (i / size + 1, i % size + 1);
                let at = |rr: usize, cc: usize| grid[rr * m + cc];
                let want = [
                    at(r, c),
                    0.5 * (at(r, c + 1) - at(r, c - 1)),
                    0.5 * (at(r + 1, c) - at(r - 1, c)),
                ];
                let got = [patch.value[i], patch.geo[i], patch.geo[n + i]];
                assert_eq!(
                    got.map(f32::to_bits),
                    want.map(f32::to_bits),
                    "size {size} case {case} centre {centre:?} pixel {i}"
                );
            }
            checked += 1;
        }
    }
    assert!(checked > 3000, "only {checked} patches fit");
}
