//! The body fit as a block-arrowhead least-squares problem: per-frame motion, shared shape
//! (SPEC 6), with part assignment and outlier rejection redone every few iterations.

use std::sync::atomic::AtomicU64;

use nalgebra::Vector3;
use rayon::prelude::*;

use super::field::Field;
use super::normal::{Blocks, PartMap};
use super::observe::{Observations, Residual, SKIN_LEVEL};
use super::skeleton::{check_vector, Skeleton};
use crate::lm::{levenberg_marquardt, ArrowNormal, ArrowProblem, LmOptions, LmReport};
use crate::ordered::sum_chunks;
use crate::Result;

/// Residuals per chunk of the cost's sum and of the normal equations' accumulators: a
/// fixed split, so both round the same on any thread count ([`crate::ordered`]). A
/// residual's cost is a field evaluation (tens of balls), its row hundreds of flops; an
/// accumulator is tens of kilobytes to zero and merge, so its chunk is larger.
const COST_CHUNK: usize = 256;
const LINEARIZE_CHUNK: usize = 1024;

/// Shape coefficients are kept in this range (half to twice the described part): a part
/// cannot shrink to nothing, nor swell over its neighbours' observations.
pub const SHAPE_RANGE: (f64, f64) = (0.5, 2.0);

/// Largest trusted change per iteration of a translation (metres), an angle (radians) and
/// a shape coefficient: the field is exponential in the state, so a Gauss-Newton step
/// computed far from the data can throw a part out of reach of its observations, after
/// which nothing pulls it back.
pub const TRUST: (f64, f64, f64) = (0.1, 0.3, 0.1);

/// Options of [`fit`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitOptions {
    /// Levenberg-Marquardt stopping rules and refresh period.
    pub lm: LmOptions,
    /// Estimate the shape (true) or keep the given one (false).
    pub fit_shape: bool,
    /// Points and rays whose approximate distance to the skin, `|F - T| / |∇F|`, exceeds
    /// this (metres) are rejected at each refresh after the first; `None`: three robust
    /// standard deviations (1.4826 MAD) of the current distances, at least 5 mm.
    pub outlier_distance: Option<f64>,
}

/// The fitted state and what the fit decided about each observation.
#[derive(Debug, Clone)]
pub struct FitResult {
    /// Motion per frame, `frames * n_motion`.
    pub motion: Vec<f64>,
    /// Shape, `4 P`.
    pub shape: Vec<f64>,
    /// Solver outcome.
    pub report: LmReport,
    /// Part assigned to each point (largest field contribution).
    pub point_part: Vec<usize>,
    /// Whether each point was kept (not an outlier).
    pub point_inlier: Vec<bool>,
    /// Part assigned to each ray.
    pub ray_part: Vec<usize>,
    /// Whether each ray was kept.
    pub ray_inlier: Vec<bool>,
}

/// The problem the solver sees.
pub struct BodyProblem<'a> {
    skeleton: &'a Skeleton,
    obs: &'a Observations,
    by_frame: Vec<Vec<Residual>>,
    fixed_shape: Option<Vec<f64>>,
    lower: Vec<f64>,
    upper: Vec<f64>,
    outlier_distance: Option<f64>,
    point_part: Vec<usize>,
    point_inlier: Vec<bool>,
    ray_part: Vec<usize>,
    ray_inlier: Vec<bool>,
    point_balls: Vec<Vec<u16>>,
    ray_balls: Vec<Vec<u16>>,
    /// See [`super::normal::HESSIAN_SHARE`].
    hessian_share: f64,
    /// `s*` of each ray at the last linearisation (f64 bits; NaN: search from scratch).
    ray_start: Vec<AtomicU64>,
}

/// Balls farther than `BOUND + BALL_MARGIN` radii from an observation at a refresh are left
/// out of its residual until the next one: the state moves far less than that in
/// `refresh_every` trust-region-limited iterations, and a point near a limb then sums a
/// handful of balls instead of all of them.
pub const BALL_MARGIN: f64 = 0.5;

impl<'a> BodyProblem<'a> {
    /// Leaves parts below `share` of an observation's largest derivative out of `J^T J`
    /// (0: the exact Gauss-Newton matrix; see [`super::normal::HESSIAN_SHARE`]).
    #[must_use]
    pub fn with_hessian_share(mut self, share: f64) -> Self {
        self.hessian_share = share;
        self
    }

