//! Joint-position residuals against central differences of the forward kinematics, and the
//! model's input checks. (The field's derivatives are checked from Python, with hypothesis.)

use nalgebra::Vector3;

use super::field::Field;
use super::observe::{Observations, Residual};
use super::skeleton::{Metaball, PartSpec, Skeleton};
use crate::Error;

const I: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// A three-part arm: a root part, a 3-axis shoulder off to the side, a 1-axis elbow.
fn arm() -> Skeleton {
    let parts = vec![
        PartSpec {
            parent: None,
            offset: [0.0; 3],
            rest: I,
            axes: vec![],
        },
        PartSpec {
            parent: Some(0),
            offset: [0.2, 0.05, 0.4],
            rest: [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]],
            axes: vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.6, 0.8]],
        },
        PartSpec {
            parent: Some(1),
            offset: [0.01, -0.02, 0.3],
            rest: I,
            axes: vec![[1.0, 0.0, 0.0]],
        },
    ];
    // Two balls per part, the second thinner: the taper has something to scale.
    let balls = (0..3)
        .flat_map(|part| {
            [
                Metaball {
                    part,
                    centre: [0.01, -0.015, 0.1],
                    radii: [0.08, 0.07, 0.15],
                },
                Metaball {
                    part,
                    centre: [0.0, 0.01, 0.22],
                    radii: [0.06, 0.05, 0.1],
                },
            ]
        })
        .collect();
    Skeleton::new(parts, balls).unwrap()
}

#[test]
fn joint_residual_rows_match_central_differences() {
    let skeleton = arm();
    let shape = [
        1.1, 0.9, 1.15, 1.2, 0.95, 1.05, 0.85, 0.7, 1.2, 0.8, 0.9, 1.1,
    ];
    let motion = [0.1, -0.2, 0.9, 0.3, -0.2, 0.4, 0.5, -0.3, 0.7, -1.1];
    let obs = Observations {
        frames: 1,
        joints: vec![[0.0; 3]; 3],
        joint_part: vec![0, 1, 2],
        joint_frame: vec![0; 3],
        sigma: [1.0, 1.0, 1.0],
        ..Default::default()
    };
    let width = skeleton.n_motion + skeleton.n_shape();
    let field = Field::new(&skeleton, skeleton.pose(&shape, &motion).unwrap());
    let h = 1e-6;
    for part in 0..3 {
        for axis in 0..3 {
            let mut row = vec![0.0; width];
            Residual::Joint(part, axis).evaluate(&obs, &field, None, None, Some(&mut row));
            for k in 0..width {
                let at = |sign: f64| {
                    let (mut s, mut m) = (shape.to_vec(), motion.to_vec());
                    if k < m.len() {
                        m[k] += sign * h;
                    } else {
                        s[k - m.len()] += sign * h;
                    }
                    skeleton.pose(&s, &m).unwrap().origin[part][axis]
                };
                let numeric = (at(1.0) - at(-1.0)) / (2.0 * h);
                assert!(
                    (row[k] - numeric).abs() <= 1e-8,
                    "part {part} axis {axis} column {k}: {} vs {numeric}",
                    row[k]
                );
            }
        }
    }
}

#[test]
fn zero_angles_give_the_rest_frames() {
    let skeleton = arm();
    let pose = skeleton.pose(&[1.0; 12], &[0.0; 10]).unwrap();
    let expected = Vector3::new(0.2, 0.05, 0.4) + pose.rotation[1] * Vector3::new(0.01, -0.02, 0.3);
    assert!((pose.origin[2] - expected).norm() < 1e-15);
    assert!((pose.rotation[1][(0, 2)] - 1.0).abs() < 1e-15);
}

