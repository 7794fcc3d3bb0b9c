"""The ``semslam`` command: thin wiring from arguments to ``semslam.pipeline``.

Known errors (``SemslamError``) become one line on stderr and exit code 2;
imports are lazy so ``semslam --help`` stays fast.
"""

from __future__ import annotations

import os
import signal
import sys
import tempfile
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

from semslam import __version__
from semslam.errors import SemslamError
from semslam.io.atomic import SPECIAL_FILE_MESSAGE, is_special_file

app = typer.Typer(
    name="semslam",
    help="Semantic SLAM for parking garages: simulate drives, build maps, localize.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


class PresetName(StrEnum):
    small = "small"
    garage = "garage"
    large = "large"


def _fail(error: Exception) -> None:
    """One line on stderr for a known error (bad input, unwritable folder), exit code 2."""
    if isinstance(error, BrokenPipeError):  # the reader of stdout left: click exits 1 quietly
        raise error
    if isinstance(error, OSError) and error.filename:
        # a failed rename names the temporary file first and the target second
        message = f"{error.filename2 or error.filename}: {error.strerror or error}"
    else:
        message = str(error)
    typer.echo(f"semslam: error: {message}", err=True)
    raise typer.Exit(2)


def _output_path(text: str, option: str) -> Path:
    if not text.strip():
        raise SemslamError(f"{option}: empty path")
    if text == "-":  # where other tools write to standard output: a file named "-" surprises
        raise SemslamError(f"{option} -: semslam writes files, not standard output; name one "
                           "(./- for a file of that name)")
    return Path(text)


def _check_writable_folder(folder: Path, option: str, text: str) -> None:
    """``folder`` is, or can be created as, a folder we can write in (one line if not)."""
    existing = folder
    while not os.path.lexists(existing) and existing != existing.parent:
        existing = existing.parent
    if not os.path.lexists(existing):  # "." is gone: the working folder was removed
        existing = Path(os.path.abspath(folder))
        while not os.path.lexists(existing) and existing != existing.parent:
            existing = existing.parent
    if not existing.is_dir():
        raise SemslamError(f"{option} {text}: {existing}: is a file, not a folder")
    try:  # a probe, not os.access: it also answers for root and read-only file systems
        fd, probe = tempfile.mkstemp(prefix=".semslam-write-test-", dir=existing)
    except OSError:
        raise SemslamError(f"{option} {text}: cannot write in {existing}") from None
    os.close(fd)
    os.unlink(probe)


def _refuse_drive_files(drive: Path, outputs: list[Path], text: str) -> None:
    """One line if an output would replace a file of the input drive folder."""
    from semslam.io.drive import is_drive_file

    for path in outputs:
        if is_drive_file(drive, path):
            raise SemslamError(f"-o {text}: would replace {path}, a file of the drive {drive}")


def _refuse_inputs(outputs: list[Path], inputs: dict[str, Path | None], text: str) -> None:
    """One line if an output would replace a file the command reads: the same folder entry,
    or the file an input link points to (an output that is a link is itself replaced, so
    the file behind it is safe)."""

    def entry(path: Path) -> str:
        return os.path.join(os.path.realpath(path.parent), path.name)

    for what, path in inputs.items():
        if path is None:
            continue
        read = {entry(path), os.path.realpath(path)}
        for out in outputs:
            if entry(out) in read:
                raise SemslamError(f"-o {text}: would replace {path}, the {what} it reads")


def _output_file(text: str, option: str = "-o") -> Path:
    """Before any work: ``text`` names a file that can be written, or a one-line error."""
    path = _output_path(text, option)
    if path.is_dir():
        raise SemslamError(f"{option} {text}: is a folder, not a file")
    if text.endswith(("/", os.sep)):  # pathlib would drop the slash and write a file there
        raise SemslamError(f"{option} {text}: ends in a slash, as a folder does; name a file")
    if is_special_file(path):  # refused by the atomic write too, but only after the work
        raise SemslamError(f"{option} {text}: {SPECIAL_FILE_MESSAGE}")
    _check_writable_folder(path.parent, option, text)
    return path


def _output_folder(text: str, option: str = "-o") -> Path:
    """Before any work: ``text`` names a folder that exists or can be created and written."""
    path = _output_path(text, option)
    if os.path.lexists(path) and not path.is_dir():
        raise SemslamError(f"{option} {text}: is a file, not a folder")
    _check_writable_folder(path, option, text)
    return path


MAX_BENCH_FRAMES = 10_000
"""Most frames `semslam bench` times per stage (10 to 30 ms each: minutes already)."""


def _at_least(value: int, least: int, option: str) -> None:
    if value < least:
        raise SemslamError(f"{option}: must be at least {least}, got {value}")


def _version(value: bool) -> None:
    if value:
        typer.echo(f"semslam {__version__}")
        raise typer.Exit()


ConfigOption = Annotated[
    Path | None,
    typer.Option("--config", help="JSON file overriding defaults (see `semslam dump-config`)."),
]
ProgressOption = Annotated[
    bool | None,
    typer.Option("--progress/--no-progress",
                 help="Progress bar on stderr (default: only when stderr is a terminal)."),
]
PxPerMetreOption = Annotated[
    float | None,
    typer.Option("--px-per-m", help="Ground resolution of the top views, pixels per metre "
                 "(default: an image's longer side spans 10 m, as ps2.0's 600 px do).",
                 min=1e-6),
]


@app.callback()
def main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version.")
    ] = False,
) -> None:
    """Semantic SLAM for parking garages."""


