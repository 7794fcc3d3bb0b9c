"""Bad input found by the CLI audit: each case is one line on stderr, exit code 2, no
traceback, checked before any work, and nothing already written is lost."""

import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from semslam.cli import app
from semslam.io import save_map, write_tum
from semslam.types import SemanticMap

runner = CliRunner()


def _run(*args):
    return runner.invoke(app, [str(a) for a in args])


def _fails(result, *words):
    """Exit code 2 and one line on stderr that holds every word; no traceback."""
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.output
    for word in words:
        assert word in lines[0], (word, lines[0])
    return lines[0]


@pytest.fixture(scope="module")
def small_drive(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "drive"
    result = _run(
        "simulate", out, "--preset", "small", "--seed", "1", "--no-images", "--no-progress"
    )
    assert result.exit_code == 0, result.output
    return out


def _route(path: Path, xy) -> Path:
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    poses = np.column_stack([xy, np.zeros(len(xy))])
    write_tum(path, np.arange(len(xy), dtype=float) * 0.1, poses)
    return path


# 1
def test_localize_refuses_a_far_init_before_any_work(small_drive, tmp_path):
    result = _run("localize", small_drive, "--map", small_drive / "world.json",
                  "-o", tmp_path / "x.tum", "--init", "1e308,1e308,0")
    _fails(result, "--init", "x and y must be within 1e6 m")
    assert not (tmp_path / "x.tum").exists()


def test_localize_refuses_an_init_far_from_the_map(small_drive, tmp_path):
    """Within the 1e6 m bound but a kilometre and more from every landmark: it used to
    run and then fail writing the trajectory, blaming the output file."""
    result = _run("localize", small_drive, "--map", small_drive / "world.json",
                  "-o", tmp_path / "x.tum", "--init", "1e6,1e6,0", "--no-progress")
    _fails(result, "--init: 1e+06, 1e+06 is", "m from the landmarks of", "map's frame")
    assert not (tmp_path / "x.tum").exists()
    result = _run("localize", small_drive, "--map", small_drive / "world.json",
                  "-o", tmp_path / "x.tum", "--init", "-30,40,0", "--no-progress")
    assert result.exit_code == 0, result.output  # off the map but near: the filter's to fix


def test_map_refuses_a_folder_where_a_file_beside_the_map_goes(small_drive, tmp_path):
    (tmp_path / "m.audit.json").mkdir()
    result = _run("map", small_drive, "-o", tmp_path / "m.json", "--no-progress")
    _fails(result, "m.audit.json, written beside the map, is a folder")
    assert sorted(os.listdir(tmp_path)) == ["m.audit.json"]


def test_localize_refuses_to_write_over_its_own_map(small_drive, tmp_path):
    the_map = tmp_path / "m.json"
    shutil.copy(small_drive / "world.json", the_map)
    before = the_map.read_bytes()
    result = _run("localize", small_drive, "--map", the_map, "-o", the_map)
    _fails(result, "would replace", "the map it reads")
    assert the_map.read_bytes() == before


def test_no_output_replaces_the_config_or_graph_the_command_reads(small_drive, tmp_path):
    config = tmp_path / "cfg.json"
    config.write_text('{"mapping": {}}')
    link = tmp_path / "link.json"
    link.symlink_to(config)
    for args in (
        ("map", small_drive, "-o", config, "--config", config),
        ("map", small_drive, "-o", config, "--config", link),  # through a link
        ("map", small_drive, "-o", tmp_path / "cfg.json", "--config", tmp_path / "x/../cfg.json"),
        ("localize", small_drive, "--map", small_drive / "world.json", "-o",
         tmp_path / "cfg.tum", "--config", tmp_path / "cfg.csv"),  # the track CSV
    ):
        if args[-1].name == "cfg.csv":
            args[-1].write_text("{}")
        result = _run(*args, "--no-progress")
        _fails(result, "would replace", "the --config file it reads")
    assert config.read_text() == '{"mapping": {}}'
    again = tmp_path / "m.config.json"  # the config a map run left beside the map: re-run
    again.write_text('{"mapping": {}}')
    result = _run("map", small_drive, "-o", tmp_path / "m.json", "--config", again,
                  "--no-progress")
    assert result.exit_code == 0, result.output
    graph = tmp_path / "g.g2o"
    graph.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    before = graph.read_text()
    _fails(_run("optimize", graph, "-o", graph), "would replace", "the graph it reads")
    assert graph.read_text() == before


def test_demo_refuses_a_folder_of_other_files(tmp_path):
    (tmp_path / "report.md").write_text("my notes")
    result = _run("demo", tmp_path, "--preset", "small", "--no-progress")
    _fails(result, "folder is not empty and holds no earlier demo")
    assert sorted(os.listdir(tmp_path)) == ["report.md"]


# 2
@pytest.mark.parametrize("command", ["map", "localize", "optimize", "accuracy"])
def test_empty_output_path(small_drive, tmp_path, command):
    args = {
        "map": ("map", small_drive),
        "localize": ("localize", small_drive, "--map", small_drive / "world.json"),
        "optimize": ("optimize", tmp_path / "g.g2o"),
        "accuracy": ("accuracy", small_drive / "world.json"),
    }[command]
    _fails(_run(*args, "-o", ""), "-o: empty path")
    _fails(_run(*args, "-o", "-"), "-o -: semslam writes files, not standard output")


# 3
def test_tags_refuses_tiny_focal_lengths(tmp_path):
    image = tmp_path / "i.png"
    cv2.imwrite(str(image), np.full((64, 64), 128, np.uint8))
    result = _run("tags", image, "--intrinsics", "1e-300,1e-300,32,32", "--tag-size", "0.065")
    _fails(result, "--intrinsics", "at least 1 px")


@pytest.mark.parametrize(
    ("options", "words"),
    [  # finite but absurd: the tag-size one crashed while writing the JSON (NaN poses)
        (("--intrinsics", "600,600,32,32", "--tag-size", "1e300"), ("--tag-size", "to 100")),
        (("--intrinsics", "600,600,32,32", "--tag-size", "1e-9"), ("--tag-size", "from 0.001")),
        (("--intrinsics", "1e300,600,32,32", "--tag-size", "0.5"), ("--intrinsics", "1e+06 px")),
        (
            ("--intrinsics", "600,600,32,32", "--tag-size", "0.5", "--distortion", "1e300,0,0,0"),
            ("--distortion", "beyond 1e+06"),
        ),
    ],
)
def test_tags_refuses_absurd_sizes(tmp_path, options, words):
    image = tmp_path / "i.png"
    cv2.imwrite(str(image), np.full((64, 64), 128, np.uint8))
    _fails(_run("tags", image, *options, "--json"), *words)


# 4
@pytest.mark.parametrize("option", ["--seed", "--drive"])
def test_simulate_refuses_negative_seed_and_drive(tmp_path, option):
    result = _run("simulate", tmp_path / "x", "--preset", "small", option, "-1", "--no-images")
    _fails(result, option, "-1")
    assert not (tmp_path / "x").exists()


def test_demo_refuses_a_negative_seed_and_creates_no_folder(tmp_path):
    _fails(_run("demo", tmp_path / "demo", "--seed", "-1"), "--seed", "-1")
    assert not (tmp_path / "demo").exists()


# 5
@pytest.mark.parametrize("frames", ["0", "-1"])
def test_bench_refuses_no_frames(frames):
    _fails(_run("bench", "--frames", frames), "--frames", "at least 1")


@pytest.mark.parametrize("frames", ["10001", "99999999999999999999999"])
def test_bench_refuses_more_frames_than_minutes_of_timing(frames):
    _fails(_run("bench", "--frames", frames), "--frames: at most 10,000")  # numpy crashed


# 6
@pytest.mark.parametrize(("size", "decimate", "left"), [((792, 1056), "400", "2 x 1"),
                                                        ((16, 16), "8", "2 x 2")])
def test_tags_refuses_a_decimation_that_leaves_almost_no_image(tmp_path, size, decimate, left):
    image = tmp_path / "i.png"
    cv2.imwrite(str(image), np.full(size, 200, np.uint8))
    result = _run("tags", image, "--intrinsics", "329.9,332.9,8,8", "--tag-size", "0.065",
                  "--decimate", decimate)
    _fails(result, str(image), f"decimate {decimate} leaves a {left} px image")


# 7
@pytest.mark.parametrize("xy", [[(1.0, 2.0)], [(1.0, 2.0), (1.0, 2.0)]])
def test_plan_tags_refuses_a_route_without_length_and_writes_nothing(small_drive, tmp_path, xy):
    route = _route(tmp_path / "two.tum", xy)
    out = tmp_path / "p"
    result = _run("plan-tags", small_drive / "world.json", "--route", route, "-o", out,
                  "--count", "1", "--random-trials", "2")
    _fails(result, str(route), "the route needs at least two poses and some length")
    assert not (out / "tag_plan.json").exists()


@pytest.mark.parametrize(
    ("plan", "words"),
    [
        (None, ["file not found"]),
        ("{}", ["missing field 'proposed_tags'"]),
        ('{"proposed_tags": [{"x": 1, "y": NaN, "yaw": 0}]}', ["proposed_tags/0/y", "NaN"]),
        ('{"proposed_tags": [{"x": 1, "y": 2}]}', ["proposed_tags/0", "'yaw'"]),
        ('{"proposed_tags": [{"x": 1e300, "y": 2, "yaw": 0}]}', ["proposed_tags/0/x", "<="]),
    ],
)
def test_simulate_refuses_a_broken_tag_plan_and_writes_nothing(tmp_path, plan, words):
    path = tmp_path / "tag_plan.json"
    if plan is not None:
        path.write_text(plan)
    out = tmp_path / "drive"
    result = _run("simulate", out, "--preset", "small", "--no-images", "--tags", path)
    _fails(result, str(path), *words)
    assert not out.exists()


def test_plan_tags_refuses_an_unknown_objective_and_a_bad_time(small_drive, tmp_path):
    route = _route(tmp_path / "r.tum", [(0, 0), (5, 0)])
    result = _run("plan-tags", small_drive / "world.json", "--route", route,
                  "-o", tmp_path / "p", "--within", "0")
    _fails(result, "--within", "seconds")
    result = _run("plan-tags", small_drive / "world.json", "--route", route,
                  "-o", tmp_path / "p", "--objective", "beauty")
    assert result.exit_code == 2 and "Traceback" not in result.output


def test_plan_tags_refuses_a_mapping_route_that_sees_no_candidate(small_drive, tmp_path):
    """The mapping drive goes the other way, so it faces none of the candidates (they face
    the cars on --route): nothing to propose, and nothing written."""
    x = np.arange(0.0, 30.5, 0.5)
    route = _route(tmp_path / "r.tum", np.column_stack([x, 0 * x]))
    back = tmp_path / "back.tum"
    write_tum(back, x * 0.1, np.column_stack([x[::-1], 0 * x, np.full_like(x, np.pi)]))
    out = tmp_path / "p"
    result = _run("plan-tags", small_drive / "world.json", "--route", route, "-o", out,
                  "--mapping-route", back, "--random-trials", "1")
    _fails(result, "--mapping-route", str(back), "sees none of the 10 candidate tags")
    assert not (out / "tag_plan.json").exists()
    result = _run("plan-tags", small_drive / "world.json", "--route", route, "-o", out,
                  "--mapping-route", tmp_path / "missing.tum", "--random-trials", "1")
    _fails(result, "missing.tum")


def test_plan_tags_caps_count(small_drive, tmp_path):
    route = _route(tmp_path / "r.tum", [(0, 0), (5, 0)])
    result = _run("plan-tags", small_drive / "world.json", "--route", route,
                  "-o", tmp_path / "p", "--count", "100000")
    _fails(result, "--count", "1000")


# 8
def test_localize_refuses_an_output_that_is_its_own_track_csv(small_drive, tmp_path):
    out = tmp_path / "t.csv"
    out.write_text("keep\n")
    result = _run("localize", small_drive, "--map", small_drive / "world.json", "-o", out)
    _fails(result, f"-o {out}", "track CSV")
    assert out.read_text() == "keep\n"


def test_map_refuses_an_output_that_a_by_product_would_replace(small_drive, tmp_path):
    _fails(_run("map", small_drive, "-o", tmp_path / "m.g2o"), "m.g2o", "replace")


# 9
def test_outputs_are_checked_before_the_work(small_drive, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("keep\n")
    world = small_drive / "world.json"
    route = _route(tmp_path / "r.tum", [(0, 0), (5, 0)])
    cases = [
        ("map", small_drive, "-o", afile / "m.json"),
        ("localize", small_drive, "--map", world, "-o", afile / "t.tum"),
        ("optimize", tmp_path / "g.g2o", "-o", afile / "o.g2o"),
        ("accuracy", world, "-o", afile),
        ("plan-tags", world, "--route", route, "-o", afile / "p"),
        ("simulate", afile / "d", "--preset", "small", "--no-images"),
        ("detect", tmp_path / "i.png", "--overlay", afile),
    ]
    for args in cases:
        line = _fails(_run(*args), "afile")
        assert "is a file, not a folder" in line, line
    assert afile.read_text() == "keep\n"
    _fails(_run("map", small_drive, "-o", tmp_path), "is a folder, not a file")


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs /proc")
def test_an_output_in_an_unwritable_folder_is_named_up_front(small_drive):
    line = _fails(_run("map", small_drive, "-o", "/proc/m.json"), "-o /proc/m.json",
                  "cannot write in /proc")
    assert ".tmp" not in line
    # a drive folder too: named as asked, not the hidden folder it would be staged in
    line = _fails(_run("import", "garage-bev", small_drive, "/proc/gb"), "OUT /proc/gb",
                  "cannot write in /proc")
    assert ".partial" not in line


# 10
def test_localize_fails_when_no_frame_gets_a_pose(small_drive, tmp_path):
    empty = tmp_path / "empty.json"
    save_map(empty, SemanticMap())
    out = tmp_path / "t.tum"
    out.write_text("keep\n")
    result = _run("localize", small_drive, "--map", empty, "-o", out, "--init", "auto",
                  "--no-progress")
    _fails(result, "no pose was found in any frame")
    assert out.read_text() == "keep\n" and not out.with_suffix(".csv").exists()


# 11
def test_detect_writes_no_overlay_when_an_image_is_bad(tmp_path):
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), np.zeros((600, 600, 3), np.uint8))
    bad = tmp_path / "zero.png"
    bad.write_bytes(b"")
    result = _run("detect", good, bad, "--overlay", tmp_path / "ov", "--no-lines")
    _fails(result, str(bad))
    assert not (tmp_path / "ov" / "good.png").exists()


