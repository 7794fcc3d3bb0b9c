"""Evaluation against ground truth: pure functions, no file I/O.

- :mod:`semslam.evaluation.alignment`: closed-form SE(2) fit of point sets.
- :mod:`semslam.evaluation.map_metrics`: a built map against the true map.
"""

from semslam.evaluation.alignment import apply_se2, fit_se2, transform_map
from semslam.evaluation.map_metrics import MapMetrics, evaluate_map, fit_map_alignment

__all__ = [
    "MapMetrics",
    "apply_se2",
    "evaluate_map",
    "fit_map_alignment",
    "fit_se2",
    "transform_map",
]
