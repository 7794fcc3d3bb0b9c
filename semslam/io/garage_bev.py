"""The real garage drive ``../shared/realdata/garage-bev-drive`` (3D-SMLoc): frames,
odometry poses and the hand-made vector map, in one planar map frame.

Folder::

    color.txt                      timestamp of frame k on line k (0-based), seconds
    masks/NNNNNN.png               bird's-eye semantic masks (1 cm/px, vehicle at the centre)
    TUM_odmetry_interpolation.txt  odometry poses ``t x y z qx qy qz qw`` at the image times
    vector_map/point.csv           PID,B,L,H,Bx,Ly,...  (Bx = odometry y, Ly = odometry x)
    vector_map/line.csv            LID,BPID,FPID,BLID,FLID  (a line joins BPID -> FPID)

Frames (this module's choice, used by the importer):

- **map frame** = the odometry file's x-y plane (its z, roll and pitch are dropped:
  the garage has ramps, up to 7.6 deg of tilt); the vector map is put into it by
  ``x = Ly, y = Bx``.
- the recording's **body frame** is x right, y forward; semslam's vehicle frame is
  ISO 8855 (x forward, y left), so a pose's yaw is the heading of the body's +y axis
  (its projection on the map plane): yaw 0 means driving along the map's +x. Positions
  stay those of the odometry file (the mask centre).
- mask pixels: body ``x = (col - W/2) / 100, y = (H/2 - row) / 100``, i.e. vehicle
  ``x = (H/2 - row) / 100, y = (W/2 - col) / 100`` (what
  :meth:`~semslam.perception.markings.MarkingDetector.detect_mask` returns with
  centre ``(W/2, H/2)``).

Frames are matched to odometry poses by timestamp (within 1 ms); frames before the first
pose (the odometry starts about 3 frames late) or without a pose are dropped. Only frames
with a mask file are listed. Numpy only; every bad input raises
:class:`~semslam.errors.FormatError` (a broken file) or :class:`~semslam.errors.DriveError`
(a missing one) with one line naming the file and line.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semslam.errors import DriveError, FormatError
from semslam.geometry import FloatArray
from semslam.io._rows import parse_number
from semslam.io._text import read_text, text_lines
from semslam.io.map_json import MAX_COORDINATE
from semslam.io.odometry import check_gaps
from semslam.io.tum import read_tum_rows

COLOR_TXT = "color.txt"
ODOMETRY_TUM = "TUM_odmetry_interpolation.txt"
MASKS_DIR = "masks"
VECTOR_MAP_DIR = "vector_map"
POINT_CSV = "point.csv"
LINE_CSV = "line.csv"
METRES_PER_PX = 0.01
SLOT_LINE_RGB = (128, 128, 0)  # parking-slot lines
LANE_LINE_RGB = (0, 128, 0)  # lane / dashed lines
MATCH_TOLERANCE_S = 1e-3  # a frame and a pose are the same instant within this

_MASK_NAME = re.compile(r"(\d+)\.png\Z")


@dataclass(frozen=True, eq=False)
class GarageBevDrive:
    """The recording, read and put into the map frame.

    Attributes:
        folder: the recording's folder.
        frame_times: (F,) time of every image (color.txt), seconds.
        odometry_t: (N,) times of the odometry poses, strictly increasing.
        odometry_poses: (N, 3) poses ``(x, y, yaw)`` of the mask centre in the map frame,
            yaw of the vehicle's forward (body +y) axis, unwrapped (continuous).
        pose_frame: (N,) index of the frame each pose belongs to (matched by time).
        mask_frames: (M,) indices of the frames that have a mask and a pose, increasing.
        mask_paths: M paths of those masks.
        mask_pose: (M,) index into ``odometry_t`` of each mask frame's pose.
    """

    folder: Path
    frame_times: FloatArray
    odometry_t: FloatArray
    odometry_poses: FloatArray
    pose_frame: np.ndarray
    mask_frames: np.ndarray
    mask_paths: tuple[Path, ...]
    mask_pose: np.ndarray

    @property
    def mask_times(self) -> FloatArray:
        """(M,) times of the mask frames."""
        return self.odometry_t[self.mask_pose]


def open_garage_bev(folder: str | os.PathLike[str]) -> GarageBevDrive:
    """Read the recording's frames and odometry (the vector map: :func:`read_vector_map`).

    Raises:
        DriveError: the folder, color.txt, the odometry file or masks/ is missing, or no
            mask frame has a pose.
        FormatError: a broken line in color.txt or the odometry file.
    """
    root = Path(folder)
    if not root.is_dir():
        raise DriveError(f"{os.fspath(root)}: garage-bev-drive folder not found")
    for name in (COLOR_TXT, ODOMETRY_TUM):
        if not (root / name).is_file():
            raise DriveError(f"{os.fspath(root / name)}: missing (not a garage-bev-drive folder?)")
    if not (root / MASKS_DIR).is_dir():
        raise DriveError(f"{os.fspath(root / MASKS_DIR)}: mask folder missing")
    frame_times = read_frame_times(root / COLOR_TXT)
    t, poses = read_odometry_poses(root / ODOMETRY_TUM)
    pose_frame = match_times(t, frame_times, root / ODOMETRY_TUM)
    frame_to_pose = {int(f): i for i, f in enumerate(pose_frame) if f >= 0}
    numbered: dict[int, Path] = {}  # frame number -> mask, in frame order below
    for path in (root / MASKS_DIR).iterdir():
        m = _MASK_NAME.match(path.name)
        if m is None or not path.is_file():
            continue
        k = int(m.group(1))
        if k >= len(frame_times):
            raise DriveError(
                f"{os.fspath(path)}: frame {k} but {COLOR_TXT} lists {len(frame_times)} frames"
            )
        if k in numbered:
            raise DriveError(f"{os.fspath(path)}: frame {k} has a second mask, "
                             f"{numbered[k].name}")
        numbered[k] = path
    frames, paths, pose_index = [], [], []
    for k in sorted(numbered):
        if k in frame_to_pose:  # frames before the odometry starts have none: dropped
            frames.append(k)
            paths.append(numbered[k])
            pose_index.append(frame_to_pose[k])
    if not frames:
        raise DriveError(f"{os.fspath(root / MASKS_DIR)}: no mask frame has an odometry pose")
    return GarageBevDrive(
        root,
        frame_times,
        t,
        poses,
        pose_frame,
        np.array(frames, dtype=int),
        tuple(paths),
        np.array(pose_index, dtype=int),
    )


def read_frame_times(path: str | os.PathLike[str]) -> FloatArray:
    """color.txt: one timestamp per line (frame k on line k + 1), strictly increasing.

    Raises:
        FormatError: missing or empty file, a line that is not one finite number, time
            not strictly increasing; the message names the file and line.
    """
    name = os.fspath(path)
    times: list[float] = []
    for lineno, line in enumerate(text_lines(read_text(path, FormatError)), start=1):
        text = line.strip()
        where = f"{name} line {lineno}"
        if not text:
            raise FormatError(f"{where}: empty line (frame {lineno - 1} has no timestamp)")
        tokens = text.split()
        if len(tokens) != 1:
            raise FormatError(f"{where}: expected one timestamp, got {len(tokens)} fields")
        t = parse_number(tokens[0], where, "timestamp", FormatError)
        if times and not t > times[-1]:
            raise FormatError(
                f"{where}: timestamp {t!r} does not increase (previous {times[-1]!r})"
            )
        times.append(t)
    if not times:
        raise FormatError(f"{name}: no timestamps")
    return np.array(times)


def read_odometry_poses(path: str | os.PathLike[str]) -> tuple[FloatArray, FloatArray]:
    """The odometry file (TUM ``t x y z qx qy qz qw``, body x right, y forward) as planar
    poses of the vehicle frame (x forward): ``(t (N,), poses (N, 3))``, yaw unwrapped.

    Raises:
        FormatError: missing file, no poses, a wrong column count, a non-number, a zero
            quaternion, a pose whose forward axis is vertical, time not strictly
            increasing, a gap in time (:func:`~semslam.io.odometry.check_gaps`); the
            message names the file and line.
    """
    data, lines = read_tum_rows(path)
    check_gaps(data[:, 0], lambda k: f"{os.fspath(path)} line {lines[k]}")
    forward = _body_y_axis(data[:, 4:8])
    vertical = np.nonzero(np.hypot(forward[:, 0], forward[:, 1]) < 1e-3)[0]
    if len(vertical):
        where = f"{os.fspath(path)} line {lines[int(vertical[0])]}"
        raise FormatError(f"{where}: the body's forward (y) axis is vertical")
    yaw = np.unwrap(np.arctan2(forward[:, 1], forward[:, 0]))
    return data[:, 0].copy(), np.column_stack([data[:, 1], data[:, 2], yaw])


def _body_y_axis(q: FloatArray) -> FloatArray:
    """The body's +y axis in the world frame (second column of the rotation matrix) for
    quaternions ``(qx, qy, qz, qw)`` (..., 4), normalised."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w)], axis=-1)