    fn m(&self) -> usize {
        self.skeleton.n_motion
    }

    /// Shape unknowns the solver sees: one per group of tied coefficients.
    fn s(&self) -> usize {
        if self.fixed_shape.is_some() {
            0
        } else {
            self.obs.shape_groups(self.skeleton.n_shape())
        }
    }

    /// Shape coefficients the field is built from (`4 P`).
    fn s_full(&self) -> usize {
        if self.fixed_shape.is_some() {
            0
        } else {
            self.skeleton.n_shape()
        }
    }

    fn shape<'x>(&'x self, x: &'x [f64]) -> std::borrow::Cow<'x, [f64]> {
        match &self.fixed_shape {
            Some(shape) => std::borrow::Cow::Borrowed(shape),
            None => {
                let tied = &x[self.obs.frames * self.m()..];
                if self.obs.shape_group.is_empty() {
                    std::borrow::Cow::Borrowed(tied)
                } else {
                    std::borrow::Cow::Owned(self.obs.expand_shape(tied))
                }
            }
        }
    }

    fn field(&self, x: &[f64], f: usize) -> Result<Field<'a>> {
        let m = self.m();
        let pose = self.skeleton.pose(&self.shape(x), &x[f * m..(f + 1) * m])?;
        Ok(Field::new(self.skeleton, pose))
    }

    fn subset(&self, r: &Residual) -> Option<&[u16]> {
        match *r {
            Residual::Point(i) => self.point_balls.get(i).map(|v| v.as_slice()),
            Residual::Ray(i) => self.ray_balls.get(i).map(|v| v.as_slice()),
            Residual::Joint(..) => None,
        }
    }

    fn start(&self, r: &Residual) -> Option<&AtomicU64> {
        match *r {
            Residual::Ray(i) => self.ray_start.get(i),
            _ => None,
        }
    }

    /// `1/2 sum w_g (s_g - 1)^2` over the shape unknowns (0 without a prior, or with the
    /// shape held).
    fn prior_cost(&self, x: &[f64]) -> f64 {
        if self.obs.shape_sigma.is_none() || self.s() == 0 {
            return 0.0;
        }
        let fm = self.obs.frames * self.m();
        x[fm..]
            .iter()
            .enumerate()
            .map(|(g, v)| 0.5 * self.obs.shape_prior_weight(g) * (v - 1.0) * (v - 1.0))
            .sum()
    }

    /// Whether shape unknown `g` is held (its bounds meet).
    fn held(&self, g: usize) -> bool {
        let (lo, hi) = self.obs.shape_bounds(g);
        lo >= hi
    }

    fn kept(&self, r: &Residual) -> bool {
        match *r {
            Residual::Point(i) => self.point_inlier[i],
            Residual::Ray(i) => self.ray_inlier[i],
            Residual::Joint(..) => true,
        }
    }
}