def test_detect_refuses_two_images_that_would_write_one_overlay(tmp_path):
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir()
        cv2.imwrite(str(tmp_path / folder / "x.png"), np.zeros((600, 600, 3), np.uint8))
    first, second = tmp_path / "a" / "x.png", tmp_path / "b" / "x.png"
    result = _run("detect", first, second, "--overlay", tmp_path / "ov", "--no-lines")
    _fails(result, f"{second}: its overlay would replace that of {first}")
    assert not (tmp_path / "ov").exists()


def test_detect_refuses_an_overlay_folder_that_holds_the_images(tmp_path):
    image = tmp_path / "x.png"
    cv2.imwrite(str(image), np.zeros((600, 600, 3), np.uint8))
    before = image.read_bytes()
    result = _run("detect", tmp_path, "--overlay", tmp_path, "--no-lines")
    _fails(result, "the overlay folder holds the input image", str(image))
    assert image.read_bytes() == before


def test_topview_perception_reads_slots_and_ids_on_its_own_grid():
    from semslam.perception.topview_perception import TopviewPerception
    from semslam.rig import TopviewSpec

    spec = TopviewSpec(size_px=500, metres_per_px=0.02)
    assert TopviewPerception(spec=spec, lines=False).slot_detector.spec == spec


def test_detect_names_the_image_too_wide_for_the_detectors(tmp_path):
    image = tmp_path / "wide.png"
    cv2.imwrite(str(image), np.zeros((79, 105, 3), np.uint8))
    line = _fails(_run("detect", image, "--px-per-m", "10"), "105 x 79 px at 10 px per metre")
    assert line.startswith(f"semslam: error: {image}: "), line
    assert "covers 10.5 m" in line
    assert _run("detect", image).exit_code == 0  # read as 10 m across, as ps2.0's views


