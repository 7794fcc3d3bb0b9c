"""Atomic file writes: readers never see a half-written file.

The data goes to a temporary file in the target's folder, is flushed and
fsync'ed, then renamed over the target with ``os.replace`` (atomic on POSIX
and Windows when both are on the same file system). If anything fails the
target keeps its old content and the temporary file is removed.

Within :func:`atomic_group`, the files written are renamed over their targets together
at the end, so a command that writes several outputs (a map and the files beside it)
replaces all of them or none: Ctrl-C and SIGTERM wait until the renames are done
(:func:`signals_deferred`), and a rename that fails puts back the targets already replaced.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import signal
import threading
from collections.abc import Iterator
from contextvars import ContextVar
from pathlib import Path

_pending: ContextVar[list[tuple[Path, Path]] | None] = ContextVar("atomic_group", default=None)


@contextlib.contextmanager
def atomic_group() -> Iterator[None]:
    """Defer the renames of every atomic write inside to the end of the block.

    Each file is written in full to its temporary file as usual; only when the block ends
    without an exception are they renamed over their targets, one after another. If the
    block fails (or is interrupted), every target keeps its old content and the temporary
    files are removed. Groups do not nest.
    """
    if _pending.get() is not None:
        raise RuntimeError("atomic_group: groups do not nest")
    pending: list[tuple[Path, Path]] = []
    token = _pending.set(pending)
    try:
        yield
    except BaseException:
        _remove(tmp for tmp, _ in pending)
        raise
    finally:
        _pending.reset(token)
    folders = [target for _, target in pending if target.is_dir()]
    if folders:  # found before any rename: all or none
        _remove(tmp for tmp, _ in pending)
        raise IsADirectoryError(errno.EISDIR, "is a folder, cannot write a file there",
                                str(folders[0]))
    special = [target for _, target in pending if is_special_file(target)]
    if special:
        _remove(tmp for tmp, _ in pending)
        raise _special_error(special[0])
    with signals_deferred():
        _replace_together(pending)
    for folder in {target.parent for _, target in pending}:
        _fsync_folder(folder)


def _replace_together(pending: list[tuple[Path, Path]]) -> None:
    """Rename every ``(tmp, target)``; if one rename fails, the targets already replaced get
    their old files back (kept as hard links meanwhile; where the file system has none,
    that target cannot be put back) and the new ones created are removed."""
    existed = {target for _, target in pending if os.path.lexists(target)}
    backups: dict[Path, Path] = {}
    for target in existed:
        backup = target.with_name(f".{target.name}.{os.getpid()}.{secrets.token_hex(4)}.old")
        try:
            os.link(target, backup, follow_symlinks=False)
        except OSError:
            continue
        backups[target] = backup
    replaced: list[Path] = []
    try:
        for tmp, target in pending:
            os.replace(tmp, target)
            replaced.append(target)
    except BaseException:
        for target in replaced:
            with contextlib.suppress(OSError):
                if target in backups:
                    os.replace(backups.pop(target), target)
                elif target not in existed:
                    os.unlink(target)
        _remove(tmp for tmp, target in pending if target not in replaced)
        raise
    finally:
        _remove(backups.values())


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM until the block ends, then raise them again, so a few renames
    that belong together are not cut in half. Python's handlers are swapped, not the
    signal mask: a signal sent to the process may reach any of its threads (onnxruntime's,
    a progress bar's). A no-op off the main thread, where handlers cannot be set."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    held = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, lambda signum, _frame: caught.append(signum)) for s in held}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)
        if caught:  # one is enough: the first raised ends the block; SIGTERM outranks Ctrl-C
            signal.raise_signal(signal.SIGTERM if signal.SIGTERM in caught else caught[0])


def is_special_file(target: str | os.PathLike[str]) -> bool:
    """Whether ``target`` exists as neither a file nor a folder (a device, pipe or socket),
    which a rename would replace with a plain file (as root even ``/dev/null``)."""
    return os.path.exists(target) and not (os.path.isfile(target) or os.path.isdir(target))


SPECIAL_FILE_MESSAGE = (
    "not a regular file (a device, pipe or socket); semslam writes regular files only"
)
"""Why :func:`is_special_file` targets are refused."""


def _special_error(target: Path) -> OSError:
    return OSError(errno.EINVAL, SPECIAL_FILE_MESSAGE, str(target))


def _remove(paths) -> None:
    for path in paths:
        with contextlib.suppress(OSError):
            os.unlink(path)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, creating the parent folder if missing.

    Args:
        path: target file; replaced if it exists.
        data: the complete new content.

    Raises:
        OSError: the folder or file cannot be written (the target is unchanged).
    """
    target = Path(path)
    if is_special_file(target):
        raise _special_error(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    # O_EXCL: never clobber a stranger's file; mode 0o666 so the umask applies
    # as for an ordinary open().
    group = _pending.get()
    try:  # the open inside: an interrupt just after it still removes the file
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        if group is not None:  # renamed at the end of the group
            group.append((tmp, target))
            return
        os.replace(tmp, target)
    except BaseException as exc:
        if not (isinstance(exc, FileExistsError) and exc.filename == os.fspath(tmp)):
            with contextlib.suppress(OSError):  # ours unless the O_EXCL open found it there
                os.unlink(tmp)
        raise
    _fsync_folder(target.parent)


def atomic_write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (no newline translation); see
    :func:`atomic_write_bytes`."""
    atomic_write_bytes(path, text.encode(encoding))


def _fsync_folder(folder: Path) -> None:
    """Make the rename durable where the platform allows it (best effort)."""
    if os.name != "posix":
        return
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
