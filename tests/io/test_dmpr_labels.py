import json
from pathlib import Path

import numpy as np
import pytest

from semslam.errors import FormatError
from semslam.io import TopviewLabels, dmpr_labels_from_dict, read_dmpr_labels, write_dmpr_labels
from semslam.types import JunctionShape, SlotKind

PS2_LABELS = Path("/work/shared/realdata/ps2.0-samples/labels")


def test_reads_every_ps2_sample() -> None:
    files = sorted(PS2_LABELS.glob("*.json")) if PS2_LABELS.is_dir() else []
    if not files:
        pytest.skip(f"{PS2_LABELS} is absent")
    for path in files:
        labels = read_dmpr_labels(path)
        n = labels.points.shape[0]
        assert n >= 1 and labels.points.shape == (n, 2)
        assert labels.directions.shape == (n,) and labels.shapes.shape == (n,)
        assert np.all((labels.points >= 0) & (labels.points < 600))
        assert labels.slots.ndim == 2 and labels.slots.shape[1] == 4
        assert np.all(labels.slots[:, :2] >= 1) and np.all(labels.slots[:, :2] <= n)


def test_direction_and_one_slot_flat_form() -> None:
    labels = dmpr_labels_from_dict(
        {"marks": [[100.0, 200.0, 100.0, 300.0, 1], [50, 60, 10, 60, 0]], "slots": [2, 1, 1, 90]}
    )
    np.testing.assert_allclose(labels.directions, [np.pi / 2, np.pi])
    assert labels.junction_shapes() == [JunctionShape.L, JunctionShape.T]
    np.testing.assert_array_equal(labels.slots, [[2, 1, 1, 90]])
    assert labels.slot_kinds() == [SlotKind.PERPENDICULAR]


def test_one_mark_flat_form_and_no_slots() -> None:
    labels = dmpr_labels_from_dict({"marks": [10.0, 20.0, 30.0, 20.0, 0], "slots": []})
    assert labels.points.shape == (1, 2) and labels.slots.shape == (0, 4)


def test_second_l_junction_turned_to_its_separator() -> None:
    # a row of two slots seen from above: entrance along +u, slots below (+v); ps2.0
    # directs the last point, an L that is only a second point, along the entrance
    # towards its first point; T junctions and first points along the separator (+v)
    labels = dmpr_labels_from_dict({
        "marks": [[100, 100, 100, 150, 1], [250, 100, 250, 150, 0], [400, 100, 350, 100, 1]],
        "slots": [[1, 2, 1, 90], [2, 3, 1, 90]],
    })
    turned = labels.with_separator_directions()
    np.testing.assert_allclose(turned.directions, [np.pi / 2] * 3, atol=1e-12)
    np.testing.assert_allclose(labels.directions, [np.pi / 2, np.pi / 2, np.pi])  # unchanged
    # an L second point directed along its separator already, or a T, is left alone
    t_row = dmpr_labels_from_dict({"marks": [[100, 100, 100, 150, 0], [250, 100, 250, 150, 1]],
                                   "slots": [1, 2, 1, 90]})
    np.testing.assert_allclose(t_row.with_separator_directions().directions, [np.pi / 2] * 2)
    # nothing to copy when the first point lies along the entrance itself
    odd = dmpr_labels_from_dict({"marks": [[100, 100, 150, 100, 1], [250, 100, 200, 100, 1]],
                                 "slots": [1, 2, 1, 90]})
    np.testing.assert_allclose(odd.with_separator_directions().directions, [0.0, np.pi])


def test_round_trip(tmp_path: Path) -> None:
    labels = TopviewLabels(
        points=np.array([[240.5, 57.8], [226.8, 387.9], [235.3, 227.6]]),
        directions=np.array([3.1, -2.0, 0.3]),
        shapes=np.array([0, 1, 0]),
        slots=np.array([[3, 1, 1, 90], [2, 3, 3, 60]]),
    )
    path = tmp_path / "labels.json"
    write_dmpr_labels(path, labels)
    loaded = read_dmpr_labels(path)
    np.testing.assert_array_equal(loaded.points, labels.points)
    np.testing.assert_allclose(loaded.directions, labels.directions, atol=1e-12)
    np.testing.assert_array_equal(loaded.shapes, labels.shapes)
    np.testing.assert_array_equal(loaded.slots, labels.slots)


def test_single_mark_and_slot_written_flat(tmp_path: Path) -> None:
    labels = TopviewLabels(
        points=np.array([[1.0, 2.0]]),
        directions=np.array([0.0]),
        shapes=np.array([1]),
        slots=np.zeros((0, 4), dtype=np.int64),
    )
    path = tmp_path / "one.json"
    write_dmpr_labels(path, labels)
    document = json.loads(path.read_text())
    assert document == {"marks": [1.0, 2.0, 51.0, 2.0, 1], "slots": []}
    np.testing.assert_array_equal(read_dmpr_labels(path).points, [[1.0, 2.0]])


@pytest.mark.parametrize(
    ("document", "message"),
    [
        ({"slots": []}, r"labels\.json: missing field 'marks'"),
        ({"marks": [[1, 2, 3, 4]]}, r"labels\.json: marks/0: expected 5 numbers"),
        (
            {"marks": [[1, 2, 3, 4, 2]]},
            r"labels\.json: marks/0/4: shape must be 0 \(T\) or 1 \(L\)",
        ),
        (
            {"marks": [[1, 2, 3, 4, 0]], "slots": [[1, 2, 1, 90]]},
            r"labels\.json: slots/0/1: mark index 2 out of range 1\.\.1",
        ),
        (
            {"marks": [[1, 2, 3, 4, 0], [5, 6, 7, 8, 0]], "slots": [1, 2, 4, 90]},
            r"labels\.json: slots/2: type must be 1, 2 or 3",
        ),
        (
            {"marks": [[1, 2, 3, 4, 0], [5, 6, 7, 8, 0]], "slots": [1, 2.5, 1, 90]},
            r"slots/1: expected an integer",
        ),
        ({"marks": [[1, "a", 3, 4, 0]]}, r"labels\.json: marks/0/1: expected a number"),
        ({"marks": [[1, 2, 1e300, 4, 0]]}, r"labels\.json: marks/0/2: must be <= 1000000"),
        (
            {"marks": [[1, 2, 3, 4, 0], [5, 6, 7, 8, 0]], "slots": [1, 2, 1, 1e20]},
            r"labels\.json: slots/3: angle must be 0 to 180 degrees, got 1e\+20$",
        ),
    ],
)
def test_rejects(tmp_path: Path, document: dict, message: str) -> None:
    path = tmp_path / "labels.json"
    path.write_text(json.dumps(document))
    with pytest.raises(FormatError, match=message):
        read_dmpr_labels(path)
