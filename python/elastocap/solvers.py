"""Sparse symmetric positive definite solvers for the elastic fitting system
``(alpha K + beta D + gamma I) x = f`` (SPEC 5, step 4).

The kernels (``rust/solve/``) group the matrix into 2x2 or 3x3 blocks (one per pair of
nodes), run conjugate gradients with a block-Jacobi preconditioner, and wrap faer's sparse
Cholesky with the symbolic analysis reused across factorisations of one pattern.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse
from numpy.typing import NDArray

import elastocap._core as _core
from elastocap._core import InvalidInputError
from elastocap._validate import as_count, as_float_array

__all__ = ["SolveStatus", "SparseCholesky", "conjugate_gradient"]

_Csr = tuple[int, NDArray[np.int32] | NDArray[np.int64], NDArray[np.int32] | NDArray[np.int64], NDArray[np.float64]]


@dataclass(frozen=True)
class SolveStatus:
    """Outcome of :func:`conjugate_gradient`; not converging is reported here, not raised.

    Attributes
    ----------
    converged : bool
        The relative residual reached the tolerance.
    iterations : int
        Conjugate-gradient iterations run (0 when the start already met the tolerance).
    relative_residual : float
        ``||rhs - A x|| / ||rhs||`` of the returned ``x``, from the true residual.
    """

    converged: bool
    iterations: int
    relative_residual: float


def _block_size(block: Any) -> int:
    size = as_count("block", block)
    if size not in (2, 3):
        raise InvalidInputError(f"block must be 2 or 3, got {size}")
    return size


def _as_csr(matrix: Any, block: int) -> _Csr:
    """``matrix`` as sorted, duplicate-free CSR arrays ``(size, indptr, indices, data)``."""
    if not scipy.sparse.issparse(matrix):
        raise InvalidInputError(
            f"matrix must be a scipy.sparse matrix or array (CSR, CSC, COO, ...), got {type(matrix).__name__}"
        )
    if matrix.ndim != 2 or matrix.shape[0] != matrix.shape[1]:
        raise InvalidInputError(f"matrix must be square, got shape {matrix.shape}")
    size = int(matrix.shape[0])
    if size == 0:
        raise InvalidInputError("matrix is empty: shape (0, 0)")
    if size % block:
        raise InvalidInputError(
            f"matrix has {size} rows, which is not a multiple of the block size {block} "
            "(degree of freedom node * block + axis)"
        )
    if matrix.dtype.kind not in "fiu":
        raise InvalidInputError(f"matrix must hold real numbers, got dtype {matrix.dtype}")
    csr = scipy.sparse.csr_array(matrix, dtype=np.float64)  # shares a float64 CSR's arrays
    if not csr.has_canonical_format:
        csr = csr.copy()  # never reorder the caller's arrays
        csr.sum_duplicates()  # also sorts the column indices
    # scipy's int32 indices are read in place; both arrays get one index type.
    index = np.int32 if csr.indptr.dtype == np.int32 and csr.indices.dtype == np.int32 else np.int64
    indptr: Any = np.ascontiguousarray(csr.indptr, dtype=index)
    indices: Any = np.ascontiguousarray(csr.indices, dtype=index)
    return size, indptr, indices, np.ascontiguousarray(csr.data, dtype=np.float64)


def _as_vector(name: str, value: Any, size: int, block: int) -> tuple[NDArray[np.float64], tuple[int, ...]]:
    """``value`` of shape ``(size,)`` or ``(size // block, block)`` as a flat float64 array,
    with the shape to give the result."""
    array = as_float_array(name, value)
    if array.shape not in ((size,), (size // block, block)):
        raise InvalidInputError(
            f"{name} must have shape ({size},) or ({size // block}, {block}) like matrix, got {array.shape}"
        )
    return np.ascontiguousarray(array.reshape(-1)), array.shape


def conjugate_gradient(
    matrix: Any,
    rhs: Any,
    *,
    x0: Any = None,
    block: int = 3,
    tolerance: float = 1e-10,
    max_iterations: int | None = None,
    preconditioner: SparseCholesky | None = None,
    nodes: Any = None,
) -> tuple[NDArray[np.float64], SolveStatus]:
    """Solve ``matrix @ x = rhs`` by preconditioned conjugate gradients.

    Parameters
    ----------
    matrix : scipy.sparse matrix or array, (N B, N B)
        Symmetric positive definite, degree of freedom ``node * block + axis`` (CSR, CSC,
        COO, ...; converted to sorted CSR). Its pattern must be symmetric at the level of
        ``block x block`` blocks; the values are taken as symmetric (not checked).
    rhs : (N B,) or (N, B) array_like of float
        Right-hand side; the solution has the same shape.
    x0 : (N B,) or (N, B) array_like of float, optional
        Initial guess (warm start), e.g. the previous iteration's solution. Default: zeros.
    block : {3, 2}, keyword-only
        Block size: 3 in 3-D, 2 in 2-D.
    tolerance : float, keyword-only
        Stop when ``||rhs - matrix @ x|| <= tolerance * ||rhs||`` (true residual).
    max_iterations : int, optional
        Iteration cap. Default ``10 * N B``.
    preconditioner : SparseCholesky, optional
        Use this factorisation (of a nearby matrix with the same size and block, e.g. the
        previous fitting iteration's) instead of the block-Jacobi preconditioner.
    nodes : (N, B) array_like of float, optional
        Node positions (one per block row). Adds a coarse correction on the rigid motions
        of node aggregates to the block-Jacobi preconditioner (two-level, additive): far
        fewer iterations on elastic systems whose bodies are only weakly held in place, as
        in the fitting (benches/README.md). Ignored with ``preconditioner``.

    Returns
    -------
    x : (N B,) or (N, B) float64 ndarray
        The solution, shaped like ``rhs``.
    status : SolveStatus
        Whether the tolerance was met, the iterations and the relative residual reached.

    Raises
    ------
    InvalidInputError
        For a non-sparse, non-square or wrongly sized matrix, an asymmetric or malformed
        pattern, NaN / infinity, a wrong ``rhs`` / ``x0`` shape or a negative tolerance.
    ConvergenceError
        When the matrix shows it is not positive definite: a diagonal block with a
        non-positive pivot, or a search direction with ``p^T A p <= 0``. Running out of
        iterations is not an error: ``status.converged`` is then False.

    Notes
    -----
    Hestenes-Stiefel conjugate gradients with a block-Jacobi preconditioner (the inverse
    ``block x block`` diagonal blocks, by Cholesky). With ``nodes``: plus ``Z E^-1 Z^T``,
    ``Z`` the translations and rotations of greedy aggregates of strongly coupled nodes
    (unsmoothed aggregation, Vanek, Mandel & Brezina 1996) and ``E = Z^T A Z``. Convergence by the recursively updated
    residual is confirmed on the true residual. SPEC 5, step 4: warm-started from the
    current positions, the per-iteration solve of the fitting.
    """
    size_block = _block_size(block)
    size, indptr, indices, data = _as_csr(matrix, size_block)
    b, shape = _as_vector("rhs", rhs, size, size_block)
    if x0 is None:
        start = np.zeros(size)
    else:
        start, _ = _as_vector("x0", x0, size, size_block)
    try:
        tol = float(tolerance)
    except (TypeError, ValueError):
        raise InvalidInputError(f"tolerance must be a number, got {tolerance!r}") from None
    if not (np.isfinite(tol) and tol >= 0):
        raise InvalidInputError(f"tolerance must be a finite number >= 0, got {tolerance!r}")
    cap = 10 * size if max_iterations is None else as_count("max_iterations", max_iterations, minimum=0)
    if preconditioner is not None and not isinstance(preconditioner, SparseCholesky):
        raise InvalidInputError(
            f"preconditioner must be an elastocap.SparseCholesky or None, got {type(preconditioner).__name__}"
        )
    positions = None
    if nodes is not None and preconditioner is None:
        positions = as_float_array("nodes", nodes)
        if positions.shape != (size // size_block, size_block):
            raise InvalidInputError(
                f"nodes must have shape ({size // size_block}, {size_block}), one position per block row, got {positions.shape}"
            )
        positions = np.ascontiguousarray(positions.reshape(-1))
    x, converged, iterations, residual = _core.conjugate_gradient(
        size, indptr, indices, data, b, start, size_block, tol, cap,
        None if preconditioner is None else preconditioner._factor,
        positions,
    )
    return x.reshape(shape), SolveStatus(bool(converged), int(iterations), float(residual))


class SparseCholesky:
    """Sparse Cholesky factorisation ``A = L L^T`` whose symbolic analysis (AMD ordering,
    elimination tree, supernodes) is reused by every :meth:`factorize` of a matrix with the
    same pattern.

    Parameters
    ----------
    matrix : scipy.sparse matrix or array, (N B, N B)
        Symmetric positive definite; analysed and factorised. Only its lower triangle is
        read; its pattern must be symmetric at the level of blocks.
    block : {3, 2}, keyword-only
        Block size: 3 in 3-D, 2 in 2-D.

    Raises
    ------
    InvalidInputError
        As :func:`conjugate_gradient` for the matrix.
    ConvergenceError
        When the matrix is not positive definite (a non-positive pivot; the message names
        its row).

    Notes
    -----
    faer's sparse ``L L^T`` (supernodal or simplicial by its flop-ratio rule). In the
    fitting (SPEC 5, step 4) the pattern of ``alpha K + beta D + gamma I`` is fixed, so the
    analysis runs once per sequence; the factor also preconditions
    :func:`conjugate_gradient` while the values drift.

    Examples
    --------
    >>> import numpy as np, scipy.sparse, elastocap
    >>> A = scipy.sparse.diags([4.0] * 6) + scipy.sparse.eye(6, k=3) + scipy.sparse.eye(6, k=-3)
    >>> chol = elastocap.solvers.SparseCholesky(A, block=3)
    >>> bool(np.allclose(A @ chol.solve(np.ones(6)), 1))
    True
    """

    def __init__(self, matrix: Any, *, block: int = 3) -> None:
        self._block = _block_size(block)
        size, indptr, indices, data = _as_csr(matrix, self._block)
        self._factor = _core.SparseCholesky(size, indptr, indices, data, self._block)

    @property
    def size(self) -> int:
        """Rows (and columns) of the matrix, ``N B``."""
        return int(self._factor.size)

    @property
    def block(self) -> int:
        """Block size, 2 or 3."""
        return self._block

    @property
    def factor_entries(self) -> int:
        """Stored entries of the factor ``L`` (8 bytes each)."""
        return int(self._factor.factor_entries)

    def factorize(self, matrix: Any) -> None:
        """Factorise new values with the analysed pattern (same size and block pattern).

        Raises
        ------
        InvalidInputError
            For another size or pattern, or NaN / infinity.
        ConvergenceError
            For a matrix that is not positive definite; after a failure, :meth:`solve`
            raises InvalidInputError until a factorisation succeeds.
        """
        size, indptr, indices, data = _as_csr(matrix, self._block)
        if size != self.size:
            raise InvalidInputError(f"matrix must have shape ({self.size}, {self.size}) like the analysed one, got {matrix.shape}")
        self._factor.factorize(indptr, indices, data)

    def solve(self, rhs: Any) -> NDArray[np.float64]:
        """``A^-1 rhs`` for ``rhs`` of shape ``(N B,)`` or ``(N, B)``; the result has its shape."""
        b, shape = _as_vector("rhs", rhs, self.size, self._block)
        return self._factor.solve(b).reshape(shape)
