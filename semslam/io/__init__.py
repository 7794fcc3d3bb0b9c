"""File formats: pure readers and writers, no other side effects.

Every reader checks what it reads and raises a :mod:`semslam.errors` error
whose one-line message names the file and the line or field; every writer
writes atomically (:mod:`semslam.io.atomic`) and refuses data that would
not read back.
"""

from semslam.io.atomic import atomic_write_bytes, atomic_write_text
from semslam.io.dmpr_labels import (
    TopviewLabels,
    dmpr_labels_from_dict,
    dmpr_labels_to_dict,
    read_dmpr_labels,
    write_dmpr_labels,
)
from semslam.io.drive import (
    DRIVE_JSON,
    FRAMES_CSV,
    GROUNDTRUTH_TUM,
    OBSERVATIONS_DIR,
    ODOMETRY_CSV,
    RIG_JSON,
    WORLD_JSON,
    Drive,
    observations_file,
)
from semslam.io.drive_info import (
    DriveInfo,
    drive_info_from_dict,
    drive_info_to_dict,
    read_drive_info,
    write_drive_info,
)
from semslam.io.errors import DriveFormatError
from semslam.io.frames import FrameIndex, read_frames, write_frames
from semslam.io.map_json import load_map, map_from_dict, map_to_dict, save_map
from semslam.io.observations import (
    frame_observations_from_dict,
    frame_observations_to_dict,
    read_observations,
    write_observations,
)
from semslam.io.odometry import Odometry, read_odometry, write_odometry
from semslam.io.rig_json import load_rig, rig_from_dict, rig_to_dict, save_rig
from semslam.io.track_csv import TRACK_STATUSES, Track, read_track_csv, write_track_csv
from semslam.io.tum import read_tum, write_tum

__all__ = [
    "DRIVE_JSON",
    "FRAMES_CSV",
    "GROUNDTRUTH_TUM",
    "OBSERVATIONS_DIR",
    "ODOMETRY_CSV",
    "RIG_JSON",
    "WORLD_JSON",
    "Drive",
    "DriveFormatError",
    "DriveInfo",
    "FrameIndex",
    "Odometry",
    "TopviewLabels",
    "atomic_write_bytes",
    "atomic_write_text",
    "dmpr_labels_from_dict",
    "dmpr_labels_to_dict",
    "drive_info_from_dict",
    "drive_info_to_dict",
    "frame_observations_from_dict",
    "frame_observations_to_dict",
    "load_map",
    "load_rig",
    "map_from_dict",
    "map_to_dict",
    "observations_file",
    "read_dmpr_labels",
    "read_drive_info",
    "read_frames",
    "read_observations",
    "read_odometry",
    "read_tum",
    "rig_from_dict",
    "rig_to_dict",
    "save_map",
    "save_rig",
    "write_dmpr_labels",
    "write_drive_info",
    "write_frames",
    "write_observations",
    "write_odometry",
    "write_tum",
    "TRACK_STATUSES",
    "Track",
    "read_track_csv",
    "write_track_csv",
]
