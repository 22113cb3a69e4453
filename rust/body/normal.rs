//! Accumulation of one frame's normal blocks `J^T P J`, `J^T P r`.
//!
//! A point's or ray's Jacobian row is `Σ_b E_b^T z_b` over the few parts b with a ball near
//! it: `z_b` ([`Field::part_derivatives_over`]) holds the moment and force of the part's
//! field gradient and its own three shape derivatives, and `E_b` (9 x columns, [`PartMap`])
//! maps them onto the parameters that move or reshape part b (the screws of its joints,
//! the offset derivatives of its ancestors' coefficients). `E_b` depends on the pose only,
//! so `J^T J = Σ_{b,c} E_b^T (Σ_rows z_b z_c^T) E_c`: each row adds 9 x 9 outer products
//! for its pairs of parts, and the 60-odd-column row is never formed. The joint residuals
//! (a handful) take the dense path. `benches/README.md` has the measurement.

use nalgebra::Vector3;

use super::field::{Field, PART_TERMS as Z};
use super::skeleton::{Twist, SHAPE_PER_PART};

/// `E_b`'s entry for a motion: moment coefficients `m`, force coefficients `f`, no shape.
fn screw(m: &Vector3<f64>, f: &Vector3<f64>) -> [f64; Z] {
    let mut e = [0.0; Z];
    e[..3].copy_from_slice(m.as_slice());
    e[3..6].copy_from_slice(f.as_slice());
    e
}

/// Parts whose compact derivative is smaller than this share of the largest one at the
/// same observation enter the gradient but not `J^T J`. The gradient, hence the fixed point
/// of the iteration, is unchanged; the Gauss-Newton matrix is off by about this share,
/// which only changes the steps slightly. A point typically has 4-6 parts within the
/// Jacobian cut, of which 1-2 carry nearly all of it (see `benches/README.md`).
pub const HESSIAN_SHARE: f64 = 1e-3;

/// Compact per-part derivatives of one observation: `(part, z_b)`, parts ascending.
pub type PartTerms = Vec<(usize, [f64; Z])>;

/// The maps `E_b` of one frame's pose: per part, its columns and their 9-vectors.
#[derive(Debug, Clone)]
pub struct PartMap {
    /// The point moments are taken about (the root part's origin: short lever arms).
    pub reference: Vector3<f64>,
    /// Per part, `(column, e)` with column `< m + s`, ascending.
    columns: Vec<Vec<(usize, [f64; Z])>>,
}

impl PartMap {
    /// `E_b` for every part at `field`'s pose, keeping the columns below `keep` (motion
    /// first, then shape; `keep = n_motion` when the shape is held).
    pub fn new(field: &Field<'_>, keep: usize) -> Self {
        let skeleton = field.skeleton;
        let pose = &field.pose;
        let n_motion = skeleton.n_motion;
        let reference = pose.origin[0];
        let columns = (0..skeleton.n_parts())
            .map(|b| {
                let mut cols: Vec<(usize, [f64; Z])> = Vec::new();
                // ∇F_b · (ω × (x - p)) = ω · ((x - c) × ∇F_b) + ∇F_b · ((p - c) × ω), and
                // a twist moves the field at a fixed point by -∇F_b · v.
                for &k in &skeleton.motion_of_part[b] {
                    let e = match pose.twists[k] {
                        Twist::Translation(t) => screw(&Vector3::zeros(), &-t),
                        Twist::Rotation { axis, pivot } => {
                            let v = (pivot - reference).cross(&axis);
                            screw(&-axis, &-v)
                        }
                    };
                    cols.push((k, e));
                }
                for (j, u) in &pose.offset_derivatives[b] {
                    cols.push((n_motion + j, screw(&Vector3::zeros(), &-u)));
                }
                // The part's own coefficients: the last entries of z_b, in shape order.
                for c in 0..SHAPE_PER_PART {
                    let mut own = [0.0; Z];
                    own[6 + c] = 1.0;
                    cols.push((n_motion + SHAPE_PER_PART * b + c, own));
                }
                cols.retain(|c| c.0 < keep);
                cols.sort_by_key(|c| c.0);
                // Merge repeated columns (none in a well-formed model, but cheap to allow).
                let mut merged: Vec<(usize, [f64; Z])> = Vec::with_capacity(cols.len());
                for (k, e) in cols {
                    match merged.last_mut() {
                        Some(last) if last.0 == k => {
                            last.1.iter_mut().zip(e).for_each(|(a, v)| *a += v);
                        }
                        _ => merged.push((k, e)),
                    }
                }
                merged
            })
            .collect();
        Self { reference, columns }
    }
}

