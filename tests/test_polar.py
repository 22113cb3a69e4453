"""polar_rotation: the nearest proper rotation (and symmetric stretch) of 2x2 and 3x3 matrices.

References: the SVD rotation U diag(1, .., 1, det(U V^T)) V^T (numpy), and, for matrices
built as U diag(s) V^T, the rotation known from the construction.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import elastocap
from tolerances import (
    DETERMINANT_ATOL,
    EQUIVARIANCE_ATOL,
    OPTIMALITY_RTOL,
    ORTHONORMAL_ATOL,
    PSD_RTOL,
    ROTATION_MATCH_ATOL,
    STRETCH_RTOL,
    SYMMETRY_RTOL,
    UNIQUENESS_MARGIN,
)

# ------------------------------------------------------------------------------------------
# References and helpers
# ------------------------------------------------------------------------------------------


def svd_rotation(a: np.ndarray) -> np.ndarray:
    """U diag(1, .., 1, det(U V^T)) V^T: a nearest proper rotation (the one when unique)."""
    u, _, vt = np.linalg.svd(a)
    flip = np.ones(a.shape[-1])
    flip[-1] = np.sign(np.linalg.det(u @ vt))
    return (u * flip) @ vt


def signed_singular_values(a: np.ndarray) -> tuple[np.ndarray, float]:
    """Singular values (descending) and the sign of det A (+1 for a singular A: then the
    smallest singular value is zero and the sign does not matter)."""
    u, s, vt = np.linalg.svd(a)
    sign = float(np.sign(np.linalg.det(u) * np.linalg.det(vt)))
    return s, sign if sign != 0 else 1.0


def uniqueness_margin(a: np.ndarray) -> float:
    """(s_{D-1} + sign(det A) s_D) / s_1: positive iff the nearest rotation is unique."""
    s, sign = signed_singular_values(a)
    if s[0] == 0:
        return 0.0
    return float((s[-2] + sign * s[-1]) / s[0])


def is_unique(a: np.ndarray) -> bool:
    return uniqueness_margin(a) > UNIQUENESS_MARGIN


def assert_proper_rotation(r: np.ndarray) -> None:
    dim = r.shape[-1]
    assert np.all(np.isfinite(r))
    gram = np.swapaxes(r, -1, -2) @ r
    np.testing.assert_allclose(gram, np.broadcast_to(np.eye(dim), gram.shape), rtol=0, atol=ORTHONORMAL_ATOL)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, rtol=0, atol=DETERMINANT_ATOL)


def trace_rt_a(r: np.ndarray, a: np.ndarray) -> float:
    """tr(R^T A) = sum_ij R_ij A_ij: the quantity the nearest rotation maximises."""
    return float(np.sum(r * a))


def assert_optimal(r: np.ndarray, a: np.ndarray) -> None:
    """tr(R^T A) reaches the SVD rotation's value (the maximum over proper rotations)."""
    best = trace_rt_a(svd_rotation(a), a)
    s1 = np.linalg.norm(a, 2)
    assert trace_rt_a(r, a) >= best - OPTIMALITY_RTOL * s1, (trace_rt_a(r, a), best)


def rotation_from(params: np.ndarray, dim: int) -> np.ndarray:
    """A rotation from an angle (2-D) or a non-zero quaternion (3-D)."""
    if dim == 2:
        c, s = np.cos(params[0]), np.sin(params[0])
        return np.array([[c, -s], [s, c]])
    w, x, y, z = params / np.linalg.norm(params)
    return np.array(
        [
            [w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z],
        ]
    )


def random_rotations(rng: np.random.Generator, n: int, dim: int) -> np.ndarray:
    if dim == 2:
        return np.array([rotation_from(rng.uniform(-np.pi, np.pi, 1), 2) for _ in range(n)])
    return np.array([rotation_from(rng.standard_normal(4), 3) for _ in range(n)])


# ------------------------------------------------------------------------------------------
# Strategies
# ------------------------------------------------------------------------------------------


def _flush_tiny(v: float) -> float:
    """Magnitudes below 1e-100 become zero: matrices whose every entry is that small (where
    squares underflow, in the references too) are the subject of test_extreme_scales."""
    return v if abs(v) >= 1e-100 else 0.0


