//! Tests of the fitting terms on shapes with known answers.

use super::contact::{find_contacts, hold_contacts};
use super::surface::{associate, invalidate_collisions, vertex_normals, MIN_ANISOTROPY};
use crate::grid_sample::GridField;

/// A sphere of radius `r` as an exact signed distance on a grid of spacing `h` over
/// [-2, 2]^3.
fn sphere_field(r: f64, h: f64) -> (Vec<f64>, [usize; 3], [f64; 3]) {
    let n = (4.0 / h) as usize + 1;
    let mut values = Vec::with_capacity(n * n * n);
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                let p = [i, j, k].map(|c| -2.0 + c as f64 * h);
                values.push((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - r);
            }
        }
    }
    (values, [n; 3], [-2.0; 3])
}

/// Points on a sphere (Fibonacci lattice).
fn sphere_points(count: usize, r: f64) -> Vec<[f64; 3]> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..count)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / count as f64;
            let rho = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            [r * rho * phi.cos(), r * rho * phi.sin(), r * z]
        })
        .collect()
}

#[test]
fn vertex_normals_of_a_tetrahedron_point_outwards() {
    let v = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let centre = [0.25; 3];
    for (p, n) in v.iter().zip(vertex_normals(&v, &faces)) {
        let out: f64 = (0..3).map(|a| (p[a] - centre[a]) * n[a]).sum();
        assert!(out > 0.0);
        assert!(((0..3).map(|a| n[a] * n[a]).sum::<f64>() - 1.0).abs() < 1e-12);
    }
}

#[test]
fn associations_pull_onto_the_target_across_more_than_along() {
    let (values, shape, origin) = sphere_field(1.0, 0.05);
    let field = GridField::new(&values, shape, origin, 0.05).unwrap();
    let points = sphere_points(200, 1.2);
    let normals: Vec<[f64; 3]> = points.iter().map(|p| p.map(|x| x / 1.2)).collect();
    let support = vec![0.4; points.len()];
    for (a, p) in associate(&field, &points, &normals, &support)
        .iter()
        .zip(&points)
    {
        let radius = a.target.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!((radius - 1.0).abs() < 2e-3, "target at radius {radius}");
        assert!((a.distance - 0.2).abs() < 2e-3);
        assert!((a.confidence - 1.0).abs() < 1e-3);
        // s = |d| / d_p = 0.5: across (radial) weight 1, along s^2 = 0.25.
        let u = p.map(|x| x / 1.2);
        let across: f64 = (0..3)
            .map(|r| (0..3).map(|c| u[r] * a.weight[r][c] * u[c]).sum::<f64>())
            .sum();
        let trace: f64 = (0..3).map(|r| a.weight[r][r]).sum();
        assert!((across - 1.0).abs() < 1e-2);
        assert!((trace - across - 2.0 * 0.25).abs() < 1e-2);
    }
    // A node facing away from the target's gradient has no confidence, and very close to
    // the surface the anisotropy bottoms out at MIN_ANISOTROPY.
    let inward = vec![[0.0, 0.0, -1.0]];
    let a = associate(&field, &[[0.0, 0.0, 1.0005]], &inward, &[1.0])[0];
    assert_eq!(a.confidence, 0.0);
    let a = associate(&field, &[[0.0, 0.0, 1.0005]], &[[0.0, 0.0, 1.0]], &[1.0])[0];
    let tangential = a.weight[0][0];
    // (The trilinear gradient's direction is off by ~1.5 degrees on a grid line here.)
    assert!(
        (tangential - MIN_ANISOTROPY * MIN_ANISOTROPY).abs() < 1e-3,
        "{tangential}"
    );
}

#[test]
fn colliding_associations_of_distant_parts_are_dropped() {
    let (values, shape, origin) = sphere_field(1.0, 0.05);
    let field = GridField::new(&values, shape, origin, 0.05).unwrap();
    // Two nodes far apart at rest, now both just outside the same spot of the target; a
    // third, near the first at rest, stays.
    let points = [[0.0, 0.0, 1.1], [0.0, 0.001, 1.1], [0.0, 0.3, 1.1]];
    let rest = [[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 0.3, 0.0]];
    let normals = [[0.0, 0.0, 1.0]; 3];
    let support = [0.5; 3];
    let mut found = associate(&field, &points, &normals, &support);
    assert_eq!(invalidate_collisions(&mut found, &rest, &support), 2);
    assert_eq!(found[0].confidence, 0.0);
    assert_eq!(found[1].confidence, 0.0);
    assert!(found[2].confidence > 0.9);
}

