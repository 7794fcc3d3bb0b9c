"""The pipeline's worker pools: errors reach the caller as errors, never as a dead pool."""

import operator
import os

import pytest

from semslam.errors import SemslamError
from semslam.pipeline.workers import pool_map, process_pool


def test_a_pool_maps_in_order():
    with process_pool(2, len, ("",)) as pool:
        assert list(pool_map(pool, abs, [-3, 2, -1], "test")) == [3, 2, 1]


def test_a_failed_start_is_raised_in_the_caller_as_it_was_raised():
    with process_pool(1, operator.truediv, (1, 0)) as pool, \
            pytest.raises(ZeroDivisionError):
        list(pool_map(pool, abs, [1, 2], "test"))


def test_a_worker_that_dies_is_one_line_naming_the_stage():
    with process_pool(1, len, ("",)) as pool, \
            pytest.raises(SemslamError, match=r"^rendering: a worker process died") as caught:
        list(pool_map(pool, os._exit, [3], "rendering"))
    assert "\n" not in str(caught.value)
