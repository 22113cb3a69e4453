//! Binding of the batched nearest-rotation kernel.

use numpy::{PyArray3, PyArrayMethods, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{invalid_input, to_py};
use crate::polar::{polar2, polar3};

/// A batched kernel: matrices, rotations out, optional stretches out.
type Kernel<const DD: usize> =
    fn(&[[f64; DD]], &mut [[f64; DD]], Option<&mut [[f64; DD]]>) -> crate::Result<()>;

type Polar<'py> = (Bound<'py, PyArray3<f64>>, Option<Bound<'py, PyArray3<f64>>>);

fn run<'py, const D: usize, const DD: usize>(
    py: Python<'py>,
    flat: &[f64],
    return_stretch: bool,
    kernel: Kernel<DD>,
) -> PyResult<Polar<'py>> {
    let matrices = flat.as_chunks::<DD>().0;
    let n = matrices.len();
    let mut rotations = vec![[0.0; DD]; n];
    let mut stretches = if return_stretch {
        Some(vec![[0.0; DD]; n])
    } else {
        None
    };
    py.detach(|| kernel(matrices, &mut rotations, stretches.as_deref_mut()))
        .map_err(|e| to_py(py, e))?;
    let to_array = |m: Vec<[f64; DD]>| -> PyResult<Bound<'py, PyArray3<f64>>> {
        numpy::PyArray1::from_vec(py, m.into_flattened()).reshape([n, D, D])
    };
    Ok((to_array(rotations)?, stretches.map(to_array).transpose()?))
}

/// `(rotations, stretches or None)` of a C-contiguous `(N, D, D)` float64 array, D = 2 or 3.
#[pyfunction]
#[pyo3(signature = (matrices, return_stretch=false))]
fn polar_rotation<'py>(
    py: Python<'py>,
    matrices: PyReadonlyArray3<'py, f64>,
    return_stretch: bool,
) -> PyResult<Polar<'py>> {
    let shape = matrices.shape().to_vec();
    let flat = matrices
        .as_slice()
        .map_err(|_| invalid_input("matrices must be C-contiguous".into()))?;
    match (shape[1], shape[2]) {
        (3, 3) => run::<3, 9>(py, flat, return_stretch, polar3),
        (2, 2) => run::<2, 4>(py, flat, return_stretch, polar2),
        _ => Err(invalid_input(format!(
            "matrices must have shape (N, 3, 3) or (N, 2, 2), got {shape:?}"
        ))),
    }
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(polar_rotation, m)?)
}
