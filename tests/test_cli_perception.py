"""Smoke tests of the perception and analysis commands through the real CLI entry point:
detect, evaluate detections, accuracy, plan-tags."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.cli import app
from semslam.io import save_map, write_tum
from semslam.io.dmpr_labels import TopviewLabels, write_dmpr_labels
from semslam.simulation.topview_samples import sample_topviews
from semslam.simulation.world import make_world

# ../shared beside the checkout (as CI has it), else this workplace's copy
PS2 = Path(__file__).resolve().parents[1].parent / "shared" / "realdata" / "ps2.0-samples"
if not PS2.is_dir():
    PS2 = Path("/work/shared/realdata/ps2.0-samples")

runner = CliRunner()


def _run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def labelled_views(tmp_path_factory):
    """Three held-out simulated top views with their labels in the DMPR-PS form."""
    root = tmp_path_factory.mktemp("views")
    (root / "images").mkdir()
    (root / "labels").mkdir()
    for k, s in enumerate(sample_topviews(range(3, 6), 1, 11, presets=("small",))):
        cv2.imwrite(str(root / "images" / f"{k:03d}.png"), s.image)
        a = s.annotation
        labels = TopviewLabels(a.points, a.directions, a.shapes.astype(int), a.slots)
        write_dmpr_labels(root / "labels" / f"{k:03d}.json", labels)
    return root


def test_detect_prints_json_and_writes_overlays(labelled_views, tmp_path):
    images = sorted((labelled_views / "images").iterdir())
    result = _run("detect", *images, "--json", "--overlay", tmp_path / "ov")
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert [e["image"] for e in doc["images"]] == [str(p) for p in images]
    found = sum(len(e["points"]) for e in doc["images"])
    assert found > 0
    for entry in doc["images"]:
        for p in entry["points"]:
            assert 0 <= p["u"] < 600 and 0 <= p["v"] < 600 and 0 <= p["confidence"] <= 1
        for s in entry["slots"]:
            assert len(s["corners_vehicle"]) == 4 and 0 <= s["label_confidence"] <= 1
    assert sorted(p.name for p in (tmp_path / "ov").iterdir()) == [p.stem + ".png" for p in images]


def test_detect_reads_a_view_of_another_size_in_its_own_pixels(labelled_views, tmp_path):
    """A view resized to 450 px (its 10 m at 45 px per metre) or cut to 600 x 480 around the
    car gives the slots of the original in the vehicle frame, in the image's pixels (in the
    cut, those whose entrance lies 30 px or more inside it, the area ps2.0 labels)."""
    source = sorted((labelled_views / "images").iterdir())[0]
    image = cv2.imread(str(source))
    small, narrow = tmp_path / "small.png", tmp_path / "narrow.png"
    cv2.imwrite(str(small), cv2.resize(image, (450, 450), interpolation=cv2.INTER_AREA))
    cv2.imwrite(str(narrow), image[:, 60:540])
    result = _run("detect", source, small, narrow, "--json", "--no-lines")
    assert result.exit_code == 0, result.output
    original, resized, cut = json.loads(result.stdout)["images"]
    assert original["slots"], "the view should show slots"
    inside_cut = [s for s in original["slots"]
                  if all(90 <= u <= 510 for u, _ in s["corners_px"][:2])]
    assert inside_cut, "the cut should keep a slot"
    for entry, expected, to_image in (
        (resized, original["slots"], lambda uv: (uv + 0.5) * 0.75 - 0.5),
        (cut, inside_cut, lambda uv: uv - [60.0, 0.0]),
    ):
        found = [s for s in entry["slots"]
                 if entry is resized or all(30 <= u <= 450 for u, _ in s["corners_px"][:2])]
        assert len(found) == len(expected)
        for a, b in zip(expected, found, strict=True):
            np.testing.assert_allclose(b["corners_vehicle"], a["corners_vehicle"], atol=0.12)
            np.testing.assert_allclose(b["corners_px"], to_image(np.array(a["corners_px"])),
                                       atol=8.0)
    wide = _run("detect", source, "--px-per-m", "40")
    assert wide.exit_code == 2 and "covers 15.0 m" in wide.stderr


def test_evaluate_detections_scores_resized_views_in_ps2_units(labelled_views, tmp_path):
    """The ps2.0 metric's 10 px are ps2.0's (1/6 m) on views of any size: labelled views
    resized to 450 px score as the originals do."""
    for sub in ("images", "labels"):
        (tmp_path / sub).mkdir()
    for path in sorted((labelled_views / "images").iterdir()):
        image = cv2.imread(str(path))
        cv2.imwrite(str(tmp_path / "images" / path.name),
                    cv2.resize(image, (450, 450), interpolation=cv2.INTER_AREA))
        doc = json.loads((labelled_views / "labels" / f"{path.stem}.json").read_text())
        marks = np.array(doc["marks"], float).reshape(-1, 5)
        marks[:, :4] = (marks[:, :4] + 0.5) * 0.75 - 0.5
        doc["marks"] = marks.tolist()
        (tmp_path / "labels" / f"{path.stem}.json").write_text(json.dumps(doc))
    scores = []
    for root in (labelled_views, tmp_path):
        result = _run("evaluate", "detections", root / "images", root / "labels", "--json")
        assert result.exit_code == 0, result.output
        scores.append(json.loads(result.stdout))
    original, resized = scores
    assert resized["point_labels"] == original["point_labels"]
    assert abs(resized["point_true_positives"] - original["point_true_positives"]) <= 1
    assert abs(resized["slot_true_positives"] - original["slot_true_positives"]) <= 1


def test_detect_reads_a_folder_as_its_images(labelled_views, tmp_path):
    folder = labelled_views / "images"
    result = _run("detect", folder, "--json", "--no-lines")
    assert result.exit_code == 0, result.output
    images = [e["image"] for e in json.loads(result.stdout)["images"]]
    assert images == [str(p) for p in sorted(folder.iterdir())]
    empty = tmp_path / "empty"
    empty.mkdir()
    refused = _run("detect", empty)
    assert refused.exit_code == 2 and "a folder with no image file" in refused.stderr


def test_detect_refuses_a_file_that_is_not_an_image(tmp_path):
    bad = tmp_path / "x.png"
    bad.write_text("not an image")
    result = _run("detect", bad)
    assert result.exit_code == 2 and "not an image OpenCV can read" in result.stderr


def test_detect_refuses_a_jpeg_cut_short(tmp_path):
    """OpenCV decodes a truncated JPEG's first rows and greys the rest; semslam refuses it."""
    whole = tmp_path / "whole.jpg"
    cv2.imwrite(str(whole), np.full((600, 600, 3), 90, np.uint8))
    data = whole.read_bytes()
    cut = tmp_path / "cut.jpg"
    cut.write_bytes(data[: len(data) // 2])
    result = _run("detect", cut)
    assert result.exit_code == 2 and "cut.jpg: JPEG cut short" in result.stderr
    assert "Traceback" not in result.output
    assert _run("detect", whole, "--json").exit_code == 0


def test_evaluate_detections_scores_labelled_views(labelled_views):
    result = _run(
        "evaluate", "detections", labelled_views / "images", labelled_views / "labels", "--json"
    )
    assert result.exit_code == 0, result.output
    m = json.loads(result.stdout)
    assert m["images"] == 3 and m["point_labels"] > 0
    for key in ("point_precision", "point_recall", "slot_precision", "slot_recall"):
        assert 0.0 <= m[key] <= 1.0
    assert m["point_recall"] > 0.5  # the shipped model finds most points of simple views
    per_image = m["per_image"]  # which views fail: the pooled counts, view by view
    assert [e["image"] for e in per_image] == sorted(p.name for p in
                                                     (labelled_views / "images").iterdir())
    assert sum(e["point_hits"] for e in per_image) == m["point_true_positives"]
    assert sum(e["false_points"] for e in per_image) == (m["point_detections"]
                                                         - m["point_true_positives"])
    assert sum(e["slot_labels"] for e in per_image) == m["slot_labels"]
    assert m["images_with_point_errors"] == sum(
        e["point_hits"] < e["point_labels"] or e["false_points"] > 0 for e in per_image)
    table = _run("evaluate", "detections", labelled_views / "images", labelled_views / "labels")
    assert table.exit_code == 0 and "images_with_point_errors" in table.output


def test_evaluate_detections_reads_ps2_l_directions_in_the_separator_convention():
    ps2 = PS2
    if not (ps2 / "labels").is_dir():
        pytest.skip(f"{ps2} is absent")
    args = ("evaluate", "detections", ps2 / "images", ps2 / "labels", "--json")
    turned, raw = _run(*args), _run(*args, "--label-directions")
    assert turned.exit_code == 0 and raw.exit_code == 0, turned.output + raw.output
    m_turned, m_raw = json.loads(turned.stdout), json.loads(raw.stdout)
    assert m_turned["labels_redirected"] == 8 and m_raw["labels_redirected"] == 0
    assert m_turned["point_detections"] == m_raw["point_detections"]
    assert m_turned["point_true_positives"] > m_raw["point_true_positives"]


def test_the_shipped_detector_keeps_its_measured_figures_on_the_real_ps2_samples():
    """A guard on the models and the checks behind them: BENCHMARKS.md reports 0.942 / 0.742
    (8-bit and 7-bit-weight twins) and 0.943 / 0.758 (float) on these 26 real views."""
    ps2 = PS2
    if not (ps2 / "labels").is_dir():
        pytest.skip(f"{ps2} is absent")
    result = _run("evaluate", "detections", ps2 / "images", ps2 / "labels", "--json")
    assert result.exit_code == 0, result.output
    metrics = json.loads(result.stdout)
    assert metrics["images"] == 26 and metrics["point_labels"] == 66
    assert metrics["point_precision"] >= 0.90
    assert metrics["point_recall"] >= 0.72  # 48 of 66 labels
    assert metrics["slot_recall"] >= 0.54


def test_evaluate_detections_refuses_a_folder_without_labels(tmp_path):
    (tmp_path / "images").mkdir()
    (tmp_path / "labels").mkdir()
    result = _run("evaluate", "detections", tmp_path / "images", tmp_path / "labels")
    assert result.exit_code == 2 and "no image with a label file" in result.stderr


def test_accuracy_and_plan_tags_on_a_small_world(tmp_path):
    world = make_world("small", 2).to_map()
    save_map(tmp_path / "world.json", world)
    t = np.arange(0.0, 20.0, 0.5)
    poses = np.column_stack([2.0 + 2.0 * t, np.full_like(t, 8.0), np.zeros_like(t)])
    write_tum(tmp_path / "route.tum", t, poses)
    result = _run("accuracy", tmp_path / "world.json", "--route", tmp_path / "route.tum",
                  "-o", tmp_path / "acc", "--grid-step", "4", "--json")
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["route"]["poses"] == len(t) and doc["grid"]["cells"] > 0
    assert (tmp_path / "acc" / "accuracy_map.png").stat().st_size > 10000
    result = _run("plan-tags", tmp_path / "world.json", "--route", tmp_path / "route.tum",
                  "-o", tmp_path / "plan", "--count", "2", "--json")
    assert result.exit_code == 0, result.output
    plan = json.loads(result.stdout)
    assert len(plan["greedy"]) == 3 and plan["greedy"][0]["count"] == 0
    result = _run("accuracy", tmp_path / "world.json", "-o", tmp_path / "a2", "--grade", "bad")
    assert result.exit_code == 2


def test_tags_planned_for_relocalization_are_seen_by_the_simulated_drive(tmp_path):
    """plan-tags --objective relocalization on a drive's route, then the same drive
    simulated with the plan: coverage rises with every tag, and the drive (the mapping
    route) sees every one."""
    bare = tmp_path / "bare"
    assert _run("simulate", bare, "--preset", "small", "--seed", "2", "--no-images",
                "--no-progress").exit_code == 0
    result = _run("plan-tags", bare / "world.json", "--route", bare / "groundtruth.tum",
                  "-o", tmp_path / "plan", "--count", "3", "--objective", "relocalization",
                  "--random-trials", "1", "--mapping-route", bare / "groundtruth.tum", "--json")
    assert result.exit_code == 0, result.output
    plan = json.loads(result.stdout)
    assert plan["mapping_route"] == str(bare / "groundtruth.tum") and plan["candidates"] > 0
    coverage = [s["relocalization_coverage"] for s in plan["greedy"]]
    assert plan["objective"] == "relocalization" and len(plan["proposed_tags"]) >= 1
    assert all(b > a for a, b in zip(coverage, coverage[1:], strict=False))
    placed = tmp_path / "placed"
    result = _run("simulate", placed, "--preset", "small", "--seed", "2", "--no-images",
                  "--tags", tmp_path / "plan" / "tag_plan.json", "--no-progress")
    assert result.exit_code == 0, result.output
    world = json.loads((placed / "world.json").read_text())
    bare_ids = {t["id"] for t in json.loads((bare / "world.json").read_text())["tags"]}
    new_ids = {t["id"] for t in world["tags"]} - bare_ids
    assert len(new_ids) == len(plan["proposed_tags"])
    seen = set()
    for line in (placed / "observations" / "exact.jsonl").read_text().splitlines():
        seen |= {t["id"] for t in json.loads(line).get("tags", [])}
    assert new_ids <= seen
