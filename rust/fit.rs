//! Fitting the elastic model through a sequence of target shapes (SPEC 5; the paper's
//! section 4). Per iteration: the rotations, the anisotropic surface-distance term with
//! confidence weights and invalidated associations ([`surface`]), the self-intersection
//! term ([`contact`]), and one sparse solve of
//! $(\alpha S + \beta W + \gamma I)\,x = \alpha f + \beta W t + \gamma I x'$
//! (block-Jacobi PCG warm-started from the current positions, [`crate::solve`]).
//!
//! Scales: $\beta = 1$ per surface node; $\alpha = $ `stiffness` $/ (\mu \bar h)$ with
//! $\bar h$ the mean node spacing, so that `stiffness = 1` makes a node's elastic diagonal
//! about as strong as a fully confident data term, whatever the units and material;
//! $\gamma = $ `contact` (SPEC 5: $\gamma = \beta$).

pub mod contact;
pub mod surface;

use crate::efg::Block;
use crate::elastic::{ElasticModel, Rotation};
use crate::error::{Error, Result};
use crate::grid_sample::Field;
use crate::solve::{BlockCsr, BlockJacobi, LinearOperator, Pcg, TwoLevel, STRENGTH};

/// $\alpha S u + E u$ with $E$ block-diagonal, matrix-free.
struct FitOperator<'a, const D: usize> {
    model: &'a ElasticModel<D>,
    rotations: &'a [Block<D>],
    alpha: f64,
    extra: &'a [Block<D>],
    stresses: Vec<Block<D>>,
    slots: Vec<[f64; D]>,
}

impl<const D: usize> LinearOperator<D> for FitOperator<'_, D> {
    fn len(&self) -> usize {
        self.model.len()
    }

    fn apply(&mut self, x: &[[f64; D]], y: &mut [[f64; D]]) {
        self.model
            .apply_into(self.rotations, x, &mut self.stresses, &mut self.slots, y);
        for ((yi, xi), e) in y.iter_mut().zip(x).zip(self.extra) {
            for r in 0..D {
                yi[r] = self.alpha * yi[r] + (0..D).map(|c| e[r][c] * xi[c]).sum::<f64>();
            }
        }
    }
}
use contact::{find_contacts, hold_contacts, Contact};
use surface::{associate, enclosed_measure, invalidate_collisions, vertex_normals, Association};

/// The knobs of the per-frame iteration.
#[derive(Debug, Clone, Copy)]
pub struct FitOptions {
    /// $\alpha / \beta$ in units of $\mu \bar h$ (see the module docs).
    pub stiffness: f64,
    /// $\gamma / \beta$.
    pub contact: f64,
    /// Iteration cap per frame (SPEC 5: 10).
    pub max_iterations: usize,
    /// Stop when the last decrease of $D$ is below this fraction of the total decrease so
    /// far (SPEC 5: 1%).
    pub stop_fraction: f64,
    /// Drop colliding associations of distant parts.
    pub invalidate: bool,
    /// Push penetrating surface nodes out of other parts.
    pub self_intersection: bool,
    /// Relative residual of each linear solve.
    pub solver_tolerance: f64,
    /// Cap on PCG iterations per solve.
    pub solver_max_iterations: usize,
    /// PCG on the matrix-free product of the model instead of the assembled matrix.
    pub matrix_free: bool,
    /// Keep a node that was pushed out of another part in contact for the rest of the frame
    /// while it stays within its partner's support ([`contact::hold_contacts`]): stops the
    /// set of contacts alternating between iterations, so limbs pressed together end with
    /// far fewer penetrating nodes (two squeezed blocks: 57 -> 20), but limbs that slide
    /// past each other are held back (horse gallop at 2,500 nodes: mean drift 2.1% ->
    /// 2.7%; benches/README.md). Off by default.
    pub hold_contacts: bool,
    /// Precondition the assembled system with block Jacobi plus the rigid modes of node
    /// aggregates ([`TwoLevel`]) instead of block Jacobi alone.
    pub coarse: bool,
}

impl Default for FitOptions {
    fn default() -> Self {
        Self {
            stiffness: 1.0,
            contact: 1.0,
            max_iterations: 10,
            stop_fraction: 0.01,
            invalidate: true,
            self_intersection: true,
            solver_tolerance: 1e-6,
            solver_max_iterations: 500,
            // Measured slower on the demo's hulls (1.87 vs 1.40 s per frame, machine loaded):
            // its two parallel passes per product cost more in synchronisation than the
            // assembled product's memory traffic at this size.
            matrix_free: false,
            coarse: true,
            hold_contacts: false,
        }
    }
}