# Entries in [-10, 10]: a few exact values (zeros, repeated entries: singular and symmetric
# matrices) and free floats.
ENTRIES = st.one_of(
    st.sampled_from([0.0, 1.0, -1.0, 0.5, 2.0]),
    st.floats(-10.0, 10.0, allow_nan=False, allow_subnormal=False).map(_flush_tiny),
)
SCALES = st.sampled_from([1.0, 1e-8, 1e8])


@st.composite
def general_matrices(draw, dim):
    a = draw(arrays(np.float64, (dim, dim), elements=ENTRIES))
    return a * draw(SCALES)


@st.composite
def rotations(draw, dim):
    if dim == 2:
        return rotation_from(np.array([draw(st.floats(-np.pi, np.pi))]), 2)
    q = np.array(draw(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4)))
    assume(np.linalg.norm(q) > 0.1)
    return rotation_from(q, 3)


# Singular values: exact zeros, near-zero, equal values (degenerate pairs), generic.
SINGULAR_VALUES = st.one_of(
    st.sampled_from([0.0, 1e-12, 1e-6, 1e-3, 0.5, 1.0, 1.0, 2.0]),
    st.floats(0.0, 10.0, allow_subnormal=False).map(_flush_tiny),
)


@st.composite
def structured_matrices(draw, dim):
    """U diag(s) V^T with a chosen rank (0 .. dim), optionally reflected (det < 0)."""
    u, v = draw(rotations(dim)), draw(rotations(dim))
    s = np.sort(np.array(draw(st.lists(SINGULAR_VALUES, min_size=dim, max_size=dim))))[::-1]
    rank = draw(st.integers(0, dim))
    s[rank:] = 0.0
    if draw(st.booleans()):
        s[-1] = -s[-1]  # det < 0 (a reflection) unless s[-1] == 0
    return (u * s) @ v.T * draw(SCALES)


def matrices(dim):
    return st.one_of(general_matrices(dim), structured_matrices(dim))


DIMS = pytest.mark.parametrize("dim", [2, 3])

# ------------------------------------------------------------------------------------------
# Invariants (hypothesis)
# ------------------------------------------------------------------------------------------


@DIMS
@settings(max_examples=300)
@given(data=st.data())
def test_rotation_is_orthonormal_with_determinant_one(dim, data):
    a = data.draw(matrices(dim), label="A")
    r = elastocap.polar_rotation(a)
    assert r.shape == (dim, dim) and r.dtype == np.float64
    assert_proper_rotation(r)


@DIMS
@settings(max_examples=300)
@given(data=st.data())
def test_matches_svd_rotation_where_unique(dim, data):
    a = data.draw(matrices(dim), label="A")
    assume(is_unique(a))
    r = elastocap.polar_rotation(a)
    np.testing.assert_allclose(r, svd_rotation(a), rtol=0, atol=ROTATION_MATCH_ATOL)


@DIMS
@settings(max_examples=300)
@given(data=st.data())
def test_is_a_nearest_rotation_always(dim, data):
    """Unique or not (rank-deficient, reflections with equal smallest singular values, the
    zero matrix), R maximises tr(R^T A)."""
    a = data.draw(matrices(dim), label="A")
    r = elastocap.polar_rotation(a)
    assert_optimal(r, a)


@DIMS
@settings(max_examples=200)
@given(data=st.data())
def test_stretch_is_symmetric_and_recomposes(dim, data):
    a = data.draw(matrices(dim), label="A")
    r, s = elastocap.polar_rotation(a, return_stretch=True)
    assert r.shape == s.shape == (dim, dim)
    np.testing.assert_array_equal(r, elastocap.polar_rotation(a))
    norm = np.linalg.norm(a)
    # S = sym(R^T A), symmetric, whatever the sign of det A.
    rta = r.T @ a
    np.testing.assert_allclose(s, (rta + rta.T) / 2, rtol=0, atol=STRETCH_RTOL * norm)
    np.testing.assert_allclose(s, s.T, rtol=0, atol=SYMMETRY_RTOL * norm)

    singular, sign = signed_singular_values(a)
    if sign > 0 and singular[-1] > 0:  # det A > 0: A = R S exactly, S is PSD
        np.testing.assert_allclose(r @ s, a, rtol=0, atol=STRETCH_RTOL * norm)
        assert np.linalg.eigvalsh(s).min() >= -PSD_RTOL * norm


