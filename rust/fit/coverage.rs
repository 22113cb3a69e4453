//! The coverage term of the fitting (SPEC 5.1; issue 17, item 1): the target's surface
//! pulls the model, not only the model's surface the target.
//!
//! The surface term (SPEC 5 step 2) pulls each model surface node to the nearest target
//! surface, so a limb that moved faster than the start predicts is pulled onto whatever
//! surface is nearest (the torso), while the hull volume the limb moved into is explained
//! by nothing and pulls nothing. Here the target surface is sampled
//! ($y_j$ with outward normal $g_j$: points of the narrow band of the signed distance moved
//! onto its zero level); a sample is *unexplained* when its nearest normal-compatible model
//! surface node $p(j)$ ($n_p \cdot g_j > 0$, among the [`CANDIDATES`] nearest) is farther
//! than $d_p / 2$, and then pulls that node (its weight ramped from 0 there to full at $d_p$):
//! $C = \sum_j w_j (x_{p(j)} - y_j)^\top M_j (x_{p(j)} - y_j)$ with SPEC 5's anisotropic
//! metric $M_j = s^2 I + (1 - s^2) g_j g_j^\top$, $s = \operatorname{clamp}(|x_p - y_j| /
//! d_p, 0.1, 1)$. $w_j$ is the sample's share of the target's area over a surface node's
//! share of the model's, so that the term pulls a stretch of surface as strongly as the
//! surface term does. Samples close together (within $d/3$) whose nodes are far apart at
//! rest are dropped, as SPEC 5's invalidation drops colliding associations.

use rayon::prelude::*;

use super::associate::SurfaceTerms;
use super::surface::{face_normal, COLLISION_FRACTION, FAR_APART, MIN_ANISOTROPY};
use super::workspace::FitWorkspace;
use crate::efg::Block;
use crate::error::{Error, Result};
use crate::grid_sample::GridField;
use crate::linalg::{distance, dot, quadratic_form, sub, unit};
use crate::spatial_hash::Knn;
use crate::SpatialHash;

/// Model surface nodes examined around each sample for a normal-compatible one.
pub const CANDIDATES: usize = 16;
/// A sample is explained when a compatible node lies within this fraction of its $d_p$.
pub const EXPLAINED_FRACTION: f64 = 0.5;

/// Points on the target's surface with outward unit normals.
#[derive(Debug, Clone, Default)]
pub struct TargetSamples<const D: usize> {
    /// Sample positions, world units.
    pub points: Vec<[f64; D]>,
    /// Outward unit normals (the distance field's gradient).
    pub normals: Vec<[f64; D]>,
    /// The target measure (area in 3-D, length in 2-D) each sample stands for.
    pub measure: f64,
}

