//! Recovery of known warps on procedural textures, statuses of bad patches, constraints.

use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A band-limited procedural texture: a sum of sinusoids with wavelengths of 8 to 30 px.
struct Texture {
    waves: Vec<([f64; 2], f64, f64)>,
}

impl Texture {
    fn new(rng: &mut ChaCha8Rng) -> Self {
        let waves = (0..12)
            .map(|_| {
                let angle = rng.random_range(0.0..std::f64::consts::TAU);
                let frequency = rng.random_range(0.2..0.8);
                (
                    [frequency * angle.cos(), frequency * angle.sin()],
                    rng.random_range(0.0..std::f64::consts::TAU),
                    rng.random_range(5.0..15.0),
                )
            })
            .collect();
        Self { waves }
    }

    fn at(&self, u: f64, v: f64) -> f64 {
        128.0
            + self
                .waves
                .iter()
                .map(|(w, phase, amplitude)| amplitude * (w[0] * u + w[1] * v + phase).sin())
                .sum::<f64>()
    }
}

/// Template `f`, search `gain f(M^-1 (y - b) + p) + offset` with noise; the true map sends
/// template offsets `x` from `p` to `M x + b`.
struct Scene {
    template: Vec<f32>,
    search: Vec<f32>,
    width: usize,
    height: usize,
}

fn noise(rng: &mut ChaCha8Rng, sigma: f64) -> f64 {
    // Box-Muller.
    let (a, b): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random_range(0.0..1.0));
    sigma * (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
}

#[allow(clippy::too_many_arguments)]
fn scene(
    texture: &Texture,
    p: [f64; 2],
    m: [f64; 4],
    b: [f64; 2],
    gain: f64,
    offset: f64,
    sigma: f64,
    rng: &mut ChaCha8Rng,
) -> Scene {
    let (width, height) = (64, 64);
    let det = m[0] * m[3] - m[1] * m[2];
    let inv = [m[3] / det, -m[1] / det, -m[2] / det, m[0] / det];
    let mut template = vec![0.0; width * height];
    let mut search = vec![0.0; width * height];
    for r in 0..height {
        for c in 0..width {
            let (u, v) = (c as f64, r as f64);
            template[r * width + c] = (texture.at(u, v) + noise(rng, sigma)) as f32;
            let (du, dv) = (u - b[0], v - b[1]);
            let x = [
                inv[0] * du + inv[1] * dv + p[0],
                inv[2] * du + inv[3] * dv + p[1],
            ];
            search[r * width + c] =
                (gain * texture.at(x[0], x[1]) + offset + noise(rng, sigma)) as f32;
        }
    }
    Scene {
        template,
        search,
        width,
        height,
    }
}

struct Matched {
    status: Vec<u8>,
    affine: Vec<[f64; 6]>,
    radiometry: Vec<[f64; 2]>,
    sigma0: Vec<f64>,
    correlation: Vec<f64>,
    iterations: Vec<u32>,
    covariance: Vec<f64>,
}

