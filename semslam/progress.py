"""Progress bars for long work (tqdm on stderr), shown only on a terminal unless asked."""

from __future__ import annotations

import sys

from tqdm import tqdm


def progress_bar(
    total: int, desc: str = "", enabled: bool | None = None, unit: str = "frame"
) -> tqdm:
    """A tqdm bar; call ``.update(n)`` and close it (or use it as a context manager)."""
    show = sys.stderr.isatty() if enabled is None else enabled
    return tqdm(
        total=total, desc=desc, disable=not show, unit=unit, dynamic_ncols=True, leave=False
    )
