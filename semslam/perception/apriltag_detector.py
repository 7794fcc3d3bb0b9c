"""One pupil-apriltags detector per tag family for the whole process.

pupil-apriltags 1.0.4 frees a detector's tag family before the detector
itself; destroying a *second* detector in a process then corrupts the heap
and the program aborts later, somewhere unrelated (pupil-labs/apriltags
PR #65, duckietown/lib-dt-apriltags PR #26). Every part of semslam therefore
asks for its detector here and never creates or deletes one itself. Even the
one detector can abort the process at exit (the family is freed first, then
the detector's clean-up reads it): at exit its pointer is dropped, so the
detector is leaked to the operating system instead of destroyed.
"""

from __future__ import annotations

import atexit
import functools
from typing import Any


@functools.cache
def shared_detector(family: str = "tag36h11") -> Any:
    """The process-wide ``pupil_apriltags.Detector`` for ``family`` (kept alive until exit)."""
    from pupil_apriltags import Detector

    detector = Detector(families=str(family))
    atexit.register(setattr, detector, "tag_detector_ptr", None)  # leak at exit, never destroy
    return detector
