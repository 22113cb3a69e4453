//! Tests of [`crate::elastic`]: rigid invariance, consistency of energy, forces, the
//! right-hand side, the matrix-free product and the assembled blocks.

use super::*;
use crate::efg::Plane;
use crate::error::Error;
use crate::linalg::{mat_mul, mat_vec};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const MATERIAL: Material = Material {
    youngs: 3.0,
    poisson: 0.3,
    plane: Plane::Stress,
};

fn jittered<const D: usize>(side: usize, seed: u64) -> Vec<[f64; D]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..side.pow(D as u32))
        .map(|mut c| {
            std::array::from_fn(|_| {
                let v = (c % side) as f64 + rng.random_range(-0.3..0.3);
                c /= side;
                v
            })
        })
        .collect()
}

fn model<const D: usize>(side: usize, rotation: Rotation, fit: RotationFit) -> ElasticModel<D> {
    let rest = jittered::<D>(side, 3);
    let n = rest.len();
    ElasticModel::new(rest, 12, vec![1.0; n], &MATERIAL, rotation, fit).unwrap()
}

fn rotation3(angle: [f64; 3]) -> Block<3> {
    let [a, b, c] = angle;
    let rx = [
        [1.0, 0.0, 0.0],
        [0.0, a.cos(), -a.sin()],
        [0.0, a.sin(), a.cos()],
    ];
    let ry = [
        [b.cos(), 0.0, b.sin()],
        [0.0, 1.0, 0.0],
        [-b.sin(), 0.0, b.cos()],
    ];
    let rz = [
        [c.cos(), -c.sin(), 0.0],
        [c.sin(), c.cos(), 0.0],
        [0.0, 0.0, 1.0],
    ];
    mat_mul(&rz, &mat_mul(&ry, &rx))
}

fn rotation2(angle: f64) -> Block<2> {
    [[angle.cos(), -angle.sin()], [angle.sin(), angle.cos()]]
}

fn moved<const D: usize>(rest: &[[f64; D]], r: &Block<D>, t: [f64; D]) -> Vec<[f64; D]> {
    rest.iter()
        .map(|x| {
            let y = mat_vec(r, x);
            std::array::from_fn(|a| y[a] + t[a])
        })
        .collect()
}

fn largest<const D: usize>(v: &[[f64; D]]) -> f64 {
    v.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()))
}

fn rigid_case<const D: usize>(m: &ElasticModel<D>, r: Block<D>) {
    let t = std::array::from_fn(|a| 0.5 + a as f64);
    let x = moved(m.rest(), &r, t);
    let rotations = m.rotations(&x).unwrap();
    for q in &rotations {
        for a in 0..D {
            for b in 0..D {
                assert!(
                    (q[a][b] - r[a][b]).abs() < 1e-10,
                    "R_p = {q:?}, expected {r:?}"
                );
            }
        }
    }
    let energy = m.energy(&x, &rotations).unwrap();
    assert!(energy.abs() < 1e-18 * m.len() as f64, "energy {energy}");
    let forces = m.forces(&x, &rotations).unwrap();
    let scale = largest(&m.rhs(&rotations).unwrap());
    assert!(
        largest(&forces) < 1e-12 * scale,
        "force {}",
        largest(&forces)
    );
}

#[test]
fn rigid_motions_have_no_energy_and_no_force() {
    for (rotation, fit) in [Rotation::Rhs, Rotation::Warped]
        .into_iter()
        .flat_map(|r| [(r, RotationFit::Weighted), (r, RotationFit::Gradient)])
    {
        let m3 = model::<3>(5, rotation, fit);
        rigid_case(&m3, rotation3([0.7, -1.9, 2.6]));
        rigid_case(&m3, rotation3([0.0, std::f64::consts::FRAC_PI_2, 0.0]));
        let m2 = model::<2>(9, rotation, fit);
        rigid_case(&m2, rotation2(2.2));
    }
}

#[test]
fn linear_mode_reads_rotation_as_strain() {
    let m = model::<3>(5, Rotation::Linear, RotationFit::Gradient);
    let x = moved(m.rest(), &rotation3([0.0, 0.0, 1.0]), [0.0; 3]);
    let rotations = m.rotations(&x).unwrap();
    assert!(m.energy(&x, &rotations).unwrap() > 1.0);
}

