//! SPEC 5 step 4, the solve: PCG on $\alpha S + E$, warm-started from the current positions,
//! either on the assembled matrix (block Jacobi plus the coarse rigid modes, or block Jacobi
//! alone) or on the model's matrix-free product.

use super::assemble::FitSystem;
use super::workspace::FitWorkspace;
use super::FitOptions;
use crate::efg::Block;
use crate::elastic::{ElasticModel, Rotation};
use crate::error::{Error, Result};
use crate::linalg::mat_vec;
use crate::solve::{BlockCsr, BlockJacobi, LinearOperator, Pcg, PcgStatus, Preconditioner};

/// Relative residual of the second right-hand side's solve (see [`solve`]).
const ALSO_TOLERANCE: f64 = 1e-3;

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

/// Solves `system` with the elastic part `alpha` $S$ (for `rotations`) from `x` in place,
/// and, given `also` (a right-hand side and a start), the same matrix for it with the same
/// preconditioner (the volume term's $A^{-1} g$). `first_iteration` of a frame refreshes the
/// coarse space's rigid modes.
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
    mut also: Option<(&[f64], &mut Vec<f64>)>,
) -> Result<PcgStatus> {
    let mut flat: Vec<f64> = x.iter().flatten().copied().collect();
    let (tolerance, cap) = (options.solver_tolerance, options.solver_max_iterations);
    // The second right-hand side is a correction's direction: three digits fewer than the
    // main solve's, at most ALSO_TOLERANCE, place the rank-one step well enough (at the
    // main tolerance it cost as many PCG iterations as the main solve).
    let also_tolerance = (tolerance * 1e3).min(ALSO_TOLERANCE);
    let rhs = &system.rhs;
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
        let mut status = workspace.pcg.solve_operator(
            &mut operator,
            &mut preconditioner,
            rhs,
            &mut flat,
            tolerance,
            cap,
        )?;
        if let Some((b, y)) = also.as_mut() {
            let more = workspace.pcg.solve_operator(
                &mut operator,
                &mut preconditioner,
                b,
                y,
                also_tolerance,
                cap,
            )?;
            status = merge(status, more);
        }
        status
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
                also,
                tolerance,
                also_tolerance,
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
                also,
                tolerance,
                also_tolerance,
                cap,
            )?
        }
    };
    *x = flat.as_chunks::<D>().0.to_vec();
    Ok(status)
}

/// `system` solved from `flat` with `preconditioner`, and `also` (a right-hand side and
/// its start) with the same preconditioner to `also_tolerance`.
#[allow(clippy::too_many_arguments)]
fn solve_with<const D: usize, P: Preconditioner<D>>(
    pcg: &mut Pcg<D>,
    system: &BlockCsr<D>,
    preconditioner: &mut P,
    rhs: &[f64],
    flat: &mut [f64],
    mut also: Option<(&[f64], &mut Vec<f64>)>,
    tolerance: f64,
    also_tolerance: f64,
    cap: usize,
) -> Result<PcgStatus> {
    let mut status = pcg.solve(system, preconditioner, rhs, flat, tolerance, cap)?;
    if let Some((b, y)) = also.as_mut() {
        let more = pcg.solve(system, preconditioner, b, y, also_tolerance, cap)?;
        status = merge(status, more);
    }
    Ok(status)
}

/// [`solve_with`] `preconditioner`, and again from the same starts with block Jacobi alone
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
    mut also: Option<(&[f64], &mut Vec<f64>)>,
    tolerance: f64,
    also_tolerance: f64,
    cap: usize,
) -> Result<PcgStatus> {
    let start = flat.to_vec();
    let also_start = also.as_ref().map(|(_, y)| y.to_vec());
    let also_again = also.as_mut().map(|(b, y)| (*b, &mut **y));
    match solve_with(
        pcg,
        system,
        preconditioner,
        rhs,
        flat,
        also_again,
        tolerance,
        also_tolerance,
        cap,
    ) {
        Err(Error::NotPositiveDefinite { .. }) => {
            flat.copy_from_slice(&start);
            if let (Some((_, y)), Some(y0)) = (also.as_mut(), also_start) {
                y.copy_from_slice(&y0);
            }
            let mut jacobi = BlockJacobi::new(system)?;
            solve_with(
                pcg,
                system,
                &mut jacobi,
                rhs,
                flat,
                also,
                tolerance,
                also_tolerance,
                cap,
            )
        }
        other => other,
    }
}

/// Two solves' status as one: iterations summed, converged if both did.
fn merge(a: PcgStatus, b: PcgStatus) -> PcgStatus {
    PcgStatus {
        iterations: a.iterations + b.iterations,
        converged: a.converged && b.converged,
        ..a
    }
}
