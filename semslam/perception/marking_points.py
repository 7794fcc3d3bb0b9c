"""Marking points on ps2.0 top views with a DMPR-PS-style CNN (onnxruntime only).

The networks (``models/marking_points.onnx`` and ``models/marking_points_long.onnx``, two
runs of ``tools/train_marking_points.py``, see ``models/marking_points.md``; by default the
detector averages the grids of their 8-bit twins, made for the CPU's 8-bit instructions,
:data:`DEFAULT_MODELS`) take the top
view resized to a square ``(1, S, S, 3)`` uint8 BGR image and return a ``(1, 6, G, G)``
grid: per cell the confidence that a marking point lies in it, the probability that it is
an L junction, the point's x and y offset inside the cell (0-1) and the cosine and sine of
its direction (image coordinates, ``atan2(dv, du)``, from the junction into the slot along
the separator).

By default each candidate the grid offers above :data:`CANDIDATE_THRESHOLD` gets a second
look from the verifier CNN (:mod:`semslam.perception.point_verifier`), on a sharper patch
turned to the point's direction: it moves the candidate onto its point, turns it to the
point's direction and rescores it. A point's confidence is then the geometric mean of the
grid's and the verifier's, kept at :data:`DEFAULT_THRESHOLD` (``verify=False``: the grid
alone at :data:`GRID_THRESHOLD`). Last, a classical check drops the points with no
entrance line across their separator (:mod:`semslam.perception.entrance_paint`): the ends
of bare lines, which the CNNs take for junctions.

Non-square images (for example real garage top views of 600 rows x 480 columns) are
padded with black to a centred square before the resize, so the pixel scale stays the
same on both axes; the points come back in the original image's pixels. Pixel
coordinates follow OpenCV's convention (pixel centres at integers).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semslam.errors import PerceptionError
from semslam.geometry import FloatArray
from semslam.perception import onnx_model
from semslam.perception.beside import run_beside
from semslam.perception.entrance_paint import bare_line_ends
from semslam.perception.point_verifier import PointVerifier
from semslam.types import JunctionShape

GRID_THRESHOLD = 0.7
"""Grid confidence above which a cell is a marking point when the grid alone decides: the
best F1 on simulated validation worlds 100-149 (neither trained on nor the benchmark's
0-99; see ``models/marking_points.md``)."""

CANDIDATE_THRESHOLD = 0.3
"""Grid confidence above which a cell is a candidate for the verifier. Below it no candidate
could be kept: the geometric mean reaches :data:`DEFAULT_THRESHOLD` only from a grid
confidence of ``DEFAULT_THRESHOLD ** 2`` (0.3025). 98.6 % of the labelled points of the
benchmark's held-out views have a candidate that hits them (96.7 % at
:data:`GRID_THRESHOLD`); the verifier was trained on candidates from 0.2
(``tools/train_point_verifier.py``)."""

DEFAULT_THRESHOLD = 0.55
"""Verified confidence (:func:`verified_confidence`) above which a candidate is a marking
point: the best F1 on the validation worlds 100-149 (``models/point_verifier.md``)."""

FLOAT_MODELS = ("marking_points.onnx", "marking_points_long.onnx")
"""The trained grid pair: two runs of the same recipe, whose mean is better than either on
the simulated views and in precision and F1 on the real ones (real recall is the second
run's; ``models/marking_points.md``)."""

INT8_MODELS = ("marking_points.int8.onnx", "marking_points_long.int8.onnx")
""":data:`FLOAT_MODELS` quantized to 8 bits (``tools/quantize_models.py``): 3-4 ms less per
top view on this 2-core machine, the same points within a few of 2,135 labelled
(``models/marking_points.md``)."""

INT8_AVX2_MODELS = ("marking_points.int8avx2.onnx", "marking_points_long.int8avx2.onnx")
""":data:`FLOAT_MODELS` quantized to 8 bits with 7-bit weights (onnxruntime's
``reduce_range``, ``tools/quantize_models.py``), for x86 CPUs without VNNI: there
onnxruntime's 8-bit convolutions run on AVX2's ``vpmaddubsw``, whose 16-bit sums saturate
with 8-bit weights (:data:`INT8_MODELS` lose 0.06 of real precision and recall there) but
not with 7-bit ones (``models/marking_points.md``)."""


def cpu_flags(cpuinfo: str | None = None) -> set[str]:
    """The CPU's feature flags from ``/proc/cpuinfo`` (its text, read when None; empty on a
    machine without it)."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text(errors="replace")
        except OSError:
            return set()
    return {word for line in cpuinfo.splitlines() if line.startswith("flags")
            for word in line.split(":", 1)[-1].split()}


def default_models(flags: set[str]) -> tuple[str, str]:
    """The grid pair for a CPU with these flags: the 8-bit twins where it has VNNI (the
    8-bit dot product they were made and checked on), the 7-bit-weight twins where it has
    AVX2 only, the float pair elsewhere."""
    if flags & {"avx512_vnni", "avx_vnni", "amx_int8"}:
        return INT8_MODELS
    if "avx2" in flags:
        return INT8_AVX2_MODELS
    return FLOAT_MODELS


DEFAULT_MODELS = default_models(cpu_flags())
"""The models whose grids the detector averages by default (:func:`default_models`)."""

NMS_RADIUS_PX = 10.0
"""Of two points closer than this (in the decoded image's pixels) the weaker is dropped."""


@dataclass(frozen=True, eq=False)
class MarkingPoint:
    """One detected marking point (a slot entrance corner).

    Attributes:
        uv: (2,) position, pixels, OpenCV convention (u right, v down).
        direction: radians in image coordinates, ``atan2(dv, du)``, of the separator line
            from the junction into the slot (DMPR-PS convention).
        shape: T or L junction.
        confidence: in [0, 1]: the geometric mean of the grid's and the verifier's
            (:func:`verified_confidence`), the grid's alone without the verifier.
        from_row: placed from its row, not seen: the next junction of a row of slots
            whose separator the CNNs do not see (:mod:`semslam.perception.row_completion`).
    """

    uv: FloatArray
    direction: float
    shape: JunctionShape
    confidence: float
    from_row: bool = False


def verified_confidence(grid: FloatArray, verifier: FloatArray) -> FloatArray:
    """A candidate's confidence from the grid's and the verifier's: their geometric mean."""
    return np.sqrt(np.asarray(grid, float) * np.asarray(verifier, float))


def suppress_close(uv: FloatArray, confidence: FloatArray, radius: float) -> list[int]:
    """Indices of the points to keep, by decreasing confidence: a point closer than
    ``radius`` pixels to a stronger kept one is dropped."""
    uv = np.asarray(uv, float).reshape(-1, 2)
    kept: list[int] = []
    for k in np.argsort(-np.asarray(confidence, float), kind="stable"):
        if all(math.hypot(uv[k, 0] - uv[m, 0], uv[k, 1] - uv[m, 1]) >= radius for m in kept):
            kept.append(int(k))
    return kept


def decode_grid(
    grid: np.ndarray, image_size: int, threshold: float = GRID_THRESHOLD
) -> list[MarkingPoint]:
    """Marking points from one network output grid.

    Args:
        grid: (6, G, G) or (1, 6, G, G): confidence, P(L junction), x offset, y offset
            (0-1 inside the cell), cos and sin of the direction.
        image_size: side of the square image the grid covers, pixels; cell ``(r, c)`` and
            offsets ``(ox, oy)`` decode to ``u = (c + ox) * image_size / G - 0.5`` (and ``v``
            alike), the OpenCV pixel centre of that position.
        threshold: minimum confidence.

    Returns:
        Points by decreasing confidence, none two closer than :data:`NMS_RADIUS_PX`
        (scaled by ``image_size / 600``).
    """
    g = np.asarray(grid, dtype=np.float64)
    if g.ndim == 4 and g.shape[0] == 1:
        g = g[0]
    if g.ndim != 3 or g.shape[0] != 6 or g.shape[1] != g.shape[2]:
        raise PerceptionError(f"marking-point grid: expected shape (6, G, G), got {g.shape}")
    n = g.shape[1]
    cell = float(image_size) / n
    rows, cols = np.nonzero(g[0] >= threshold)
    if not len(rows):
        return []
    conf = np.clip(g[0, rows, cols], 0.0, 1.0)
    u = (cols + np.clip(g[2, rows, cols], 0.0, 1.0)) * cell - 0.5
    v = (rows + np.clip(g[3, rows, cols], 0.0, 1.0)) * cell - 0.5
    direction = np.arctan2(g[5, rows, cols], g[4, rows, cols])
    is_l = g[1, rows, cols] >= 0.5
    radius = NMS_RADIUS_PX * float(image_size) / 600.0
    kept = suppress_close(np.stack([u, v], 1), conf, radius)
    return [
        MarkingPoint(
            np.array([u[k], v[k]]),
            float(direction[k]),
            JunctionShape.L if is_l[k] else JunctionShape.T,
            float(conf[k]),
        )
        for k in kept
    ]


def check_topview(image: object) -> np.ndarray:
    """``image`` as a uint8 (H, W, 3) array, or a one-line PerceptionError."""
    if not isinstance(image, np.ndarray):
        raise PerceptionError(f"top view: expected a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise PerceptionError(f"top view: expected dtype uint8, got {image.dtype}")
    if image.ndim != 3 or image.shape[2] != 3:
        raise PerceptionError(f"top view: expected shape (H, W, 3) BGR, got {image.shape}")
    if min(image.shape[:2]) < 16:
        raise PerceptionError(f"top view: image too small {image.shape[:2]}")
    return image


class MarkingPointDetector:
    """The marking-point CNN on one onnxruntime thread, or the mean grid of several.

    Args:
        model_path: an ONNX file, or several with the same input and output shapes whose
            grids are averaged; default the shipped pair :data:`DEFAULT_MODELS`.
        threshold: minimum confidence of a point; default :data:`DEFAULT_THRESHOLD` with
            the verifier, :data:`GRID_THRESHOLD` without.
        verify: give each candidate the verifier's second look.
        verifier_path: the verifier's ONNX file, or several whose verdicts are averaged;
            default the shipped pair.
        check_entrance: drop the points with no entrance line across their separator
            (:func:`semslam.perception.entrance_paint.bare_line_ends`).

    Raises:
        PerceptionError: a model is missing or not loadable, or its input is not
            ``(1, S, S, 3)`` uint8, or the models' input sizes differ.
    """

    def __init__(
        self,
        model_path: str | os.PathLike[str] | list | tuple | None = None,
        threshold: float | None = None,
        verify: bool = True,
        verifier_path: str | os.PathLike[str] | list | tuple | None = None,
        check_entrance: bool = True,
    ) -> None:
        self.check_entrance = check_entrance
        paths = onnx_model.model_paths(model_path, DEFAULT_MODELS, "marking points")
        self.paths = paths
        self.path = paths[0]
        self.verifier = PointVerifier(verifier_path) if verify else None
        if threshold is None:
            threshold = DEFAULT_THRESHOLD if verify else GRID_THRESHOLD
        self.threshold = float(threshold)
        self._sessions = [onnx_model.load_session(p) for p in paths]
        self._input_names = [sess.get_inputs()[0].name for sess in self._sessions]
        sizes = {self._input_size(p, sess) for p, sess in zip(paths, self._sessions, strict=True)}
        if len(sizes) != 1:
            raise PerceptionError(
                f"marking points: the models' input sizes differ {sorted(sizes)}"
            )
        self.input_size = sizes.pop()

    @staticmethod
    def _input_size(path: Path, session) -> int:
        inp = session.get_inputs()[0]
        shape = list(inp.shape)
        if (
            len(shape) != 4
            or not all(isinstance(d, int) for d in shape[1:])
            or shape[1] != shape[2]
            or shape[3] != 3
            or inp.type != "tensor(uint8)"
        ):
            raise PerceptionError(
                f"{path}: expected input (1, S, S, 3) uint8, got {shape} {inp.type}"
            )
        return int(shape[1])

    def grid(self, topview_bgr: np.ndarray) -> tuple[np.ndarray, int, tuple[int, int]]:
        """The raw (6, G, G) grid (the models' mean), the padded square side and the
        (top, left) padding."""
        import cv2

        img = check_topview(topview_bgr)
        h, w = img.shape[:2]
        side = max(h, w)
        top, left = (side - h) // 2, (side - w) // 2
        if h != w:
            img = cv2.copyMakeBorder(
                img, top, side - h - top, left, side - w - left, cv2.BORDER_CONSTANT, value=0
            )
        s = self.input_size
        if side != s:
            img = shrink(img, s) if side > s else cv2.resize(img, (s, s), cv2.INTER_LINEAR)
        x = np.ascontiguousarray(img)[None]
        return np.mean(self._run_all(x), axis=0), side, (top, left)

    def _run_all(self, x: np.ndarray) -> list[np.ndarray]:
        """Each model's (6, G, G) grid for the input batch ``x``; the second model runs
        beside the first (:mod:`semslam.perception.beside`): on a 2-core machine the pair
        takes about as long as one model."""
        feeds = [{name: x} for name in self._input_names]
        others = [
            run_beside(sess.run, None, feed)
            for sess, feed in zip(self._sessions[1:], feeds[1:], strict=True)
        ]
        first = self._sessions[0].run(None, feeds[0])[0][0]
        return [first, *(future.result()[0][0] for future in others)]

    def detect(self, topview_bgr: np.ndarray) -> list[MarkingPoint]:
        """Marking points in ``topview_bgr`` (uint8 BGR, H x W x 3), in its pixels."""
        points = self._detect(topview_bgr)
        if not self.check_entrance or not points:
            return points
        bare = bare_line_ends(
            topview_bgr, np.array([p.uv for p in points]), np.array([p.direction for p in points])
        )
        return [p for p, b in zip(points, bare, strict=True) if not b]

    def _detect(self, topview_bgr: np.ndarray) -> list[MarkingPoint]:
        """The CNNs' points, before the entrance check."""
        g, side, (top, left) = self.grid(topview_bgr)
        first = self.threshold if self.verifier is None else CANDIDATE_THRESHOLD
        h, w = topview_bgr.shape[:2]
        out = []
        for p in decode_grid(g, side, first):
            uv = p.uv - np.array([left, top], float)
            if -0.5 <= uv[0] <= w - 0.5 and -0.5 <= uv[1] <= h - 0.5:
                out.append(MarkingPoint(uv, p.direction, p.shape, p.confidence))
        if self.verifier is None or not out:
            return out
        prob, uv, direction = self.verifier.verify(
            topview_bgr, np.array([p.uv for p in out]), np.array([p.direction for p in out])
        )
        conf = verified_confidence([p.confidence for p in out], prob)
        inside = np.all((uv >= -0.5) & (uv <= np.array([w, h]) - 0.5), axis=1)
        keep = np.nonzero((conf >= self.threshold) & inside)[0]
        # two candidates the verifier moved onto the same point: the stronger stays
        kept = keep[suppress_close(uv[keep], conf[keep], NMS_RADIUS_PX * side / 600.0)]
        return [
            MarkingPoint(uv[k], float(direction[k]), out[k].shape, float(conf[k])) for k in kept
        ]


def shrink(image: np.ndarray, size: int) -> np.ndarray:
    """``cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA)`` of a square image
    larger than ``size``. When both sides are even, the top and bottom halves are resized at
    once, one beside the other (:mod:`semslam.perception.beside`): area resampling maps
    input row ``side / 2`` onto output row ``size / 2`` exactly, so the halves are the
    whole, to the bit."""
    import cv2

    side = image.shape[0]
    if side % 2 or size % 2:
        return cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA)
    def half(rows: np.ndarray) -> np.ndarray:
        return cv2.resize(rows, (size, size // 2), interpolation=cv2.INTER_AREA)

    bottom = run_beside(half, image[side // 2 :])
    return np.vstack([half(image[: side // 2]), bottom.result()])


__all__ = [
    "CANDIDATE_THRESHOLD",
    "DEFAULT_MODELS",
    "DEFAULT_THRESHOLD",
    "FLOAT_MODELS",
    "GRID_THRESHOLD",
    "INT8_AVX2_MODELS",
    "INT8_MODELS",
    "NMS_RADIUS_PX",
    "MarkingPoint",
    "MarkingPointDetector",
    "check_topview",
    "cpu_flags",
    "decode_grid",
    "default_models",
    "shrink",
    "suppress_close",
    "verified_confidence",
]