def test_map_from_images_refuses_a_front_image_of_the_wrong_size(small_drive, tmp_path):
    drive = shutil.copytree(small_drive, tmp_path / "d")  # a copy to break
    times = (drive / "frames.csv").read_text().split()[1:]
    (drive / "img").mkdir()
    cv2.imwrite(str(drive / "img" / "f0.png"), np.full((400, 640), 128, np.uint8))
    rows = ["t,front", f"{times[0]},img/f0.png", *(f"{t}," for t in times[1:])]
    (drive / "frames.csv").write_text("\n".join(rows) + "\n")
    result = runner.invoke(app, ["map", str(drive), "-o", str(tmp_path / "m.json"),
                                 "--observations", "images", "--no-progress"])
    assert result.exit_code == 2, result.output
    assert "f0.png: 640 x 400 px, but rig.json gives the front camera 1280 x 800" in result.stderr
    assert "Traceback" not in result.output
    assert not (tmp_path / "m.json").exists()


def test_map_from_images_names_a_top_view_of_the_wrong_size(small_drive, tmp_path):
    drive = shutil.copytree(small_drive, tmp_path / "d")  # a copy to break
    times = (drive / "frames.csv").read_text().split()[1:]
    (drive / "img").mkdir()
    cv2.imwrite(str(drive / "img" / "t0.png"), np.full((100, 100, 3), 128, np.uint8))
    rows = ["t,topview", f"{times[0]},img/t0.png", *(f"{t}," for t in times[1:])]
    (drive / "frames.csv").write_text("\n".join(rows) + "\n")
    result = runner.invoke(app, ["map", str(drive), "-o", str(tmp_path / "m.json"),
                                 "--observations", "images", "--no-progress"])
    assert result.exit_code == 2, result.output
    assert f"{drive / 'img' / 't0.png'}: " in result.stderr and "100 x 100" in result.stderr
    assert not (tmp_path / "m.json").exists()