def match_times(
    pose_t: FloatArray, frame_t: FloatArray, source: str | os.PathLike[str] = "odometry"
) -> np.ndarray:
    """(N,) index of the frame at each pose time (within :data:`MATCH_TOLERANCE_S`), -1
    where no frame is that close.

    Raises:
        FormatError: no pose matches any frame (``source`` names the pose file).
    """
    j = np.clip(np.searchsorted(frame_t, pose_t), 1, len(frame_t) - 1) if len(frame_t) > 1 else (
        np.zeros(len(pose_t), dtype=int)
    )
    if len(frame_t) > 1:
        j = np.where(np.abs(frame_t[j - 1] - pose_t) < np.abs(frame_t[j] - pose_t), j - 1, j)
    out = np.where(np.abs(frame_t[j] - pose_t) <= MATCH_TOLERANCE_S, j, -1)
    if not (out >= 0).any():
        raise FormatError(
            f"{os.fspath(source)}: no pose time matches a frame time of {COLOR_TXT} "
            f"within {MATCH_TOLERANCE_S * 1e3:g} ms"
        )
    return out


# --------------------------------------------------------------------------- vector map


def read_vector_map(folder: str | os.PathLike[str]) -> FloatArray:
    """The vector map's lines as segments ``(L, 2, 2)`` (BPID end, FPID end) in the map
    frame (``x = Ly, y = Bx``), in line.csv's order.

    Args:
        folder: the recording (holding ``vector_map/``) or ``vector_map/`` itself.

    Raises:
        DriveError: the folder, its vector map, point.csv or line.csv is missing.
        FormatError: a wrong header, column count or number, a coordinate beyond
            :data:`~semslam.io.map_json.MAX_COORDINATE`, a repeated ID, a line whose end
            point is not in point.csv, a line whose two end points coincide; the message
            names the file and line.
    """
    given = Path(folder)
    if not given.is_dir():
        raise DriveError(f"{os.fspath(given)}: vector map folder not found")
    root = given
    if not (root / POINT_CSV).is_file() and (root / VECTOR_MAP_DIR).is_dir():
        root = root / VECTOR_MAP_DIR
    points_path, lines_path = root / POINT_CSV, root / LINE_CSV
    if not points_path.is_file() and not lines_path.is_file() and root == given:
        raise DriveError(f"{os.fspath(given)}: no vector map there (neither {POINT_CSV} and "
                         f"{LINE_CSV} nor a {VECTOR_MAP_DIR}/ folder holding them)")
    for p in (points_path, lines_path):
        if not p.is_file():
            raise DriveError(f"{os.fspath(p)}: missing (vector map)")
    points: dict[int, tuple[float, float]] = {}
    for where, row in _csv_rows(points_path, ("PID", "Bx", "Ly")):
        pid = _integer(row["PID"], where, "PID")
        if pid in points:
            raise FormatError(f"{where}: repeated PID {pid}")
        bx, ly = (
            parse_number(row[c], where, c, FormatError, MAX_COORDINATE, "m") for c in ("Bx", "Ly")
        )
        points[pid] = (ly, bx)  # map x = Ly, map y = Bx
    segments: list[tuple[tuple[float, float], tuple[float, float]]] = []
    seen: set[int] = set()
    for where, row in _csv_rows(lines_path, ("LID", "BPID", "FPID")):
        lid = _integer(row["LID"], where, "LID")
        if lid in seen:
            raise FormatError(f"{where}: repeated LID {lid}")
        seen.add(lid)
        ends = []
        for column in ("BPID", "FPID"):
            pid = _integer(row[column], where, column)
            if pid not in points:
                raise FormatError(f"{where}: {column} {pid} is not in {os.fspath(points_path)}")
            ends.append(points[pid])
        if ends[0] == ends[1]:
            raise FormatError(
                f"{where}: zero-length line (BPID {row['BPID']} and FPID {row['FPID']} are the "
                "same point)"
            )
        segments.append((ends[0], ends[1]))
    return np.array(segments, dtype=float).reshape(-1, 2, 2)


