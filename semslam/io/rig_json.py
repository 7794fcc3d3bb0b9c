"""rig.json: cameras, the top-view grid and the vehicle footprint.

Layout (vehicle frame ISO 8855, camera frame OpenCV, metres)::

    {"format": "semslam-rig", "version": 1,
     "cameras": [{"name", "model": "pinhole"|"fisheye", "K": [3][3], "D": [k...],
                  "size": [w, h], "T_vehicle_camera": [4][4]}],
     "topview": {"size_px", "metres_per_px", "ego_length_m", "ego_width_m"},
     "vehicle": {"length", "width", "wheelbase"}}

``D`` holds OpenCV's distortion coefficients: 4 for the fisheye model,
4, 5, 8, 12 or 14 for the pinhole model (or none).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from semslam.errors import FormatError
from semslam.io._fields import Field, check_header
from semslam.io._json import dumps_pretty, find_non_finite, non_finite_message, parse_json
from semslam.io._text import read_text
from semslam.io.atomic import atomic_write_text
from semslam.rig import Camera, CameraModel, Rig, TopviewSpec, VehicleSpec

RIG_FORMAT = "semslam-rig"
RIG_VERSION = 1
_PINHOLE_D = (0, 4, 5, 8, 12, 14)
MIN_FOCAL_PX = 1.0
"""Smallest ``fx``, ``fy`` read, pixels (as ``semslam tags --intrinsics``): a focal length of
1e-300 px passed ``> 0`` and the tag covariance divided by ``fx * fy``, underflowed to 0."""
MAX_PIXELS = 1e6
"""Bound on every entry of ``K`` (px) and every distortion coefficient (as ``semslam tags``
bounds ``--intrinsics`` and ``--distortion``)."""


def rig_to_dict(rig: Rig) -> dict[str, Any]:
    """The JSON document of a rig (plain Python values)."""
    tv, veh = rig.topview, rig.vehicle
    return {
        "format": RIG_FORMAT,
        "version": RIG_VERSION,
        "cameras": [_camera_to_dict(c) for c in rig.cameras.values()],
        "topview": {
            "size_px": int(tv.size_px),
            "metres_per_px": float(tv.metres_per_px),
            "ego_length_m": float(tv.ego_length_m),
            "ego_width_m": float(tv.ego_width_m),
        },
        "vehicle": {
            "length": float(veh.length),
            "width": float(veh.width),
            "wheelbase": float(veh.wheelbase),
        },
    }


def rig_from_dict(document: Any, source: str = "<dict>") -> Rig:
    """A rig from its JSON document, fully checked.

    Raises:
        FormatError: wrong format or version, a missing, unknown or mistyped
            field, a wrong shape, duplicate camera names; the message names
            ``source`` and the field (``cameras/1/K``).
    """
    bad = find_non_finite(document)
    if bad is not None:
        raise FormatError(f"{source}: {non_finite_message(*bad)}")
    root = Field(document, source, FormatError)
    check_header(root, RIG_FORMAT, RIG_VERSION)
    root.only("format", "version", "cameras", "topview", "vehicle")
    cameras: dict[str, Camera] = {}
    for f in root["cameras"].items():
        camera = _camera_from_field(f)
        if camera.name in cameras:
            f["name"].fail(f"duplicate camera name '{camera.name}'")
        cameras[camera.name] = camera
    return Rig(
        cameras=cameras,
        topview=_topview_from_field(root["topview"]),
        vehicle=_vehicle_from_field(root["vehicle"]),
    )


def save_rig(path: str | os.PathLike[str], rig: Rig) -> None:
    """Write rig.json atomically after checking that it reads back.

    Raises:
        FormatError: the rig would not read back (NaN, wrong shapes...); nothing is written.
    """
    document = rig_to_dict(rig)
    rig_from_dict(document, os.fspath(path))
    atomic_write_text(path, dumps_pretty(document))


def load_rig(path: str | os.PathLike[str]) -> Rig:
    """Read and check rig.json.

    Raises:
        FormatError: missing file, broken JSON, or anything :func:`rig_from_dict` refuses.
    """
    source = os.fspath(path)
    return rig_from_dict(parse_json(read_text(path, FormatError), source, FormatError), source)


# --------------------------------------------------------------------------- parts


def _camera_to_dict(camera: Camera) -> dict[str, Any]:
    return {
        "name": camera.name,
        "model": CameraModel(camera.model).value,
        "K": np.asarray(camera.K, dtype=float).tolist(),
        "D": np.asarray(camera.D, dtype=float).ravel().tolist(),
        "size": [int(v) for v in camera.size],
        "T_vehicle_camera": np.asarray(camera.T_vehicle_camera, dtype=float).tolist(),
    }


def _camera_from_field(f: Field) -> Camera:
    f.only("name", "model", "K", "D", "size", "T_vehicle_camera")
    model = f["model"].choice(CameraModel)
    K = f["K"].array((3, 3), within=MAX_PIXELS)
    if K[0, 0] <= 0 or K[1, 1] <= 0 or np.any(K[2] != (0.0, 0.0, 1.0)):
        f["K"].fail("expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    if min(K[0, 0], K[1, 1]) < MIN_FOCAL_PX:
        f["K"].fail(
            f"focal lengths must be at least {MIN_FOCAL_PX:g} px, got {K[0, 0]:g}, {K[1, 1]:g}"
        )
    D = f["D"].array((None,), within=MAX_PIXELS)
    allowed = (4,) if model is CameraModel.FISHEYE else _PINHOLE_D
    if D.shape[0] not in allowed:
        f["D"].fail(
            f"{model.value} model takes {' or '.join(map(str, allowed))} coefficients, "
            f"got {D.shape[0]}"
        )
    size = f["size"]
    w, h = (e.integer(1) for e in _exactly(size, 2))
    T = f["T_vehicle_camera"].array((4, 4))
    if not np.allclose(T[3], (0.0, 0.0, 0.0, 1.0)):
        f["T_vehicle_camera"].fail("last row must be [0, 0, 0, 1]")
    if not np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-6):
        f["T_vehicle_camera"].fail("rotation part is not orthonormal")
    if np.linalg.det(T[:3, :3]) < 0:
        f["T_vehicle_camera"].fail("rotation part is a reflection (determinant -1)")
    return Camera(
        name=f["name"].string(nonempty=True), model=model, K=K, D=D, size=(w, h), T_vehicle_camera=T
    )


def _exactly(f: Field, n: int) -> list[Field]:
    items = f.items()
    if len(items) != n:
        f.fail(f"expected {n} numbers, got {len(items)}")
    return items


TOPVIEW_MAX_PX = 4096
"""Largest top view side, pixels (ps2.0's is 600)."""
TOPVIEW_METRES_PER_PX = (1e-3, 0.1)
"""Range of a top view's pixel size, metres (ps2.0's 1/60 m, the garage masks' 0.01 m): the
detectors resample a view to their own scale, which a pixel far outside asks for a view of
terabytes or of a few pixels."""


def _topview_from_field(f: Field) -> TopviewSpec:
    f.only("size_px", "metres_per_px", "ego_length_m", "ego_width_m")
    low, high = TOPVIEW_METRES_PER_PX
    return TopviewSpec(
        size_px=f["size_px"].integer(1, TOPVIEW_MAX_PX),
        metres_per_px=f["metres_per_px"].number(minimum=low, maximum=high),
        ego_length_m=f["ego_length_m"].number(minimum=0.0, maximum=50.0),
        ego_width_m=f["ego_width_m"].number(minimum=0.0, maximum=50.0),
    )


def _vehicle_from_field(f: Field) -> VehicleSpec:
    f.only("length", "width", "wheelbase")
    return VehicleSpec(
        length=f["length"].number(positive=True),
        width=f["width"].number(positive=True),
        wheelbase=f["wheelbase"].number(positive=True),
    )
