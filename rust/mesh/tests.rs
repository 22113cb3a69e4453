//! Exactness against brute force, signs on closed meshes, rays, and input errors.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::TriangleMesh;
use crate::Error;

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn axpy(a: [f64; 3], s: f64, d: [f64; 3]) -> [f64; 3] {
    [a[0] + s * d[0], a[1] + s * d[1], a[2] + s * d[2]]
}

/// Distance from p to segment ab.
fn segment_distance(p: [f64; 3], a: [f64; 3], b: [f64; 3]) -> f64 {
    let ab = sub(b, a);
    let len2 = dot(ab, ab);
    let t = if len2 > 0.0 {
        (dot(sub(p, a), ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let d = sub(p, axpy(a, t, ab));
    dot(d, d).sqrt()
}

/// Brute force: the plane distance when p projects inside the triangle, else the nearest edge.
fn triangle_distance(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    let (ab, ac) = (sub(b, a), sub(c, a));
    let n = [
        ab[1] * ac[2] - ab[2] * ac[1],
        ab[2] * ac[0] - ab[0] * ac[2],
        ab[0] * ac[1] - ab[1] * ac[0],
    ];
    let edges = segment_distance(p, a, b)
        .min(segment_distance(p, b, c))
        .min(segment_distance(p, c, a));
    let nn = dot(n, n);
    if nn == 0.0 {
        return edges;
    }
    let ap = sub(p, a);
    let h = dot(ap, n) / nn;
    let q = sub(ap, [h * n[0], h * n[1], h * n[2]]);
    // Barycentric coordinates of the projection q (relative to a).
    let (d00, d01, d11) = (dot(ab, ab), dot(ab, ac), dot(ac, ac));
    let (d20, d21) = (dot(q, ab), dot(q, ac));
    let den = d00 * d11 - d01 * d01;
    let v = (d11 * d20 - d01 * d21) / den;
    let w = (d00 * d21 - d01 * d20) / den;
    if v >= 0.0 && w >= 0.0 && v + w <= 1.0 {
        (h.abs() * nn.sqrt()).min(edges)
    } else {
        edges
    }
}

fn cube() -> (Vec<[f64; 3]>, Vec<[i64; 3]>) {
    let v = (0..8)
        .map(|i| [(i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64])
        .collect();
    // Outward, counter-clockwise seen from outside.
    let t = vec![
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5],
    ];
    (v, t)
}

#[test]
fn distances_equal_brute_force_on_a_soup_of_thin_triangles() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    for t in 0..300 {
        let a: [f64; 3] = [rng.random(), rng.random(), rng.random()];
        // Every third triangle long and thin (a sliver), the others of uneven sizes.
        let scale = if t % 3 == 0 {
            1.0
        } else {
            10f64.powf(-3.0 * rng.random::<f64>())
        };
        let b = axpy(
            a,
            scale,
            [
                rng.random::<f64>() - 0.5,
                rng.random::<f64>() - 0.5,
                rng.random::<f64>() - 0.5,
            ],
        );
        let c = if t % 3 == 0 {
            axpy(axpy(a, 0.3, sub(b, a)), 1e-6, [1.0, 0.0, 0.0])
        } else {
            axpy(
                a,
                scale,
                [
                    rng.random::<f64>() - 0.5,
                    rng.random::<f64>() - 0.5,
                    rng.random::<f64>() - 0.5,
                ],
            )
        };
        let base = vertices.len() as i64;
        vertices.extend([a, b, c]);
        triangles.push([base, base + 1, base + 2]);
    }
    let mesh = TriangleMesh::new(&vertices, &triangles).unwrap();
    let queries: Vec<[f64; 3]> = (0..500)
        .map(|_| {
            [
                3.0 * rng.random::<f64>() - 1.0,
                3.0 * rng.random::<f64>() - 1.0,
                3.0 * rng.random::<f64>() - 1.0,
            ]
        })
        .collect();
    let found = mesh.closest_points(&queries, false).unwrap();
    let tolerance = 1e-12 * mesh.diagonal();
    for (i, p) in queries.iter().enumerate() {
        let brute = triangles
            .iter()
            .map(|t| {
                triangle_distance(
                    *p,
                    vertices[t[0] as usize],
                    vertices[t[1] as usize],
                    vertices[t[2] as usize],
                )
            })
            .fold(f64::INFINITY, f64::min);
        assert!(
            (found.distances[i] - brute).abs() <= tolerance,
            "query {i}: {} vs {brute}",
            found.distances[i]
        );
        let t = triangles[found.triangles[i] as usize];
        let own = triangle_distance(
            *p,
            vertices[t[0] as usize],
            vertices[t[1] as usize],
            vertices[t[2] as usize],
        );
        assert!(
            (own - brute).abs() <= tolerance,
            "query {i}: the reported triangle is not a closest one"
        );
        let d = sub(*p, found.points[i]);
        assert!((dot(d, d).sqrt() - brute).abs() <= tolerance);
    }
}

#[test]
fn signed_distances_and_containment_of_a_cube() {
    let (v, t) = cube();
    let mesh = TriangleMesh::new(&v, &t).unwrap();
    assert!((mesh.volume() - 1.0).abs() < 1e-15);
    assert!(mesh.is_closed());
    assert!((mesh.area() - 6.0).abs() < 1e-14);
    let open = TriangleMesh::new(&v, &t[1..]).unwrap();
    assert!(!open.is_closed());
    let mut flipped = t.clone();
    flipped[0].swap(1, 2);
    assert!(!TriangleMesh::new(&v, &flipped).unwrap().is_closed());
    let queries = [
        [0.5, 0.5, 0.5],
        [0.1, 0.5, 0.5],
        [1.5, 0.5, 0.5],
        [2.0, 2.0, 2.0],
        [0.0, 0.0, 0.0],
        [-1.0, -1.0, 0.5],
    ];
    let d = mesh.signed_distances(&queries).unwrap();
    let expected = [-0.5, -0.1, 0.5, 3f64.sqrt(), 0.0, 2f64.sqrt()];
    for (got, want) in d.iter().zip(expected) {
        assert!((got - want).abs() < 1e-14, "{got} vs {want}");
    }
    assert_eq!(
        mesh.contains(&queries).unwrap(),
        vec![true, true, false, false, false, false]
    );
}

#[test]
fn rays_hit_the_first_face() {
    let (v, t) = cube();
    let mesh = TriangleMesh::new(&v, &t).unwrap();
    let origins = [
        [0.3, 0.4, -2.0],
        [0.3, 0.4, 0.5],
        [5.0, 5.0, 5.0],
        [0.3, 0.4, -2.0],
    ];
    let directions = [
        [0.0, 0.0, 2.0],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let hits = mesh.cast_rays(&origins, &directions, 10.0).unwrap();
    assert!((hits.distances[0] - 1.0).abs() < 1e-15); // half-length steps of a direction of length 2
    assert!((hits.distances[1] - 0.5).abs() < 1e-15); // from inside, onto the top
    assert_eq!((hits.distances[2], hits.triangles[2]), (f64::INFINITY, -1));
    assert!(
        hits.triangles[0] == 0 || hits.triangles[0] == 1,
        "bottom face, got {}",
        hits.triangles[0]
    );
    assert!(
        hits.triangles[1] == 2 || hits.triangles[1] == 3,
        "top face, got {}",
        hits.triangles[1]
    );
    let short = mesh
        .cast_rays(&origins[3..], &directions[3..], 1.5)
        .unwrap();
    assert_eq!(short.triangles[0], -1);
}

#[test]
fn degenerate_triangles_are_their_segments_and_points() {
    let vertices = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 0.0, 0.0],
        [5.0, 5.0, 5.0],
    ];
    let triangles = [[0, 1, 2], [3, 3, 3]];
    let mesh = TriangleMesh::new(&vertices, &triangles).unwrap();
    let queries = [[1.5, 1.0, 0.0], [-1.0, 0.0, 0.0], [5.0, 5.0, 6.0]];
    let found = mesh.closest_points(&queries, false).unwrap();
    for (got, want) in found.distances.iter().zip([1.0, 1.0, 1.0]) {
        assert!((got - want).abs() < 1e-14, "{got} vs {want}");
    }
    assert_eq!(found.triangles, vec![0, 0, 1]);
}

#[test]
fn bad_input_is_an_error() {
    let (v, t) = cube();
    assert!(matches!(
        TriangleMesh::new(&[], &t),
        Err(Error::Empty {
            argument: "vertices",
            ..
        })
    ));
    assert!(matches!(
        TriangleMesh::new(&v, &[]),
        Err(Error::Empty {
            argument: "triangles",
            ..
        })
    ));
    assert!(matches!(
        TriangleMesh::new(&v, &[[0, 1, 8]]),
        Err(Error::IndexOutOfRange {
            argument: "triangles",
            row: 0,
            value: 8,
            bound: 8
        })
    ));
    assert!(matches!(
        TriangleMesh::new(&v, &[[0, -1, 2]]),
        Err(Error::IndexOutOfRange { .. })
    ));
    let mut nan = v.clone();
    nan[3][1] = f64::NAN;
    assert!(matches!(
        TriangleMesh::new(&nan, &t),
        Err(Error::NonFinite {
            argument: "vertices",
            row: 3
        })
    ));
    let mesh = TriangleMesh::new(&v, &t).unwrap();
    assert!(matches!(
        mesh.signed_distances(&[[f64::INFINITY, 0.0, 0.0]]),
        Err(Error::NonFinite { .. })
    ));
    assert!(matches!(
        mesh.cast_rays(&[[0.0; 3]], &[[0.0; 3]], 1.0),
        Err(Error::BadRay { row: 0 })
    ));
    assert!(matches!(
        mesh.cast_rays(&[[0.0; 3]], &[], 1.0),
        Err(Error::LengthMismatch { .. })
    ));
    assert!(matches!(
        mesh.cast_rays(&[[0.0; 3]], &[[1.0, 0.0, 0.0]], f64::NAN),
        Err(Error::InvalidOption { .. })
    ));
    assert!(mesh.closest_points(&[], true).unwrap().points.is_empty());
}

#[test]
fn distances_past_the_band_are_clamped_with_exact_signs() {
    let (v, t) = cube();
    let mesh = TriangleMesh::new(&v, &t).unwrap();
    let queries = [
        [0.5, 0.5, 0.5],
        [0.45, 0.5, 0.9],
        [1.1, 0.5, 0.5],
        [3.0, -2.0, 0.5],
        [0.3, 0.3, 0.3],
    ];
    let mut d = vec![0.0; queries.len()];
    mesh.distances_into(&queries, true, 0.2, &mut d).unwrap();
    let expected = [-0.2, -0.1, 0.1, 0.2, -0.2];
    for (got, want) in d.iter().zip(expected) {
        assert!((got - want).abs() < 1e-14, "{got} vs {want}");
    }
    mesh.distances_into(&queries, false, 0.2, &mut d).unwrap();
    assert!(d
        .iter()
        .zip(expected)
        .all(|(got, want)| (got - want.abs()).abs() < 1e-14));
    assert!(matches!(
        mesh.distances_into(&queries, true, -1.0, &mut d),
        Err(Error::InvalidOption { .. })
    ));
}
