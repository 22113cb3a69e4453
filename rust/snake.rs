//! Closed active contours (Kass, Witkin, Terzopoulos 1988; SPEC 8): a polygon pulled up the
//! slope of an attraction image (the disparity-filtered gradient) and held together by
//! elasticity `α |x'|²` and rigidity `β |x''|²`, by the semi-implicit scheme
//! `(A + γ I) x_{t+1} = γ x_t + κ ∇G(x_t)`, `A` the circulant pentadiagonal matrix of the
//! internal energy.
//!
//! Unlike scikit-image's `active_contour` (a fixed number of points), the contour is
//! resampled to a target spacing whenever a segment leaves `[min_spacing, max_spacing]`,
//! so a contour that stretches over a limb keeps its resolution, and one that shrinks to
//! nothing is reported as collapsed rather than returned.
//!
//! `A + γ I` is circulant for uniform spacing, so its inverse is circulant too: its first
//! row is computed once per resampling by a direct cosine sum (eigenvalues
//! `γ + α (2 - 2 cos θ) + β (2 - 2 cos θ)²`) and, since it decays geometrically away from
//! the diagonal, applied as a band.

use crate::{Error, Result};

/// Options of [`active_contour`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SnakeOptions {
    /// Elasticity `α` (per pixel of spacing²): resists stretching.
    pub alpha: f64,
    /// Rigidity `β`: resists bending.
    pub beta: f64,
    /// Step damping `γ`: larger is slower and steadier.
    pub gamma: f64,
    /// Weight `κ` of the attraction image's gradient.
    pub kappa: f64,
    /// Largest move of a point per iteration, pixels.
    pub max_move: f64,
    /// Target spacing of the points, pixels.
    pub spacing: f64,
    /// Segments shorter than this trigger a resampling.
    pub min_spacing: f64,
    /// Segments longer than this trigger a resampling.
    pub max_spacing: f64,
    /// Iteration cap.
    pub max_iterations: usize,
    /// Converged when no point moved more than this (pixels) over `window` iterations.
    pub tolerance: f64,
    /// Iterations over which convergence is judged.
    pub window: usize,
    /// A contour whose area (pixels²) falls below this has collapsed.
    pub min_area: f64,
}

impl Default for SnakeOptions {
    fn default() -> Self {
        Self {
            alpha: 0.05,
            beta: 0.5,
            gamma: 1.0,
            kappa: 2.0,
            max_move: 1.0,
            spacing: 3.0,
            min_spacing: 1.5,
            max_spacing: 6.0,
            max_iterations: 300,
            tolerance: 0.1,
            window: 10,
            min_area: 50.0,
        }
    }
}

/// Why the contour stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SnakeStatus {
    /// Points moved less than the tolerance over the window.
    Converged,
    /// The iteration cap was reached.
    MaxIterations,
    /// The area fell below `min_area` or fewer than 4 points were left.
    Collapsed,
}

/// The contour after the iterations.
#[derive(Debug, Clone, PartialEq)]
pub struct SnakeResult {
    /// Points `(x, y)` = (column, row), pixels; empty when collapsed.
    pub points: Vec<[f64; 2]>,
    /// Outcome.
    pub status: SnakeStatus,
    /// Iterations run.
    pub iterations: usize,
    /// Resamplings done.
    pub resamplings: usize,
}

/// A row-major `(height, width)` attraction image, sampled with bilinear interpolation of
/// its central-difference gradient.
struct Image<'a> {
    values: &'a [f64],
    width: usize,
    height: usize,
}

impl Image<'_> {
    fn at(&self, x: isize, y: isize) -> f64 {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        self.values[y * self.width + x]
    }

    fn gradient_at(&self, x: isize, y: isize) -> [f64; 2] {
        [
            0.5 * (self.at(x + 1, y) - self.at(x - 1, y)),
            0.5 * (self.at(x, y + 1) - self.at(x, y - 1)),
        ]
    }

    /// `∇G` at `(x, y)`, bilinear between the four surrounding pixels.
    fn gradient(&self, p: [f64; 2]) -> [f64; 2] {
        let (fx, fy) = (p[0].floor(), p[1].floor());
        let (tx, ty) = (p[0] - fx, p[1] - fy);
        let (x0, y0) = (fx as isize, fy as isize);
        let g00 = self.gradient_at(x0, y0);
        let g10 = self.gradient_at(x0 + 1, y0);
        let g01 = self.gradient_at(x0, y0 + 1);
        let g11 = self.gradient_at(x0 + 1, y0 + 1);
        std::array::from_fn(|k| {
            (1.0 - ty) * ((1.0 - tx) * g00[k] + tx * g10[k])
                + ty * ((1.0 - tx) * g01[k] + tx * g11[k])
        })
    }
}