fn perturbed<const D: usize>(rest: &[[f64; D]], seed: u64) -> Vec<[f64; D]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let r = rotation2(0.8);
    rest.iter()
        .map(|x| {
            let y: [f64; D] = if D == 2 {
                let v = mat_vec(&r, &[x[0], x[1]]);
                std::array::from_fn(|a| v[a])
            } else {
                *x
            };
            std::array::from_fn(|a| y[a] * 1.05 + rng.random_range(-0.1..0.1))
        })
        .collect()
}

fn consistency<const D: usize>(m: &ElasticModel<D>) {
    let x = perturbed(m.rest(), 5);
    let rotations = m.rotations(&x).unwrap();
    // forces = f - S x, matrix-free and assembled.
    let forces = m.forces(&x, &rotations).unwrap();
    let rhs = m.rhs(&rotations).unwrap();
    let sx = m.apply(&rotations, &x).unwrap();
    let scale = largest(&rhs);
    for i in 0..m.len() {
        for a in 0..D {
            assert!((forces[i][a] - (rhs[i][a] - sx[i][a])).abs() < 1e-10 * scale);
        }
    }
    let pattern = m.pattern();
    let mut blocks = vec![[[0.0; D]; D]; pattern.nnz()];
    m.system_blocks(&rotations, &mut blocks).unwrap();
    for (i, expected) in sx.iter().enumerate() {
        let mut y = [0.0; D];
        for at in pattern.indptr[i]..pattern.indptr[i + 1] {
            let v = mat_vec(&blocks[at], &x[pattern.indices[at] as usize]);
            for a in 0..D {
                y[a] += v[a];
            }
        }
        for a in 0..D {
            assert!((y[a] - expected[a]).abs() < 1e-10 * scale, "row {i}");
        }
    }
    // forces = -dE/dx with rotations fixed (central differences).
    let step = 1e-6;
    for &(i, a) in &[(0usize, 0usize), (m.len() / 2, D - 1), (m.len() - 1, 1)] {
        let mut plus = x.clone();
        plus[i][a] += step;
        let mut minus = x.clone();
        minus[i][a] -= step;
        let numeric = -(m.energy(&plus, &rotations).unwrap()
            - m.energy(&minus, &rotations).unwrap())
            / (2.0 * step);
        assert!(
            (numeric - forces[i][a]).abs() < 1e-6 * scale.max(1.0),
            "node {i} axis {a}: {numeric} vs {}",
            forces[i][a]
        );
    }
}

#[test]
fn energy_forces_rhs_and_system_agree() {
    for rotation in [Rotation::Linear, Rotation::Rhs, Rotation::Warped] {
        for fit in [RotationFit::Weighted, RotationFit::Gradient] {
            consistency(&model::<3>(5, rotation, fit));
            consistency(&model::<2>(8, rotation, fit));
        }
    }
}

#[test]
fn bad_input_is_an_error() {
    let rest = jittered::<3>(4, 1);
    let n = rest.len();
    let build = |k, volumes: Vec<f64>| {
        ElasticModel::new(
            rest.clone(),
            k,
            volumes,
            &MATERIAL,
            Rotation::Rhs,
            RotationFit::Gradient,
        )
    };
    assert!(matches!(
        build(n + 1, vec![1.0; n]),
        Err(Error::InvalidK { .. })
    ));
    assert!(matches!(
        build(3, vec![1.0; n]),
        Err(Error::InvalidK { .. })
    ));
    assert!(matches!(
        build(10, vec![1.0; n - 1]),
        Err(Error::LengthMismatch { .. })
    ));
    let mut volumes = vec![1.0; n];
    volumes[3] = -1.0;
    assert!(matches!(
        build(10, volumes),
        Err(Error::InvalidVolume { node: 3, .. })
    ));
    let m = build(10, vec![1.0; n]).unwrap();
    let mut x = rest.clone();
    x[5][1] = f64::NAN;
    assert!(matches!(
        m.rotations(&x),
        Err(Error::NonFinite { row: 5, .. })
    ));
    assert!(matches!(
        m.rotations(&rest[1..]),
        Err(Error::LengthMismatch { .. })
    ));
}

