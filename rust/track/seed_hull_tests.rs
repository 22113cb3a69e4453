//! `seed_hull`'s tests: the pixel, the fused rotation, and the four-lane, any-order hull test
//! and pixels against the one-at-a-time code.

use super::*;

fn camera(dist: [f64; DIST_LEN]) -> HullCamera {
    HullCamera {
        k: [[800.0, 0.3, 320.0], [0.0, 790.0, 240.0], [0.0, 0.0, 1.0]],
        dist,
        width: 640,
        height: 480,
    }
}

#[test]
fn pinhole_without_distortion() {
    let cam = camera([0.0; DIST_LEN]);
    let [u, v] = cam.pixel([0.1, -0.2, 2.0]);
    assert_eq!(u, 800.0 * 0.05 + 0.3 * -0.1 + 320.0);
    assert_eq!(v, 790.0 * -0.1 + 240.0);
}

#[test]
fn seen_and_mask_read_at_the_rounded_pixel() {
    let cam = camera([
        -0.1, 0.02, 0.001, -0.002, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    ]);
    let mut mask = vec![false; 640 * 480];
    let x = [0.05, 0.03, 1.5];
    let [u, v] = cam.pixel(x);
    mask[v.round() as usize * 640 + u.round() as usize] = true;
    assert_eq!(cam.held(x, &mask), (true, true));
    mask[v.round() as usize * 640 + u.round() as usize] = false;
    assert_eq!(cam.held(x, &mask), (false, true));
    // Behind the camera, and outside the image: not seen, held.
    assert_eq!(cam.held([0.05, 0.03, -1.5], &mask), (true, false));
    assert_eq!(cam.held([5.0, 0.03, 1.0], &mask), (true, false));
}

#[test]
fn a_zero_coefficient_changes_nothing() {
    // The skipped terms add exact zeros: with a rational term whose coefficients are
    // tiny but nonzero the pixel moves, with zeros it equals the plain polynomial.
    let plain = camera([
        -0.1, 0.02, 0.0, 0.0, 0.003, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
    ]);
    let mut rational = plain;
    rational.dist[5] = 1e-3;
    let x = [0.2, -0.1, 1.0];
    assert_ne!(plain.pixel(x), rational.pixel(x));
    let (a, b) = (0.2, -0.1);
    let r2: f64 = a * a + b * b;
    let radial = 1.0 + r2 * (-0.1 + r2 * (0.02 + r2 * 0.003));
    assert_eq!(
        plain.pixel(x),
        [
            800.0 * (a * radial) + 0.3 * (b * radial) + 320.0,
            790.0 * (b * radial) + 240.0
        ]
    );
}

/// Views looking at the origin from a ring, with random lenses and masks (a disc
/// about the origin's pixel, holes punched at random).
fn ring(
    rng: &mut impl rand::Rng,
    n: usize,
    masks: &mut Vec<Vec<bool>>,
) -> Vec<(HullCamera, [[f64; 3]; 3], [f64; 3])> {
    let (w, h) = (64usize, 48usize);
    (0..n)
        .map(|c| {
            let angle =
                c as f64 * 2.0 * std::f64::consts::PI / n as f64 + rng.random_range(-0.2..0.2);
            let (s, co) = angle.sin_cos();
            // Rows: the camera's x, y, z axes; z towards the origin from radius 4.
            let r = [[co, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, co]];
            let t = [0.0, 0.0, 4.0];
            let mut dist = [0.0; DIST_LEN];
            for (d, scale) in dist.iter_mut().zip([
                0.2, 0.05, 0.01, 0.01, 0.01, 0.05, 0.01, 0.005, 0.002, 0.001, 0.002, 0.001,
            ]) {
                if rng.random_bool(0.5) {
                    *d = rng.random_range(-1.0..1.0) * scale;
                }
            }
            let camera = HullCamera {
                k: [
                    [60.0, rng.random_range(-1.0..1.0), 32.0],
                    [0.0, 61.0, 24.0],
                    [0.0, 0.0, 1.0],
                ],
                dist,
                width: w,
                height: h,
            };
            let radius = rng.random_range(8.0..20.0);
            masks.push(
                (0..w * h)
                    .map(|i| {
                        let (u, v) = ((i % w) as f64 - 32.0, (i / w) as f64 - 24.0);
                        u.hypot(v) < radius && rng.random_bool(0.95)
                    })
                    .collect(),
            );
            (camera, r, t)
        })
        .collect()
}

