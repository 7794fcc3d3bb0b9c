"""Painted slot IDs ("B17", "213") read from ps2.0-style top views.

Two steps. :func:`crop_id_patch` cuts a rectified grey patch of the floor just inside a
slot's entrance, where the simulator paints the ID (``semslam.simulation.world``: text
centre ``0.35 m + text height`` (0.35-0.55 m) into the slot along the separator, so the
glyphs span 0.53-1.18 m deep), turned so the text reads upright for a viewer in the aisle
looking into the slot. The patch covers -0.1-1.5 m into the slot (real ps2.0 garages
paint their numbers right at the entrance line, 0-0.3 m deep) and +-1.6 m across
(neighbouring slots' IDs, 2.4 m away, stay out) at 40 px per metre: 64 x 128 px.

:class:`SlotIdReader` runs the shipped CTC model (``models/slot_ids.onnx``, trained by
``tools/train_slot_ids.py``; see ``models/slot_ids.md``) and decodes greedily. CTC rather
than a fixed-slot classifier: labels have 1-4 characters of variable width and position,
and CTC needs no character alignment or length head. The graph takes raw grey levels,
normalises each patch itself and returns per-frame probabilities with the calibration
temperature already applied, so the reader is plain numpy.

Confidence of a reading = the model's probability of the whole label: the CTC sum over
every frame alignment that spells it (:func:`ctc_label_probability`), with the
temperature fitted on held-out simulated views. An earlier confidence, the product of the
emitted characters' probabilities, never saw a character the greedy path dropped (a blank
just ahead of a likely "T" reads "T21" as "21"): on the demo drive readings it gave 0.9 or
more were 95.4 % right, with the label probability 99.5 % (BENCHMARKS.md). An empty
decoding (the model sees no text) gives ``label=None``, as does a reading below
``min_confidence``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from semslam.errors import PerceptionError
from semslam.perception import onnx_model
from semslam.perception.beside import run_beside
from semslam.rig import TOPVIEW_BLACK

ALPHABET = "0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ"  # class k + 1; class 0 is the CTC blank
PATCH_HEIGHT = 64
PATCH_WIDTH = 128
PX_PER_M = 40.0  # patch resolution
DEPTH_RANGE_M = (-0.1, 1.5)  # along the slot, from the entrance line
TOPVIEW_M_PER_PX = 1.0 / 60.0  # ps2.0
SHIFTED_READS_PX = (0, -2, 2)
"""Shifts across the patch (patch px) at which :class:`SlotIdReader` reads a patch: as
cropped first, then moved 2 columns left and right when the first reading is unsure
(:data:`REREAD_BELOW`). The CTC frames are 4 px wide, so text between two frames reads
better from a shifted copy; the label most probable on average over the reads wins
(:func:`reading_from_shifted_probs`)."""
REREAD_BELOW = 0.7
"""Confidence under which the first reading is read again at the other shifts. Picked on
the calibration worlds, the lowest at which re-reading gains all that reading every crop
three times gains (0.865 -> 0.881 of readable IDs) while the labels given >= 0.9 stay the
same; on the held-out crops 0.821 -> 0.827 of readable IDs and 104 -> 107 of the 108 a
person reads, re-reading 29 % of the crops (``models/slot_ids.md``)."""

MAX_BLACK_SHARE = 0.4
"""Share of a patch's pixels at grey <= :data:`~semslam.rig.TOPVIEW_BLACK` above which it is
not read: that much of it lies off the view (or on the ego box), and no ID there is read
whole. Of the patches of held-out simulated views over this share (239 of 1,355 in test
worlds 0-99, 265 of 1,504 in validation worlds 100-149), none gave a label; over 0.3, 15
did, two of them on IDs the benchmark can check, one right (BENCHMARKS.md). Along a drive,
where slots beside the car run off the view, such patches are about half of all, and many
of their readings were unsure and read again."""


@dataclass(frozen=True)
class SlotIdReading:
    """One slot's painted ID as read: ``label`` (None when nothing readable), the
    calibrated probability that the whole label is right, and per-character
    probabilities (in reading order)."""

    label: str | None
    confidence: float
    char_confidences: tuple[float, ...]


def crop_id_patch(
    topview_bgr: np.ndarray,
    entrance_uv: np.ndarray,
    into_slot: np.ndarray,
    *,
    height: int = PATCH_HEIGHT,
    width: int = PATCH_WIDTH,
    px_per_m: float = PX_PER_M,
    depth_range_m: tuple[float, float] = DEPTH_RANGE_M,
    topview_m_per_px: float = TOPVIEW_M_PER_PX,
) -> np.ndarray:
    """The rectified (height, width) uint8 grey patch where a slot's ID is painted.

    Args:
        topview_bgr: (H, W, 3) uint8 BGR (or (H, W) grey) top view.
        entrance_uv: (2, 2) pixel coordinates of the entrance-left and entrance-right
            marking points (OpenCV convention); only their midpoint is used.
        into_slot: (2,) direction in pixels from the entrance into the slot (along the
            separator lines); normalised here.
        height, width, px_per_m, depth_range_m: the patch: rows cover ``depth_range_m``
            into the slot (row 0 deepest), columns ``width / px_per_m`` metres across,
            centred on the entrance midpoint.
        topview_m_per_px: metres per top-view pixel (1/60 for ps2.0).

    Returns:
        The patch, text upright (its up = into the slot, reading direction left to
        right as seen from the aisle). Outside the image is black.

    Raises:
        PerceptionError: wrong image type or shape, non-finite points, zero direction.
    """
    img = _grey(topview_bgr)
    e = np.asarray(entrance_uv, dtype=float)
    d = np.asarray(into_slot, dtype=float)
    if e.shape != (2, 2) or not np.isfinite(e).all():
        raise PerceptionError(f"entrance_uv: expected finite (2, 2) pixels, got shape {e.shape}")
    if d.shape != (2,) or not np.isfinite(d).all() or float(np.hypot(*d)) < 1e-9:
        raise PerceptionError(f"into_slot: expected a finite non-zero (2,) vector, got {d!r}")
    if height < 1 or width < 1 or px_per_m <= 0 or topview_m_per_px <= 0:
        raise PerceptionError("crop_id_patch: patch size and scales must be positive")
    up = d / float(np.hypot(*d))
    right = np.array([-up[1], up[0]])  # image frame is mirrored against the ground frame
    s = 1.0 / (px_per_m * topview_m_per_px)  # top-view px per patch px
    d0, d1 = depth_range_m
    mid = e.mean(axis=0)
    # patch pixel (x, y) -> top view: mid + right * (x - (w-1)/2) * s + up * depth(y)
    depth0 = d1 / topview_m_per_px  # row 0 (deepest), in top-view px
    step = (d1 - d0) / topview_m_per_px / max(height - 1, 1)  # top-view px per row
    col = right * s
    row = -up * step
    origin = mid + up * depth0 - col * (width - 1) / 2.0
    M = np.array([[col[0], row[0], origin[0]], [col[1], row[1], origin[1]]])
    return cv2.warpAffine(
        img,
        M,
        (width, height),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )


def _grey(image: np.ndarray) -> np.ndarray:
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
        kind = image.dtype if isinstance(image, np.ndarray) else type(image).__name__
        raise PerceptionError(f"topview: expected a uint8 image, got {kind}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    raise PerceptionError(f"topview: expected (H, W, 3) BGR or (H, W) grey, got {image.shape}")


def ctc_greedy(probs: np.ndarray, alphabet: str = ALPHABET) -> tuple[str, tuple[float, ...]]:
    """Greedy CTC decoding of one (T, C) probability array (class 0 blank, class k is
    ``alphabet[k - 1]``): best class per frame, repeats merged, blanks dropped.

    Returns the string and per-character confidences (the highest probability among the
    frames of each emitted character).
    """
    p = np.asarray(probs, dtype=float)
    if p.ndim != 2 or p.shape[1] != len(alphabet) + 1:
        raise PerceptionError(
            f"ctc_greedy: expected (T, {len(alphabet) + 1}) probabilities, got {p.shape}"
        )
    best = p.argmax(axis=1).tolist()
    top = p.max(axis=1).tolist()
    chars: list[str] = []
    confs: list[float] = []
    prev = 0
    for k, c in enumerate(best):
        if c != 0 and c == prev:
            confs[-1] = max(confs[-1], top[k])
        elif c != 0:
            chars.append(alphabet[c - 1])
            confs.append(top[k])
        prev = c
    return "".join(chars), tuple(confs)


def ctc_label_probability(probs: np.ndarray, label: str, alphabet: str = ALPHABET) -> float:
    """Probability of ``label`` under one (T, C) array of per-frame probabilities (class 0
    blank): the CTC forward sum over every alignment of T frames that collapses to it
    (Graves et al. 2006), frames independent given the image. The empty label is the
    all-blank path. One case of :func:`ctc_label_probabilities`."""
    p = np.asarray(probs, dtype=float)
    if p.ndim != 2 or p.shape[1] != len(alphabet) + 1:
        raise PerceptionError(
            f"ctc_label_probability: expected (T, {len(alphabet) + 1}) probabilities, "
            f"got {p.shape}"
        )
    return float(ctc_label_probabilities(p[None], [label], alphabet)[0])


def ctc_label_probabilities(
    probs: np.ndarray, labels: list[str], alphabet: str = ALPHABET
) -> np.ndarray:
    """(N,) CTC probabilities of ``labels[k]`` under ``probs[k]``, (N, T, C) per-frame
    probabilities: :func:`ctc_label_probability` for N patches at once, one pass of the
    forward recursion over the frames for all of them (labels padded to the longest).

    Raises:
        PerceptionError: wrong shape, a label count other than N, or a character not
            in ``alphabet``.
    """
    p = np.asarray(probs, dtype=float)
    if p.ndim != 3 or p.shape[2] != len(alphabet) + 1:
        raise PerceptionError(
            f"ctc_label_probabilities: expected (N, T, {len(alphabet) + 1}) probabilities, "
            f"got {p.shape}"
        )
    if len(labels) != len(p):
        raise PerceptionError(
            f"ctc_label_probabilities: {len(labels)} labels for {len(p)} probability arrays"
        )
    unknown = set("".join(labels)) - set(alphabet)
    if unknown:
        raise PerceptionError(f"ctc_label_probabilities: {sorted(unknown)} not in the alphabet")
    n_items, n_frames = p.shape[:2]
    if n_items == 0:
        return np.zeros(0)
    if n_frames == 0:
        return np.array([0.0 if label else 1.0 for label in labels])
    # states per item: blank, c1, blank, c2, ..., blank, after two guard states that emit
    # nothing; all items in one row, so a frame is four array operations on contiguous
    # memory (a guard is entered from the item before it and passes nothing on)
    classes, owner, emits, starts, skips, ends = [], [], [], [], [], []
    for k, label in enumerate(labels):
        item = [0] * (2 * len(label) + 1)
        item[1::2] = [alphabet.index(ch) + 1 for ch in label]
        classes += [0, 0, *item]
        owner += [k] * (len(item) + 2)
        emits += [False, False, *[True] * len(item)]
        starts += [False, False, *(j < 2 for j in range(len(item)))]
        # a state may be entered from itself, the one before, or (a character different
        # from the one two back) skip the blank between them
        skips += [False, False, *(j >= 2 and c != 0 and c != item[j - 2]
                                  for j, c in enumerate(item))]
        ends.append(len(classes) - 1)
    # (T, states): each frame's emission probability of each state, 0 at the guards
    emitted = p[np.array(owner), :, np.array(classes)].T * np.array(emits)
    skip = np.array(skips, float)
    buf = np.zeros(len(classes) + 2)
    alpha, before, two_before = buf[2:], buf[1:-1], buf[:-2]
    alpha[:] = emitted[0] * np.array(starts)
    for t in range(1, n_frames):
        entered = alpha + before
        entered += skip * two_before
        np.multiply(entered, emitted[t], out=alpha)
    end = np.array(ends)
    empty = np.array([not label for label in labels])
    total = alpha[end] + np.where(empty, 0.0, alpha[end - 1])
    return np.clip(total, 0.0, 1.0)


def reading_from_probs(probs: np.ndarray, alphabet: str = ALPHABET) -> SlotIdReading:
    """A :class:`SlotIdReading` from one (T, C) probability array: greedy decoding, the
    confidence the label's CTC probability (:func:`ctc_label_probability`); nothing
    decoded -> None with the probability that there is nothing (the all-blank path)."""
    return readings_from_probs(np.asarray(probs)[None], alphabet)[0]


def readings_from_probs(probs: np.ndarray, alphabet: str = ALPHABET) -> list[SlotIdReading]:
    """:func:`reading_from_probs` of each of (N, T, C) probability arrays, the CTC
    probabilities in one pass (:func:`ctc_label_probabilities`)."""
    p = np.asarray(probs, dtype=float)
    greedy = [ctc_greedy(q, alphabet) for q in p]
    confs = ctc_label_probabilities(p, [label for label, _ in greedy], alphabet)
    return [_reading(label, float(conf), chars)
            for (label, chars), conf in zip(greedy, confs, strict=True)]


def _reading(label: str, confidence: float, chars: tuple[float, ...]) -> SlotIdReading:
    if not label:
        return SlotIdReading(None, confidence, ())
    return SlotIdReading(label, confidence, tuple(min(max(float(c), 0.0), 1.0) for c in chars))


def _mostly_black(patch: np.ndarray) -> bool:
    """Whether more than :data:`MAX_BLACK_SHARE` of a uint8 patch is the view's black
    (:data:`~semslam.rig.TOPVIEW_BLACK`); any other input is left for
    :meth:`SlotIdReader.probabilities` to check."""
    return (
        patch.dtype == np.uint8
        and patch.shape == (PATCH_HEIGHT, PATCH_WIDTH)
        and np.count_nonzero(patch <= TOPVIEW_BLACK) > MAX_BLACK_SHARE * patch.size
    )


def shift_columns(patch: np.ndarray, dx: int) -> np.ndarray:
    """``patch`` moved ``dx`` columns to the right (left when negative); the columns it
    uncovers are black, as outside the top view. ``dx == 0`` returns ``patch`` itself."""
    if dx == 0:
        return patch
    out = np.zeros_like(patch)
    if dx > 0:
        out[:, dx:] = patch[:, :-dx]
    else:
        out[:, :dx] = patch[:, -dx:]
    return out


def reading_from_shifted_probs(probs: np.ndarray, alphabet: str = ALPHABET) -> SlotIdReading:
    """A :class:`SlotIdReading` from one patch read at several shifts, (S, T, C)
    probabilities: each shift's greedy label is a candidate, the one with the highest CTC
    probability averaged over the shifts wins, and that average is its confidence (the
    characters' confidences from the first shift that decodes it). One shift is
    :func:`reading_from_probs`."""
    p = np.asarray(probs, dtype=float)
    if p.ndim != 3 or len(p) < 1:
        raise PerceptionError(f"reading_from_shifted_probs: expected (S, T, C), got {p.shape}")
    greedy = [ctc_greedy(q, alphabet) for q in p]
    candidates = list(dict.fromkeys(g[0] for g in greedy))
    # every candidate under every shift, one batch: (candidates, S) probabilities
    conf = ctc_label_probabilities(
        np.concatenate([p] * len(candidates)), [c for c in candidates for _ in p], alphabet
    ).reshape(len(candidates), len(p)).mean(axis=1)
    k = int(np.argmax(conf))  # the first of equals, as a strict > over candidates in order
    best, best_conf = candidates[k], float(conf[k])
    if not best:
        return SlotIdReading(None, best_conf, ())
    chars = next(c for g, c in greedy if g == best)
    return _reading(best, best_conf, chars)


class SlotIdReader:
    """Reads painted slot IDs with the shipped ONNX model (one CPU thread).

    ``min_confidence``: readings below it come back with ``label=None`` (keeping their
    confidence and characters), so callers only see labels more likely right than wrong
    (default 0.5); 0 keeps every decoded label. Mapping should vote with labels of
    confidence >= 0.9 (>= 99 % right on held-out simulated views, see the model card).
    ``shifts``: the patch columns each patch is read at, the first for every patch, the
    others only for readings whose confidence is below ``reread_below`` (defaults
    :data:`SHIFTED_READS_PX`, :data:`REREAD_BELOW`; ``shifts=(0,)`` or ``reread_below=0``
    reads once, ``reread_below=math.inf`` reads every patch at every shift).
    """

    def __init__(
        self,
        model_path: str | Path | None = None,
        min_confidence: float = 0.5,
        shifts: tuple[int, ...] = SHIFTED_READS_PX,
        reread_below: float = REREAD_BELOW,
    ):
        if not 0.0 <= float(min_confidence) <= 1.0:
            raise PerceptionError(f"min_confidence: expected 0..1, got {min_confidence}")
        if not shifts or any(abs(int(d)) >= PATCH_WIDTH for d in shifts):
            raise PerceptionError(f"shifts: expected patch columns, got {shifts!r}")
        self.shifts = tuple(int(d) for d in shifts)
        if not float(reread_below) >= 0.0:
            raise PerceptionError(f"reread_below: expected >= 0, got {reread_below}")
        self.reread_below = float(reread_below)
        if model_path is None:
            model_path = onnx_model.model_path("slot_ids.onnx")
        path = Path(model_path)
        self.path = path
        self.min_confidence = float(min_confidence)
        self._session = onnx_model.load_session(path)
        inputs = self._session.get_inputs()
        shape = inputs[0].shape if inputs else None
        if (
            len(inputs) != 1
            or shape is None
            or len(shape) != 4
            or shape[1:]
            != [
                1,
                PATCH_HEIGHT,
                PATCH_WIDTH,
            ]
        ):
            raise PerceptionError(
                f"{path}: expected one input (N, 1, {PATCH_HEIGHT}, {PATCH_WIDTH}), got {shape}"
            )
        self._input = inputs[0].name

    def read(
        self, topview_bgr: np.ndarray, entrance_uv: np.ndarray, into_slot: np.ndarray
    ) -> SlotIdReading:
        """The ID painted in the slot at ``entrance_uv`` (see :func:`crop_id_patch`)."""
        return self.read_patches([crop_id_patch(topview_bgr, entrance_uv, into_slot)])[0]

    def probabilities(self, patches) -> np.ndarray:
        """(N, 32, 37) per-frame class probabilities of (N, 64, 128) uint8 patches from
        :func:`crop_id_patch` (calibration temperature applied), one batch."""
        arr = [np.asarray(p) for p in patches]
        if not arr:
            return np.zeros((0, 32, len(ALPHABET) + 1), np.float32)
        for k, p in enumerate(arr):
            if p.dtype != np.uint8 or p.shape != (PATCH_HEIGHT, PATCH_WIDTH):
                raise PerceptionError(
                    f"patches[{k}]: expected uint8 ({PATCH_HEIGHT}, {PATCH_WIDTH}), "
                    f"got {p.dtype} {p.shape}"
                )
        x = np.stack(arr).astype(np.float32)[:, None]
        if len(x) < 2:
            return self._session.run(None, {self._input: x})[0]
        # the batch in two halves, the second beside the first: each patch is read alone,
        # so the halves give what the whole batch gives, on both cores
        half = (len(x) + 1) // 2
        second = run_beside(self._session.run, None, {self._input: x[half:]})
        first = self._session.run(None, {self._input: x[:half]})[0]
        return np.concatenate([first, second.result()[0]])

    def read_patches(self, patches) -> list[SlotIdReading]:
        """Readings of (N, 64, 128) uint8 patches from :func:`crop_id_patch`: each read at
        the first of ``shifts``, those read with confidence below ``reread_below`` again
        at the others, combined (:func:`reading_from_shifted_probs`); one batch per pass.
        A patch more than :data:`MAX_BLACK_SHARE` black is not read: ``(None, 0.0, ())``."""
        every = [np.asarray(p) for p in patches]
        seen = [k for k, p in enumerate(every) if not _mostly_black(p)]
        readings = [SlotIdReading(None, 0.0, ())] * len(every)
        for k, reading in zip(seen, self._read([every[k] for k in seen]), strict=True):
            readings[k] = reading
        return readings

    def _read(self, arr: list[np.ndarray]) -> list[SlotIdReading]:
        """:meth:`read_patches` of patches that are not mostly black."""
        if not arr:
            return []
        first = self.probabilities([shift_columns(p, self.shifts[0]) if p.ndim == 2 else p
                                    for p in arr])
        out = readings_from_probs(first)
        unsure = [k for k, r in enumerate(out) if r.confidence < self.reread_below]
        others = self.shifts[1:]
        if unsure and others:
            again = self.probabilities([shift_columns(arr[k], d) for d in others for k in unsure])
            again = again.reshape(len(others), len(unsure), *first.shape[1:])
            for j, k in enumerate(unsure):
                out[k] = reading_from_shifted_probs(np.concatenate([first[k][None], again[:, j]]))
        return [SlotIdReading(None, r.confidence, r.char_confidences)
                if r.label is not None and r.confidence < self.min_confidence else r for r in out]


__all__ = [
    "ALPHABET",
    "MAX_BLACK_SHARE",
    "PATCH_HEIGHT",
    "PATCH_WIDTH",
    "REREAD_BELOW",
    "SHIFTED_READS_PX",
    "SlotIdReader",
    "SlotIdReading",
    "crop_id_patch",
    "ctc_greedy",
    "ctc_label_probabilities",
    "ctc_label_probability",
    "reading_from_probs",
    "reading_from_shifted_probs",
    "readings_from_probs",
    "shift_columns",
]
