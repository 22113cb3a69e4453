"""Rigs: the named cameras of a capture, in order, loaded from and saved to the calibration
formats of :mod:`elastocap.cameras.formats`."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.cameras import formats as _calibration_files
from elastocap.cameras.camera import Camera
from elastocap.cameras.checks import as_rotation as _as_rotation

__all__ = ["Rig"]


class Rig(Mapping[str, Camera]):
    """The cameras of a capture, by name, in a fixed order.

    Parameters
    ----------
    cameras : iterable of Camera
        In rig order; names must be unique.

    Notes
    -----
    A read-only mapping: ``rig["cam0"]``, ``len(rig)``, ``for name in rig`` (in order),
    ``rig.names``, ``rig.cameras``. Load and save with :meth:`load` and :meth:`save`.
    """

    def __init__(self, cameras: Iterable[Camera]) -> None:
        ordered: dict[str, Camera] = {}
        for camera in cameras:
            if not isinstance(camera, Camera):
                raise InvalidInputError(f"cameras must hold Camera objects, got {type(camera).__name__}")
            if camera.name in ordered:
                raise InvalidInputError(f"cameras: the name {camera.name!r} appears twice")
            ordered[camera.name] = camera
        if not ordered:
            raise InvalidInputError("cameras is empty: a rig needs at least one camera")
        self._cameras = ordered

    def __getitem__(self, name: str) -> Camera:
        try:
            return self._cameras[name]
        except KeyError:
            raise KeyError(f"no camera named {name!r} in the rig (cameras: {self.names})") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._cameras)

    def __len__(self) -> int:
        return len(self._cameras)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Rig):
            return NotImplemented
        return list(self._cameras.items()) == list(other._cameras.items())

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"Rig({len(self)} cameras: {', '.join(self.names)})"

    @property
    def names(self) -> list[str]:
        """The camera names, in rig order."""
        return list(self._cameras)

    @property
    def cameras(self) -> list[Camera]:
        """The cameras, in rig order."""
        return list(self._cameras.values())

    # -- loading --------------------------------------------------------------------------

    @classmethod
    def load(
        cls,
        path: str | Path,
        *,
        size: tuple[int, int] | None = None,
        format: str | None = None,
        units: str | None = None,
        scale: float | None = None,
        up: str | None = None,
    ) -> Rig:
        """Read a rig from a capture folder or a calibration file, in any format
        elastocap knows (see :mod:`elastocap.cameras.formats`).

        Parameters
        ----------
        path : str or Path
            A calibration file, or a folder holding one. In a folder the first found of:
            ``intri.yml`` + ``extri.yml`` (EasyMocap), ``rig.json``, a COLMAP model
            (``cameras.txt`` + ``images.txt`` or ``.bin``, also under ``sparse/0/`` or
            ``sparse/``), ``calib.toml`` (Anipose / Pose2Sim, or one ``Calib*.toml``),
            ``transforms.json`` (NeRF), a single ``*_par.txt`` (Middlebury), OpenCV's
            ``intrinsics.yml`` + ``extrinsics.yml`` (stereo). A file is told by its name:
            ``intri.yml`` / ``extri.yml``, ``*.json`` (``transforms*.json`` or a
            ``"frames"`` list: NeRF), ``cameras.txt`` / ``images.txt``, ``*.bin``,
            ``*.toml``, other ``*.yml`` / ``*.yaml`` / ``*.xml`` (OpenCV stereo), other
            ``*.txt`` (Middlebury).
        size : (width, height), optional, keyword-only
            Image size for cameras whose file does not give it. Where a size is also found
            in the files or images, the two must agree.
        format : str, optional, keyword-only
            Force the format: ``easymocap``, ``json``, ``middlebury``, ``colmap``,
            ``colmap-binary``, ``anipose``, ``opencv-stereo`` or ``nerf``.
        units : {"m", "cm", "mm"}, optional, keyword-only
            The units the calibration's world is in (its translations). Given, the rig is
            converted to metres, which the body model assumes. Without it (and without
            ``scale``) world units are the file's.
        scale : float, optional, keyword-only
            Multiply world coordinates by this instead (e.g. an SfM model's arbitrary
            scale, or feet: 0.3048). Not with ``units``.
        up : {"x", "-x", "y", "-y", "z", "-z"}, optional, keyword-only
            The calibration world's up axis. Given, the world is rotated so that it
            becomes +y, elastocap's up (the synthetic captures' floor is y = 0 and the
            body stage assumes y up): e.g. ``up="z"`` maps (x, y, z) to (x, z, -y).

        Returns
        -------
        Rig

        Raises
        ------
        FileNotFoundError
            The path or a calibration file does not exist, or a folder holds no
            calibration.
        InvalidInputError
            A malformed file, a camera model or field elastocap does not support (named),
            a non-finite or invalid calibration, or no way to tell an image size; the
            message names the file and the camera.

        Notes
        -----
        Rotations printed with few digits are projected onto the nearest rotation with a
        :class:`CalibrationWarning` (see :class:`Camera`). EasyMocap: when both ``Rot_``
        and ``R_`` are present they must agree to the precision the file prints them
        with, and the matrix wins. COLMAP and NeRF files put the image origin at the
        corner of the top-left pixel: their principal points are moved by half a pixel
        to elastocap's (OpenCV's) pixel-centre origin. NeRF's camera-to-world matrices
        with OpenGL axes (y up, looking down -z) are converted to world-to-camera with
        OpenCV's axes. Without a size in the file, it comes from the camera's first
        image, mask, background or video in the folder (see :class:`elastocap.Capture`),
        else from ``size``.
        """
        records = _calibration_files.read(Path(path), size, format)
        rig = cls(_camera(record) for record in records)
        factor = world_scale(units, scale)
        rotation = up_rotation(up)
        if factor == 1.0 and rotation is None:
            return rig
        return rig.transformed(rotation=rotation, scale=factor)

    # -- saving ---------------------------------------------------------------------------

    def save(self, path: str | Path, *, format: str | None = None, model: str | None = None) -> Path:
        """Write the rig.

        Parameters
        ----------
        path : str or Path
            Where to write; the format comes from the name unless ``format`` is given:
            ``*.json`` (``rig.json``; ``transforms*.json``: NeRF), ``*_par.txt`` or other
            ``*.txt`` (Middlebury), ``cameras.txt`` / ``images.txt`` (COLMAP text, into
            that folder), ``cameras.bin`` / ``images.bin`` (COLMAP binary), ``*.toml``
            (Anipose), ``*.yml`` / ``*.yaml`` / ``*.xml`` (OpenCV stereo; ``intri.yml`` /
            ``extri.yml``: EasyMocap). A path without a suffix is a folder (created if
            needed) that receives ``intri.yml`` + ``extri.yml`` (EasyMocap), or the
            ``format``'s files. Existing files are overwritten.
        format : str, optional, keyword-only
            As in :meth:`load`.
        model : str, optional, keyword-only
            COLMAP only: the camera model to write (``SIMPLE_PINHOLE``, ``PINHOLE``,
            ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``, ``FULL_OPENCV``); default the
            simplest that holds each camera.

        Returns
        -------
        Path
            The file or folder written.

        Raises
        ------
        InvalidInputError
            The format cannot hold the rig (skew in COLMAP or NeRF, distortion terms the
            format or the chosen COLMAP model lacks, distortion in Middlebury, other than
            two cameras or a first camera off the origin in OpenCV stereo); the message
            names the camera and what the format lacks.

        Notes
        -----
        EasyMocap, rig.json, Middlebury, OpenCV stereo and COLMAP text store every number
        exactly (17 significant digits or the shortest exact decimal; the half-pixel shift
        of COLMAP and NeRF in exact decimal arithmetic), so :meth:`load` gives back the
        same cameras bit for bit. Formats that store the rotation differently round it:
        COLMAP (quaternion) and Anipose (Rodrigues vector) change R by a few units in the
        last place; NeRF (camera-to-world) changes t likewise; COLMAP binary stores
        ``cx + 0.5`` as a double, exact unless it needs one more bit than ``cx``.
        """
        _, target = _calibration_files.write(
            Path(path), self.cameras, format, **({"model": model} if model is not None else {})
        )
        return target

    # -- world frames ---------------------------------------------------------------------

    def transformed(
        self, *, rotation: Any = None, translation: Any = None, scale: float = 1.0
    ) -> Rig:
        """The rig in a new world frame ``X' = scale * (rotation @ X) + translation``.

        Parameters
        ----------
        rotation : (3, 3) array_like, optional, keyword-only
            A rotation (default identity).
        translation : (3,) array_like, optional, keyword-only
            In the new world's units (default zero).
        scale : float, keyword-only
            Positive; camera coordinates scale with the world, so projections are unchanged.

        Returns
        -------
        Rig
            Cameras with ``R' = R A^T`` and ``t' = scale t - R' b``: every world point maps
            to the same pixel in both rigs.
        """
        if not (isinstance(scale, (int, float)) and np.isfinite(scale) and scale > 0):
            raise InvalidInputError(f"scale must be a positive number, got {scale!r}")
        A = np.eye(3) if rotation is None else _as_rotation("rotation", rotation)
        b = np.zeros(3) if translation is None else np.asarray(translation, dtype=np.float64).reshape(3)
        cameras = []
        for camera in self.cameras:
            R = camera.R @ A.T
            cameras.append(camera.replace(R=R, t=scale * camera.t - R @ b))
        return Rig(cameras)

    def relative_to(self, name: str) -> Rig:
        """The rig in camera ``name``'s frame: that camera gets ``R = I``, ``t = 0``
        exactly (what the OpenCV stereo format needs); world units unchanged."""
        reference = self[name]
        moved = self.transformed(rotation=reference.R, translation=reference.t)
        return Rig(
            camera.replace(R=np.eye(3), t=np.zeros(3)) if camera.name == name else camera
            for camera in moved.cameras
        )


# Metres per unit.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
# Rotations taking each axis to +y (up_rotation); "z" is the body model's z-up -> y-up.
_UP = {
    "y": None,
    "-y": [[1, 0, 0], [0, -1, 0], [0, 0, -1]],
    "z": [[1, 0, 0], [0, 0, 1], [0, -1, 0]],
    "-z": [[1, 0, 0], [0, 0, -1], [0, 1, 0]],
    "x": [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
    "-x": [[0, 1, 0], [-1, 0, 0], [0, 0, 1]],
}


def world_scale(units: Any, scale: Any) -> float:
    """The factor to metres from ``units`` or ``scale`` (1 with neither)."""
    if units is not None and scale is not None:
        raise InvalidInputError("give units or scale, not both")
    if units is not None:
        if units not in UNITS:
            raise InvalidInputError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
        return UNITS[units]
    if scale is None:
        return 1.0
    if isinstance(scale, bool) or not isinstance(scale, (int, float, np.floating)) or not (np.isfinite(scale) and scale > 0):
        raise InvalidInputError(f"scale must be a positive number, got {scale!r}")
    return float(scale)


def up_rotation(up: Any) -> NDArray[np.float64] | None:
    """The rotation taking axis ``up`` to +y, or None for none."""
    if up is None:
        return None
    key = up.lstrip("+") if isinstance(up, str) else up
    if key not in _UP:
        raise InvalidInputError(f"up must be one of x, -x, y, -y, z, -z, got {up!r}")
    matrix = _UP[key]
    return None if matrix is None else np.array(matrix, dtype=np.float64)


def _camera(record: _calibration_files.CameraRecord) -> Camera:
    """A Camera from a file's record, with construction errors prefixed by the file and
    camera they come from."""
    try:
        return Camera(record.name, record.K, record.dist, record.R, record.t, record.width, record.height)
    except InvalidInputError as error:
        raise InvalidInputError(f"{record.where}: camera {record.name!r}: {error}") from None