/// Figures of one fitted frame (SPEC 5's outputs), at the returned positions.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameMetrics {
    /// $D = \sum_p w_p (x_p - t_p)^\top M_p (x_p - t_p)$.
    pub distance_term: f64,
    /// Mean $|d(x_p)|$ over surface nodes, units of the model.
    pub mean_distance: f64,
    /// Largest $|d(x_p)|$.
    pub max_distance: f64,
    /// Elastic energy.
    pub elastic_energy: f64,
    /// Surface nodes penetrating another part.
    pub penetrating: usize,
    /// Surface nodes whose association was invalidated (last iteration).
    pub invalidated: usize,
    /// Iterations run.
    pub iterations: usize,
    /// PCG iterations over all solves.
    pub solver_iterations: usize,
    /// Every linear solve reached its tolerance.
    pub solver_converged: bool,
    /// Wall-clock seconds spent assembling the system and in the linear solves.
    pub solver_seconds: f64,
}

/// What the iteration keeps across frames: the surface, the stiffness on its fixed pattern,
/// the system matrix and the solver's work vectors.
#[derive(Debug)]
pub struct FitWorkspace<const D: usize> {
    surface: Vec<u32>,
    faces: Vec<[u32; D]>,
    rest_surface: Vec<[f64; D]>,
    support: Vec<f64>,
    stiffness: BlockCsr<D>,
    system: BlockCsr<D>,
    pcg: Pcg<D>,
    /// The two-level preconditioner, aggregated on the rest stiffness and kept (the
    /// pattern does not change); its rigid modes follow the positions.
    coarse: TwoLevel<D>,
    spacing: f64,
}

impl<const D: usize> FitWorkspace<D> {
    /// For `model` with surface nodes `surface` (model node indices) and its faces `faces`
    /// (triangles in 3-D, contour edges in 2-D; model node indices, each a surface node).
    /// Faces are reoriented outward if the surface encloses a negative measure.
    ///
    /// # Errors
    /// [`Error::Empty`] without surface nodes or faces; [`Error::NodeIndex`] for an index
    /// that is not a model node or a face corner that is not a surface node.
    pub fn new(model: &ElasticModel<D>, surface: &[u32], faces: &[[u32; D]]) -> Result<Self> {
        let n = model.len();
        if surface.is_empty() || faces.is_empty() {
            return Err(Error::Empty {
                argument: if surface.is_empty() {
                    "surface_nodes"
                } else {
                    "faces"
                },
                needed: 1,
            });
        }
        let mut local = vec![u32::MAX; n];
        for (at, &i) in surface.iter().enumerate() {
            if i as usize >= n {
                return Err(Error::NodeIndex {
                    argument: "surface_nodes",
                    position: at,
                    index: i as usize,
                    n,
                });
            }
            local[i as usize] = at as u32;
        }
        let faces = faces
            .iter()
            .enumerate()
            .map(|(position, f)| {
                let mut out = [0u32; D];
                for (o, &i) in out.iter_mut().zip(f) {
                    match local.get(i as usize) {
                        Some(&l) if l != u32::MAX => *o = l,
                        _ => {
                            return Err(Error::NodeIndex {
                                argument: "faces",
                                position,
                                index: i as usize,
                                n,
                            })
                        }
                    }
                }
                Ok(out)
            })
            .collect::<Result<Vec<_>>>()?;
        let rest_surface: Vec<[f64; D]> =
            surface.iter().map(|&i| model.rest()[i as usize]).collect();
        // Normals must point out of the body (the targets' distances are positive outside).
        let mut faces = faces;
        if enclosed_measure(&rest_surface, &faces) < 0.0 {
            faces.iter_mut().for_each(|f| f.swap(0, 1));
        }
        let pattern = model.pattern();
        let rows: Vec<&[u32]> = pattern
            .indptr
            .windows(2)
            .map(|w| &pattern.indices[w[0]..w[1]])
            .collect();
        let mut stiffness = BlockCsr::<D>::from_pattern(&rows)?;
        let eye = vec![identity(); n];
        model.system_blocks(&eye, stiffness.blocks_mut())?;
        let system = stiffness.zeros_like();
        // Aggregated on the rest stiffness, so that a frame's result does not depend on
        // which frame was fitted first (resumed runs match).
        let coarse = TwoLevel::new(&stiffness, model.rest(), STRENGTH)?;
        let mean_volume = model.volumes().iter().sum::<f64>() / n as f64;
        Ok(Self {
            rest_surface,
            support: surface
                .iter()
                .map(|&i| model.support()[i as usize])
                .collect(),
            surface: surface.to_vec(),
            faces,
            stiffness,
            system,
            pcg: Pcg::new(),
            coarse,
            spacing: mean_volume.powf(1.0 / D as f64),
        })
    }

