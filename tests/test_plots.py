"""The pictures come out as PNG images with the map and the trajectory in them."""

from dataclasses import replace

import numpy as np

from semslam.plots import audit_figure, error_figure, map_figure, trajectory_figure
from semslam.types import Marking, SemanticMap, Slot, SlotKind, Tag, TagFamily

PNG = b"\x89PNG\r\n\x1a\n"


def _map() -> SemanticMap:
    c = np.array([[0.0, 0.0], [2.5, 0.0], [2.5, 5.0], [0.0, 5.0]])
    slot = Slot(1, "A1", 0.9, c, np.tile(np.eye(2) * 1e-3, (4, 1, 1)), SlotKind.PERPENDICULAR, 4)
    tag = Tag(TagFamily.TAG36H11, 3, 0.3, np.array([5.0, 2.0, 1.0]), 1.0, np.eye(3) * 1e-4)
    line = Marking(np.array([0.0, -1.0]), np.array([10.0, -1.0]), 0.12)
    return SemanticMap((slot,), (tag,), (line,))


def test_every_picture_is_a_png():
    t = np.linspace(0.0, 10.0, 50)
    poses = np.column_stack([t, np.sin(t), np.zeros_like(t)])
    err = np.abs(np.cos(t)) * 0.1
    status = ["initializing"] * 5 + ["tracking"] * 40 + ["coasting"] * 5
    rows = [{"status": "accepted", "slot": 1}, {"status": "null", "slot": None}]
    per_slot = [{"id": 1, "accepted": [0], "went_to_other_slot": [], "null": [1]}]
    for data in (
        map_figure(_map(), _map()),
        trajectory_figure(poses, poses, err, _map()),
        error_figure(t, err, err / 2, status),
        audit_figure(rows, per_slot),
    ):
        assert data.startswith(PNG) and len(data) > 5000


def _has_colour(png: bytes, hex_rgb: str, tolerance: int = 12) -> bool:
    import cv2

    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    bgr = np.array([int(hex_rgb[i : i + 2], 16) for i in (5, 3, 1)])
    return bool((np.abs(image.astype(int) - bgr).max(axis=2) <= tolerance).sum() > 20)


def test_the_map_picture_draws_the_mapped_slot_over_the_true_one():
    """The map in its blue, the truth under it in green: both drawn, not empty axes."""
    truth = _map()
    shifted = SemanticMap(tuple(replace(s, corners=s.corners + 1.0) for s in truth.slots))
    png = map_figure(shifted, truth)
    assert _has_colour(png, "#1f4e9c") and _has_colour(png, "#a6dba0")
    assert not _has_colour(map_figure(SemanticMap(), None), "#1f4e9c")