#[test]
fn four_at_a_time_in_any_order_is_one_at_a_time() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    for n in 1..8 {
        let mut masks = Vec::new();
        let parts = ring(&mut rng, n, &mut masks);
        let views: Vec<HullView<'_>> = parts
            .iter()
            .zip(&masks)
            .map(|(&(camera, r, t), mask)| HullView { r, t, camera, mask })
            .collect();
        // Rays' samples through the hull and far off, some non-finite, an odd count.
        let mut points: Vec<[f64; 3]> = (0..4001)
            .map(|_| {
                std::array::from_fn(|_| {
                    rng.random_range(-1.0..1.0) * if rng.random_bool(0.1) { 8.0 } else { 0.8 }
                })
            })
            .collect();
        for p in points.iter_mut().step_by(97) {
            p[rng.random_range(0..3)] =
                [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][rng.random_range(0..3)];
        }
        for min_seen in 0..=n.min(4) {
            let want: Vec<bool> = points
                .iter()
                .map(|&p| in_hull(p, &views, min_seen))
                .collect();
            let mut got = vec![false; points.len()];
            hull_inside(&points, &views, min_seen, &mut got);
            assert_eq!(got, want, "{n} views, {min_seen} seen");
            let mut portable = vec![false; points.len()];
            hull_fill(&points, &views, min_seen, &mut 0, &mut portable);
            assert_eq!(portable, want, "{n} views, {min_seen} seen (portable)");
            assert!(
                want.iter().any(|&i| i) && want.iter().any(|&i| !i),
                "{n} views: both answers"
            );
        }
    }
}

#[test]
fn the_rotation_is_a_fused_chain_from_zero() {
    // fma(x2, r2, fma(x1, r1, fma(x0, r0, 0))) + t, as OpenBLAS's product: with
    // x0 r0 = -(1 + 2 eps) and x1 r1 = (1 + eps)^2 the fused chain keeps eps^2, the
    // rounded products cancel to 0.
    let x = 1.0 + f64::EPSILON;
    let view = HullView {
        r: [
            [-(1.0 + 2.0 * f64::EPSILON), x, 0.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
        ],
        t: [0.0, 0.0, 0.5],
        camera: camera([0.0; DIST_LEN]),
        mask: &[],
    };
    let p = [1.0, x, 0.0];
    assert_eq!(view.camera_frame(p)[0], f64::EPSILON * f64::EPSILON);
    assert_eq!(
        -(1.0 + 2.0 * f64::EPSILON) + x * x,
        0.0,
        "unfused, it cancels"
    );
    assert_eq!(view.camera_frame(p)[2], 0.5);
    // The four-lane product equals the one-point product, lane by lane.
    let q = [[1.0, x, 3.0, -2.0], [x, x, 0.25, 0.5], [0.0, 7.0, 0.0, 1.5]];
    let four = view.camera_frames(&q);
    for i in 0..LANES {
        let one = view.camera_frame([q[0][i], q[1][i], q[2][i]]);
        for a in 0..3 {
            assert_eq!(four[a][i].to_bits(), one[a].to_bits());
        }
    }
}

#[test]
fn pixels_four_at_a_time_are_one_at_a_time() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let mut masks = Vec::new();
    let parts = ring(&mut rng, 3, &mut masks);
    for (&(camera, r, t), mask) in parts.iter().zip(&masks) {
        let view = HullView { r, t, camera, mask };
        let points: Vec<[f64; 3]> = (0..1003)
            .map(|_| std::array::from_fn(|_| rng.random_range(-6.0..6.0)))
            .collect();
        let (mut uv, mut seen) = (vec![[0.0; 2]; points.len()], vec![false; points.len()]);
        hull_pixels(&points, &view, &mut uv, &mut seen);
        for (i, &p) in points.iter().enumerate() {
            let x = view.camera_frame(p);
            let want = camera.pixel(x);
            assert_eq!(
                [uv[i][0].to_bits(), uv[i][1].to_bits()],
                [want[0].to_bits(), want[1].to_bits()]
            );
            let all_held = vec![true; mask.len()];
            assert_eq!(seen[i], camera.held(x, &all_held).1);
        }
        assert!(seen.iter().any(|&s| s) && seen.iter().any(|&s| !s));
    }
}
