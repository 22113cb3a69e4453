//! Scratch probe (not committed): cold block-Jacobi PCG, min / median wall and CPU per solve.
use _core::efg::{Material, Plane};
use _core::elastic::{ElasticModel, Rotation, RotationFit};
use _core::solve::{BlockCsr, BlockJacobi, Pcg};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Instant;

fn cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap();
    let f: Vec<&str> = s.rsplit(')').next().unwrap().split_whitespace().collect();
    (f[11].parse::<f64>().unwrap() + f[12].parse::<f64>().unwrap()) / 100.0
}

const K: usize = 20;
const TOLERANCE: f64 = 1e-8;

/// The consistency penalty of `python/elastocap/elastic.py`'s default.
const STABILIZATION: f64 = 0.1;

/// Stiffness, surface nodes, their 3x3 blocks, right-hand side, node positions.
type System = (
    BlockCsr<3>,
    Vec<u32>,
    Vec<[[f64; 3]; 3]>,
    Vec<f64>,
    Vec<[f64; 3]>,
);

/// The fitting system of `n` nodes: the first `n` points of a jittered cubic grid (unit
/// spacing, unit volumes), its stiffness, and on the nodes of the grid's outer layer the
/// blocks `s (0.3 I + g g^T)` with `g` a random unit vector and `s` the mean diagonal of K,
/// shaped like the anisotropic surface metric (SPEC 5, step 2); plus a right-hand side.
pub fn fitting_system(n: usize, seed: u64) -> System {
    let side = (n as f64).cbrt().ceil() as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let cells: Vec<[usize; 3]> = (0..n)
        .map(|i| [i % side, (i / side) % side, i / (side * side)])
        .collect();
    let points: Vec<[f64; 3]> = cells
        .iter()
        .map(|c| std::array::from_fn(|a| c[a] as f64 + rng.random_range(-0.3..0.3)))
        .collect();
    let layers = n.div_ceil(side * side);
    let material = Material {
        youngs: 1.0,
        poisson: 0.3,
        plane: Plane::Strain,
    };
    let model = ElasticModel::<3>::new(
        points.clone(),
        K,
        vec![1.0; n],
        &material,
        Rotation::Rhs,
        RotationFit::Gradient,
    )
    .unwrap()
    .with_stabilization(STABILIZATION)
    .unwrap();
    let pattern = model.pattern();
    let rows: Vec<&[u32]> = pattern
        .indptr
        .windows(2)
        .map(|w| &pattern.indices[w[0]..w[1]])
        .collect();
    let mut matrix = BlockCsr::<3>::from_pattern(&rows).unwrap();
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    model
        .system_blocks(&vec![identity; n], matrix.blocks_mut())
        .unwrap();
    let scale = (0..n)
        .map(|i| (0..3).map(|a| matrix.diagonal_block(i)[a][a]).sum::<f64>())
        .sum::<f64>()
        / (3 * n) as f64;
    let surface: Vec<u32> = (0..n as u32)
        .filter(|&i| {
            let c = cells[i as usize];
            c.contains(&0) || c[0] == side - 1 || c[1] == side - 1 || c[2] + 1 >= layers
        })
        .collect();
    let blocks: Vec<[[f64; 3]; 3]> = surface
        .iter()
        .map(|_| {
            let g: [f64; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
            let norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
            std::array::from_fn(|a| {
                std::array::from_fn(|b| {
                    scale * (0.3 * f64::from(u8::from(a == b)) + g[a] * g[b] / (norm * norm))
                })
            })
        })
        .collect();
    let rhs: Vec<f64> = (0..3 * n).map(|_| rng.random_range(-1.0..1.0)).collect();
    (matrix, surface, blocks, rhs, points)
}

fn assemble(
    stiffness: &BlockCsr<3>,
    surface: &[u32],
    blocks: &[[[f64; 3]; 3]],
    beta: f64,
) -> BlockCsr<3> {
    let mut a = stiffness.zeros_like();
    stiffness.scale_into(1.0, &mut a).unwrap();
    a.add_diagonal_blocks(beta, surface, blocks).unwrap();
    a
}

fn main() {
    let (stiffness, surface, blocks, rhs, _points) = fitting_system(2465, 7);
    let a = assemble(&stiffness, &surface, &blocks, 1.0);
    let csr = a.to_csr();
    let size = a.size();
    let mut pcg = Pcg::new();
    let mut jacobi = BlockJacobi::new(&a).unwrap();
    let mut x = vec![0.0; size];
    let runs: usize = std::env::var("RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(200);
    let what = std::env::var("WHAT").unwrap_or("cold".into());
    let mut times = Vec::new();
    let mut iters = 0;
    let c0 = cpu();
    for _ in 0..runs {
        let t = Instant::now();
        match what.as_str() {
            "csr" => {
                x.fill(0.0);
                let s = pcg
                    .solve_csr_parts(
                        size,
                        &csr.indptr,
                        &csr.indices,
                        &csr.data,
                        &rhs,
                        &mut x,
                        TOLERANCE,
                        100 * size,
                    )
                    .unwrap();
                iters = s.iterations;
            }
            "csr0" => {
                x.fill(0.0);
                pcg.solve_csr_parts(
                    size,
                    &csr.indptr,
                    &csr.indices,
                    &csr.data,
                    &rhs,
                    &mut x,
                    TOLERANCE,
                    0,
                )
                .unwrap();
            }
            "it20" => {
                x.fill(0.0);
                let s = pcg.solve(&a, &mut jacobi, &rhs, &mut x, 0.0, 20).unwrap();
                iters = s.iterations;
            }
            _ => {
                x.fill(0.0);
                jacobi.update(&a).unwrap();
                let s = pcg
                    .solve(&a, &mut jacobi, &rhs, &mut x, TOLERANCE, 100 * size)
                    .unwrap();
                iters = s.iterations;
            }
        }
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let c = (cpu() - c0) * 1e3 / runs as f64;
    times.sort_by(|a, b| a.partial_cmp(b).unwrap());
    println!(
        "{what}: iters {iters} min {:.3} ms median {:.3} ms cpu/run {:.3} ms",
        times[0],
        times[runs / 2],
        c
    );
}
