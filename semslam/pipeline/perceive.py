"""`--observations images`: a drive's observations computed from its images.

Per frame: the top view (frames.csv column ``topview``) gives slots with their painted
IDs and painted lines (:class:`~semslam.perception.topview_perception.TopviewPerception`);
the front camera (column ``front``, camera ``front`` of rig.json) gives tags
(:func:`~semslam.perception.tags.observe_tags`). A frame without one of the images
simply has none of those observations; a drive without either column is refused.
"""

from __future__ import annotations

from semslam.config import SemslamConfig
from semslam.errors import DriveError
from semslam.progress import progress_bar
from semslam.types import FrameObservations


def perceive_drive(
    drive, config: SemslamConfig, show_progress: bool | None = None
) -> list[FrameObservations]:
    """The observations of every frame of ``drive`` from its images.

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
    from semslam.perception.tags import observe_tags, settings_from_config
    from semslam.perception.topview_perception import TopviewPerception
    from semslam.pipeline.detect import read_bgr

    perception = TopviewPerception(spec=drive.rig.topview) if has_top else None
    tag_settings = settings_from_config(config)
    out: list[FrameObservations] = []
    with progress_bar(len(frames), "perception", show_progress) as bar:
        for i, t in enumerate(frames.t):
            slots, markings, tags = (), (), ()
            if perception is not None and frames.images["topview"][i]:
                det = perception.detect(read_bgr(drive.image_path("topview", i)))
                slots, markings = perception.slot_observations(det), det.markings
            if has_front and frames.images["front"][i]:
                image = read_bgr(drive.image_path("front", i))
                tags = observe_tags(image, drive.rig.cameras["front"], tag_settings)
            out.append(FrameObservations(float(t), slots, tags, markings))
            bar.update(1)
    return out


__all__ = ["perceive_drive"]