#[test]
fn bad_models_and_states_are_errors_not_panics() {
    let mut parts = arm().parts;
    parts[1].parent = Some(2);
    let balls = arm().balls;
    assert!(matches!(
        Skeleton::new(parts, balls.clone()),
        Err(Error::BadModel { .. })
    ));
    let mut parts = arm().parts;
    parts[2].axes[0] = [0.0; 3];
    assert!(matches!(
        Skeleton::new(parts, balls.clone()),
        Err(Error::BadModel { .. })
    ));
    let mut parts = arm().parts;
    parts[0].rest = [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    assert!(matches!(
        Skeleton::new(parts, balls),
        Err(Error::BadModel { .. })
    ));
    let skeleton = arm();
    assert!(matches!(
        skeleton.pose(&[1.0; 11], &[0.0; 10]),
        Err(Error::WrongLength { .. })
    ));
    assert!(matches!(
        skeleton.pose(&[1.0; 12], &[f64::NAN; 10]),
        Err(Error::NonFinite { .. })
    ));
    assert!(matches!(
        skeleton.pose(&[0.0; 12], &[0.0; 10]),
        Err(Error::BadModel { .. })
    ));
    // A zero depth alone is refused too.
    assert!(matches!(
        skeleton.pose(
            &[1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0],
            &[0.0; 10]
        ),
        Err(Error::BadModel { .. })
    ));
    // A taper that would turn a ball's section inside out (weight -0.5: t = 1 - (τ - 1) / 2).
    assert!(matches!(
        skeleton.pose(
            &[1.0, 1.0, 1.0, 3.5, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
            &[0.0; 10]
        ),
        Err(Error::BadModel { .. })
    ));
}

/// Length, width and depth scale the part frame's z, x and y apart: the child's joint
/// (the parent's offset) and the balls' centres and radii move on that axis only.
#[test]
fn length_width_and_depth_scale_one_axis_each() {
    let skeleton = arm();
    let motion = [0.0; 10];
    let unit = skeleton.pose(&[1.0; 12], &motion).unwrap();
    let local = |pose: &super::skeleton::Pose| {
        pose.rotation[1].transpose() * (pose.origin[2] - pose.origin[1])
    };
    for (c, axis) in [(0usize, 2usize), (1, 0), (2, 1)] {
        let mut shape = [1.0; 12];
        shape[4 + c] = 1.5;
        let pose = skeleton.pose(&shape, &motion).unwrap();
        let (a, b) = (local(&unit), local(&pose));
        for k in 0..3 {
            let expected = if k == axis { 1.5 * a[k] } else { a[k] };
            assert!((b[k] - expected).abs() < 1e-14, "coefficient {c}, axis {k}");
        }
        let field = Field::new(&skeleton, pose);
        let ball = field.balls.iter().find(|b| b.part == 1).unwrap();
        let scale = ball.scale;
        for k in 0..3 {
            assert_eq!(scale[k], if k == axis { 1.5 } else { 1.0 });
        }
    }
}

/// The normal blocks of the fit (accumulated per pair of parts through `E_b`) equal
/// `J^T J` and `J^T r` of the dense Jacobian rows, with and without the shape, over two
/// frames with points, rays and joints.
#[test]
fn normal_blocks_match_dense_rows() {
    use crate::body::fit::{problem, FitOptions};
    use crate::lm::{ArrowNormal, ArrowProblem, LmOptions};

    let skeleton = arm();
    let shape = [
        1.1, 0.9, 1.15, 1.2, 0.95, 1.05, 0.85, 0.7, 1.2, 0.8, 0.9, 1.1,
    ];
    let motions = [
        [0.1, -0.2, 0.9, 0.3, -0.2, 0.4, 0.5, -0.3, 0.7, -1.1],
        [0.0, 0.1, 1.0, -0.2, 0.1, 0.2, -0.4, 0.6, 0.1, -0.5],
    ];
    let mut obs = Observations {
        frames: 2,
        sigma: [0.05, 0.07, 0.01],
        log_epsilon: Some(0.01),
        ..Default::default()
    };
    for (f, motion) in motions.iter().enumerate() {
        let pose = skeleton.pose(&shape, motion).unwrap();
        for i in 0..60 {
            let b = i % 3;
            let t = i as f64 * 0.37;
            let local = Vector3::new(0.06 * t.cos(), 0.05 * t.sin(), 0.02 + 0.004 * i as f64);
            obs.points
                .push((pose.origin[b] + pose.rotation[b] * local).into());
            obs.point_frame.push(f);
            let target = pose.origin[b] + pose.rotation[b] * (0.9 * local);
            let origin = Vector3::new(2.0, 0.3 * t.sin(), 1.0);
            obs.origins.push(origin.into());
            obs.directions.push((target - origin).into());
            obs.ray_frame.push(f);
        }
        obs.joints.push([0.2, 0.1, 1.3]);
        obs.joint_part.push(2);
        obs.joint_frame.push(f);
    }
    let (lower, upper) = (vec![-10.0; 10], vec![10.0; 10]);
    for fit_shape in [true, false] {
        let options = FitOptions {
            lm: LmOptions::default(),
            fit_shape,
            outlier_distance: None,
        };
        let body = problem(&skeleton, &obs, &shape, (&lower, &upper), &options)
            .unwrap()
            .with_hessian_share(0.0);
        let (frames, m, s) = body.dims();
        let mut x: Vec<f64> = motions.concat();
        if fit_shape {
            x.extend_from_slice(&shape);
        }
        let mut normal = ArrowNormal::new(frames, m, s);
        let cost = body.linearize(&x, &mut normal).unwrap();

        let n = frames * m + s;
        let mut jtj = vec![0.0; n * n];
        let mut jtr = vec![0.0; n];
        let mut expected_cost = 0.0;
        let width = skeleton.n_motion + skeleton.n_shape();
        let mut residuals: Vec<(usize, Residual)> = Vec::new();
        residuals.extend((0..obs.points.len()).map(|i| (obs.point_frame[i], Residual::Point(i))));
        residuals.extend((0..obs.origins.len()).map(|i| (obs.ray_frame[i], Residual::Ray(i))));
        for (i, &f) in obs.joint_frame.iter().enumerate() {
            residuals.extend((0..3).map(|k| (f, Residual::Joint(i, k))));
        }
        for (f, residual) in &residuals {
            let field = Field::new(&skeleton, skeleton.pose(&shape, &motions[*f]).unwrap());
            let mut row = vec![0.0; width];
            let r = residual.evaluate(&obs, &field, None, None, Some(&mut row));
            expected_cost += 0.5 * r * r;
            // Global columns: this frame's motion block, then the shape.
            let global: Vec<(usize, f64)> = (0..m)
                .map(|k| (f * m + k, row[k]))
                .chain((0..s).map(|k| (frames * m + k, row[m + k])))
                .collect();
            for &(i, vi) in &global {
                jtr[i] += vi * r;
                for &(j, vj) in &global {
                    jtj[i * n + j] += vi * vj;
                }
            }
        }
        let close = |got: f64, want: f64, what: &str| {
            let scale = 1e-10 * (1.0 + want.abs());
            assert!((got - want).abs() <= scale, "{what}: {got} vs {want}");
        };
        close(cost, expected_cost, "cost");
        for f in 0..frames {
            for i in 0..m {
                close(normal.g[f * m + i], jtr[f * m + i], "g motion");
                for j in 0..m {
                    let want = jtj[(f * m + i) * n + f * m + j];
                    close(normal.a[f * m * m + i * m + j], want, "A");
                }
                for j in 0..s {
                    let want = jtj[(f * m + i) * n + frames * m + j];
                    close(normal.b[f * m * s + i * s + j], want, "B");
                }
            }
        }
        // The default leaves weak parts out of J^T J only: the gradient is the same.
        let body = problem(&skeleton, &obs, &shape, (&lower, &upper), &options).unwrap();
        let mut pruned = ArrowNormal::new(frames, m, s);
        close(
            body.linearize(&x, &mut pruned).unwrap(),
            expected_cost,
            "cost",
        );
        for (got, want) in pruned.g.iter().zip(&jtr) {
            close(*got, *want, "g with the default share");
        }
        for i in 0..s {
            close(normal.g[frames * m + i], jtr[frames * m + i], "g shape");
            for j in 0..s {
                let want = jtj[(frames * m + i) * n + frames * m + j];
                close(normal.c[i * s + j], want, "C");
            }
        }
    }
}

#[test]
fn one_sided_rays_add_only_when_violated() {
    let skeleton = arm();
    let shape = [1.0; 12];
    let motion = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3, -0.2, 0.1, -0.4];
    let field = Field::new(&skeleton, skeleton.pose(&shape, &motion).unwrap());
    // One ray through the root ball off its centre (it meets the skin), one far beside it.
    let origins = vec![[0.03, -2.0, 0.13], [1.5, -2.0, 0.1]];
    let directions = vec![[0.0, 1.0, 0.0]; 2];
    let width = skeleton.n_motion + skeleton.n_shape();
    let residual = |side: i8, i: usize| {
        let obs = Observations {
            frames: 1,
            origins: origins.clone(),
            directions: directions.clone(),
            ray_frame: vec![0; 2],
            ray_side: vec![side; 2],
            sigma: [1.0, 1.0, 1.0],
            log_epsilon: Some(0.01),
            ..Default::default()
        };
        let mut row = vec![1.0; width];
        let r = Residual::Ray(i).evaluate(&obs, &field, None, None, Some(&mut row));
        (r, row.iter().any(|v| *v != 0.0))
    };
    let (through, _) = residual(0, 0);
    let (beside, _) = residual(0, 1);
    assert!(through > 0.0 && beside < 0.0);
    // inside: the ray that meets the skin is satisfied, the one that misses is pulled
    assert_eq!(residual(1, 0), (0.0, false));
    assert_eq!(residual(1, 1).0, beside);
    // outside: the reverse
    assert_eq!(residual(-1, 1), (0.0, false));
    assert_eq!(residual(-1, 0).0, through);
    assert!(residual(-1, 0).1);
}

#[test]
fn the_shape_prior_adds_its_weight_to_the_shape_block_and_cost() {
    use super::fit::{problem, FitOptions};
    use crate::lm::{ArrowNormal, ArrowProblem, LmOptions};
    let skeleton = arm();
    let shape = [
        1.1, 0.9, 1.15, 1.2, 0.95, 1.05, 0.85, 0.7, 1.2, 0.8, 0.9, 1.1,
    ];
    let motion = [0.1, -0.2, 0.9, 0.3, -0.2, 0.4, 0.5, -0.3, 0.7, -1.1];
    let pose = skeleton.pose(&shape, &motion).unwrap();
    let mut obs = Observations {
        frames: 1,
        sigma: [0.05, 0.07, 0.01],
        log_epsilon: Some(0.01),
        // the lengths of parts 1 and 2 tied: that unknown carries two coefficients' priors
        shape_group: vec![0, 1, 2, 3, 4, 5, 6, 7, 4, 8, 9, 10],
        ..Default::default()
    };
    for i in 0..40 {
        let b = i % 3;
        let t = i as f64 * 0.41;
        let local = Vector3::new(0.05 * t.cos(), 0.05 * t.sin(), 0.03 + 0.004 * i as f64);
        obs.points
            .push((pose.origin[b] + pose.rotation[b] * local).into());
        obs.point_frame.push(0);
    }
    let (lower, upper) = (vec![-10.0; 10], vec![10.0; 10]);
    let options = FitOptions {
        lm: LmOptions::default(),
        fit_shape: true,
        outlier_distance: None,
    };
    let sigma = 0.05;
    let with_prior = Observations {
        shape_sigma: Some(sigma),
        ..obs.clone()
    };
    let plain = problem(&skeleton, &obs, &shape, (&lower, &upper), &options).unwrap();
    let prior = problem(&skeleton, &with_prior, &shape, (&lower, &upper), &options).unwrap();
    let (frames, m, s) = plain.dims();
    assert_eq!(s, 11);
    let mut x: Vec<f64> = motion.to_vec();
    x.extend_from_slice(&obs.group_shape(&shape));
    let (mut a, mut b) = (
        ArrowNormal::new(frames, m, s),
        ArrowNormal::new(frames, m, s),
    );
    let cost_plain = plain.linearize(&x, &mut a).unwrap();
    let cost_prior = prior.linearize(&x, &mut b).unwrap();
    let members = |g: usize| obs.shape_group.iter().filter(|&&h| h == g).count() as f64;
    let expected: f64 = (0..s)
        .map(|g| 0.5 * members(g) / (sigma * sigma) * (x[m + g] - 1.0).powi(2))
        .sum();
    let close = |got: f64, want: f64, what: &str| {
        assert!(
            (got - want).abs() <= 1e-9 * (1.0 + want.abs()),
            "{what}: {got} vs {want}"
        );
    };
    close(cost_prior - cost_plain, expected, "linearize cost");
    close(
        prior.cost(&x).unwrap() - plain.cost(&x).unwrap(),
        expected,
        "cost",
    );
    for g in 0..s {
        let w = members(g) / (sigma * sigma);
        close(b.g[m + g] - a.g[m + g], w * (x[m + g] - 1.0), "gradient");
        for l in 0..s {
            let want = if g == l { w } else { 0.0 };
            close(b.c[g * s + l] - a.c[g * s + l], want, "shape block");
        }
    }
    assert_eq!(a.a, b.a);
    assert_eq!(a.b, b.b);
    // a prior on a non-positive or infinite sigma is refused, not a silent NaN
    for bad in [0.0, -1.0, f64::INFINITY] {
        let obs = Observations {
            shape_sigma: Some(bad),
            ..obs.clone()
        };
        assert!(problem(&skeleton, &obs, &shape, (&lower, &upper), &options).is_err());
    }
}