def _csv_rows(path: Path, required: tuple[str, ...]):
    """(where, {column: text}) per data row of a headed CSV file, with ``required`` columns."""
    name = os.fspath(path)
    lines = text_lines(read_text(path, FormatError))
    if not lines or not lines[0].strip():
        raise FormatError(f"{name}: empty file")
    header = [h.strip().lstrip("\ufeff") for h in lines[0].split(",")]
    missing = [c for c in required if c not in header]
    if missing:
        raise FormatError(f"{name} line 1: header lacks {', '.join(missing)} ({','.join(header)})")
    rows = 0
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        fields = [f.strip() for f in line.split(",")]
        where = f"{name} line {lineno}"
        if len(fields) != len(header):
            raise FormatError(f"{where}: expected {len(header)} columns, got {len(fields)}")
        rows += 1
        yield where, dict(zip(header, fields, strict=True))
    if not rows:
        raise FormatError(f"{name}: no data rows after the header")


def _integer(text: str, where: str, column: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise FormatError(f"{where}: {column} is {text!r}, expected an integer") from None


# --------------------------------------------------------------------------- masks


def class_mask(image: np.ndarray, rgb: tuple[int, int, int], path: str = "mask") -> np.ndarray:
    """Boolean mask of the pixels of colour ``rgb`` in an (H, W, 3) **BGR** image (as
    OpenCV reads it).

    Raises:
        FormatError: not an (H, W, 3) 8-bit image.
    """
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or (
        image.dtype != np.uint8
    ):
        shape = getattr(image, "shape", None)
        raise FormatError(f"{path}: expected an 8-bit colour image, got shape {shape}")
    r, g, b = rgb
    return (image[:, :, 0] == b) & (image[:, :, 1] == g) & (image[:, :, 2] == r)


__all__ = [
    "LANE_LINE_RGB",
    "METRES_PER_PX",
    "SLOT_LINE_RGB",
    "GarageBevDrive",
    "class_mask",
    "match_times",
    "open_garage_bev",
    "read_frame_times",
    "read_odometry_poses",
    "read_vector_map",
]
