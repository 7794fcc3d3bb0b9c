"""`semslam map`: build a map from a drive folder and write it with its by-products.

Writes, next to ``MAP.json``: ``MAP.trajectory.tum`` (keyframes, TUM), ``MAP.g2o``
(the graph, for the usual tools),
``MAP.audit.jsonl`` (what became of every slot observation), ``MAP.audit.json`` (per slot:
the observations it accepted, those that went to another slot or to the null hypothesis),
``MAP.config.json`` (the configuration used).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

from semslam import __version__
from semslam.config import SemslamConfig, config_to_json
from semslam.errors import DriveError, MappingError
from semslam.geometry import FloatArray
from semslam.progress import progress_bar

OBSERVATION_SOURCES = ("exact", "noisy", "cached", "images")


@dataclass(frozen=True)
class MapSummary:
    """What ``semslam map`` did."""

    map_path: Path
    drive: str
    observations: str
    frames: int
    driving_s: float
    mapping_s: float
    slots: int
    tags: int
    statistics: dict


SIBLING_SUFFIXES = (".trajectory.tum", ".g2o", ".audit.jsonl", ".audit.json", ".config.json")


def _sibling(map_path: Path, suffix: str) -> Path:
    return map_path.with_name(map_path.stem + suffix)


def sibling_paths(map_path: Path) -> list[Path]:
    """The files ``semslam map`` writes beside the map at ``map_path``."""
    return [_sibling(Path(map_path), suffix) for suffix in SIBLING_SUFFIXES]


def load_observations(
    drive, source: str, config: SemslamConfig | None = None, show_progress: bool | None = None
):
    """The per-frame observations of ``drive`` from ``source``: a stored set (exact,
    noisy, cached) or, for ``images``, the detectors run on the drive's images."""
    if source not in OBSERVATION_SOURCES:
        raise DriveError(f"--observations {source}: choose one of {', '.join(OBSERVATION_SOURCES)}")
    if source == "images":
        from semslam.pipeline.perceive import perceive_drive

        return perceive_drive(drive, config or SemslamConfig(), show_progress)
    return drive.observations(source)


def check_observation_times(drive_folder: Path, frames: list, odometry_t: FloatArray) -> None:
    """The observations lie within the odometry: none before its first sample, none more
    than one sample period after its last (odometry.csv cut short).

    Raises:
        DriveError: naming the drive folder and the times.
    """
    from semslam.io.odometry import check_covered, odometry_span

    span = odometry_span(odometry_t)
    try:
        for frame in (frames[:1] + frames[-1:]) if frames else []:
            check_covered(frame.t, span, start=True)
    except DriveError as e:
        raise DriveError(f"{drive_folder}: {e}") from None


def build_map(
    drive_folder: Path,
    map_path: Path,
    observations: str,
    config: SemslamConfig,
    show_progress: bool | None = None,
) -> MapSummary:
    """Map the drive at ``drive_folder`` and write ``map_path`` and its siblings."""
    from semslam.io import Drive, save_map, write_tum
    from semslam.io._text import path_text
    from semslam.io.atomic import atomic_group, atomic_write_text
    from semslam.io.g2o import write_g2o
    from semslam.mapping.export import to_pose_graph
    from semslam.mapping.mapper import Mapper

    drive = Drive.open(drive_folder)
    odometry = drive.odometry()
    frames = load_observations(drive, observations, config, show_progress)
    check_observation_times(drive_folder, frames, odometry.t)
    started = time.perf_counter()
    mapper = Mapper(config.mapping, drive.start_pose, odometry.t, odometry.speed, odometry.yaw_rate)
    try:
        with progress_bar(len(frames), "mapping", show_progress) as bar:
            for frame in frames:
                mapper.add_frame(frame)
                bar.update(1)
        result = mapper.finish()
    except MappingError as e:  # gtsam's words alone name no file and no setting
        raise MappingError(
            f"{drive_folder}: {e}; a mapping sigma far from the sensors' (see `semslam "
            "dump-config`) or odometry far off can make the graph unsolvable"
        ) from None
    elapsed = time.perf_counter() - started
    driving = float(frames[-1].t - frames[0].t) if frames else 0.0
    statistics = {
        **result.statistics,
        "mapping_s": round(elapsed, 3),
        "driving_s": round(driving, 3),
        "speedup": round(driving / elapsed, 2) if elapsed > 0 else None,
    }
    semantic_map = replace(
        result.map,
        metadata={
            "generator": "semslam",
            "version": __version__,
            "created": datetime.now(UTC).isoformat(timespec="seconds"),
            "source": path_text(Path(drive_folder).resolve()),
            "drive": drive.info.name,
            "observations": observations,
            "statistics": statistics,
        },
    )
    graph = to_pose_graph(replace(result, map=semantic_map))
    with atomic_group():  # the six files replace the old ones together, or none does
        save_map(map_path, semantic_map)
        write_tum(_sibling(map_path, ".trajectory.tum"), result.keyframe_times,
                  result.keyframe_poses)
        write_g2o(_sibling(map_path, ".g2o"), graph)
        atomic_write_text(_sibling(map_path, ".audit.jsonl"), _audit_jsonl(result))
        atomic_write_text(_sibling(map_path, ".audit.json"), _audit_by_slot(result))
        atomic_write_text(_sibling(map_path, ".config.json"), config_to_json(config))
    return MapSummary(
        map_path,
        drive.info.name,
        observations,
        len(frames),
        driving,
        elapsed,
        len(semantic_map.slots),
        len(semantic_map.tags),
        statistics,
    )


def _audit_jsonl(result) -> str:
    """One line per slot observation: when, what it read, its candidates and its fate."""
    slot_id = result.slot_of_landmark
    lines = []
    for s in result.sightings:
        obs = s.observation
        lines.append(
            json.dumps(
                {
                    "t": round(s.t, 6),
                    "keyframe": s.keyframe,
                    "label": obs.label,
                    "label_confidence": round(obs.label_confidence, 4),
                    "candidates": [slot_id.get(c) for c in s.candidates],
                    "status": s.status.value,
                    "slot": slot_id.get(s.landmark) if s.landmark is not None else None,
                },
                separators=(",", ":"),
            )
        )
    return "\n".join(lines) + ("\n" if lines else "")


def _audit_by_slot(result) -> str:
    """Per mapped slot: indices (lines of the .audit.jsonl) of the observations it accepted,
    of those first proposed for it that ended on another slot, and of those that ended on
    the null hypothesis while it was their nearest candidate."""
    slot_id = result.slot_of_landmark
    slots: dict[int, dict[str, list[int]]] = {
        s.id: {"accepted": [], "went_to_other_slot": [], "null": []} for s in result.map.slots
    }
    for i, s in enumerate(result.sightings):
        final = slot_id.get(s.landmark) if s.landmark is not None else None
        first = slot_id.get(s.first_choice) if s.first_choice is not None else None
        if s.status.value in ("accepted", "reassigned") and final in slots:
            slots[final]["accepted"].append(i)
        if s.status.value == "reassigned" and first in slots and first != final:
            slots[first]["went_to_other_slot"].append(i)
        if s.status.value == "null" and first in slots:
            slots[first]["null"].append(i)
    return json.dumps({"slots": [{"id": k, **v} for k, v in slots.items()]}) + "\n"
