"""`--observations images`: a drive's observations computed from its images.

Per frame: the top view (frames.csv column ``topview``) gives slots with their painted
IDs and painted lines (:class:`~semslam.perception.topview_perception.TopviewPerception`);
the front camera (column ``front``, camera ``front`` of rig.json) gives tags
(:func:`~semslam.perception.tags.observe_tags`). A frame without one of the images
simply has none of those observations; a drive without either column is refused.
Frames are processed in chunks by ``workers`` processes (each loads the models once).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from semslam.config import SemslamConfig
from semslam.errors import DriveError, FormatError, PerceptionError, SemslamError
from semslam.pipeline.workers import pool_map, process_pool
from semslam.progress import progress_bar
from semslam.types import FrameObservations

_WORKER: dict[str, Any] = {}
_CHUNK = 20


def _init_worker(folder: str, config_json: str, has_top: bool, has_front: bool) -> None:
    import cv2

    from semslam.config import SemslamConfig
    from semslam.io import Drive
    from semslam.perception.tags import settings_from_config
    from semslam.perception.topview_perception import TopviewPerception

    cv2.setNumThreads(1)
    drive = Drive.open(folder)
    _WORKER.clear()
    _WORKER.update(
        drive=drive,
        frames=drive.frames(),
        perception=TopviewPerception(spec=drive.rig.topview) if has_top else None,
        front=has_front,
        tag_settings=settings_from_config(SemslamConfig.model_validate_json(config_json)),
    )


def _perceive_frames(indices: list[int]) -> list[FrameObservations]:
    from semslam.io.images import read_image
    from semslam.perception.tags import observe_tags

    drive, frames = _WORKER["drive"], _WORKER["frames"]
    perception = _WORKER["perception"]
    out = []
    for i in indices:
        slots, markings, tags = (), (), ()
        if perception is not None and frames.images["topview"][i]:
            path = drive.image_path("topview", i)
            image = read_image(path)  # names the file itself when it cannot be read
            try:
                det = perception.detect(image)
            except SemslamError as e:  # name the image: the detector does not know it
                raise PerceptionError(f"{path}: {e}") from None
            slots, markings = perception.slot_observations(det), det.markings
        if _WORKER["front"] and frames.images["front"][i]:
            path = drive.image_path("front", i)
            image = read_image(path, grey=True)
            camera = drive.rig.cameras["front"]
            if (image.shape[1], image.shape[0]) != tuple(camera.size):
                raise FormatError(f"{path}: {image.shape[1]} x {image.shape[0]} px, but rig.json "
                                  f"gives the front camera {camera.size[0]} x {camera.size[1]}")
            try:
                tags = observe_tags(image, camera, _WORKER["tag_settings"])
            except SemslamError as e:  # name the image and the camera: the detector knows neither
                raise PerceptionError(f"{path}: {e} (camera 'front' of rig.json)") from None
        out.append(FrameObservations(float(frames.t[i]), slots, tags, markings))
    return out


def perceive_drive(
    drive, config: SemslamConfig, show_progress: bool | None = None, workers: int | None = None
) -> list[FrameObservations]:
    """The observations of every frame of ``drive`` from its images.

    Args:
        workers: processes (default: ``config.simulation.render.workers``; 1 runs here).

    Raises:
        DriveError: the drive has no top-view or front images, or an image is missing.
        FormatError: an image cannot be read.
        PerceptionError: a model is missing or broken.
    """
    frames = drive.frames()
    has_top = "topview" in frames.images
    has_front = "front" in frames.images and "front" in drive.rig.cameras
    if not (has_top or has_front):
        raise DriveError(
            f"{drive.folder}: --observations images needs a topview or front image column "
            "in frames.csv (and the front camera in rig.json)"
        )
    workers = config.simulation.render.workers if workers is None else workers
    workers = max(1, min(int(workers), os.cpu_count() or 1))
    chunks = [list(range(k, min(k + _CHUNK, len(frames)))) for k in range(0, len(frames), _CHUNK)]
    init_args = (os.fspath(Path(drive.folder)), config.model_dump_json(), has_top, has_front)
    out: list[FrameObservations] = []
    with progress_bar(len(frames), "perception", show_progress) as bar:
        if workers == 1:
            _init_worker(*init_args)
            for chunk in chunks:
                out.extend(_perceive_frames(chunk))
                bar.update(len(chunk))
            return out
        with process_pool(workers, _init_worker, init_args) as pool:
            for part in pool_map(pool, _perceive_frames, chunks, "perception"):
                out.extend(part)
                bar.update(len(part))
    return out


__all__ = ["perceive_drive"]
