"""`semslam simulate`: write a simulated drive as a drive folder.

Library modules compute; this module reads inputs, writes outputs
atomically, shows progress and leaves the configuration beside the results.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semslam import __version__
from semslam.config import SemslamConfig, config_to_json
from semslam.errors import FormatError, SimulationError
from semslam.pipeline.drive_output import staged_drive_folder
from semslam.pipeline.workers import pool_map, process_pool
from semslam.progress import progress_bar


@dataclass(frozen=True)
class SimulationSummary:
    """What ``simulate`` wrote."""

    folder: Path
    preset: str
    seed: int
    drive_index: int
    duration_s: float
    distance_m: float
    frames: int
    slots: int
    tags: int
    markings: int
    images: bool
    seconds: float


# --------------------------------------------------------------------------- image rendering

_WORKER: dict = {}


def _init_render_worker(
    preset: str, seed: int, quality: int, fmt: str, placed_tags: np.ndarray | None
) -> None:
    import cv2

    from semslam.rig import default_rig
    from semslam.simulation.render_front import FrontRenderer
    from semslam.simulation.render_topview import TopviewRenderer
    from semslam.simulation.world import make_world, with_placed_tags

    cv2.setNumThreads(1)
    world = with_placed_tags(make_world(preset, seed), placed_tags)
    rig = default_rig()
    _WORKER.update(
        topview=TopviewRenderer(world, rig.topview),
        front=FrontRenderer(world, rig.cameras["front"]),
        params=[cv2.IMWRITE_JPEG_QUALITY, quality] if fmt == "jpg" else [],
        fmt=fmt,
    )


def _render_frames(job: tuple[str, list[tuple[int, np.ndarray, int]]]) -> int:
    """Render, encode and write the top view, its labels and the front image of each frame."""
    import cv2

    from semslam.io.atomic import atomic_write_bytes, atomic_write_text
    from semslam.simulation.labels import annotation_to_json

    folder, frames = job
    root = Path(folder)
    fmt, params = _WORKER["fmt"], _WORKER["params"]
    for index, mTv, seed in frames:
        top, annotation = _WORKER["topview"].render(mTv, seed)
        front = _WORKER["front"].render(mTv, seed)
        for name, image in (("topview", top), ("front", front)):
            ok, data = cv2.imencode(f".{fmt}", image, params)
            if not ok:
                raise SimulationError(f"could not encode the {name} image of frame {index}")
            atomic_write_bytes(root / "images" / name / f"{index:06d}.{fmt}", data.tobytes())
        atomic_write_text(
            root / "labels" / "topview" / f"{index:06d}.json", annotation_to_json(annotation)
        )
    return len(frames)


def _render_images(
    tmp: Path, sim, config: SemslamConfig, show_progress: bool | None, placed_tags
) -> None:
    from semslam.simulation.scenario import frame_seed

    render = config.simulation.render
    poses = sim.frame_poses
    frames = [(i, poses[i], frame_seed(sim.seed, sim.drive_index, i)) for i in range(len(poses))]
    chunk = 25
    jobs = [(str(tmp), frames[k : k + chunk]) for k in range(0, len(frames), chunk)]
    init_args = (
        sim.world.preset, sim.world.seed, render.jpeg_quality, render.image_format, placed_tags
    )
    with progress_bar(len(frames), "rendering", show_progress) as bar:
        if render.workers <= 1:
            _init_render_worker(*init_args)
            for n in map(_render_frames, jobs):
                bar.update(n)
            return
        with process_pool(render.workers, _init_render_worker, init_args) as pool:
            for n in pool_map(pool, _render_frames, jobs, "rendering"):
                bar.update(n)


# --------------------------------------------------------------------------- simulate


def _write_drive(tmp: Path, sim, preset: str, seed: int, drive_index: int, images: bool,
                 config: SemslamConfig, show_progress: bool | None, placed_tags) -> None:
    """Every file of the simulated drive ``sim`` into the staging folder ``tmp``."""
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
    from semslam.io.atomic import atomic_write_text

    rec = sim.record
    save_rig(tmp / "rig.json", sim.rig)
    write_odometry(tmp / "odometry.csv", Odometry(rec.t, rec.odo_speed, rec.odo_yaw_rate))
    write_tum(tmp / "groundtruth.tum", sim.frame_times, sim.frame_poses)
    save_map(tmp / "world.json", sim.world.to_map())
    write_observations(tmp / "observations" / "exact.jsonl", sim.exact)
    write_observations(tmp / "observations" / "noisy.jsonl", sim.noisy)
    fmt = config.simulation.render.image_format
    n = len(sim.frame_times)
    columns = (
        {
            "topview": [f"images/topview/{i:06d}.{fmt}" for i in range(n)],
            "front": [f"images/front/{i:06d}.{fmt}" for i in range(n)],
        }
        if images
        else {}
    )
    write_frames(tmp / "frames.csv", FrameIndex(sim.frame_times, columns))
    if images:
        _render_images(tmp, sim, config, show_progress, placed_tags)
    write_drive_info(
        tmp / "drive.json",
        DriveInfo(
            name=f"{preset}-seed{seed}-drive{drive_index}",
            start_pose=sim.frame_poses[0],
            frame_rate=config.simulation.drive.frame_rate,
            source={
                "generator": f"semslam {__version__}",
                "simulator": {
                    "preset": preset,
                    "seed": seed,
                    "drive": drive_index,
                    "placed_tags": 0 if placed_tags is None else len(placed_tags),
                },
            },
            observations=("exact", "noisy"),
        ),
    )
    atomic_write_text(tmp / "config.json", config_to_json(config))


def simulate(
    out_dir: Path,
    preset: str,
    seed: int,
    drive_index: int,
    images: bool,
    config: SemslamConfig,
    show_progress: bool | None = None,
    placed_tags: np.ndarray | None = None,
) -> SimulationSummary:
    """Simulate a drive and write it as a drive folder at ``out_dir``; ``placed_tags``
    (K, 3) are tags added to the world (a `semslam plan-tags` plan to try out)."""
    from semslam.simulation.scenario import simulate_drive

    started = time.perf_counter()
    with staged_drive_folder(out_dir, SimulationError) as tmp:
        sim = simulate_drive(preset, seed, drive_index, config.simulation, placed_tags)
        try:  # every file is read back as written: a value out of range came from the settings
            _write_drive(tmp, sim, preset, seed, drive_index, images, config, show_progress,
                         placed_tags)
        except FormatError as e:
            raise SimulationError(
                f"{e}; the simulation settings in force made it (see `semslam dump-config`)"
            ) from None
    steps = np.linalg.norm(np.diff(sim.frame_poses[:, :2], axis=0), axis=1)
    return SimulationSummary(
        folder=out_dir,
        preset=preset,
        seed=seed,
        drive_index=drive_index,
        duration_s=float(sim.frame_times[-1] - sim.frame_times[0]),
        distance_m=float(steps.sum()),
        frames=len(sim.frame_times),
        slots=len(sim.world.slots),
        tags=len(sim.world.tags),
        markings=len(sim.world.markings),
        images=images,
        seconds=time.perf_counter() - started,
    )
