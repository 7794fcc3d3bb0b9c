"""Suite-wide hooks."""

import gc


def pytest_sessionfinish(session, exitstatus):
    """Free gtsam factors that hold Python callbacks (CustomFactor) while the interpreter is
    still whole: left to interpreter shutdown, their C++ destructors may run after Python's
    own objects are gone."""
    gc.collect()
