//! Observations of a body for the fit (SPEC 6): 3-D points on the skin, silhouette rays
//! tangent to it, optional 3-D joint positions, each type weighted by its a-priori sigma.

use nalgebra::Vector3;

use super::field::{Cutoff, Field};
use super::fit::SHAPE_RANGE;
use super::normal::PartTerms;
use super::ray::ray_maximum_over;
use super::skeleton::Skeleton;
use crate::error::check_finite;
use crate::{Error, Result};

/// The skin level `T` of SPEC 6: the skin is `F = T`.
pub const SKIN_LEVEL: f64 = 0.5;

/// Everything observed, over all frames.
#[derive(Debug, Clone, Default)]
pub struct Observations {
    /// Number of frames.
    pub frames: usize,
    /// 3-D points on the skin (world).
    pub points: Vec<[f64; 3]>,
    /// Frame of each point.
    pub point_frame: Vec<usize>,
    /// Silhouette ray origins (world).
    pub origins: Vec<[f64; 3]>,
    /// Silhouette ray directions (world, any length but not zero).
    pub directions: Vec<[f64; 3]>,
    /// Frame of each ray.
    pub ray_frame: Vec<usize>,
    /// Observed joint positions (world): the origin of a part's frame.
    pub joints: Vec<[f64; 3]>,
    /// Part whose joint each joint observation sees.
    pub joint_part: Vec<usize>,
    /// Frame of each joint observation.
    pub joint_frame: Vec<usize>,
    /// Where each joint observation sits in its part's frame (metres; a tracked surface
    /// point attached to the part, issue 15); empty: all at the part's origin (the joint).
    pub joint_offset: Vec<[f64; 3]>,
    /// Per-joint factor on `sigma[2]` (e.g. a track's standard deviation over it); empty:
    /// all 1.
    pub joint_scale: Vec<f64>,
    /// A-priori standard deviations `[point, ray, joint]`: points and rays in field units
    /// (F - T), joints in metres. Weights are `1 / sigma^2`.
    pub sigma: [f64; 3],
    /// `Some(ε)`: points and rays use `g(F) = (T + ε) ln((F + ε) / (T + ε))` instead of
    /// `F - T`. Both vanish on the skin and agree to first order there (so sigmas keep
    /// their meaning), but `F - T` goes flat a few radii from a ball, where a part that
    /// starts a few centimetres off feels no pull; `g` keeps pulling (like a squared
    /// distance) until `F` falls well below `ε`. `benches/README.md` has the measurement.
    pub log_epsilon: Option<f64>,
    /// Per-point factor on `sigma[0]` (its precision relative to the others, e.g. from
    /// stereo's covariance); empty: all 1.
    pub point_scale: Vec<f64>,
    /// Per-ray factor on `sigma[1]`; empty: all 1.
    pub ray_scale: Vec<f64>,
    /// Per-ray kind; empty: all 0. 0: an outline ray, tangent to the skin (`F* = T`);
    /// +1: a ray through a pixel inside the silhouette, which must meet the skin (only
    /// `F* < T` is penalised); -1: a ray through a pixel outside it, which must miss the
    /// skin (only `F* > T` is penalised). Outline rays alone let a limb hide inside the
    /// silhouette of the torso; the one-sided rays say where the body is and is not.
    pub ray_side: Vec<i8>,
    /// Shape unknown of each shape coefficient (`4 P`, groups numbered `0..G` with none
    /// empty); empty: each coefficient its own. Coefficients of one group are tied (e.g. a
    /// left and a right limb: a person's sides have the same proportions, and a fit free
    /// to stretch one shin and not the other explains a mis-posed leg by its shape).
    pub shape_group: Vec<usize>,
    /// Lower and upper bound of each shape coefficient (`4 P`); empty: [`SHAPE_RANGE`].
    pub shape_lower: Vec<f64>,
    /// See `shape_lower`.
    pub shape_upper: Vec<f64>,
    /// `Some(sigma)`: each shape coefficient carries a Gaussian prior about 1 (the part as
    /// described) with this standard deviation, a residual `(s - 1) / sigma`. Along a limb
    /// that does not bend in the fitted frames the skin says nothing about where one part
    /// ends and the next begins: free coefficients slide the joint along the bone (a
    /// shorter forearm under a wider, longer hand) at no cost to the skin, and the prior
    /// keeps such splits at the described proportions (`benches/README.md`, branch body6).
    pub shape_sigma: Option<f64>,
}

