//! A consistency penalty that stabilises direct nodal integration (SPEC 4.3, "a consistent
//! penalty on the difference between the MLS gradient and the neighbourhood's affine fit").
//!
//! Nodal integration sees a field only through its gradient at the nodes, so fields that
//! oscillate from node to node while keeping every nodal gradient small cost almost no
//! energy. They are not exact zero modes on our clouds (`tests/test_elastic.py` counts
//! exactly the rigid ones), but they are soft: they make the lowest eigenvalues of the
//! fitting system a dense cluster of oscillating modes, which is what makes conjugate
//! gradients slow (measured in benches/README.md), and they let a fitted surface ripple.
//!
//! The penalty measures how far each neighbour strays from the affine field that node
//! $p$'s MLS gradient predicts,
//! $$ r_{pj}(x) = (x_j - x_p) - F_p(x)\,(X_j - X_p), \qquad
//!    E_s = \tfrac12 \sum_p s_p \sum_{j \in N_p \setminus p} \frac{|r_{pj}|^2}{|X_j - X_p|^2},
//!    \quad s_p = \frac{\epsilon\, \mu\, V_p}{k - 1}, $$
//! in the units of the elastic energy ($\mu V$ times a squared strain). Linear
//! reproduction of the MLS gradients makes $r_{pj} = 0$ for every affine field $x = A X +
//! t$, rigid motions included (finite rotations too), so the constant-strain patch test,
//! the rigid-motion invariance and the six zero modes are untouched and no rotation
//! compensation is needed; a smooth bend costs $O(\epsilon\, h^2)$ of its elastic energy.
//!
//! $E_s = \tfrac12 \sum_p x_{N_p}^\top (s_p L_p \otimes I) x_{N_p}$ with the $k \times k$
//! matrix $L_p = \sum_j w_j c_j c_j^\top$, $w_j = |d_j|^{-2}$, $d_j = X_j - X_p$ and
//! $c_j[a] = \delta_{ja} - \delta_{0a} - g_a \cdot d_j$ (slot 0 is $p$ itself). With the
//! moments $W = \sum_j w_j$, $m = \sum_j w_j d_j$, $M = \sum_j w_j d_j d_j^\top$ each entry is
//! closed form:
//! $$ L_{ab} = w_a \delta_{ab} - w_a \delta_{0b} - w_b \delta_{0a} + W \delta_{0a}\delta_{0b}
//!    - w_a\, g_b \cdot d_a - w_b\, g_a \cdot d_b + \delta_{0a}\, g_b \cdot m
//!    + \delta_{0b}\, g_a \cdot m + g_a^\top M g_b, $$
//!
//! So assembling it costs what the stiffness blocks cost.

use rayon::prelude::*;

use super::assembly::Block;
use crate::linalg::{dot, mat_vec};

/// The penalty's per-neighbourhood data: offsets, weights and their moments.
#[derive(Debug, Clone)]
pub struct Consistency<const D: usize> {
    k: usize,
    /// $d_{pa} = X_{N_p[a]} - X_p$, row-major `(n, k)`.
    offsets: Vec<[f64; D]>,
    /// $w_{pa} = |d_{pa}|^{-2}$ (0 for the node itself), row-major `(n, k)`.
    weights: Vec<f64>,
    /// $s_p$.
    scale: Vec<f64>,
    /// $(W_p, m_p, M_p)$.
    moments: Vec<(f64, [f64; D], Block<D>)>,
}

impl<const D: usize> Consistency<D> {
    /// The penalty of strength `epsilon` (relative to the shear modulus `mu`) on rest
    /// positions `rest` with row-major `(n, k)` neighbour lists (each row starting with its
    /// node, neighbours distinct from it: already checked by the model).
    pub fn new(
        rest: &[[f64; D]],
        neighbors: &[u32],
        k: usize,
        volumes: &[f64],
        mu: f64,
        epsilon: f64,
    ) -> Self {
        let n = rest.len();
        let offsets: Vec<[f64; D]> = neighbors
            .par_iter()
            .enumerate()
            .map(|(at, &j)| {
                let (x, c) = (rest[j as usize], rest[at / k]);
                std::array::from_fn(|a| x[a] - c[a])
            })
            .collect();
        let weights: Vec<f64> = offsets
            .par_iter()
            .map(|d| {
                let length2: f64 = d.iter().map(|v| v * v).sum();
                // The node itself (slot 0) has no offset; coincident nodes were rejected by
                // the MLS conditioning check.
                if length2 > 0.0 {
                    1.0 / length2
                } else {
                    0.0
                }
            })
            .collect();
        let scale = (0..n)
            .map(|p| epsilon * mu * volumes[p] / (k - 1) as f64)
            .collect();
        let moments = (0..n)
            .into_par_iter()
            .map(|p| {
                let (mut total, mut first, mut second) = (0.0, [0.0; D], [[0.0; D]; D]);
                for a in 0..k {
                    let (w, d) = (weights[p * k + a], offsets[p * k + a]);
                    total += w;
                    for r in 0..D {
                        first[r] += w * d[r];
                        for c in 0..D {
                            second[r][c] += w * d[r] * d[c];
                        }
                    }
                }
                (total, first, second)
            })
            .collect();
        Self {
            k,
            offsets,
            weights,
            scale,
            moments,
        }
    }

