//! Sparse Levenberg-Marquardt for problems with per-frame parameters and shared parameters
//! (SPEC 6): the normal matrix `J^T P J` is block-arrowhead (a dense block per frame, a
//! dense shared block, and their couplings), factorised by faer's sparse Cholesky with
//! the symbolic analysis done once and reused every iteration.
//!
//! Unknowns are ordered `[frame 0 (m), frame 1 (m), …, shared (s)]`: with the shared block
//! last, the arrowhead factorises without fill.

mod arrow;
#[cfg(test)]
mod tests;

pub use arrow::{ArrowNormal, ArrowSolver};

use crate::Result;

/// A least-squares problem `min ½ Σ p_i r_i(x)²` with block-arrowhead structure.
pub trait ArrowProblem {
    /// `(frames, per-frame parameters m, shared parameters s)`.
    fn dims(&self) -> (usize, usize, usize);
    /// The cost `½ Σ p_i r_i²` at `x`.
    fn cost(&self, x: &[f64]) -> Result<f64>;
    /// The cost at `x`, and `J^T P J`, `J^T P r` accumulated into `normal` (zeroed first).
    fn linearize(&self, x: &[f64], normal: &mut ArrowNormal) -> Result<f64>;
    /// Puts `x` back into its admissible set (e.g. joint limits).
    fn project(&self, x: &mut [f64]);
    /// Whether a step is short enough to trust the linearisation (a trust region in the
    /// problem's own units); longer steps are damped further instead of tried.
    fn trusted(&self, _step: &[f64]) -> bool {
        true
    }
    /// Re-decides data association (part assignment, outlier rejection) at `x`; `round`
    /// counts the calls.
    fn refresh(&mut self, x: &[f64], round: usize) -> Result<()>;
}

/// Stopping rules and damping control.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LmOptions {
    /// Iteration cap (one iteration = one linearisation).
    pub max_iterations: usize,
    /// Call [`ArrowProblem::refresh`] every this many iterations (0: only at the start).
    pub refresh_every: usize,
    /// Stop when an accepted step lowers the cost by less than `ftol * cost`.
    pub ftol: f64,
    /// Stop when the step is shorter than `xtol * (|x| + xtol)`.
    pub xtol: f64,
    /// Stop when `max |J^T P r| <= gtol`.
    pub gtol: f64,
    /// Initial damping relative to the largest diagonal entry of `J^T P J`.
    pub initial_damping: f64,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            refresh_every: 5,
            ftol: 1e-10,
            xtol: 1e-10,
            gtol: 1e-12,
            initial_damping: 1e-4,
        }
    }
}

/// Why the iteration stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LmStatus {
    /// The relative cost decrease fell below `ftol`.
    CostConverged,
    /// The step fell below `xtol`.
    StepConverged,
    /// The gradient fell below `gtol`.
    GradientConverged,
    /// `max_iterations` reached.
    MaxIterations,
    /// No damping made a step that lowers the cost (a local minimum at rounding level, or
    /// a problem the model cannot explain).
    NoDescent,
}

/// The outcome of a fit: status and cost history.
#[derive(Debug, Clone, PartialEq)]
pub struct LmReport {
    /// Why it stopped.
    pub status: LmStatus,
    /// Linearisations done.
    pub iterations: usize,
    /// Cost at the start (after the first refresh).
    pub initial_cost: f64,
    /// Cost at the end.
    pub final_cost: f64,
    /// Final damping factor.
    pub damping: f64,
}

/// Minimises the problem from `x` (updated in place) by Levenberg-Marquardt with
/// Marquardt scaling `(A + λ diag(A)) δ = -g` and Nielsen's damping update.
///
/// # Errors
/// Whatever the problem's evaluations return; failure to converge is a status, not an
/// error.
pub fn levenberg_marquardt<P: ArrowProblem>(
    problem: &mut P,
    x: &mut [f64],
    options: &LmOptions,
) -> Result<LmReport> {
    let (frames, m, s) = problem.dims();
    let mut normal = ArrowNormal::new(frames, m, s);
    let mut solver = ArrowSolver::new(frames, m, s)?;
    problem.project(x);
    problem.refresh(x, 0)?;
    let mut rounds = 1;
    let mut cost = problem.linearize(x, &mut normal)?;
    let initial_cost = cost;
    let mut lambda = f64::NAN;
    let mut nu = 2.0;
    let mut candidate = x.to_vec();
    let mut status = LmStatus::MaxIterations;
    let mut iterations = 1;
    while iterations <= options.max_iterations {
        if normal.g.iter().fold(0.0f64, |a, v| a.max(v.abs())) <= options.gtol {
            status = LmStatus::GradientConverged;
            break;
        }
        if lambda.is_nan() {
            lambda = options.initial_damping;
        }
        let mut accepted = false;
        let mut stop = None;
        for _ in 0..60 {
            let Some(step) = solver.solve(&normal, lambda) else {
                lambda *= nu;
                nu *= 2.0;
                continue;
            };
            if !problem.trusted(&step) {
                lambda *= nu;
                nu *= 2.0;
                continue;
            }
            let step_norm = step.iter().map(|v| v * v).sum::<f64>().sqrt();
            let x_norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
            for (c, (xi, di)) in candidate.iter_mut().zip(x.iter().zip(&step)) {
                *c = xi + di;
            }
            problem.project(&mut candidate);
            let new_cost = problem.cost(&candidate)?;
            // Predicted decrease of the damped model: ½ δ·(λ D δ - g).
            let predicted = 0.5
                * step
                    .iter()
                    .zip(&normal.g)
                    .zip(solver.scaling())
                    .map(|((d, g), dd)| d * (lambda * dd * d - g))
                    .sum::<f64>();
            let rho = (cost - new_cost) / predicted;
            if new_cost < cost && rho > 0.0 {
                let decrease = cost - new_cost;
                x.copy_from_slice(&candidate);
                cost = new_cost;
                lambda *= (1.0f64 / 3.0).max(1.0 - (2.0 * rho - 1.0).powi(3));
                nu = 2.0;
                accepted = true;
                if decrease <= options.ftol * cost {
                    stop = Some(LmStatus::CostConverged);
                } else if step_norm <= options.xtol * (x_norm + options.xtol) {
                    stop = Some(LmStatus::StepConverged);
                }
                break;
            }
            if step_norm <= options.xtol * (x_norm + options.xtol) {
                stop = Some(LmStatus::StepConverged);
                break;
            }
            lambda *= nu;
            nu *= 2.0;
        }
        if let Some(reason) = stop {
            status = reason;
            break;
        }
        if !accepted {
            status = LmStatus::NoDescent;
            break;
        }
        iterations += 1;
        if options.refresh_every > 0 && iterations % options.refresh_every == 0 {
            problem.refresh(x, rounds)?;
            rounds += 1;
        }
        cost = problem.linearize(x, &mut normal)?;
    }
    Ok(LmReport {
        status,
        iterations: iterations.min(options.max_iterations),
        initial_cost,
        final_cost: cost,
        damping: lambda,
    })
}
