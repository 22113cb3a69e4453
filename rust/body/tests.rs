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
    let balls = (0..3)
        .map(|part| Metaball {
            part,
            centre: [0.0, 0.0, 0.1],
            radii: [0.08, 0.07, 0.15],
        })
        .collect();
    Skeleton::new(parts, balls).unwrap()
}

#[test]
fn joint_residual_rows_match_central_differences() {
    let skeleton = arm();
    let shape = [1.1, 0.9, 0.95, 1.05, 1.2, 0.8];
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
    let pose = skeleton.pose(&[1.0; 6], &[0.0; 10]).unwrap();
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
        skeleton.pose(&[1.0; 5], &[0.0; 10]),
        Err(Error::WrongLength { .. })
    ));
    assert!(matches!(
        skeleton.pose(&[1.0; 6], &[f64::NAN; 10]),
        Err(Error::NonFinite { .. })
    ));
    assert!(matches!(
        skeleton.pose(&[0.0; 6], &[0.0; 10]),
        Err(Error::BadModel { .. })
    ));
}
