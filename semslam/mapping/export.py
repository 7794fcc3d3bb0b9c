"""The mapper's graph as a g2o pose graph, for inspection in the usual tools.

Ids: keyframes 0..K-1 (VERTEX_SE2), tags ``TAG_ID_OFFSET + tag id``
(VERTEX_SE2), slot corners ``CORNER_ID_OFFSET + 4 * slot id + corner``
(VERTEX_XY). Edges: odometry and tag observations (EDGE_SE2), and each
*accepted* slot observation as four EDGE_SE2_XY corner observations on the
slot it was finally associated with (observations on the null hypothesis or
still pooled are left out; the audit lists them).
"""

from __future__ import annotations

import numpy as np

from semslam.io.g2o import Edge2D, PointEdge2D, PoseGraph2D
from semslam.mapping.mapper import MappingResult, SightingStatus

TAG_ID_OFFSET = 1_000_000
CORNER_ID_OFFSET = 2_000_000


def _information(covariance: np.ndarray) -> np.ndarray:
    info = np.linalg.inv(covariance)
    return 0.5 * (info + info.T)


def to_pose_graph(result: MappingResult) -> PoseGraph2D:
    """The final estimate and the measurements of ``result`` as a :class:`PoseGraph2D`."""
    graph = PoseGraph2D()
    for k, pose in enumerate(result.keyframe_poses):
        graph.vertices[k] = np.asarray(pose, dtype=float)
    for tag in result.map.tags:
        graph.vertices[TAG_ID_OFFSET + tag.tag_id] = np.asarray(tag.mTt, dtype=float)
    for slot in result.map.slots:
        for c in range(4):
            graph.points[CORNER_ID_OFFSET + 4 * slot.id + c] = np.asarray(slot.corners[c])
    for a, b, delta, cov in result.odometry_edges:
        graph.edges.append(Edge2D(a, b, np.asarray(delta, dtype=float), _information(cov)))
    for k, tag_id, vTt, cov in result.tag_edges:
        if TAG_ID_OFFSET + tag_id in graph.vertices:
            graph.edges.append(Edge2D(k, TAG_ID_OFFSET + tag_id, vTt, _information(cov)))
    for s in result.sightings:
        if s.status not in (SightingStatus.ACCEPTED, SightingStatus.REASSIGNED):
            continue
        slot_id = result.slot_of_landmark.get(s.landmark) if s.landmark is not None else None
        if slot_id is None:
            continue
        sigma = s.sigma if s.sigma is not None else s.observation.corner_sigma
        info = np.eye(2) / max(sigma, 1e-3) ** 2
        for c in range(4):
            graph.point_edges.append(
                PointEdge2D(
                    s.keyframe,
                    CORNER_ID_OFFSET + 4 * slot_id + c,
                    np.asarray(s.observation.vCorners[c], dtype=float),
                    info,
                )
            )
    graph.fixed.append(0)
    return graph
