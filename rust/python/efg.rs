//! Binding of the nodal-integration elasticity: stiffness (CSR), energy, forces, strains.

use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyReadonlyArray3,
    PyUntypedArrayMethods,
};
use pyo3::prelude::*;

use super::{c_slice, invalid_input, rows};
use crate::efg::{Material, NodalElasticity, Plane};

type Csr<'py> = (
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<f64>>,
);

type EnergyOutputs<'py> = (f64, Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<f64>>);

/// The checked inputs shared by the functions: flat neighbours, k, dimension.
struct Inputs<'a> {
    neighbors: Vec<u32>,
    k: usize,
    dim: usize,
    grad: &'a [f64],
    volumes: &'a [f64],
    material: Material,
}

fn inputs<'a>(
    points: &PyReadonlyArray2<'_, f64>,
    neighbors: &PyReadonlyArray2<'_, i64>,
    grad: &'a PyReadonlyArray3<'_, f64>,
    volumes: &'a PyReadonlyArray1<'_, f64>,
    youngs: f64,
    poisson: f64,
    plane: &str,
) -> PyResult<Inputs<'a>> {
    let [n, dim] = [points.shape()[0], points.shape()[1]];
    if dim != 2 && dim != 3 {
        return Err(invalid_input(format!(
            "points must have shape (N, 2) or (N, 3), got {:?}",
            points.shape()
        )));
    }
    let k = neighbors.shape()[1];
    if neighbors.shape()[0] != n {
        return Err(invalid_input(format!(
            "neighbors must have shape (N, k) with N = {n} rows like points, got {:?}",
            neighbors.shape()
        )));
    }
    if grad.shape() != [n, k, dim] {
        return Err(invalid_input(format!(
            "grad must have shape (N, k, D) = ({n}, {k}, {dim}) like neighbors and points, got {:?}",
            grad.shape()
        )));
    }
    if volumes.shape() != [n] {
        return Err(invalid_input(format!(
            "volumes must have shape (N,) = ({n},) like points, got {:?}",
            volumes.shape()
        )));
    }
    let plane = match plane {
        "strain" => Plane::Strain,
        "stress" => Plane::Stress,
        other => {
            return Err(invalid_input(format!(
                "plane must be \"strain\" or \"stress\", got {other:?}"
            )))
        }
    };
    let flat = c_slice(neighbors, "neighbors")?;
    let neighbors = flat
        .iter()
        .enumerate()
        .map(|(at, &index)| match u32::try_from(index) {
            Ok(i) if (i as usize) < n => Ok(i),
            _ => Err(invalid_input(format!(
                "neighbors[{}, {}] = {index} is not a point index: it must be in 0..{n}",
                at / k.max(1),
                at % k.max(1)
            ))),
        })
        .collect::<PyResult<Vec<u32>>>()?;
    Ok(Inputs {
        neighbors,
        k,
        dim,
        grad: c_slice(grad, "grad")?,
        volumes: c_slice(volumes, "volumes")?,
        material: Material {
            youngs,
            poisson,
            plane,
        },
    })
}

fn stiffness<const D: usize>(inputs: &Inputs<'_>) -> crate::Result<crate::efg::Csr> {
    let grad = inputs.grad.as_chunks::<D>().0;
    let model = NodalElasticity::<D>::new(
        &inputs.neighbors,
        inputs.k,
        grad,
        inputs.volumes,
        &inputs.material,
    )?;
    Ok(model.stiffness())
}

/// `(energy, forces (N, D), strains (N, S))` for displacements `u` (N, D).
fn energy<const D: usize>(
    inputs: &Inputs<'_>,
    u: &[[f64; D]],
) -> crate::Result<(f64, Vec<f64>, Vec<f64>)> {
    let grad = inputs.grad.as_chunks::<D>().0;
    let model = NodalElasticity::<D>::new(
        &inputs.neighbors,
        inputs.k,
        grad,
        inputs.volumes,
        &inputs.material,
    )?;
    let energy = model.energy(u)?;
    let forces = model.forces(u)?.into_iter().flatten().collect();
    Ok((energy, forces, model.strains(u)?))
}

/// CSR `(indptr, indices, data)` of the `(N D, N D)` stiffness by nodal integration
/// (SPEC 4.3), degrees of freedom `node * D + axis`.
#[pyfunction]
#[pyo3(signature = (points, neighbors, grad, volumes, youngs, poisson, plane = "strain"))]
#[allow(clippy::too_many_arguments)]
fn efg_stiffness<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    neighbors: PyReadonlyArray2<'py, i64>,
    grad: PyReadonlyArray3<'py, f64>,
    volumes: PyReadonlyArray1<'py, f64>,
    youngs: f64,
    poisson: f64,
    plane: &str,
) -> PyResult<Csr<'py>> {
    let inputs = inputs(&points, &neighbors, &grad, &volumes, youngs, poisson, plane)?;
    let csr = super::detach(py, || match inputs.dim {
        2 => stiffness::<2>(&inputs),
        _ => stiffness::<3>(&inputs),
    })?;
    let as_i64 = |v: Vec<usize>| v.into_iter().map(|x| x as i64).collect::<Vec<_>>();
    Ok((
        as_i64(csr.indptr).into_pyarray(py),
        as_i64(csr.indices).into_pyarray(py),
        csr.data.into_pyarray(py),
    ))
}

/// `(energy, forces (N, D), strains (N, S))` of displacements `(N, D)`, matrix-free:
/// energy `1/2 sum_p V_p eps_p^T C eps_p`, forces `-K u`, Voigt strains `B_p u_Np`.
#[pyfunction]
#[pyo3(signature = (points, neighbors, grad, volumes, displacements, youngs, poisson, plane = "strain"))]
#[allow(clippy::too_many_arguments)]
fn efg_energy<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'py, f64>,
    neighbors: PyReadonlyArray2<'py, i64>,
    grad: PyReadonlyArray3<'py, f64>,
    volumes: PyReadonlyArray1<'py, f64>,
    displacements: PyReadonlyArray2<'py, f64>,
    youngs: f64,
    poisson: f64,
    plane: &str,
) -> PyResult<EnergyOutputs<'py>> {
    let inputs = inputs(&points, &neighbors, &grad, &volumes, youngs, poisson, plane)?;
    let (n, dim) = (points.shape()[0], inputs.dim);
    if displacements.shape() != [n, dim] {
        return Err(invalid_input(format!(
            "displacements must have shape (N, D) = ({n}, {dim}) like points, got {:?}",
            displacements.shape()
        )));
    }
    let (energy, forces, strains) = match dim {
        2 => {
            let u = rows::<2>(&displacements, "displacements")?;
            super::detach(py, || energy::<2>(&inputs, u))
        }
        _ => {
            let u = rows::<3>(&displacements, "displacements")?;
            super::detach(py, || energy::<3>(&inputs, u))
        }
    }?;
    let s = dim * (dim + 1) / 2;
    let forces = numpy::ndarray::Array2::from_shape_vec((n, dim), forces)
        .map_err(|e| invalid_input(e.to_string()))?;
    let strains = numpy::ndarray::Array2::from_shape_vec((n, s), strains)
        .map_err(|e| invalid_input(e.to_string()))?;
    Ok((energy, forces.into_pyarray(py), strains.into_pyarray(py)))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(efg_stiffness, m)?)?;
    m.add_function(wrap_pyfunction!(efg_energy, m)?)
}
