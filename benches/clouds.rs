//! Point clouds shared by the criterion benches: seeded, so every run measures the same input.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` points uniform in the unit cube.
pub fn uniform(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| [rng.random(), rng.random(), rng.random()])
        .collect()
}

/// `n` points uniform on the unit sphere: a surface, as hull and model surfaces are.
pub fn sphere(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let z: f64 = rng.random_range(-1.0..1.0);
            let t: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let r = (1.0 - z * z).sqrt();
            [r * t.cos(), r * t.sin(), z]
        })
        .collect()
}

/// `n` points in 20 tight Gaussian clusters plus 5% uniform outliers in a box 100x larger.
pub fn clustered(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let centres: Vec<[f64; 3]> = (0..20)
        .map(|_| [rng.random(), rng.random(), rng.random()])
        .collect();
    (0..n)
        .map(|i| {
            if i % 20 == 0 {
                std::array::from_fn(|_| rng.random_range(-50.0..50.0))
            } else {
                let c = centres[i % centres.len()];
                std::array::from_fn(|a| c[a] + 1e-3 * (rng.random::<f64>() - 0.5))
            }
        })
        .collect()
}