/// Whether a one-sided ray of kind `side` with residual `r` (of `F* - T`'s sign) is
/// satisfied, so that it adds nothing.
#[inline]
pub fn side_satisfied(side: i8, r: f64) -> bool {
    (side > 0 && r >= 0.0) || (side < 0 && r <= 0.0)
}

/// The residual of a field value `F` (weighted by `w`) and its derivative in `F`.
#[inline]
pub fn field_residual(f: f64, log_epsilon: Option<f64>) -> (f64, f64) {
    match log_epsilon {
        None => (f - SKIN_LEVEL, 1.0),
        Some(eps) => {
            let scale = SKIN_LEVEL + eps;
            (scale * ((f + eps) / scale).ln(), scale / (f + eps))
        }
    }
}

fn check_index(argument: &'static str, values: &[usize], bound: usize) -> Result<()> {
    match values.iter().position(|&v| v >= bound) {
        Some(row) => Err(Error::IndexOutOfRange {
            argument,
            row,
            value: values[row] as i64,
            bound,
        }),
        None => Ok(()),
    }
}

fn check_len(argument: &'static str, got: usize, expected: usize) -> Result<()> {
    if got == expected {
        Ok(())
    } else {
        Err(Error::WrongLength {
            argument,
            expected,
            got,
        })
    }
}

impl Observations {
    /// Shape unknowns for `n_shape` coefficients: the number of groups, else `n_shape`.
    pub fn shape_groups(&self, n_shape: usize) -> usize {
        if self.shape_group.is_empty() {
            n_shape
        } else {
            self.shape_group.iter().max().map_or(0, |g| g + 1)
        }
    }

    /// Bounds of shape unknown `g`: the tightest over the coefficients of its group.
    pub fn shape_bounds(&self, g: usize) -> (f64, f64) {
        let bound = |k: usize| {
            (
                self.shape_lower.get(k).copied().unwrap_or(SHAPE_RANGE.0),
                self.shape_upper.get(k).copied().unwrap_or(SHAPE_RANGE.1),
            )
        };
        if self.shape_group.is_empty() {
            return bound(g);
        }
        self.shape_group
            .iter()
            .enumerate()
            .filter(|(_, &h)| h == g)
            .fold((f64::MIN, f64::MAX), |(lo, hi), (k, _)| {
                let (a, b) = bound(k);
                (lo.max(a), hi.min(b))
            })
    }

    /// Weight `n / sigma^2` of the prior of shape unknown `g` (`n` coefficients tied in
    /// it; each carries its own prior), 0 without [`Observations::shape_sigma`].
    pub fn shape_prior_weight(&self, g: usize) -> f64 {
        let Some(sigma) = self.shape_sigma else {
            return 0.0;
        };
        let members = if self.shape_group.is_empty() {
            1
        } else {
            self.shape_group.iter().filter(|&&h| h == g).count()
        };
        members as f64 / (sigma * sigma)
    }

    /// The shape unknowns of the coefficients `shape`: each group's mean.
    pub fn group_shape(&self, shape: &[f64]) -> Vec<f64> {
        if self.shape_group.is_empty() {
            return shape.to_vec();
        }
        let n = self.shape_groups(shape.len());
        let (mut sum, mut count) = (vec![0.0; n], vec![0.0; n]);
        for (&g, v) in self.shape_group.iter().zip(shape) {
            sum[g] += v;
            count[g] += 1.0;
        }
        sum.iter().zip(&count).map(|(s, c)| s / c).collect()
    }

