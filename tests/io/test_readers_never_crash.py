"""Property: on damaged input every reader raises a SemslamError, never a raw exception."""

from pathlib import Path

import pytest
from conftest import write_drive
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from semslam.errors import SemslamError
from semslam.io import (
    load_map,
    load_rig,
    read_dmpr_labels,
    read_drive_info,
    read_frames,
    read_observations,
    read_odometry,
    read_tum,
)

READERS = {
    "world.json": load_map,
    "rig.json": load_rig,
    "drive.json": read_drive_info,
    "odometry.csv": read_odometry,
    "frames.csv": read_frames,
    "groundtruth.tum": read_tum,
    "observations/exact.jsonl": read_observations,
    "labels.json": read_dmpr_labels,
}

JUNK = st.sampled_from(
    [b"", b"\x00", b"\xff", b"{", b"]", b",", b'"', b"NaN", b"-", b"1e999", b"\n", b"9" * 5000]
)


@pytest.fixture(scope="module")
def originals(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    folder = tmp_path_factory.mktemp("drive")
    write_drive(folder)
    (folder / "labels.json").write_text(
        '{"marks": [[1, 2, 3, 4, 0], [5, 6, 7, 8, 1]], "slots": [1, 2, 1, 90]}'
    )
    return {name: (folder / name).read_bytes() for name in READERS}


@pytest.mark.parametrize("name", list(READERS))
def test_damaged_files(name: str, originals: dict[str, bytes], tmp_path: Path) -> None:
    original = originals[name]
    path = tmp_path / Path(name).name

    @settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
    @given(
        cut=st.integers(0, len(original)),
        edits=st.lists(
            st.tuples(st.integers(0, len(original)), st.integers(0, 8), JUNK), max_size=3
        ),
    )
    def check(cut: int, edits: list[tuple[int, int, bytes]]) -> None:
        data = original
        for at, width, junk in edits:
            data = data[:at] + junk + data[at + width :]
        if cut < len(original):
            data = data[:cut]
        path.write_bytes(data)
        try:
            READERS[name](path)
        except SemslamError as exc:
            assert "\n" not in str(exc) and str(path) in str(exc)

    check()
