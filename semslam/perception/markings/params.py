"""The painted-line detector's settings: every tunable (:class:`MarkingParams`), the
CMA-ES-tuned defaults for top views (:data:`TUNED`, from ``tools/tune_markings.py``), the
hand-set ones for semantic masks (:data:`MASK_PARAMS`), and the line features the
confidence regression weighs (:data:`FEATURES`)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from semslam.errors import MarkingInputError

FEATURES = (
    "width_m",  # S: mean painted width
    "intensity",  # L: mean equalised intensity between the pairs (0-255)
    "std",  # sqrt(V): mean spread of the intensity between the pairs
    "residual_px",  # O: RMS distance of the centre points from the fitted line
    "gradient",  # G: mean edge strength (intensity per pixel)
    "contrast",  # L minus the brighter of the two floor samples beside the line
    "asymmetry",  # difference between the two floor samples (cars, walls: large)
    "chroma",  # B - (R + G) / 2 between the pair (white paint: about 0, yellow: negative)
    "red_green",  # |R - G| between the pair (white and yellow paint: small)
    "floor_dev",  # the floor samples' distance from the view's median (car bodies: large)
    "log_length",  # log of the length on the ground over 0.3 m
    "fill",  # centre pixels per pixel of length (gaps lower it)
    "distance_m",  # distance of the line's middle from the vehicle centre
)
FEATURE_SCALES = np.array(
    [0.1, 255.0, 30.0, 1.0, 50.0, 50.0, 50.0, 50.0, 50.0, 50.0, 1.0, 1.0, 5.0]
)


@dataclass(frozen=True)
class MarkingParams:
    """Every tunable of the detector (pixel quantities at the working resolution,
    :meth:`shrink_factor`). The class defaults are the full-size tuning
    (:data:`FULL_SIZE`); the shipped defaults are :data:`TUNED`.

    ``weights`` are the logistic regression's: bias first, then one per entry of
    :data:`FEATURES` (features divided by ``FEATURE_SCALES``).
    """

    preseg_margin_m: float = 0.5  # not tuned: around the map's markings
    # not tuned: stages 2-7 run at this many pixels per metre at most (a finer view is
    # shrunk by the whole factor that keeps it at least this fine; the top views have 60)
    work_px_per_m: float = 60.0
    extend_ends: bool = True  # not tuned: stage 6b (line ends run on through free points)
    clahe_clip: float = 1.8732  # CLAHE clip limit (0: no equalisation)
    clahe_tiles: int = 3
    blur_sigma_px: float = 1.9995
    grad_min: float = 3.8091  # edge strength, intensity per pixel
    pair_ratio: float = 0.7455  # the opposite edge must reach pair_ratio * grad_min
    pair_angle_deg: float = 49.6422  # alpha: opposite gradients within this of pi
    min_width_m: float = 0.0602
    max_width_m: float = 0.3301
    min_contrast: float = 18.1179
    max_asymmetry: float = 101.2923  # largest difference between the two floor samples
    max_floor_dev: float = 140.8841  # largest floor-sample distance from the view's median
    link_radius_px: float = 4.2813  # the gap region growing bridges (the penalty counter)
    link_angle_deg: float = 24.7524
    link_offset_px: float = 0.6013
    link_width_ratio: float = 0.2812
    link_intensity: float = 14.2738
    min_segment_px: float = 8.7896  # shortest segment, pixels
    max_residual_px: float = 1.3777
    trim_px: float = 2.2378  # points farther from the axis fit are dropped (twice)
    cluster_angle_deg: float = 4.7503
    cluster_offset_m: float = 0.0797
    cluster_gap_m: float = 0.9815
    cluster_width_m: float = 0.0569
    cluster_intensity: float = 145.6697
    min_length_m: float = 0.247
    # fmt: off
    weights: tuple[float, ...] = (-3.8125, -0.0570, -0.1719, 0.8542, -1.0911, 0.3340, 1.7181,
                                  -0.4438, -0.5096, -1.0851, -1.0614, 1.0927, 0.7477, 1.3431)
    # fmt: on
    min_confidence: float = 0.76  # operating point: precision >= 0.96 within 5 m (validation)

    def __post_init__(self) -> None:
        if not (isinstance(self.work_px_per_m, (int, float)) and self.work_px_per_m > 0):
            raise MarkingInputError(
                f"MarkingParams.work_px_per_m: expected a number > 0, got {self.work_px_per_m!r}"
            )
        if len(self.weights) != len(FEATURES) + 1:
            raise MarkingInputError(
                f"MarkingParams.weights: expected {len(FEATURES) + 1} numbers, "
                f"got {len(self.weights)}"
            )

    def shrink_factor(self, metres_per_px: float) -> int:
        """How many times a view of ``metres_per_px`` is shrunk before stages 2-7: the
        largest whole factor that leaves at least ``work_px_per_m`` pixels per metre."""
        return max(1, int(math.floor(1.0 / (metres_per_px * self.work_px_per_m) + 1e-6)))

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready values."""
        d = asdict(self)
        d["weights"] = [float(w) for w in self.weights]
        return d

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> MarkingParams:
        """From :meth:`to_dict` output; unknown keys are refused."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise MarkingInputError(f"MarkingParams: unknown field(s) {', '.join(unknown)}")
        v = dict(values)
        if "weights" in v:
            v["weights"] = tuple(float(w) for w in v["weights"])
        if "clahe_tiles" in v:
            v["clahe_tiles"] = int(round(v["clahe_tiles"]))
        return cls(**v)


# the full-size tuning (tools/tune_markings.py, CMA-ES, 2026-11-22): about 2.5 times the
# time of TUNED for a little more recall (BENCHMARKS.md, "Painted-line detector")
FULL_SIZE = MarkingParams()
# the defaults: at 30 px per metre (the top views shrunk twice, 300 x 300), tuned there by
# tools/tune_markings.py (CMA-ES, started from FULL_SIZE with its pixel lengths halved)
TUNED = MarkingParams(
    work_px_per_m=30.0,
    clahe_clip=1.6023,
    clahe_tiles=3,
    blur_sigma_px=0.9653,
    grad_min=11.958,
    pair_ratio=0.7486,
    pair_angle_deg=39.0117,
    min_width_m=0.0579,
    max_width_m=0.3111,
    min_contrast=14.3776,
    max_asymmetry=142.7073,
    max_floor_dev=122.8642,
    link_radius_px=2.1696,
    link_angle_deg=24.9765,
    link_offset_px=0.3585,
    link_width_ratio=0.1695,
    link_intensity=38.5692,
    min_segment_px=2.6291,
    max_residual_px=0.7088,
    trim_px=0.7342,
    cluster_angle_deg=5.5223,
    cluster_offset_m=0.0777,
    cluster_gap_m=0.9938,
    cluster_width_m=0.0538,
    cluster_intensity=146.9475,
    min_length_m=0.2694,
    # fmt: off
    weights=(-3.8884, -0.1158, -0.3083, 0.4306, -0.4425, 0.5008, 1.6716, -0.525,
             -0.5121, -1.2904, -1.0155, 1.1809, 0.5661, 1.4266),
    # fmt: on
    min_confidence=0.83,
)
# the mask path (hand-set, not tuned; full size): no equalisation, a fixed edge threshold
# for 0/255 masks; on a clean mask L, V, G and colour are constant, so the confidence
# weighs only length, fill, straightness and distance
MASK_PARAMS = replace(
    FULL_SIZE,
    # off: on the real garage drive it lengthened the mapped lines and moved the map's
    # medians against the vector map from 0.126 / 0.180 m to 0.148 / 0.200 m
    extend_ends=False,
    clahe_clip=0.0,
    blur_sigma_px=1.0,
    grad_min=40.0,
    min_contrast=60.0,
    link_intensity=255.0,
    cluster_intensity=255.0,
    weights=(-3.0, 0.0, 0.0, 0.0, -2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 3.0, 3.0, -0.3),
    min_confidence=0.5,
)


__all__ = [
    "FEATURES",
    "FEATURE_SCALES",
    "FULL_SIZE",
    "MASK_PARAMS",
    "TUNED",
    "MarkingInputError",
    "MarkingParams",
]
