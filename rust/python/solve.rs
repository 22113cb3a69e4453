//! Binding of the sparse solvers: scalar CSR arrays in (scipy's, sorted, int32 or int64), grouped
//! into 2x2 / 3x3 blocks by the core; conjugate gradients and a sparse Cholesky object.

use std::sync::Mutex;

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{c_slice, invalid_input};
use crate::solve::{
    conjugate_gradient_csr, CsrParts, CsrPreconditioner, SparseCholesky as Cholesky,
};

/// `(x, converged, iterations, relative_residual)`.
type CgOutputs<'py> = (Bound<'py, PyArray1<f64>>, bool, usize, f64);

/// scipy's index arrays: int32 (its default) or int64 (large matrices), read in place.
enum IndexArrays<'py> {
    I32(PyReadonlyArray1<'py, i32>, PyReadonlyArray1<'py, i32>),
    I64(PyReadonlyArray1<'py, i64>, PyReadonlyArray1<'py, i64>),
}

fn index_arrays<'py>(
    indptr: &Bound<'py, PyAny>,
    indices: &Bound<'py, PyAny>,
) -> PyResult<IndexArrays<'py>> {
    let narrow = (indptr.extract().ok(), indices.extract().ok());
    if let (Some(p), Some(i)) = narrow {
        return Ok(IndexArrays::I32(p, i));
    }
    let wide = (indptr.extract().ok(), indices.extract().ok());
    if let (Some(p), Some(i)) = wide {
        return Ok(IndexArrays::I64(p, i));
    }
    Err(invalid_input(
        "matrix indptr and indices must be 1-D arrays, both int32 or both int64".to_string(),
    ))
}

/// Borrowed scalar CSR arrays of either index type.
enum Csr<'a> {
    I32(CsrParts<'a, i32>),
    I64(CsrParts<'a, i64>),
}

fn csr<'a>(
    size: usize,
    indices: &'a IndexArrays<'_>,
    data: &'a PyReadonlyArray1<'_, f64>,
) -> PyResult<Csr<'a>> {
    let data = c_slice(data, "data")?;
    Ok(match indices {
        IndexArrays::I32(p, i) => Csr::I32(CsrParts {
            size,
            indptr: c_slice(p, "indptr")?,
            indices: c_slice(i, "indices")?,
            data,
        }),
        IndexArrays::I64(p, i) => Csr::I64(CsrParts {
            size,
            indptr: c_slice(p, "indptr")?,
            indices: c_slice(i, "indices")?,
            data,
        }),
    })
}

/// Runs `$body` with `$m` bound to the CSR parts of either index type.
macro_rules! with_csr {
    ($csr:expr, $m:ident => $body:expr) => {
        match $csr {
            Csr::I32($m) => $body,
            Csr::I64($m) => $body,
        }
    };
}

/// A factorisation of either block size.
enum Factor {
    Two(Cholesky<2>),
    Three(Cholesky<3>),
}

fn check_block(block: usize) -> PyResult<()> {
    if block == 2 || block == 3 {
        Ok(())
    } else {
        Err(invalid_input(format!("block must be 2 or 3, got {block}")))
    }
}

/// The core's preconditioner from what the caller passed: a factor, node positions (flat,
/// `B` per block row) or neither.
fn choose_preconditioner<'a, const B: usize>(
    factor: Option<&'a mut Cholesky<B>>,
    nodes: Option<&'a [f64]>,
) -> CsrPreconditioner<'a, B> {
    match (factor, nodes) {
        (Some(factor), _) => CsrPreconditioner::Factor(factor),
        (None, Some(nodes)) => CsrPreconditioner::TwoLevel(nodes.as_chunks::<B>().0),
        (None, None) => CsrPreconditioner::BlockJacobi,
    }
}

/// Sparse Cholesky of a symmetric positive definite matrix, the symbolic analysis reused
/// by every `factorize` of a matrix with the same pattern.
#[pyclass(module = "elastocap._core", frozen)]
pub struct SparseCholesky {
    factor: Mutex<Factor>,
    size: usize,
    block: usize,
}

impl SparseCholesky {
    fn lock(&self) -> std::sync::MutexGuard<'_, Factor> {
        // A panic while holding the lock would be a bug; the factor is still consistent
        // (a failed factorize marks it empty), so a poisoned lock is taken over.
        self.factor.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[pymethods]
impl SparseCholesky {
    #[new]
    #[pyo3(signature = (size, indptr, indices, data, block))]
    fn new(
        py: Python<'_>,
        size: usize,
        indptr: Bound<'_, PyAny>,
        indices: Bound<'_, PyAny>,
        data: PyReadonlyArray1<'_, f64>,
        block: usize,
    ) -> PyResult<Self> {
        check_block(block)?;
        let index = index_arrays(&indptr, &indices)?;
        let csr = csr(size, &index, &data)?;
        let factor = super::detach(py, || {
            with_csr!(&csr, m => match block {
                2 => Cholesky::from_csr_parts(m).map(Factor::Two),
                _ => Cholesky::from_csr_parts(m).map(Factor::Three),
            })
        })?;
        Ok(Self {
            factor: Mutex::new(factor),
            size,
            block,
        })
    }