/// Per-frame accumulator of the normal blocks.
pub struct Blocks {
    /// `A` (m x m, upper triangle until [`Blocks::mirror`]).
    pub a: Vec<f64>,
    /// `B` (m x s).
    pub b: Vec<f64>,
    /// `C` (s x s, upper triangle until [`Blocks::mirror`]).
    pub c: Vec<f64>,
    /// `g` (m + s).
    pub g: Vec<f64>,
    /// `½ Σ r²`.
    pub cost: f64,
    /// Scratch row for the dense path (`width` entries).
    pub row: Vec<f64>,
    /// Scratch per-part derivatives for the compact path.
    pub terms: PartTerms,
    strong: PartTerms,
    nz: Vec<usize>,
    parts: usize,
    share: f64,
    /// `Σ z_b z_c^T` for parts `b <= c`, Z x Z row-major at `(b P + c) Z²`.
    pair: Vec<f64>,
    /// Whether a pair block has been touched.
    pair_used: Vec<bool>,
    /// `Σ z_b r`, Z per part.
    part_g: Vec<f64>,
}

impl Blocks {
    /// Zero blocks for `m` motion and `s` shape columns, dense rows of `width` entries,
    /// `parts` parts, and parts below `share` of the largest left out of `J^T J`
    /// ([`HESSIAN_SHARE`]; 0 keeps them all).
    pub fn new(m: usize, s: usize, width: usize, parts: usize, share: f64) -> Self {
        Self {
            a: vec![0.0; m * m],
            b: vec![0.0; m * s],
            c: vec![0.0; s * s],
            g: vec![0.0; m + s],
            cost: 0.0,
            row: vec![0.0; width],
            terms: Vec::with_capacity(8),
            strong: Vec::with_capacity(8),
            nz: Vec::with_capacity(width),
            parts,
            share,
            pair: vec![0.0; Z * Z * parts * parts],
            pair_used: vec![false; parts * parts],
            part_g: vec![0.0; Z * parts],
        }
    }

    /// The sum of two accumulators.
    pub fn merge(mut self, other: Self) -> Self {
        for (x, y) in [
            (&mut self.a, &other.a),
            (&mut self.b, &other.b),
            (&mut self.c, &other.c),
            (&mut self.g, &other.g),
            (&mut self.pair, &other.pair),
            (&mut self.part_g, &other.part_g),
        ] {
            x.iter_mut().zip(y).for_each(|(u, v)| *u += v);
        }
        self.pair_used
            .iter_mut()
            .zip(&other.pair_used)
            .for_each(|(u, v)| *u |= v);
        self.cost += other.cost;
        self
    }

