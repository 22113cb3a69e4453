//! The skeleton: a tree of body parts joined by chains of single-DoF revolute joints, a
//! 6-DoF root, per-part length, width, depth and taper coefficients, and forward kinematics with the
//! first derivatives of every part frame with respect to every state parameter.

use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

use crate::{Error, Result};

/// Shape coefficients per part, in this order: [`LENGTH`] scales the part frame's z
/// (along the bone), [`WIDTH`] its x, [`DEPTH`] its y, [`TAPER`] the cross-section of
/// each ball by `t_i = 1 + (τ - 1) k_i` with `k_i` the ball's place along the part
/// ([`Skeleton::taper_weight`]). Width and depth apart let an elliptic section become
/// round (or flatter); the taper lets a tapered limb become a cylinder (or taper more),
/// and a part's small end (the neck ball under the head) shrink while its big end grows.
/// All four are 1 for the part as described.
pub const SHAPE_PER_PART: usize = 4;
/// Offset of the length coefficient in a part's shape triple.
pub const LENGTH: usize = 0;
/// Offset of the width coefficient (part x).
pub const WIDTH: usize = 1;
/// Offset of the depth coefficient (part y).
pub const DEPTH: usize = 2;
/// Offset of the taper coefficient.
pub const TAPER: usize = 3;

/// One body part as the user describes it.
///
/// The part's frame, at state `(shape, motion)`, is
/// `F_b = F_parent · T(S_parent o) · Rest · Rot(a_1, θ_1) · Rot(a_2, θ_2) · …`
/// where `S_parent = diag(w, d, l)` of the parent and each `Rot(a_k, θ) = R_k Rot_z(θ) R_k^T`
/// (`R_k` maps `e_z` onto `a_k`): SPEC 6's chain of 1-DoF joints `D = Rot_z(θ) D_ini` with
/// `D_ini` folded from `Rest`, the offset and the `R_k`. The root part's parent is the
/// 6-DoF root frame `Trans(t) · Rot_z(α) · Rot_y(β) · Rot_x(γ)`.
#[derive(Debug, Clone, PartialEq)]
pub struct PartSpec {
    /// Index of the parent part; `None` for parts hanging from the root frame. Parents come
    /// before their children.
    pub parent: Option<usize>,
    /// Joint position in the parent part's frame at unit coefficients (metres).
    pub offset: [f64; 3],
    /// Rotation from the parent's frame to this part's frame at zero angles (row-major).
    pub rest: [[f64; 3]; 3],
    /// Joint axes, each a unit vector in the frame after the previous rotations.
    pub axes: Vec<[f64; 3]>,
}

/// One ellipsoidal metaball, axis-aligned in its part's frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Metaball {
    /// The part carrying the ball.
    pub part: usize,
    /// Centre in the part frame at unit coefficients; scaled to `(w cx, d cy, l cz)`.
    pub centre: [f64; 3],
    /// Radii at unit coefficients; scaled to `(w lx, d ly, l lz)`.
    pub radii: [f64; 3],
}

/// How one motion parameter moves the parts downstream of it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Twist {
    /// Translation along a world direction (the root's `t`).
    Translation(Vector3<f64>),
    /// Rotation about a world axis through a world pivot.
    Rotation {
        /// Unit axis (world).
        axis: Vector3<f64>,
        /// A point on the axis (world).
        pivot: Vector3<f64>,
    },
}

impl Twist {
    /// Velocity of the world point `x` carried by the moving part, per unit parameter.
    #[inline]
    pub fn velocity(&self, x: &Vector3<f64>) -> Vector3<f64> {
        match self {
            Twist::Translation(e) => *e,
            Twist::Rotation { axis, pivot } => axis.cross(&(x - pivot)),
        }
    }
}

/// A validated body model: parts, metaballs, motion-parameter bookkeeping.
#[derive(Debug, Clone)]
pub struct Skeleton {
    /// The parts, parents first.
    pub parts: Vec<PartSpec>,
    /// The metaballs.
    pub balls: Vec<Metaball>,
    /// First motion index of each part's joint angles (after the 6 root parameters).
    pub first_angle: Vec<usize>,
    /// Motion parameters per frame: 6 + the number of joint axes.
    pub n_motion: usize,
    /// For each part, the motion parameters that move it, ascending.
    pub motion_of_part: Vec<Vec<usize>>,
    /// For each part, its ancestors and itself, root-most first.
    pub chain: Vec<Vec<usize>>,
    /// Per ball (in `balls` order), `k_i = (c_z - mean) / (max - min)` over the centres'
    /// z of its part's balls (0 for a part with one ball, or all at one height): where
    /// the ball sits along the part, in [-1, 1], its part's balls spanning 1.
    pub taper_weight: Vec<f64>,
}