/// Two parallel 5 x 5 sheets of surface nodes 0.1 apart, far apart at rest, facing each
/// other (normals +z below, -z above): `(positions, normals, rest)`.
#[allow(clippy::type_complexity)]
fn facing_sheets() -> (Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    let mut rest = Vec::new();
    for (z, nz, rest_z) in [(0.0, 1.0, 0.0), (0.1, -1.0, 10.0)] {
        for i in 0..5 {
            for j in 0..5 {
                positions.push([0.1 * i as f64, 0.1 * j as f64, z]);
                normals.push([0.0, 0.0, nz]);
                rest.push([0.1 * i as f64, 0.1 * j as f64, rest_z]);
            }
        }
    }
    (positions, normals, rest)
}

#[test]
fn a_node_pushed_through_another_part_is_a_contact() {
    // Two parallel sheets of surface nodes, far apart at rest, facing each other (normals
    // +z below, -z above); one node of the lower sheet has passed above the upper sheet.
    let (mut positions, normals, rest) = facing_sheets();
    positions[12][2] = 0.15; // the lower sheet's centre node, now 0.05 inside the upper part
    let support = vec![0.25; positions.len()];
    let contacts = find_contacts(&positions, &normals, &rest, &support);
    // The spike is inside the upper part, and the upper sheet's nodes around it are inside
    // the lower part as its tangent plane at the spike sees it: every one is pushed apart,
    // the spike down onto the upper sheet, the upper nodes up onto the spike's plane.
    let spike = contacts
        .iter()
        .find(|c| c.node == 12)
        .expect("the spike penetrates");
    assert!((spike.depth - 0.05).abs() < 1e-12);
    assert!((spike.target[2] - 0.1).abs() < 1e-12);
    for c in &contacts {
        if c.node != 12 {
            assert!(
                c.node >= 25,
                "only upper-sheet nodes are near the spike: {c:?}"
            );
            assert!((c.target[2] - 0.15).abs() < 1e-12);
        }
        // Pushed along z (e = normalise(n_p - n_q) = +-z): full weight along z, s_I^2 across.
        assert!((c.weight[2][2] - 1.0).abs() < 1e-12);
        assert!((c.weight[0][0] - 0.01).abs() < 1e-12);
    }
    assert!(contacts.len() > 1 && contacts.len() <= 9);
}

#[test]
fn a_contact_pushed_out_is_held_while_near_its_partner() {
    // Two facing sheets as above; the lower centre node was a contact of the upper sheet's
    // centre node and has been pushed out (0.02 below the upper sheet), so a fresh search
    // no longer reports it; held, it is kept where it is (target = its position, depth 0).
    let (mut positions, normals, rest) = facing_sheets();
    let support = vec![0.25; positions.len()];
    positions[12][2] = 0.15;
    let before = find_contacts(&positions, &normals, &rest, &support);
    positions[12][2] = 0.08;
    let mut now = find_contacts(&positions, &normals, &rest, &support);
    assert!(now.iter().all(|c| c.node != 12), "no longer penetrating");
    hold_contacts(&mut now, &before, &positions, &normals, &support);
    let held = now.iter().find(|c| c.node == 12).expect("held");
    assert!(held.partner >= 25, "its partner is on the upper sheet");
    assert_eq!(held.depth, 0.0);
    assert_eq!(held.target, positions[12]);
    // Out of its partner's support, it is released.
    positions[12][2] = -0.5;
    let mut far = find_contacts(&positions, &normals, &rest, &support);
    hold_contacts(&mut far, &before, &positions, &normals, &support);
    assert!(far.iter().all(|c| c.node != 12));
}

/// A disc of radius 1 (a jittered grid inside, a ring of surface nodes on the rim) and
/// the signed distance of an ellipse with semi-axes 1.2 and 0.85 on a grid one voxel thick.
fn disc_and_ellipse() -> (
    crate::elastic::ElasticModel<2>,
    Vec<u32>,
    Vec<[u32; 2]>,
    Vec<f64>,
) {
    use crate::efg::{Material, Plane};
    use crate::elastic::{ElasticModel, Rotation, RotationFit};
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut nodes = Vec::new();
    for i in -9..=9 {
        for j in -9..=9 {
            let p = [
                i as f64 * 0.1 + rng.random_range(-0.02..0.02),
                j as f64 * 0.1 + rng.random_range(-0.02..0.02),
            ];
            if p[0].hypot(p[1]) < 0.93 {
                nodes.push(p);
            }
        }
    }
    let first = nodes.len() as u32;
    let ring = 60;
    for t in 0..ring {
        let a = std::f64::consts::TAU * t as f64 / ring as f64;
        nodes.push([a.cos(), a.sin()]);
    }
    let surface: Vec<u32> = (first..first + ring).collect();
    let faces = (0..ring)
        .map(|t| [first + t, first + (t + 1) % ring])
        .collect();
    let volumes = vec![std::f64::consts::PI / nodes.len() as f64; nodes.len()];
    let material = Material {
        youngs: 1.0,
        poisson: 0.3,
        plane: Plane::Stress,
    };
    let model = ElasticModel::new(
        nodes,
        12,
        volumes,
        &material,
        Rotation::Warped,
        RotationFit::Gradient,
    )
    .unwrap()
    .with_stabilization(0.1)
    .unwrap();
    let n = 161;
    let mut values = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (-2.0 + 0.025 * i as f64, -2.0 + 0.025 * j as f64);
            // Distance-like: exact on the axes, a smooth level set with |grad| ~ 1 near it.
            let r = ((x / 1.2).powi(2) + (y / 0.85).powi(2)).sqrt();
            values.push((r - 1.0) * (1.2f64 * 0.85).sqrt());
        }
    }
    (model, surface, faces, values)
}

