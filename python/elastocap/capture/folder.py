"""Capture folders: calibration, colour frames, silhouettes and backgrounds of a multi-view
recording, in the ZJU-MoCap / EasyMocap layout of DESIGN.md, read lazily.

::

    CAPTURE/
      intri.yml + extri.yml, or rig.json, or a *_par.txt    calibration (Rig.load)
      images/<camera>/<frame:06d>.jpg|png                    colour frames
      masks/<camera>/<frame:06d>.png    (or mask/)           silhouettes, non-zero = foreground
      videos/<camera>.mp4                                     colour frames, instead of images/
      background/<camera>.jpg|png                             empty-scene frame
"""

from __future__ import annotations

import re
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.cameras.formats import IMAGE_SUFFIXES
from elastocap.cameras.rig import Rig

__all__ = ["Capture"]

# A frame file's stem: the frame number, usually zero-padded to 6 digits.
_FRAME_STEM = re.compile(r"^\d+$")
# How many missing frames an error message lists before it says "and N more".
_LISTED = 10


class Capture:
    """A capture folder: a calibrated rig and, per camera and frame, images and masks.

    Open one with :meth:`Capture.open`. Opening reads the calibration and lists the
    folders (and video headers); images and masks are read only when asked for, and are
    not kept.

    Attributes
    ----------
    root : Path
        The capture folder.
    rig : Rig
        The cameras, from ``intri.yml`` + ``extri.yml``, ``rig.json`` or ``*_par.txt``.

    Notes
    -----
    Colour comes from ``images/`` when present, else from ``videos/`` (frame ``i`` of a
    video is frame number ``i``, counting from 0). Camera folders that the rig does not
    name are ignored. A Capture holding videos keeps them open; close it with
    :meth:`close` or use it as a context manager.
    """

    def __init__(
        self,
        root: Path,
        rig: Rig,
        images: dict[str, dict[int, Path]] | None,
        masks: dict[str, dict[int, Path]] | None,
        videos: dict[str, tuple[Path, int]] | None,
        frames: list[int],
    ) -> None:
        self.root = root
        self.rig = rig
        self._images = images
        self._masks = masks
        self._videos = videos
        self._frames = frames
        self._open_videos: dict[str, tuple[cv2.VideoCapture, int]] = {}

    # -- opening --------------------------------------------------------------------------

    @classmethod
    def open(
        cls, path: str | Path, *, strict: bool = True, size: tuple[int, int] | None = None
    ) -> Capture:
        """Open a capture folder.

        Parameters
        ----------
        path : str or Path
            The capture folder.
        strict : bool, default True, keyword-only
            Require every camera to have the same frames in each of ``images/``,
            ``masks/`` and ``videos/``. With ``strict=False``, :attr:`frames` is the
            frames all cameras have, and the others are left out.
        size : (width, height), optional, keyword-only
            Image size, for calibrations that do not state it and folders without images
            to read it from (passed to :meth:`Rig.load`).

        Returns
        -------
        Capture

        Raises
        ------
        FileNotFoundError
            ``path`` does not exist, holds no calibration, or ``images/``, ``masks/`` or
            ``videos/`` exists but lacks a camera's folder or video.
        InvalidInputError
            A malformed calibration; frames missing in some cameras (with ``strict``,
            naming the folder and the frames); two files for one frame (``000001.jpg`` and
            ``000001.png``); both ``masks/`` and ``mask/``; an unreadable video.
        """
        root = Path(path)
        if not root.exists():
            raise FileNotFoundError(f"capture folder not found: {root}")
        if not root.is_dir():
            raise InvalidInputError(f"path must be a capture folder, got the file {root}")
        try:
            rig = Rig.load(root, size=size)
        except FileNotFoundError as error:
            raise FileNotFoundError(f"capture {root} has no calibration: {error}") from None
        names = rig.names

        masks_dir = root / "masks"
        if (root / "mask").is_dir():
            if masks_dir.is_dir():
                raise InvalidInputError(f"{root} holds both masks/ and mask/: keep one")
            masks_dir = root / "mask"
        images = _list_frames(root / "images", names) if (root / "images").is_dir() else None
        masks = _list_frames(masks_dir, names) if masks_dir.is_dir() else None
        videos = _list_videos(root / "videos", names) if images is None and (root / "videos").is_dir() else None

        per_source: list[tuple[str, dict[str, set[int]]]] = []
        if images is not None:
            per_source.append(("images", {name: set(images[name]) for name in names}))
        if masks is not None:
            per_source.append((masks_dir.name, {name: set(masks[name]) for name in names}))
        if videos is not None:
            per_source.append(
                ("videos", {name: set(range(videos[name][1])) for name in names})
            )
        common: set[int] | None = None
        for source, frames_of in per_source:
            union = set().union(*frames_of.values())
            if strict:
                for name in names:
                    missing = sorted(union - frames_of[name])
                    if missing:
                        where = f"{source}/{name}.mp4" if source == "videos" else f"{source}/{name}/"
                        raise InvalidInputError(
                            f"{root / where} lacks frame(s) {_listing(missing)} that other cameras have "
                            "(pass strict=False to use only the frames all cameras have)"
                        )
            shared = set.intersection(*frames_of.values())
            common = shared if common is None else common & shared
        return cls(root, rig, images, masks, videos, sorted(common or ()))

    # -- listing --------------------------------------------------------------------------

    @property
    def cameras(self) -> list[str]:
        """The camera names, in rig order."""
        return self.rig.names

    @property
    def frames(self) -> list[int]:
        """The frame numbers (sorted) that every camera has in every source present
        (``images/`` or ``videos/``, and ``masks/``); empty without any."""
        return list(self._frames)

    @property
    def has_masks(self) -> bool:
        """Whether the capture holds silhouettes (``masks/`` or ``mask/``)."""
        return self._masks is not None

    @property
    def has_images(self) -> bool:
        """Whether the capture holds colour frames (``images/`` or ``videos/``)."""
        return self._images is not None or self._videos is not None

    @property
    def has_background(self) -> bool:
        """Whether the capture has a ``background/`` folder (per camera, see
        :meth:`background`)."""
        return (self.root / "background").is_dir()

    def __repr__(self) -> str:
        sources = [s for s, present in (("images", self._images is not None), ("videos", self._videos is not None),
                                        ("masks", self.has_masks), ("background", self.has_background)) if present]
        return (
            f"Capture({str(self.root)!r}, {len(self.rig)} cameras, {len(self._frames)} frames, "
            f"{', '.join(sources) or 'calibration only'})"
        )

    # -- reading --------------------------------------------------------------------------

    def mask(self, camera: str, frame: int) -> NDArray[np.bool_]:
        """The silhouette of one camera in one frame.

        Parameters
        ----------
        camera : str
            A camera name of the rig.
        frame : int
            A frame number.

        Returns
        -------
        (H, W) bool
            True where the file is non-zero (any colour channel; alpha is ignored). JPEG
            masks are thresholded at 128 instead, because compression makes zero noisy.

        Raises
        ------
        FileNotFoundError
            The capture has no masks, or none for this camera and frame.
        InvalidInputError
            Unknown camera; an unreadable file; a size that disagrees with the calibration.
        """
        self._check_camera(camera)
        if self._masks is None:
            raise FileNotFoundError(f"capture {self.root} has no masks/ (or mask/) folder")
        file = self._frame_file(self._masks, camera, frame, "masks")
        data = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
        if data is None:
            raise InvalidInputError(f"{file}: unreadable mask image")
        self._check_size(file, camera, data.shape)
        if data.ndim == 3:
            data = data[:, :, :3].max(axis=2)
        if file.suffix.lower() in (".jpg", ".jpeg"):
            return np.asarray(data >= 128)
        return np.asarray(data != 0)

    def masks(self, frame: int) -> dict[str, NDArray[np.bool_]]:
        """Every camera's silhouette in one frame.

        Parameters
        ----------
        frame : int
            A frame number.

        Returns
        -------
        dict of str to (H, W) bool
            Camera name to mask (see :meth:`mask`), in rig order.
        """
        return {name: self.mask(name, frame) for name in self.cameras}

    def image(self, camera: str, frame: int) -> NDArray[np.uint8]:
        """The colour frame of one camera.

        Parameters
        ----------
        camera : str
            A camera name of the rig.
        frame : int
            A frame number.

        Returns
        -------
        (H, W, 3) uint8
            **RGB** channel order (converted from OpenCV's BGR; pass
            ``image[:, :, ::-1]`` to cv2 functions that expect BGR). Grey files are
            expanded to three equal channels.

        Raises
        ------
        FileNotFoundError
            The capture has no images or videos, or none for this camera and frame.
        InvalidInputError
            Unknown camera; an unreadable file or undecodable video frame; a size that
            disagrees with the calibration.
        """
        self._check_camera(camera)
        if self._images is not None:
            file = self._frame_file(self._images, camera, frame, "images")
            return self._read_colour(file, camera)
        if self._videos is not None:
            return self._video_frame(camera, frame)
        raise FileNotFoundError(f"capture {self.root} has no images/ or videos/ folder")

    def background(self, camera: str) -> NDArray[np.uint8]:
        """The empty-scene frame of one camera, ``background/<camera>.jpg|png``.

        Parameters
        ----------
        camera : str
            A camera name of the rig.

        Returns
        -------
        (H, W, 3) uint8
            RGB, like :meth:`image`.

        Raises
        ------
        FileNotFoundError
            No background file for this camera.
        InvalidInputError
            Unknown camera; an unreadable file; a size that disagrees with the calibration.
        """
        self._check_camera(camera)
        folder = self.root / "background"
        found = [folder / f"{camera}{suffix}" for suffix in IMAGE_SUFFIXES if (folder / f"{camera}{suffix}").exists()]
        if not found:
            raise FileNotFoundError(
                f"no background for camera {camera!r}: expected {folder / camera}.png or .jpg"
            )
        if len(found) > 1:
            raise InvalidInputError(f"camera {camera!r} has several backgrounds: {', '.join(map(str, found))}")
        return self._read_colour(found[0], camera)

    # -- videos ---------------------------------------------------------------------------

    def close(self) -> None:
        """Release the videos opened for reading (reopened when read again)."""
        for capture, _ in self._open_videos.values():
            capture.release()
        self._open_videos.clear()

    def __enter__(self) -> Capture:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def _video_frame(self, camera: str, frame: int) -> NDArray[np.uint8]:
        assert self._videos is not None
        file, count = self._videos[camera]
        index = _frame_number(frame)
        if not 0 <= index < count:
            raise FileNotFoundError(f"{file} has no frame {index} (it has frames 0 to {count - 1})")
        capture, position = self._open_videos.get(camera, (None, -1))
        if capture is None:
            capture = cv2.VideoCapture(str(file))
            position = 0
            if not capture.isOpened():
                raise InvalidInputError(f"{file}: unreadable video")
        if position != index:
            capture.set(cv2.CAP_PROP_POS_FRAMES, index)
        ok, bgr = capture.read()
        self._open_videos[camera] = (capture, index + 1)
        if not ok or bgr is None:
            raise InvalidInputError(f"{file}: could not decode frame {index}")
        self._check_size(file, camera, bgr.shape, what=f"frame {index}")
        return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))

    def with_masks(self, folder: str | Path) -> Capture:
        """This capture with its silhouettes read from ``folder`` instead, laid out as
        ``masks/`` is (``<camera>/<frame:06d>.png``), e.g. the masks elastocap wrote into
        an output folder. Its frames are those it has that every camera has in ``folder``.

        Raises
        ------
        FileNotFoundError
            ``folder`` lacks a camera's folder.
        """
        masks = _list_frames(Path(folder), self.cameras)
        shared = set.intersection(*(set(table) for table in masks.values()))
        return Capture(self.root, self.rig, self._images, masks, self._videos, sorted(shared & set(self._frames)))

    # -- helpers --------------------------------------------------------------------------

    def _check_camera(self, camera: Any) -> None:
        if camera not in self.rig:
            raise InvalidInputError(f"camera {camera!r} is not in the rig (cameras: {', '.join(self.cameras)})")

    def _frame_file(self, table: dict[str, dict[int, Path]], camera: str, frame: Any, source: str) -> Path:
        number = _frame_number(frame)
        try:
            return table[camera][number]
        except KeyError:
            raise FileNotFoundError(
                f"frame {number} of camera {camera!r} not found: no {self.root / source / camera / f'{number:06d}'}"
                ".png or .jpg"
            ) from None

    def _read_colour(self, file: Path, camera: str) -> NDArray[np.uint8]:
        bgr = cv2.imread(str(file), cv2.IMREAD_COLOR)
        if bgr is None:
            raise InvalidInputError(f"{file}: unreadable image")
        self._check_size(file, camera, bgr.shape)
        return np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))

    def _check_size(self, file: Path, camera: str, shape: tuple[int, ...], what: str = "") -> None:
        expected = self.rig[camera]
        height, width = shape[:2]
        if (width, height) != (expected.width, expected.height):
            label = f"{file} {what}".rstrip()
            raise InvalidInputError(
                f"{label} is {width}x{height} but the calibration of camera {camera!r} says "
                f"{expected.width}x{expected.height}"
            )


