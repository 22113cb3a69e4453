//! The precision of a match whose Jacobian is the template's (errors in variables).
//!
//! Gauss-Newton here uses the template's gradients `G` in place of the warped search
//! patch's `H` (see `gauss_newton`): the estimate solves `G^T e(p) = 0`. When the texture
//! is faint against the noise, `G` carries the template's noise: `G^T G` then exceeds
//! `G_0^T G_0` (noise-free gradients) by the noise's share, about `n sigma^2 / 2` per
//! gradient column, and `(G^T G)^-1`, the usual cofactor, is too small by that share
//! while the estimate's spread grows with it. Linearising the estimating equation instead,
//! `dp = B^-1 G^T e` with the sensitivity `B = G^T H`, gives the sandwich
//! `Cov(p) = sigma_0^2 B^-1 (G^T G) B^-T`. `H` is measured on the search image, whose
//! noise is independent of the template's, so `B` is unbiased for `G_0^T G_0` while
//! `G^T G` is not. Where the texture is strong, `H ~ G` and the sandwich is `(G^T G)^-1`.

use super::dense::{general_inverse, product, product_transposed, MAX};
use super::dots::dots_into;
use super::normal::Sums;
use super::sample::{dot, TemplatePatch};

const U: usize = MAX;

/// `B = G^T H` from the search image resampled on the template grid widened by one pixel
/// (`ring`, `(size + 2)^2` row by row), with rows `G = [g (6), S, 1]` (the template's
/// geometric columns, the search samples, one) and `H = [gain h (6), S, 1]`, where `h` are
/// the same six columns built from the central differences of the warped search patch.
/// `columns` is scratch of `6 n` values.
pub(crate) fn sensitivity(
    patch: &TemplatePatch,
    sums: &Sums,
    gain: f64,
    ring: &[f32],
    columns: &mut [f32],
) -> [[f64; U]; U] {
    let (size, n) = (patch.size, patch.len());
    let m = size + 2;
    for r in 0..size {
        for c in 0..size {
            let (i, j) = (r * size + c, (r + 1) * m + c + 1);
            let hx = 0.5 * (ring[j + 1] - ring[j - 1]);
            let hy = 0.5 * (ring[j + m] - ring[j - m]);
            let (dx, dy) = (patch.dx[i], patch.dy[i]);
            let row = [hx, hy, hx * dx, hx * dy, hy * dx, hy * dy];
            for (k, h) in row.into_iter().enumerate() {
                columns[k * n + i] = h;
            }
        }
    }
    let mut b = [[0.0; U]; U];
    // `sum g_k h_l` (36) and `sum h_l` (6, the dot product with the unit weights: this
    // path runs for unweighted patches only) side by side, eight at a time (`dots_into`:
    // the same bits as one `dot` after the other).
    let (geo, h) = (
        |k: usize| &patch.geo[k * n..(k + 1) * n],
        |l: usize| &columns[l * n..(l + 1) * n],
    );
    debug_assert!(!patch.weighted(), "the sandwich is for unweighted patches");
    let ones = patch.weights();
    let pairs: [(&[f32], &[f32]); 42] = std::array::from_fn(|i| {
        if i < 36 {
            (geo(i / 6), h(i % 6))
        } else {
            (ones, h(i - 36))
        }
    });
    let mut products = [0.0; 42];
    dots_into(&pairs, &mut products);
    for k in 0..6 {
        for l in 0..6 {
            b[k][l] = gain * products[k * 6 + l];
        }
        b[k][6] = sums.geo_search[k];
        b[k][7] = patch.geo_sum[k];
    }
    // The search samples are the ring's interior.
    for l in 0..6 {
        let h = h(l);
        let mut with_search = 0.0;
        for r in 0..size {
            let row = &ring[(r + 1) * m + 1..(r + 1) * m + 1 + size];
            with_search += dot(&h[r * size..(r + 1) * size], row);
        }
        b[6][l] = gain * with_search;
        b[7][l] = gain * products[36 + l];
    }
    b[6][6] = sums.search_square;
    b[6][7] = sums.search;
    b[7][6] = sums.search;
    b[7][7] = n as f64;
    b
}

/// The spread of the estimating equation `G^T e` over `sigma_0^2`:
/// `share sym(B) + (1 - share) G^T G`, with `share` the template's part of the residual
/// variance. The template's noise enters `G` and `e` together and its share telescopes:
/// a pixel's noise multiplies its neighbours' differences of the same noise, which sum to
/// (almost) nothing, so that part of the spread is `G_0^T G_0` (estimated by `B`), not
/// `G^T G`. The search image's noise is independent of `G`: its part is `G^T G`.
pub(crate) fn meat(b: &[[f64; U]; U], normal: &[[f64; U]; U], share: f64) -> [[f64; U]; U] {
    std::array::from_fn(|i| {
        std::array::from_fn(|j| share * 0.5 * (b[i][j] + b[j][i]) + (1.0 - share) * normal[i][j])
    })
}

/// The cofactor `M meat M^T` and the estimator's map `M` (so that a step is `M G^T e`):
/// `M = B^-1`, or with a hard constraint `c . step = h` the constrained
/// `B^-1 - B^-1 c c^T B^-1 / (c^T B^-1 c)`. `None` when `B` is singular.
pub(crate) fn sandwich(
    b: &[[f64; U]; U],
    meat: &[[f64; U]; U],
    hard: Option<[f64; U]>,
) -> Option<([[f64; U]; U], [[f64; U]; U])> {
    let mut map = general_inverse(b)?;
    if let Some(c) = hard {
        let right: [f64; U] = std::array::from_fn(|i| (0..U).map(|j| map[i][j] * c[j]).sum());
        let left: [f64; U] = std::array::from_fn(|j| (0..U).map(|i| c[i] * map[i][j]).sum());
        let through: f64 = (0..U).map(|i| c[i] * right[i]).sum();
        if !(through.abs() > 0.0) {
            return None;
        }
        for i in 0..U {
            for j in 0..U {
                map[i][j] -= right[i] * left[j] / through;
            }
        }
    }
    let mut cofactor = product_transposed(&product(&map, meat), &map);
    // Symmetric up to rounding: make it exactly so.
    for i in 0..U {
        for j in 0..i {
            let mean = 0.5 * (cofactor[i][j] + cofactor[j][i]);
            cofactor[i][j] = mean;
            cofactor[j][i] = mean;
        }
    }
    Some((cofactor, map))
}
