import os
from pathlib import Path

import pytest

from semslam.io import atomic_write_bytes, atomic_write_text


def test_writes_and_creates_parent(tmp_path: Path) -> None:
    target = tmp_path / "a" / "b" / "out.txt"
    atomic_write_text(target, "hello\n")
    assert target.read_text() == "hello\n"
    atomic_write_bytes(target, b"\x00\x01")
    assert target.read_bytes() == b"\x00\x01"
    assert os.listdir(target.parent) == ["out.txt"]


def test_failed_replace_keeps_old_content(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "map.json"
    target.write_text("old")

    def broken_replace(src: object, dst: object) -> None:
        raise OSError("disk on fire")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk on fire"):
        atomic_write_text(target, "new")
    assert target.read_text() == "old"
    assert os.listdir(tmp_path) == ["map.json"]  # the temporary file is gone


def test_failed_write_keeps_old_content(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "odometry.csv"
    target.write_text("old")

    def broken_fsync(fd: int) -> None:
        raise OSError("I/O error")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(OSError):
        atomic_write_bytes(target, b"new" * 1000)
    assert target.read_text() == "old"
    assert os.listdir(tmp_path) == ["odometry.csv"]


def test_new_file_gets_ordinary_permissions(tmp_path: Path) -> None:
    target = tmp_path / "x.txt"
    atomic_write_text(target, "x")
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask


def test_a_group_replaces_all_its_files_at_the_end(tmp_path: Path) -> None:
    from semslam.io.atomic import atomic_group

    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old a")
    b.write_text("old b")
    with atomic_group():
        atomic_write_text(a, "new a")
        assert a.read_text() == "old a"  # not yet
        atomic_write_text(b, "new b")
    assert (a.read_text(), b.read_text()) == ("new a", "new b")
    assert sorted(os.listdir(tmp_path)) == ["a.txt", "b.txt"]


def test_a_failed_or_interrupted_group_replaces_none(tmp_path: Path) -> None:
    from semslam.io.atomic import atomic_group

    a = tmp_path / "a.txt"
    a.write_text("old a")
    for error in (ValueError("broken"), KeyboardInterrupt()):
        with pytest.raises(type(error)), atomic_group():
            atomic_write_text(a, "new a")
            raise error
        assert a.read_text() == "old a" and os.listdir(tmp_path) == ["a.txt"]


def test_a_rename_failing_within_a_group_puts_the_replaced_files_back(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The third of three renames fails (an immutable file, say): the first target gets its
    old file back, the second, new one is removed, and nothing temporary is left."""
    from semslam.io.atomic import atomic_group

    a, b, c = tmp_path / "a.txt", tmp_path / "b.txt", tmp_path / "c.txt"
    a.write_text("old a")
    c.write_text("old c")
    real_replace = os.replace

    def replace(src, dst):
        if Path(dst) == c:
            raise PermissionError(1, "Operation not permitted", str(dst))
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(PermissionError), atomic_group():
        for path in (a, b, c):
            atomic_write_text(path, "new")
    assert (a.read_text(), c.read_text()) == ("old a", "old c")
    assert sorted(os.listdir(tmp_path)) == ["a.txt", "c.txt"]


def test_ctrl_c_waits_until_the_renames_are_done() -> None:
    import signal

    from semslam.io.atomic import signals_deferred

    arrived: list[str] = []
    previous = signal.signal(signal.SIGINT, lambda *_: arrived.append("signal"))
    try:
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # bytecodes where the handler would otherwise run
                pass
            arrived.append("end of block")
        for _ in range(1000):
            pass
    finally:
        signal.signal(signal.SIGINT, previous)
    assert arrived == ["end of block", "signal"]


def test_a_group_with_a_folder_for_a_target_replaces_none(tmp_path: Path) -> None:
    from semslam.io.atomic import atomic_group

    a, folder = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old a")
    folder.mkdir()
    with pytest.raises(IsADirectoryError) as err, atomic_group():
        atomic_write_text(a, "new a")
        atomic_write_text(folder, "new b")
    assert err.value.filename == str(folder)
    assert a.read_text() == "old a" and sorted(os.listdir(tmp_path)) == ["a.txt", "b.txt"]


def test_a_pipe_is_never_replaced_by_a_file(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(OSError, match="not a regular file"):
        atomic_write_bytes(fifo, b"x")
    assert not fifo.is_file() and os.path.exists(fifo)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo"]


def test_a_stranger_s_file_under_the_temporary_name_is_left_alone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import semslam.io.atomic as atomic

    monkeypatch.setattr(atomic.secrets, "token_hex", lambda n: "deadbeef")
    stranger = tmp_path / f".x.txt.{os.getpid()}.deadbeef.tmp"
    stranger.write_text("not ours")
    with pytest.raises(FileExistsError):
        atomic_write_text(tmp_path / "x.txt", "new")
    assert stranger.read_text() == "not ours" and not (tmp_path / "x.txt").exists()


def test_sigterm_held_with_ctrl_c_is_the_one_raised_after_the_block() -> None:
    import signal

    from semslam.io.atomic import signals_deferred

    arrived: list[int] = []
    previous = {s: signal.signal(s, lambda signum, _f: arrived.append(signum))
                for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):
                pass
            assert arrived == []
        for _ in range(1000):
            pass
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    assert arrived == [signal.SIGTERM]  # exits 143, as a scheduler's stop asks
