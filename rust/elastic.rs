//! The element-free elastic body (SPEC 4): nodes, fixed neighbourhoods, MLS gradients,
//! nodal volumes and an isotropic material, with per-node rotation compensation (SPEC 4.4).
//!
//! Everything is written through the MLS deformation gradient of a neighbourhood,
//! $F_p(x) = \sum_{i \in N_p} x_i\, \nabla\Phi_i(x_p)^\top$ (and $G_p = F_p(X)$, the identity
//! up to rounding by linear reproduction). With $H_p$ the displacement gradient the mode
//! measures strain from,
//!
//! * `Linear`: $H_p = F_p - G_p$ (no compensation; rotations read as strain);
//! * `Rhs` (the paper's Eq. 12): $H_p = F_p - R_p G_p$, i.e. the neighbourhood's rest shape
//!   rotated by $R_p$ is the target, so $K$ stays fixed and only the right-hand side
//!   $f = \sum_p k_p R_p X_{N_p}$ changes;
//! * `Warped` (corotational): $H_p = R_p^\top F_p - G_p$, i.e. $k_p \to R_p k_p R_p^\top$;
//!
//! the energy is $\sum_p \tfrac12 V_p\, \sigma(\varepsilon_p) : \varepsilon_p$ with
//! $\varepsilon_p = \operatorname{sym} H_p$ and
//! $\sigma = \lambda \operatorname{tr}\varepsilon\, I + 2\mu\varepsilon$, and the force
//! on node $i$ is $-\sum_p V_p\, (R_p)\, \sigma_p\, \nabla\Phi_i(x_p)$ (with $R_p$ in the
//! warped mode), $R_p$ held fixed as in the paper.
//! A rigid motion $x = R X + t$ gives $R_p = R$ and zero strain in both compensated modes.
//!
//! $R_p$ is the rotation of the polar decomposition of
//! $A_p = \sum_i m_i (x_i - x_p)(X_i - X_p)^\top$, $m_i = \exp(-|X_i - X_p|^2 / (d_p/2)^2)$,
//! by the batched kernel of [`crate::polar`].

//!
//! The files: `model` (nodes, neighbourhoods, MLS gradients, the build), `rotations`
//! ($R_p$ from the matrix they are fitted to), `energy` (strain, stress, energy, forces,
//! the right-hand side) and `operator` (the system matrix: matrix-free product, diagonal
//! blocks, assembled blocks).

mod energy;
mod model;
mod operator;
mod rotations;

pub use model::ElasticModel;

#[cfg(test)]
use crate::efg::{Block, Material};

/// How rotations are taken out of the strain (SPEC 4.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rotation {
    /// None: plain linear elasticity about the rest state.
    Linear,
    /// The paper's: rotated rest shapes on the right-hand side, $K$ fixed.
    Rhs,
    /// Corotational: $R_p k_p R_p^\top$, the system matrix changes with the rotations.
    Warped,
}

/// Which matrix's polar rotation is $R_p$ (SPEC 4.4 names the first).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RotationFit {
    /// $A_p = \sum_i m_i (x_i - x_p)(X_i - X_p)^\top$ with Gaussian weights (the paper's).
    Weighted,
    /// The MLS deformation gradient $F_p$: the rotation the strain measure itself sees.
    /// Measured: on a bar bent by 90 degrees the `Rhs` fixed-point iteration diverges with
    /// `Weighted` rotations and converges with these (benches/README.md).
    Gradient,
}

/// Support radius factor $c$ of SPEC 4.1: $d_p = c\, r_k$.
pub const SUPPORT_FACTOR: f64 = 1.1;

#[cfg(test)]
mod tests;