@DIMS
@settings(max_examples=200)
@given(data=st.data())
def test_left_and_right_equivariance(dim, data):
    """polar(Q A) = Q polar(A) and polar(A Q) = polar(A) Q for rotations Q."""
    a = data.draw(matrices(dim), label="A")
    q = data.draw(rotations(dim), label="Q")
    assume(is_unique(a))
    r = elastocap.polar_rotation(a)
    np.testing.assert_allclose(elastocap.polar_rotation(q @ a), q @ r, rtol=0, atol=EQUIVARIANCE_ATOL)
    np.testing.assert_allclose(elastocap.polar_rotation(a @ q), r @ q, rtol=0, atol=EQUIVARIANCE_ATOL)


@DIMS
@settings(max_examples=200)
@given(data=st.data())
def test_positive_scaling_does_not_change_the_rotation(dim, data):
    a = data.draw(matrices(dim), label="A")
    c = data.draw(st.sampled_from([1e-6, 0.1, 3.0, 1e6]), label="c")
    assume(is_unique(a))
    np.testing.assert_allclose(
        elastocap.polar_rotation(c * a), elastocap.polar_rotation(a), rtol=0, atol=ROTATION_MATCH_ATOL
    )


@DIMS
@settings(max_examples=60)
@given(data=st.data())
def test_batch_equals_single_matrices(dim, data):
    """Each matrix of a batch gets the rotation it gets alone, wherever it sits in the batch
    (batches may be processed several matrices at a time, with a scalar remainder): equal
    up to rounding where the rotation is unique, and optimal where it is not."""
    batch = np.stack(data.draw(st.lists(matrices(dim), min_size=1, max_size=11), label="batch"))
    rotations_, stretches = elastocap.polar_rotation(batch, return_stretch=True)
    assert rotations_.shape == stretches.shape == batch.shape
    np.testing.assert_array_equal(rotations_, elastocap.polar_rotation(batch))
    for a, r, s in zip(batch, rotations_, stretches, strict=True):
        if is_unique(a):
            single_r, single_s = elastocap.polar_rotation(a, return_stretch=True)
            np.testing.assert_allclose(r, single_r, rtol=0, atol=ROTATION_MATCH_ATOL)
            np.testing.assert_allclose(s, single_s, rtol=0, atol=STRETCH_RTOL * np.linalg.norm(a))
        else:
            assert_optimal(r, a)


# ------------------------------------------------------------------------------------------
# Deterministic batches: many random, rank-deficient, near-zero and reflected matrices
# ------------------------------------------------------------------------------------------