    /// Refactorises with new values; the pattern must be the analysed one.
    fn factorize(
        &self,
        py: Python<'_>,
        indptr: Bound<'_, PyAny>,
        indices: Bound<'_, PyAny>,
        data: PyReadonlyArray1<'_, f64>,
    ) -> PyResult<()> {
        let index = index_arrays(&indptr, &indices)?;
        let csr = csr(self.size, &index, &data)?;
        let mut guard = self.lock();
        let factor = &mut *guard;
        Ok(super::detach(py, || {
            with_csr!(&csr, m => match factor {
                Factor::Two(f) => f.factorize_csr_parts(m),
                Factor::Three(f) => f.factorize_csr_parts(m),
            })
        })?)
    }

    /// `x = A^-1 rhs` for `rhs` of shape `(size,)`.
    fn solve<'py>(
        &self,
        py: Python<'py>,
        rhs: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let rhs = c_slice(&rhs, "rhs")?;
        let mut guard = self.lock();
        let factor = &mut *guard;
        let x = super::detach(py, || match factor {
            Factor::Two(f) => f.solve(rhs),
            Factor::Three(f) => f.solve(rhs),
        })?;
        Ok(PyArray1::from_vec(py, x))
    }

    /// Number of rows (and columns) of the matrix.
    #[getter]
    fn size(&self) -> usize {
        self.size
    }

    /// Block size, 2 or 3.
    #[getter]
    fn block(&self) -> usize {
        self.block
    }

    /// Stored entries of the factor L (its memory is 8 bytes each).
    #[getter]
    fn factor_entries(&self) -> usize {
        match &*self.lock() {
            Factor::Two(f) => f.factor_len(),
            Factor::Three(f) => f.factor_len(),
        }
    }
}

/// `(x, converged, iterations, relative_residual)` of preconditioned conjugate gradients on
/// the CSR matrix, from `x0`; block-Jacobi preconditioner, or `preconditioner`'s factor.
#[pyfunction]
#[pyo3(signature = (size, indptr, indices, data, rhs, x0, block, tolerance, max_iterations, preconditioner=None, nodes=None))]
#[allow(clippy::too_many_arguments)]
fn conjugate_gradient<'py>(
    py: Python<'py>,
    size: usize,
    indptr: Bound<'py, PyAny>,
    indices: Bound<'py, PyAny>,
    data: PyReadonlyArray1<'py, f64>,
    rhs: PyReadonlyArray1<'py, f64>,
    x0: PyReadonlyArray1<'py, f64>,
    block: usize,
    tolerance: f64,
    max_iterations: usize,
    preconditioner: Option<&Bound<'py, SparseCholesky>>,
    nodes: Option<PyReadonlyArray1<'py, f64>>,
) -> PyResult<CgOutputs<'py>> {
    check_block(block)?;
    let index = index_arrays(&indptr, &indices)?;
    let csr = csr(size, &index, &data)?;
    let rhs = c_slice(&rhs, "rhs")?;
    if x0.len() != size {
        return Err(invalid_input(format!(
            "x0 must have shape ({size},) like rhs, got {:?}",
            x0.shape()
        )));
    }
    let nodes = match &nodes {
        Some(array) if array.len() != size => {
            return Err(invalid_input(format!(
                "nodes must hold one position per block row: {} values for a {size}x{size} matrix, got {}",
                size,
                array.len()
            )))
        }
        Some(array) => Some(c_slice(array, "nodes")?),
        None => None,
    };
    let x = PyArray1::<f64>::zeros(py, size, false);
    let status = {
        let mut out = x.readwrite();
        let out = out.as_slice_mut()?;
        out.copy_from_slice(c_slice(&x0, "x0")?);
        let held = preconditioner.map(|p| p.get());
        if let Some(p) = held {
            if p.block != block || p.size != size {
                return Err(invalid_input(format!(
                    "preconditioner factors a {0}x{0} matrix with block {1}, but matrix is {size}x{size} with block {block}",
                    p.size, p.block
                )));
            }
        }
        let mut guard = held.map(|p| p.lock());
        let factor = guard.as_deref_mut();
        super::detach(py, || {
            with_csr!(&csr, m => match (block, factor) {
                (2, factor) => {
                    let factor = match factor {
                        Some(Factor::Two(f)) => Some(f),
                        _ => None,
                    };
                    conjugate_gradient_csr(m, rhs, out, tolerance, max_iterations, choose_preconditioner::<2>(factor, nodes))
                }
                (_, factor) => {
                    let factor = match factor {
                        Some(Factor::Three(f)) => Some(f),
                        _ => None,
                    };
                    conjugate_gradient_csr(m, rhs, out, tolerance, max_iterations, choose_preconditioner::<3>(factor, nodes))
                }
            })
        })?
    };
    Ok((
        x,
        status.converged,
        status.iterations,
        status.relative_residual,
    ))
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<SparseCholesky>()?;
    m.add_function(wrap_pyfunction!(conjugate_gradient, m)?)
}