def test_map_and_localize_refuse_odometry_cut_short(small_drive, tmp_path):
    drive = shutil.copytree(small_drive, tmp_path / "d")  # a copy to break
    built = runner.invoke(app, ["map", str(drive), "-o", str(tmp_path / "m.json"),
                                "--no-progress"])
    assert built.exit_code == 0, built.output
    lines = (drive / "odometry.csv").read_text().splitlines()
    (drive / "odometry.csv").write_text("\n".join(lines[:500]) + "\n")
    for args in (["map", str(drive), "-o", str(tmp_path / "m2.json")],
                 ["localize", str(drive), "--map", str(tmp_path / "m.json"),
                  "-o", str(tmp_path / "t.tum")]):
        result = runner.invoke(app, [*args, "--no-progress"])
        assert result.exit_code == 2, result.output
        assert str(drive) in result.stderr and "is odometry.csv cut short?" in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "m2.json").exists() and not (tmp_path / "t.tum").exists()


def test_localize_refuses_a_broken_drive_json_it_would_not_otherwise_read(small_drive, tmp_path):
    drive = shutil.copytree(small_drive, tmp_path / "d")  # a copy to break
    (drive / "drive.json").write_text("{")
    result = _run("localize", drive, "--map", drive / "world.json", "-o", tmp_path / "t.tum",
                  "--init", "auto", "--no-progress")
    _fails(result, "drive.json", "not valid JSON")
    assert not (tmp_path / "t.tum").exists()


