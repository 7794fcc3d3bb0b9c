"""A short memory of recent frames, merged into one frame for global relocalization.

One frame often sees too few confidently read slot IDs to fix the pose. Over the last
second or two the car has seen more, and odometry alone places those older observations in
the current vehicle frame with millimetre-level error. :class:`RecentFrames` keeps the
frames of a time window with their dead-reckoned poses (in an arbitrary odometry frame
``o``), and :meth:`RecentFrames.merged` returns one :class:`FrameObservations` in the
current vehicle frame where

- observations of the same slot (centres within ``merge_distance``) become one slot with
  averaged corners and the label with the largest summed confidence; its confidence is
  the best confidence of a reading of that label times the winner's share of all summed
  confidences (a misread among several right readings loses, a split vote is not
  confident, and one physical slot never counts as several agreeing slots);
- with three or more frames remembered, a slot seen only once is dropped (false
  detections come and go from frame to frame; real slots stay in view);
- the most recent observation of each tag is kept.
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace

import numpy as np

from semslam.geometry import FloatArray, between, compose, rotation, transform_points
from semslam.types import FrameObservations, SlotObservation, TagObservation


class RecentFrames:
    """Frames of the last ``window`` seconds with their odometry poses ``oTv``."""

    def __init__(self, window: float = 2.0, merge_distance: float = 0.7) -> None:
        self.window = window
        self.merge_distance = merge_distance
        self._frames: deque[tuple[FloatArray, FrameObservations]] = deque()

    def add(self, oTv: FloatArray, frame: FrameObservations) -> None:
        self._frames.append((np.asarray(oTv, dtype=float).copy(), frame))
        while self._frames and frame.t - self._frames[0][1].t > self.window:
            self._frames.popleft()

    def clear(self) -> None:
        self._frames.clear()

    def merged(self) -> FrameObservations | None:
        """All remembered observations in the vehicle frame of the newest frame."""
        if not self._frames:
            return None
        oTnow, newest = self._frames[-1]
        slots: list[tuple[FloatArray, SlotObservation]] = []
        tags: dict[tuple, TagObservation] = {}
        for oTv, frame in self._frames:
            nowTv = between(oTnow, oTv)
            for s in frame.slots:
                corners = transform_points(nowTv, s.vCorners)
                slots.append((corners, replace(s, vCorners=corners)))
            R = rotation(nowTv[2])
            for tag in frame.tags:
                cov = np.array(tag.covariance, dtype=float)
                cov[:2, :2] = R @ cov[:2, :2] @ R.T
                tags[(tag.family, tag.tag_id)] = replace(
                    tag, vTt=compose(nowTv, tag.vTt), covariance=cov
                )
        return FrameObservations(
            newest.t, tuple(self._merge_slots(slots)), tuple(tags.values()), ()
        )

    def _merge_slots(self, slots: list[tuple[FloatArray, SlotObservation]]):
        groups: list[list[SlotObservation]] = []
        centres: list[FloatArray] = []
        for corners, s in slots:
            c = corners.mean(axis=0)
            for i, g in enumerate(centres):
                if np.hypot(*(c - g)) < self.merge_distance:
                    groups[i].append(s)
                    break
            else:
                groups.append([s])
                centres.append(c)
        confirm = len(self._frames) >= 3  # false detections are independent from frame to frame
        for group in groups:
            if confirm and len(group) < 2:
                continue
            votes: dict[str, float] = {}
            for s in group:
                if s.label is not None:
                    votes[s.label] = votes.get(s.label, 0.0) + s.label_confidence
            label = max(votes, key=votes.get) if votes else None
            confidence = 0.0
            if label is not None:  # the best reading of the winner, discounted by dissent
                best = max(s.label_confidence for s in group if s.label == label)
                confidence = best * votes[label] / sum(votes.values())
            yield replace(
                group[-1],
                vCorners=np.mean([s.vCorners for s in group], axis=0),
                label=label,
                label_confidence=float(confidence),
                confidence=float(np.mean([s.confidence for s in group])),
            )
