//! The normal equations of one search image from sums over the patch: the template's
//! (fixed per point) and the resampled search patch's (per iteration).

use super::dense::MAX;
use super::dots::dots;
use super::gauss_newton::State;
use super::sample::TemplatePatch;

const U: usize = MAX;

/// The per-iteration sums over the resampled search patch `S`: `sum g S` (6 geometric
/// columns), `sum S`, `sum S^2`, `sum S T` (weighted sums when the patch is weighted: the
/// samples are then already scaled by the root weights).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Sums {
    pub geo_search: [f64; 6],
    pub search: f64,
    pub search_square: f64,
    pub search_value: f64,
}

impl Sums {
    pub fn new(patch: &TemplatePatch, samples: &[f32]) -> Self {
        let n = patch.len();
        let g = |k: usize| &patch.geo[k * n..(k + 1) * n];
        // One pass for the nine sums (`dots`: the same bits as nine `dot`s); `sum S` is
        // the dot product with the unit weights when the patch is not weighted.
        let [g0, g1, g2, g3, g4, g5, search, search_square, search_value] = dots([
            (g(0), samples),
            (g(1), samples),
            (g(2), samples),
            (g(3), samples),
            (g(4), samples),
            (g(5), samples),
            (patch.weights(), samples),
            (samples, samples),
            (samples, &patch.value),
        ]);
        Self {
            geo_search: [g0, g1, g2, g3, g4, g5],
            search,
            search_square,
            search_value,
        }
    }

    /// The normal matrix `G^T G`, rows of `G` = `[g (6), S, 1]`.
    pub fn normal(&self, patch: &TemplatePatch) -> [[f64; U]; U] {
        let mut m = [[0.0; U]; U];
        for k in 0..6 {
            m[k][..6].copy_from_slice(&patch.geo_normal[k * 6..k * 6 + 6]);
            m[k][6] = self.geo_search[k];
            m[k][7] = patch.geo_sum[k];
            m[6][k] = self.geo_search[k];
            m[7][k] = patch.geo_sum[k];
        }
        m[6][6] = self.search_square;
        m[6][7] = self.search;
        m[7][6] = self.search;
        m[7][7] = patch.weight_total;
        m
    }

    /// `G^T e` with the residual `e = T - offset - gain S`.
    pub fn gradient(&self, patch: &TemplatePatch, state: &State) -> [f64; U] {
        let (g, o) = (state.gain, state.offset);
        let mut r = [0.0; U];
        for k in 0..6 {
            r[k] = patch.geo_value[k] - o * patch.geo_sum[k] - g * self.geo_search[k];
        }
        r[6] = self.search_value - o * self.search - g * self.search_square;
        r[7] = patch.value_sum - o * patch.weight_total - g * self.search;
        r
    }

    /// `e^T e` from the sums (for weights only: it cancels digits).
    pub fn residual_square(&self, patch: &TemplatePatch, state: &State) -> f64 {
        let (g, o, n) = (state.gain, state.offset, patch.weight_total);
        patch.value_square - 2.0 * o * patch.value_sum - 2.0 * g * self.search_value
            + n * o * o
            + 2.0 * o * g * self.search
            + g * g * self.search_square
    }
}
