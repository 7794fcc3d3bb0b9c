"""The drive folder: what ``semslam simulate`` writes and ``semslam map`` reads.

::

    drive/
      drive.json                 name, start pose, frame rate, source    (DriveInfo)
      rig.json                   cameras, top view, vehicle               (semslam.rig.Rig)
      odometry.csv               t,speed,yaw_rate                         (Odometry)
      frames.csv                 t,topview,front,...  relative image paths (FrameIndex)
      images/...                 png or jpg
      groundtruth.tum            optional: true vehicle poses (TUM)
      world.json                 optional: the true map (map format)
      observations/<name>.jsonl  optional: FrameObservations per frame ("exact", "noisy"...)

:class:`Drive` reads lazily: opening checks only that the four required files
exist; each part is parsed on first use and kept.
"""

from __future__ import annotations

import os
from functools import cached_property
from pathlib import Path

import numpy as np

from semslam.errors import DriveError
from semslam.geometry import FloatArray
from semslam.io.drive_info import DriveInfo, read_drive_info, write_drive_info
from semslam.io.errors import DriveFormatError
from semslam.io.frames import FrameIndex, read_frames, write_frames
from semslam.io.map_json import load_map
from semslam.io.observations import read_observations
from semslam.io.odometry import Odometry, read_odometry, write_odometry
from semslam.io.rig_json import load_rig
from semslam.io.tum import read_tum
from semslam.rig import Rig
from semslam.types import FrameObservations, SemanticMap

__all__ = [
    "DRIVE_JSON",
    "FRAMES_CSV",
    "GROUNDTRUTH_TUM",
    "OBSERVATIONS_DIR",
    "ODOMETRY_CSV",
    "REQUIRED_FILES",
    "RIG_JSON",
    "WORLD_JSON",
    "Drive",
    "DriveFormatError",
    "DriveInfo",
    "FrameIndex",
    "Odometry",
    "observations_file",
    "is_drive_file",
    "read_drive_info",
    "read_frames",
    "read_odometry",
    "write_drive_info",
    "write_frames",
    "write_odometry",
]

DRIVE_JSON = "drive.json"
RIG_JSON = "rig.json"
ODOMETRY_CSV = "odometry.csv"
FRAMES_CSV = "frames.csv"
GROUNDTRUTH_TUM = "groundtruth.tum"
WORLD_JSON = "world.json"
OBSERVATIONS_DIR = "observations"
REQUIRED_FILES = (DRIVE_JSON, RIG_JSON, ODOMETRY_CSV, FRAMES_CSV)
OWN_FILES = (*REQUIRED_FILES, GROUNDTRUTH_TUM, WORLD_JSON, "config.json", "vector_map.json")
"""The top-level files the commands that write drive folders (``simulate``, ``import``) put
there."""


