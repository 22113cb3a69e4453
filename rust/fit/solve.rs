//! SPEC 5 step 4, the solve: PCG on $\alpha S + E$, warm-started from the current positions,
//! either on the assembled matrix (block Jacobi plus the coarse rigid modes, or block Jacobi
//! alone) or on the model's matrix-free product.

use super::assemble::FitSystem;
use super::volume::VolumeTerm;
use super::workspace::FitWorkspace;
use super::FitOptions;
use crate::efg::Block;
use crate::elastic::{ElasticModel, Rotation};
use crate::error::{Error, Result};
use crate::linalg::mat_vec;
use crate::solve::{
    BlockCsr, BlockJacobi, LinearOperator, Pcg, PcgStatus, Preconditioner, RankOne,
};

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
            let ex = mat_vec(e, xi);
            for r in 0..D {
                yi[r] = self.alpha * yi[r] + ex[r];
            }
        }
    }
}

/// Solves `system` with the elastic part `alpha` $S$ (for `rotations`), plus the `volume`
/// term linearised at `x` when given, from `x` in place. `first_iteration` of a
/// frame refreshes the coarse space's rigid modes.
///
/// # Errors
/// [`crate::Error::NotPositiveDefinite`] if the system (or a diagonal block) loses
/// definiteness; bad rotations.
#[allow(clippy::too_many_arguments)]
pub(super) fn solve<const D: usize>(
    model: &ElasticModel<D>,
    workspace: &mut FitWorkspace<D>,
    rotations: &[Block<D>],
    system: &FitSystem<D>,
    alpha: f64,
    first_iteration: bool,
    options: &FitOptions,
    x: &mut Vec<[f64; D]>,
    volume: Option<&VolumeTerm>,
) -> Result<PcgStatus> {
    let mut flat: Vec<f64> = x.iter().flatten().copied().collect();
    let (mut tolerance, cap) = (options.solver_tolerance, options.solver_max_iterations);
    let mut rhs = &system.rhs;
    let with_volume;
    let rank_one = match volume {
        Some(volume) => {
            let mut b = system.rhs.clone();
            volume.add_to_rhs(x, &mut b);
            // The same absolute accuracy as the system without the term: its right-hand
            // side can outweigh the rest, and a tolerance relative to the sum then loosened
            // the solve (more fit iterations; measured in benches/README.md).
            let (norm, with) = (norm(&system.rhs), norm(&b));
            if norm > 0.0 && with > norm {
                tolerance *= norm / with;
            }
            with_volume = b;
            rhs = &with_volume;
            Some(volume.rank_one())
        }
        None => None,
    };
    let status = if options.matrix_free {
        let mut diagonal = model.diagonal_blocks(rotations)?;
        for (d, e) in diagonal.iter_mut().zip(&system.extra) {
            for r in 0..D {
                for c in 0..D {
                    d[r][c] = alpha * d[r][c] + e[r][c];
                }
            }
        }
        let mut preconditioner = BlockJacobi::from_diagonal(&diagonal)?;
        let mut operator = FitOperator {
            model,
            rotations,
            alpha,
            extra: &system.extra,
            stresses: Vec::new(),
            slots: Vec::new(),
        };
        match rank_one {
            Some(term) => workspace.pcg.solve_operator_plus_rank_one(
                &mut operator,
                &mut preconditioner,
                term,
                rhs,
                &mut flat,
                tolerance,
                cap,
            )?,
            None => workspace.pcg.solve_operator(
                &mut operator,
                &mut preconditioner,
                rhs,
                &mut flat,
                tolerance,
                cap,
            )?,
        }
    } else {
        // System: alpha S + E, assembled on the stiffness pattern.
        if model.rotation() == Rotation::Warped {
            model.system_blocks(rotations, workspace.stiffness.blocks_mut())?;
        }
        workspace
            .stiffness
            .scale_into(alpha, &mut workspace.system)?;
        let all: Vec<u32> = (0..model.len() as u32).collect();
        workspace
            .system
            .add_diagonal_blocks(1.0, &all, &system.extra)?;
        if options.coarse {
            // The coarse matrix once per frame (its modes change little between
            // iterations; measured in benches/README.md), block Jacobi every time.
            let coarse = &mut workspace.coarse;
            if first_iteration {
                coarse.set_positions(x)?;
                coarse.update(&workspace.system)?;
            } else {
                coarse.update_smoother(&workspace.system)?;
            }
            solve_or_jacobi(
                &mut workspace.pcg,
                &workspace.system,
                coarse,
                rhs,
                &mut flat,
                rank_one,
                tolerance,
                cap,
            )?
        } else {
            let mut jacobi = BlockJacobi::new(&workspace.system)?;
            solve_with(
                &mut workspace.pcg,
                &workspace.system,
                &mut jacobi,
                rhs,
                &mut flat,
                rank_one,
                tolerance,
                cap,
            )?
        }
    };
    *x = flat.as_chunks::<D>().0.to_vec();
    Ok(status)
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|a| a * a).sum::<f64>().sqrt()
}

/// `system` (plus `rank_one`) solved from `flat` with `preconditioner`.
#[allow(clippy::too_many_arguments)]
fn solve_with<const D: usize, P: Preconditioner<D>>(
    pcg: &mut Pcg<D>,
    system: &BlockCsr<D>,
    preconditioner: &mut P,
    rhs: &[f64],
    flat: &mut [f64],
    rank_one: Option<RankOne<'_>>,
    tolerance: f64,
    cap: usize,
) -> Result<PcgStatus> {
    match rank_one {
        Some(term) => {
            pcg.solve_plus_rank_one(system, preconditioner, term, rhs, flat, tolerance, cap)
        }
        None => pcg.solve(system, preconditioner, rhs, flat, tolerance, cap),
    }
}

/// [`solve_with`] `preconditioner`, and again from the same start with block Jacobi alone
/// if PCG met a non-positive curvature. The two-level preconditioner can lose definiteness
/// where the matrix has not (its coarse factor drops entries; aggregates whose surface
/// nodes were all invalidated are nearly free): measured on the textured fast capture,
/// seed 2, frame 16 with the tracker's tracks, where block Jacobi alone solved it. Block
/// Jacobi is definite wherever the matrix is, so a second failure is the matrix's own and
/// is reported.
#[allow(clippy::too_many_arguments)]
pub(super) fn solve_or_jacobi<const D: usize, P: Preconditioner<D>>(
    pcg: &mut Pcg<D>,
    system: &BlockCsr<D>,
    preconditioner: &mut P,
    rhs: &[f64],
    flat: &mut [f64],
    rank_one: Option<RankOne<'_>>,
    tolerance: f64,
    cap: usize,
) -> Result<PcgStatus> {
    let start = flat.to_vec();
    match solve_with(
        pcg,
        system,
        preconditioner,
        rhs,
        flat,
        rank_one,
        tolerance,
        cap,
    ) {
        Err(Error::NotPositiveDefinite { .. }) => {
            flat.copy_from_slice(&start);
            let mut jacobi = BlockJacobi::new(system)?;
            solve_with(
                pcg,
                system,
                &mut jacobi,
                rhs,
                flat,
                rank_one,
                tolerance,
                cap,
            )
        }
        other => other,
    }
}
