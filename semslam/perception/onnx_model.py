"""The shipped ONNX models: where they live and how they are loaded.

The models are trained by the scripts in ``tools/`` and committed in ``semslam/models/``
(``models/`` at the top of the repository links there), package data, so a plain
``pip install .`` carries them. Loading never fetches anything: a missing or corrupt
file is a :class:`~semslam.errors.PerceptionError` naming the file.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

from semslam.errors import PerceptionError


def model_path(name: str) -> Path:
    """Path of the shipped model file ``name`` (for example ``"marking_points.onnx"``)."""
    return Path(str(resources.files("semslam").joinpath("models", name)))


def model_paths(given, defaults: tuple[str, ...], what: str) -> list[Path]:
    """The model files a detector is given: one path, a list or tuple of them, or None
    for the shipped files ``defaults``.

    Raises:
        PerceptionError: an empty list (``what`` names the detector).
    """
    if given is None:
        paths = [model_path(name) for name in defaults]
    elif isinstance(given, (list, tuple)):
        paths = [Path(p) for p in given]
    else:
        paths = [Path(given)]
    if not paths:
        raise PerceptionError(f"{what}: no model given")
    return paths


def load_session(path: str | os.PathLike[str]):
    """An onnxruntime session on one CPU thread for the model at ``path``.

    One thread: the detectors run per frame beside other work, and on this class of
    machine (2 cores) intra-op threading costs more than it gains on small CNNs.

    Raises:
        PerceptionError: the file is missing or is not a model onnxruntime can load.
    """
    import onnxruntime as ort

    path = Path(path)
    if not path.is_file():
        raise PerceptionError(f"{path}: model file not found (train it with tools/, see models/)")
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    try:
        return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own Fail / InvalidProtobuf types
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise PerceptionError(f"{path}: not a loadable ONNX model ({first})") from None


__all__ = ["load_session", "model_path", "model_paths"]
