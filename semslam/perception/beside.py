"""A second thread for the other core: start a GIL-free call and go on meanwhile.

onnxruntime (a session's ``run``) and OpenCV release the GIL while they work, so a call
started here runs on the machine's other core while the caller does its own part. The
perception stages use it to halve their latency on a 2-core machine: the two marking-point
models at once, the ID batch and the top view's shrink in two halves (each with results
identical to the serial ones, to the bit). One thread per onnxruntime session: two
threads inside one session cost more than they gain on these small CNNs.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")

_THREAD: ThreadPoolExecutor | None = None


def run_beside(fn: Callable[..., T], *args: Any) -> Future[T]:
    """Start ``fn(*args)`` on the second thread (made on first use) and return at once."""
    global _THREAD
    if _THREAD is None:
        _THREAD = ThreadPoolExecutor(1, "semslam-beside")
    return _THREAD.submit(fn, *args)


def _forget_thread() -> None:
    """In a forked child: the parent's thread is not there, so a new one is made on first
    use (the inherited executor would queue the work for a thread that never runs it)."""
    global _THREAD
    _THREAD = None


os.register_at_fork(after_in_child=_forget_thread)


__all__ = ["run_beside"]