@app.command()
def simulate(
    out_dir: Annotated[str, typer.Argument(metavar="OUT_DIR", help="Drive folder to write.")],
    preset: Annotated[PresetName, typer.Option(help="World size.")] = PresetName.garage,
    seed: Annotated[int, typer.Option(help="Fixes the world.")] = 0,
    drive: Annotated[int, typer.Option(help="Another route and noise through the same world.")] = 0,
    images: Annotated[bool, typer.Option("--images/--no-images", help="Render images.")] = True,
    tags: Annotated[
        Path | None,
        typer.Option(metavar="TAG_PLAN.json",
                     help="Add the tags a `semslam plan-tags` plan proposes to the world."),
    ] = None,
    config: ConfigOption = None,
    progress: ProgressOption = None,
) -> None:
    """Simulate a drive through a seeded garage and write it as a drive folder."""
    from semslam.config import load_config
    from semslam.io.tag_plan import read_proposed_tags
    from semslam.pipeline.simulate import simulate as run
    from semslam.reporting import print_simulation_summary

    try:
        _at_least(seed, 0, "--seed")
        _at_least(drive, 0, "--drive")
        out = _output_folder(out_dir, "OUT_DIR")
        placed = None if tags is None else read_proposed_tags(tags)
        summary = run(out, preset.value, seed, drive, images, load_config(config), progress,
                      placed)
    except (SemslamError, OSError) as e:
        _fail(e)
    print_simulation_summary(summary)


MapOptimizer = StrEnum("MapOptimizer", "isam2 none")  # functional: each value its name
MapRobust = StrEnum("MapRobust", "maxmix none")
UpdateMode = StrEnum("UpdateMode", "ekf sigma")


def _value(choice: StrEnum | None) -> str | None:
    return None if choice is None else choice.value


class ObservationSource(StrEnum):
    exact = "exact"
    noisy = "noisy"
    cached = "cached"
    images = "images"


@app.command()
def demo(
    out_dir: Annotated[
        Path, typer.Argument(metavar="[OUT_DIR]", help="Folder for the drives, map and report.")
    ] = Path("semslam-demo"),
    preset: Annotated[PresetName, typer.Option(help="World size.")] = PresetName.garage,
    seed: Annotated[int, typer.Option(help="World seed.")] = 1,
    config: ConfigOption = None,
    progress: ProgressOption = None,
) -> None:
    """The main job in one command: two simulated drives, mapped and localized, evaluated.

    Simulates two drives through one garage, perceives their images, maps the first,
    localizes the second with no initial pose, evaluates both and writes a report."""
    from semslam.config import load_config
    from semslam.pipeline.demo import run_demo
    from semslam.reporting import print_metrics

    try:
        _at_least(seed, 0, "--seed")
        _output_folder(str(out_dir), "OUT_DIR")
        results = run_demo(out_dir, load_config(config), preset.value, seed, progress,
                           log=lambda m: typer.echo(m, err=True))
    except (SemslamError, OSError) as e:
        _fail(e)
    rows: dict[str, object] = {f"map {k}": v for k, v in results["map"].items()}
    rows.update({f"localization {k}": v for k, v in results["localization"].items()})
    rows["first pose after (s)"] = results["first_pose_after_s"]
    rows["mapping / driving (s)"] = f"{results['mapping_s']:.0f} / {results['driving_s']:.0f}"
    rows["total time (s)"] = results["timings_s"]["total"]
    rows["report"] = str(out_dir / "report.md")
    print_metrics("semslam demo", rows, False)


