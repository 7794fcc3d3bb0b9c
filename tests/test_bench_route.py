"""`semslam bench`'s views: poses evenly along drive 0's route, heading along it."""

from __future__ import annotations

import numpy as np

from semslam.config import SemslamConfig
from semslam.pipeline.bench import route_poses
from semslam.simulation.route import make_path
from semslam.simulation.world import make_world


def test_route_poses_lie_on_the_route_and_face_along_it():
    config = SemslamConfig()
    world = make_world("garage", 1)
    poses = route_poses(config, world, 12)
    assert len(poses) == 12
    drive = config.simulation.drive
    path = make_path(world, 0, drive.lane_offset, drive.turn_radius).points
    for pose in poses:
        assert pose.shape == (3,) and np.isfinite(pose).all()
        k = int(np.argmin(np.linalg.norm(path - pose[:2], axis=1)))
        assert np.linalg.norm(path[k] - pose[:2]) < 1e-9  # a route sample itself
        ahead = path[min(k + 1, len(path) - 1)] - path[k]
        assert np.cos(pose[2] - np.arctan2(ahead[1], ahead[0])) > 0.99
    steps = [np.linalg.norm(b[:2] - a[:2]) for a, b in zip(poses[:-1], poses[1:], strict=True)]
    assert min(steps) > 1.0  # spread over the drive, not bunched at its start
