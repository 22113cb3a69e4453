//! Exact mesh queries through parry's BVH: build, and 100,000 closest points / signed
//! distances / ray casts against a closed 20,000-vertex mesh (a lumpy torus: a human
//! figure's size of mesh; benches/peers.py runs the same on the figure's skin).

use criterion::{criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::TAU;
use std::hint::black_box;

use _core::mesh::TriangleMesh;

/// A closed torus of `u * v` vertices, its tube radius varying by a factor of two.
fn lumpy_torus(u: usize, v: usize) -> (Vec<[f64; 3]>, Vec<[i64; 3]>) {
    let mut vertices = Vec::with_capacity(u * v);
    for i in 0..u {
        let a = TAU * i as f64 / u as f64;
        let tube = 0.25 + 0.08 * (3.0 * a).sin() + 0.04 * (7.0 * a).cos();
        for j in 0..v {
            let b = TAU * j as f64 / v as f64;
            let r = 1.0 + tube * b.cos();
            vertices.push([r * a.cos(), r * a.sin(), tube * b.sin()]);
        }
    }
    let at = |i: usize, j: usize| ((i % u) * v + j % v) as i64;
    let mut triangles = Vec::with_capacity(2 * u * v);
    for i in 0..u {
        for j in 0..v {
            triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    (vertices, triangles)
}

fn queries(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            [
                rng.random_range(-1.6..1.6),
                rng.random_range(-1.6..1.6),
                rng.random_range(-0.6..0.6),
            ]
        })
        .collect()
}

fn mesh_queries(c: &mut Criterion) {
    let (vertices, triangles) = lumpy_torus(200, 100);
    let points = queries(100_000, 1);
    let mut group = c.benchmark_group("mesh_20k_vertices");
    group.sample_size(10);
    group.bench_function("build", |b| {
        b.iter(|| TriangleMesh::new(black_box(&vertices), &triangles).unwrap())
    });
    let mesh = TriangleMesh::new(&vertices, &triangles).unwrap();
    group.bench_function("closest_points_100k", |b| {
        b.iter(|| mesh.closest_points(black_box(&points), false).unwrap())
    });
    group.bench_function("signed_distances_100k", |b| {
        b.iter(|| mesh.signed_distances(black_box(&points)).unwrap())
    });
    let directions = queries(100_000, 2);
    group.bench_function("cast_rays_100k", |b| {
        b.iter(|| {
            mesh.cast_rays(black_box(&points), &directions, f64::INFINITY)
                .unwrap()
        })
    });
    group.finish();
}

criterion_group!(benches, mesh_queries);
criterion_main!(benches);
