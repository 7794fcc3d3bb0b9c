"""A whole simulated drive in memory: world, rig, trajectory, odometry, observations.

This is the library side of ``semslam simulate`` (no file I/O): the pipeline
writes what it returns into a drive folder and renders the images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semslam.config import SimulationConfig
from semslam.geometry import FloatArray
from semslam.rig import Rig, default_rig
from semslam.simulation.driver import DriveRecord, drive_path
from semslam.simulation.route import make_path
from semslam.simulation.sensors import ExactSensor, NoisySensor
from semslam.simulation.world import make_world, with_placed_tags
from semslam.simulation.world_types import World
from semslam.types import FrameObservations


@dataclass(frozen=True, eq=False)
class SimulatedDrive:
    """Everything about one simulated drive.

    Attributes:
        world, rig: the garage and the sensor rig.
        record: the drive at the odometry rate (truth and odometry).
        exact, noisy: observations at each camera frame, vehicle frame.
        seed, drive_index: what made it.
    """

    world: World
    rig: Rig
    record: DriveRecord
    exact: tuple[FrameObservations, ...]
    noisy: tuple[FrameObservations, ...]
    seed: int
    drive_index: int

    @property
    def frame_times(self) -> FloatArray:
        """(M,) camera frame times, s."""
        return self.record.t[self.record.frame_index]

    @property
    def frame_poses(self) -> FloatArray:
        """(M, 3) true poses mTv at the camera frames."""
        return self.record.poses[self.record.frame_index]


def frame_seed(seed: int, drive_index: int, frame: int) -> int:
    """A per-frame seed for rendering, fixed by (seed, drive, frame)."""
    return int(np.random.SeedSequence([seed, drive_index, frame, 3]).generate_state(1)[0])


def simulate_drive(
    preset: str,
    seed: int,
    drive_index: int,
    config: SimulationConfig,
    placed_tags: FloatArray | None = None,
) -> SimulatedDrive:
    """Build the world of (``preset``, ``seed``) and drive route ``drive_index`` through it.

    The seed fixes the world; the drive index picks the route, the speed
    profile, the odometry noise and the detector noise. ``placed_tags`` (K, 3): tags
    added to the world (:func:`~semslam.simulation.world.with_placed_tags`), e.g. a
    `semslam plan-tags` plan to try out.
    """
    world = with_placed_tags(make_world(preset, seed), placed_tags)
    rig = default_rig()
    cfg = config.drive
    path = make_path(world, drive_index, cfg.lane_offset, cfg.turn_radius)
    record = drive_path(
        path, cfg, config.odometry_noise, np.random.default_rng([seed, drive_index, 1])
    )
    exact_sensor = ExactSensor(world, rig, config.observation_noise)
    noisy_sensor = NoisySensor(
        world, rig, config.observation_noise, np.random.default_rng([seed, drive_index, 2])
    )
    exact = tuple(
        exact_sensor.observe(float(record.t[i]), record.poses[i]) for i in record.frame_index
    )
    noisy = tuple(noisy_sensor.corrupt(e) for e in exact)
    return SimulatedDrive(world, rig, record, exact, noisy, seed, drive_index)
