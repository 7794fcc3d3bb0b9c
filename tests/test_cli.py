"""Smoke tests of every command, through the real CLI entry point."""

import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from semslam import __version__
from semslam.cli import app
from semslam.config import load_config
from semslam.io import Drive

runner = CliRunner()


def _run(*args, env=None):
    return runner.invoke(app, [str(a) for a in args], env=env)


@pytest.fixture(scope="module")
def small_drive(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "drive"
    result = _run(
        "simulate", out, "--preset", "small", "--seed", "3", "--no-images", "--no-progress"
    )
    assert result.exit_code == 0, result.output
    return out


def test_version():
    result = _run("--version")
    assert result.exit_code == 0
    assert __version__ in result.stdout


def _commands(typer_app):
    for command in typer_app.registered_commands:
        yield command.callback
    for group in typer_app.registered_groups:
        yield from _commands(group.typer_instance)


def test_every_command_summary_is_one_line():
    """The command lists print a docstring's first paragraph with its line breaks kept."""
    callbacks = list(_commands(app))
    assert len(callbacks) >= 15
    for callback in callbacks:
        summary = callback.__doc__.strip().split("\n\n")[0]
        assert "\n" not in summary, f"{callback.__name__}: {summary!r}"


def test_dump_config_is_json_with_defaults_and_env_overrides():
    result = _run("dump-config", env={"SEMSLAM_SIMULATION__DRIVE__MAX_SPEED": "2.5"})
    assert result.exit_code == 0
    config = json.loads(result.stdout)
    assert config["simulation"]["drive"]["max_speed"] == 2.5
    assert config["simulation"]["observation_noise"]["slot_miss_rate"] == 0.2


def test_simulate_writes_a_complete_readable_drive(small_drive):
    drive = Drive.open(small_drive)
    assert drive.info.start_pose is not None
    odo = drive.odometry()
    frames = drive.frames()
    t_gt, poses = drive.groundtruth()
    assert len(odo.t) > 4 * len(frames.t)
    assert np.allclose(t_gt, frames.t)
    assert np.allclose(poses[0], drive.start_pose, atol=1e-6)
    assert len(drive.world().slots) > 30
    assert set(drive.observation_names()) == {"exact", "noisy"}
    assert len(drive.observations("noisy")) == len(frames.t)
    assert json.loads((small_drive / "config.json").read_text())["simulation"]
    assert "summary" not in (small_drive / "drive.json").read_text()


def test_simulate_same_seed_same_bytes(small_drive, tmp_path):
    out = tmp_path / "again"
    assert (
        _run(
            "simulate", out, "--preset", "small", "--seed", "3", "--no-images", "--no-progress"
        ).exit_code
        == 0
    )
    for name in (
        "odometry.csv",
        "groundtruth.tum",
        "world.json",
        "observations/noisy.jsonl",
        "observations/exact.jsonl",
        "rig.json",
        "drive.json",
        "frames.csv",
    ):
        assert (out / name).read_bytes() == (small_drive / name).read_bytes(), name


def test_simulate_with_images_writes_images_and_labels(tmp_path):
    out = tmp_path / "img"
    result = _run(
        "simulate",
        out,
        "--preset",
        "small",
        "--seed",
        "1",
        "--no-progress",
        env={
            "SEMSLAM_SIMULATION__DRIVE__MAX_DURATION": "0.55",
            "SEMSLAM_SIMULATION__RENDER__WORKERS": "1",
        },
    )
    assert result.exit_code == 0, result.output
    drive = Drive.open(out)
    frames = drive.frames()
    assert len(frames.t) == 6
    for column in ("topview", "front"):
        assert drive.image_path(column, 5).stat().st_size > 10_000
    labels = json.loads((out / "labels" / "topview" / "000000.json").read_text())
    assert set(labels) >= {"marks", "slots"}


def test_simulate_refuses_a_folder_with_other_files(tmp_path):
    (tmp_path / "precious.txt").write_text("keep me")
    result = _run("simulate", tmp_path, "--preset", "small", "--no-images")
    assert result.exit_code == 2
    assert "not empty" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert (tmp_path / "precious.txt").read_text() == "keep me"


def test_simulate_refuses_to_replace_a_drive_holding_a_users_files(small_drive, tmp_path):
    import shutil

    drive = shutil.copytree(small_drive, tmp_path / "d")
    (drive / "mymap.json").write_text("keep me")
    result = _run("simulate", drive, "--preset", "small", "--seed", "4", "--no-images",
                  "--no-progress")
    assert result.exit_code == 2, result.output
    assert "also holds mymap.json" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    assert (drive / "mymap.json").read_text() == "keep me"
    (drive / "mymap.json").unlink()  # a drive folder with only a drive's files is replaced
    again = _run("simulate", drive, "--preset", "small", "--seed", "4", "--no-images",
                 "--no-progress")
    assert again.exit_code == 0, again.output


def test_broken_config_file_is_one_line_error(tmp_path):
    cfg = tmp_path / "c.json"
    cfg.write_text('{"simulation": {"drive": {"max_speed": -1}}}')
    result = _run("dump-config", "--config", cfg)
    assert result.exit_code == 2
    assert "simulation.drive.max_speed" in result.stderr
    cfg.write_text('{"simulation": ')
    result = _run("dump-config", "--config", cfg)
    assert result.exit_code == 2 and "c.json" in result.stderr
    cfg.write_text('{"mapping": {"corner_sigma_typo": 0.1}}')  # a misspelt setting
    result = _run("dump-config", "--config", cfg)
    assert result.exit_code == 2
    assert "c.json: mapping.corner_sigma_typo: not a setting semslam knows" in result.stderr


def test_unknown_preset_exits_nonzero(tmp_path):
    result = _run("simulate", tmp_path / "x", "--preset", "huge")
    assert result.exit_code != 0


def test_console_script_module_entry_point_runs():
    proc = subprocess.run(
        [sys.executable, "-m", "semslam", "--version"], capture_output=True, text=True, check=False
    )
    assert proc.returncode == 0 and __version__ in proc.stdout


def test_evaluate_map_of_the_truth_is_perfect(small_drive):
    world = small_drive / "world.json"
    result = _run("evaluate", "map", world, "--truth", world, "--json")
    assert result.exit_code == 0, result.output
    metrics = json.loads(result.stdout)
    assert metrics["corner_rmse_m"] == 0.0
    assert metrics["slots_matched"] == metrics["slots_true"]
    assert metrics["id_accuracy"] == 1.0


def test_evaluate_map_refuses_a_broken_map(small_drive, tmp_path):
    broken = tmp_path / "map.json"
    broken.write_text((small_drive / "world.json").read_text()[:500])
    result = _run("evaluate", "map", broken, "--truth", small_drive / "world.json")
    assert result.exit_code == 2
    assert "map.json" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_map_writes_a_valid_map_and_its_by_products(small_drive, tmp_path):
    out = tmp_path / "garage.json"
    result = _run("map", small_drive, "-o", out, "--observations", "noisy", "--no-progress")
    assert result.exit_code == 0, result.output
    for suffix in (
        ".json",
        ".trajectory.tum",
        ".audit.jsonl",
        ".audit.json",
        ".config.json",
        ".g2o",
    ):
        assert (tmp_path / f"garage{suffix}").stat().st_size > 0
    metrics = json.loads(
        _run("evaluate", "map", out, "--truth", small_drive / "world.json", "--json").stdout
    )
    assert metrics["slots_matched"] >= 0.9 * metrics["slots_mapped"]
    audit = [
        json.loads(line) for line in (tmp_path / "garage.audit.jsonl").read_text().splitlines()
    ]
    assert {a["status"] for a in audit} <= {"accepted", "null", "reassigned", "pooled"}
    by_slot = json.loads((tmp_path / "garage.audit.json").read_text())["slots"]
    assert len(by_slot) == metrics["slots_mapped"]
    accepted = sum(len(s["accepted"]) for s in by_slot)
    assert accepted == sum(
        a["status"] in ("accepted", "reassigned") and a["slot"] is not None for a in audit
    )
    # the exported graph reads back and solves
    solved = _run("optimize", tmp_path / "garage.g2o", "-o", tmp_path / "solved.g2o", "--json")
    assert solved.exit_code == 0, solved.output
    assert json.loads(solved.stdout)["poses"] > 10


def test_map_refuses_missing_drive_and_unknown_observations(small_drive, tmp_path):
    result = _run("map", tmp_path / "nothing", "-o", tmp_path / "m.json")
    assert result.exit_code == 2 and "drive folder not found" in result.stderr
    result = _run("map", small_drive, "-o", tmp_path / "m.json", "--observations", "images")
    assert result.exit_code == 2 and "needs a topview or front image column" in result.stderr
    assert not (tmp_path / "m.json").exists()


def test_optimize_solves_a_small_g2o_graph_and_refuses_a_broken_one(tmp_path):
    lines = ["VERTEX_SE2 0 0 0 0", "VERTEX_SE2 1 1.1 0.1 0.05", "VERTEX_SE2 2 2.2 -0.1 0"]
    info = "100 0 0 100 0 1000"
    lines += [
        f"EDGE_SE2 0 1 1 0 0 {info}",
        f"EDGE_SE2 1 2 1 0 0 {info}",
        f"EDGE_SE2_MIXTURE 0 2 2 EDGE_SE2 1 0 2 2 0 0 {info} "
        f"EDGE_SE2 0.01 0 2 2 0 0 {' '.join('1e-9' if v != '0' else '0' for v in info.split())}",
    ]
    graph = tmp_path / "g.g2o"
    graph.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.g2o"
    result = _run("optimize", graph, "-o", out, "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["mixtures"] == 1 and summary["accepted"] == 1
    assert "VERTEX_SE2 2 2" in out.read_text()
    result = _run("optimize", graph, "-o", out, "--robust", "dcs", "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["robust"] == "dcs" and summary["accepted"] == 1
    two_targets = lines[:-1] + [
        f"EDGE_SE2_MIXTURE 0 2 2 EDGE_SE2 1 0 2 2 0 0 {info} EDGE_SE2 1 0 1 2 0 0 {info}"
    ]
    graph.write_text("\n".join(two_targets) + "\n")
    result = _run("optimize", graph, "-o", out, "--robust", "dcs")
    assert result.exit_code == 2 and "use 'maxmix'" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1
    graph.write_text("VERTEX_SE2 0 0 0\n")
    result = _run("optimize", graph, "-o", out)
    assert result.exit_code == 2 and "line 1" in result.stderr


def test_localize_against_the_true_map_writes_tum_and_track_and_evaluates(small_drive, tmp_path):
    traj = tmp_path / "traj.tum"
    result = _run("localize", small_drive, "--map", small_drive / "world.json", "-o", traj,
                  "--no-progress")
    assert result.exit_code == 0, result.output
    assert traj.stat().st_size > 0 and traj.with_suffix(".csv").stat().st_size > 0
    assert "wheel-speed scale error" in result.output and "gyro bias" in result.output
    result = _run("evaluate", "trajectory", traj, "--truth", small_drive / "groundtruth.tum",
                  "--map", small_drive / "world.json", "--json")
    assert result.exit_code == 0, result.output
    metrics = json.loads(result.stdout)
    assert metrics["ate_rmse_m"] < 0.1 and metrics["frames_lost"] == 0
    assert 0.5 < metrics["nees_mean"] < 10
    auto = _run("localize", small_drive, "--map", small_drive / "world.json", "-o",
                tmp_path / "auto.tum", "--init", "auto", "--update", "sigma", "--no-progress")
    assert auto.exit_code == 0, auto.output
    # the settings in force beside the results, readable as --config
    assert load_config(traj.with_name("traj.config.json")).localization.update == "ekf"
    assert load_config(tmp_path / "auto.config.json").localization.update == "sigma"


def test_localize_refuses_a_broken_map_and_a_bad_init(small_drive, tmp_path):
    broken = tmp_path / "map.json"
    broken.write_text((small_drive / "world.json").read_text()[:300])
    result = _run("localize", small_drive, "--map", broken, "-o", tmp_path / "t.tum")
    assert result.exit_code == 2
    assert "map.json" in result.stderr and len(result.stderr.strip().splitlines()) == 1
    result = _run("localize", small_drive, "--map", small_drive / "world.json", "-o",
                  tmp_path / "t.tum", "--init", "1,2")
    assert result.exit_code == 2 and "--init" in result.stderr
    assert not (tmp_path / "t.tum").exists()