impl ArrowProblem for BodyProblem<'_> {
    fn dims(&self) -> (usize, usize, usize) {
        (self.obs.frames, self.m(), self.s())
    }

    fn cost(&self, x: &[f64]) -> Result<f64> {
        let mut cost = self.prior_cost(x);
        for f in 0..self.obs.frames {
            let field = self.field(x, f)?;
            // Fixed chunks summed in order (crate::ordered): the step's acceptance compares
            // this cost, so it must round the same on any thread count.
            let residuals = &self.by_frame[f];
            cost += sum_chunks(residuals.len(), COST_CHUNK, |range| {
                residuals[range]
                    .iter()
                    .filter(|r| self.kept(r))
                    .map(|r| {
                        let v = r.evaluate(self.obs, &field, self.subset(r), self.start(r), None);
                        0.5 * v * v
                    })
                    .sum::<f64>()
            });
        }
        Ok(cost)
    }

    fn linearize(&self, x: &[f64], normal: &mut ArrowNormal) -> Result<f64> {
        normal.clear();
        let (m, s, reduced) = (self.m(), self.s_full(), self.s());
        let group = |k: usize| self.obs.shape_group.get(k).copied().unwrap_or(k);
        let width = self.skeleton.n_motion + self.skeleton.n_shape();
        let mut cost = 0.0;
        for f in 0..self.obs.frames {
            let field = self.field(x, f)?;
            let map = PartMap::new(&field, m + s);
            let parts = self.skeleton.n_parts();
            // Accumulators of fixed chunks of residuals, merged in order (crate::ordered): a
            // fold / reduce would follow rayon's adaptive split, and the normal equations
            // would round differently on another thread count.
            let chunks: Vec<Blocks> = self.by_frame[f]
                .par_chunks(LINEARIZE_CHUNK)
                .map(|chunk| {
                    chunk.iter().filter(|r| self.kept(r)).fold(
                        Blocks::new(m, s, width, parts, self.hessian_share),
                        |mut acc, residual| {
                            let mut terms = std::mem::take(&mut acc.terms);
                            let compact = residual.evaluate_parts(
                                self.obs,
                                &field,
                                self.subset(residual),
                                self.start(residual),
                                &map.reference,
                                &mut terms,
                            );
                            acc.terms = terms;
                            match compact {
                                Some(r) => acc.accumulate_parts(r),
                                None => {
                                    let mut row = std::mem::take(&mut acc.row);
                                    let r = residual.evaluate(
                                        self.obs,
                                        &field,
                                        None,
                                        None,
                                        Some(&mut row),
                                    );
                                    acc.row = row;
                                    acc.accumulate(r, m, s);
                                }
                            }
                            acc
                        },
                    )
                })
                .collect();
            let mut blocks = chunks
                .into_iter()
                .reduce(Blocks::merge)
                .unwrap_or_else(|| Blocks::new(m, s, 0, parts, 0.0));
            blocks.finish(&map, m, s);
            normal.a[f * m * m..(f + 1) * m * m].copy_from_slice(&blocks.a);
            normal.g[f * m..(f + 1) * m].copy_from_slice(&blocks.g[..m]);
            // Tied coefficients (one group's columns summed: J T with T the 0/1 map from
            // groups to coefficients) enter as one unknown.
            let fm = self.obs.frames * m;
            for i in 0..m {
                for k in 0..s {
                    normal.b[f * m * reduced + i * reduced + group(k)] += blocks.b[i * s + k];
                }
            }
            for k in 0..s {
                for l in 0..s {
                    normal.c[group(k) * reduced + group(l)] += blocks.c[k * s + l];
                }
                normal.g[fm + group(k)] += blocks.g[m + k];
            }
            cost += blocks.cost;
        }
        // The shape prior: residual sqrt(w) (s - 1) per unknown, so J^T J gains w on the
        // diagonal and J^T r gains w (s - 1).
        if self.obs.shape_sigma.is_some() && reduced > 0 {
            let fm = self.obs.frames * m;
            for g in 0..reduced {
                let w = self.obs.shape_prior_weight(g);
                normal.c[g * reduced + g] += w;
                normal.g[fm + g] += w * (x[fm + g] - 1.0);
            }
            cost += self.prior_cost(x);
        }
        // A shape unknown whose bounds meet is held exactly: its row and column leave the
        // normal equations (unit diagonal, zero gradient), so its step is 0 and the others'
        // steps are solved without it. Clamping it after a free step instead (what `project`
        // alone did) moved every other coefficient by a step computed as if it had moved
        // too, and the fit converged worse (family `width` held so: 15.0 mm against 12.2 mm
        // tied, benches/README.md, branch body4).
        if reduced > 0 {
            let fm = self.obs.frames * m;
            for g in (0..reduced).filter(|&g| self.held(g)) {
                for f in 0..self.obs.frames {
                    for i in 0..m {
                        normal.b[f * m * reduced + i * reduced + g] = 0.0;
                    }
                }
                for l in 0..reduced {
                    normal.c[g * reduced + l] = 0.0;
                    normal.c[l * reduced + g] = 0.0;
                }
                normal.c[g * reduced + g] = 1.0;
                normal.g[fm + g] = 0.0;
            }
        }
        Ok(cost)
    }

    fn project(&self, x: &mut [f64]) {
        let m = self.m();
        let fm = self.obs.frames * m;
        for (i, v) in x[..fm].iter_mut().enumerate() {
            let k = i % m;
            *v = v.clamp(self.lower[k], self.upper[k]);
        }
        for (k, v) in x[fm..].iter_mut().enumerate() {
            let (lo, hi) = self.obs.shape_bounds(k);
            *v = v.clamp(lo, hi);
        }
    }

    fn trusted(&self, step: &[f64]) -> bool {
        let m = self.m();
        let fm = self.obs.frames * m;
        step[..fm].iter().enumerate().all(|(i, d)| {
            let limit = if i % m < 3 { TRUST.0 } else { TRUST.1 };
            d.abs() <= limit
        }) && step[fm..].iter().all(|d| d.abs() <= TRUST.2)
    }

    fn refresh(&mut self, x: &[f64], round: usize) -> Result<()> {
        let frames = self.obs.frames;
        let fields: Vec<Field<'_>> = (0..frames)
            .map(|f| self.field(x, f))
            .collect::<Result<_>>()?;
        for start in &self.ray_start {
            start.store(f64::NAN.to_bits(), std::sync::atomic::Ordering::Relaxed);
        }
        self.point_balls = (0..self.obs.points.len())
            .into_par_iter()
            .map(|i| {
                fields[self.obs.point_frame[i]]
                    .near_balls(&Vector3::from(self.obs.points[i]), BALL_MARGIN)
            })
            .collect();
        self.ray_balls = (0..self.obs.origins.len())
            .into_par_iter()
            .map(|i| {
                let o = Vector3::from(self.obs.origins[i]);
                let r = Vector3::from(self.obs.directions[i]);
                super::ray::ray_near_balls(&fields[self.obs.ray_frame[i]], &o, &r, BALL_MARGIN)
            })
            .collect();
        // (part, approximate distance |F - T| / |∇F|) per point and per ray.
        let measure = |field: &Field<'_>, x: Vector3<f64>| {
            let (part, _) = field.strongest_part(&x);
            let (f, g, _) = field.value_gradient_hessian(&x);
            let distance = if f < 1e-8 {
                f64::INFINITY
            } else {
                (f - SKIN_LEVEL).abs() / g.norm().max(1e-300)
            };
            (part, distance)
        };
        let points: Vec<(usize, f64)> = (0..self.obs.points.len())
            .into_par_iter()
            .map(|i| {
                measure(
                    &fields[self.obs.point_frame[i]],
                    Vector3::from(self.obs.points[i]),
                )
            })
            .collect();
        let rays: Vec<(usize, f64)> = (0..self.obs.origins.len())
            .into_par_iter()
            .map(|i| {
                let field = &fields[self.obs.ray_frame[i]];
                let o = Vector3::from(self.obs.origins[i]);
                let r = Vector3::from(self.obs.directions[i]);
                let max = ray_maximum_point(field, &o, &r);
                match max {
                    Some(x) => measure(field, x),
                    None => (0, f64::INFINITY),
                }
            })
            .collect();
        self.point_part = points.iter().map(|p| p.0).collect();
        self.ray_part = rays.iter().map(|p| p.0).collect();
        // The first round only drops what carries no information (no field there: zero
        // gradient); distances are judged once the state has moved towards the data.
        let limit = |set: &[(usize, f64)]| {
            if round == 0 {
                f64::MAX
            } else {
                self.outlier_distance
                    .unwrap_or_else(|| (3.0 * 1.4826 * median(set.iter().map(|p| p.1))).max(5e-3))
            }
        };
        // One-sided rays (inside / outside the silhouette) are never outliers: far from
        // the skin is what most of them are, and their residual is bounded.
        let outline: Vec<(usize, f64)> = rays
            .iter()
            .enumerate()
            .filter(|(i, _)| self.obs.side(*i) == 0)
            .map(|(_, p)| *p)
            .collect();
        let (lp, lr) = (limit(&points), limit(&outline));
        self.point_inlier = points.iter().map(|p| p.1 <= lp).collect();
        self.ray_inlier = rays
            .iter()
            .enumerate()
            .map(|(i, p)| self.obs.side(i) != 0 || p.1 <= lr)
            .collect();
        Ok(())
    }
}