@app.command("map")
def map_command(
    drive: Annotated[Path, typer.Argument(help="Drive folder to map.")],
    output: Annotated[
        str, typer.Option("-o", "--output", metavar="PATH", help="Map file to write (JSON).")
    ],
    observations: Annotated[
        ObservationSource, typer.Option(help="Which observations to map from.")
    ] = ObservationSource.noisy,
    optimizer: Annotated[
        MapOptimizer | None,
        typer.Option(help="isam2 (factor graph) or none (odometry only); default: the config's."),
    ] = None,
    robust: Annotated[
        MapRobust | None,
        typer.Option(help="maxmix (null hypothesis) or none (plain least squares); default: "
                     "the config's."),
    ] = None,
    config: ConfigOption = None,
    progress: ProgressOption = None,
) -> None:
    """Build the semantic map of a drive: slots with IDs and tags on a robust factor graph."""
    from semslam.config import load_config, with_overrides
    from semslam.pipeline.mapping import build_map, sibling_paths
    from semslam.reporting import print_map_summary

    try:
        out = _output_file(output)
        if out in sibling_paths(out):
            raise SemslamError(f"-o {output}: a file written beside the map would replace it; "
                               "name the map .json")
        for sibling in sibling_paths(out):
            if sibling.is_dir():
                raise SemslamError(f"-o {output}: {sibling}, written beside the map, is a folder")
        _refuse_drive_files(drive, [out, *sibling_paths(out)], output)
        written = [p for p in sibling_paths(out) if not p.name.endswith(".config.json")]
        # MAP.config.json is the config in force, written back: a re-run with the config
        # the last run left there (`--config MAP.config.json`) replaces it by the same
        _refuse_inputs([out, *written], {"--config file": config}, output)
        cfg = with_overrides(
            load_config(config), mapping={"optimizer": _value(optimizer), "robust": _value(robust)}
        )
        summary = build_map(drive, out, observations.value, cfg, progress)
    except (SemslamError, OSError) as e:
        _fail(e)
    print_map_summary(summary)


@app.command()
def localize(
    drive: Annotated[Path, typer.Argument(help="Drive folder to localize.")],
    map_path: Annotated[Path, typer.Option("--map", help="Map from `semslam map` (JSON).")],
    output: Annotated[
        str, typer.Option("-o", "--output", metavar="PATH",
                          help="Trajectory to write (TUM; a .csv beside it).")
    ],
    init: Annotated[
        str | None,
        typer.Option(help="Start pose x,y,yaw (m, m, rad), or auto; default: the drive's."),
    ] = None,
    observations: Annotated[
        ObservationSource, typer.Option(help="Which observations to localize with.")
    ] = ObservationSource.noisy,
    update: Annotated[
        UpdateMode | None,
        typer.Option(help="ekf (analytic Jacobians) or sigma (Houben's sigma points); default: "
                     "the config's."),
    ] = None,
    config: ConfigOption = None,
    progress: ProgressOption = None,
) -> None:
    """Track a drive against a map, frame by frame: pose, covariance and status."""
    from semslam.config import load_config, with_overrides
    from semslam.pipeline.localize import localize_drive, output_paths, parse_init
    from semslam.reporting import print_localize_summary

    try:
        out = _output_file(output)
        track, settings = output_paths(out)
        if track == out:
            raise SemslamError(f"-o {output}: the per-frame track CSV goes to {track} too; "
                               "name the trajectory .tum")
        for path, what in ((track, "the per-frame track"), (settings, "the configuration")):
            if path.is_dir():
                raise SemslamError(f"-o {output}: {path} ({what}) is a folder")
        _refuse_drive_files(drive, [out, track, settings], output)
        _refuse_inputs([out, track, settings], {"map": map_path, "--config file": config},
                       output)
        parse_init(init)
        cfg = with_overrides(load_config(config), localization={"update": _value(update)})
        summary = localize_drive(drive, map_path, out, observations.value, init, cfg, progress)
    except (SemslamError, OSError) as e:
        _fail(e)
    print_localize_summary(summary)


