//! Sparse symmetric positive definite systems of the elastic fitting (SPEC 5, step 4):
//! $(\alpha K + \beta D + \gamma I)\,x = f$ with $K$ the EFG stiffness and $D$, $I$
//! $B \times B$ diagonal blocks on the surface nodes ($B$ = 3 in 3-D, 2 in 2-D).
//!
//! * [`BlockCsr`]: the matrix, $B \times B$ blocks in compressed sparse rows with the full
//!   symmetric pattern; the pattern is fixed through a sequence, the values are rewritten
//!   per iteration without allocating.
//! * [`Pcg`]: preconditioned conjugate gradients, warm-started, with a [`BlockJacobi`]
//!   preconditioner or any other [`Preconditioner`], returning a [`PcgStatus`]; its
//!   products read only the upper triangle (half the memory traffic), for 3x3 blocks with
//!   an AVX2 kernel on a float32 copy inside float64 iterative refinement (convergence is
//!   always decided on the float64 residual). [`Pcg::solve_csr_parts`] reads scipy's CSR
//!   arrays straight into that upper triangle.
//! * [`TwoLevel`]: block Jacobi plus a coarse correction on the rigid motions of node
//!   aggregates, for bodies the surface term anchors only weakly.
//! * [`SparseCholesky`]: faer's sparse $L L^\top$ with the symbolic analysis (AMD ordering,
//!   elimination tree, supernodes) done once per pattern; it also serves as the
//!   preconditioner of CG while the values drift from those it factored.
//! * [`conjugate_gradient_csr`]: CG from scalar CSR arrays ([`CsrParts`]) with the
//!   preconditioner the caller holds ([`CsrPreconditioner`]).
//!
//! The per-iteration solve of the fitting, allocation-free after the first pass:
//!
//! ```no_run
//! # use _core::solve::{Block, BlockCsr, BlockJacobi, Pcg};
//! # fn fit(stiffness: &_core::efg::Csr, surface: &[u32], metric: &[Block<3>],
//! #        rhs: &[f64], x: &mut [f64]) -> _core::Result<()> {
//! let k = BlockCsr::<3>::from_csr(stiffness)?;
//! let mut a = k.zeros_like(); // shares k's pattern
//! let mut pcg = Pcg::new();
//! let (alpha, beta) = (1.0, 10.0);
//! k.scale_into(alpha, &mut a)?;
//! a.add_diagonal_blocks(beta, surface, metric)?;
//! let mut jacobi = BlockJacobi::new(&a)?;
//! for _iteration in 0..10 {
//!     // ... new metric blocks and right-hand side ...
//!     k.scale_into(alpha, &mut a)?;
//!     a.add_diagonal_blocks(beta, surface, metric)?;
//!     jacobi.update(&a)?;
//!     let status = pcg.solve(&a, &mut jacobi, rhs, x, 1e-8, 1000)?; // warm: x is the last fit
//!     if !status.converged { /* report status.relative_residual */ }
//! }
//! # Ok(()) }
//! ```

mod block;
mod cholesky;
mod coarse;
mod csr_solve;
mod pcg;
mod upper;

pub use block::{Block, BlockCsr, CsrIndex};
pub use cholesky::SparseCholesky;
pub use coarse::{TwoLevel, STRENGTH};
pub use csr_solve::{conjugate_gradient_csr, CsrParts, CsrPreconditioner};
pub use pcg::{
    BlockJacobi, LinearOperator, Pcg, PcgStatus, PlusRankOne, Preconditioner, RankOne,
    ShermanMorrison,
};

#[cfg(test)]
mod coarse_tests;
#[cfg(test)]
mod csr_tests;
#[cfg(test)]
mod tests;