    /// The shape coefficients of the unknowns `tied` (one per group).
    pub fn expand_shape(&self, tied: &[f64]) -> Vec<f64> {
        if self.shape_group.is_empty() {
            return tied.to_vec();
        }
        self.shape_group.iter().map(|&g| tied[g]).collect()
    }

    /// The weight `1 / (sigma[0] * point_scale[i])` of point `i`.
    #[inline]
    pub fn point_weight(&self, i: usize) -> f64 {
        1.0 / (self.sigma[0] * self.point_scale.get(i).copied().unwrap_or(1.0))
    }

    /// The weight `1 / (sigma[2] * joint_scale[i])` of joint observation `i`.
    #[inline]
    pub fn joint_weight(&self, i: usize) -> f64 {
        1.0 / (self.sigma[2] * self.joint_scale.get(i).copied().unwrap_or(1.0))
    }

    /// The kind of ray `i` (see [`Observations::ray_side`]).
    #[inline]
    pub fn side(&self, i: usize) -> i8 {
        self.ray_side.get(i).copied().unwrap_or(0)
    }

    /// The weight `1 / (sigma[1] * ray_scale[i])` of ray `i`.
    #[inline]
    pub fn ray_weight(&self, i: usize) -> f64 {
        1.0 / (self.sigma[1] * self.ray_scale.get(i).copied().unwrap_or(1.0))
    }

    /// Checks lengths, indices, finiteness and sigmas.
    ///
    /// # Errors
    /// [`Error::WrongLength`], [`Error::IndexOutOfRange`], [`Error::NonFinite`],
    /// [`Error::BadRay`], [`Error::Empty`] (nothing observed), [`Error::InvalidMaterial`]
    /// is not used; a non-positive sigma gives [`Error::BadModel`].
    pub fn validate(&self, skeleton: &Skeleton) -> Result<()> {
        check_len("point_frame", self.point_frame.len(), self.points.len())?;
        check_len("directions", self.directions.len(), self.origins.len())?;
        check_len("ray_frame", self.ray_frame.len(), self.origins.len())?;
        check_len("joint_part", self.joint_part.len(), self.joints.len())?;
        check_len("joint_frame", self.joint_frame.len(), self.joints.len())?;
        if !self.point_scale.is_empty() {
            check_len("point_scale", self.point_scale.len(), self.points.len())?;
        }
        if !self.ray_scale.is_empty() {
            check_len("ray_scale", self.ray_scale.len(), self.origins.len())?;
        }
        if !self.joint_offset.is_empty() {
            check_len("joint_offset", self.joint_offset.len(), self.joints.len())?;
        }
        if !self.joint_scale.is_empty() {
            check_len("joint_scale", self.joint_scale.len(), self.joints.len())?;
        }
        if !self.ray_side.is_empty() {
            check_len("ray_side", self.ray_side.len(), self.origins.len())?;
        }
        if let Some(bad) = self
            .point_scale
            .iter()
            .chain(&self.ray_scale)
            .chain(&self.joint_scale)
            .find(|s| !(s.is_finite() && **s > 0.0))
        {
            return Err(Error::BadModel {
                reason: format!(
                    "point, ray and joint sigma scales must be positive and finite, got {bad}"
                ),
            });
        }
        if let Some(sigma) = self.shape_sigma {
            if !(sigma.is_finite() && sigma > 0.0) {
                return Err(Error::BadModel {
                    reason: format!("shape_sigma must be positive and finite, got {sigma}"),
                });
            }
        }
        let n_shape = skeleton.n_shape();
        if !self.shape_group.is_empty() {
            check_len("shape_group", self.shape_group.len(), n_shape)?;
            let groups = self.shape_groups(n_shape);
            if let Some(g) = (0..groups).find(|g| !self.shape_group.contains(g)) {
                return Err(Error::BadModel {
                    reason: format!("shape_group must number its groups 0..{groups} with none empty; group {g} is"),
                });
            }
        }
        for (name, bound) in [
            ("shape_lower", &self.shape_lower),
            ("shape_upper", &self.shape_upper),
        ] {
            if !bound.is_empty() {
                check_len(name, bound.len(), n_shape)?;
            }
        }
        if !self.shape_lower.is_empty() || !self.shape_upper.is_empty() {
            for g in 0..self.shape_groups(n_shape) {
                let (lo, hi) = self.shape_bounds(g);
                if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && lo <= hi) {
                    return Err(Error::BadModel {
                        reason: format!("shape bounds must be finite with 0 < lower <= upper (over each group), got [{lo}, {hi}] for shape unknown {g}"),
                    });
                }
            }
        }
        check_index("point_frame", &self.point_frame, self.frames)?;
        check_index("ray_frame", &self.ray_frame, self.frames)?;
        check_index("joint_frame", &self.joint_frame, self.frames)?;
        check_index("joint_part", &self.joint_part, skeleton.n_parts())?;
        check_finite("points", &self.points)?;
        check_finite("joints", &self.joints)?;
        check_finite("joint_offset", &self.joint_offset)?;
        super::check_rays(&self.origins, &self.directions)?;
        if self.points.len() + self.origins.len() + self.joints.len() == 0 || self.frames == 0 {
            return Err(Error::Empty {
                argument: "observations",
                needed: 1,
            });
        }
        if !self.log_epsilon.is_none_or(|e| e.is_finite() && e > 0.0) {
            return Err(Error::BadModel {
                reason: format!(
                    "log_epsilon must be positive and finite, got {:?}",
                    self.log_epsilon
                ),
            });
        }
        if !self.sigma.iter().all(|s| s.is_finite() && *s > 0.0) {
            return Err(Error::BadModel {
                reason: format!("sigmas must be positive and finite, got {:?}", self.sigma),
            });
        }
        Ok(())
    }
}

