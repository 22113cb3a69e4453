//! What the per-frame iteration keeps across frames: the surface, the stiffness on its
//! fixed pattern, the system matrix and the solver's state.

use super::surface::enclosed_measure;
use crate::elastic::ElasticModel;
use crate::error::{Error, Result};
use crate::linalg::identity;
use crate::solve::{BlockCsr, Pcg, TwoLevel, STRENGTH};

/// What the iteration keeps across frames: the surface, the stiffness on its fixed pattern,
/// the system matrix and the solver's work vectors.
#[derive(Debug)]
pub struct FitWorkspace<const D: usize> {
    /// Model node of each surface node.
    pub(super) surface: Vec<u32>,
    /// Faces over surface nodes (indices among them), outward.
    pub(super) faces: Vec<[u32; D]>,
    /// Rest positions of the surface nodes.
    pub(super) rest_surface: Vec<[f64; D]>,
    /// $d_p$ of the surface nodes.
    pub(super) support: Vec<f64>,
    /// The rest stiffness $K$ (or the last warped $K_R$) on the model's pattern.
    pub(super) stiffness: BlockCsr<D>,
    /// The system matrix $\alpha S + E$ on the same pattern.
    pub(super) system: BlockCsr<D>,
    pub(super) pcg: Pcg<D>,
    /// The two-level preconditioner, aggregated on the rest stiffness and kept (the
    /// pattern does not change); its rigid modes follow the positions.
    pub(super) coarse: TwoLevel<D>,
    /// Mean node spacing $\bar h$.
    pub(super) spacing: f64,
}

impl<const D: usize> FitWorkspace<D> {
    /// For `model` with surface nodes `surface` (model node indices) and its faces `faces`
    /// (triangles in 3-D, contour edges in 2-D; model node indices, each a surface node).
    /// Faces are reoriented outward if the surface encloses a negative measure.
    ///
    /// # Errors
    /// [`Error::Empty`] without surface nodes or faces; [`Error::NodeIndex`] for an index
    /// that is not a model node or a face corner that is not a surface node.
    pub fn new(model: &ElasticModel<D>, surface: &[u32], faces: &[[u32; D]]) -> Result<Self> {
        let n = model.len();
        if surface.is_empty() || faces.is_empty() {
            return Err(Error::Empty {
                argument: if surface.is_empty() {
                    "surface_nodes"
                } else {
                    "faces"
                },
                needed: 1,
            });
        }
        let mut local = vec![u32::MAX; n];
        for (at, &i) in surface.iter().enumerate() {
            if i as usize >= n {
                return Err(Error::NodeIndex {
                    argument: "surface_nodes",
                    position: at,
                    index: i as usize,
                    n,
                });
            }
            local[i as usize] = at as u32;
        }
        let faces = faces
            .iter()
            .enumerate()
            .map(|(position, f)| {
                let mut out = [0u32; D];
                for (o, &i) in out.iter_mut().zip(f) {
                    match local.get(i as usize) {
                        Some(&l) if l != u32::MAX => *o = l,
                        _ => {
                            return Err(Error::NodeIndex {
                                argument: "faces",
                                position,
                                index: i as usize,
                                n,
                            })
                        }
                    }
                }
                Ok(out)
            })
            .collect::<Result<Vec<_>>>()?;
        let rest_surface: Vec<[f64; D]> =
            surface.iter().map(|&i| model.rest()[i as usize]).collect();
        // Normals must point out of the body (the targets' distances are positive outside).
        let mut faces = faces;
        if enclosed_measure(&rest_surface, &faces) < 0.0 {
            faces.iter_mut().for_each(|f| f.swap(0, 1));
        }
        let pattern = model.pattern();
        let rows: Vec<&[u32]> = pattern
            .indptr
            .windows(2)
            .map(|w| &pattern.indices[w[0]..w[1]])
            .collect();
        let mut stiffness = BlockCsr::<D>::from_pattern(&rows)?;
        let eye = vec![identity(); n];
        model.system_blocks(&eye, stiffness.blocks_mut())?;
        let system = stiffness.zeros_like();
        // Aggregated on the rest stiffness, so that a frame's result does not depend on
        // which frame was fitted first (resumed runs match).
        let coarse = TwoLevel::new(&stiffness, model.rest(), STRENGTH)?;
        let mean_volume = model.volumes().iter().sum::<f64>() / n as f64;
        Ok(Self {
            rest_surface,
            support: surface
                .iter()
                .map(|&i| model.support()[i as usize])
                .collect(),
            surface: surface.to_vec(),
            faces,
            stiffness,
            system,
            pcg: Pcg::new(),
            coarse,
            spacing: mean_volume.powf(1.0 / D as f64),
        })
    }

    /// Surface positions out of all positions.
    pub(super) fn surface_positions(&self, x: &[[f64; D]]) -> Vec<[f64; D]> {
        self.surface.iter().map(|&i| x[i as usize]).collect()
    }
}
