//! The track term of the fitting (SPEC 5.1; issue 15, item 4): tracked 3-D surface points
//! pull the material points of the model they were attached to.
//!
//! A track $k$ is attached once, at its frame nearest the rest frame, as a material point
//! $x(a_k) = \sum_i \Phi_i(a_k)\, x_i$ over the nodes around it (MLS shape-function
//! weights, computed by the caller). In every other frame where the track has a position
//! $X_k$ with covariance $\Sigma_k$, the term is
//! $T = \sum_k w\,\sigma_0^2\,c^2 \ln(1 + m_k / c^2)$, $m_k = r_k^\top P_k r_k$,
//! $r_k = x(a_k) - X_k$, $P_k = (\Sigma_k + \sigma_0^2 I)^{-1}$: a Cauchy loss of the
//! Mahalanobis distance, so a track that went astray (a wrong match the tracker's filters
//! kept) pulls less the farther it is instead of tearing the model; $\sigma_0$ caps the
//! precision, so no track is trusted below $\sigma_0$ however small its covariance, and
//! $w\,\sigma_0^2 P_k \preceq w\,I$ (one track pulls at most as hard as a fully confident
//! surface node at weight $w$).
//!
//! Gauss-Newton with the Cauchy weight frozen at the iterate (IRLS) gives the metric
//! $W_k = w\,\sigma_0^2 P_k / (1 + m_k / c^2)$ on the residual $\sum_i \Phi_i x_i - X_k$,
//! whose Hessian $\Phi \Phi^\top \otimes W_k$ couples the nodes of a track. The system here
//! holds block-diagonal terms only (see `assemble`), so the term is majorised by one
//! (Jensen's inequality with the weights $|\Phi_i| / S$, $S = \sum_i |\Phi_i|$):
//! $(\sum_i \Phi_i \delta_i + r)^\top W (\ldots) \le \sum_i |\Phi_i| S\,
//! (\delta_i + \operatorname{sgn}\Phi_i\, r / S)^\top W (\ldots)$, equal with the same
//! gradient at $\delta = 0$. Each node $i$ is thus pulled towards
//! $x_i - \operatorname{sgn}(\Phi_i)\, r / S$ with metric $|\Phi_i| S\, W_k$: every
//! iteration lowers $T$ (majorise-minimise), and for the rigid motion of a neighbourhood
//! (all $\delta_i$ equal, $\Phi \ge 0$) the bound is exact, which is the motion a track
//! mostly asks for; the elastic term keeps the neighbours together.

use super::assemble::FitSystem;
use crate::efg::Block;
use crate::error::{check_finite, Error, Result};
use crate::linalg::quadratic_form;

/// The tracks of one frame, attached to the model.
#[derive(Debug, Clone)]
pub struct FrameTracks<const D: usize> {
    /// Nodes per material point.
    k: usize,
    /// Row-major `(T, k)`: the nodes of each material point.
    nodes: Vec<u32>,
    /// Row-major `(T, k)`: their MLS weights $\Phi_i(a_k)$.
    phi: Vec<f64>,
    /// `(T,)`: the tracked positions $X_k$ of this frame, world units.
    targets: Vec<[f64; D]>,
    /// `(T,)`: $P_k = (\Sigma_k + \sigma_0^2 I)^{-1}$, inverse world units squared.
    precisions: Vec<Block<D>>,
    /// $w$, relative to the surface term's $\beta$.
    weight: f64,
    /// $\sigma_0$, world units.
    sigma: f64,
    /// $c$, the Cauchy scale in Mahalanobis units.
    scale: f64,
}

/// The term at one iterate: its block-diagonal majoriser's pulls (model node, target,
/// metric) and $T$.
#[derive(Debug, Clone, Default)]
pub(super) struct TrackTerm<const D: usize> {
    pulls: Vec<(u32, [f64; D], Block<D>)>,
    pub(super) energy: f64,
}