/// One observation's residual and (optionally) its Jacobian row, weighted by
/// `sqrt(p)`. `row` has `n_motion + n_shape` entries.
pub enum Residual {
    /// A point: `F(x) - T`.
    Point(usize),
    /// A ray: `max_s F(o + s r) - T`.
    Ray(usize),
    /// Axis `k` of a joint: `o_b[k] - observed[k]`.
    Joint(usize, usize),
}

impl Residual {
    /// The weighted residual; fills `row` (weighted Jacobian) when given. `subset` (ascending
    /// ball indices) limits the field to the balls that matter for this observation.
    pub fn evaluate(
        &self,
        obs: &Observations,
        field: &Field<'_>,
        subset: Option<&[u16]>,
        start: Option<&std::sync::atomic::AtomicU64>,
        row: Option<&mut [f64]>,
    ) -> f64 {
        match *self {
            Residual::Point(i) => {
                let w = obs.point_weight(i);
                let x = Vector3::from(obs.points[i]);
                match row {
                    Some(row) => {
                        let f = field.state_derivative_over(&x, subset, Cutoff::Bounded, row);
                        let (r, slope) = field_residual(f, obs.log_epsilon);
                        row.iter_mut().for_each(|v| *v *= w * slope);
                        w * r
                    }
                    None => w * field_residual(field.value_over(&x, subset), obs.log_epsilon).0,
                }
            }
            Residual::Ray(i) => {
                let w = obs.ray_weight(i);
                let o = Vector3::from(obs.origins[i]);
                let r = Vector3::from(obs.directions[i]);
                use std::sync::atomic::Ordering::Relaxed;
                // Warm start from the last linearisation's maximum; a linearisation (the
                // accepted state) stores its own for the next iteration.
                let previous = start
                    .map(|s| f64::from_bits(s.load(Relaxed)))
                    .filter(|s| s.is_finite());
                let max = ray_maximum_over(field, subset, &o, &r, previous);
                if let (Some(start), true, true) = (start, row.is_some(), max.hit) {
                    start.store(max.s.to_bits(), Relaxed);
                }
                let (residual, slope) = field_residual(max.value, obs.log_epsilon);
                if side_satisfied(obs.side(i), residual) {
                    if let Some(row) = row {
                        row.iter_mut().for_each(|v| *v = 0.0);
                    }
                    return 0.0;
                }
                if let Some(row) = row {
                    row.iter_mut().for_each(|v| *v = 0.0);
                    if max.hit {
                        field.state_derivative_over(&max.point, subset, Cutoff::Bounded, row);
                        row.iter_mut().for_each(|v| *v *= w * slope);
                    }
                }
                w * residual
            }
            Residual::Joint(i, k) => {
                let w = obs.joint_weight(i);
                let b = obs.joint_part[i];
                let pose = &field.pose;
                // The observed point: the part's origin, or a point fixed in its frame (its
                // offset is in metres, so the part's own coefficients do not move it).
                let origin = match obs.joint_offset.get(i) {
                    Some(offset) => pose.origin[b] + pose.rotation[b] * Vector3::from(*offset),
                    None => pose.origin[b],
                };
                if let Some(row) = row {
                    row.iter_mut().for_each(|v| *v = 0.0);
                    let n_motion = field.skeleton.n_motion;
                    for &j in &field.skeleton.motion_of_part[b] {
                        row[j] = w * pose.twists[j].velocity(&origin)[k];
                    }
                    for (j, u) in &pose.offset_derivatives[b] {
                        row[n_motion + j] += w * u[k];
                    }
                }
                w * (origin[k] - obs.joints[i][k])
            }
        }
    }