#[test]
fn planar_fit_matrix_free_agrees_with_the_assembled_system() {
    use super::{fit_frame, FitOptions, FitWorkspace};
    let (model, surface, faces, values) = disc_and_ellipse();
    let field = GridField::new(&values, [161, 161, 1], [-2.0, -2.0, 0.0], 0.025).unwrap();
    let mut fitted = Vec::new();
    for matrix_free in [false, true] {
        let mut workspace = FitWorkspace::new(&model, &surface, &faces).unwrap();
        let options = FitOptions {
            matrix_free,
            solver_tolerance: 1e-10,
            max_iterations: 3,
            ..FitOptions::default()
        };
        let (x, metrics) =
            fit_frame(&model, &mut workspace, &field, model.rest(), &options).unwrap();
        assert!(metrics.solver_converged);
        fitted.push((x, metrics));
    }
    let (assembled, free) = (&fitted[0], &fitted[1]);
    assert_eq!(assembled.1.iterations, free.1.iterations);
    let gap = assembled
        .0
        .iter()
        .zip(&free.0)
        .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
        .fold(0.0, f64::max);
    assert!(gap < 1e-6, "matrix-free and assembled fits differ by {gap}");
    // The rim (radius 1 at rest) moved towards the ellipse: wider along x, narrower along y.
    let rim = |x: &[[f64; 2]], a: usize| {
        surface
            .iter()
            .map(|&i| x[i as usize][a].abs())
            .fold(0.0, f64::max)
    };
    let (wide, tall) = (rim(&free.0, 0), rim(&free.0, 1));
    assert!(
        wide > 1.02 && tall < 0.98,
        "rim {wide} x {tall}, metrics {:?}",
        free.1
    );
}

/// A preconditioner that has lost definiteness: it returns nothing, so PCG's first
/// direction has zero curvature.
struct Broken;

impl crate::solve::Preconditioner<3> for Broken {
    fn apply(&mut self, _r: &[[f64; 3]], z: &mut [[f64; 3]]) {
        z.iter_mut().for_each(|v| *v = [0.0; 3]);
    }
}

#[test]
fn a_solve_whose_preconditioner_breaks_is_redone_with_block_jacobi() {
    use crate::efg::Csr;
    use crate::solve::{BlockCsr, BlockJacobi, Pcg, RankOne};
    // A tridiagonal SPD matrix of 4 blocks (12 scalars), diagonally dominant.
    let n: usize = 12;
    let (mut indptr, mut indices, mut data) = (vec![0], Vec::new(), Vec::new());
    for r in 0..n {
        for c in r.saturating_sub(1)..(r + 2).min(n) {
            indices.push(c);
            data.push(if c == r { 4.0 } else { -1.0 });
        }
        indptr.push(indices.len());
    }
    let system = BlockCsr::<3>::from_csr(&Csr {
        size: n,
        indptr,
        indices,
        data,
    })
    .unwrap();
    let rhs: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).sin()).collect();
    // A rank-one term (the volume term's) rides along with both solves.
    let g: Vec<f64> = (0..n).map(|i| 1.0 + i as f64).collect();
    let term = RankOne {
        vector: &g,
        weight: 0.3,
    };

    let mut pcg = Pcg::new();
    let mut x = vec![0.5; n];
    let status = super::solve::solve_or_jacobi(
        &mut pcg,
        &system,
        &mut Broken,
        &rhs,
        &mut x,
        Some(term),
        1e-10,
        100,
    )
    .unwrap();
    assert!(status.converged, "{status:?}");

    let mut jacobi = BlockJacobi::new(&system).unwrap();
    let mut expected = vec![0.5; n];
    pcg.solve_plus_rank_one(&system, &mut jacobi, term, &rhs, &mut expected, 1e-10, 100)
        .unwrap();
    assert_eq!(x, expected);

    // Without the fallback the broken preconditioner is an error.
    let mut z = vec![0.5; n];
    assert!(matches!(
        pcg.solve(&system, &mut Broken, &rhs, &mut z, 1e-10, 100),
        Err(crate::Error::NotPositiveDefinite { .. })
    ));
}
