"""Worker processes for the pipeline's parallel stages (rendering, perception)."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from semslam.errors import SemslamError

T = TypeVar("T")
R = TypeVar("R")

_start_error: BaseException | None = None  # in a worker: why its initializer failed


def _guarded_start(initializer: Callable[..., None], *initargs: Any) -> None:
    """Run ``initializer``; keep its error for the first task instead of letting the pool
    print a traceback and kill the worker (which would only say "terminated abruptly")."""
    global _start_error
    try:
        initializer(*initargs)
    except Exception as e:  # noqa: BLE001 (re-raised in the caller, via the first task)
        _start_error = e


def _guarded_call(fn: Callable[[T], R], job: T) -> R:
    if _start_error is not None:
        raise _start_error
    return fn(job)


def process_pool(
    workers: int, initializer: Callable[..., None], initargs: tuple[Any, ...]
) -> ProcessPoolExecutor:
    """A pool of ``workers`` processes forked from a fork server, never from the caller.

    Forking the calling process is unsafe once it runs threads (onnxruntime's, OpenCV's, a
    test runner's): a child can inherit a lock that another thread held and wait on it
    forever. The fork server is a clean single-threaded process, started by the first
    pool, that imports that pool's ``initializer`` module once (later pools' workers
    import theirs); each worker is forked from it, then runs ``initializer`` (an error
    there is raised by :func:`pool_map` in the caller, as the tasks' own errors are).
    """
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([initializer.__module__])
    return ProcessPoolExecutor(
        workers, mp_context=context, initializer=_guarded_start,
        initargs=(initializer, *initargs),
    )


def pool_map(
    pool: ProcessPoolExecutor, fn: Callable[[T], R], jobs: Iterable[T], what: str
) -> Iterator[R]:
    """``fn`` over ``jobs`` in ``pool``, results in order. A worker's error (its start's
    too) is raised here as it was raised there; a worker that died (killed by the system,
    out of memory) becomes one ``SemslamError`` line naming ``what``."""
    results = pool.map(_guarded_call, [fn] * len(jobs := list(jobs)), jobs)
    try:
        yield from results
    except BrokenProcessPool:
        raise SemslamError(
            f"{what}: a worker process died or could not start (killed by the system, "
            "out of memory?)"
        ) from None


__all__ = ["pool_map", "process_pool"]
