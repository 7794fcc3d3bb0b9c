"""Slot detections from the frames between two keyframes, fused into the keyframe's.

The graph has a pose variable per keyframe only (every ``keyframe_distance``), but the
camera sees a slot in every frame, two to three times per keyframe at parking speed.
The frames in between are placed in the next keyframe's vehicle frame by odometry (a
fraction of a metre: millimetres of odometry error against centimetres of corner
noise) and each keyframe detection averages the in-between detections of the same slot
(same kind, every corner near). The fused detection carries ``corner_sigma /
sqrt(n)``: independent corner noise averages out. Real detectors make errors that
repeat from one frame to the next, so ``n`` is capped (``fuse_frames_max``) rather than
trusted without bound. Association, labels and confidences stay the keyframe
detection's own: fusion only sharpens corners.

All positions in the keyframe's vehicle frame (x forward, y left), metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from semslam.geometry import FloatArray, between, transform_points
from semslam.types import FrameObservations, SlotObservation


def slots_in_keyframe(
    frames: list[tuple[FrameObservations, FloatArray]], keyframe_delta: FloatArray
) -> list[SlotObservation]:
    """The slot detections of in-between frames, moved into the new keyframe's frame.

    Args:
        frames: (frame, pose of that frame in the previous keyframe's frame) per frame.
        keyframe_delta: pose of the new keyframe in the previous keyframe's frame.
    """
    moved = []
    for frame, delta in frames:
        kTf = between(keyframe_delta, delta)
        for obs in frame.slots:
            moved.append(replace(obs, vCorners=transform_points(kTf, obs.vCorners)))
    return moved


def fuse_detection(
    primary: SlotObservation,
    others: Sequence[SlotObservation],
    radius: float,
    max_count: int,
) -> tuple[SlotObservation, int]:
    """``primary`` with the corners of the ``others`` that show the same slot averaged in.

    A detection joins when it has the primary's kind and each of its corners lies within
    ``radius`` metres of the primary's corner of the same index; the closest join first,
    at most ``max_count - 1`` of them. Returns the fused detection (corner sigma and its own
    part divided by sqrt of the count; the shared part stays) and the count (1: nothing
    joined).
    """
    if max_count <= 1 or not others:
        return primary, 1
    reference = np.asarray(primary.vCorners, dtype=float)
    near = []
    for obs in others:
        if obs.kind != primary.kind:
            continue
        worst = float(np.max(np.linalg.norm(np.asarray(obs.vCorners) - reference, axis=1)))
        if worst <= radius:
            near.append((worst, obs))
    if not near:
        return primary, 1
    near.sort(key=lambda item: item[0])
    chosen = [obs for _, obs in near[: max_count - 1]]
    count = 1 + len(chosen)
    corners = (reference + sum(np.asarray(o.vCorners, dtype=float) for o in chosen)) / count
    own = primary.corner_sigma_own
    return replace(
        primary,
        vCorners=corners,
        corner_sigma=primary.corner_sigma / math.sqrt(count),
        corner_sigma_own=None if own is None else tuple(v / math.sqrt(count) for v in own),
    ), count