/// Forward kinematics at one state: part frames and the twists of all motion parameters.
#[derive(Debug, Clone)]
pub struct Pose {
    /// World rotation of each part frame.
    pub rotation: Vec<Matrix3<f64>>,
    /// World origin of each part frame (the joint position).
    pub origin: Vec<Vector3<f64>>,
    /// Scale of each part frame's axes: `(w, d, l)` (width, depth, length coefficients).
    pub coefficients: Vec<Vector3<f64>>,
    /// The taper coefficient `τ` of each part.
    pub taper: Vec<f64>,
    /// The twist of every motion parameter.
    pub twists: Vec<Twist>,
    /// For each part b, the world translation of b's frame per unit change of the length,
    /// width and depth coefficients of its ancestors: `(shape index, vector)`.
    pub offset_derivatives: Vec<Vec<(usize, Vector3<f64>)>>,
}

fn unit(v: [f64; 3]) -> Option<Unit<Vector3<f64>>> {
    let v = Vector3::from(v);
    let n = v.norm();
    (n.is_finite() && n > 1e-12).then(|| Unit::new_normalize(v))
}

fn bad(reason: String) -> Error {
    Error::BadModel { reason }
}

impl Skeleton {
    /// Validates parts and metaballs.
    ///
    /// # Errors
    /// [`Error::BadModel`] for a parent that does not come before its child, a rest matrix
    /// that is not a rotation, a zero or non-finite axis, offset, centre or radius, a ball
    /// naming no part, or a model without parts or balls.
    pub fn new(parts: Vec<PartSpec>, balls: Vec<Metaball>) -> Result<Self> {
        if parts.is_empty() || balls.is_empty() {
            return Err(bad(
                "a body model needs at least one part and one metaball".into()
            ));
        }
        if balls.len() > u16::MAX as usize {
            return Err(bad(format!(
                "{} metaballs: at most {} are supported",
                balls.len(),
                u16::MAX
            )));
        }
        let mut first_angle = Vec::with_capacity(parts.len());
        let mut n_motion = 6;
        let mut motion_of_part: Vec<Vec<usize>> = Vec::with_capacity(parts.len());
        let mut chain: Vec<Vec<usize>> = Vec::with_capacity(parts.len());
        for (b, part) in parts.iter().enumerate() {
            let rest = Matrix3::from_fn(|i, j| part.rest[i][j]);
            let orthogonality = (rest.transpose() * rest - Matrix3::identity()).amax();
            if !(orthogonality < 1e-6 && rest.determinant() > 0.0) {
                return Err(bad(format!("part {b}: rest is not a rotation matrix")));
            }
            if !part.offset.iter().all(|v| v.is_finite()) {
                return Err(bad(format!("part {b}: offset is not finite")));
            }
            if part.axes.iter().any(|&a| unit(a).is_none()) {
                return Err(bad(format!("part {b}: a joint axis is zero or not finite")));
            }
            first_angle.push(n_motion);
            let own: Vec<usize> = (n_motion..n_motion + part.axes.len()).collect();
            n_motion += part.axes.len();
            let (mut motion, mut links) = match part.parent {
                None => ((0..6).collect::<Vec<_>>(), vec![]),
                Some(p) if p < b => (motion_of_part[p].clone(), chain[p].clone()),
                Some(p) => {
                    return Err(bad(format!(
                        "part {b}: parent {p} must come before its child"
                    )))
                }
            };
            motion.extend(own);
            links.push(b);
            motion_of_part.push(motion);
            chain.push(links);
        }
        for (i, ball) in balls.iter().enumerate() {
            if ball.part >= parts.len() {
                return Err(bad(format!(
                    "metaball {i}: part {} does not exist ({} parts)",
                    ball.part,
                    parts.len()
                )));
            }
            let finite = ball.centre.iter().chain(&ball.radii).all(|v| v.is_finite());
            if !finite || ball.radii.iter().any(|&r| r <= 0.0) {
                return Err(bad(format!(
                    "metaball {i}: centre must be finite and radii positive"
                )));
            }
        }
        let mut balls = balls;
        // The field sums each part's balls in one run (see `Field::state_derivative`).
        balls.sort_by_key(|b| b.part);
        let taper_weight = balls
            .iter()
            .map(|ball| {
                let heights = balls
                    .iter()
                    .filter(|b| b.part == ball.part)
                    .map(|b| b.centre[2]);
                let (lo, hi, sum, n) = heights.fold(
                    (f64::INFINITY, f64::NEG_INFINITY, 0.0, 0.0),
                    |(lo, hi, s, n), z| (lo.min(z), hi.max(z), s + z, n + 1.0),
                );
                if hi - lo > 1e-9 {
                    (ball.centre[2] - sum / n) / (hi - lo)
                } else {
                    0.0
                }
            })
            .collect();
        Ok(Self {
            parts,
            balls,
            first_angle,
            n_motion,
            motion_of_part,
            chain,
            taper_weight,
        })
    }

    /// Number of parts.
    pub fn n_parts(&self) -> usize {
        self.parts.len()
    }

    /// Shape parameters: `(length, width, depth, taper)` per part.
    pub fn n_shape(&self) -> usize {
        SHAPE_PER_PART * self.parts.len()
    }