#[test]
fn matrix_free_product_and_diagonal_match_the_assembled_matrix() {
    for rotation in [Rotation::Rhs, Rotation::Warped] {
        let m = model::<3>(5, rotation, RotationFit::Gradient);
        let x = perturbed(m.rest(), 9);
        let rotations = m.rotations(&x).unwrap();
        let pattern = m.pattern();
        let mut blocks = vec![[[0.0; 3]; 3]; pattern.nnz()];
        m.system_blocks(&rotations, &mut blocks).unwrap();
        let diagonal = m.diagonal_blocks(&rotations).unwrap();
        for (i, d) in diagonal.iter().enumerate() {
            let at = (pattern.indptr[i]..pattern.indptr[i + 1])
                .find(|&at| pattern.indices[at] as usize == i)
                .unwrap();
            for r in 0..3 {
                for c in 0..3 {
                    assert!(
                        (d[r][c] - blocks[at][r][c]).abs() < 1e-12 * (1.0 + blocks[at][r][c].abs())
                    );
                }
            }
        }
        let (mut scratch, mut slots) = (Vec::new(), Vec::new());
        let mut out = vec![[0.0; 3]; m.len()];
        m.apply_into(&rotations, &x, &mut scratch, &mut slots, &mut out);
        let expected = m.apply(&rotations, &x).unwrap();
        assert_eq!(out, expected);
    }
}

fn stabilised<const D: usize>(side: usize, rotation: Rotation) -> ElasticModel<D> {
    model::<D>(side, rotation, RotationFit::Gradient)
        .with_stabilization(0.7)
        .unwrap()
}

#[test]
fn consistency_penalty_keeps_rigid_invariance_and_agrees_with_itself() {
    for rotation in [Rotation::Linear, Rotation::Rhs, Rotation::Warped] {
        // Energy, forces (against finite differences), right-hand side, matrix-free product
        // and assembled blocks all carry the penalty consistently.
        consistency(&stabilised::<3>(5, rotation));
        consistency(&stabilised::<2>(8, rotation));
    }
    for rotation in [Rotation::Rhs, Rotation::Warped] {
        rigid_case(&stabilised::<3>(5, rotation), rotation3([0.7, -1.9, 2.6]));
        rigid_case(&stabilised::<2>(9, rotation), rotation2(2.2));
    }
    // The penalty alone vanishes on any affine field, a shear included.
    let m = stabilised::<3>(5, Rotation::Linear);
    let plain = model::<3>(5, Rotation::Linear, RotationFit::Gradient);
    let shear = [[1.1, 0.3, 0.0], [0.0, 0.9, 0.2], [0.1, 0.0, 1.0]];
    let x = moved(m.rest(), &shear, [0.2, 0.0, -0.4]);
    let rotations = m.rotations(&x).unwrap();
    let (with, without) = (
        m.energy(&x, &rotations).unwrap(),
        plain.energy(&x, &rotations).unwrap(),
    );
    assert!(
        (with - without).abs() < 1e-10 * without,
        "{with} vs {without}"
    );
    // ... and costs energy on a field that oscillates from node to node.
    let wiggle: Vec<[f64; 3]> = m
        .rest()
        .iter()
        .enumerate()
        .map(|(i, p)| [p[0] + 0.01 * (i % 2) as f64, p[1], p[2]])
        .collect();
    let rotations = m.rotations(&wiggle).unwrap();
    assert!(
        m.energy(&wiggle, &rotations).unwrap() > 1.3 * plain.energy(&wiggle, &rotations).unwrap()
    );
    assert!(matches!(
        plain.with_stabilization(-1.0),
        Err(Error::InvalidOption { .. })
    ));
}

#[test]
fn stabilised_matrix_free_product_and_diagonal_match_the_assembled_matrix() {
    for rotation in [Rotation::Rhs, Rotation::Warped] {
        let m = stabilised::<3>(5, rotation);
        let x = perturbed(m.rest(), 9);
        let rotations = m.rotations(&x).unwrap();
        let pattern = m.pattern();
        let mut blocks = vec![[[0.0; 3]; 3]; pattern.nnz()];
        m.system_blocks(&rotations, &mut blocks).unwrap();
        let diagonal = m.diagonal_blocks(&rotations).unwrap();
        for (i, d) in diagonal.iter().enumerate() {
            let at = (pattern.indptr[i]..pattern.indptr[i + 1])
                .find(|&at| pattern.indices[at] as usize == i)
                .unwrap();
            for r in 0..3 {
                for c in 0..3 {
                    assert!(
                        (d[r][c] - blocks[at][r][c]).abs() < 1e-12 * (1.0 + blocks[at][r][c].abs())
                    );
                }
            }
        }
        let (mut scratch, mut slots) = (Vec::new(), Vec::new());
        let mut out = vec![[0.0; 3]; m.len()];
        m.apply_into(&rotations, &x, &mut scratch, &mut slots, &mut out);
        assert_eq!(out, m.apply(&rotations, &x).unwrap());
    }
}
