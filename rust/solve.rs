//! Sparse symmetric positive definite systems of the elastic fitting (SPEC 5, step 4):
//! $(\alpha K + \beta D + \gamma I)\,x = f$ with $K$ the EFG stiffness and $D$, $I$
//! $B \times B$ diagonal blocks on the surface nodes ($B$ = 3 in 3-D, 2 in 2-D).
//!
//! * [`BlockCsr`]: the matrix, $B \times B$ blocks in compressed sparse rows with the full
//!   symmetric pattern; the pattern is fixed through a sequence, the values are rewritten
//!   per iteration without allocating.
//! * [`Pcg`]: preconditioned conjugate gradients, warm-started, with a [`BlockJacobi`]
//!   preconditioner or any other [`Preconditioner`], returning a [`PcgStatus`].
//! * [`SparseCholesky`]: faer's sparse $L L^\top$ with the symbolic analysis (AMD ordering,
//!   elimination tree, supernodes) done once per pattern; it also serves as the
//!   preconditioner of CG while the values drift from those it factored.

mod block;
mod cholesky;
mod pcg;
mod upper;

pub use block::{Block, BlockCsr, CsrIndex};
pub use cholesky::SparseCholesky;
pub use pcg::{BlockJacobi, Pcg, PcgStatus, Preconditioner};

#[cfg(test)]
mod tests;