def batch_of_kind(kind: str, dim: int, n: int = 2_000, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u, v = random_rotations(rng, n, dim), random_rotations(rng, n, dim)
    s = np.sort(rng.uniform(0.1, 10.0, (n, dim)), axis=1)[:, ::-1]
    if kind == "random":
        return rng.uniform(-10.0, 10.0, (n, dim, dim))
    if kind.startswith("rank"):
        s[:, int(kind[-1]) :] = 0.0
    elif kind == "near_zero":
        s *= 1e-8
    elif kind == "reflected":
        s[:, -1] *= -1.0
    elif kind == "reflected_near_zero":
        s[:, -1] *= -1.0
        s *= 1e-8
    elif kind == "large":
        s *= 1e8
    else:
        raise ValueError(kind)
    return (u * s[:, None, :]) @ np.swapaxes(v, 1, 2)


KINDS = ["random", "rank0", "rank1", "rank2", "near_zero", "reflected", "reflected_near_zero", "large"]


@DIMS
@pytest.mark.parametrize("kind", KINDS)
def test_batches_are_proper_optimal_and_match_svd_where_unique(kind, dim):
    if kind == "rank2" and dim == 2:
        pytest.skip("a 2x2 matrix has rank 2 at most: that is the 'random' case")
    a = batch_of_kind(kind, dim)
    r, s = elastocap.polar_rotation(a, return_stretch=True)
    assert r.shape == s.shape == a.shape
    assert_proper_rotation(r)
    unique = np.array([is_unique(m) for m in a])
    if kind == "rank0" or (kind == "rank1" and dim == 3):
        assert not unique.any()
    np.testing.assert_allclose(r[unique], np.array([svd_rotation(m) for m in a[unique]]).reshape(-1, dim, dim),
                               rtol=0, atol=ROTATION_MATCH_ATOL)
    for m, rot in zip(a[~unique], r[~unique], strict=True):
        assert_optimal(rot, m)
    if kind == "rank0":
        np.testing.assert_array_equal(r, np.broadcast_to(np.eye(dim), r.shape))  # documented


@DIMS
def test_rotation_of_a_rotation_is_itself_and_of_rotated_spd_is_the_rotation(dim):
    rng = np.random.default_rng(8)
    q = random_rotations(rng, 500, dim)
    np.testing.assert_allclose(elastocap.polar_rotation(q), q, rtol=0, atol=ROTATION_MATCH_ATOL)
    b = rng.standard_normal((500, dim, dim))
    spd = b @ np.swapaxes(b, 1, 2) + 0.1 * np.eye(dim)
    r, s = elastocap.polar_rotation(q @ spd, return_stretch=True)
    np.testing.assert_allclose(r, q, rtol=0, atol=ROTATION_MATCH_ATOL)
    np.testing.assert_allclose(s, spd, rtol=0, atol=STRETCH_RTOL * np.abs(spd).max())


def test_known_3x3_cases():
    # det < 0 with distinct singular values: the smallest singular direction is flipped.
    np.testing.assert_allclose(
        elastocap.polar_rotation(np.diag([1.0, 2.0, -3.0])), np.diag([-1.0, 1.0, -1.0]), atol=ROTATION_MATCH_ATOL
    )
    np.testing.assert_allclose(
        elastocap.polar_rotation(np.diag([-5.0, 2.0, 3.0])), np.diag([-1.0, -1.0, 1.0]), atol=ROTATION_MATCH_ATOL
    )
    # Two negative entries: a rotation by pi, reached exactly.
    np.testing.assert_allclose(
        elastocap.polar_rotation(np.diag([-1.0, -2.0, 3.0])), np.diag([-1.0, -1.0, 1.0]), atol=ROTATION_MATCH_ATOL
    )
    # The zero matrix gives the identity (documented).
    np.testing.assert_array_equal(elastocap.polar_rotation(np.zeros((3, 3))), np.eye(3))
    # A pure reflection with equal singular values: not unique, any optimal rotation goes.
    for reflection in (np.diag([1.0, 1.0, -1.0]), -np.eye(3)):
        r = elastocap.polar_rotation(reflection)
        assert_proper_rotation(r)
        assert_optimal(r, reflection)


def test_known_2x2_cases():
    # The angle of (a00 + a11, a10 - a01), closed form.
    angle = np.arctan2(1.0, 2.0)
    want = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    np.testing.assert_allclose(elastocap.polar_rotation([[2.0, -1.0], [1.0, 2.0]]), want, atol=ROTATION_MATCH_ATOL)
    # det < 0, distinct singular values: diag(1, -3) -> rotation by pi.
    np.testing.assert_allclose(elastocap.polar_rotation(np.diag([1.0, -3.0])), -np.eye(2), atol=ROTATION_MATCH_ATOL)
    np.testing.assert_allclose(elastocap.polar_rotation(np.diag([3.0, -1.0])), np.eye(2), atol=ROTATION_MATCH_ATOL)
    np.testing.assert_array_equal(elastocap.polar_rotation(np.zeros((2, 2))), np.eye(2))
    # A reflection (non-unique): any rotation is optimal; it must still be a rotation.
    r = elastocap.polar_rotation(np.diag([1.0, -1.0]))
    assert_proper_rotation(r)
    assert_optimal(r, np.diag([1.0, -1.0]))


# ------------------------------------------------------------------------------------------
# Shapes
# ------------------------------------------------------------------------------------------


@DIMS
def test_single_matrix_in_single_matrix_out(dim):
    a = np.random.default_rng(0).standard_normal((dim, dim))
    r = elastocap.polar_rotation(a)
    assert r.shape == (dim, dim)
    r2, s2 = elastocap.polar_rotation(a, return_stretch=True)
    assert r2.shape == s2.shape == (dim, dim)
    batch = elastocap.polar_rotation(a[None])
    assert batch.shape == (1, dim, dim)
    np.testing.assert_array_equal(batch[0], r)
    # Lists, integer dtypes and non-contiguous arrays are accepted.
    np.testing.assert_array_equal(elastocap.polar_rotation(a.tolist()), r)
    np.testing.assert_array_equal(elastocap.polar_rotation(np.asfortranarray(a)), r)
    ints = np.arange(dim * dim).reshape(dim, dim) - 3
    np.testing.assert_array_equal(elastocap.polar_rotation(ints), elastocap.polar_rotation(ints.astype(float)))


def test_return_stretch_is_keyword_only():
    with pytest.raises(TypeError):
        elastocap.polar_rotation(np.eye(3), True)  # type: ignore[misc]


# ------------------------------------------------------------------------------------------
# Accuracy near the non-unique set, and at extreme scales
# ------------------------------------------------------------------------------------------


def near_degenerate_batch(margin: float, det_sign: float, n: int = 500, seed: int = 4):
    """A = U diag(1, s2, det_sign * s3) V^T (U, V rotations) with s2 + det_sign * s3 = margin
    (s1 = 1), and its nearest rotation U V^T known from the construction."""
    rng = np.random.default_rng(seed)
    u, v = random_rotations(rng, n, 3), random_rotations(rng, n, 3)
    if det_sign > 0:
        s2 = s3 = np.full(n, margin / 2)
    else:
        s3 = rng.uniform(0.0, 0.5, n)
        s2 = s3 + margin
    s = np.stack([np.ones(n), s2, det_sign * s3], axis=1)
    a = (u * s[:, None, :]) @ np.swapaxes(v, 1, 2)
    return a, u @ np.swapaxes(v, 1, 2)


@pytest.mark.parametrize("det_sign", [1.0, -1.0])
@pytest.mark.parametrize("margin", [1e-1, 1e-2, 1e-3, 1e-4, 2 * UNIQUENESS_MARGIN])
def test_accuracy_close_to_the_non_unique_set(margin, det_sign):
    """Unique but close to non-unique: a backward-stable method errs by ~eps / margin
    (<= ~1e-11 here), far below ROTATION_MATCH_ATOL."""
    a, want = near_degenerate_batch(margin, det_sign)
    r = elastocap.polar_rotation(a)
    assert_proper_rotation(r)
    np.testing.assert_allclose(r, want, rtol=0, atol=ROTATION_MATCH_ATOL)


@pytest.mark.parametrize("det_sign", [1.0, -1.0])
@pytest.mark.parametrize("margin", [1e-6, 1e-8, 1e-10, 0.0])
def test_optimality_at_and_near_the_non_unique_set(margin, det_sign):
    a, _ = near_degenerate_batch(margin, det_sign)
    r = elastocap.polar_rotation(a)
    assert_proper_rotation(r)
    deficit = np.einsum("nij,nij->n", np.array([svd_rotation(m) for m in a]) - r, a)
    assert deficit.max() <= OPTIMALITY_RTOL, f"tr(R^T A) short of the optimum by {deficit.max():.3g} (s1 = 1)"


@DIMS
@pytest.mark.parametrize("scale", [1e-200, 1e-160, 1e160, 1e200])
def test_extreme_scales(dim, scale):
    """The rotation of c A is that of A for any c > 0, even where squaring an entry under-
    or overflows (and 1e-200 * A is not the zero matrix)."""
    a = batch_of_kind("random", dim, n=200)
    a = a[[is_unique(m) for m in a]]
    r = elastocap.polar_rotation(a * scale)
    assert_proper_rotation(r)
    np.testing.assert_allclose(r, np.array([svd_rotation(m) for m in a]), rtol=0, atol=ROTATION_MATCH_ATOL)
