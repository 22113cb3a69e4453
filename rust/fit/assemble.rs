//! SPEC 5 step 4, the system of one iteration:
//! $(\alpha S + E)\,x = \alpha f + \sum_\text{terms} W t$ with $E$ the block-diagonal
//! sum of the terms' metrics $W$ on their nodes (data: $W = w_p M_p$ towards $t_p$;
//! contacts: $\gamma M_I$ towards $p'$).

use super::associate::SurfaceTerms;
use super::contact::Contact;
use super::coverage::Pull;
use super::workspace::FitWorkspace;
use crate::efg::Block;
use crate::elastic::ElasticModel;
use crate::error::Result;
use crate::linalg::{add_scaled, mat_vec};

/// The terms of one iteration's system besides $\alpha S$.
pub(super) struct FitSystem<const D: usize> {
    /// $E$: one block per model node (zero off the surface).
    pub(super) extra: Vec<Block<D>>,
    /// The right-hand side, flat `(n D,)`.
    pub(super) rhs: Vec<f64>,
}

impl<const D: usize> FitSystem<D> {
    /// $\alpha f$ alone (the elastic right-hand side for `rotations`), no terms yet.
    fn elastic(model: &ElasticModel<D>, rotations: &[Block<D>], alpha: f64) -> Result<Self> {
        let rhs = model
            .rhs(rotations)?
            .into_iter()
            .flatten()
            .map(|v| alpha * v)
            .collect();
        Ok(Self {
            extra: vec![[[0.0; D]; D]; model.len()],
            rhs,
        })
    }

    /// Adds a pull of model node `node` towards `target` with metric `scale * weight`.
    pub(super) fn pull(&mut self, node: u32, weight: &Block<D>, target: &[f64; D], scale: f64) {
        let node = node as usize;
        add_scaled(&mut self.extra[node], weight, scale);
        let wt = mat_vec(weight, target);
        for (value, wt) in self.rhs[node * D..(node + 1) * D].iter_mut().zip(wt) {
            *value += scale * wt;
        }
    }
}

/// The system of one iteration: elasticity with `rotations` scaled by `alpha`, the surface
/// associations, the `contacts` with weight `contact` ($\gamma$) and the `pulls` of
/// SPEC 5.1's terms (their weights included).
///
/// # Errors
/// As [`ElasticModel::rhs`].
pub(super) fn assemble<const D: usize>(
    model: &ElasticModel<D>,
    workspace: &FitWorkspace<D>,
    rotations: &[Block<D>],
    surface: &SurfaceTerms<D>,
    contacts: &[Contact<D>],
    pulls: &[Pull<D>],
    alpha: f64,
    contact: f64,
) -> Result<FitSystem<D>> {
    let mut system = FitSystem::elastic(model, rotations, alpha)?;
    for (&node, a) in workspace.surface.iter().zip(&surface.found) {
        system.pull(node, &a.weight, &a.target, 1.0);
    }
    for c in contacts {
        system.pull(workspace.surface[c.node], &c.weight, &c.target, contact);
    }
    for p in pulls {
        system.pull(workspace.surface[p.node], &p.weight, &p.target, 1.0);
    }
    Ok(system)
}