fn ray_maximum_point(
    field: &Field<'_>,
    o: &Vector3<f64>,
    r: &Vector3<f64>,
) -> Option<Vector3<f64>> {
    let max = super::ray::ray_maximum(field, o, r);
    max.hit.then_some(max.point)
}

fn median(values: impl Iterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.filter(|d| d.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// A problem set up for the solver (exposed for the benchmark of one iteration).
///
/// # Errors
/// Invalid observations, limits or initial state.
pub fn problem<'a>(
    skeleton: &'a Skeleton,
    obs: &'a Observations,
    shape: &[f64],
    limits: (&[f64], &[f64]),
    options: &FitOptions,
) -> Result<BodyProblem<'a>> {
    obs.validate(skeleton)?;
    check_vector("shape", shape, skeleton.n_shape())?;
    check_vector("lower", limits.0, skeleton.n_motion)?;
    check_vector("upper", limits.1, skeleton.n_motion)?;
    let mut by_frame: Vec<Vec<Residual>> = (0..obs.frames).map(|_| Vec::new()).collect();
    for (i, &f) in obs.point_frame.iter().enumerate() {
        by_frame[f].push(Residual::Point(i));
    }
    for (i, &f) in obs.ray_frame.iter().enumerate() {
        by_frame[f].push(Residual::Ray(i));
    }
    for (i, &f) in obs.joint_frame.iter().enumerate() {
        for k in 0..3 {
            by_frame[f].push(Residual::Joint(i, k));
        }
    }
    Ok(BodyProblem {
        skeleton,
        obs,
        by_frame,
        fixed_shape: (!options.fit_shape).then(|| shape.to_vec()),
        lower: limits.0.to_vec(),
        upper: limits.1.to_vec(),
        outlier_distance: options.outlier_distance,
        point_part: vec![0; obs.points.len()],
        point_inlier: vec![true; obs.points.len()],
        ray_part: vec![0; obs.origins.len()],
        ray_inlier: vec![true; obs.origins.len()],
        point_balls: Vec::new(),
        ray_balls: Vec::new(),
        hessian_share: super::normal::HESSIAN_SHARE,
        ray_start: (0..obs.origins.len())
            .map(|_| AtomicU64::new(f64::NAN.to_bits()))
            .collect(),
    })
}