def is_drive_file(folder: str | os.PathLike[str], path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is an existing file of the drive folder ``folder``: one of its
    :data:`OWN_FILES` or anything in its subfolders (observations, images, labels), which no
    command may write over."""
    path = Path(path)
    if not os.path.lexists(path):
        return False
    try:
        relative = path.resolve().relative_to(Path(folder).resolve())
    except ValueError:
        return False
    return len(relative.parts) > 1 or relative.name in OWN_FILES


def observations_file(folder: str | os.PathLike[str], name: str) -> Path:
    """Path of the observation set ``name`` in a drive folder."""
    return Path(folder) / OBSERVATIONS_DIR / f"{name}.jsonl"


class Drive:
    """A drive folder on disk, read lazily. Create with :meth:`Drive.open`.

    Parsed parts are cached and shared: do not modify the arrays returned.
    """

    def __init__(self, folder: Path) -> None:
        """Use :meth:`Drive.open`, which checks the folder first."""
        self.folder = folder
        self._odometry: Odometry | None = None
        self._frames: FrameIndex | None = None

    @classmethod
    def open(cls, folder: str | os.PathLike[str]) -> Drive:
        """Open a drive folder.

        Raises:
            DriveError: the folder does not exist or lacks drive.json, rig.json,
                odometry.csv or frames.csv (the message names the missing file).
            DriveFormatError: drive.json is broken (read here, so that every command
                refuses such a folder, whichever parts it goes on to read).
        """
        path = Path(folder)
        if path.is_file():
            raise DriveError(f"{os.fspath(path)}: a file, not a drive folder")
        if not path.is_dir():
            raise DriveError(f"{os.fspath(path)}: drive folder not found")
        missing = [name for name in REQUIRED_FILES if not (path / name).is_file()]
        if missing:
            raise DriveError(f"{os.fspath(path)}: not a drive folder, missing {', '.join(missing)}")
        drive = cls(path)
        drive.info  # noqa: B018 (read now: a broken drive.json is refused at once)
        return drive

    def __repr__(self) -> str:
        return f"Drive({os.fspath(self.folder)!r})"

    # ------------------------------------------------------------------ required parts

    @cached_property
    def info(self) -> DriveInfo:
        """drive.json's content (DriveFormatError when broken)."""
        return read_drive_info(self.folder / DRIVE_JSON)

    @cached_property
    def rig(self) -> Rig:
        """The sensor rig from rig.json (FormatError when broken)."""
        return load_rig(self.folder / RIG_JSON)

    @property
    def start_pose(self) -> FloatArray:
        """(3,) start pose ``(x, y, yaw)`` in the map frame; the origin when unknown."""
        start = self.info.start_pose
        return np.zeros(3) if start is None else np.array(start, dtype=float)

    def odometry(self) -> Odometry:
        """The odometry samples (DriveFormatError when odometry.csv is broken)."""
        if self._odometry is None:
            self._odometry = read_odometry(self.folder / ODOMETRY_CSV)
        return self._odometry

    def frames(self) -> FrameIndex:
        """Frame times and image paths (DriveFormatError when frames.csv is broken)."""
        if self._frames is None:
            self._frames = read_frames(self.folder / FRAMES_CSV)
        return self._frames

    # ------------------------------------------------------------------ optional parts

    def groundtruth(self) -> tuple[FloatArray, FloatArray] | None:
        """True poses ``(t (N,), poses (N, 3))`` from groundtruth.tum, or None if absent.

        Raises:
            FormatError: the file is broken.
        """
        path = self.folder / GROUNDTRUTH_TUM
        return read_tum(path) if path.is_file() else None

    def world(self) -> SemanticMap | None:
        """The true map from world.json, or None if absent.

        Raises:
            MapError: the file is broken.
        """
        path = self.folder / WORLD_JSON
        return load_map(path) if path.is_file() else None

    def observation_names(self) -> list[str]:
        """Names of the observation sets present in ``observations/``, sorted."""
        folder = self.folder / OBSERVATIONS_DIR
        if not folder.is_dir():
            return []
        return sorted(p.stem for p in folder.glob("*.jsonl") if p.is_file())

    def observations(self, name: str) -> list[FrameObservations]:
        """The observation set ``observations/<name>.jsonl``.

        Raises:
            DriveError: no such set (the message lists the available ones), the file
                holds no observations (nothing to map or localize), or they end before the
                last frame of frames.csv (a file cut at a line boundary).
            FormatError: the file is broken.
        """
        path = observations_file(self.folder, name)
        if not path.is_file():
            available = ", ".join(self.observation_names()) or "none"
            listed = " (drive.json lists it)" if name in self.info.observations else ""
            raise DriveError(
                f"{os.fspath(path)}: no observation set '{name}'{listed}; available: {available}"
            )
        frames = read_observations(path)
        if not frames:
            raise DriveError(f"{os.fspath(path)}: no observations (the file has no frames)")
        frame_times = self.frames().t
        if len(frame_times) and frames[-1].t < frame_times[-1] - 1e-6:
            raise DriveError(
                f"{os.fspath(path)}: the observations end at t = {frames[-1].t:.3f} s, "
                f"{FRAMES_CSV} runs to {frame_times[-1]:.3f} s (the file looks cut short)"
            )
        return frames

    def image_path(self, column: str, i: int) -> Path:
        """Path of the image of frame ``i`` (0-based) in column ``column`` of frames.csv.

        Raises:
            DriveError: unknown column, ``i`` out of range, no image for that
                frame, or the image file does not exist.
        """
        frames = self.frames()
        csv = os.fspath(self.folder / FRAMES_CSV)
        if column not in frames.images:
            columns = ", ".join(frames.images) or "none"
            raise DriveError(f"{csv}: no column '{column}' (image columns: {columns})")
        if not 0 <= i < len(frames):
            raise DriveError(f"{csv}: frame {i} out of range (the drive has {len(frames)} frames)")
        relative = frames.images[column][i]
        if not relative:
            raise DriveError(f"{csv}: frame {i} has no {column} image")
        path = self.folder / relative
        if not path.is_file():
            raise DriveError(f"{os.fspath(path)}: image file missing ({csv}: frame {i}, {column})")
        return path