/// Signed area of a closed polygon (shoelace), pixels².
pub fn polygon_area(points: &[[f64; 2]]) -> f64 {
    let n = points.len();
    0.5 * (0..n)
        .map(|i| {
            let (a, b) = (points[i], points[(i + 1) % n]);
            a[0] * b[1] - b[0] * a[1]
        })
        .sum::<f64>()
}

/// The closed polygon resampled at equal arc-length steps of about `spacing`.
pub fn resample(points: &[[f64; 2]], spacing: f64) -> Vec<[f64; 2]> {
    let n = points.len();
    let mut cumulative = Vec::with_capacity(n + 1);
    cumulative.push(0.0);
    for i in 0..n {
        let (a, b) = (points[i], points[(i + 1) % n]);
        let last = *cumulative.last().unwrap_or(&0.0);
        cumulative.push(last + ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt());
    }
    let perimeter = cumulative[n];
    let count = ((perimeter / spacing).round() as usize).max(4);
    let step = perimeter / count as f64;
    let mut out = Vec::with_capacity(count);
    let mut segment = 0;
    for k in 0..count {
        let s = k as f64 * step;
        while segment + 1 < n && cumulative[segment + 1] < s {
            segment += 1;
        }
        let length = cumulative[segment + 1] - cumulative[segment];
        let t = if length > 0.0 {
            (s - cumulative[segment]) / length
        } else {
            0.0
        };
        let (a, b) = (points[segment], points[(segment + 1) % n]);
        out.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
    }
    out
}

/// The band of the first row of `(A + γ I)^{-1}` for `n` points: entries `c_0 .. c_K`
/// (symmetric: `c_{-j} = c_j`) down to `1e-10 c_0`.
fn inverse_band(n: usize, options: &SnakeOptions) -> Vec<f64> {
    let (a, b, g) = (options.alpha, options.beta, options.gamma);
    let inverse_eigen: Vec<f64> = (0..n)
        .map(|k| {
            let c = 2.0 - 2.0 * (std::f64::consts::TAU * k as f64 / n as f64).cos();
            1.0 / (g + a * c + b * c * c)
        })
        .collect();
    let mut band = Vec::new();
    for j in 0..=n / 2 {
        let theta = std::f64::consts::TAU * j as f64 / n as f64;
        let value = inverse_eigen
            .iter()
            .enumerate()
            .map(|(k, v)| v * (theta * k as f64).cos())
            .sum::<f64>()
            / n as f64;
        if j > 0 && value.abs() < 1e-10 * band[0] {
            break;
        }
        band.push(value);
    }
    band
}

fn check(
    values: &[f64],
    width: usize,
    height: usize,
    init: &[[f64; 2]],
    o: &SnakeOptions,
) -> Result<()> {
    if width < 2 || height < 2 || values.len() != width * height {
        return Err(Error::WrongLength {
            argument: "image",
            expected: width.max(2) * height.max(2),
            got: values.len(),
        });
    }
    if init.len() < 3 {
        return Err(Error::Empty {
            argument: "init",
            needed: 3,
        });
    }
    crate::error::check_finite("init", init)?;
    if let Some(row) = values.iter().position(|v| !v.is_finite()) {
        return Err(Error::NonFinite {
            argument: "image",
            row,
        });
    }
    let positive = [
        ("gamma", o.gamma),
        ("spacing", o.spacing),
        ("max_move", o.max_move),
        ("min_spacing", o.min_spacing),
    ];
    for (argument, value) in positive {
        if !(value.is_finite() && value > 0.0) {
            return Err(Error::InvalidOption {
                argument,
                value,
                expected: "positive and finite",
            });
        }
    }
    for (argument, value) in [("alpha", o.alpha), ("beta", o.beta), ("kappa", o.kappa)] {
        if !(value.is_finite() && value >= 0.0) {
            return Err(Error::InvalidOption {
                argument,
                value,
                expected: "non-negative and finite",
            });
        }
    }
    if !(o.max_spacing > o.spacing && o.spacing > o.min_spacing) {
        return Err(Error::InvalidOption {
            argument: "spacing",
            value: o.spacing,
            expected: "between min_spacing and max_spacing",
        });
    }
    Ok(())
}