/// Fits shape (shared) and motion (per frame) to the observations from the initial
/// `shape` and `motion` (`frames * n_motion`), within the motion limits `lower..upper`
/// (per parameter, applied to every frame).
///
/// # Errors
/// Bad input (see [`Observations::validate`], [`Skeleton::pose`]); non-convergence is
/// reported in [`FitResult::report`].
pub fn fit(
    skeleton: &Skeleton,
    obs: &Observations,
    shape: &[f64],
    motion: &[f64],
    limits: (&[f64], &[f64]),
    options: &FitOptions,
) -> Result<FitResult> {
    check_vector("motion", motion, obs.frames * skeleton.n_motion)?;
    // Motion first with the shape held, then both: started with the shape wrong by ~10%,
    // a joint first step lets small parts (feet, hands) swell to cover points that their
    // misplaced neighbours should explain, a valley they do not leave (measured; SPEC 6's
    // alternation of shape and motion).
    let motion_only = FitOptions {
        fit_shape: false,
        ..*options
    };
    let mut first = problem(skeleton, obs, shape, limits, &motion_only)?;
    let mut x = motion.to_vec();
    let mut report = levenberg_marquardt(&mut first, &mut x, &options.lm)?;
    let mut problem = first;
    if options.fit_shape {
        let mut joint = self::problem(skeleton, obs, shape, limits, options)?;
        x.extend_from_slice(&obs.group_shape(shape));
        let second = levenberg_marquardt(&mut joint, &mut x, &options.lm)?;
        report = LmReport {
            iterations: report.iterations + second.iterations,
            initial_cost: report.initial_cost,
            ..second
        };
        problem = joint;
    }
    // The assignment and inliers reported are those of the final state.
    problem.refresh(&x, usize::MAX)?;
    let fm = obs.frames * skeleton.n_motion;
    let shape = if options.fit_shape {
        obs.expand_shape(&x[fm..])
    } else {
        shape.to_vec()
    };
    Ok(FitResult {
        motion: x[..fm].to_vec(),
        shape,
        report,
        point_part: problem.point_part,
        point_inlier: problem.point_inlier,
        ray_part: problem.ray_part,
        ray_inlier: problem.ray_inlier,
    })
}