def test_evaluate_trajectory_refuses_times_that_never_meet_the_truth(small_drive, tmp_path):
    estimate = tmp_path / "late.tum"
    write_tum(estimate, np.array([500.0, 501.0]), np.zeros((2, 3)))
    line = _fails(_run("evaluate", "trajectory", estimate, "--truth",
                       small_drive / "groundtruth.tum"), "late.tum", "no pose lies within")
    assert "500.000-501.000 s" in line and "0.000-91.900 s" in line


@pytest.mark.parametrize(
    ("args", "message"),
    [(["map"], "semslam map: error: Missing argument 'drive'."),
     (["nosuch"], "semslam: error: No such command 'nosuch'."),
     (["accuracy", "m.json", "-o", "x", "--grid-step", "abc"],
      "semslam accuracy: error: Invalid value for '--grid-step'"),
     (["map", "d", "-o", "m.json", "--robust", "dcs"],  # named the config, not the option
      "semslam map: error: Invalid value for '--robust': 'dcs' is not one of 'maxmix', 'none'"),
     (["localize", "d", "--map", "m.json", "-o", "t.tum", "--update", "x"],
      "semslam localize: error: Invalid value for '--update': 'x' is not one of 'ekf'"),
     (["map", "d", "-o"],  # pointed at `semslam --help`
      "semslam map: error: Option '-o' requires an argument. (see semslam map --help)")],
)
def test_usage_errors_are_one_line_through_the_console_entry(args, message):
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "semslam", *args], capture_output=True,
                          text=True, check=False)
    assert proc.returncode == 2
    assert proc.stderr.startswith(message) and len(proc.stderr.strip().splitlines()) == 1
    assert "Traceback" not in proc.stderr and proc.stdout == ""