/// Runs the active contour from the closed polygon `init` (points `(x, y)`, pixels) on the
/// attraction image `values` (row-major `height x width`; the contour climbs it).
///
/// # Errors
/// [`Error::WrongLength`] for an image of the wrong size, [`Error::Empty`] for fewer than
/// three points, [`Error::NonFinite`], [`Error::InvalidOption`] for bad options. A
/// collapse is a status, not an error.
pub fn active_contour(
    values: &[f64],
    width: usize,
    height: usize,
    init: &[[f64; 2]],
    options: &SnakeOptions,
) -> Result<SnakeResult> {
    check(values, width, height, init, options)?;
    let image = Image {
        values,
        width,
        height,
    };
    let (w, h) = ((width - 1) as f64, (height - 1) as f64);
    let mut x = resample(init, options.spacing);
    let mut band = inverse_band(x.len(), options);
    let mut rhs = vec![[0.0; 2]; x.len()];
    let mut moved = Vec::with_capacity(options.window);
    let mut resamplings = 0;
    let collapsed = |x: &[[f64; 2]]| x.len() < 4 || polygon_area(x).abs() < options.min_area;
    for iteration in 1..=options.max_iterations {
        if collapsed(&x) {
            return Ok(SnakeResult {
                points: Vec::new(),
                status: SnakeStatus::Collapsed,
                iterations: iteration - 1,
                resamplings,
            });
        }
        let n = x.len();
        for (r, p) in rhs.iter_mut().zip(&x) {
            let g = image.gradient(*p);
            *r = [
                options.gamma * p[0] + options.kappa * g[0],
                options.gamma * p[1] + options.kappa * g[1],
            ];
        }
        let reach = (band.len() - 1).min(n / 2);
        let mut largest = 0.0f64;
        let next: Vec<[f64; 2]> = (0..n)
            .map(|i| {
                let mut v = [band[0] * rhs[i][0], band[0] * rhs[i][1]];
                for (j, c) in band.iter().enumerate().take(reach + 1).skip(1) {
                    let (a, b) = (&rhs[(i + j) % n], &rhs[(i + n - j) % n]);
                    // For even n the opposite entry j = n/2 is one element, not two.
                    let weight = if 2 * j == n { 0.5 * c } else { *c };
                    v[0] += weight * (a[0] + b[0]);
                    v[1] += weight * (a[1] + b[1]);
                }
                let (dx, dy) = (v[0] - x[i][0], v[1] - x[i][1]);
                let step = (dx * dx + dy * dy).sqrt();
                let scale = if step > options.max_move {
                    options.max_move / step
                } else {
                    1.0
                };
                largest = largest.max(step.min(options.max_move));
                [
                    (x[i][0] + scale * dx).clamp(0.0, w),
                    (x[i][1] + scale * dy).clamp(0.0, h),
                ]
            })
            .collect();
        x = next;
        let out_of_bounds = (0..x.len()).any(|i| {
            let (a, b) = (x[i], x[(i + 1) % x.len()]);
            let d = ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
            d < options.min_spacing || d > options.max_spacing
        });
        if out_of_bounds {
            x = resample(&x, options.spacing);
            band = inverse_band(x.len(), options);
            rhs.resize(x.len(), [0.0; 2]);
            resamplings += 1;
        }
        moved.push(largest);
        if moved.len() > options.window {
            moved.remove(0);
        }
        if moved.len() == options.window && moved.iter().all(|m| *m < options.tolerance) {
            return Ok(finish(
                x,
                SnakeStatus::Converged,
                iteration,
                resamplings,
                &collapsed,
            ));
        }
    }
    Ok(finish(
        x,
        SnakeStatus::MaxIterations,
        options.max_iterations,
        resamplings,
        &collapsed,
    ))
}