    /// The weighted residual of a point or ray with its Jacobian row in compact per-part
    /// form (see [`Field::part_derivatives_over`], moments about `reference`) written to
    /// `terms`; `None` for a joint observation (use [`Residual::evaluate`]).
    pub fn evaluate_parts(
        &self,
        obs: &Observations,
        field: &Field<'_>,
        subset: Option<&[u16]>,
        start: Option<&std::sync::atomic::AtomicU64>,
        reference: &Vector3<f64>,
        terms: &mut PartTerms,
    ) -> Option<f64> {
        let (w, f) = match *self {
            Residual::Point(i) => {
                let x = Vector3::from(obs.points[i]);
                let f = field.part_derivatives_over(&x, subset, Cutoff::Bounded, reference, terms);
                (obs.point_weight(i), f)
            }
            Residual::Ray(i) => {
                let o = Vector3::from(obs.origins[i]);
                let r = Vector3::from(obs.directions[i]);
                use std::sync::atomic::Ordering::Relaxed;
                let previous = start
                    .map(|s| f64::from_bits(s.load(Relaxed)))
                    .filter(|s| s.is_finite());
                let max = ray_maximum_over(field, subset, &o, &r, previous);
                terms.clear();
                if max.hit {
                    if let Some(start) = start {
                        start.store(max.s.to_bits(), Relaxed);
                    }
                    // Envelope theorem: the derivative at fixed x* (∇F · r = 0 there).
                    field.part_derivatives_over(
                        &max.point,
                        subset,
                        Cutoff::Bounded,
                        reference,
                        terms,
                    );
                }
                (obs.ray_weight(i), max.value)
            }
            Residual::Joint(..) => return None,
        };
        let (residual, slope) = field_residual(f, obs.log_epsilon);
        if let Residual::Ray(i) = *self {
            if side_satisfied(obs.side(i), residual) {
                terms.clear();
                return Some(0.0);
            }
        }
        let scale = w * slope;
        for (_, z) in terms.iter_mut() {
            z.iter_mut().for_each(|v| *v *= scale);
        }
        Some(w * residual)
    }
}
