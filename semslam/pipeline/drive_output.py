"""Writing a whole drive folder atomically: built in a temporary folder beside the target,
then renamed into place, so a drive folder appears only when complete and an old drive
there is replaced only then."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from semslam.errors import SemslamError
from semslam.io.atomic import signals_deferred

DRIVE_ENTRIES = frozenset({
    "config.json", "drive.json", "frames.csv", "groundtruth.tum", "images", "labels", "masks",
    "observations", "odometry.csv", "rig.json", "vector_map.json", "world.json",
})
"""What ``semslam simulate`` and ``semslam import`` write in a drive folder."""


def prepare_drive_folder(out_dir: Path, error: type[SemslamError]) -> Path:
    """A fresh temporary folder beside ``out_dir``; ``error`` (one line) when ``out_dir``
    is a file, a non-empty folder that holds no drive, or a drive folder that also holds
    files of the user's (a map written into it, say): a new drive replaces the whole folder,
    so it is never written over those."""
    out_dir = Path(out_dir).resolve()
    if out_dir.exists():
        if not out_dir.is_dir():
            raise error(f"{out_dir}: exists and is not a folder")
        if any(out_dir.iterdir()) and not (out_dir / "drive.json").exists():
            raise error(
                f"{out_dir}: folder is not empty and holds no drive; choose another output folder"
            )
        other = sorted(p.name for p in out_dir.iterdir() if p.name not in DRIVE_ENTRIES)
        if other:
            shown = ", ".join(other[:3]) + (", ..." if len(other) > 3 else "")
            raise error(
                f"{out_dir}: the drive there also holds {shown}, which a new drive would "
                "delete; move them or choose another output folder"
            )
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_dir.parent / f".{out_dir.name}.partial-{os.getpid()}"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    return tmp


def commit_drive_folder(tmp: Path, out_dir: Path) -> None:
    """Move the finished ``tmp`` folder to ``out_dir``, replacing an old drive there."""
    out_dir = Path(out_dir).resolve()
    with signals_deferred():  # Ctrl-C waits: no old drive left half-deleted beside the new
        old = None
        if out_dir.exists():
            old = out_dir.parent / f".{out_dir.name}.old-{os.getpid()}"
            out_dir.rename(old)
        try:
            tmp.rename(out_dir)
        except OSError:
            if old is not None:
                old.rename(out_dir)
            raise
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


@contextmanager
def staged_drive_folder(out_dir: Path, error: type[SemslamError]) -> Iterator[Path]:
    """Yield a temporary folder to write a drive into; on success it becomes ``out_dir``.

    On any exception the temporary folder is removed and nothing at ``out_dir`` changes;
    a :class:`SemslamError` about a file in the temporary folder is re-worded to name
    the file's place in ``out_dir`` (the user never sees the temporary name) and to say
    that nothing was written; an ``OSError``'s file name is moved there too.
    """
    out_dir = Path(out_dir).resolve()
    tmp = prepare_drive_folder(out_dir, error)
    try:
        yield tmp
    except BaseException as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        staged, final = os.fspath(tmp), os.fspath(out_dir)
        if isinstance(exc, SemslamError) and staged in str(exc):
            exc.args = (f"{str(exc).replace(staged, final)} (nothing was written)",)
        elif isinstance(exc, OSError) and str(exc.filename).startswith(staged):
            exc.filename = final + exc.filename[len(staged):]  # a disk full, a permission
        raise
    commit_drive_folder(tmp, out_dir)


__all__ = ["commit_drive_folder", "prepare_drive_folder", "staged_drive_folder"]