    /// Adds the residual `r` whose weighted row is `Σ_b E_b^T z_b` over `self.terms`
    /// (parts ascending): `g` exactly (every part), `J^T J` from the parts whose `|z_b|` is
    /// at least the accumulator's share (usually [`HESSIAN_SHARE`]) of the largest.
    pub fn accumulate_parts(&mut self, r: f64) {
        self.cost += 0.5 * r * r;
        let p = self.parts;
        let mut largest = 0.0f64;
        for (b, z) in &self.terms {
            let g = &mut self.part_g[Z * b..Z * b + Z];
            g.iter_mut().zip(z).for_each(|(u, v)| *u += v * r);
            largest = largest.max(dot(z, z));
        }
        let floor = self.share * self.share * largest;
        self.strong.clear();
        self.strong
            .extend(self.terms.iter().filter(|(_, z)| dot(z, z) >= floor));
        for (i, (b, z)) in self.strong.iter().enumerate() {
            for (c, y) in &self.strong[i..] {
                self.pair_used[b * p + c] = true;
                let block = &mut self.pair[Z * Z * (b * p + c)..Z * Z * (b * p + c + 1)];
                for (out, zi) in block.chunks_exact_mut(Z).zip(z) {
                    out.iter_mut().zip(y).for_each(|(u, v)| *u += zi * v);
                }
            }
        }
    }

    /// Adds the weighted row in `self.row` and its residual `r`: `A += j j^T` (upper
    /// triangles of the frame and shape blocks), `g += j r`. Columns `>= m + s` (the shape
    /// when it is held) are dropped.
    pub fn accumulate(&mut self, r: f64, m: usize, s: usize) {
        self.cost += 0.5 * r * r;
        self.nz.clear();
        self.nz.extend((0..m + s).filter(|&k| self.row[k] != 0.0));
        let split = self.nz.partition_point(|&k| k < m);
        let (motion, shape) = self.nz.split_at(split);
        let row = &self.row;
        for &k in self.nz.iter() {
            self.g[k] += row[k] * r;
        }
        for (ia, &ka) in motion.iter().enumerate() {
            let va = row[ka];
            let a = &mut self.a[ka * m..(ka + 1) * m];
            for &kb in &motion[ia..] {
                a[kb] += va * row[kb];
            }
            let b = &mut self.b[ka * s..(ka + 1) * s];
            for &kb in shape {
                b[kb - m] += va * row[kb];
            }
        }
        for (ia, &ka) in shape.iter().enumerate() {
            let va = row[ka];
            let c = &mut self.c[(ka - m) * s..(ka - m + 1) * s];
            for &kb in &shape[ia..] {
                c[kb - m] += va * row[kb];
            }
        }
    }

    /// Maps the per-part sums through `E_b` into the blocks (upper triangles), then copies
    /// the upper triangles of the frame and shape blocks onto the lower ones.
    pub fn finish(&mut self, map: &PartMap, m: usize, s: usize) {
        let p = self.parts;
        let n = m + s;
        let mut h = vec![0.0; n * n];
        for b in 0..p {
            for (k, e) in &map.columns[b] {
                self.g[*k] += dot(e, &self.part_g[Z * b..Z * b + Z]);
            }
            for c in b..p {
                if !self.pair_used[b * p + c] {
                    continue;
                }
                let block = &self.pair[Z * Z * (b * p + c)..Z * Z * (b * p + c + 1)];
                for (kc, ec) in &map.columns[c] {
                    let mut t = [0.0; Z];
                    for (ti, row) in t.iter_mut().zip(block.chunks_exact(Z)) {
                        *ti = dot(row, ec);
                    }
                    for (kb, eb) in &map.columns[b] {
                        let v = dot(eb, &t);
                        h[kb * n + kc] += v;
                        if b != c {
                            h[kc * n + kb] += v;
                        }
                    }
                }
            }
        }
        for ka in 0..n {
            for kb in ka..n {
                let v = h[ka * n + kb];
                // ka <= kb: a motion-shape pair always has the motion column first.
                if kb < m {
                    self.a[ka * m + kb] += v;
                } else if ka < m {
                    self.b[ka * s + kb - m] += v;
                } else {
                    self.c[(ka - m) * s + kb - m] += v;
                }
            }
        }
        for (block, n) in [(&mut self.a, m), (&mut self.c, s)] {
            for i in 0..n {
                for j in 0..i {
                    block[i * n + j] = block[j * n + i];
                }
            }
        }
    }
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