@app.command()
def tags(
    images: Annotated[
        list[Path], typer.Argument(metavar="IMAGE...", help="Image files, or folders of them.")
    ],
    intrinsics: Annotated[
        str, typer.Option(metavar="FX,FY,CX,CY", help="Pinhole intrinsics, px (OpenCV).")
    ],
    tag_size: Annotated[
        float, typer.Option(help="Edge of the tag's black square, metres.")
    ],
    distortion: Annotated[
        str | None,
        typer.Option(metavar="K1,K2,...", help="OpenCV distortion (4/5/8 coefficients; "
                     "4 with --fisheye). Default: none (a rectified image)."),
    ] = None,
    fisheye: Annotated[
        bool, typer.Option(help="--distortion is OpenCV's fisheye (equidistant) model.")
    ] = False,
    family: Annotated[str, typer.Option(help="Tag family.")] = "tag36h11",
    variant: Annotated[
        str, typer.Option(help="pnp (PnP translation) or tiev (centre-pixel bearing).")
    ] = "pnp",
    decimate: Annotated[
        float, typer.Option(help="Search quads on an image this many times smaller "
                            "(1: full resolution; 2: about 3 x faster, loses tags < 20 px).")
    ] = 1.0,
    json_output: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
) -> None:
    """AprilTag poses in images: corners, pose in the camera frame, covariance.

    Also the pose's ambiguity (--json: {"images": [{"image", "detections": [...]}]})."""
    from semslam.pipeline.tags import parse_numbers, tags_in_images
    from semslam.reporting import print_metrics

    try:
        k = parse_numbers(intrinsics, "--intrinsics", (4,))
        d = None if distortion is None else parse_numbers(distortion, "--distortion",
                                                          (4, 5, 8, 12, 14))
        result = tags_in_images(images, k, tag_size, d, fisheye, family, variant, decimate)
    except (SemslamError, OSError) as e:
        _fail(e)
    if json_output:
        print_metrics("semslam tags", result, True)
        return
    rows: dict[str, object] = {}
    for entry in result["images"]:
        if not entry["detections"]:
            rows[entry["image"]] = "no tags"
        for n, det in enumerate(entry["detections"]):
            x, y, z = det["position"]
            rows[f"{entry['image']} [{n}] {det['family']} {det['id']}"] = (
                f"x {x:.3f} y {y:.3f} z {z:.3f} m, ambiguity {det['ambiguity']:.2f}")
    print_metrics("semslam tags", rows, False)


@app.command()
def detect(
    images: Annotated[
        list[Path], typer.Argument(metavar="IMAGE...", help="Top-view images, or folders of them.")
    ],
    overlay: Annotated[
        str | None,
        typer.Option(metavar="DIR", help="Write each image with its detections drawn."),
    ] = None,
    lines: Annotated[bool, typer.Option(help="Also find painted lines (Houben).")] = True,
    px_per_m: PxPerMetreOption = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
) -> None:
    """Marking points, slots with their painted IDs, and painted lines in top views.

    Top views as ps2.0's: the car in the middle, 10 m across (600 x 600 px; another size is
    resampled, see --px-per-m). --json: {"images": [{"image", "points", "slots",
    "markings"}]}, pixels in each image's own."""
    from semslam.pipeline.detect import detect_files
    from semslam.reporting import print_metrics

    try:
        overlay_dir = None if overlay is None else _output_folder(overlay, "--overlay")
        result = detect_files(images, overlay_dir, lines=lines, px_per_m=px_per_m)
    except (SemslamError, OSError) as e:
        _fail(e)
    if json_output:
        print_metrics("semslam detect", result, True)
        return
    rows: dict[str, object] = {}
    for entry in result["images"]:
        labels = ", ".join(s["label"] or "?" for s in entry["slots"]) or "-"
        from_row = sum(p["from_row"] for p in entry["points"])
        placed = f" ({from_row} from their row)" if from_row else ""
        rows[entry["image"]] = (
            f"{len(entry['points'])} points{placed}, {len(entry['slots'])} slots ({labels}), "
            f"{len(entry['markings'])} lines"
        )
    print_metrics("semslam detect", rows, False)


class RobustMode(StrEnum):
    maxmix = "maxmix"
    dcs = "dcs"
    none = "none"


