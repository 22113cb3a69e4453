"""Textured stereo scenes with exact ground truth, for testing and tuning the disparity stage.

A :class:`TexturedScene` is a few spheres and oriented boxes in front of a background plane,
each with a solid (3-D) procedural texture, so that a surface point has the same colour in
every view (Lambertian, view-independent shading). :meth:`TexturedScene.render` ray-casts a
:class:`~elastocap.Camera` (distortion and skew included) with ``n x n`` sub-pixels per
pixel and adds sensor noise; :meth:`TexturedScene.depth` gives the exact depth of every
pixel centre. Scenes are random but seeded (:func:`random_scene`), so tuning can use some
seeds and tests report others.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elastocap.cameras import Camera
from elastocap.stereo.board import subpixel_rays

__all__ = ["TexturedScene", "random_scene", "rectified_test_pair"]

# The finest texture detail spans at least this many pixels where it is seen, so that the
# texture is band-limited like a real image (a lens and a sensor blur anything finer) and the
# renderer's sub-pixels do not alias it into noise that differs between views.
MIN_FEATURE_PIXELS = 2.0
_OCTAVES = 4
_LIGHT = np.array([0.4, -0.6, -0.7]) / np.linalg.norm([0.4, -0.6, -0.7])


@dataclass(frozen=True)
class TexturedScene:
    """Spheres and boxes before a background plane, world units.

    Attributes
    ----------
    spheres : (S, 4) float64
        Centre and radius.
    boxes : (B, 3, 3), (B, 3), (B, 3) float64
        ``box_rotations`` (box -> world), ``box_centres``, ``box_half_sizes``.
    plane : (4,) float64
        Background plane ``n . X = d`` as ``(n, d)``, ``n`` unit.
    colours : (S + B + 1, 3) float64
        Base colour per object (spheres, boxes, plane), 0..1.
    contrasts, scales : (S + B + 1,) float64
        Texture contrast (0 = flat) and size of its coarsest features (world units) per
        object.
    prints : (S + B + 1,) float64
        Contrast of sharp-edged blotches over the smooth texture (printed patterns, seams);
        0 for none.
    seed : int
        Seeds the texture lattice.
    """

    spheres: NDArray[np.float64]
    box_rotations: NDArray[np.float64]
    box_centres: NDArray[np.float64]
    box_half_sizes: NDArray[np.float64]
    plane: NDArray[np.float64]
    colours: NDArray[np.float64]
    contrasts: NDArray[np.float64]
    scales: NDArray[np.float64]
    prints: NDArray[np.float64]
    seed: int

    def cast(
        self, origin: NDArray[np.float64], directions: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
        """Nearest hit of rays ``origin + s * directions`` (``s > 0``).

        Returns
        -------
        s : (N,) float64
            Ray parameter of the hit (inf for a miss).
        ids : (N,) int64
            Object hit: spheres first, then boxes, then the plane; -1 for a miss.
        normals : (N, 3) float64
            Unit surface normal at the hit.
        """
        n = len(directions)
        best = np.full(n, np.inf)
        ids = np.full(n, -1)
        normals = np.zeros((n, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            a = np.einsum("ij,ij->i", directions, directions)
            for k, (c, r) in enumerate(zip(self.spheres[:, :3], self.spheres[:, 3])):
                oc = origin - c
                b = directions @ oc
                disc = b * b - a * (oc @ oc - r * r)
                s = (-b - np.sqrt(disc)) / a
                closer = (disc > 0) & (s > 0) & (s < best)
                best[closer], ids[closer] = s[closer], k
                normals[closer] = (origin + s[closer, None] * directions[closer] - c) / r
            base = len(self.spheres)
            for k, (R, c, h) in enumerate(zip(self.box_rotations, self.box_centres, self.box_half_sizes)):
                o = R.T @ (origin - c)
                d = directions @ R  # box frame
                t1, t2 = (-h - o) / d, (h - o) / d
                near, far = np.minimum(t1, t2), np.maximum(t1, t2)
                s = near.max(axis=1)
                closer = (s <= far.min(axis=1)) & (s > 0) & (s < best)
                best[closer], ids[closer] = s[closer], base + k
                face = np.argmax(near[closer], axis=1)
                local = np.zeros((int(closer.sum()), 3))
                local[np.arange(len(face)), face] = -np.sign(d[closer][np.arange(len(face)), face])
                normals[closer] = local @ R.T
            normal, offset = self.plane[:3], self.plane[3]
            s = (offset - origin @ normal) / (directions @ normal)
            closer = (s > 0) & (s < best)
            best[closer], ids[closer] = s[closer], len(self.colours) - 1
            normals[closer] = -normal * np.sign(directions[closer] @ normal)[:, None]
        return best, ids, normals

    def shade(self, points: NDArray[np.float64], ids: NDArray[np.int64], normals: NDArray[np.float64]) -> NDArray[np.float64]:
        """RGB 0..255 ``(N, 3)`` of surface points: base colour x solid texture x Lambert."""
        scaled = points / self.scales[ids][:, None]
        texture = _fbm(scaled, self.seed + 101 * ids)
        blotches = np.sign(_value_noise(4.0 * scaled, self.seed + 101 * ids + 57) - 0.5)
        grey = 1.0 + self.contrasts[ids] * (texture - 0.5) * 2.0 + self.prints[ids] * blotches
        light = 0.45 + 0.55 * np.clip(-(normals @ _LIGHT), 0.0, 1.0)
        return 255.0 * np.clip(self.colours[ids] * (grey * light)[:, None], 0.0, 1.0)

    def render(
        self, camera: Camera, *, supersample: int = 2, noise: float = 2.0, rng: np.random.Generator | None = None
    ) -> NDArray[np.uint8]:
        """The ``(height, width, 3)`` uint8 RGB image ``camera`` sees, ``supersample^2`` rays
        per pixel, plus Gaussian noise of ``noise`` grey levels."""
        rng = np.random.default_rng(0) if rng is None else rng
        directions = subpixel_rays(camera, supersample)
        colour = np.zeros((len(directions), 3))
        ok = np.isfinite(directions).all(axis=1)
        s, ids, normals = self.cast(camera.center, directions[ok])
        hit = ids >= 0
        points = camera.center + s[hit, None] * directions[ok][hit]
        shaded = np.zeros((int(ok.sum()), 3))
        shaded[hit] = self.shade(points, ids[hit], normals[hit])
        colour[ok] = shaded
        image = colour.reshape(camera.height, camera.width, supersample * supersample, 3).mean(axis=2)
        image += rng.normal(0.0, noise, image.shape)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)

    def depth(self, camera: Camera) -> NDArray[np.float64]:
        """``(height, width)``: depth ``z`` (camera frame, world units) of the surface seen
        at each pixel centre; inf where nothing is hit."""
        directions = subpixel_rays(camera, 1)
        s, ids, _ = self.cast(camera.center, directions)
        z = s * (directions @ camera.R[2])
        return np.where(ids >= 0, z, np.inf).reshape(camera.height, camera.width)


def _fbm(points: NDArray[np.float64], seeds: NDArray[np.int64], octaves: int = _OCTAVES) -> NDArray[np.float64]:
    """Fractal value noise in [0, 1] at ``(N, 3)`` points, one lattice per seed."""
    total = np.zeros(len(points))
    weight = 0.0
    for octave in range(octaves):
        amplitude = 0.7**octave
        total += amplitude * _value_noise(points * 2.0**octave, seeds + 7919 * octave)
        weight += amplitude
    return total / weight


def _value_noise(points: NDArray[np.float64], seeds: NDArray[np.int64]) -> NDArray[np.float64]:
    """Trilinear (smoothstep) interpolation of hashed random values on the integer lattice."""
    cell = np.floor(points)
    f = points - cell
    f = f * f * (3 - 2 * f)
    c = cell.astype(np.int64)
    total = np.zeros(len(points))
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1]) * (f[:, 2] if dz else 1 - f[:, 2])
                total += w * _hash(c[:, 0] + dx, c[:, 1] + dy, c[:, 2] + dz, seeds)
    return total


def _hash(x: NDArray[np.int64], y: NDArray[np.int64], z: NDArray[np.int64], seed: NDArray[np.int64]) -> NDArray[np.float64]:
    """A value in [0, 1) per integer lattice point (a 64-bit integer mix)."""
    with np.errstate(over="ignore"):
        h = (x * 73856093) ^ (y * 19349663) ^ (z * 83492791) ^ (seed * 2654435761)
        h = h.astype(np.uint64)
        h ^= h >> np.uint64(33)
        h *= np.uint64(0xFF51AFD7ED558CCD)
        h ^= h >> np.uint64(33)
        h *= np.uint64(0xC4CEB9FE1A85EC53)
        h ^= h >> np.uint64(33)
    return (h >> np.uint64(11)).astype(np.float64) / float(2**53)


def random_scene(
    seed: int,
    centre: NDArray[np.float64],
    radius: float,
    viewer: NDArray[np.float64],
    *,
    focal: float,
    background: float = 2.0,
) -> TexturedScene:
    """A random scene: 2-4 spheres and 2-4 boxes within ``radius`` of ``centre``, and a
    background plane facing ``viewer`` at ``background x radius`` behind the centre.

    Textures vary per object: the coarsest features span 8 to 24 times the finest, which
    spans :data:`MIN_FEATURE_PIXELS` pixels of a camera of focal length ``focal`` (pixels) at
    ``viewer``; contrasts range from 0.15 (faint) to 0.7; half the objects carry sharp-edged
    blotches of contrast 0.05 to 0.3 (blotches 2 to 6 times the finest detail).
    """
    rng = np.random.default_rng(seed)
    centre = np.asarray(centre, dtype=np.float64)
    toward = np.asarray(viewer, dtype=np.float64) - centre
    toward /= np.linalg.norm(toward)
    n_spheres, n_boxes = rng.integers(2, 5), rng.integers(2, 5)
    spheres = np.hstack([
        centre + rng.uniform(-0.7, 0.7, (n_spheres, 3)) * radius,
        rng.uniform(0.12, 0.35, (n_spheres, 1)) * radius,
    ])
    rotations = []
    for _ in range(n_boxes):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        w, x, y, z = q
        rotations.append(np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]))
    box_centres = centre + rng.uniform(-0.7, 0.7, (n_boxes, 3)) * radius
    half = rng.uniform(0.05, 0.35, (n_boxes, 3)) * radius
    plane = np.concatenate([-toward, [float(-toward @ (centre - background * radius * toward))]])
    count = n_spheres + n_boxes + 1
    colours = rng.uniform(0.35, 1.0, (count, 3))
    contrasts = rng.uniform(0.15, 0.7, count)
    distances = np.linalg.norm(np.vstack([spheres[:, :3], box_centres, [centre - background * radius * toward]]) - viewer, axis=1)
    finest = MIN_FEATURE_PIXELS * distances / focal
    scales = finest * 2.0 ** (_OCTAVES - 1) * rng.uniform(1.0, 3.0, count)
    prints = np.where(rng.random(count) < 0.5, rng.uniform(0.05, 0.3, count), 0.0)
    return TexturedScene(spheres, np.array(rotations), box_centres, half, plane, colours, contrasts, scales, prints, seed)


def rectified_test_pair(
    seed: int,
    *,
    size: tuple[int, int] = (384, 288),
    focal: float = 380.0,
    disparities: tuple[float, float] = (5.0, 15.0),
    noise: float = 2.0,
) -> tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[np.float64]]:
    """A rectified pair with exact left disparity, laid out like Middlebury's Tsukuba:
    background at the smallest disparity, objects up to the largest.

    Returns
    -------
    left, right : (H, W, 3) uint8
    disparity : (H, W) float64
        ``f B / Z`` of the left image's pixel centres, pixels.
    """
    width, height = size
    baseline = 0.1
    K = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    left = Camera("left", K, None, np.eye(3), np.zeros(3), width, height)
    right = Camera("right", K, None, np.eye(3), np.array([-baseline, 0.0, 0.0]), width, height)
    far = focal * baseline / disparities[0]
    near = focal * baseline / disparities[1]
    centre = np.array([0.0, 0.0, (far + near) / 2 - 0.1 * (far - near)])
    radius = 0.5 * (far - near)
    scene = random_scene(seed, centre, radius, np.zeros(3), focal=focal, background=(far - centre[2]) / radius)
    rng = np.random.default_rng(10_000 + seed)
    return scene.render(left, noise=noise, rng=rng), scene.render(right, noise=noise, rng=rng), focal * baseline / scene.depth(left)