def test_map_and_localize_refuse_to_write_over_a_file_of_their_drive(small_drive, tmp_path):
    odometry = small_drive / "odometry.csv"
    before = odometry.read_bytes()
    _fails(_run("map", small_drive, "-o", odometry, "--no-progress"),
           "would replace", "a file of the drive")
    _fails(_run("localize", small_drive, "--map", small_drive / "world.json",
                "-o", small_drive / "groundtruth.tum", "--no-progress"),
           "would replace", "a file of the drive")
    assert odometry.read_bytes() == before


def test_an_output_that_is_a_pipe_is_refused_and_left_a_pipe(small_drive, tmp_path):
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    _fails(_run("map", small_drive, "-o", fifo, "--no-progress"), "not a regular file")
    assert fifo.exists() and not fifo.is_file()


def test_map_reports_an_indeterminate_graph_in_one_line(small_drive, tmp_path):
    """A marking sigma of 1e-300 makes gtsam's system indeterminate; iSAM2 finds out only
    when an estimate is read, which used to escape as gtsam's ten-line RuntimeError."""
    config = tmp_path / "c.json"
    config.write_text('{"mapping": {"marking_sigma": 1e-300}}')
    out = tmp_path / "m.json"
    result = _run("map", small_drive, "-o", out, "--config", config, "--no-progress")
    _fails(result, "the factor graph could not be solved", "Indeterminate")
    assert not out.exists()


def test_simulate_refuses_a_frame_rate_that_leaves_no_frames(tmp_path):
    config = tmp_path / "c.json"
    config.write_text('{"simulation": {"drive": {"frame_rate": 1e-20}}}')
    result = _run("simulate", tmp_path / "d", "--preset", "small", "--no-images",
                  "--config", config, "--no-progress")
    _fails(result, "simulation.drive.frame_rate", "0.1")
    assert not (tmp_path / "d").exists()


def test_simulate_names_the_drive_not_its_temporary_folder(tmp_path):
    """Odometry noise so large that the drive's odometry is impossible: the error names
    the file in the drive folder asked for, not the hidden folder it was written in."""
    config = tmp_path / "c.json"
    config.write_text('{"simulation": {"odometry_noise": {"gyro_sigma": 1000}}}')
    out = tmp_path / "d"
    result = _run("simulate", out, "--preset", "small", "--no-images",
                  "--config", config, "--no-progress")
    line = _fails(result, f"{out.resolve()}/odometry.csv", "yaw_rate", "nothing was written")
    assert "partial" not in line
    assert not out.exists() and list(tmp_path.iterdir()) == [config]