@app.command()
def optimize(
    graph: Annotated[Path, typer.Argument(metavar="GRAPH.g2o", help="2D g2o pose graph.")],
    output: Annotated[
        str, typer.Option("-o", "--output", metavar="PATH", help="Optimised graph to write.")
    ],
    robust: Annotated[
        RobustMode,
        typer.Option(
            help="maxmix: EDGE_SE2_MIXTURE as max-mixtures; dcs: each mixture's measurement "
            "with dynamic covariance scaling (outlier closures only); none: LS."
        ),
    ] = RobustMode.maxmix,
    json_output: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Solve a g2o pose graph (EDGE_SE2_MIXTURE edges read as max-mixtures with null)."""
    from semslam.pipeline.optimize import optimize_g2o_file
    from semslam.reporting import print_metrics

    try:
        out = _output_file(output)
        _refuse_inputs([out], {"graph": graph}, output)
        summary = optimize_g2o_file(graph, out, robust.value)
    except (SemslamError, OSError) as e:
        _fail(e)
    if not json_output:
        summary.pop("chosen", None)  # one index per mixture: for scripts, not for a table
    print_metrics("semslam optimize", summary, json_output)


evaluate_app = typer.Typer(
    help="Score outputs against ground truth (JSON for scripts).", no_args_is_help=True
)
app.add_typer(evaluate_app, name="evaluate")


@evaluate_app.command("map")
def evaluate_map(
    map_path: Annotated[Path, typer.Argument(metavar="MAP.json", help="The map to score.")],
    truth: Annotated[Path, typer.Option(help="The true map (a simulated drive's world.json).")],
    align: Annotated[bool, typer.Option(help="Fit the best SE(2) transform first.")] = False,
    json_output: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
) -> None:
    """Corner errors, matched / duplicate / false slots, wrong merges, ID accuracy, tags."""
    from semslam.pipeline.evaluate import evaluate_map_files
    from semslam.reporting import print_metrics

    try:
        metrics = evaluate_map_files(map_path, truth, align=align)
    except (SemslamError, OSError) as e:
        _fail(e)
    print_metrics("map evaluation", metrics, json_output)


_TRAJECTORY_TABLE = (
    "frames",
    "frames_evaluated",
    "frames_lost",
    "frames_unmatched",
    "alignment",
    "ate_rmse_m",
    "ate_median_m",
    "ate_p95_m",
    "ate_max_m",
    "yaw_rmse_deg",
    "rpe_trans_rmse_m",
    "rpe_yaw_rmse_deg",
    "split_reference",
    "parallel_mean_m",
    "orthogonal_mean_m",
    "nees_mean",
    "nees_position_mean",
    "nees_heading_mean",
    "nees_within_95",
)


@evaluate_app.command("trajectory")
def evaluate_trajectory(
    trajectory: Annotated[
        Path, typer.Argument(metavar="TRAJ.tum", help="The trajectory to score (TUM).")
    ],
    truth: Annotated[Path, typer.Option(help="The true trajectory (TUM, e.g. groundtruth.tum).")],
    map_path: Annotated[
        Path | None,
        typer.Option("--map", metavar="MAP.json", help="Split errors along its painted lines."),
    ] = None,
    align: Annotated[bool, typer.Option(help="Fit the best SE(2) transform first.")] = False,
    json_output: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
) -> None:
    """ATE, yaw and 1 s relative errors, parallel / orthogonal split, NEES (with TRAJ.csv)."""
    from semslam.pipeline.evaluate import evaluate_trajectory_files
    from semslam.reporting import print_metrics

    try:
        metrics = evaluate_trajectory_files(trajectory, truth, map_path, align=align)
    except (SemslamError, OSError) as e:
        _fail(e)
    if not json_output:  # the main figures; --json has them all
        metrics = {k: metrics[k] for k in _TRAJECTORY_TABLE if metrics.get(k) is not None}
        if "alignment" in metrics:
            x, y, yaw = metrics["alignment"]
            metrics["alignment"] = f"{x:.3f} m, {y:.3f} m, {yaw:.3f} deg"
    print_metrics("trajectory evaluation", metrics, json_output)


@evaluate_app.command("detections")
def evaluate_detections(
    images_dir: Annotated[Path, typer.Argument(metavar="IMAGES_DIR", help="Top views.")],
    labels_dir: Annotated[
        Path, typer.Argument(metavar="LABELS_DIR", help="DMPR-PS labels, <image stem>.json.")
    ],
    label_directions: Annotated[
        bool,
        typer.Option("--label-directions", help="Score the directions exactly as the labels "
                     "give them (ps2.0 points a slot's second L junction along the entrance; "
                     "by default it is turned to its separator, as semslam reports it)."),
    ] = False,
    px_per_m: PxPerMetreOption = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
) -> None:
    """Marking-point and slot precision / recall with the ps2.0 metric (10 px, 30 deg).

    The 10 px are ps2.0's (60 px per metre) whatever the images' size."""
    from semslam.pipeline.detect import evaluate_detection_folder
    from semslam.reporting import print_metrics

    try:
        metrics = evaluate_detection_folder(images_dir, labels_dir,
                                            separator_convention=not label_directions,
                                            px_per_m=px_per_m)
    except (SemslamError, OSError) as e:
        _fail(e)
    if not json_output:  # the table counts the views with point errors; --json lists them
        metrics.pop("per_image")
    print_metrics("detection evaluation", metrics, json_output)


@evaluate_app.command("markings")
def evaluate_markings(
    map_path: Annotated[Path, typer.Argument(metavar="MAP.json", help="The map to score.")],
    vector_map: Annotated[
        Path,
        typer.Option(metavar="DIR", help="Reference: a vector_map/ folder (point.csv, line.csv), "
                     "or a map JSON whose markings are the reference."),
    ],
    trajectory: Annotated[
        Path | None,
        typer.Option(metavar="TRAJ.tum", help="Where the drive went (default: the "
                     "MAP.trajectory.tum that `semslam map` writes)."),
    ] = None,
    radius: Annotated[float, typer.Option(help="Area compared: metres from the drive.")] = 5.0,
    tolerance: Annotated[float, typer.Option(help="Matched within this, metres.")] = 0.3,
    json_output: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
) -> None:
    """Painted lines against a vector map, both ways: end-point distances (median, p95).

    From the vector map to the map (is everything there?) and back (is what was mapped
    real?)."""
    from semslam.pipeline.evaluate import evaluate_markings_files
    from semslam.reporting import print_metrics

    try:
        metrics = evaluate_markings_files(map_path, vector_map, trajectory, radius, tolerance)
    except (SemslamError, OSError) as e:
        _fail(e)
    print_metrics("markings evaluation", metrics, json_output)


class Grade(StrEnum):
    automotive = "automotive"
    precise = "precise"
    localizer = "localizer"


class HofmannGrade(StrEnum):
    automotive = "automotive"
    precise = "precise"


class PlanObjective(StrEnum):
    accuracy = "accuracy"
    relocalization = "relocalization"


@app.command()
def accuracy(
    map_path: Annotated[Path, typer.Argument(metavar="MAP.json", help="The map.")],
    output: Annotated[str, typer.Option("-o", "--output", metavar="DIR",
                                        help="Folder for accuracy.json and accuracy_map.png "
                                        "(and config.json with --grade localizer).")],
    route: Annotated[
        Path | None, typer.Option(metavar="TRAJ.tum", help="A route to predict along.")
    ] = None,
    grade: Annotated[
        Grade, typer.Option(help="Odometry / IMU grade (Hofmann's ideal filter), or localizer: "
                            "semslam's localizer as configured, on the simulator's detectors.")
    ] = Grade.automotive,
    grid_step: Annotated[float, typer.Option(help="Grid spacing, m.")] = 1.0,
    threshold: Annotated[float, typer.Option(help="Accuracy target, m (worst stretches).")] = 0.2,
    json_output: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
    config: Annotated[
        Path | None,
        typer.Option("--config", help="JSON file overriding defaults (see `semslam "
                     "dump-config`): the localizer predicted by --grade localizer."),
    ] = None,
) -> None:
    """Predicted accuracy from the map alone (Hofmann), on a grid and along a route.

    Single-frame (A^T P A)^-1 on a grid and, along a route, filtered with an odometry
    grade or as semslam's localizer would; the worst stretches."""
    from semslam.config import load_config
    from semslam.pipeline.accuracy import predicted_accuracy
    from semslam.reporting import print_metrics

    try:
        if config is not None and grade != Grade.localizer:
            raise SemslamError(f"--config {config}: only --grade localizer reads a "
                               "configuration")
        out = _output_folder(output)
        written = [out / name for name in ("accuracy.json", "accuracy_map.png")]
        _refuse_inputs([*written, out / "config.json"], {"map": map_path, "route": route},
                       output)
        # DIR/config.json is the config in force, written back: a re-run with it replaces
        # it by the same
        _refuse_inputs(written, {"--config file": config}, output)
        cfg = load_config(config) if grade == Grade.localizer else None
        result = predicted_accuracy(map_path, out, route, grade.value, grid_step, threshold,
                                    cfg)
    except (SemslamError, OSError) as e:
        _fail(e)
    if json_output:
        print_metrics("semslam accuracy", result, True)
        return
    rows: dict[str, object] = {f"grid {k}": v for k, v in result["grid"].items()}
    if "route" in result:
        rows.update({f"route {k}": v for k, v in result["route"].items()
                     if k not in ("per_pose", "worst_stretches", "file")})
        for n, s in enumerate(result["route"]["worst_stretches"]):
            rows[f"worst stretch {n + 1}"] = (
                f"{s['start_m']:.0f}-{s['end_m']:.0f} m, up to {s['worst_sigma_m']:.2f} m")
    rows["written"] = ", ".join(result["files"])
    print_metrics("semslam accuracy", rows, False)


def _m(value: float | None) -> str:
    """A sigma from a JSON result (None where unobservable), in metres."""
    return "unobservable" if value is None else f"{value:.3f} m"


@app.command("plan-tags")
def plan_tags_command(
    map_path: Annotated[Path, typer.Argument(metavar="MAP.json", help="The map.")],
    route: Annotated[Path, typer.Option(metavar="TRAJ.tum", help="The route cars drive.")],
    output: Annotated[str, typer.Option("-o", "--output", metavar="DIR",
                                        help="Folder for tag_plan.json and tag_plan.png.")],
    count: Annotated[int, typer.Option(help="How many tags to propose.")] = 5,
    grade: Annotated[
        HofmannGrade, typer.Option(help="Odometry / IMU grade (Hofmann).")
    ] = HofmannGrade.automotive,
    keep_existing: Annotated[
        bool, typer.Option(help="Keep the map's own tags (--no-keep-existing: plan from none).")
    ] = True,
    random_trials: Annotated[
        int, typer.Option(help="Random placements drawn per number of tags (seed 0).")
    ] = 20,
    objective: Annotated[
        PlanObjective,
        typer.Option(help="accuracy: lower the worst predicted sigma; relocalization: a slot "
                     "or tag in view within --within seconds from anywhere on the route."),
    ] = PlanObjective.accuracy,
    within: Annotated[
        float, typer.Option(metavar="SECONDS", help="Relocalization: time allowed to see one.")
    ] = 2.0,
    mapping_route: Annotated[
        Path | None,
        typer.Option(metavar="TRAJ.tum", help="The route of the drive that will map the tags: "
                     "only tags it sees are proposed."),
    ] = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
) -> None:
    """Where to put COUNT tags, and how accuracy changes with their number.

    Greedy on the predicted worst sigma along the route (or on relocalization coverage),
    against evenly spread and randomly placed tags."""
    from semslam.pipeline.plan_tags import plan_tags
    from semslam.reporting import print_metrics

    try:
        out = _output_folder(output)
        result = plan_tags(map_path, route, out, count, grade.value, keep_existing,
                           random_trials=random_trials, objective=objective.value, within=within,
                           mapping_route=mapping_route)
    except (SemslamError, OSError) as e:
        _fail(e)
    if json_output:
        print_metrics("semslam plan-tags", result, True)
        return
    rows: dict[str, object] = {}
    random = [None, *result["random"]["steps"]]
    evenly = [None, *result["evenly_spread"]]
    for n, step in enumerate(result["greedy"]):
        even = evenly[n] if n < len(evenly) else None
        rand = random[n] if n < len(random) else None
        where = "" if step["tag"] is None else " at ({:.1f}, {:.1f})".format(*step["tag"][:2])
        spread = "" if even is None else f"; evenly spread {_m(even['worst_m'])}"
        if rand is not None:
            spread += f"; random median {_m(rand['worst_m']['median'])}"
        rows[f"{step['count']} tags{where}"] = (
            f"worst {_m(step['worst_m'])}{spread}; a slot or tag within {within:g} s from "
            f"{step['relocalization_coverage']:.1%} of the route"
        )
    if result["mapping_route"] is not None:
        rows["candidates"] = (f"{result['candidates']} the mapping route sees, "
                              f"{result['candidates_unmapped']} set aside")
    rows["written"] = ", ".join(result["files"])
    print_metrics("semslam plan-tags", rows, False)


@app.command()
def bench(
    frames: Annotated[int, typer.Option(help="Frames timed per perception stage.")] = 40,
    large: Annotated[bool, typer.Option(help="Also map the `large` drive (about 7 min).")] = False,
    config: ConfigOption = None,
    json_output: Annotated[bool, typer.Option("--json", help="Print JSON only.")] = False,
) -> None:
    """Every speed target in one run: stage timings and mapping time against driving time.

    The stages run on a simulated drive; mapping time is set against its driving time."""
    from semslam.config import load_config
    from semslam.pipeline.bench import run_bench
    from semslam.reporting import print_metrics

    try:
        _at_least(frames, 1, "--frames")
        if frames > MAX_BENCH_FRAMES:
            raise SemslamError(f"--frames: at most {MAX_BENCH_FRAMES:,} (a few minutes of "
                               f"timing), got {frames}")
        result = run_bench(load_config(config), frames, large,
                           log=lambda m: typer.echo(m, err=True))
    except (SemslamError, OSError) as e:
        _fail(e)
    print_metrics("semslam bench", result, json_output)


import_app = typer.Typer(help="Turn recordings of other tools into semslam drive folders.",
                         no_args_is_help=True)
app.add_typer(import_app, name="import")


@import_app.command("garage-bev")
def import_garage_bev_command(
    src: Annotated[Path, typer.Argument(metavar="SRC", help="The garage-bev-drive folder.")],
    out_dir: Annotated[Path, typer.Argument(metavar="OUT", help="Drive folder to write.")],
    crop_rows: Annotated[
        int, typer.Option(help="Mask rows ignored at the top and bottom (less reliable).")
    ] = 300,
    every: Annotated[int, typer.Option(help="Use every n-th mask (quick looks).")] = 1,
    progress: ProgressOption = None,
) -> None:
    """A real drive of bird's-eye masks + odometry (3D-SMLoc's garage) as a drive folder.

    Odometry, line observations from the slot-line masks (cached), the hand-made vector
    map, and the mapping settings for it (map with `--observations cached --config
    OUT/config.json`)."""
    from dataclasses import asdict

    from semslam.pipeline.import_bev import import_garage_bev
    from semslam.reporting import print_metrics

    try:
        _output_folder(str(out_dir), "OUT")
        summary = import_garage_bev(src, out_dir, crop_rows=crop_rows, every=every,
                                    show_progress=progress)
    except (SemslamError, OSError) as e:
        _fail(e)
    print_metrics("semslam import garage-bev",
                  {k: str(v) if isinstance(v, Path) else v for k, v in asdict(summary).items()},
                  False)


@app.command("dump-config")
def dump_config(config: ConfigOption = None) -> None:
    """Print the configuration in force (defaults, then --config, then SEMSLAM_ variables)."""
    from semslam.config import config_to_json, load_config

    try:
        typer.echo(config_to_json(load_config(config)), nl=False)
    except (SemslamError, OSError) as e:
        _fail(e)


def _exit_on_sigterm(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)


def _command_path(args: list[str]) -> str:
    """``semslam`` and the (sub)commands that ``args`` start with (``semslam map``), for a
    usage error click raised before it knew its command (an option missing its value)."""
    command = typer.main.get_command(app)
    path = ["semslam"]
    for arg in args:
        sub = getattr(command, "commands", {}).get(arg)
        if sub is None:
            break
        path.append(arg)
        command = sub
    return " ".join(path)


def run() -> None:
    """The console entry (`semslam`, `python -m semslam`): the commands, with a usage error
    (unknown command or option, missing argument, a value of the wrong type) as one line on
    stderr, exit code 2, instead of click's framed box. SIGTERM exits as SystemExit(143),
    so a half-written output folder is removed as it is on Ctrl-C."""
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    for stream in (sys.stdout, sys.stderr):  # a path or label the terminal cannot show
        if hasattr(stream, "reconfigure"):  # (PYTHONIOENCODING=ascii) is replaced, not fatal
            stream.reconfigure(errors="replace")
    try:
        code = app(prog_name="semslam", standalone_mode=False)
    except KeyboardInterrupt:
        code = 130
    except Exception as e:  # click's usage errors (typer may vendor click): by their interface
        if type(e).__name__ == "Abort":
            typer.echo("semslam: aborted", err=True)
            code = 130
        elif hasattr(e, "format_message") and getattr(e, "exit_code", None) == 2:
            ctx = getattr(e, "ctx", None)
            command = ctx.command_path if ctx is not None else _command_path(sys.argv[1:])
            message = e.format_message().replace("Value error, ", "")  # typer's enum wording
            if message:  # empty: no arguments at all, the help is printed already
                typer.echo(f"{command}: error: {message} (see {command} --help)", err=True)
            code = 2
        else:
            raise
    sys.exit(code if isinstance(code, int) else 0)


if __name__ == "__main__":  # pragma: no cover
    run()