    /// $s_p L_p[a, b]$ for neighbourhood `p` with MLS gradients `grad` (its `k` rows).
    #[inline]
    pub fn coefficient(&self, p: usize, a: usize, b: usize, grad: &[[f64; D]]) -> f64 {
        let k = self.k;
        let (total, first, second) = &self.moments[p];
        let (ga, gb) = (&grad[a], &grad[b]);
        let (wa, wb) = (self.weights[p * k + a], self.weights[p * k + b]);
        let (da, db) = (&self.offsets[p * k + a], &self.offsets[p * k + b]);
        let mut l = -wa * dot(gb, da) - wb * dot(ga, db);
        let second_gb = mat_vec(second, gb);
        for r in 0..D {
            l += ga[r] * second_gb[r];
        }
        if a == b {
            l += wa;
        }
        if a == 0 {
            l += dot(gb, first) - wb;
        }
        if b == 0 {
            l += dot(ga, first) - wa;
        }
        if a == 0 && b == 0 {
            l += total;
        }
        self.scale[p] * l
    }

    /// Node `p`'s share of $E_s$ at positions `x`, with $F_p(x)$ given.
    pub fn energy(&self, p: usize, hood: &[u32], f: &Block<D>, x: &[[f64; D]]) -> f64 {
        let k = self.k;
        let mut sum = 0.0;
        for a in 1..k {
            let r = self.residual(p, a, hood, f, x);
            sum += self.weights[p * k + a] * r.iter().map(|v| v * v).sum::<f64>();
        }
        0.5 * self.scale[p] * sum
    }

    /// $r_{pa}$ of neighbour slot `a`.
    #[inline]
    fn residual(&self, p: usize, a: usize, hood: &[u32], f: &Block<D>, x: &[[f64; D]]) -> [f64; D] {
        let d = &self.offsets[p * self.k + a];
        let (xj, xp) = (x[hood[a] as usize], x[hood[0] as usize]);
        let fd = mat_vec(f, d);
        std::array::from_fn(|r| xj[r] - xp[r] - fd[r])
    }

    /// Node `p`'s contributions to $\partial E_s / \partial x$, one vector per neighbour
    /// slot, written into `out` (`k` rows), with $F_p(x)$ given and `grad` node `p`'s MLS
    /// gradients: $s_p (w_a r_a - \delta_{0a} \sum_j w_j r_j - T g_a)$ with
    /// $T = \sum_j w_j r_j d_j^\top$.
    pub fn slot_gradients(
        &self,
        p: usize,
        hood: &[u32],
        f: &Block<D>,
        x: &[[f64; D]],
        grad: &[[f64; D]],
        out: &mut [[f64; D]],
    ) {
        let k = self.k;
        let s = self.scale[p];
        let mut t = [[0.0; D]; D];
        let mut sum = [0.0; D];
        out[0] = [0.0; D];
        for (a, slot) in out.iter_mut().enumerate().skip(1) {
            let r = self.residual(p, a, hood, f, x);
            let w = self.weights[p * k + a];
            let d = &self.offsets[p * k + a];
            for ((total, t_row), r_row) in sum.iter_mut().zip(t.iter_mut()).zip(r) {
                *total += w * r_row;
                for (value, d_c) in t_row.iter_mut().zip(d) {
                    *value += w * r_row * d_c;
                }
            }
            *slot = std::array::from_fn(|row| s * w * r[row]);
        }
        for (a, (o, g)) in out.iter_mut().zip(grad).enumerate() {
            for row in 0..D {
                let tg = dot(&t[row], g);
                o[row] -= s * tg;
                if a == 0 {
                    o[row] -= s * sum[row];
                }
            }
        }
    }
}