impl<const D: usize> FrameTracks<D> {
    /// Tracks with `k` nodes each over a model of `n` nodes (see the fields).
    ///
    /// # Errors
    /// [`Error::LengthMismatch`] for arrays of the wrong length, [`Error::NodeIndex`] for a
    /// node that is not one of the `n`, [`Error::NonFinite`] for non-finite weights,
    /// targets or precisions, [`Error::InvalidOption`] for a weight, `sigma` or `scale`
    /// that is not finite and positive (the weight may be 0).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        n: usize,
        k: usize,
        nodes: Vec<u32>,
        phi: Vec<f64>,
        targets: Vec<[f64; D]>,
        precisions: Vec<Block<D>>,
        weight: f64,
        sigma: f64,
        scale: f64,
    ) -> Result<Self> {
        let t = targets.len();
        for (argument, got) in [
            ("track_nodes", nodes.len()),
            ("track_phi", phi.len()),
            ("track_precisions", precisions.len() * k),
        ] {
            if got != t * k {
                return Err(Error::LengthMismatch {
                    argument,
                    expected: t,
                    got: got / k.max(1),
                });
            }
        }
        if let Some(position) = nodes.iter().position(|&i| i as usize >= n) {
            return Err(Error::NodeIndex {
                argument: "track_nodes",
                position,
                index: nodes[position] as usize,
                n,
            });
        }
        check_finite("track_targets", &targets)?;
        let flat: Vec<[f64; D]> = precisions.iter().flatten().copied().collect();
        check_finite("track_precisions", &flat)?;
        let phi_rows: Vec<[f64; 1]> = phi.iter().map(|&v| [v]).collect();
        check_finite("track_phi", &phi_rows)?;
        for (argument, value) in [
            ("tracks", weight),
            ("track_sigma", sigma),
            ("track_scale", scale),
        ] {
            if !(value.is_finite() && (value > 0.0 || (argument == "tracks" && value == 0.0))) {
                return Err(Error::InvalidOption {
                    argument,
                    value,
                    expected: "a finite positive number (the weight may be 0)",
                });
            }
        }
        Ok(Self {
            k,
            nodes,
            phi,
            targets,
            precisions,
            weight,
            sigma,
            scale,
        })
    }

    /// Number of tracks.
    pub fn len(&self) -> usize {
        self.targets.len()
    }

    /// True without tracks.
    pub fn is_empty(&self) -> bool {
        self.targets.is_empty()
    }

    /// The material points $x(a_k)$ at positions `x`.
    pub fn material_points(&self, x: &[[f64; D]]) -> Vec<[f64; D]> {
        (0..self.len())
            .map(|t| {
                let mut p = [0.0; D];
                for (&i, &w) in self.row(&self.nodes, t).iter().zip(self.row(&self.phi, t)) {
                    for (p, xi) in p.iter_mut().zip(x[i as usize]) {
                        *p += w * xi;
                    }
                }
                p
            })
            .collect()
    }

    fn row<'a, T>(&self, values: &'a [T], t: usize) -> &'a [T] {
        &values[t * self.k..(t + 1) * self.k]
    }

    /// The term and its majoriser's pulls at positions `x` (module docs).
    pub(super) fn term(&self, x: &[[f64; D]]) -> TrackTerm<D> {
        let mut term = TrackTerm::default();
        if self.weight == 0.0 {
            return term;
        }
        let (c2, base) = (
            self.scale * self.scale,
            self.weight * self.sigma * self.sigma,
        );
        for (t, point) in self.material_points(x).iter().enumerate() {
            let residual: [f64; D] = std::array::from_fn(|a| point[a] - self.targets[t][a]);
            let m = quadratic_form(&self.precisions[t], &residual);
            term.energy += base * c2 * (m / c2).ln_1p();
            let robust = base / (1.0 + m / c2);
            let phi = self.row(&self.phi, t);
            let total: f64 = phi.iter().map(|v| v.abs()).sum();
            if total <= 0.0 {
                continue;
            }
            for (&i, &w) in self.row(&self.nodes, t).iter().zip(phi) {
                if w == 0.0 {
                    continue;
                }
                let xi = x[i as usize];
                let target = std::array::from_fn(|a| xi[a] - w.signum() * residual[a] / total);
                let metric =
                    self.precisions[t].map(|row| row.map(|v| v * robust * w.abs() * total));
                term.pulls.push((i, target, metric));
            }
        }
        term
    }

    /// Mean Mahalanobis distance $\sqrt{m_k}$ of the material points at `x` (0 without
    /// tracks).
    pub fn mean_mahalanobis(&self, x: &[[f64; D]]) -> f64 {
        let points = self.material_points(x);
        if points.is_empty() {
            return 0.0;
        }
        let sum: f64 = points
            .iter()
            .enumerate()
            .map(|(t, p)| {
                let r: [f64; D] = std::array::from_fn(|a| p[a] - self.targets[t][a]);
                quadratic_form(&self.precisions[t], &r).sqrt()
            })
            .sum();
        sum / points.len() as f64
    }
}

impl<const D: usize> TrackTerm<D> {
    /// Adds the pulls to `system` (model nodes, weights included).
    pub(super) fn add_to(&self, system: &mut FitSystem<D>) {
        for (node, target, metric) in &self.pulls {
            system.pull(*node, metric, target, 1.0);
        }
    }
}
