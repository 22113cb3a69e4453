//! Tests of [`crate::efg`].

use super::*;
use crate::mls::shape_functions;
use crate::SpatialHash;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct Model<const D: usize> {
    points: Vec<[f64; D]>,
    neighbors: Vec<u32>,
    grad: Vec<[f64; D]>,
    volumes: Vec<f64>,
}

/// A jittered grid of `side^D` nodes of spacing 1, k neighbours, c = 1.1, volume 1 each.
fn jittered<const D: usize, const M: usize>(side: usize, k: usize) -> Model<D> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let points: Vec<[f64; D]> = (0..side.pow(D as u32))
        .map(|mut c| {
            std::array::from_fn(|_| {
                let v = (c % side) as f64 + rng.random_range(-0.3..0.3);
                c /= side;
                v
            })
        })
        .collect();
    let knn = SpatialHash::new(&points).unwrap().knn(None, k - 1).unwrap();
    let mut neighbors = Vec::new();
    let mut support = Vec::new();
    for p in 0..points.len() {
        neighbors.push(p as u32);
        neighbors.extend(
            knn.indices[p * (k - 1)..(p + 1) * (k - 1)]
                .iter()
                .map(|&i| i as u32),
        );
        support.push(1.1 * knn.distances[(p + 1) * (k - 1) - 1]);
    }
    let grad = shape_functions::<D, M>(&points, &neighbors, k, &support)
        .unwrap()
        .grad;
    let volumes = vec![1.0; points.len()];
    Model {
        points,
        neighbors,
        grad,
        volumes,
    }
}

const MATERIAL: Material = Material {
    youngs: 2.0,
    poisson: 0.3,
    plane: Plane::Strain,
};

fn multiply(k: &Csr, u: &[f64]) -> Vec<f64> {
    (0..k.size)
        .map(|r| {
            (k.indptr[r]..k.indptr[r + 1])
                .map(|e| k.data[e] * u[k.indices[e]])
                .sum()
        })
        .collect()
}

fn check<const D: usize, const M: usize>(side: usize) {
    let model = jittered::<D, M>(side, 20);
    let elastic =
        NodalElasticity::<D>::new(&model.neighbors, 20, &model.grad, &model.volumes, &MATERIAL)
            .unwrap();
    let k = elastic.stiffness();
    // Affine field u = A x + b: constant strain sym(A), forces agree with -K u.
    let a: [[f64; D]; D] =
        std::array::from_fn(|i| std::array::from_fn(|j| 0.1 * (1 + i + 2 * j) as f64));
    let u: Vec<[f64; D]> = model
        .points
        .iter()
        .map(|x| std::array::from_fn(|i| 0.5 + (0..D).map(|j| a[i][j] * x[j]).sum::<f64>()))
        .collect();
    let strains = elastic.strains(&u).unwrap();
    let expected: Vec<f64> = voigt_pairs(D)
        .iter()
        .map(|pairs| pairs.iter().map(|&(i, j)| a[i][j]).sum())
        .collect();
    for row in strains.chunks(voigt_size(D)) {
        for (got, want) in row.iter().zip(&expected) {
            assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        }
    }
    let flat: Vec<f64> = u.iter().flatten().copied().collect();
    let ku = multiply(&k, &flat);
    let forces = elastic.forces(&u).unwrap();
    let scale = ku.iter().map(|v| v.abs()).fold(0.0, f64::max);
    for (f, g) in forces.iter().flatten().zip(&ku) {
        assert!((f + g).abs() <= 1e-12 * scale.max(1.0));
    }
    let energy = 0.5 * flat.iter().zip(&ku).map(|(x, y)| x * y).sum::<f64>();
    assert!((elastic.energy(&u).unwrap() - energy).abs() <= 1e-10 * energy.abs());
    // The CSR equals the dense scatter of the local stiffnesses.
    let size = D * model.points.len();
    let mut dense = vec![0.0; size * size];
    for p in 0..model.points.len() {
        let local = elastic.local_stiffness(p);
        let hood = &model.neighbors[p * 20..(p + 1) * 20];
        let dof = |l: usize| hood[l / D] as usize * D + l % D;
        for i in 0..D * 20 {
            for j in 0..D * 20 {
                dense[dof(i) * size + dof(j)] += local[i * D * 20 + j];
            }
        }
    }
    let kmax = k.data.iter().map(|v| v.abs()).fold(0.0, f64::max);
    for r in 0..size {
        for e in k.indptr[r]..k.indptr[r + 1] {
            assert!((k.data[e] - dense[r * size + k.indices[e]]).abs() <= 1e-13 * kmax);
            dense[r * size + k.indices[e]] = 0.0;
        }
    }
    assert!(
        dense.iter().all(|v| v.abs() <= 1e-13 * kmax),
        "entries outside the pattern"
    );
    // Symmetry, relative to the largest entry.
    let find = |r: usize, c: usize| {
        (k.indptr[r]..k.indptr[r + 1])
            .find(|&e| k.indices[e] == c)
            .map_or(0.0, |e| k.data[e])
    };
    for r in 0..k.size {
        for e in k.indptr[r]..k.indptr[r + 1] {
            assert!((k.data[e] - find(k.indices[e], r)).abs() <= 1e-12 * kmax);
        }
    }
}

#[test]
fn efg_patch_forces_energy_and_symmetry_3d() {
    check::<3, 4>(4);
}

#[test]
fn efg_patch_forces_energy_and_symmetry_2d() {
    check::<2, 3>(7);
}

#[test]
fn efg_rejects_bad_input() {
    let model = jittered::<2, 3>(4, 6);
    let new = |material: &Material, volumes: &[f64], neighbors: &[u32]| {
        NodalElasticity::<2>::new(neighbors, 6, &model.grad, volumes, material).map(|_| ())
    };
    let bad_nu = Material {
        poisson: 0.5,
        ..MATERIAL
    };
    assert!(matches!(
        new(&bad_nu, &model.volumes, &model.neighbors),
        Err(Error::InvalidMaterial {
            argument: "poisson",
            ..
        })
    ));
    let mut volumes = model.volumes.clone();
    volumes[3] = f64::NAN;
    assert!(matches!(
        new(&MATERIAL, &volumes, &model.neighbors),
        Err(Error::InvalidVolume { node: 3, .. })
    ));
    let mut neighbors = model.neighbors.clone();
    neighbors[7] = 99;
    assert!(matches!(
        new(&MATERIAL, &model.volumes, &neighbors),
        Err(Error::NeighborIndex {
            row: 1,
            column: 1,
            ..
        })
    ));
}
