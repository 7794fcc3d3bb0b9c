"""One pupil-apriltags detector per tag family for the whole process.

pupil-apriltags 1.0.4 frees a detector's tag family before the detector
itself; destroying a *second* detector in a process then corrupts the heap
and the program aborts later, somewhere unrelated (pupil-labs/apriltags
PR #65, duckietown/lib-dt-apriltags PR #26). Every part of semslam therefore
asks for its detector here and never creates or deletes one itself.
"""

from __future__ import annotations

import functools
from typing import Any


@functools.cache
def shared_detector(family: str = "tag36h11") -> Any:
    """The process-wide ``pupil_apriltags.Detector`` for ``family`` (kept alive until exit)."""
    from pupil_apriltags import Detector

    return Detector(families=str(family))
