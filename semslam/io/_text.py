"""Reading a whole text file with every failure turned into a semslam error."""

from __future__ import annotations

import os
from pathlib import Path

from semslam.errors import SemslamError

MAX_TEXT_BYTES = 1 << 30
"""Largest text file read, bytes (1 GiB; the observations of a long drive are tens of MB):
more is not a semslam file, and ``/dev/zero`` given as one would fill the memory."""


def read_text(path: str | os.PathLike[str], error: type[SemslamError]) -> str:
    """The content of ``path`` decoded as UTF-8 (a leading BOM is dropped).

    Raises:
        error: the file is missing, unreadable, larger than :data:`MAX_TEXT_BYTES` or not
            UTF-8; the message names the file.
    """
    try:
        with Path(path).open("rb") as f:
            data = _read_at_most(f, MAX_TEXT_BYTES + 1)
    except FileNotFoundError:
        raise error(f"{os.fspath(path)}: file not found") from None
    except IsADirectoryError:
        raise error(f"{os.fspath(path)}: a folder, not a file") from None
    except OSError as exc:
        raise error(f"{os.fspath(path)}: cannot read ({exc.strerror or exc})") from None
    if len(data) > MAX_TEXT_BYTES:
        raise error(f"{os.fspath(path)}: larger than {MAX_TEXT_BYTES >> 30} GiB, not a text file "
                    "semslam reads")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise error(f"{os.fspath(path)} line {line}: not UTF-8 text") from None


def _read_at_most(f, limit: int) -> bytes:
    """Up to ``limit`` bytes of ``f``, in chunks (``f.read(limit)`` would reserve ``limit``
    bytes first, whatever the file's size)."""
    chunks, total = [], 0
    while total < limit:
        chunk = f.read(min(1 << 24, limit - total))
        if not chunk:
            break
        chunks.append(chunk)
        total += len(chunk)
    return b"".join(chunks)


def text_lines(text: str) -> list[str]:
    """The lines of a text file's content: split at ``\n`` only (a trailing ``\r`` dropped),
    as the formats define a line. ``str.splitlines`` also splits at form feeds, ``\x1c-\x1e``,
    ``\x85`` and U+2028, which may stand inside a comment or a file name."""
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    return [line[:-1] if line.endswith("\r") else line for line in lines]


def path_text(path: str | os.PathLike[str]) -> str:
    """``path`` as text that can be written as UTF-8: bytes of a file name that are not
    UTF-8 (kept by Python as lone surrogates, which no UTF-8 writer takes) become U+FFFD."""
    return os.fspath(path).encode("utf-8", "surrogateescape").decode("utf-8", "replace")