impl<const D: usize> TargetSamples<D> {
    /// The narrow band of a signed distance grid (`values` C-ordered over `shape`, the field
    /// `field` of the same grid with voxel edge `spacing`): each voxel centre with
    /// $-h/2 \le d < h/2$ moved onto the zero level along the gradient. In 2-D the grid is one
    /// voxel thick and its plane's first two coordinates are kept. One sample per voxel
    /// column crossing the surface, so each stands for $h^{D-1}$.
    ///
    /// # Errors
    /// [`Error::GridShape`] when `values` does not hold `shape` voxels or a 2-D grid is
    /// more than one voxel thick.
    pub fn from_grid(
        values: &[f64],
        shape: [usize; 3],
        origin: [f64; 3],
        spacing: f64,
        field: &GridField<'_>,
    ) -> Result<Self> {
        if shape.iter().product::<usize>() != values.len() || (D == 2 && shape[2] != 1) {
            return Err(Error::GridShape {
                voxels: values.len(),
                shape,
                spacing: [spacing; 3],
            });
        }
        // The band [-h/2, h/2): about one voxel per column crossing the surface for a
        // smooth distance; a carved hull's distances next to its surface are exactly -h/2
        // inside and +h/2 outside, and the half-open band (shifted by a slack) keeps the
        // inside ones only.
        // (Saved hulls hold float32 distances: a relative slack of 1e-5, not of rounding.)
        let slack = 1e-5 * spacing;
        let (lo, hi) = (-0.5 * spacing - slack, 0.5 * spacing - slack);
        let (points, normals): (Vec<[f64; D]>, Vec<[f64; D]>) = values
            .par_iter()
            .enumerate()
            .filter(|(_, &v)| lo <= v && v < hi)
            .filter_map(|(index, _)| {
                let k = index % shape[2];
                let j = (index / shape[2]) % shape[1];
                let i = index / (shape[1] * shape[2]);
                let centre = [i, j, k].map(|c| c as f64);
                let centre: [f64; 3] = std::array::from_fn(|a| origin[a] + spacing * centre[a]);
                let (d, gradient) = field.sample(&centre);
                let g: [f64; D] = unit(&std::array::from_fn(|a| gradient[a]));
                (dot(&g, &g) > 0.0).then(|| (std::array::from_fn(|a| centre[a] - d * g[a]), g))
            })
            .unzip();
        Ok(Self {
            points,
            normals,
            measure: spacing.powi(D as i32 - 1),
        })
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// True without samples.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

/// A pull of one surface node towards a point with a metric (the coverage and silhouette
/// terms' blocks), added to the system like a surface association.
#[derive(Debug, Clone, Copy)]
pub struct Pull<const D: usize> {
    /// Index of the node among the surface nodes.
    pub node: usize,
    /// Where it is pulled.
    pub target: [f64; D],
    /// The metric (weight included).
    pub weight: Block<D>,
}

/// The coverage term at one iterate.
#[derive(Debug, Clone, Default)]
pub struct Coverage<const D: usize> {
    /// One pull per unexplained sample that found a compatible node and was kept.
    pub pulls: Vec<Pull<D>>,
    /// Samples not explained by the model's surface.
    pub unexplained: usize,
    /// Unexplained samples dropped because they pulled rest-far nodes to one place.
    pub invalidated: usize,
    /// $C$ at the iterate.
    pub energy: f64,
}

/// The unexplained samples of `samples` and the pulls they exert on the model's surface
/// nodes at `positions` (with unit `normals`, `rest` positions and supports `support`);
/// each sample's weight is `weight` times its measure over `node_measure`, the model
/// surface's measure per surface node.
#[allow(clippy::too_many_arguments)]
pub fn coverage<const D: usize>(
    samples: &TargetSamples<D>,
    positions: &[[f64; D]],
    normals: &[[f64; D]],
    rest: &[[f64; D]],
    support: &[f64],
    node_measure: f64,
    weight: f64,
    invalidate: bool,
) -> Coverage<D> {
    let n = positions.len();
    if samples.is_empty() || n == 0 || !(weight > 0.0) || !(node_measure > 0.0) {
        return Coverage::default();
    }
    let Ok(hash) = SpatialHash::new(positions) else {
        return Coverage::default();
    };
    // Most samples' nearest node faces their way: one neighbour settles them, and only the
    // rest look among the CANDIDATES nearest (the same node either way: the lists are
    // sorted by distance, then index). The term's knn costs a fraction of asking every
    // sample for all of them.
    let Ok(nearest) = hash.knn(Some(&samples.points), 1) else {
        return Coverage::default();
    };
    let facing = |j: usize| dot(&normals[nearest.indices[j] as usize], &samples.normals[j]) > 0.0;
    let wide: Vec<usize> = (0..samples.len()).filter(|&j| !facing(j)).collect();
    let wide_points: Vec<[f64; D]> = wide.iter().map(|&j| samples.points[j]).collect();
    let k = CANDIDATES.min(n);
    let near = if wide.is_empty() {
        Knn {
            k,
            indices: Vec::new(),
            distances: Vec::new(),
        }
    } else {
        let Ok(near) = hash.knn(Some(&wide_points), k) else {
            return Coverage::default();
        };
        near
    };
    let mut wide_row = vec![usize::MAX; samples.len()];
    for (row, &j) in wide.iter().enumerate() {
        wide_row[j] = row;
    }
    let scale = weight * samples.measure / node_measure;
    // Per sample: None if explained, Some(None) if unexplained without a compatible node
    // among the candidates, Some(Some(pull)) otherwise.
    let found: Vec<Option<Option<Pull<D>>>> = (0..samples.len())
        .into_par_iter()
        .map(|j| {
            let (y, g) = (&samples.points[j], &samples.normals[j]);
            let candidate = if wide_row[j] == usize::MAX {
                Some((nearest.indices[j] as usize, nearest.distances[j]))
            } else {
                let r = wide_row[j];
                let row = &near.indices[r * k..(r + 1) * k];
                let gaps = &near.distances[r * k..(r + 1) * k];
                row.iter()
                    .zip(gaps)
                    .map(|(&p, &gap)| (p as usize, gap))
                    .find(|&(p, _)| dot(&normals[p], g) > 0.0)
            };
            let Some((p, gap)) = candidate else {
                return Some(None);
            };
            if gap <= EXPLAINED_FRACTION * support[p] {
                return None;
            }
            let s = (gap / support[p]).clamp(MIN_ANISOTROPY, 1.0);
            let s2 = s * s;
            // Full weight from one support radius on, none at the threshold: a sample just
            // beyond it lies between surface nodes of a surface that is in place (a rigid
            // motion then gained 6x the elastic energy of a step pull), a lost limb's lie
            // limb widths away.
            let ramp = scale
                * ((gap / support[p] - EXPLAINED_FRACTION) / (1.0 - EXPLAINED_FRACTION))
                    .clamp(0.0, 1.0);
            let metric = std::array::from_fn(|r| {
                std::array::from_fn(|c| {
                    ramp * (if r == c { s2 } else { 0.0 } + (1.0 - s2) * g[r] * g[c])
                })
            });
            Some(Some(Pull {
                node: p,
                target: *y,
                weight: metric,
            }))
        })
        .collect();
    let unexplained = found.iter().filter(|f| f.is_some()).count();
    let mut pulls: Vec<Pull<D>> = found.into_iter().flatten().flatten().collect();
    let before = pulls.len();
    if invalidate {
        drop_collisions(&mut pulls, rest, support);
    }
    let energy = pulls
        .iter()
        .map(|pull| quadratic_form(&pull.weight, &sub(&positions[pull.node], &pull.target)))
        .sum();
    Coverage {
        invalidated: before - pulls.len(),
        pulls,
        unexplained,
        energy,
    }
}

/// Drops the pulls whose targets lie within $d/3$ of another's while their nodes are more
/// than $3 d$ apart at rest (two parts pulled to one place).
fn drop_collisions<const D: usize>(pulls: &mut Vec<Pull<D>>, rest: &[[f64; D]], support: &[f64]) {
    if pulls.len() < 2 {
        return;
    }
    let targets: Vec<[f64; D]> = pulls.iter().map(|p| p.target).collect();
    let Ok(hash) = SpatialHash::new(&targets) else {
        return;
    };
    let radius = COLLISION_FRACTION * support.iter().copied().fold(0.0, f64::max);
    let Ok(close) = hash.radius_neighbors(None, radius) else {
        return;
    };
    let dropped: Vec<bool> = (0..pulls.len())
        .into_par_iter()
        .map(|a| {
            let p = pulls[a].node;
            let row = close.indptr[a] as usize..close.indptr[a + 1] as usize;
            close.indices[row.clone()]
                .iter()
                .zip(&close.distances[row])
                .any(|(&b, &gap)| {
                    let q = pulls[b as usize].node;
                    q != p
                        && gap < COLLISION_FRACTION * support[p].min(support[q])
                        && distance(&rest[p], &rest[q]) > FAR_APART * support[p].max(support[q])
                })
        })
        .collect();
    let mut keep = dropped.iter().map(|d| !d);
    pulls.retain(|_| keep.next().unwrap_or(true));
}

/// The model surface's rest measure (area in 3-D, length in 2-D) per surface node.
fn node_measure<const D: usize>(workspace: &FitWorkspace<D>) -> f64 {
    let total: f64 = workspace
        .faces
        .iter()
        .map(|face| {
            let n = face_normal(&face.map(|i| workspace.rest_surface[i as usize]));
            dot(&n, &n).sqrt() / if D == 3 { 2.0 } else { 1.0 }
        })
        .sum();
    total / workspace.surface.len() as f64
}

/// The coverage term of the surface at one iterate, with weight `weight` (none without
/// samples or at weight 0).
pub(super) fn coverage_term<const D: usize>(
    workspace: &FitWorkspace<D>,
    surface: &SurfaceTerms<D>,
    samples: Option<&TargetSamples<D>>,
    weight: f64,
    invalidate: bool,
) -> Coverage<D> {
    match samples {
        Some(samples) if weight > 0.0 => coverage(
            samples,
            &surface.positions,
            &surface.normals,
            &workspace.rest_surface,
            &workspace.support,
            node_measure(workspace),
            weight,
            invalidate,
        ),
        _ => Coverage::default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sphere of radius `r` as an exact signed distance on a grid of spacing `h` over
    /// [-1, 1]^3.
    fn sphere(r: f64, h: f64) -> (Vec<f64>, [usize; 3], [f64; 3]) {
        let n = (2.0 / h) as usize + 1;
        let mut values = Vec::with_capacity(n * n * n);
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let p = [i, j, k].map(|c| -1.0 + c as f64 * h);
                    values.push((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - r);
                }
            }
        }
        (values, [n; 3], [-1.0; 3])
    }

    /// The two-pass search (one neighbour, then the candidates for samples whose nearest
    /// node faces away) finds the node a full scan finds: the nearest of the
    /// [`CANDIDATES`] nearest (by distance, then index) whose normal faces the sample's.
    #[test]
    fn each_sample_pulls_the_node_a_full_scan_finds() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let random_unit = |rng: &mut rand_chacha::ChaCha8Rng| {
            unit(&std::array::from_fn::<f64, 3, _>(|_| {
                rng.random_range(-1.0..1.0)
            }))
        };
        let n = 300;
        let positions: Vec<[f64; 3]> = (0..n)
            .map(|_| std::array::from_fn(|_| rng.random_range(-1.0..1.0)))
            .collect();
        let normals: Vec<[f64; 3]> = (0..n).map(|_| random_unit(&mut rng)).collect();
        let support = vec![0.05; n];
        let samples = TargetSamples {
            points: (0..2000)
                .map(|_| std::array::from_fn(|_| rng.random_range(-1.1..1.1)))
                .collect(),
            normals: (0..2000).map(|_| random_unit(&mut rng)).collect(),
            measure: 1.0,
        };
        let found = coverage(
            &samples, &positions, &normals, &positions, &support, 1.0, 1.0, false,
        );
        let mut expected = Vec::new();
        let mut unexplained = 0;
        for (y, g) in samples.points.iter().zip(&samples.normals) {
            let mut order: Vec<usize> = (0..n).collect();
            order.sort_by(|&a, &b| {
                let (da, db) = (distance(&positions[a], y), distance(&positions[b], y));
                da.total_cmp(&db).then(a.cmp(&b))
            });
            match order[..CANDIDATES]
                .iter()
                .find(|&&p| dot(&normals[p], g) > 0.0)
            {
                None => unexplained += 1,
                Some(&p) if distance(&positions[p], y) > EXPLAINED_FRACTION * support[p] => {
                    unexplained += 1;
                    expected.push((p, *y));
                }
                Some(_) => {}
            }
        }
        assert!(expected.len() > 1000, "{}", expected.len());
        assert_eq!(found.unexplained, unexplained);
        let got: Vec<(usize, [f64; 3])> = found.pulls.iter().map(|p| (p.node, p.target)).collect();
        assert_eq!(got, expected);
    }

    #[test]
    fn narrow_band_samples_lie_on_the_surface_with_outward_normals_and_cover_its_area() {
        let (r, h) = (0.5, 0.02);
        let (values, shape, origin) = sphere(r, h);
        let field = GridField::new(&values, shape, origin, h).unwrap();
        let samples = TargetSamples::<3>::from_grid(&values, shape, origin, h, &field).unwrap();
        assert!(!samples.is_empty());
        for (y, g) in samples.points.iter().zip(&samples.normals) {
            let radius = dot(y, y).sqrt();
            assert!((radius - r).abs() < 0.05 * h, "{radius}");
            assert!(dot(&unit(y), g) > 0.999);
        }
        // One sample per voxel column: the sphere's area within a few percent.
        let area = samples.len() as f64 * samples.measure;
        let exact = 4.0 * std::f64::consts::PI * r * r;
        assert!((area / exact - 1.0).abs() < 0.1, "{area} vs {exact}");
    }
}
