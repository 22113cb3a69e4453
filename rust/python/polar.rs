//! Binding of the batched nearest-rotation kernel.

use numpy::{PyArray3, PyArrayMethods, PyReadonlyArray3, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{c_slice, invalid_input};
use crate::polar::{polar2, polar3};

/// A batched kernel: matrices, rotations out, optional stretches out.
type Kernel<const DD: usize> =
    fn(&[[f64; DD]], &mut [[f64; DD]], Option<&mut [[f64; DD]]>) -> crate::Result<()>;

type Polar<'py> = (Bound<'py, PyArray3<f64>>, Option<Bound<'py, PyArray3<f64>>>);

/// Runs `kernel` into output arrays that numpy allocates: numpy puts large arrays on huge
/// pages, which saves most of the page faults of writing a fresh result.
fn run<'py, const D: usize, const DD: usize>(
    py: Python<'py>,
    flat: &[f64],
    return_stretch: bool,
    kernel: Kernel<DD>,
) -> PyResult<Polar<'py>> {
    let matrices = flat.as_chunks::<DD>().0;
    let n = matrices.len();
    let rotations = PyArray3::<f64>::zeros(py, [n, D, D], false);
    let stretches = return_stretch.then(|| PyArray3::<f64>::zeros(py, [n, D, D], false));
    {
        let mut r = rotations.readwrite();
        let mut s = stretches.as_ref().map(|s| s.readwrite());
        let r = r.as_slice_mut()?.as_chunks_mut::<DD>().0;
        let s = match s.as_mut() {
            Some(s) => Some(s.as_slice_mut()?.as_chunks_mut::<DD>().0),
            None => None,
        };
        super::detach(py, || kernel(matrices, r, s))?;
    }
    Ok((rotations, stretches))
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
    let flat = c_slice(&matrices, "matrices")?;
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
