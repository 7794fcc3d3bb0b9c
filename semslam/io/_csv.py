"""Plain comma-separated tables with a fixed header line and no quoting."""

from __future__ import annotations

import os

from semslam.errors import SemslamError
from semslam.io._text import read_text, text_lines


def read_table(
    path: str | os.PathLike[str], error: type[SemslamError]
) -> tuple[list[str], list[tuple[int, list[str]]]]:
    """The header and the data rows of a CSV file (blank lines skipped).

    Returns:
        ``(header, rows)``: header names (stripped) and ``(line number, fields)``
        per data row, line numbers counted from 1 (the header is line 1).

    Raises:
        error: missing or empty file, or a header without data rows.
    """
    name = os.fspath(path)
    lines = text_lines(read_text(path, error))
    if not lines or not any(line.strip() for line in lines):
        raise error(f"{name}: empty file")
    header = [h.strip() for h in lines[0].split(",")]
    rows = [
        (lineno, line.split(",")) for lineno, line in enumerate(lines[1:], start=2) if line.strip()
    ]
    if not rows:
        raise error(f"{name}: no data rows after the header")
    return header, rows


def check_header(
    header: list[str], expected: list[str], path: str | os.PathLike[str], error: type[SemslamError]
) -> None:
    """Refuse a header other than ``expected``."""
    if header != expected:
        raise error(
            f"{os.fspath(path)} line 1: header is '{','.join(header)}', "
            f"expected '{','.join(expected)}'"
        )


def check_columns(
    fields: list[str], header: list[str], where: str, error: type[SemslamError]
) -> None:
    """Refuse a row whose column count differs from the header's."""
    if len(fields) != len(header):
        raise error(
            f"{where}: expected {len(header)} columns ({','.join(header)}), got {len(fields)}"
        )
