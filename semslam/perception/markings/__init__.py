"""Painted line markings in top views: Houben's classical detector, vectorised.

The stages (Houben et al. 2016, ``../shared/DESIGN.md``, "Houben"):

1. presegmentation (optional): only pixels near the map's markings, given as segments
   in the vehicle frame around the predicted pose, are looked at;
2. contrast equalisation (CLAHE) of the marking channel ``(R + G) / 2`` (white and
   yellow paint are both bright there; green or grey floors are not);
3. gradients (Sobel on a Gaussian-smoothed image) and non-maximum suppression along
   the gradient;
4. symmetry: from every edge pixel, walk along its gradient (into the brighter side)
   up to the largest line width and pair it with the first pixel whose gradient is
   opposite (within ``pair_angle_deg`` of pi) and a local maximum; pairs whose floor
   samples beside the line are not darker by ``min_contrast``, differ from each other
   (``max_asymmetry``) or from the view's floor (``max_floor_dev``) are dropped; at the
   pair's centre pixel keep the means of the intensity between the pair ``L``, its
   variance ``V``, the gradient strength ``G``, the width ``S`` and the orientation
   ``O`` (plus contrast, asymmetry, colour and floor level);
5. region growing into short segments: neighbouring centre pixels (within
   ``link_radius_px``: the gap the penalty counter forgives) are joined when their
   ``O``, ``S`` and ``L`` agree and the step runs along the line; the connected
   components of that graph are the segments (all pixels at once instead of one seed
   at a time), fitted by their principal axis twice without outliers, straight ones kept;
6. single-link clustering of segments into lines (angle, offset across, gap along,
   width, intensity); a line is the principal axis of its centre points, its ends the
   extreme end points of its segments projected onto it, then moved to where the
   intensity along the line falls half way to the floor (the gradients stop short);
7. confidence: logistic regression over the line's features (:data:`FEATURES`).

Pixels are OpenCV's (u right, v down, centres at integers); results are in the
vehicle frame (x forward, y left, metres) through :class:`~semslam.rig.TopviewSpec`.
The parameters (:data:`TUNED`, the defaults) were tuned with CMA-ES on simulated top
views by ``tools/tune_markings.py``; the benchmark is ``benchmarks/bench_markings.py``.
By default stages 2-7 run at 30 px per metre (``work_px_per_m``): the 600 x 600 top
view shrunk twice, in about 40 % of the time; :data:`FULL_SIZE` runs them on the top
view itself (60 px per metre). Lines are returned in the view's pixels either way.
Semantic masks of the line class (:meth:`MarkingDetector.detect_mask`) are resampled to
:data:`MASK_PARAMS`' ``work_px_per_m`` (the top views' 60) and run through stages 3-7.

The pieces: :mod:`~semslam.perception.markings.params` (settings, tuned defaults,
features), :mod:`~semslam.perception.markings.edges` (stages 3-4),
:mod:`~semslam.perception.markings.segments` (stages 5-7) and
:mod:`~semslam.perception.markings.detector` (checks, stage 2, the public detector).
"""

from semslam.perception.markings.detector import MarkingDetector, marking_channel
from semslam.perception.markings.params import (
    FEATURE_SCALES,
    FEATURES,
    FULL_SIZE,
    MASK_PARAMS,
    TUNED,
    MarkingInputError,
    MarkingParams,
)
from semslam.perception.markings.segments import MarkingLines

__all__ = [
    "FEATURES",
    "FEATURE_SCALES",
    "FULL_SIZE",
    "MASK_PARAMS",
    "MarkingLines",
    "TUNED",
    "MarkingDetector",
    "MarkingInputError",
    "MarkingParams",
    "marking_channel",
]
