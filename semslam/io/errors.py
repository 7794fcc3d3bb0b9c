"""Errors of the I/O layer beyond those in :mod:`semslam.errors`."""

from semslam.errors import DriveError, FormatError


class DriveFormatError(DriveError, FormatError):
    """A file inside a drive folder is broken (odometry.csv, frames.csv, drive.json):
    both a broken file (FormatError) and an unusable drive (DriveError)."""
