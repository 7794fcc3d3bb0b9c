"""The second thread of the perception stages."""

from __future__ import annotations

import multiprocessing

from semslam.perception.beside import run_beside


def test_runs_a_call_beside_the_caller():
    assert run_beside(sum, [1, 2, 3]).result(timeout=10) == 6


def _child(queue) -> None:
    queue.put(run_beside(sum, [4, 5]).result(timeout=10))


def test_a_forked_child_gets_a_thread_of_its_own():
    run_beside(sum, [0]).result(timeout=10)  # the parent's thread exists now
    context = multiprocessing.get_context("fork")
    queue = context.Queue()
    child = context.Process(target=_child, args=(queue,), daemon=True)
    child.start()
    child.join(timeout=30)
    if child.is_alive():  # the work never ran: do not leave the child behind
        child.kill()
    assert child.exitcode == 0
    assert queue.get(timeout=5) == 9