fn run(
    template: &ImageView<'_>,
    points: &[[f64; 2]],
    searches: &[ImageView<'_>],
    starts: &[[f64; 6]],
    lines: Option<&[[f64; 3]]>,
    options: &MatchOptions,
) -> Result<Matched> {
    let pairs = points.len() * searches.len();
    let mut m = Matched {
        status: vec![0; pairs],
        affine: vec![[0.0; 6]; pairs],
        radiometry: vec![[0.0; 2]; pairs],
        sigma0: vec![0.0; pairs],
        correlation: vec![0.0; pairs],
        iterations: vec![0; pairs],
        covariance: vec![0.0; pairs * searches.len() * 64],
    };
    match_patches(
        template,
        points,
        searches,
        starts,
        lines,
        options,
        MatchOutput {
            status: &mut m.status,
            affine: &mut m.affine,
            radiometry: &mut m.radiometry,
            sigma0: &mut m.sigma0,
            correlation: &mut m.correlation,
            iterations: &mut m.iterations,
            covariance: &mut m.covariance,
        },
    )?;
    Ok(m)
}

fn rotation_scale(angle_deg: f64, scale: f64, shear: f64) -> [f64; 4] {
    let (s, c) = angle_deg.to_radians().sin_cos();
    // R * diag(scale) * [[1, shear], [0, 1]]
    [
        c * scale,
        c * scale * shear - s * scale,
        s * scale,
        s * scale * shear + c * scale,
    ]
}

#[test]
fn recovers_affine_warp_gain_and_offset_without_noise() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let texture = Texture::new(&mut rng);
    let p = [30.0, 31.0];
    let m = rotation_scale(12.0, 1.15, 0.15);
    let b = [33.3, 28.7];
    let sc = scene(&texture, p, m, b, 1.25, 15.0, 0.0, &mut rng);
    let template = ImageView {
        data: &sc.template,
        width: sc.width,
        height: sc.height,
    };
    let search = ImageView {
        data: &sc.search,
        width: sc.width,
        height: sc.height,
    };
    let options = MatchOptions {
        size: 15,
        ..Default::default()
    };
    let start = [1.0, 0.0, b[0] + 1.5, 0.0, 1.0, b[1] - 1.2];
    let out = run(&template, &[p], &[search], &[start], None, &options).unwrap();
    assert_eq!(out.status[0], Status::Converged as u8, "{:?}", out.affine);
    let a = out.affine[0];
    let err = (a[2] - b[0]).hypot(a[5] - b[1]);
    assert!(err < 0.02, "centre error {err}");
    for (got, want) in [a[0], a[1], a[3], a[4]].iter().zip(m) {
        assert!((got - want).abs() < 0.01, "affine {a:?} vs {m:?}");
    }
    let [gain, offset] = out.radiometry[0];
    // Bilinear resampling damps the search patch's contrast by about omega^2 / 12 at
    // angular frequency omega (rad/px): up to ~4% here, which the gain absorbs.
    assert!((gain / (1.0 / 1.25) - 1.0).abs() < 0.04, "gain {gain}");
    // The means still match: 128 = offset + gain (1.25 * 128 + 15).
    assert!(
        (offset + gain * (1.25 * 128.0 + 15.0) - 128.0).abs() < 0.5,
        "offset {offset}"
    );
    assert!(out.correlation[0] > 0.999);
    assert!(out.iterations[0] > 1 && out.iterations[0] < 30);
}

#[test]
fn without_the_sandwich_the_match_is_the_same_and_only_the_covariance_changes() {
    // The tracker's forward-backward check turns the sandwich off: the position, shape,
    // radiometry and correlation must not move, and the covariance becomes (G^T G)^-1
    // scaled by sigma0^2 (the template taken noise-free), which is smaller.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let texture = Texture::new(&mut rng);
    let (p, m, b) = ([30.0, 31.0], rotation_scale(5.0, 1.05, 0.0), [31.6, 30.2]);
    let sc = scene(&texture, p, m, b, 1.1, 5.0, 2.0, &mut rng);
    let view = |data| ImageView {
        data,
        width: sc.width,
        height: sc.height,
    };
    let start = [1.0, 0.0, b[0] + 0.8, 0.0, 1.0, b[1] - 0.6];
    let with = MatchOptions {
        size: 15,
        ..Default::default()
    };
    let without = MatchOptions {
        sandwich: false,
        ..with
    };
    let a = run(
        &view(&sc.template),
        &[p],
        &[view(&sc.search)],
        &[start],
        None,
        &with,
    )
    .unwrap();
    let c = run(
        &view(&sc.template),
        &[p],
        &[view(&sc.search)],
        &[start],
        None,
        &without,
    )
    .unwrap();
    assert_eq!(a.status, c.status);
    assert_eq!(a.status[0], Status::Converged as u8);
    assert_eq!(a.affine, c.affine);
    assert_eq!(a.radiometry, c.radiometry);
    assert_eq!(a.correlation, c.correlation);
    let (va, vc) = (a.covariance[0], c.covariance[0]);
    assert!(vc > 0.0 && vc.is_finite() && vc < va, "{vc} vs {va}");
}

