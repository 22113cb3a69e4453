//! The exception hierarchy and the one place where core errors become Python exceptions.
//!
//! `ElastocapError` is the root; `InvalidInputError` is also a `ValueError` (bad input);
//! `ConvergenceError` is for numerical failure on valid input (a matrix found not positive
//! definite). Methods that may stop short of their tolerance report it in a returned status
//! instead (conjugate gradients' `converged`, the body fit's `status`, the elastic fit's
//! `solver_converged`).

use pyo3::exceptions::{PyException, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple, PyType};

use crate::Error;

pyo3::create_exception!(
    elastocap,
    ElastocapError,
    PyException,
    "Root of every error elastocap raises."
);
pyo3::create_exception!(
    elastocap,
    ConvergenceError,
    ElastocapError,
    "A numerical method did not converge or met a singular system."
);

static INVALID_INPUT: PyOnceLock<Py<PyType>> = PyOnceLock::new();

/// `class InvalidInputError(ElastocapError, ValueError)`: pyo3 declares single-base
/// exceptions only, so this one is made by calling `type` once.
fn invalid_input_type(py: Python<'_>) -> PyResult<&Bound<'_, PyType>> {
    let ty = INVALID_INPUT.get_or_try_init(py, || -> PyResult<Py<PyType>> {
        let bases = PyTuple::new(
            py,
            [
                py.get_type::<ElastocapError>(),
                py.get_type::<PyValueError>(),
            ],
        )?;
        let namespace = PyDict::new(py);
        namespace.set_item("__module__", "elastocap")?;
        namespace.set_item(
            "__doc__",
            "Bad input: wrong shape, dtype or value. Also a ValueError.",
        )?;
        let ty = py
            .get_type::<PyType>()
            .call1(("InvalidInputError", bases, namespace))?;
        Ok(ty.cast_into::<PyType>()?.unbind())
    })?;
    Ok(ty.bind(py))
}

/// An `InvalidInputError` carrying `message`.
pub(crate) fn invalid_input(message: String) -> PyErr {
    Python::attach(|py| match invalid_input_type(py) {
        Ok(ty) => PyErr::from_type(ty.clone(), message),
        Err(e) => e,
    })
}

/// The three kinds of failure a caller tells apart.
enum Kind {
    /// The input is wrong (shape, value, range, pattern): `InvalidInputError`.
    InvalidInput,
    /// A numerical method failed on valid input (not converged, singular, not positive
    /// definite): `ConvergenceError`.
    Numerical,
    /// Neither: a resource failure or a bug of the caller: the root `ElastocapError`.
    Other,
}

/// The kind of every core error. Exhaustive on purpose, with no wildcard: a new variant
/// does not compile until it is given its exception here.
fn kind(error: &Error) -> Kind {
    match error {
        Error::Empty { .. }
        | Error::NonFinite { .. }
        | Error::InvalidK { .. }
        | Error::InvalidRadius { .. }
        | Error::TooManyPoints { .. }
        | Error::GridShape { .. }
        | Error::BadCamera { .. }
        | Error::MaskSize { .. }
        | Error::DimensionMismatch { .. }
        | Error::LengthMismatch { .. }
        | Error::NeighborIndex { .. }
        | Error::SelfNotNeighbour { .. }
        | Error::NotEnoughNeighbours { .. }
        | Error::InvalidSupport { .. }
        // SPEC 4.2: a neighbourhood still degenerate after its support was enlarged is a
        // property of the nodes given (collinear or coplanar), not of the arithmetic.
        | Error::IllConditioned { .. }
        | Error::InvalidMaterial { .. }
        | Error::InvalidVolume { .. }
        | Error::BlockSize { .. }
        | Error::SparsePattern { .. }
        | Error::PatternMismatch { .. }
        | Error::VectorLength { .. }
        | Error::NodeIndex { .. }
        | Error::InvalidOption { .. }
        // A solve asked of a factorisation whose last factorize failed (and raised).
        | Error::NotFactorized
        | Error::BadModel { .. }
        | Error::WrongLength { .. }
        | Error::BadRay { .. }
        | Error::IndexOutOfRange { .. } => Kind::InvalidInput,
        // A Cholesky pivot, a diagonal block or a CG curvature that is not positive.
        Error::NotPositiveDefinite { .. } => Kind::Numerical,
        // Memory or index overflow in faer; a wrong output buffer is the binding's bug.
        Error::Factorization { .. } | Error::OutputSize { .. } => Kind::Other,
    }
}

/// The core's error as a Python exception, so that bindings use `?` on core results.
impl From<Error> for PyErr {
    fn from(error: Error) -> PyErr {
        let message = error.to_string();
        match kind(&error) {
            Kind::InvalidInput => invalid_input(message),
            Kind::Numerical => ConvergenceError::new_err(message),
            Kind::Other => ElastocapError::new_err(message),
        }
    }
}

pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("ElastocapError", py.get_type::<ElastocapError>())?;
    m.add("ConvergenceError", py.get_type::<ConvergenceError>())?;
    m.add("InvalidInputError", invalid_input_type(py)?)?;
    Ok(())
}
