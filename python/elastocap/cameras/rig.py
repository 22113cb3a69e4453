"""Rigs: the named cameras of a capture, in order, loaded from and saved to the calibration
formats of :mod:`elastocap.cameras.formats`."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path


from elastocap._core import InvalidInputError
from elastocap.cameras import formats as _calibration_files
from elastocap.cameras.camera import Camera

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
    def load(cls, path: str | Path, *, size: tuple[int, int] | None = None) -> Rig:
        """Read a rig from a capture folder or a calibration file.

        Parameters
        ----------
        path : str or Path
            One of

            - a capture folder with ``intri.yml`` + ``extri.yml`` (preferred when present)
              or ``rig.json``, or a single ``*_par.txt``;
            - ``intri.yml`` or ``extri.yml`` itself (the pair is read from its folder);
            - a ``.json`` file in the ``rig.json`` format;
            - a Middlebury ``*_par.txt`` file.
        size : (width, height), optional, keyword-only
            Image size for cameras whose file does not give it. Where a size is also found
            in the files or images, the two must agree.

        Returns
        -------
        Rig

        Raises
        ------
        FileNotFoundError
            The path or a calibration file does not exist, or a folder holds no
            calibration.
        InvalidInputError
            A malformed file, a camera listed in ``names`` without its matrices, a
            non-finite or invalid calibration, or no way to tell an image size; the
            message names the file and the camera.

        Notes
        -----
        ``intri.yml``: ``names`` (sequence of strings), ``K_<name>`` (3x3),
        ``dist_<name>`` (1x5 or shorter; missing means none), optional ``H_<name>``,
        ``W_<name>`` (image height and width). ``extri.yml``: ``Rot_<name>`` (3x3,
        preferred) or ``R_<name>`` (3x1 Rodrigues), ``T_<name>`` (3x1); when both
        rotations are present they must agree to the precision the file prints them with
        (a few units in the last digit of each) and the matrix wins. Rotations printed with
        few digits are projected onto the nearest rotation with a
        :class:`CalibrationWarning` (see :class:`Camera`). Without ``H_``/``W_``, the size
        comes from the camera's first image, mask, background or video in the folder
        (see :class:`elastocap.Capture`), else from ``size``; with them, images are not
        opened (:class:`elastocap.Capture` checks each image's size when reading it).

        Middlebury ``*_par.txt``: a count, then one line per image ``name.png k11 .. k33
        r11 .. r33 t1 t2 t3`` (P = K [R | t]); camera names are the image names' stems;
        the size is read from the image beside the file if it exists.
        """
        records = _calibration_files.read(Path(path), size)
        return cls(_camera(record) for record in records)

    # -- saving ---------------------------------------------------------------------------

    def save(self, path: str | Path) -> None:
        """Write the rig.

        Parameters
        ----------
        path : str or Path
            A path ending in ``.json``: the ``rig.json`` format. Anything else is a folder
            (created if needed) that receives ``intri.yml`` and ``extri.yml`` in the
            EasyMocap layout, with both ``R_<name>`` (Rodrigues) and ``Rot_<name>`` (3x3)
            and the image size as ``H_<name>`` / ``W_<name>``; existing files are
            overwritten.

        Notes
        -----
        Both formats store doubles exactly (OpenCV prints 17 significant digits, JSON the
        shortest exact form), so :meth:`load` gives back exactly the same cameras.
        """
        path = Path(path)
        if path.suffix.lower() == ".json":
            _calibration_files.write_json(path, self.cameras)
        else:
            _calibration_files.write_yaml(path, self.cameras)


def _camera(record: _calibration_files.CameraRecord) -> Camera:
    """A Camera from a file's record, with construction errors prefixed by the file and
    camera they come from."""
    try:
        return Camera(record.name, record.K, record.dist, record.R, record.t, record.width, record.height)
    except InvalidInputError as error:
        raise InvalidInputError(f"{record.where}: camera {record.name!r}: {error}") from None
