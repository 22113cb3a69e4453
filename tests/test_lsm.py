"""Least-squares matching: recovery of known affine warps, gain and offset under noise on
procedural textures and on crops of the temple images, to the precision the covariance
predicts; statuses of bad patches; the epipolar constraint; the joint covariance of
several search images; bad input.

Scenes are exact: template and search image sample one continuous texture (a sum of
sinusoids, or a cubic spline of a lightly smoothed temple crop) at their own pixels, so
the true map is known to rounding. The statistical thresholds were set on seeds 0-199;
the tests run on seeds from 1000.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import cache
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from elastocap import InvalidInputError
from elastocap.stereo import Matches, MatchStatus, match_patches

TEMPLE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "temple_sparse_ring"
if not TEMPLE.exists():
    TEMPLE = Path("/work/shared/data/temple_sparse_ring")
HALF = 24  # scene images are (2 HALF + 1)^2, the point at their centre
NOISE = 2.0

Texture = Callable[[np.ndarray, np.ndarray], np.ndarray]


def procedural(rng: np.random.Generator, contrast: float = 35.0) -> Texture:
    """24 sinusoids, wavelengths 6-30 px, contrast (standard deviation) 35 grey levels."""
    k = 24
    angle = rng.uniform(0, 2 * np.pi, k)
    frequency = rng.uniform(2 * np.pi / 30, 2 * np.pi / 6, k)
    phase = rng.uniform(0, 2 * np.pi, k)
    w = np.stack([frequency * np.cos(angle), frequency * np.sin(angle)], axis=1)
    amplitude = contrast * np.sqrt(2 / k)

    def texture(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.asarray(128 + amplitude * np.sin(u[..., None] * w[:, 0] + v[..., None] * w[:, 1] + phase).sum(-1))

    return texture


@cache
def _temple_images() -> tuple[np.ndarray, ...]:
    paths = sorted(TEMPLE.glob("templeSR*.png"))[::4]
    if not paths:
        pytest.skip(f"temple images not found in {TEMPLE}")
    return tuple(np.asarray(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), dtype=np.float64) for p in paths)


def temple(rng: np.random.Generator) -> Texture:
    """A crop of a temple image with some contrast, smoothed by a 0.7 px Gaussian (the
    images are sharp to the pixel) and read through its cubic spline."""
    images = _temple_images()
    image = images[rng.integers(len(images))]
    while True:
        u0, v0 = rng.integers(150, 450), rng.integers(100, 380)
        crop = image[v0 - 40 : v0 + 41, u0 - 40 : u0 + 41]
        if crop[30:51, 30:51].std() > 15:
            break
    coefficients = ndimage.spline_filter(ndimage.gaussian_filter(crop, 0.7), order=3)

    def texture(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.asarray(ndimage.map_coordinates(coefficients, [v + 40, u + 40], order=3, prefilter=False, mode="nearest"))

    return texture


def warp(rng: np.random.Generator) -> tuple[float, float, float, float, float, float, float, float]:
    """Scale 0.8-1.25, shear +-0.2, rotation +-15 degrees, aspect 0.9-1.1, gain 0.7-1.3,
    offset +-20, start +-2 px off in each axis."""
    return (
        rng.uniform(0.8, 1.25), rng.uniform(-0.2, 0.2), rng.uniform(-15, 15), rng.uniform(0.9, 1.1),
        rng.uniform(0.7, 1.3), rng.uniform(-20, 20), rng.uniform(-2, 2), rng.uniform(-2, 2),
    )


def scene(
    texture: Texture,
    rng: np.random.Generator,
    scale: float, shear: float, rotation: float, aspect: float, gain: float, offset: float, du: float, dv: float,
    *,
    noise: float = NOISE,
    searches: int = 1,
) -> tuple[np.ndarray, list[np.ndarray], np.ndarray, np.ndarray]:
    """Template, search images, the true map (2, 3) and the start (2, 3): identity linear
    part, centre off by ``(du, dv)``. ``template = offset + gain * search`` up to noise."""
    r = np.deg2rad(rotation)
    A = np.array([[np.cos(r), -np.sin(r)], [np.sin(r), np.cos(r)]]) @ np.array([[scale, shear * scale], [0, scale * aspect]])
    n = 2 * HALF + 1
    g = np.arange(n, dtype=np.float64)
    U, V = np.meshgrid(g, g)
    template = texture(U - HALF, V - HALF) + rng.normal(0, noise, (n, n))
    b = np.array([HALF, HALF]) + rng.uniform(-0.5, 0.5, 2)
    Y = np.stack([U - b[0], V - b[1]], axis=-1) @ np.linalg.inv(A).T
    clean = (texture(Y[..., 0], Y[..., 1]) - offset) / gain
    images = [(clean + rng.normal(0, noise, (n, n))).astype(np.float32) for _ in range(searches)]
    truth = np.hstack([A, b[:, None]])
    start = np.hstack([np.eye(2), (b + [du, dv])[:, None]])
    return template.astype(np.float32), images, truth, start


def _match(template: np.ndarray, images: list[np.ndarray], start: np.ndarray, **options: object) -> Matches:
    s = len(images)
    return match_patches(template, [[HALF, HALF]], images, initial=np.broadcast_to(start, (1, s, 2, 3)).copy(), **options)  # type: ignore[arg-type]


def _chi2(m: Matches, truth: np.ndarray) -> tuple[np.ndarray, float]:
    e = (m.positions[0] - truth[:, 2]).ravel()
    return e, float(e @ np.linalg.solve(m.position_covariance()[0], e))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(
    seed=st.integers(1000, 2**31),
    textured=st.sampled_from(["procedural", "temple"]),
    scale=st.floats(0.8, 1.25), shear=st.floats(-0.2, 0.2), rotation=st.floats(-15, 15),
    aspect=st.floats(0.9, 1.1), gain=st.floats(0.7, 1.3), offset=st.floats(-20, 20),
    du=st.floats(-2, 2), dv=st.floats(-2, 2),
)
def test_recovers_warp_gain_and_offset_to_the_predicted_precision(
    seed: int, textured: str, scale: float, shear: float, rotation: float, aspect: float,
    gain: float, offset: float, du: float, dv: float,
) -> None:
    rng = np.random.default_rng(seed)
    texture = procedural(rng) if textured == "procedural" else temple(rng)
    template, images, truth, start = scene(texture, rng, scale, shear, rotation, aspect, gain, offset, du, dv)
    m = _match(template, images, start)
    status = MatchStatus(int(m.status[0, 0]))
    if status != MatchStatus.CONVERGED:
        # Only weak patches and (rarely) the largest warps from 2 px off may fail, and
        # they say so.
        assert status in (MatchStatus.LOW_TEXTURE, MatchStatus.DIVERGED, MatchStatus.MAX_ITERATIONS)
        return
    e, chi2 = _chi2(m, truth)
    assert chi2 < 25, (e, m.position_covariance()[0])  # 5 sigma in two dimensions
    cov = m.covariance[0]
    assert np.abs(m.affine[0, 0, :, :2] - truth[:, :2]).max() < 0.02 + 5 * np.sqrt(np.diag(cov)[2:6].max())
    assert abs(m.gain[0, 0] - gain) < 0.03 + 5 * np.sqrt(cov[6, 6])
    # The offset is correlated with the gain through the mean grey level of the patch:
    # check that mean.
    mean = float(template[HALF - 5 : HALF + 6, HALF - 5 : HALF + 6].mean())
    assert abs(m.offset[0, 0] + m.gain[0, 0] * (mean - offset) / gain - mean) < 1.0
    assert m.correlation[0, 0] > 0.9
    assert 1 <= m.iterations[0, 0] < 30


def _batch(kind: Callable[[np.random.Generator], Texture], seeds: range, **options: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    status, errors, chi2 = [], [], []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        template, images, truth, start = scene(kind(rng), rng, *warp(rng))
        m = _match(template, images, start, **options)
        status.append(int(m.status[0, 0]))
        if m.status[0, 0] == MatchStatus.CONVERGED:
            e, c = _chi2(m, truth)
            errors.append(e)
            chi2.append(c)
    return np.array(status), np.array(errors), np.array(chi2)


def test_procedural_errors_have_unit_variance_and_meet_the_accuracy() -> None:
    status, errors, chi2 = _batch(procedural, range(1000, 1200))
    assert (status == MatchStatus.CONVERGED).mean() >= 0.95
    # Normalised errors: chi-square with 2 degrees of freedom, mean 2 (standard error of
    # the mean of ~195 of them 0.14).
    assert 0.75 < chi2.mean() / 2 < 1.3
    # Seeds 0-199: 0.031 px RMS (length of the 2-D error) with bicubic resampling.
    assert np.sqrt(np.mean(np.sum(errors**2, axis=1))) < 0.04


def _faint_batch(contrast: float, seeds: range, size: int = 11) -> np.ndarray:
    """Normalised errors ``e^T C^-1 e`` of converged matches on procedural texture of the
    given contrast, noise 2, the warps above, started 0.5 px off the true map (a dense
    matcher's prediction from its neighbour: from 2 px off faint texture has false minima)."""
    chi2 = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        template, images, truth, _ = scene(procedural(rng, contrast), rng, *warp(rng))
        start = truth.copy()
        start[:, 2] += rng.uniform(-0.5, 0.5, 2)
        m = _match(template, images, start, size=size, min_texture=0.0)
        if m.status[0, 0] == MatchStatus.CONVERGED:
            chi2.append(_chi2(m, truth)[1])
    return np.array(chi2)


@settings(max_examples=6, deadline=None, derandomize=True)
@given(contrast=st.floats(4, 35), seed=st.integers(1000, 2**20))
def test_faint_texture_errors_have_unit_variance(contrast: float, seed: int) -> None:
    # Gradients of 1-2 grey levels per pixel against noise 2 (the textured capture's
    # cloth): the template's noisy gradients made the plain (G^T G)^-1 covariance 2.2x too
    # small in sigma at contrast 4 (normalised variance 4.7 on seeds 0-199); the sandwich
    # covariance gives 0.85-1.11 over contrast 4-35 and sizes 11 and 21 (benches/README).
    chi2 = _faint_batch(contrast, range(seed, seed + 50))
    assert len(chi2) >= 40
    # Mean of ~48 chi-square(2) / 2: standard error 0.15; the median is robust to the
    # odd match that slid along an edge.
    assert 0.6 < np.median(chi2) / 1.386 < 1.5, np.median(chi2) / 1.386
    assert 0.5 < np.mean(chi2) / 2 < 1.8, np.mean(chi2) / 2


def test_bilinear_resampling_is_close() -> None:
    status, errors, chi2 = _batch(procedural, range(1200, 1300), interpolation="bilinear")
    assert (status == MatchStatus.CONVERGED).mean() >= 0.95
    # Bilinear interpolation biases the positions somewhat on this texture (seeds 0-199:
    # 0.037 px RMS, normalised variance 1.34).
    assert chi2.mean() / 2 < 1.7
    assert np.sqrt(np.mean(np.sum(errors**2, axis=1))) < 0.05


def test_temple_crops_match_or_report_low_texture() -> None:
    status, errors, chi2 = _batch(temple, range(1000, 1150))
    assert set(status.tolist()) <= {int(s) for s in MatchStatus}
    converged = status == MatchStatus.CONVERGED
    assert converged.mean() > 0.3
    # Of what passes the texture test (twice the noise level) little is far off (edges
    # along which the patch slides: the linearised covariance understates those).
    assert (np.sqrt(chi2) > 5).mean() < 0.03
    assert 0.6 < np.median(chi2) / 1.386 < 1.8


def test_joint_covariance_of_two_search_images() -> None:
    chi2, products, predicted = [], [], []
    for seed in range(2000, 2150):
        rng = np.random.default_rng(seed)
        template, images, truth, start = scene(procedural(rng), rng, *warp(rng), searches=2)
        m = _match(template, images, start)
        if not (m.status == MatchStatus.CONVERGED).all():
            continue
        e = (m.positions[0] - truth[:, 2]).ravel()
        cov = m.position_covariance()[0]
        chi2.append(e @ np.linalg.solve(cov, e))
        sd = np.sqrt(np.diag(cov))
        # The shared template correlates the two images' positions: compare the product of
        # the standardised errors of u in image 1 and image 2 with the predicted correlation.
        products.append(e[0] * e[2] / (sd[0] * sd[2]))
        predicted.append(cov[0, 2] / (sd[0] * sd[2]))
    assert len(chi2) > 130
    # Four degrees of freedom.
    assert 0.75 < np.mean(chi2) / 4 < 1.3
    assert np.mean(predicted) > 0.2
    # Standard error of the mean product about 1 / sqrt(140) = 0.085.
    assert abs(np.mean(products) - np.mean(predicted)) < 0.25


def test_epipolar_line_holds_the_centre() -> None:
    rng = np.random.default_rng(3000)
    errors_free, errors_line = [], []
    for _ in range(40):
        template, images, truth, start = scene(procedural(rng), rng, *warp(rng))
        angle = rng.uniform(0, np.pi)
        normal = np.array([np.cos(angle), np.sin(angle)])
        line = np.array([[normal[0], normal[1], -normal @ truth[:, 2]]])
        m = _match(template, images, start, epipolar=line)
        free = _match(template, images, start)
        if m.status[0, 0] != MatchStatus.CONVERGED:
            continue
        assert abs(normal @ m.positions[0, 0] + line[0, 2]) < 1e-9
        cov = m.position_covariance()[0]
        assert abs(normal @ cov @ normal) < 1e-12  # no variance across the line
        if free.status[0, 0] == MatchStatus.CONVERGED:
            errors_line.append(np.linalg.norm(m.positions[0, 0] - truth[:, 2]))
            errors_free.append(np.linalg.norm(free.positions[0, 0] - truth[:, 2]))
    assert np.sqrt(np.mean(np.square(errors_line))) < np.sqrt(np.mean(np.square(errors_free)))
    # A soft constraint sits between.
    template, images, truth, start = scene(procedural(rng), rng, *warp(rng))
    m = _match(template, images, start, epipolar=np.array([[1.0, 0.0, -truth[0, 2] - 0.3]]), epipolar_sigma=0.02)
    assert m.status[0, 0] == MatchStatus.CONVERGED
    assert 0.03 < abs(m.positions[0, 0, 0] - truth[0, 2]) < 0.27


def cramer_rao(texture: Texture, truth: np.ndarray, gain: float, size: int, noise: float = NOISE) -> np.ndarray:
    """(2, 2) bound on the covariance of the matched centre (search pixels) for any unbiased
    estimator of the 8 parameters from a ``size`` patch: ``noise^2 (1 + gain^2) (J^T J)^-1``
    with ``J`` from the NOISE-FREE texture's exact gradients at the true map (noise in both
    images; an estimator that knew the texture could do no better)."""
    h = size // 2
    grid = np.arange(-h, h + 1, dtype=float)
    dx, dy = (a.ravel() for a in np.meshgrid(grid, grid))
    step = 1e-4
    value = texture(dx, dy)
    gx = (texture(dx + step, dy) - texture(dx - step, dy)) / (2 * step)
    gy = (texture(dx, dy + step) - texture(dx, dy - step)) / (2 * step)
    J = np.stack([gx, gy, gx * dx, gx * dy, gy * dx, gy * dy, value, np.ones_like(value)], axis=1)
    C = noise**2 * (1 + gain**2) * np.linalg.inv(J.T @ J)
    A = truth[:, :2]
    return np.asarray(A @ C[:2, :2] @ A.T)


def _accuracy(size: int, seeds: range, **options: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Statuses, centre errors of converged matches (px) and their Cramer-Rao bounds (2x2)
    on procedural texture, the warps above, started 2 px off."""
    status, errors, bounds = [], [], []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        texture = procedural(rng)
        w = warp(rng)
        template, images, truth, start = scene(texture, rng, *w)
        m = _match(template, images, start, size=size, **options)
        status.append(int(m.status[0, 0]))
        if m.status[0, 0] == MatchStatus.CONVERGED:
            errors.append(m.positions[0, 0] - truth[:, 2])
            bounds.append(cramer_rao(texture, truth, w[4], size))
    return np.array(status), np.array(errors), np.array(bounds)


def test_size_11_is_at_the_cramer_rao_bound() -> None:
    # Why issue 14's 0.02 px per axis cannot hold at size 11 on these scenes: the bound
    # itself is above it, and the matcher is at the bound (seeds 1400-1799: 0.0234 px per
    # axis against a bound of 0.0237). Seeds 1800-1999 were not looked at before this test.
    status, errors, bounds = _accuracy(11, range(1800, 2000))
    assert (status == MatchStatus.CONVERGED).mean() >= 0.93
    rms = np.sqrt(np.mean(errors**2))
    bound = np.sqrt(np.mean(np.trace(bounds, axis1=1, axis2=2)) / 2)
    assert bound > 0.02
    assert rms < 1.15 * bound


def test_size_15_with_the_sigma0_rejection_meets_the_0_02_px_line() -> None:
    # SPEC 7's rejection of poor matches by sigma0 (three times the two images' noise)
    # removes the false minima that a larger patch sometimes settles in (seeds 1400-1799:
    # 1 of 389 at size 15, 5 of 384 at 21, all with sigma0 > 20 against <= 3.4 for every
    # correct match); the rest meet the line per axis.
    status, errors, _ = _accuracy(15, range(1800, 2000), max_sigma0=3 * np.sqrt(2) * NOISE)
    assert (status == MatchStatus.CONVERGED).mean() >= 0.93
    assert np.abs(errors).max() < 0.2
    assert np.sqrt(np.mean(errors**2)) <= 0.02


def test_rejection_marks_a_false_minimum_and_keeps_its_estimate() -> None:
    # Seed 1650 at size 15: converges 2.1 px from the truth with sigma0 27 (noise 2).
    rng = np.random.default_rng(1650)
    template, images, truth, start = scene(procedural(rng), rng, *warp(rng))
    plain = _match(template, images, start, size=15)
    judged = _match(template, images, start, size=15, max_sigma0=3 * np.sqrt(2) * NOISE, min_correlation=0.9)
    assert plain.status[0, 0] == MatchStatus.CONVERGED
    assert np.linalg.norm(plain.positions[0, 0] - truth[:, 2]) > 1
    assert judged.status[0, 0] == MatchStatus.REJECTED
    np.testing.assert_array_equal(judged.positions, plain.positions)
    assert np.isfinite(judged.covariance).all()


def test_bad_patches_get_their_status_and_never_raise() -> None:
    rng = np.random.default_rng(4000)
    template, images, truth, start = scene(procedural(rng), rng, *warp(rng))
    black = np.zeros_like(template)
    points = np.array([[HALF, HALF], [1.0, 1.0], [HALF, HALF], [HALF, HALF]])
    initial = np.array([truth, truth, truth, truth])
    initial[2, :, 2] = [2.0, 2.0]  # the warped patch reaches outside the search image
    initial[3, :, 2] += [4.5, -4.5]  # too far to find: runs away or lands elsewhere
    m = match_patches(template, points, images[0], initial=initial)
    assert m.status[0, 0] == MatchStatus.CONVERGED
    assert m.status[1, 0] == MatchStatus.LEFT_IMAGE
    assert m.status[2, 0] == MatchStatus.LEFT_IMAGE
    assert m.status[3, 0] != MatchStatus.CONVERGED or np.linalg.norm(m.positions[3, 0] - truth[:, 2]) > 1
    assert np.isnan(m.covariance[1]).all() and np.isnan(m.sigma0[1, 0])
    # All-black template: no texture. All-black search image: the template has texture
    # but the search patch has none, so the gain is undetermined: not converged.
    flat = match_patches(black, [[HALF, HALF]], images[0])
    assert flat.status[0, 0] == MatchStatus.LOW_TEXTURE
    dark = match_patches(template, [[HALF, HALF]], black, initial=truth[None])
    assert dark.status[0, 0] != MatchStatus.CONVERGED
    # A search image of another size, and an unrelated one.
    small = images[0][5:40, 3:44]
    start_small = truth.copy()
    start_small[:, 2] -= [3, 5]
    shifted = match_patches(template, [[HALF, HALF]], small, initial=start_small[None])
    assert shifted.status[0, 0] == MatchStatus.CONVERGED
    np.testing.assert_allclose(shifted.positions[0, 0], truth[:, 2] - [3, 5], atol=0.15)
    other = procedural(rng)(*np.meshgrid(np.arange(49.0), np.arange(49.0))).astype(np.float32)
    unrelated = match_patches(template, [[HALF, HALF]], other)
    assert unrelated.status[0, 0] != MatchStatus.CONVERGED or unrelated.correlation[0, 0] < 0.9


def test_bad_input_raises_naming_the_argument() -> None:
    image = np.random.default_rng(0).uniform(0, 255, (30, 30)).astype(np.float32)
    with pytest.raises(InvalidInputError, match="template"):
        match_patches(np.zeros((30, 30, 3)), [[15, 15]], image)
    with pytest.raises(InvalidInputError, match="search_images"):
        match_patches(image, [[15, 15]], [image, np.full((30, 30), np.nan)])
    with pytest.raises(InvalidInputError, match="search_images"):
        match_patches(image, [[15, 15]], [])
    with pytest.raises(InvalidInputError, match="points"):
        match_patches(image, [[15, 15, 1]], image)
    with pytest.raises(InvalidInputError, match="points"):
        match_patches(image, [[np.nan, 15]], image)
    with pytest.raises(InvalidInputError, match="size"):
        match_patches(image, [[15, 15]], image, size=10)
    with pytest.raises(InvalidInputError, match="initial"):
        match_patches(image, [[15, 15]], image, initial=np.zeros((2, 2)))
    with pytest.raises(InvalidInputError, match="initial"):
        match_patches(image, [[15, 15]], image, initial=[[[-1.0, 0, 15], [0, 1, 15]]])
    with pytest.raises(InvalidInputError, match="epipolar"):
        match_patches(image, [[15, 15]], image, epipolar=np.zeros((1, 2)))
    with pytest.raises(InvalidInputError, match="interpolation"):
        match_patches(image, [[15, 15]], image, interpolation="nearest")
    with pytest.raises(InvalidInputError, match="tolerance"):
        match_patches(image, [[15, 15]], image, tolerance=0)
    with pytest.raises(InvalidInputError, match="max_sigma0"):
        match_patches(image, [[15, 15]], image, max_sigma0=-1.0)
    with pytest.raises(InvalidInputError, match="max_sigma0"):
        match_patches(image, [[15, 15]], image, max_sigma0="3")
    with pytest.raises(InvalidInputError, match="min_correlation"):
        match_patches(image, [[15, 15]], image, min_correlation=1.5)
    with pytest.raises(InvalidInputError, match="min_correlation"):
        match_patches(image, [[15, 15]], image, min_correlation=np.nan)
