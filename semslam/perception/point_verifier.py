"""A second look at each marking-point candidate: a small CNN on a sharper, turned patch.

The marking-point CNN (:mod:`semslam.perception.marking_points`) sees the top view shrunk
to 256 px and scores every grid cell. Its confident mistakes are few kinds of place: the
back corners of a row (a separator meeting the rear line looks like an entrance T),
hazard stripes, car edges and the image border; a third of its misses are true points it
scored just under its threshold, and most of the rest it placed 10-20 px off or turned
more than 30 deg (``models/marking_points.md``). The verifier looks again at each
candidate the grid offers above a low threshold, in a patch cut from the full-resolution
top view around the point and turned so that the point's direction (its separator, into
the slot) points up. It returns the probability that a marking point lies within 20 px of
the candidate, and where exactly: the move to it and the turn to its direction.

Patch: :data:`PATCH_PX` square, uint8 BGR, covering :data:`SPAN_PX` top-view pixels
(1.6 m in a ps2.0 view) centred on the point; pixels outside the view are black, as the
ego box is. A model takes ``(N, PATCH_PX, PATCH_PX, 3)`` uint8 and returns ``(N, 5)``:
the probability, the move along the patch's right and up in top-view pixels, and the cosine
and sine of the turn (:func:`refined`). Two are shipped (:data:`DEFAULT_MODELS`, both
trained by ``tools/train_point_verifier.py`` on the shipped marking-point pair's candidates
in simulated views; see ``models/point_verifier.md`` and ``point_verifier_turned.md``),
and the verifier returns the mean of their verdicts: the second saw candidates turned up to
45 deg off their separator in training, as the grid turns some real ones, and the first
did not.
"""

from __future__ import annotations

import math
import os

import numpy as np

from semslam.errors import PerceptionError
from semslam.geometry import wrap_angle
from semslam.perception import onnx_model
from semslam.perception.beside import run_beside

PATCH_PX = 64
"""Side of a verifier patch, pixels."""

SPAN_PX = 96.0
"""Top-view pixels one patch side covers (1.6 m at ps2.0's 60 px per metre)."""

DEFAULT_MODELS = ("point_verifier.onnx", "point_verifier_turned.onnx")
"""The shipped verifiers, whose verdicts are averaged: the first trained on candidates turned
by up to 8 deg, the second (``--wide-turn-deg 45``) also on candidates turned by up to
45 deg. Either alone is about as good on simulated views; their mean keeps more real points
and lets fewer false ones through (``models/point_verifier_turned.md``)."""

MIRROR_LOOK_BAND = (0.05, 0.95)
"""Probabilities of a first look that get a second, mirrored one (:meth:`PointVerifier.score`)."""

_MIRRORED_SIGN = np.array([1.0, -1.0, 1.0, 1.0, -1.0])
"""A verdict of the mirrored patch, mirrored back: the move along the patch's right and the
sine of the turn change sign."""


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
        ``uv + s (x - c) r - s (y - c) d`` (bilinear) with ``s = SPAN_PX / PATCH_PX``,
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


