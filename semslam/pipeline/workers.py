"""Worker processes for the pipeline's parallel stages (rendering, perception)."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any


def process_pool(
    workers: int, initializer: Callable[..., None], initargs: tuple[Any, ...]
) -> ProcessPoolExecutor:
    """A pool of ``workers`` processes forked from a fork server, never from the caller.

    Forking the calling process is unsafe once it runs threads (onnxruntime's, OpenCV's, a
    test runner's): a child can inherit a lock that another thread held and wait on it
    forever. The fork server is a clean single-threaded process, started by the first
    pool, that imports that pool's ``initializer`` module once (later pools' workers
    import theirs); each worker is forked from it, then runs ``initializer``.
    """
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([initializer.__module__])
    return ProcessPoolExecutor(
        workers, mp_context=context, initializer=initializer, initargs=initargs
    )


__all__ = ["process_pool"]
