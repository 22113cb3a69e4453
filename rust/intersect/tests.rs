//! The intersection recovers constructed points, rejects a planted blunder, and its camera
//! derivatives and ray inversion agree with the model they differentiate and invert.

use super::*;

/// Camera `i` of `n` on an arc around the origin, looking at it, with skew and distortion.
fn arc_camera(i: usize, n: usize) -> Camera {
    let angle = -0.8 + 1.6 * i as f64 / (n - 1).max(1) as f64;
    let (s, c) = angle.sin_cos();
    // Rows: camera x, y, z axes in world; z points to the origin from (4 sin, 0.3, -4 cos).
    let r = [c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c];
    let center = [-4.0 * s, 0.3, -4.0 * c];
    let t: [f64; 3] = std::array::from_fn(|k| {
        -(r[3 * k] * center[0] + r[3 * k + 1] * center[1] + r[3 * k + 2] * center[2])
    });
    let k = [800.0, 1.5, 320.0, 0.0, 790.0, 240.0, 0.0, 0.0, 1.0];
    let dist = [
        -0.2, 0.05, 1e-3, -5e-4, 0.01, 0.02, 0.0, 0.0, 1e-3, 0.0, -1e-3, 0.0,
    ];
    Camera::new(k, dist, r, t, 640, 480).unwrap()
}

fn options() -> IntersectOptions {
    IntersectOptions {
        reject: true,
        critical: 4.0,
        iterations: 20,
        step_tolerance: 4e-12,
    }
}

#[test]
fn jacobian_matches_central_differences() {
    let cam = arc_camera(1, 4);
    let p = [0.13, -0.2, 0.31];
    let (_, jac) = cam.project_jacobian(&p);
    for j in 0..3 {
        let h = 1e-6;
        let (mut a, mut b) = (p, p);
        a[j] += h;
        b[j] -= h;
        let (ua, _) = cam.project_jacobian(&a);
        let (ub, _) = cam.project_jacobian(&b);
        for i in 0..2 {
            let fd = (ua[i] - ub[i]) / (2.0 * h);
            assert!(
                (fd - jac[i][j]).abs() <= 1e-5 * jac[i][j].abs().max(1.0),
                "{i} {j}: {fd} vs {}",
                jac[i][j]
            );
        }
    }
}

#[test]
fn ray_passes_through_the_projected_point() {
    let cam = arc_camera(0, 3);
    let p = [0.4, -0.35, 0.2];
    let (uv, _) = cam.project_jacobian(&p);
    let d = cam.ray_direction(uv);
    let c = cam.center();
    let v: [f64; 3] = std::array::from_fn(|i| p[i] - c[i]);
    let along = v[0] * d[0] + v[1] * d[1] + v[2] * d[2];
    let off: f64 = (0..3)
        .map(|i| (v[i] - along * d[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    assert!(off < 1e-12, "ray misses the point by {off}");
}

#[test]
fn recovers_points_and_rejects_a_blunder() {
    let cameras: Vec<Camera> = (0..5).map(|i| arc_camera(i, 5)).collect();
    let truth = [[0.1, 0.2, -0.1], [-0.3, 0.05, 0.25]];
    let mut obs = Vec::new();
    let mut cov = Vec::new();
    for p in &truth {
        for cam in &cameras {
            obs.push(cam.project_jacobian(p).0);
            cov.push([0.25, 0.05, 0.05, 0.3]);
        }
    }
    // A 12 px blunder in the second point's third view.
    obs[5 + 2][0] += 12.0;
    let out = intersect_views(&cameras, &obs, &cov, options());
    assert!(out[0].used.iter().all(|&u| u) && out[0].converged);
    for (p, t) in out.iter().zip(&truth) {
        for i in 0..3 {
            assert!((p.point[i] - t[i]).abs() < 1e-10, "{:?} vs {t:?}", p.point);
        }
        // The covariance is symmetric positive definite.
        let m = Matrix3::from_fn(|i, j| p.covariance[i][j]);
        assert_eq!(m, m.transpose());
        assert!(SymmetricEigen::new(m).eigenvalues.min() > 0.0);
    }
    assert_eq!(out[1].used, vec![true, true, false, true, true]);
    assert!(out[1].normalised[2] > 4.0);
}

#[test]
fn one_view_leaves_the_point_unsolved() {
    let cameras: Vec<Camera> = (0..3).map(|i| arc_camera(i, 3)).collect();
    let nan = [f64::NAN; 2];
    let obs = [cameras[0].project_jacobian(&[0.0, 0.1, 0.0]).0, nan, nan];
    let cov = [[1.0, 0.0, 0.0, 1.0]; 3];
    let out = intersect_views(&cameras, &obs, &cov, options());
    assert_eq!(out[0].used, vec![true, false, false]);
    assert!(out[0].normalised.iter().all(|w| w.is_nan()));
}

#[test]
fn a_batch_and_its_points_alone_agree() {
    // A batch of 150 points runs on the pool, each point alone on the calling thread
    // (SERIAL_POINTS): the same answers to the bit, noisy views and a planted blunder.
    let cameras: Vec<Camera> = (0..4).map(|i| arc_camera(i, 4)).collect();
    let mut obs = Vec::new();
    let mut cov = Vec::new();
    for n in 0..150 {
        let f = n as f64;
        let p = [
            0.3 * (f * 0.37).sin(),
            0.2 * (f * 0.11).cos(),
            0.25 * (f * 0.53).sin(),
        ];
        for (k, cam) in cameras.iter().enumerate() {
            let mut uv = cam.project_jacobian(&p).0;
            uv[0] += 0.3 * ((f + k as f64) * 1.7).sin();
            uv[1] += 0.3 * ((f - k as f64) * 2.3).cos();
            if n % 17 == 3 && k == 1 {
                uv[0] += 15.0;
            }
            obs.push(uv);
            cov.push([0.25, 0.02, 0.02, 0.3]);
        }
    }
    assert!(obs.len() / cameras.len() >= SERIAL_POINTS);
    let batch = intersect_views(&cameras, &obs, &cov, options());
    for (n, whole) in batch.iter().enumerate() {
        let one = &intersect_views(
            &cameras,
            &obs[4 * n..4 * n + 4],
            &cov[4 * n..4 * n + 4],
            options(),
        )[0];
        assert_eq!(whole.point.map(f64::to_bits), one.point.map(f64::to_bits));
        assert_eq!(whole.used, one.used);
        assert_eq!(
            format!("{:?}", whole.covariance),
            format!("{:?}", one.covariance)
        );
    }
}