def _frame_number(frame: Any) -> int:
    if isinstance(frame, (bool, np.bool_)) or not isinstance(frame, (int, np.integer)):
        raise InvalidInputError(f"frame must be an integer frame number, got {frame!r}")
    return int(frame)


def _listing(numbers: list[int]) -> str:
    shown = ", ".join(str(n) for n in numbers[:_LISTED])
    return shown if len(numbers) <= _LISTED else f"{shown} and {len(numbers) - _LISTED} more"


def _list_frames(folder: Path, names: list[str]) -> dict[str, dict[int, Path]]:
    """Frame number -> file, per camera, of ``folder/<camera>/<frame>.png|jpg``."""
    table: dict[str, dict[int, Path]] = {}
    for name in names:
        directory = folder / name
        if not directory.is_dir():
            raise FileNotFoundError(f"camera folder missing: {directory} (the rig names camera {name!r})")
        files: dict[int, Path] = {}
        for file in directory.iterdir():
            if file.suffix.lower() not in IMAGE_SUFFIXES or not _FRAME_STEM.match(file.stem):
                continue
            number = int(file.stem)
            if number in files:
                raise InvalidInputError(f"two files for frame {number}: {files[number]} and {file}")
            files[number] = file
        table[name] = dict(sorted(files.items()))
    return table


def _list_videos(folder: Path, names: list[str]) -> dict[str, tuple[Path, int]]:
    """Path and frame count of ``folder/<camera>.mp4``, per camera (from the header)."""
    table: dict[str, tuple[Path, int]] = {}
    for name in names:
        file = folder / f"{name}.mp4"
        if not file.exists():
            raise FileNotFoundError(f"video missing: {file} (the rig names camera {name!r})")
        capture = cv2.VideoCapture(str(file))
        try:
            count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) if capture.isOpened() else -1
        finally:
            capture.release()
        if count < 0:
            raise InvalidInputError(f"{file}: unreadable video")
        table[name] = (file, count)
    return table