#[test]
fn flat_and_outside_patches_report_their_status() {
    let width = 40;
    let flat = vec![100.0f32; width * width];
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let texture = Texture::new(&mut rng);
    let textured: Vec<f32> = (0..width * width)
        .map(|i| texture.at((i % width) as f64, (i / width) as f64) as f32)
        .collect();
    let view = |data| ImageView {
        data,
        width,
        height: width,
    };
    let options = MatchOptions {
        min_texture: 0.5,
        ..Default::default()
    };
    let identity = |u: f64, v: f64| [1.0, 0.0, u, 0.0, 1.0, v];
    // Flat template: too little texture.
    let out = run(
        &view(&flat),
        &[[20.0, 20.0]],
        &[view(&textured)],
        &[identity(20.0, 20.0)],
        None,
        &options,
    )
    .unwrap();
    assert_eq!(out.status[0], Status::LowTexture as u8);
    assert!(out.covariance.iter().all(|c| c.is_nan()));
    // Template patch over the border; search start over the border.
    let out = run(
        &view(&textured),
        &[[3.0, 20.0], [20.0, 20.0]],
        &[view(&textured)],
        &[identity(3.0, 20.0), identity(36.0, 20.0)],
        None,
        &options,
    )
    .unwrap();
    assert_eq!(out.status, vec![Status::LeftImage as u8; 2]);
    // A textured template against a flat search image: singular or runaway, never a panic.
    let out = run(
        &view(&textured),
        &[[20.0, 20.0]],
        &[view(&flat)],
        &[identity(20.0, 20.0)],
        None,
        &options,
    )
    .unwrap();
    assert_ne!(out.status[0], Status::Converged as u8);
}

#[test]
fn hard_line_keeps_the_centre_on_it() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let texture = Texture::new(&mut rng);
    let p = [32.0, 32.0];
    let m = rotation_scale(-8.0, 0.9, -0.1);
    let b = [31.4, 33.6];
    let sc = scene(&texture, p, m, b, 0.8, -10.0, 2.0, &mut rng);
    let template = ImageView {
        data: &sc.template,
        width: sc.width,
        height: sc.height,
    };
    let search = ImageView {
        data: &sc.search,
        width: sc.width,
        height: sc.height,
    };
    // A line through the true centre, slightly off horizontal.
    let normal: [f64; 2] = [0.1, 1.0];
    let line = [normal[0], normal[1], -(normal[0] * b[0] + normal[1] * b[1])];
    let start = [1.0, 0.0, b[0] - 1.5, 0.0, 1.0, b[1] + 1.0];
    for sigma in [0.0, 0.05] {
        let options = MatchOptions {
            size: 13,
            line_sigma: sigma,
            ..Default::default()
        };
        let out = run(
            &template,
            &[p],
            &[search],
            &[start],
            Some(&[line]),
            &options,
        )
        .unwrap();
        assert_eq!(out.status[0], Status::Converged as u8);
        let a = out.affine[0];
        let distance = (line[0] * a[2] + line[1] * a[5] + line[2]) / normal[0].hypot(normal[1]);
        if sigma == 0.0 {
            assert!(distance.abs() < 1e-9, "distance {distance}");
            // The covariance is singular across the line: var of the normal component ~ 0.
            let c = &out.covariance;
            let n = [
                normal[0] / normal[0].hypot(normal[1]),
                normal[1] / normal[0].hypot(normal[1]),
            ];
            let across = n[0] * n[0] * c[0] + 2.0 * n[0] * n[1] * c[1] + n[1] * n[1] * c[9];
            assert!(
                across.abs() < 1e-12 * (c[0] + c[9]),
                "variance across the line {across}"
            );
        } else {
            assert!(distance.abs() < 0.2, "distance {distance}");
        }
        assert!((a[2] - b[0]).hypot(a[5] - b[1]) < 0.1);
    }
}

#[test]
fn rejects_bad_arguments() {
    let data = vec![0.0f32; 100];
    let image = ImageView {
        data: &data,
        width: 10,
        height: 10,
    };
    let identity = [1.0, 0.0, 5.0, 0.0, 1.0, 5.0];
    let even = MatchOptions {
        size: 10,
        ..Default::default()
    };
    assert!(matches!(
        run(&image, &[[5.0, 5.0]], &[image], &[identity], None, &even),
        Err(Error::InvalidOption {
            argument: "size",
            ..
        })
    ));
    let options = MatchOptions::default();
    assert!(matches!(
        run(&image, &[[5.0, 5.0]], &[], &[], None, &options),
        Err(Error::Empty { .. })
    ));
    assert!(matches!(
        run(
            &image,
            &[[f64::NAN, 5.0]],
            &[image],
            &[identity],
            None,
            &options
        ),
        Err(Error::NonFinite {
            argument: "points",
            ..
        })
    ));
    let short = ImageView {
        data: &data[..50],
        width: 10,
        height: 10,
    };
    assert!(run(&image, &[[5.0, 5.0]], &[short], &[identity], None, &options).is_err());
    let flipped = [-1.0, 0.0, 5.0, 0.0, 1.0, 5.0];
    assert!(run(&image, &[[5.0, 5.0]], &[image], &[flipped], None, &options).is_err());
}

