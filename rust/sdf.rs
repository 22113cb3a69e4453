//! Exact Euclidean distance transforms and signed distance fields of voxel grids.
//!
//! The squared distance transform is separable (Felzenszwalb & Huttenlocher 2012,
//! "Distance transforms of sampled functions"): one pass per axis, each computing for every
//! line the lower envelope of the parabolas $s^2 (q - p)^2 + f(p)$ in linear time. All
//! values stay exact multiples of the squared spacings, so the result equals
//! `scipy.ndimage.distance_transform_edt` to rounding. Lines are independent: every pass
//! runs in parallel, in batches of neighbouring lines so that the strided passes read whole
//! cache lines.
//!
//! Grids are C-ordered `(nx, ny, nz)`: voxel `[i, j, k]` sits at flat index
//! `(i * ny + j) * nz + k`.

use rayon::prelude::*;

use crate::error::{Error, Result};

/// Lines transformed together in the strided passes (one cache line of f64).
const BATCH: usize = 8;

/// Squared Euclidean distance, in world units squared, from every voxel to the nearest
/// voxel where `sites` is true; infinite everywhere when there is no site.
///
/// # Errors
/// [`Error::GridShape`] when `sites.len()` is not the product of `shape` or a spacing is
/// not positive and finite.
pub fn squared_distance_to(
    sites: &[bool],
    shape: [usize; 3],
    spacing: [f64; 3],
) -> Result<Vec<f64>> {
    check_grid(sites.len(), shape, spacing)?;
    let mut a: Vec<f64> = sites
        .par_iter()
        .map(|&s| if s { 0.0 } else { f64::INFINITY })
        .collect();
    let mut b = vec![0.0; a.len()];
    // An axis one voxel long changes nothing (each of its lines is one value): a mask's
    // signed distance (H, W, 1) skips a pass over H x W lines of one value.
    for axis in (0..3).rev().filter(|&axis| shape[axis] > 1) {
        transform_axis(&a, &mut b, shape, axis, spacing[axis] * spacing[axis]);
        std::mem::swap(&mut a, &mut b);
    }
    Ok(a)
}

/// Signed distance, in world units, negative inside: with `edt_in` the distance from an
/// inside voxel to the nearest outside voxel and `edt_out` the reverse, the surface is put
/// half a voxel from the centres: `-(edt_in - h/2)` inside, `edt_out - h/2` outside, with
/// `h` the smallest spacing (SPEC 3). An empty grid is `+inf` everywhere, a full one `-inf`.
///
/// # Errors
/// [`Error::GridShape`] as [`squared_distance_to`].
pub fn signed_distance(
    occupancy: &[bool],
    shape: [usize; 3],
    spacing: [f64; 3],
) -> Result<Vec<f64>> {
    let outside: Vec<bool> = occupancy.par_iter().map(|&o| !o).collect();
    let to_outside = squared_distance_to(&outside, shape, spacing)?;
    let to_inside = squared_distance_to(occupancy, shape, spacing)?;
    let half = 0.5 * spacing.iter().cloned().fold(f64::INFINITY, f64::min);
    Ok(occupancy
        .par_iter()
        .zip(to_outside.par_iter().zip(to_inside.par_iter()))
        .map(|(&inside, (&d_in, &d_out))| {
            if inside {
                half - d_in.sqrt()
            } else {
                d_out.sqrt() - half
            }
        })
        .collect())
}

fn check_grid(len: usize, shape: [usize; 3], spacing: [f64; 3]) -> Result<()> {
    let voxels = shape.iter().try_fold(1usize, |t, &s| t.checked_mul(s));
    if voxels != Some(len) || spacing.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(Error::GridShape {
            voxels: len,
            shape,
            spacing,
        });
    }
    Ok(())
}

/// A writable view that parallel tasks share, each writing its own disjoint set of lines.
struct SharedOut {
    data: *mut f64,
    len: usize,
}

// SAFETY: tasks write disjoint indices (each line belongs to one task), see `transform_axis`.
unsafe impl Sync for SharedOut {}

impl SharedOut {
    /// # Safety
    /// No other task may write `index` concurrently.
    unsafe fn write(&self, index: usize, value: f64) {
        assert!(index < self.len);
        // SAFETY: in bounds by the assertion, exclusive by the caller's contract.
        unsafe { *self.data.add(index) = value }
    }
}

