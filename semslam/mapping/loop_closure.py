"""Loop closures found by painted slot IDs when the drift exceeds the association gates.

Back in a row mapped long ago, the dead-reckoned pose can be metres off, a slot pitch
or more: the nearest landmark is a neighbour and the slot with the observed ID is beyond
the ID gate, so the max-mixture never sees the right hypothesis (and, seen from an
estimate metres away, would pick the null anyway). TiEV trusts IDs; here one ID is not
trusted alone (readings can be wrong with high confidence), but several agree:

- every confidently read slot whose ID belongs to a landmark casts a *vote*: the rigid
  correction ``T`` (map frame) that moves the sighting's corners, placed by the current
  pose, onto that landmark's corners (near the identity when the pose is right);
- votes of the last ``window`` keyframes are compared as the pose they would give the
  newest keyframe (``T * pose``); when ``support`` distinct landmarks with distinct IDs
  agree within ``distance`` and ``yaw`` on a correction away from the identity, they are
  at least half of the landmarks voting in the window, and no other correction (the
  identity included) has half as much support, the agreeing votes are a loop closure.

Misreads vote for scattered corrections, but the typical misread is a neighbour's ID,
one slot pitch off, so over a window a few misreads do agree with each other: they
must outvote the right readings, which all agree on the identity. The mapper then
adds the agreeing sightings as plain (no null) factors on their landmarks, which pulls
the trajectory onto the old map; duplicates made during the drift are merged after.
Pure numpy; map frame, metres, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from semslam.evaluation.alignment import fit_se2
from semslam.geometry import FloatArray, compose, wrap_angle


@dataclass(frozen=True)
class ClosureVote:
    """One sighting's vote: keyframe, sighting index (the audit), landmark index, its ID,
    and the correction ``T`` (3,) with ``landmark corners ≈ T * sighting corners``."""

    keyframe: int
    sighting: int
    landmark: int
    label: str
    correction: FloatArray


def correction_to(sighted: FloatArray, landmark: FloatArray) -> FloatArray:
    """The rigid transform (3,) moving map-frame corners ``sighted`` (4, 2) onto
    ``landmark`` (4, 2) in the least-squares sense."""
    return fit_se2(np.asarray(sighted, float), np.asarray(landmark, float))


class IdLoopClosure:
    """Votes of recent sightings and the consensus test."""

    def __init__(
        self,
        window: int = 20,
        support: int = 3,
        distance: float = 0.5,
        yaw_deg: float = 3.0,
    ) -> None:
        self.window = int(window)
        self.support = int(support)
        self.distance = float(distance)
        self.yaw = math.radians(yaw_deg)
        self.votes: list[ClosureVote] = []
        self.closures = 0

    def vote(self, vote: ClosureVote) -> None:
        self.votes.append(vote)

    def consensus(self, keyframe: int, pose: FloatArray) -> list[ClosureVote]:
        """The agreeing votes if ``support`` distinct landmarks (distinct IDs) agree on
        where keyframe ``keyframe`` at ``pose`` (map frame) really is, else []. Old votes
        (beyond ``window`` keyframes) are forgotten; a closure clears the votes."""
        self.votes = [v for v in self.votes if keyframe - v.keyframe <= self.window]
        voting = len({v.landmark for v in self.votes})
        if voting < self.support:
            return []
        moved = np.array([compose(v.correction, pose) for v in self.votes])
        clusters = []  # (distinct landmarks with distinct IDs, members, seed)
        for i in range(len(self.votes)):
            near = np.hypot(*(moved[:, :2] - moved[i, :2]).T) <= self.distance
            turn = np.abs(wrap_angle(moved[:, 2] - moved[i, 2])) <= self.yaw
            agree = np.flatnonzero(near & turn)
            members = [self.votes[j] for j in agree]
            score = min(len({v.landmark for v in members}), len({v.label for v in members}))
            clusters.append((score, members, i))
        score, chosen, seed = max(clusters, key=lambda c: c[0])
        if score < self.support or 2 * score < voting:
            return []  # too few, or scattered votes (a confused stretch) that agree by chance
        shift = math.hypot(*(moved[seed, :2] - np.asarray(pose, float)[:2]))
        if shift <= self.distance and abs(wrap_angle(moved[seed, 2] - pose[2])) <= self.yaw:
            return []  # the readings agree with the current pose
        # a rival correction (the identity among them) with half the support from votes
        # outside the chosen cluster: no closure (whichever of two equals came first)
        inside = {id(v) for v in chosen}
        for _, members, _ in clusters:
            rest = [v for v in members if id(v) not in inside]
            rival = min(len({v.landmark for v in rest}), len({v.label for v in rest}))
            if 2 * rival >= score:
                return []
        self.votes = []
        self.closures += 1
        return chosen