def refined(uv: np.ndarray, directions: np.ndarray, verdicts: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Points and directions moved and turned as the verifier says.

    Args:
        uv: (N, 2) pixels; directions: (N,) radians (image coordinates), as cropped.
        verdicts: (N, 5) from :meth:`PointVerifier.verdicts`.

    Returns:
        (N, 2) points ``uv + right * r + up * d`` (``d`` the direction, ``r`` the patch's
        right, as in :func:`crop_point_patches`) and (N,) directions turned by
        ``atan2(sine, cosine)``, wrapped to (-pi, pi].
    """
    uv = np.asarray(uv, float).reshape(-1, 2)
    a = np.asarray(directions, float)
    v = np.asarray(verdicts, float).reshape(-1, 5)
    dx, dy = np.cos(a), np.sin(a)
    moved = uv + v[:, 1:2] * np.stack([-dy, dx], 1) + v[:, 2:3] * np.stack([dx, dy], 1)
    turned = wrap_angle(a + np.arctan2(v[:, 4], v[:, 3]))
    return moved, turned


def _mean_verdict(verdicts: list[np.ndarray]) -> np.ndarray:
    """The mean of several (N, 5) verdicts of the same patches, the turn's cosine and sine
    made a unit vector again."""
    mean = np.mean(verdicts, axis=0)
    mean[:, 3:] /= np.maximum(np.hypot(mean[:, 3], mean[:, 4]), 1e-9)[:, None]
    return mean


class PointVerifier:
    """The verifier CNNs on one onnxruntime thread: the mean verdict of one or more models.

    Args:
        model_path: an ONNX file, or several whose verdicts are averaged; default the
            shipped pair :data:`DEFAULT_MODELS`.
        mirror_look: give the candidates of an uncertain first verdict a second look at
            their patch mirrored left-right (:meth:`score`).

    Raises:
        PerceptionError: no model is given, or one is missing or not loadable, or does
            not take ``(N, PATCH_PX, PATCH_PX, 3)`` uint8 and return ``(N, 5)``.
    """

    def __init__(
        self,
        model_path: str | os.PathLike[str] | list | tuple | None = None,
        mirror_look: bool = True,
    ) -> None:
        self.mirror_look = mirror_look
        self.paths = onnx_model.model_paths(model_path, DEFAULT_MODELS, "point verifier")
        self._sessions = [onnx_model.load_session(p) for p in self.paths]
        for path, session in zip(self.paths, self._sessions, strict=True):
            inp, out = session.get_inputs()[0], session.get_outputs()[0]
            if (
                list(inp.shape)[1:] != [PATCH_PX, PATCH_PX, 3]
                or inp.type != "tensor(uint8)"
                or len(out.shape) != 2
                or out.shape[1] != 5
            ):
                raise PerceptionError(
                    f"{path}: expected input (N, {PATCH_PX}, {PATCH_PX}, 3) uint8 and output "
                    f"(N, 5), got {inp.shape} {inp.type} and {out.shape}"
                )
        self._inputs = [session.get_inputs()[0].name for session in self._sessions]

    def _run(self, x: np.ndarray) -> np.ndarray:
        """The models' mean verdict (:meth:`verdicts`) on the patches ``x``."""
        outs = [
            session.run(None, {name: x})[0].astype(float).reshape(-1, 5)
            for session, name in zip(self._sessions, self._inputs, strict=True)
        ]
        out = _mean_verdict(outs)
        out[:, 0] = np.clip(out[:, 0], 0.0, 1.0)
        return out

    def score(self, x: np.ndarray) -> np.ndarray:
        """(N, 5) verdicts for the uint8 patches ``x`` (:meth:`verdicts`).

        A patch mirrored left-right shows the same junction (an L turned into the other
        L), so where the first verdict is uncertain (a probability inside
        :data:`MIRROR_LOOK_BAND`) the verifier looks again at the mirrored patch and the
        two verdicts are averaged, the second mirrored back (the turn's mean made a unit
        vector again). About one candidate in five of the simulated views gets the second
        look; on the real ps2.0 samples it keeps two more true points (``BENCHMARKS.md``).
        """
        out = self._run(x)
        if not self.mirror_look or not len(out):
            return out
        lo, hi = MIRROR_LOOK_BAND
        again = np.nonzero((out[:, 0] >= lo) & (out[:, 0] <= hi))[0]
        if len(again):
            mirrored = self._run(np.ascontiguousarray(x[again, :, ::-1])) * _MIRRORED_SIGN
            out[again] = _mean_verdict([out[again], mirrored])
        return out

    def verdicts(self, patches: np.ndarray) -> np.ndarray:
        """(N, 5) per patch: the probability that a marking point lies near its centre
        (within 20 px), the move to it along the patch's right and up (top-view pixels),
        and the cosine and sine of the turn from up to its direction (positive towards
        the right)."""
        x = np.ascontiguousarray(patches, dtype=np.uint8)
        if x.ndim != 4 or x.shape[1:] != (PATCH_PX, PATCH_PX, 3):
            raise PerceptionError(
                f"point verifier: expected patches (N, {PATCH_PX}, {PATCH_PX}, 3), got {x.shape}"
            )
        if len(x) < 2:
            return self.score(x) if len(x) else np.zeros((0, 5))
        # two halves, the second beside the first: each patch is scored alone, so the
        # halves give what the whole batch gives, on both cores
        half = (len(x) + 1) // 2
        second = run_beside(self.score, x[half:])
        return np.concatenate([self.score(x[:half]), second.result()])

    def verify(
        self, topview_bgr: np.ndarray, uv: np.ndarray, directions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For points ``uv`` with ``directions`` in ``topview_bgr``: (N,) probabilities,
        (N, 2) points and (N,) directions as the verifier places them (:func:`refined`)."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        directions = np.asarray(directions, float).reshape(-1)
        if len(uv) < 2:
            v = self.verdicts(crop_point_patches(topview_bgr, uv, directions))
        else:
            # two halves, each cropped and scored on its own core (the crops are a fifth
            # of the time); each patch is scored alone, so this is the whole batch's result
            def crop_and_score(rows: slice) -> np.ndarray:
                return self.score(crop_point_patches(topview_bgr, uv[rows], directions[rows]))

            mid = (len(uv) + 1) // 2
            second = run_beside(crop_and_score, slice(mid, None))
            v = np.concatenate([crop_and_score(slice(0, mid)), second.result()])
        moved, turned = refined(uv, directions, v)
        return v[:, 0], moved, turned


__all__ = [
    "DEFAULT_MODELS",
    "MIRROR_LOOK_BAND",
    "PATCH_PX",
    "SPAN_PX",
    "PointVerifier",
    "crop_point_patches",
    "refined",
]