/// One pass of the separable transform along `axis`: `dst` line = envelope of `src` line.
fn transform_axis(src: &[f64], dst: &mut [f64], shape: [usize; 3], axis: usize, s2: f64) {
    let length = shape[axis];
    let stride: usize = shape[axis + 1..].iter().product();
    let outer: usize = shape[..axis].iter().product();
    if length == 0 || stride == 0 || outer == 0 {
        return;
    }
    let out = SharedOut {
        data: dst.as_mut_ptr(),
        len: dst.len(),
    };
    let batches = stride.div_ceil(BATCH);
    (0..outer * batches).into_par_iter().for_each_init(
        || Envelope::new(length),
        |envelope, task| {
            let (o, batch) = (task / batches, task % batches);
            let base = o * length * stride;
            for inner in batch * BATCH..((batch + 1) * BATCH).min(stride) {
                for t in 0..length {
                    envelope.f[t] = src[base + t * stride + inner];
                }
                envelope.transform(s2);
                for t in 0..length {
                    // SAFETY: (o, inner) identifies this line, and each task owns its lines.
                    unsafe { out.write(base + t * stride + inner, envelope.d[t]) };
                }
            }
        },
    );
}

/// Scratch of the 1-D transform: input `f`, output `d`, and the envelope's parabola
/// vertices `v` and boundaries `z`.
struct Envelope {
    f: Vec<f64>,
    d: Vec<f64>,
    v: Vec<usize>,
    z: Vec<f64>,
}

impl Envelope {
    fn new(n: usize) -> Self {
        Envelope {
            f: vec![0.0; n],
            d: vec![0.0; n],
            v: vec![0; n],
            z: vec![0.0; n + 1],
        }
    }

    /// $d(q) = \min_p s^2 (q - p)^2 + f(p)$ over the finite $f(p)$.
    fn transform(&mut self, s2: f64) {
        let n = self.f.len();
        let Some(first) = self.f.iter().position(|v| v.is_finite()) else {
            self.d.fill(f64::INFINITY);
            return;
        };
        let (f, v, z) = (&self.f, &mut self.v, &mut self.z);
        let mut k = 0;
        v[0] = first;
        z[0] = f64::NEG_INFINITY;
        z[1] = f64::INFINITY;
        for q in first + 1..n {
            if !f[q].is_finite() {
                continue;
            }
            let fq = f[q] + s2 * (q * q) as f64;
            // Where the parabola of q overtakes that of p (z[0] = -inf ends the loop).
            let meet = |p: usize| (fq - (f[p] + s2 * (p * p) as f64)) / (2.0 * s2 * (q - p) as f64);
            let mut s = meet(v[k]);
            while s <= z[k] {
                k -= 1;
                s = meet(v[k]);
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f64::INFINITY;
        }
        let mut k = 0;
        for q in 0..n {
            while z[k + 1] < q as f64 {
                k += 1;
            }
            let p = v[k];
            let dq = q as f64 - p as f64;
            self.d[q] = s2 * dq * dq + f[p];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn brute(sites: &[bool], shape: [usize; 3], spacing: [f64; 3]) -> Vec<f64> {
        let idx = |i: usize, j: usize, k: usize| (i * shape[1] + j) * shape[2] + k;
        let mut out = vec![f64::INFINITY; sites.len()];
        for i in 0..shape[0] {
            for j in 0..shape[1] {
                for k in 0..shape[2] {
                    for a in 0..shape[0] {
                        for b in 0..shape[1] {
                            for c in 0..shape[2] {
                                if sites[idx(a, b, c)] {
                                    let d = [
                                        i as f64 - a as f64,
                                        j as f64 - b as f64,
                                        k as f64 - c as f64,
                                    ];
                                    let d2 = (0..3)
                                        .map(|x| d[x] * d[x] * spacing[x] * spacing[x])
                                        .sum::<f64>();
                                    out[idx(i, j, k)] = out[idx(i, j, k)].min(d2);
                                }
                            }
                        }
                    }
                }
            }
        }
        out
    }

    #[test]
    fn matches_brute_force_on_random_sparse_sites() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for (shape, p) in [
            ([7, 9, 5], 0.05),
            ([1, 12, 3], 0.2),
            ([6, 1, 1], 0.3),
            ([5, 6, 7], 0.0),
        ] {
            let sites: Vec<bool> = (0..shape.iter().product())
                .map(|_| rng.random::<f64>() < p)
                .collect();
            let spacing = [0.5, 1.0, 2.0];
            let got = squared_distance_to(&sites, shape, spacing).unwrap();
            let want = brute(&sites, shape, spacing);
            for (g, w) in got.iter().zip(&want) {
                assert!(
                    (g - w).abs() <= 1e-12 * w.max(1.0) || (g.is_infinite() && w.is_infinite()),
                    "{g} vs {w}"
                );
            }
        }
    }

    #[test]
    fn signed_distance_of_a_single_voxel_and_bad_shapes() {
        let mut occ = vec![false; 27];
        occ[13] = true;
        let sdf = signed_distance(&occ, [3, 3, 3], [1.0; 3]).unwrap();
        assert_eq!(sdf[13], -0.5);
        assert_eq!(sdf[12], 0.5);
        assert!((sdf[0] - (3f64.sqrt() - 0.5)).abs() < 1e-15);
        assert!(signed_distance(&occ, [3, 3, 2], [1.0; 3]).is_err());
        assert!(signed_distance(&occ, [3, 3, 3], [1.0, 0.0, 1.0]).is_err());
    }
}