#[test]
fn bilinear_template_rows_equal_the_per_sample_bilinear() {
    // The unwarped template is blended row by row with one pair of weights; it must give
    // the per-sample bilinear values (to rounding) at any sub-pixel centre.
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let texture = Texture::new(&mut rng);
    let (w, h) = (48usize, 40usize);
    let data: Vec<f32> = (0..w * h)
        .map(|i| texture.at((i % w) as f64, (i / w) as f64) as f32)
        .collect();
    let image = ImageView {
        data: &data,
        width: w,
        height: h,
    };
    let mut patch = super::sample::TemplatePatch::default();
    for centre in [[20.3, 17.8], [9.01, 9.99], [37.5, 29.25]] {
        assert!(patch.sample(&image, centre, 15, Interpolation::Bilinear));
        let base = [centre[0].floor(), centre[1].floor()];
        for r in 0..15 {
            for c in 0..15 {
                let offset = [
                    (centre[0] - base[0]) as f32 + (c as f32 - 7.0),
                    (centre[1] - base[1]) as f32 + (r as f32 - 7.0),
                ];
                let want = super::resample::bilinear(&image, base, offset);
                let got = patch.value[r * 15 + c];
                assert!(
                    (got - want).abs() < 1e-3,
                    "{centre:?} ({r}, {c}): {got} vs {want}"
                );
            }
        }
    }
}

#[test]
fn template_weights_leave_out_a_moving_background() {
    // The template patch's right quarter is background that stays while the surface moves
    // by b (an unrelated texture at the same place in both images). Weighted by the mask
    // of the surface the match recovers the surface's shift and correlates as an interior
    // patch does; weights of all ones give the unweighted match exactly. (How far the
    // unweighted match is pulled off is tested on larger backgrounds in
    // tests/test_lsm_weights.py.)
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let texture = Texture::new(&mut rng);
    let other = Texture::new(&mut rng);
    let (p, b) = ([30.0, 31.0], [31.4, 30.3]);
    let mut sc = scene(
        &texture,
        p,
        [1.0, 0.0, 0.0, 1.0],
        b,
        1.0,
        0.0,
        0.5,
        &mut rng,
    );
    let edge = 34usize;
    for r in 0..sc.height {
        for c in edge..sc.width {
            sc.template[r * sc.width + c] = other.at(c as f64, r as f64) as f32;
            if c as f64 >= edge as f64 + (b[0] - p[0]) {
                sc.search[r * sc.width + c] = other.at(c as f64, r as f64) as f32;
            }
        }
    }
    let mask: Vec<f32> = (0..sc.width * sc.height)
        .map(|i| if i % sc.width < edge { 1.0 } else { 0.0 })
        .collect();
    let ones = vec![1.0f32; sc.width * sc.height];
    let view = |data| ImageView {
        data,
        width: sc.width,
        height: sc.height,
    };
    let options = MatchOptions {
        size: 15,
        sandwich: false,
        ..Default::default()
    };
    let start = [1.0, 0.0, b[0] + 0.5, 0.0, 1.0, b[1] - 0.5];
    let matched = |weights: Option<&ImageView<'_>>| {
        let mut m = Matched {
            status: vec![0; 1],
            affine: vec![[0.0; 6]; 1],
            radiometry: vec![[0.0; 2]; 1],
            sigma0: vec![0.0; 1],
            correlation: vec![0.0; 1],
            iterations: vec![0; 1],
            covariance: vec![0.0; 64],
        };
        match_weighted_patches(
            &view(&sc.template),
            weights,
            &[p],
            &[view(&sc.search)],
            &[start],
            None,
            &options,
            MatchOutput {
                status: &mut m.status,
                affine: &mut m.affine,
                radiometry: &mut m.radiometry,
                sigma0: &mut m.sigma0,
                correlation: &mut m.correlation,
                iterations: &mut m.iterations,
                covariance: &mut m.covariance,
            },
        )
        .unwrap();
        m
    };
    let plain = matched(None);
    let unit = matched(Some(&view(&ones)));
    assert_eq!(plain.affine, unit.affine);
    assert_eq!(plain.covariance, unit.covariance);
    let weighted = matched(Some(&view(&mask)));
    assert_eq!(weighted.status[0], Status::Converged as u8);
    let a = weighted.affine[0];
    let err = (a[2] - b[0]).hypot(a[5] - b[1]);
    assert!(err < 0.05, "weighted centre error {err}");
    assert!(weighted.correlation[0] > 0.99);
}