def test_map_refuses_observations_cut_at_a_line_boundary(small_drive, tmp_path):
    drive = tmp_path / "drive"
    shutil.copytree(small_drive, drive)
    observations = drive / "observations" / "noisy.jsonl"
    lines = observations.read_text().splitlines(keepends=True)
    observations.write_text("".join(lines[: len(lines) // 2]))
    result = _run("map", drive, "-o", tmp_path / "m.json", "--no-progress")
    _fails(result, str(observations), "the observations end at", "looks cut short")


def test_sigterm_removes_the_half_written_drive(tmp_path):
    """SIGTERM (a job scheduler's stop) cleans up as Ctrl-C does: no `.partial-PID` left."""
    import signal
    import subprocess
    import sys
    import time

    process = subprocess.Popen(
        [sys.executable, "-m", "semslam", "simulate", tmp_path / "d", "--no-progress"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60
    while not any(tmp_path.glob(".d.partial-*")) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert any(tmp_path.glob(".d.partial-*")), "the simulation never started writing"
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=60) == 128 + signal.SIGTERM
    assert list(tmp_path.iterdir()) == []


def test_a_drive_folder_whose_name_is_not_utf8_maps(small_drive, tmp_path):
    """The map's metadata holds the drive's path: a name with a byte that is not UTF-8 used
    to crash the writer (a lone surrogate); it is written as U+FFFD."""
    from semslam.io import load_map

    drive = tmp_path / os.fsdecode(b"bad\xffname")
    shutil.copytree(small_drive, drive)
    out = tmp_path / "m.json"
    result = _run("map", drive, "-o", out, "--no-progress")
    assert result.exit_code == 0, result.output
    assert load_map(out).metadata["source"].endswith("bad\ufffdname")


@pytest.mark.parametrize(
    ("args", "words"),
    [  # messages named the library's arguments (crop_rows, radius), not the options
        (["import", "garage-bev", "src", "out", "--every", "0"], ["--every: must be >= 1"]),
        (["import", "garage-bev", "src", "out", "--crop-rows", "-1"], ["--crop-rows: must be"]),
        (["evaluate", "markings", "m.json", "--vector-map", "v", "--radius", "0"],
         ["--radius: must be a positive number"]),
    ],
)
def test_errors_name_the_option_given(tmp_path, monkeypatch, args, words):
    monkeypatch.chdir(tmp_path)
    _fails(_run(*args), *words)


def test_an_output_file_named_like_a_folder_is_refused(small_drive, tmp_path):
    result = _run("map", small_drive, "-o", f"{tmp_path}/newout/", "--no-progress")
    _fails(result, "newout/: ends in a slash")
    assert os.listdir(tmp_path) == []  # it wrote a file `newout` and five beside it


def test_a_terminal_that_cannot_show_a_path_does_not_crash_the_summary(tmp_path):
    """PYTHONIOENCODING=ascii: rich's summary table raised UnicodeEncodeError after the
    outputs were written (exit 1, a traceback)."""
    import subprocess
    import sys

    graph = tmp_path / "ü.g2o"
    graph.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    proc = subprocess.run(
        [sys.executable, "-m", "semslam", "optimize", str(graph), "-o", str(tmp_path / "ö.g2o")],
        capture_output=True, text=True, check=False,
        env={**os.environ, "PYTHONIOENCODING": "ascii"},
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "ö.g2o").is_file()


@pytest.mark.parametrize("args", [["dump-config"], ["--help"]])
def test_a_closed_output_pipe_ends_quietly(args):
    """`semslam dump-config | head -0`: exit 1 with nothing on stderr (click's way), as
    every command does; dump-config used to report '[Errno 32] Broken pipe' as an error."""
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "semslam", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    err = proc.stderr.read()
    proc.stderr.close()
    assert proc.wait() in (0, 1) and b"Errno" not in err and b"Traceback" not in err


def test_plan_tags_refuses_a_route_far_from_the_map(small_drive, tmp_path):
    """A route given in another frame (5 km off) planned tags as for an empty map."""
    route = _route(tmp_path / "far.tum", [[5000, 5000], [5010, 5000], [5020, 5000]])
    result = _run("plan-tags", small_drive / "world.json", "--route", route,
                  "-o", tmp_path / "plan", "--count", "2")
    _fails(result, "--route", "comes no nearer than", "give it in the map's frame")
    assert not (tmp_path / "plan").exists()


def test_a_drive_that_stands_still_says_why_its_map_is_empty(small_drive, tmp_path):
    """Found by fuzzing: a car that never moved mapped nothing without a word."""
    drive = tmp_path / "standing"
    shutil.copytree(small_drive, drive)
    odometry = (drive / "odometry.csv").read_text().splitlines()
    t = [line.split(",")[0] for line in odometry[1:]]
    (drive / "odometry.csv").write_text(
        "\n".join([odometry[0], *(f"{ti},0.0,0.0" for ti in t)]) + "\n"
    )
    result = _run("map", drive, "-o", tmp_path / "m.json", "--no-progress")
    assert result.exit_code == 0, result.output
    assert "nothing mapped" in result.output and "never moved" in result.output


def test_simulate_refuses_an_empty_out_dir():
    _fails(_run("simulate", "", "--preset", "small", "--no-images"), "OUT_DIR: empty path")


def test_simulated_values_out_of_range_name_the_settings(tmp_path):
    config = tmp_path / "loud.json"
    config.write_text('{"simulation": {"odometry_noise": {"speed_sigma": 1000}}}')
    out = tmp_path / "drive"
    line = _fails(_run("simulate", out, "--preset", "small", "--no-images", "--no-progress",
                       "--config", config), "odometry.csv", "speed", "simulation settings",
                  "nothing was written")
    assert "dump-config" in line and not out.exists()


def test_an_unsolvable_graph_names_the_drive_and_the_settings(small_drive, tmp_path):
    config = tmp_path / "tiny.json"
    config.write_text('{"mapping": {"marking_sigma": 1e-300}}')
    out = tmp_path / "map.json"
    _fails(_run("map", small_drive, "-o", out, "--config", config, "--no-progress"),
           str(small_drive), "could not be solved", "mapping sigma", "dump-config")
    assert not out.exists()


def test_accuracy_refuses_to_write_over_the_map_it_reads(tmp_path):
    the_map = tmp_path / "config.json"  # where --grade localizer writes its settings
    save_map(the_map, SemanticMap())
    before = the_map.read_text()
    _fails(_run("accuracy", the_map, "-o", tmp_path, "--grade", "localizer"),
           "would replace", "the map it reads")
    assert the_map.read_text() == before


def test_localize_stops_when_odometry_drives_the_estimate_past_any_trajectory(small_drive,
                                                                                  tmp_path):
    """Speeds of +-100 m/s sample by sample are each within the reader's bounds; the filter's
    estimate then ran past 1,000 km and the run stopped only on writing its own trajectory
    ("T.tum: pose 437: x 1.01e+06 is out of range"; found by semantic fuzzing). It now stops
    at that frame, naming the drive and the odometry."""
    drive = tmp_path / "drive"
    shutil.copytree(small_drive, drive)
    rows = (drive / "odometry.csv").read_text().splitlines()
    flipped = [rows[0]] + [
        f"{t},{100.0 if i % 2 == 0 else -100.0},{w}"
        for i, (t, _, w) in enumerate(r.split(",") for r in rows[1:])
    ]
    (drive / "odometry.csv").write_text("\n".join(flipped) + "\n")
    result = _run("localize", drive, "--map", small_drive / "world.json", "-o",
                  tmp_path / "T.tum", "--no-progress")
    _fails(result, "the estimate is over 1000 km from the map's origin", "100 m/s",
           "T.tum not written")
    assert not (tmp_path / "T.tum").exists()
