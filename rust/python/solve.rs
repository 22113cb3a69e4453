//! Binding of the sparse solvers: scalar CSR arrays in (scipy's, sorted, int32 or int64), grouped
//! into 2x2 / 3x3 blocks by the core; conjugate gradients and a sparse Cholesky object.

use std::sync::Mutex;

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArray1, PyUntypedArrayMethods};
use pyo3::prelude::*;

use super::{c_slice, invalid_input};
use crate::solve::{BlockCsr, Pcg, PcgStatus, SparseCholesky as Cholesky, TwoLevel, STRENGTH};

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

/// Borrowed scalar CSR arrays (scipy's, sorted); grouped into blocks by the core.
enum Indices<'a> {
    I32(&'a [i32], &'a [i32]),
    I64(&'a [i64], &'a [i64]),
}

struct CsrArrays<'a> {
    size: usize,
    indices: Indices<'a>,
    data: &'a [f64],
}

impl CsrArrays<'_> {
    fn blocks<const B: usize>(&self) -> crate::Result<BlockCsr<B>> {
        match self.indices {
            Indices::I32(p, i) => BlockCsr::from_csr_parts(self.size, p, i, self.data),
            Indices::I64(p, i) => BlockCsr::from_csr_parts(self.size, p, i, self.data),
        }
    }
}

fn csr<'a>(
    size: usize,
    indices: &'a IndexArrays<'_>,
    data: &'a PyReadonlyArray1<'_, f64>,
) -> PyResult<CsrArrays<'a>> {
    let indices = match indices {
        IndexArrays::I32(p, i) => Indices::I32(c_slice(p, "indptr")?, c_slice(i, "indices")?),
        IndexArrays::I64(p, i) => Indices::I64(c_slice(p, "indptr")?, c_slice(i, "indices")?),
    };
    Ok(CsrArrays {
        size,
        indices,
        data: c_slice(data, "data")?,
    })
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

fn analyse_and_factorize<const B: usize>(csr: &CsrArrays<'_>) -> crate::Result<Cholesky<B>> {
    let matrix = csr.blocks::<B>()?;
    let mut factor = Cholesky::analyse(&matrix)?;
    factor.factorize(&matrix)?;
    Ok(factor)
}

fn factorize<const B: usize>(factor: &mut Cholesky<B>, csr: &CsrArrays<'_>) -> crate::Result<()> {
    factor.factorize(&csr.blocks::<B>()?)
}

fn solve<const B: usize>(factor: &mut Cholesky<B>, rhs: &[f64]) -> crate::Result<Vec<f64>> {
    let mut x = vec![0.0; rhs.len()];
    factor.solve_into(rhs, &mut x)?;
    Ok(x)
}

fn cg<const B: usize>(
    csr: &CsrArrays<'_>,
    rhs: &[f64],
    x: &mut [f64],
    tolerance: f64,
    max_iterations: usize,
    factor: Option<&mut Cholesky<B>>,
    nodes: Option<&[f64]>,
) -> crate::Result<PcgStatus> {
    let mut pcg = Pcg::new();
    match (factor, nodes) {
        (Some(factor), _) => {
            let matrix = csr.blocks::<B>()?;
            pcg.solve(&matrix, factor, rhs, x, tolerance, max_iterations)
        }
        (None, Some(nodes)) => {
            let matrix = csr.blocks::<B>()?;
            let mut two_level = TwoLevel::new(&matrix, nodes.as_chunks::<B>().0, STRENGTH)?;
            pcg.solve(&matrix, &mut two_level, rhs, x, tolerance, max_iterations)
        }
        // Block Jacobi needs only the upper triangle: read it straight from the arrays.
        (None, None) => match csr.indices {
            Indices::I32(p, i) => {
                pcg.solve_csr_parts(csr.size, p, i, csr.data, rhs, x, tolerance, max_iterations)
            }
            Indices::I64(p, i) => {
                pcg.solve_csr_parts(csr.size, p, i, csr.data, rhs, x, tolerance, max_iterations)
            }
        },
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
        let factor = py.detach(|| match block {
            2 => analyse_and_factorize::<2>(&csr).map(Factor::Two),
            _ => analyse_and_factorize::<3>(&csr).map(Factor::Three),
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
        Ok(py.detach(|| match factor {
            Factor::Two(f) => factorize(f, &csr),
            Factor::Three(f) => factorize(f, &csr),
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
        let x = py.detach(|| match factor {
            Factor::Two(f) => solve(f, rhs),
            Factor::Three(f) => solve(f, rhs),
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
        py.detach(|| match (block, factor) {
            (2, Some(Factor::Two(f))) => {
                cg::<2>(&csr, rhs, out, tolerance, max_iterations, Some(f), nodes)
            }
            (2, _) => cg::<2>(&csr, rhs, out, tolerance, max_iterations, None, nodes),
            (_, Some(Factor::Three(f))) => {
                cg::<3>(&csr, rhs, out, tolerance, max_iterations, Some(f), nodes)
            }
            _ => cg::<3>(&csr, rhs, out, tolerance, max_iterations, None, nodes),
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