fn finish(
    x: Vec<[f64; 2]>,
    status: SnakeStatus,
    iterations: usize,
    resamplings: usize,
    collapsed: &dyn Fn(&[[f64; 2]]) -> bool,
) -> SnakeResult {
    if collapsed(&x) {
        return SnakeResult {
            points: Vec::new(),
            status: SnakeStatus::Collapsed,
            iterations,
            resamplings,
        };
    }
    SnakeResult {
        points: x,
        status,
        iterations,
        resamplings,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn circle(cx: f64, cy: f64, r: f64, n: usize) -> Vec<[f64; 2]> {
        (0..n)
            .map(|k| {
                let t = std::f64::consts::TAU * k as f64 / n as f64;
                [cx + r * t.cos(), cy + r * t.sin()]
            })
            .collect()
    }

    /// An attraction ridge on the circle of radius 30 about (50, 50), width ~3 px.
    fn ring() -> Vec<f64> {
        (0..100 * 100)
            .map(|i| {
                let (x, y) = ((i % 100) as f64, (i / 100) as f64);
                let d = ((x - 50.0).powi(2) + (y - 50.0).powi(2)).sqrt() - 30.0;
                (-d * d / 18.0).exp()
            })
            .collect()
    }

    #[test]
    fn band_inverts_the_circulant_matrix() {
        let o = SnakeOptions::default();
        let n = 40;
        let band = inverse_band(n, &o);
        // (A + γI) times the inverse's first row is the first unit vector.
        let c = |j: isize| {
            let j = j.unsigned_abs() % n;
            let j = j.min(n - j);
            band.get(j).copied().unwrap_or(0.0)
        };
        let (a, b, g) = (o.alpha, o.beta, o.gamma);
        let stencil = [(0, g + 2.0 * a + 6.0 * b), (1, -a - 4.0 * b), (2, b)];
        for i in 0..n as isize {
            let mut v = stencil[0].1 * c(i);
            for &(k, s) in &stencil[1..] {
                v += s * (c(i + k) + c(i - k));
            }
            assert!(
                (v - if i == 0 { 1.0 } else { 0.0 }).abs() < 1e-9,
                "row {i}: {v}"
            );
        }
    }

    #[test]
    fn converges_to_a_ring_from_inside_and_outside() {
        let image = ring();
        for r0 in [24.0, 36.0] {
            let result = active_contour(
                &image,
                100,
                100,
                &circle(50.0, 50.0, r0, 30),
                &SnakeOptions::default(),
            )
            .unwrap();
            assert_eq!(result.status, SnakeStatus::Converged);
            for p in &result.points {
                let r = ((p[0] - 50.0).powi(2) + (p[1] - 50.0).powi(2)).sqrt();
                assert!((r - 30.0).abs() < 1.0, "start {r0}: point at radius {r}");
            }
        }
    }

    #[test]
    fn collapse_is_reported() {
        let flat = vec![0.0; 100 * 100];
        let options = SnakeOptions {
            alpha: 2.0,
            min_area: 200.0,
            max_iterations: 2000,
            ..SnakeOptions::default()
        };
        let result =
            active_contour(&flat, 100, 100, &circle(50.0, 50.0, 20.0, 40), &options).unwrap();
        assert_eq!(result.status, SnakeStatus::Collapsed);
        assert!(result.points.is_empty());
    }

    #[test]
    fn bad_input_is_an_error() {
        let o = SnakeOptions::default();
        assert!(active_contour(&[0.0; 10], 100, 100, &circle(5.0, 5.0, 3.0, 8), &o).is_err());
        assert!(active_contour(&vec![0.0; 100], 10, 10, &[[1.0, 1.0], [2.0, 2.0]], &o).is_err());
        assert!(active_contour(
            &vec![0.0; 100],
            10,
            10,
            &[[f64::NAN, 1.0], [2.0, 2.0], [3.0, 1.0]],
            &o
        )
        .is_err());
    }
}