#[cfg(target_arch = "x86_64")]
#[test]
fn gathered_bilinear_samples_equal_the_portable_loop_to_the_bit() {
    // The AVX2 gather path must reproduce the portable bilinear resampling exactly (the
    // tracker's results may not move with the CPU): random warps anywhere the 15x15 patch
    // fits, many at the image border where the clamps act, and centres on whole pixels.
    if !super::resample::wide() {
        return;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (w, h) = (53usize, 41usize);
    // Noise, not a smooth texture: any misplaced tap or weight changes the value.
    let data: Vec<f32> = (0..w * h).map(|_| rng.random_range(-50.0..250.0)).collect();
    let image = ImageView {
        data: &data,
        width: w,
        height: h,
    };
    let (size, half) = (15usize, 7.0f32);
    let n = size * size;
    let padded = n.div_ceil(8) * 8;
    let dx: Vec<f32> = (0..padded)
        .map(|i| if i < n { (i % size) as f32 - half } else { 0.0 })
        .collect();
    let dy: Vec<f32> = (0..padded)
        .map(|i| if i < n { (i / size) as f32 - half } else { 0.0 })
        .collect();
    let (mut want, mut got) = (vec![0.0f32; n], vec![0.0f32; n]);
    let mut checked = 0;
    for case in 0..4000 {
        let a = if case % 4 == 0 {
            [1.0, 0.0, 0.0, 1.0]
        } else {
            rotation_scale(
                rng.random_range(-40.0..40.0),
                rng.random_range(0.7..1.4),
                rng.random_range(-0.2..0.2),
            )
        };
        let mut b = [
            rng.random_range(0.0..w as f64),
            rng.random_range(0.0..h as f64),
        ];
        if case % 3 == 0 {
            b = [b[0].round(), b[1].round()];
        }
        let linear = [
            [a[0] * half as f64, a[1] * half as f64],
            [a[2] * half as f64, a[3] * half as f64],
        ];
        if !super::resample::inside(&image, b, linear, Interpolation::Bilinear) {
            continue;
        }
        super::resample::resample(&image, a, b, &dx, &dy, &mut want, Interpolation::Bilinear);
        // SAFETY: `wide` checked the CPU; the patch lies inside the image.
        unsafe { super::gather::bilinear_wide(&image, a, b, &dx, &dy, &mut got) };
        for i in 0..n {
            assert_eq!(
                got[i].to_bits(),
                want[i].to_bits(),
                "case {case}, a {a:?}, b {b:?}, pixel {i}: {} vs {}",
                got[i],
                want[i]
            );
        }
        checked += 1;
    }
    // The patch fits at the very border too: the identity at the corners.
    for b in [
        [7.0, 7.0],
        [(w - 8) as f64, (h - 8) as f64],
        [7.0, (h - 8) as f64],
    ] {
        let a = [1.0, 0.0, 0.0, 1.0];
        super::resample::resample(&image, a, b, &dx, &dy, &mut want, Interpolation::Bilinear);
        // SAFETY: as above.
        unsafe { super::gather::bilinear_wide(&image, a, b, &dx, &dy, &mut got) };
        assert!(got
            .iter()
            .zip(&want)
            .all(|(g, x)| g.to_bits() == x.to_bits()));
        checked += 1;
    }
    assert!(checked > 1000, "only {checked} warps fit");
}