    /// Surface positions out of all positions.
    fn surface_positions(&self, x: &[[f64; D]]) -> Vec<[f64; D]> {
        self.surface.iter().map(|&i| x[i as usize]).collect()
    }
}

/// $D$ of the associations at surface positions `xs`.
fn distance_term<const D: usize>(xs: &[[f64; D]], found: &[Association<D>]) -> f64 {
    xs.iter()
        .zip(found)
        .map(|(x, a)| {
            let r: [f64; D] = std::array::from_fn(|i| x[i] - a.target[i]);
            (0..D)
                .map(|i| r[i] * (0..D).map(|j| a.weight[i][j] * r[j]).sum::<f64>())
                .sum::<f64>()
        })
        .sum()
}

fn add_block<const D: usize>(target: &mut Block<D>, block: &Block<D>, scale: f64) {
    for r in 0..D {
        for c in 0..D {
            target[r][c] += scale * block[r][c];
        }
    }
}

fn identity<const D: usize>() -> Block<D> {
    std::array::from_fn(|r| std::array::from_fn(|c| if r == c { 1.0 } else { 0.0 }))
}

/// Fits one frame: from `start` (the neighbouring frame's fit) towards the zero level of
/// the signed distance field `target`.
///
/// # Errors
/// Bad positions or options; [`Error::NotPositiveDefinite`] if the system loses
/// definiteness (it cannot with positive stiffness and a surface term; reported, not
/// hidden).
pub fn fit_frame<const D: usize, F: Field<D>>(
    model: &ElasticModel<D>,
    workspace: &mut FitWorkspace<D>,
    target: &F,
    start: &[[f64; D]],
    options: &FitOptions,
) -> Result<(Vec<[f64; D]>, FrameMetrics)> {
    model.check_positions(start)?;
    for (argument, value) in [
        ("stiffness", options.stiffness),
        ("contact", options.contact),
        ("stop_fraction", options.stop_fraction),
        ("solver_tolerance", options.solver_tolerance),
    ] {
        if !(value.is_finite() && value >= 0.0) || (argument == "stiffness" && value <= 0.0) {
            return Err(Error::InvalidOption {
                argument,
                value,
                expected: "a finite number, positive for stiffness and non-negative otherwise",
            });
        }
    }
    let (_, mu) = model.lame();
    let alpha = options.stiffness / (mu * workspace.spacing);
    let n = model.len();
    let mut x = start.to_vec();
    let mut metrics = FrameMetrics {
        solver_converged: true,
        ..FrameMetrics::default()
    };
    let (mut first, mut previous) = (None::<f64>, None::<f64>);
    let mut previous_contacts = 0;
    let mut held: Vec<Contact<D>> = Vec::new();
    for iteration in 0..options.max_iterations {
        let rotations = model.rotations(&x)?;
        let xs = workspace.surface_positions(&x);
        let normals = vertex_normals(&xs, &workspace.faces);
        let mut found = associate(target, &xs, &normals, &workspace.support);
        metrics.invalidated = if options.invalidate {
            invalidate_collisions(&mut found, &workspace.rest_surface, &workspace.support)
        } else {
            0
        };
        let mut contacts = if options.self_intersection {
            find_contacts(&xs, &normals, &workspace.rest_surface, &workspace.support)
        } else {
            Vec::new()
        };
        let penetrating = contacts.len();
        hold_contacts(&mut contacts, &held, &xs, &normals, &workspace.support);
        // SPEC 5 step 5: stop when the last decrease is a small part of the total so far,
        // unless penetrations are still being resolved (pushing nodes out of another part
        // moves them off their targets, so D alone would stop those iterations early).
        let d = distance_term(&xs, &found);
        if let (Some(d0), Some(last)) = (first, previous) {
            // Contacts present and not stalled (they appeared, or their count still falls).
            let stalled = previous_contacts > 0 && penetrating >= previous_contacts;
            let resolving = penetrating > 0 && !stalled;
            if !resolving && d0 - d > 0.0 && last - d < options.stop_fraction * (d0 - d) {
                break;
            }
        }
        first.get_or_insert(d);
        previous = Some(d);
        previous_contacts = penetrating;
        if options.hold_contacts {
            held.clone_from(&contacts);
        }
        metrics.iterations = iteration + 1;

        // Data and contact terms: 3x3 blocks on surface nodes (E = W + gamma I).
        let mut extra = vec![[[0.0; D]; D]; n];
        for (&node, a) in workspace.surface.iter().zip(&found) {
            add_block(&mut extra[node as usize], &a.weight, 1.0);
        }
        for c in &contacts {
            add_block(
                &mut extra[workspace.surface[c.node] as usize],
                &c.weight,
                options.contact,
            );
        }
        let mut rhs: Vec<f64> = model
            .rhs(&rotations)?
            .into_iter()
            .flatten()
            .map(|v| alpha * v)
            .collect();
        let mut pull = |node: u32, weight: &Block<D>, t: &[f64; D], scale: f64| {
            for r in 0..D {
                rhs[node as usize * D + r] +=
                    scale * (0..D).map(|c| weight[r][c] * t[c]).sum::<f64>();
            }
        };
        for (&node, a) in workspace.surface.iter().zip(&found) {
            pull(node, &a.weight, &a.target, 1.0);
        }
        for c in &contacts {
            pull(
                workspace.surface[c.node],
                &c.weight,
                &c.target,
                options.contact,
            );
        }
        let mut flat: Vec<f64> = x.iter().flatten().copied().collect();
        let (tolerance, cap) = (options.solver_tolerance, options.solver_max_iterations);
        let clock = std::time::Instant::now();
        let status = if options.matrix_free {
            let mut diagonal = model.diagonal_blocks(&rotations)?;
            for (d, e) in diagonal.iter_mut().zip(&extra) {
                for r in 0..3 {
                    for c in 0..3 {
                        d[r][c] = alpha * d[r][c] + e[r][c];
                    }
                }
            }
            let mut preconditioner = BlockJacobi::from_diagonal(&diagonal)?;
            let mut operator = FitOperator {
                model,
                rotations: &rotations,
                alpha,
                extra: &extra,
                stresses: Vec::new(),
                slots: Vec::new(),
            };
            workspace.pcg.solve_operator(
                &mut operator,
                &mut preconditioner,
                &rhs,
                &mut flat,
                tolerance,
                cap,
            )?
        } else {
            // System: alpha S + E, assembled on the stiffness pattern.
            if model.rotation() == Rotation::Warped {
                model.system_blocks(&rotations, workspace.stiffness.blocks_mut())?;
            }
            workspace
                .stiffness
                .scale_into(alpha, &mut workspace.system)?;
            let all: Vec<u32> = (0..n as u32).collect();
            workspace.system.add_diagonal_blocks(1.0, &all, &extra)?;
            if options.coarse {
                // The coarse matrix once per frame (its modes change little between
                // iterations; measured in benches/README.md), block Jacobi every time.
                let coarse = &mut workspace.coarse;
                if iteration == 0 {
                    coarse.set_positions(&x)?;
                    coarse.update(&workspace.system)?;
                } else {
                    coarse.update_smoother(&workspace.system)?;
                }
                workspace
                    .pcg
                    .solve(&workspace.system, coarse, &rhs, &mut flat, tolerance, cap)?
            } else {
                let mut preconditioner = BlockJacobi::new(&workspace.system)?;
                workspace.pcg.solve(
                    &workspace.system,
                    &mut preconditioner,
                    &rhs,
                    &mut flat,
                    tolerance,
                    cap,
                )?
            }
        };
        metrics.solver_iterations += status.iterations;
        metrics.solver_converged &= status.converged;
        metrics.solver_seconds += clock.elapsed().as_secs_f64();
        x = flat.as_chunks::<D>().0.to_vec();
        debug_assert_eq!(x.len(), n);
    }
    // Figures at the returned positions.
    let xs = workspace.surface_positions(&x);
    let normals = vertex_normals(&xs, &workspace.faces);
    let found = associate(target, &xs, &normals, &workspace.support);
    metrics.distance_term = distance_term(&xs, &found);
    let distances: Vec<f64> = found.iter().map(|a| a.distance.abs()).collect();
    metrics.mean_distance = distances.iter().sum::<f64>() / distances.len() as f64;
    metrics.max_distance = distances.iter().copied().fold(0.0, f64::max);
    metrics.elastic_energy = model.energy(&x, &model.rotations(&x)?)?;
    // Counted whether or not the term acted, so runs with it off can be compared.
    metrics.penetrating =
        find_contacts(&xs, &normals, &workspace.rest_surface, &workspace.support).len();
    Ok((x, metrics))
}

#[cfg(test)]
mod tests;
