"""Builders of small, fully populated values for the format tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from semslam.io import (
    DriveInfo,
    FrameIndex,
    Odometry,
    save_map,
    save_rig,
    write_drive_info,
    write_frames,
    write_observations,
    write_odometry,
    write_tum,
)
from semslam.rig import Camera, CameraModel, Rig, TopviewSpec, VehicleSpec, default_front_camera
from semslam.types import (
    FrameObservations,
    Marking,
    MarkingObservation,
    SemanticMap,
    Slot,
    SlotKind,
    SlotObservation,
    Tag,
    TagFamily,
    TagObservation,
    default_covariance,
)


def make_map() -> SemanticMap:
    """Two slots (one unlabelled), a tag and a marking."""
    square = np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 5.0], [0.0, 5.0]])
    covs = np.stack([default_covariance(0.05 * (k + 1)) for k in range(4)])
    return SemanticMap(
        slots=(
            Slot(3, "B17", 0.93, square + 0.1, covs, SlotKind.PERPENDICULAR, 12),
            Slot(7, None, 0.0, square + [3.0, 0.25], covs, SlotKind.SLANTED, 0),
        ),
        tags=(
            Tag(
                TagFamily.TAG36H11,
                5,
                0.16,
                np.array([4.0, -1.5, 1.25]),
                1.1,
                np.diag([0.01, 0.02, 0.003]),
            ),
        ),
        markings=(Marking(np.array([0.0, -0.1]), np.array([10.0, -0.1]), 0.12),),
        metadata={
            "generator": "semslam",
            "version": "0.1.0",
            "created": "2024-05-01T12:00:00Z",
            "source": "drives/a",
            "statistics": {"keyframes": 120, "rmse": np.float64(0.031)},
        },
    )


def make_frame(t: float) -> FrameObservations:
    """A frame that sees one slot, one tag and one marking."""
    corners = np.array([[2.0, 1.0], [2.0, -1.5], [7.0, -1.5], [7.0, 1.0]])
    return FrameObservations(
        t=t,
        slots=(SlotObservation(corners, SlotKind.PARALLEL, "A3", 0.8, 0.95, 0.05),),
        tags=(
            TagObservation(
                TagFamily.TAG25H9,
                2,
                0.2,
                np.array([5.0, 0.5, -3.0]),
                1.0,
                default_covariance(0.1, 3),
            ),
        ),
        markings=(MarkingObservation(np.array([1.0, 2.0]), np.array([4.0, 2.1]), 0.1, 0.7),),
    )


def make_rig() -> Rig:
    """The simulator's front camera plus a fisheye camera."""
    front = default_front_camera()
    fisheye = Camera(
        name="fisheye_rear",
        model=CameraModel.FISHEYE,
        K=np.array([[300.0, 0.0, 640.0], [0.0, 300.0, 480.0], [0.0, 0.0, 1.0]]),
        D=np.array([0.1, -0.02, 0.003, -0.0004]),
        size=(1280, 960),
        T_vehicle_camera=np.eye(4),
    )
    return Rig(
        cameras={"front": front, "fisheye_rear": fisheye},
        topview=TopviewSpec(600, 1 / 60, 3.75, 1.72),
        vehicle=VehicleSpec(3.6, 1.6, 2.3),
    )


def write_drive(folder: Path, with_optional: bool = True) -> None:
    """A complete small drive folder with three frames."""
    t = np.array([0.0, 0.1, 0.2])
    write_drive_info(
        folder / "drive.json",
        DriveInfo(
            name="test",
            start_pose=np.array([1.0, 2.0, 0.5]),
            frame_rate=10.0,
            source={"simulator": {"seed": 1}},
            observations=("exact",),
        ),
    )
    save_rig(folder / "rig.json", make_rig())
    write_odometry(
        folder / "odometry.csv",
        Odometry(np.linspace(0, 0.2, 5), np.full(5, 2.0), np.full(5, 0.1)),
    )
    images = {"topview": [f"images/{i:06d}_topview.png" for i in range(3)], "front": ["", "", ""]}
    write_frames(folder / "frames.csv", FrameIndex(t, images))
    (folder / "images").mkdir()
    for p in images["topview"]:
        (folder / p).write_bytes(b"png")
    if with_optional:
        write_tum(folder / "groundtruth.tum", t, np.array([[1.0, 2.0, 0.5]] * 3))
        save_map(folder / "world.json", make_map())
        write_observations(folder / "observations" / "exact.jsonl", [make_frame(x) for x in t])


@pytest.fixture
def drive_folder(tmp_path: Path) -> Path:
    """A complete drive folder with all optional files."""
    folder = tmp_path / "drive"
    folder.mkdir()
    write_drive(folder)
    return folder
