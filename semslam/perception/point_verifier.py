"""A second look at each marking-point candidate: a small CNN on a sharper, turned patch.

The marking-point CNN (:mod:`semslam.perception.marking_points`) sees the top view shrunk
to 256 px and scores every grid cell. Its confident mistakes are few kinds of place: the
back corners of a row (a separator meeting the rear line looks like an entrance T),
hazard stripes, car edges and the image border; and a third of its misses are true points
it scored just under its threshold (``models/marking_points.md``). The verifier looks
again at each candidate the grid offers above a low threshold, in a patch cut from the
full-resolution top view around the point and turned so that the point's direction (its
separator, into the slot) points up, and returns the probability that the candidate is a
marking point where the grid put it, pointing where the grid says (the ps2.0 hit: within
10 px and 30 deg).

Patch: :data:`PATCH_PX` square, uint8 BGR, covering :data:`SPAN_PX` top-view pixels
(1.6 m in a ps2.0 view) centred on the point; pixels outside the view are black, as the
ego box is. The model (``models/point_verifier.onnx``, trained by
``tools/train_point_verifier.py`` on the shipped marking-point pair's candidates in
simulated views; see ``models/point_verifier.md``) takes ``(N, PATCH_PX, PATCH_PX, 3)``
uint8 and returns ``(N,)`` probabilities.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from semslam.errors import PerceptionError
from semslam.perception import onnx_model
from semslam.perception.beside import run_beside

PATCH_PX = 64
"""Side of a verifier patch, pixels."""

SPAN_PX = 96.0
"""Top-view pixels one patch side covers (1.6 m at ps2.0's 60 px per metre)."""

DEFAULT_MODEL = "point_verifier.onnx"


def crop_point_patches(
    topview_bgr: np.ndarray, uv: np.ndarray, directions: np.ndarray
) -> np.ndarray:
    """Patches around points, turned so each point's direction points up.

    Args:
        topview_bgr: (H, W, 3) uint8 top view.
        uv: (N, 2) points, pixels (OpenCV convention).
        directions: (N,) radians, image coordinates, ``atan2(dv, du)``.

    Returns:
        (N, PATCH_PX, PATCH_PX, 3) uint8; patch pixel ``(x, y)`` shows the view at
        ``uv + s (x - c) r - s (y - c) d`` with ``s = SPAN_PX / PATCH_PX``,
        ``c = (PATCH_PX - 1) / 2``, ``d`` the direction and ``r = (-d_v, d_u)``.
    """
    import cv2

    uv = np.asarray(uv, float).reshape(-1, 2)
    out = np.zeros((len(uv), PATCH_PX, PATCH_PX, 3), np.uint8)
    s = SPAN_PX / PATCH_PX
    c = (PATCH_PX - 1) / 2.0
    for k, ((u, v), a) in enumerate(zip(uv, np.asarray(directions, float), strict=True)):
        dx, dy = math.cos(a), math.sin(a)
        rx, ry = -dy, dx
        src_from_patch = np.array(
            [
                [s * rx, -s * dx, u - s * c * (rx - dx)],
                [s * ry, -s * dy, v - s * c * (ry - dy)],
            ]
        )
        out[k] = cv2.warpAffine(
            topview_bgr,
            src_from_patch,
            (PATCH_PX, PATCH_PX),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0,
        )
    return out


class PointVerifier:
    """The verifier CNN on one onnxruntime thread.

    Raises:
        PerceptionError: the model is missing or not loadable, or does not take
            ``(N, PATCH_PX, PATCH_PX, 3)`` uint8.
    """

    def __init__(self, model_path: str | os.PathLike[str] | None = None) -> None:
        self.path = Path(model_path) if model_path else onnx_model.model_path(DEFAULT_MODEL)
        self._session = onnx_model.load_session(self.path)
        inp = self._session.get_inputs()[0]
        if list(inp.shape)[1:] != [PATCH_PX, PATCH_PX, 3] or inp.type != "tensor(uint8)":
            raise PerceptionError(
                f"{self.path}: expected input (N, {PATCH_PX}, {PATCH_PX}, 3) uint8, "
                f"got {inp.shape} {inp.type}"
            )
        self._input = inp.name

    def probabilities(self, patches: np.ndarray) -> np.ndarray:
        """(N,) probabilities that each patch's centre is a marking point pointing up."""
        x = np.ascontiguousarray(patches, dtype=np.uint8)
        if x.ndim != 4 or x.shape[1:] != (PATCH_PX, PATCH_PX, 3):
            raise PerceptionError(
                f"point verifier: expected patches (N, {PATCH_PX}, {PATCH_PX}, 3), got {x.shape}"
            )
        if not len(x):
            return np.zeros(0)
        # two halves, the second beside the first: each patch is scored alone, so the
        # halves give what the whole batch gives, on both cores
        half = (len(x) + 1) // 2
        rest = x[half:]
        second = run_beside(self._session.run, None, {self._input: rest}) if len(rest) else None
        parts = [self._session.run(None, {self._input: x[:half]})[0]]
        if second is not None:
            parts.append(second.result()[0])
        return np.clip(np.concatenate(parts).astype(float).reshape(-1), 0.0, 1.0)

    def verify(self, topview_bgr: np.ndarray, uv: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(N,) probabilities for points ``uv`` with ``directions`` in ``topview_bgr``."""
        return self.probabilities(crop_point_patches(topview_bgr, uv, directions))


__all__ = ["DEFAULT_MODEL", "PATCH_PX", "SPAN_PX", "PointVerifier", "crop_point_patches"]