    /// Forward kinematics at `shape` (`4 P`: length, width, depth, taper per part) and `motion`
    /// (`n_motion`: root translation, root angles z-y-x, joint angles in part order).
    ///
    /// # Errors
    /// [`Error::LengthMismatch`] for vectors of the wrong length, [`Error::NonFinite`] for
    /// NaN or infinity, [`Error::BadModel`] for non-positive coefficients or a taper that
    /// gives a ball a non-positive section.
    pub fn pose(&self, shape: &[f64], motion: &[f64]) -> Result<Pose> {
        check_vector("shape", shape, self.n_shape())?;
        check_vector("motion", motion, self.n_motion)?;
        let k = SHAPE_PER_PART;
        if let Some(b) =
            (0..self.n_parts()).find(|&b| shape[k * b..k * b + k].iter().any(|&v| v <= 0.0))
        {
            return Err(bad(format!(
                "shape coefficients of part {b} must be positive, got length {}, width {}, depth {} and taper {}",
                shape[k * b + LENGTH],
                shape[k * b + WIDTH],
                shape[k * b + DEPTH],
                shape[k * b + TAPER]
            )));
        }
        if let Some((ball, t)) = self
            .balls
            .iter()
            .zip(&self.taper_weight)
            .find(|(ball, &w)| 1.0 + (shape[k * ball.part + TAPER] - 1.0) * w <= 0.0)
        {
            return Err(bad(format!(
                "the taper {} of part {} leaves a ball no section (its taper weight is {t})",
                shape[k * ball.part + TAPER],
                ball.part
            )));
        }
        let taper: Vec<f64> = (0..self.n_parts()).map(|b| shape[k * b + TAPER]).collect();
        let coefficients: Vec<Vector3<f64>> = (0..self.n_parts())
            .map(|b| {
                Vector3::new(
                    shape[k * b + WIDTH],
                    shape[k * b + DEPTH],
                    shape[k * b + LENGTH],
                )
            })
            .collect();
        let mut twists = vec![Twist::Translation(Vector3::zeros()); self.n_motion];
        let t = Vector3::new(motion[0], motion[1], motion[2]);
        let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), motion[3]);
        let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), motion[4]);
        let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), motion[5]);
        for (k, twist) in twists.iter_mut().take(3).enumerate() {
            *twist = Twist::Translation(Vector3::ith(k, 1.0));
        }
        twists[3] = Twist::Rotation {
            axis: Vector3::z(),
            pivot: t,
        };
        twists[4] = Twist::Rotation {
            axis: rz * Vector3::y(),
            pivot: t,
        };
        twists[5] = Twist::Rotation {
            axis: (rz * ry) * Vector3::x(),
            pivot: t,
        };
        let root = (rz * ry * rx).into_inner();

        let n = self.n_parts();
        let mut rotation = Vec::with_capacity(n);
        let mut origin: Vec<Vector3<f64>> = Vec::with_capacity(n);
        let mut offset_derivatives: Vec<Vec<(usize, Vector3<f64>)>> = Vec::with_capacity(n);
        for (b, part) in self.parts.iter().enumerate() {
            let o = Vector3::from(part.offset);
            let (parent_rotation, joint, mut derivs) = match part.parent {
                None => (root, t + root * o, vec![]),
                Some(p) => {
                    let r = rotation[p];
                    let scaled = coefficients[p].component_mul(&o);
                    let mut d: Vec<(usize, Vector3<f64>)> = offset_derivatives[p].clone();
                    d.push((k * p + LENGTH, r * Vector3::new(0.0, 0.0, o.z)));
                    d.push((k * p + WIDTH, r * Vector3::new(o.x, 0.0, 0.0)));
                    d.push((k * p + DEPTH, r * Vector3::new(0.0, o.y, 0.0)));
                    (r, origin[p] + r * scaled, d)
                }
            };
            derivs.retain(|(_, v)| v.norm_squared() > 0.0);
            let mut frame = parent_rotation * Matrix3::from_fn(|i, j| part.rest[i][j]);
            for (k, &a) in part.axes.iter().enumerate() {
                let axis = unit(a).expect("validated in new");
                let world_axis = frame * axis.into_inner();
                twists[self.first_angle[b] + k] = Twist::Rotation {
                    axis: world_axis,
                    pivot: joint,
                };
                let angle = motion[self.first_angle[b] + k];
                frame *= Rotation3::from_axis_angle(&axis, angle).into_inner();
            }
            rotation.push(frame);
            origin.push(joint);
            offset_derivatives.push(derivs);
        }
        Ok(Pose {
            rotation,
            origin,
            coefficients,
            taper,
            twists,
            offset_derivatives,
        })
    }
}

/// Fails unless `values` has `expected` finite entries.
pub(crate) fn check_vector(argument: &'static str, values: &[f64], expected: usize) -> Result<()> {
    if values.len() != expected {
        return Err(Error::WrongLength {
            argument,
            expected,
            got: values.len(),
        });
    }
    match values.iter().position(|v| !v.is_finite()) {
        Some(row) => Err(Error::NonFinite { argument, row }),
        None => Ok(()),
    }
}
