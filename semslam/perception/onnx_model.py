"""The shipped ONNX models: where they live and how they are loaded.

The models are trained by the scripts in ``tools/`` and committed in ``semslam/models/``
(``models/`` at the top of the repository links there), package data, so a plain
``pip install .`` carries them. Loading never fetches anything: a missing or corrupt
file is a :class:`~semslam.errors.PerceptionError` naming the file.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from semslam.errors import PerceptionError

T = TypeVar("T")


def model_path(name: str) -> Path:
    """Path of the shipped model file ``name`` (for example ``"marking_points.onnx"``)."""
    return Path(str(resources.files("semslam").joinpath("models", name)))


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


def run_beside(fn: Callable[..., T], *args: Any) -> Future[T]:
    """Start ``fn(*args)`` on a second thread, kept for the purpose, and return at once.

    onnxruntime releases the GIL while a session runs, so a run started here uses the
    machine's other core while the caller runs another (one thread per session, as two
    threads inside one session cost more than they gain on these small CNNs)."""
    global _BESIDE
    if _BESIDE is None:
        _BESIDE = ThreadPoolExecutor(1, "onnx-beside")
    return _BESIDE.submit(fn, *args)


_BESIDE: ThreadPoolExecutor | None = None

__all__ = ["load_session", "model_path", "run_beside"]
