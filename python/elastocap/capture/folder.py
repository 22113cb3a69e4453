"""Capture folders: calibration, colour frames, silhouettes and backgrounds of a multi-view
recording, in the ZJU-MoCap / EasyMocap layout of DESIGN.md, read lazily.

::

    CAPTURE/
      intri.yml + extri.yml, rig.json, ... or any calibration Rig.load reads
      capture.toml                                  optional: offsets, missing frames, units
      images/<camera>/<frame:06d>.png|jpg|tif       colour frames (8- or 16-bit, grey, RGB(A))
      videos/<camera>.mp4|avi|mkv|mov               colour frames, for cameras without images/
      masks/<camera>/<frame:06d>.png (or mask/)     silhouettes, non-zero = foreground
      masks/<camera>.mp4|avi|mkv|mov                silhouettes as a video (thresholded at 128)
      background/<camera>.jpg|png                   empty-scene frame

A camera's frames come from its image folder or, without one, its video (frame ``i`` of a
video is the camera's frame ``i``). Frame offsets, the handling of frames some camera lacks,
and the calibration's units and up axis are set in ``capture.toml``
(:mod:`elastocap.capture.config`).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elastocap._core import InvalidInputError
from elastocap.cameras.formats import IMAGE_SUFFIXES
from elastocap.cameras.rig import Rig
from elastocap.capture.config import CONFIG_NAME, CaptureConfig, CaptureWarning, missing_policy, read_config
from elastocap.capture.listing import FrameTable, Where, by_camera, list_source, settle_frames
from elastocap.capture.media import Video, bgr_to_rgb, mask_from_pixels, read_colour, read_pixels, to_uint8

__all__ = ["Capture"]


class Capture:
    """A capture folder: a calibrated rig and, per camera and frame, images and masks.

    Open one with :meth:`Capture.open`. Opening reads the calibration and the
    configuration and lists the folders (and video headers); images and masks are read
    only when asked for, and are not kept.

    Attributes
    ----------
    root : Path
        The capture folder.
    rig : Rig
        The cameras (see :meth:`Rig.load`), in metres and y up when ``capture.toml`` gives
        ``units`` / ``up``.
    config : CaptureConfig
        What ``capture.toml`` says (defaults without one).
    skipped : dict of int to list of str
        Frames left out because some cameras lack them, and those cameras.
    incomplete : dict of int to list of str
        Frames kept without some cameras (``missing = "present"``), and those cameras.
    trimmed : dict of int to list of str
        Frames before the last camera's first frame or after the first camera's last
        (recordings of different starts or lengths), left out whatever ``missing`` says,
        and the cameras that lack them.

    Notes
    -----
    Camera folders that the rig does not name are ignored. A Capture holding videos keeps
    them open; close it with :meth:`close` or use it as a context manager.
    """

    def __init__(
        self,
        root: Path,
        rig: Rig,
        config: CaptureConfig,
        colour: FrameTable | None,
        masks: FrameTable | None,
        frames: dict[int, list[str]],
        skipped: dict[int, list[str]],
    ) -> None:
        self.root = root
        self.rig = rig
        self.config = config
        self._colour = colour
        self._masks = masks
        self._present = frames
        self.skipped = skipped
        self.trimmed: dict[int, list[str]] = {}
        self.incomplete = {f: [n for n in rig.names if n not in present] for f, present in frames.items()
                           if len(present) < len(rig)}
        self._videos: dict[Path, Video] = {}

    # -- opening --------------------------------------------------------------------------

    @classmethod
    def open(
        cls,
        path: str | Path,
        *,
        strict: bool | None = None,
        missing: str | None = None,
        size: tuple[int, int] | None = None,
        config: str | Path | None = None,
    ) -> Capture:
        """Open a capture folder.

        Parameters
        ----------
        path : str or Path
            The capture folder.
        strict : bool, optional, keyword-only
            ``True`` is ``missing="error"``, ``False`` is ``missing="skip"``.
        missing : {"error", "skip", "present"}, optional, keyword-only
            Frames that some camera lacks (in ``images/``/``videos/`` or ``masks/``):
            refused (naming the folder and frames), left out, or kept with the cameras
            that have them (at least two). Default: ``capture.toml``'s ``missing``, else
            "error". "skip" and "present" report what they did with a
            :class:`CaptureWarning` and in :attr:`skipped` / :attr:`incomplete`.
        size : (width, height), optional, keyword-only
            Image size, for calibrations that do not state it and folders without images
            to read it from (passed to :meth:`Rig.load`).
        config : str or Path, optional, keyword-only
            The configuration file (default ``path/capture.toml``, if it exists).

        Returns
        -------
        Capture

        Raises
        ------
        FileNotFoundError
            ``path`` does not exist, holds no calibration, or ``images/``, ``masks/`` or
            ``videos/`` exists but lacks a camera's folder or video.
        InvalidInputError
            A malformed calibration or configuration; frames missing in some cameras (with
            ``missing="error"``, naming the folder and the frames); two files for one frame
            (``000001.jpg`` and ``000001.png``); both ``masks/`` and ``mask/``; an
            unreadable video.
        """
        root = Path(path)
        if not root.exists():
            raise FileNotFoundError(f"capture folder not found: {root}")
        if not root.is_dir():
            raise InvalidInputError(f"path must be a capture folder, got the file {root}")
        settings = read_config(Path(config) if config is not None else root / CONFIG_NAME)
        policy = missing_policy(strict, missing, settings)
        try:
            rig = Rig.load(root, size=size, units=settings.units, up=settings.up, scale=settings.scale)
        except FileNotFoundError as error:
            raise FileNotFoundError(f"capture {root} has no calibration: {error}") from None
        names = rig.names
        unknown = sorted(set(settings.offsets) - set(names))
        if unknown:
            raise InvalidInputError(f"{CONFIG_NAME}: offsets name camera(s) {unknown} that the rig lacks")

        masks_dir = root / "masks"
        if (root / "mask").is_dir():
            if masks_dir.is_dir():
                raise InvalidInputError(f"{root} holds both masks/ and mask/: keep one")
            masks_dir = root / "mask"
        colour_dirs = [d for d in (root / "images", root / "videos") if d.is_dir()]
        colour = list_source(colour_dirs, names, settings.offsets, "colour frames") if colour_dirs else None
        masks = list_source([masks_dir], names, settings.offsets, "silhouettes") if masks_dir.is_dir() else None

        frames, skipped, trimmed = settle_frames(names, colour, masks, masks_dir, policy)
        capture = cls(root, rig, settings, colour, masks, frames, skipped)
        capture.trimmed = trimmed
        capture._report(policy)
        return capture

    def _report(self, policy: str) -> None:
        parts = []
        if self.trimmed and not self.config.offsets:
            parts.append(f"frame(s) {by_camera(self.trimmed)} cut: recordings of different lengths")
        if self.skipped:
            parts.append(f"frame(s) {by_camera(self.skipped)} left out")
        if self.incomplete:
            parts.append(f"frame(s) {by_camera(self.incomplete)} kept with the cameras present")
        if parts:
            warnings.warn(f"capture {self.root} (missing = {policy!r}): {'; '.join(parts)}", CaptureWarning,
                          stacklevel=3)

    # -- listing --------------------------------------------------------------------------

    @property
    def cameras(self) -> list[str]:
        """The camera names, in rig order."""
        return self.rig.names

    @property
    def frames(self) -> list[int]:
        """The frame numbers (sorted, on the capture's time line: see ``offsets`` in
        :mod:`elastocap.capture.config`) that every camera has in every source present
        (``images/`` or ``videos/``, and ``masks/``), or, with ``missing = "present"``, at
        least two cameras have; empty without any source."""
        return list(self._present)

    def cameras_at(self, frame: int) -> list[str]:
        """The cameras that have ``frame`` in every source, in rig order (all of them unless
        ``missing = "present"``)."""
        number = _frame_number(frame)
        if number not in self._present:
            raise FileNotFoundError(f"frame {number} is not in the capture {self.root}")
        return list(self._present[number])

    def rig_at(self, frame: int) -> Rig:
        """The rig of the cameras that have ``frame`` (see :meth:`cameras_at`)."""
        cameras = self.cameras_at(frame)
        return self.rig if len(cameras) == len(self.rig) else Rig(self.rig[name] for name in cameras)

    @property
    def has_masks(self) -> bool:
        """Whether the capture holds silhouettes (``masks/`` or ``mask/``)."""
        return self._masks is not None

    @property
    def has_images(self) -> bool:
        """Whether the capture holds colour frames (``images/`` or ``videos/``)."""
        return self._colour is not None

    @property
    def has_background(self) -> bool:
        """Whether the capture has a ``background/`` folder (per camera, see
        :meth:`background`)."""
        return (self.root / "background").is_dir()

    def __repr__(self) -> str:
        sources = [s for s, present in (("images", self._colour is not None), ("masks", self.has_masks),
                                        ("background", self.has_background)) if present]
        return (
            f"Capture({str(self.root)!r}, {len(self.rig)} cameras, {len(self._present)} frames, "
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
            A frame number (capture time line).

        Returns
        -------
        (H, W) bool
            True where the file is non-zero in any colour channel, or, for an RGBA file
            with transparency (a cut-out), where alpha is non-zero. JPEG masks and mask
            videos are thresholded at half range instead, because compression makes zero
            noisy. 16-bit files work alike.

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
        where = self._where(self._masks, camera, frame, "masks")
        if isinstance(where, tuple):
            data = self._video_frame(where, camera)
            return mask_from_pixels(data, noisy=True)
        data = read_pixels(where)
        self._check_size(where, camera, data.shape)
        return mask_from_pixels(data, noisy=where.suffix.lower() in (".jpg", ".jpeg"))

    def masks(self, frame: int) -> dict[str, NDArray[np.bool_]]:
        """The silhouettes of every camera that has the frame (:meth:`cameras_at`: all of
        them unless ``missing = "present"``).

        Parameters
        ----------
        frame : int
            A frame number.

        Returns
        -------
        dict of str to (H, W) bool
            Camera name to mask (see :meth:`mask`), in rig order.
        """
        names = self.cameras_at(frame) if _frame_number(frame) in self._present else self.cameras
        return {name: self.mask(name, frame) for name in names}

    def image(self, camera: str, frame: int) -> NDArray[np.uint8]:
        """The colour frame of one camera.

        Parameters
        ----------
        camera : str
            A camera name of the rig.
        frame : int
            A frame number (capture time line).

        Returns
        -------
        (H, W, 3) uint8
            **RGB** channel order (converted from OpenCV's BGR; pass
            ``image[:, :, ::-1]`` to cv2 functions that expect BGR). Grey files are
            expanded to three equal channels, 16-bit files scaled to 8 bits
            (``round(v / 257)``), an alpha channel dropped.

        Raises
        ------
        FileNotFoundError
            The capture has no images or videos, or none for this camera and frame.
        InvalidInputError
            Unknown camera; an unreadable file or undecodable video frame; a size that
            disagrees with the calibration.
        """
        self._check_camera(camera)
        if self._colour is None:
            raise FileNotFoundError(f"capture {self.root} has no images/ or videos/ folder")
        where = self._where(self._colour, camera, frame, "images")
        if isinstance(where, tuple):
            return bgr_to_rgb(to_uint8(self._video_frame(where, camera), where[0]))
        image = read_colour(where)
        self._check_size(where, camera, image.shape)
        return image

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
        image = read_colour(found[0])
        self._check_size(found[0], camera, image.shape)
        return image

    # -- videos ---------------------------------------------------------------------------

    def close(self) -> None:
        """Release the videos opened for reading (reopened when read again)."""
        for video in self._videos.values():
            video.close()
        self._videos.clear()

    def __enter__(self) -> Capture:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def _video_frame(self, where: tuple[Path, int], camera: str) -> NDArray[Any]:
        file, index = where
        if file not in self._videos:
            self._videos[file] = Video(file)
        data = self._videos[file].frame(index)
        self._check_size(file, camera, data.shape, what=f"frame {index}")
        return data

    def with_masks(self, folder: str | Path) -> Capture:
        """This capture with its silhouettes read from ``folder`` instead, laid out as
        ``masks/`` is (``<camera>/<frame:06d>.png``), e.g. the masks elastocap wrote into
        an output folder. Its frames are those it has that every camera has in ``folder``.

        Raises
        ------
        FileNotFoundError
            ``folder`` lacks a camera's folder.
        """
        # Masks elastocap wrote are numbered by capture frame already: no offsets.
        masks = list_source([Path(folder)], self.cameras, {}, f"silhouettes in {folder}")
        frames = {frame: present for frame, present in self._present.items()
                  if all(frame in masks[name] for name in present)}
        capture = Capture(self.root, self.rig, self.config, self._colour, masks, frames, dict(self.skipped))
        capture.trimmed = dict(self.trimmed)
        return capture

    # -- helpers --------------------------------------------------------------------------

    def _check_camera(self, camera: Any) -> None:
        if camera not in self.rig:
            raise InvalidInputError(f"camera {camera!r} is not in the rig (cameras: {', '.join(self.cameras)})")

    def _where(self, table: FrameTable, camera: str, frame: Any, source: str) -> Where:
        number = _frame_number(frame)
        try:
            return table[camera][number]
        except KeyError:
            pass
        files = table[camera]
        sample = next(iter(files.values()), None)
        if isinstance(sample, tuple):
            known = sorted(files)
            raise FileNotFoundError(
                f"{sample[0]} has no frame {number} (it has frames {known[0]} to {known[-1]})"
                if known else f"{sample[0]} has no frames"
            )
        offset = self.config.offsets.get(camera, 0)
        stem = f"{number - offset:06d}"
        raise FileNotFoundError(
            f"frame {number} of camera {camera!r} not found: no {self.root / source / camera / stem}.png or .jpg"
        )

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
