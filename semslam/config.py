"""Configuration: one root model, a section per part, defaults that are the documented behaviour.

Each part of semslam is built from its own section (``config.simulation.drive``
builds the route follower, and so on). Values come from the defaults, then an
optional JSON file (``--config``), then ``SEMSLAM_`` environment variables
(``SEMSLAM_SIMULATION__DRIVE__MAX_SPEED=2.5``). ``semslam dump-config``
prints the result; every run writes it beside its outputs.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path
from typing import Any, get_args

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_settings import BaseSettings, EnvSettingsSource, SettingsConfigDict, SettingsError

from semslam.errors import ConfigError
from semslam.io._json import parse_json
from semslam.io._text import read_text

MAX_SETTING = 1e3
"""Largest magnitude of a real-valued setting. Settings are metres, seconds, radians,
sigmas, gates and rates; beyond a thousand a file is broken, and the filters' squares and
gates would overflow or admit every candidate."""

MAX_COUNT = 1_000_000
"""Largest integer setting (counts of keyframes, frames, iterations, observations): beyond it
a file is broken, and gtsam's C++ integers overflow (2**31 crashed iSAM2's parameters)."""


MAX_GATE = 10.0
"""Largest association gate, m. Four slot widths: a wider gate makes every landmark in view a
candidate for every detection, which costs minutes (a gate of 1000 m on `small`: > 60 s
against 3.5 s) and associates nothing better."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    @field_validator("*", mode="before")
    @classmethod
    def _no_boolean_for_a_number(cls, value: Any, info: ValidationInfo) -> Any:
        """``true`` / ``false`` where a number is meant is a mistake, not 1 / 0 (pydantic's
        lax mode would take it)."""
        annotation = cls.model_fields[info.field_name].annotation
        admits = {annotation, *get_args(annotation)}
        if isinstance(value, bool) and bool not in admits and admits & {int, float}:
            raise ValueError(f"expected a number, got {str(value).lower()}")
        return value

    @field_validator("*", mode="after")
    @classmethod
    def _within_max_setting(cls, value: Any) -> Any:
        for v in value if isinstance(value, tuple) else (value,):
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{v} is not a finite number")
            if isinstance(v, float) and abs(v) > MAX_SETTING:
                raise ValueError(f"{v:g} is out of range (|value| <= {MAX_SETTING:g})")
            if isinstance(v, int) and not isinstance(v, bool) and abs(v) > MAX_COUNT:
                raise ValueError(f"{v} is out of range (|value| <= {MAX_COUNT:,})")
        return value


class OdometryNoiseConfig(_Section):
    """Wheel-speed and gyro errors of a simulated drive (per odometry sample)."""

    speed_sigma: float = Field(0.03, ge=0, description="white noise on wheel speed, m/s")
    speed_scale_sigma: float = Field(0.01, ge=0, description="per-drive scale error (1-sigma)")
    gyro_sigma: float = Field(0.003, ge=0, description="white noise on yaw rate, rad/s")
    gyro_bias_sigma: float = Field(
        1e-4, ge=0, description="per-drive constant gyro bias, rad/s (0.006 deg/s, automotive)"
    )
    gyro_bias_walk: float = Field(
        5e-6, ge=0, description="gyro bias random walk, rad/s per sqrt(s)"
    )


class ObservationNoiseConfig(_Section):
    """The noisy detector model. Defaults are the hard case later issues are judged on."""

    tag_range_limit: float = Field(25.0, gt=0, description="farthest tag reported, m")
    tag_max_incidence_deg: float = Field(70.0, gt=0, le=90)
    tag_min_pixels: float = Field(14.0, ge=0, description="smallest tag side in the image, px")
    tag_miss_rate: float = Field(0.05, ge=0, le=1)
    tag_range_sigma_rel: float = Field(0.01, ge=0, description="range noise per metre of range")
    tag_range_sigma_abs: float = Field(0.02, ge=0, description="range noise floor, m")
    tag_bearing_sigma_deg: float = Field(0.3, ge=0)
    tag_yaw_sigma_deg: float = Field(3.0, ge=0, description="PnP rotation noise")
    slot_miss_rate: float = Field(0.2, ge=0, le=1)
    slot_false_rate: float = Field(
        0.05, ge=0, le=0.9,
        description="expected fraction of slot detections that are false (at most 0.9: nine "
        "false for every true one; near 1 the simulator would draw millions)",
    )
    slot_corner_sigma: float = Field(0.05, ge=0, description="corner noise per axis, m")
    slot_exact_sigma: float = Field(0.01, gt=0, description="corner sigma declared by exact obs")
    id_error_rate: float = Field(0.2, ge=0, le=1, description="readable IDs that are wrong")
    id_missing_rate: float = Field(0.1, ge=0, le=1, description="IDs not readable at all")
    label_confidence_range: tuple[float, float] = Field(
        (0.5, 1.0), description="confidence of right AND wrong IDs is drawn from this range"
    )
    detection_confidence_range: tuple[float, float] = (0.6, 1.0)
    marking_endpoint_sigma: float = Field(0.03, ge=0, description="end-point noise per axis, m")
    marking_miss_rate: float = Field(0.1, ge=0, le=1)
    marking_false_rate: float = Field(0.1, ge=0, le=0.9, description="as slot_false_rate")
    marking_min_length: float = Field(0.4, gt=0, description="shortest visible segment, m")

    @field_validator("label_confidence_range", "detection_confidence_range", mode="after")
    @classmethod
    def _a_range_of_confidences(cls, value: tuple[float, float]) -> tuple[float, float]:
        low, high = value
        if not 0.0 <= low <= high <= 1.0:
            raise ValueError(f"({low:g}, {high:g}) must be (low, high) with 0 <= low <= high <= 1")
        return value


class DriveConfig(_Section):
    """Route following: speeds, rates and the lane the car keeps."""

    min_speed: float = Field(1.0, gt=0, description="m/s")
    max_speed: float = Field(3.0, gt=0, description="m/s")
    lateral_accel: float = Field(0.8, gt=0, description="comfort limit in turns, m/s^2")
    accel: float = Field(0.6, gt=0, description="longitudinal limit, m/s^2")
    turn_radius: float = Field(4.0, gt=0, description="corner fillet radius, m")
    lane_offset: float = Field(1.5, ge=0, description="right of the aisle centre line, m")
    odometry_rate: float = Field(
        50.0, gt=0, le=1000, description="wheel speed + gyro samples, Hz (at most 1000)"
    )
    frame_rate: float = Field(
        10.0, ge=0.1, le=100, description="camera frames and observations, Hz (0.1 to 100)"
    )
    max_duration: float | None = Field(
        None, gt=0, description="stop the drive after this many seconds (None: whole route)"
    )

    @model_validator(mode="after")
    def _speeds_in_order(self) -> DriveConfig:
        if self.min_speed > self.max_speed:
            raise ValueError(
                f"min_speed ({self.min_speed:g}) must be <= max_speed ({self.max_speed:g})"
            )
        steps = self.odometry_rate / self.frame_rate  # a frame on every steps-th sample
        if steps < 1 - 1e-9 or abs(steps - round(steps)) > 1e-9:
            raise ValueError(
                f"frame_rate ({self.frame_rate:g} Hz) must divide odometry_rate "
                f"({self.odometry_rate:g} Hz): frames fall on odometry samples"
            )
        return self


class RenderConfig(_Section):
    """Which images the simulator writes and how."""

    images: bool = True
    image_format: str = Field("jpg", pattern="^(jpg|png)$")
    jpeg_quality: int = Field(92, ge=50, le=100)
    workers: int = Field(2, ge=1, le=64, description="processes rendering images")


class SimulationConfig(_Section):
    """Everything ``semslam simulate`` uses."""

    drive: DriveConfig = DriveConfig()
    odometry_noise: OdometryNoiseConfig = OdometryNoiseConfig()
    observation_noise: ObservationNoiseConfig = ObservationNoiseConfig()
    render: RenderConfig = RenderConfig()


class MappingConfig(_Section):
    """The offline mapper: keyframes, odometry model, association and robust back-end."""

    optimizer: str = Field(
        "isam2",
        pattern="^(isam2|none)$",
        description="isam2: factor graph; none: observations placed by odometry alone",
    )
    robust: str = Field(
        "maxmix",
        pattern="^(maxmix|none)$",
        description="maxmix: max-mixture with null hypothesis; none: plain least squares",
    )
    keyframe_distance: float = Field(0.5, gt=0, description="m between keyframes")
    keyframe_angle_deg: float = Field(5.0, gt=0)
    update_every: int = Field(
        10,
        ge=1,
        description="keyframes between iSAM2 updates (5 took 25-50 % more iSAM2 time on "
        "`garage`, maps within 1 mm; BENCHMARKS.md)",
    )
    relinearize_threshold: float = Field(
        0.3,
        gt=0,
        description="iSAM2: relinearise a variable whose step exceeds this (m or rad); on "
        "`large` 0.4 and above let association go wrong after long loops (BENCHMARKS.md)",
    )
    relinearize_skip: int = Field(
        5, ge=1, description="iSAM2: updates between relinearisations (x update_every: 50 "
        "keyframes)"
    )
    reorder_growth: float = Field(
        2.0,
        ge=0,
        description="iSAM2 re-orders the whole Bayes tree (gtsam's adaptive reordering) when "
        "its fill-in has grown to this many times that after the last full ordering; 0: never "
        "(on `large` worlds 1-5, 2 cut iSAM2's time by a fifth in all, one world slower, maps "
        "the same; BENCHMARKS.md)",
    )
    rebuild_share: float = Field(
        0.15,
        ge=0,
        le=1,
        description="iSAM2 is rebuilt with every factor linearised at its estimate when a "
        "relinearisation would move more than this share of the variables (after long "
        "loops); 0: never (on `large` worlds 1-5 a third less mapping time, maps as close or "
        "closer; at 0.05 world 3 broke; BENCHMARKS.md)",
    )
    batch_max_iterations: int = Field(20, ge=1, description="final Levenberg-Marquardt")
    batch_relative_tolerance: float = Field(
        1e-5, gt=0, description="final LM stops when the error improves by less than this"
    )
    speed_sigma: float = Field(0.03, gt=0, description="odometry model: speed noise, m/s")
    speed_scale_sigma: float = Field(
        0.002, ge=0, description="odometry model: scale error left after calibration"
    )
    yaw_rate_sigma: float = Field(0.003, gt=0, description="odometry model: gyro noise, rad/s")
    calibrate_odometry: bool = Field(
        True, description="estimate wheel-speed scale and gyro bias in the graph"
    )
    scale_prior_sigma: float = Field(0.03, gt=0, description="speed scale prior around 1")
    gyro_bias_prior_sigma: float = Field(1e-3, gt=0, description="gyro bias prior, rad/s")
    calibration_window: int = Field(
        40, ge=1, description="keyframes sharing one calibration variable (keeps iSAM2 local)"
    )
    calibration_walk: tuple[float, float] = Field(
        (0.002, 2e-5), description="random walk of (scale, bias) from one window to the next"
    )
    tag_range_limit: float = Field(20.0, gt=0, description="tags farther than this are dropped, m")
    tag_conflict_distance: float = Field(
        5.0, gt=0, description="a sighting placing its tag farther than this (plus "
        "tag_conflict_per_m) from the tag's estimate is another tag under the same ID: "
        "reported, not used, m"
    )
    tag_conflict_per_m: float = Field(
        0.1, ge=0, le=1, description="drift allowed for per metre driven since the tag was "
        "last seen (a loop closed on a tag after drift is kept)"
    )
    slot_corner_sigma_min: float = Field(0.02, gt=0, description="floor on corner sigma, m")
    id_confidence_high: float = Field(
        0.5, ge=0, le=1, description="label confidence from which the ID proposes the slot"
    )
    association_gate: float = Field(
        1.0, gt=0, le=MAX_GATE, description="mean corner distance for a geometric candidate, m"
    )
    id_gate: float = Field(
        2.0, gt=0, le=MAX_GATE, description="mean corner distance for an ID candidate, m"
    )
    max_candidates: int = Field(3, ge=1)
    fuse_frames_max: int = Field(
        3, ge=1, description="detections of one slot (keyframe + frames before it) fused "
        "into one factor; 1: keyframe frames only"
    )
    fuse_radius: float = Field(
        0.3, gt=0, description="m: every corner this near the keyframe detection's to fuse"
    )
    label_vote_gate: float = Field(
        0.4, gt=0, le=MAX_GATE,
        description="m: a slot read between keyframes votes for the landmark this near",
    )
    loop_closure_radius: float = Field(
        0.0, ge=0, description="m: a confident ID's landmark beyond the ID gate and within "
        "this votes for a loop closure (0: off; 30 closes metre-sized drift, see BENCHMARKS.md)"
    )
    loop_closure_support: int = Field(
        3, ge=2, description="distinct slot IDs that must agree on one loop-closure correction"
    )
    loop_closure_window: int = Field(20, ge=1, description="keyframes a loop-closure vote lasts")
    null_weight: float = Field(0.05, gt=0, lt=1, description="prior weight of the null hypothesis")
    null_information_scale: float = Field(
        1e-4, gt=0, lt=1, description="null component's information relative to the measurement"
    )
    new_landmark_observations: int = Field(
        3, ge=1, description="M: consistent observations before a pooled slot becomes a landmark"
    )
    pool_radius: float = Field(0.5, gt=0, description="m, mean corner distance within the pool")
    max_overlap: float = Field(
        0.3, gt=0, le=1, description="a new slot overlapping a mapped one more than this is a ghost"
    )
    pool_max_age: int = Field(40, ge=1, description="keyframes a pooled slot waits to be seen")
    merge_distance: float = Field(0.6, gt=0, description="m, duplicates closer than this merge")
    min_accepted_observations: int = Field(
        2, ge=1, description="slots with fewer accepted observations are dropped from the map"
    )
    use_markings: bool = Field(True, description="map painted lines as line landmarks")
    marking_sigma: float = Field(0.05, gt=0, description="detected line end point, across, m")
    marking_min_length: float = Field(0.5, gt=0, description="shorter detections are ignored, m")
    marking_min_confidence: float = Field(0.3, ge=0, le=1)
    marking_angle_tolerance_deg: float = Field(5.0, gt=0, le=30)
    marking_distance_gate: float = Field(
        0.2, gt=0, le=MAX_GATE, description="m: both end points this near a line to belong to it"
    )
    marking_gap: float = Field(
        1.0, ge=0, le=2 * MAX_GATE, description="m: a detection may extend a line by this"
    )
    marking_min_support: int = Field(
        5, ge=1, description="detections before a line joins the graph (and the map)"
    )

    @field_validator("reorder_growth", mode="after")
    @classmethod
    def _growth_beyond_one(cls, value: float) -> float:
        if 0 < value <= 1:
            raise ValueError(f"{value:g}: 0 (never) or a growth factor above 1")
        return value

    @field_validator("calibration_walk", mode="after")
    @classmethod
    def _a_walk_is_a_sigma(cls, value: tuple[float, float]) -> tuple[float, float]:
        if min(value) < 0:
            raise ValueError(f"({value[0]:g}, {value[1]:g}) must be sigmas >= 0")
        return value


class LocalizationConfig(_Section):
    """The online filter against a map (``semslam localize``)."""

    update: str = Field(
        "ekf", pattern="^(ekf|sigma)$",
        description="frame update: ekf (analytic Jacobians) or sigma (Houben's 2n + 1 sigma "
        "points: 15 with the 7 states)",
    )
    sigma_alpha: float = Field(0.2, gt=0, lt=1, description="sigma-point weight w0 (Houben)")
    speed_sigma: float = Field(
        0.03, gt=0, description="wheel speed as a measurement of v, m/s (the mapper's model)"
    )
    yaw_rate_sigma: float = Field(
        0.003, gt=0, description="gyro as a measurement of yaw rate, rad/s (the mapper's model)"
    )
    acceleration_sigma: float = Field(2.0, gt=0, description="process noise on v, m/s^2")
    yaw_acceleration_sigma: float = Field(1.0, gt=0, description="process noise, rad/s^2")
    position_walk: float = Field(0.0, ge=0, description="unmodelled slip, m per sqrt(s)")
    yaw_walk: float = Field(0.0, ge=0, description="unmodelled heading drift, rad per sqrt(s)")
    estimate_odometry_errors: bool = Field(
        True, description="filter states for the wheel speed's scale error and the gyro's bias"
    )
    speed_scale_prior_sigma: float = Field(
        0.02, gt=0, description="wheel-speed scale error before any landmark, relative"
    )
    gyro_bias_prior_sigma: float = Field(
        1e-3, gt=0, description="gyro bias before any landmark, rad/s"
    )
    speed_scale_walk: float = Field(2e-5, ge=0, description="scale error drift, per sqrt(s)")
    gyro_bias_walk: float = Field(5e-6, ge=0, description="gyro bias drift, rad/s per sqrt(s)")
    init_position_sigma: float = Field(0.3, gt=0, description="--init x,y,yaw: 1-sigma, m")
    init_yaw_sigma_deg: float = Field(3.0, gt=0, description="--init x,y,yaw: 1-sigma, deg")
    slot_corner_sigma_min: float = Field(0.03, gt=0, description="floor on corner sigma, m")
    map_covariance_scale: float = Field(
        10.0, gt=0, description="map landmark covariance multiplier: a map error is the same "
        "at every frame that sees the landmark, so it must not average out like sensor noise",
    )
    map_floor_scale: float = Field(
        1.0, ge=0, description="the position covariance never drops below this times the "
        "associated map corners' covariance (0: off)",
    )
    map_heading_radius: float = Field(
        5.0, ge=0, description="m: the reported heading variance is at least map_floor_scale "
        "times the mean orientation variance of the map's slots this near the car, the map's "
        "own heading error there, which frames updated by painted lines alone do not hold "
        "(reported only: the filter's covariance is not changed; 0: off; BENCHMARKS.md)",
    )
    id_confidence_high: float = Field(
        0.8, ge=0, le=1, description="label confidence from which a slot is looked up by ID"
    )
    map_label_confidence_min: float = Field(
        0.5, ge=0, le=1, description="map slot labels less likely than this to be right are "
        "not used: the slot counts as unlabelled"
    )
    search_radius: float = Field(4.0, gt=0, description="local map: candidates this near, m")
    tag_range_limit: float = Field(20.0, gt=0, description="tags farther than this are dropped, m")
    slot_gate: float = Field(0.999, gt=0, lt=1, description="per-slot chi-square gate probability")
    tag_gate: float = Field(0.999, gt=0, lt=1, description="per-tag chi-square gate probability")
    marking_gate: float = Field(0.99, gt=0, lt=1, description="per-marking gate probability")
    second_nearest_ratio: float = Field(
        3.0, gt=1, description="the runner-up must be this much farther (chi-square) to accept"
    )
    frame_gate: float = Field(
        0.9999, gt=0, lt=1, description="whole-frame chi-square gate probability (Houben)"
    )
    marking_endpoint_sigma: float = Field(
        0.03, gt=0, description="marking end point when the detector declares none, m "
        "(the simulator's detector: 3 cm)"
    )
    marking_map_sigma: float = Field(
        0.05, ge=0, description="m: least uncertainty of a map marking's line; a line whose "
        "own uncertainty where it is seen (a semslam map's marginal: the map's drift there) "
        "is larger counts with that (the own sigma alone, smaller, moved NEES out of its "
        "band on two simulated seeds, BENCHMARKS.md)"
    )
    marking_min_length: float = Field(0.5, gt=0, description="shorter detections are ignored, m")
    marking_clamp_reach: float = Field(
        0.0, ge=0, description="m: a detection end this far past a map marking's end is "
        "clamped to it (Houben); farther, the map's marking is taken as incomplete. 0 (no "
        "clamping) for maps built by semslam, whose line ends are where the view clipped "
        "them, not where the paint ends; a surveyed map can use 0.3",
    )
    marking_max_angle_deg: float = Field(10.0, gt=0, description="marking association angle")
    use_slots: bool = Field(True, description="update with slot corners")
    use_tags: bool = Field(True, description="update with tags")
    use_markings: bool = Field(True, description="update with line markings")
    markings_as_fallback: bool = Field(
        True, description="use markings only in frames with few slot / tag associations"
    )
    slot_sides_as_markings: bool = Field(
        True, description="the map's slots' sides (their painted separators) join its painted "
        "lines where it holds none there (BENCHMARKS.md: a row mapped from afar has its slots "
        "but not their separators)"
    )
    fallback_below: int = Field(
        2, ge=1, description="markings are used when fewer slots + tags than this associate"
    )
    lost_position_sigma: float = Field(1.0, gt=0, description="m: beyond this the filter is lost")
    lost_rejections: int = Field(
        5, ge=1, description="frames in a row whose observations were all rejected: lost"
    )
    relocalize_label_confidence: float = Field(
        0.5, ge=0, le=1, description="slot IDs read at least this confidently may relocalize "
        "(merged over the recent frames: best confidence x the label's share of the votes)"
    )
    relocalize_min_slots: int = Field(2, ge=1, description="slots that must agree to relocalize")
    relocalize_single_slot_reads: int = Field(
        3, ge=0, description="one slot whose ID the recent frames read alike this often is "
        "enough to relocalize (0: never)"
    )
    relocalize_window: float = Field(
        2.0, ge=0, description="s of recent frames, placed by odometry, used to relocalize"
    )
    lone_tag_after: float = Field(
        1.0, ge=0, description="s without an applied slot or tag after which one tag alone, "
        "contradicting the filter twice in a row, may move the car far (a kidnap seen by one "
        "tag; 0: never, once tracking has begun)"
    )
    check_every: int = Field(
        2, ge=1, description="frames between consistency checks against global relocalization"
    )
    label_check_window: int = Field(
        20, ge=1, description="the last IDs read confidently on associated slots that the "
        "map's labels are checked against"
    )
    label_contradiction: float = Field(
        0.8, gt=0, le=1, description="share of those differing from the map's from which the "
        "filter is lost (a wrong map; 20 % misread IDs reach 0.5 at worst, BENCHMARKS.md)"
    )


class SemslamConfig(BaseSettings):
    """The root configuration."""

    model_config = SettingsConfigDict(
        env_prefix="SEMSLAM_", env_nested_delimiter="__", extra="forbid", frozen=True
    )

    simulation: SimulationConfig = SimulationConfig()
    mapping: MappingConfig = MappingConfig()
    localization: LocalizationConfig = LocalizationConfig()


def load_config(path: Path | None = None) -> SemslamConfig:
    """Defaults, overridden by the JSON file at ``path`` (if given), overridden in turn by
    SEMSLAM_ variables."""
    data: dict[str, Any] = {}
    if path is not None:
        data = parse_json(read_text(path, ConfigError), os.fspath(path), ConfigError)
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: a config file holds one JSON object")
        # only the sections: other keys would reach BaseSettings' own keyword arguments
        # (``_cli_parse_args``, ``_env_file``, ``_secrets_dir``...) and change how it loads
        unknown = sorted(key for key in data if key not in SemslamConfig.model_fields)
        if unknown:
            raise ConfigError(f"{path}: {unknown[0]}: not a setting semslam knows "
                              "(`semslam dump-config` lists them)")
    where = str(path) if path is not None else "configuration"
    return _build(_merged(data, _environment()), where)


_ENV_PREFIX = "SEMSLAM_"


def _environment() -> dict[str, Any]:
    """The settings the SEMSLAM_ variables give, nested by section; a variable naming no
    section is refused (a misspelt one would otherwise be ignored)."""
    sections = {name.upper() for name in SemslamConfig.model_fields}
    for name in os.environ:
        upper = name.upper()
        if upper.startswith(_ENV_PREFIX):
            section = upper[len(_ENV_PREFIX):].split("__")[0]
            if section not in sections:
                known = ", ".join(sorted(s.lower() for s in sections))
                raise ConfigError(f"{name}: no section {section.lower()!r} ({known})")
    try:
        return EnvSettingsSource(SemslamConfig)()
    except SettingsError as e:
        raise _not_json(e) from None


def _merged(base: dict[str, Any], top: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``top``'s settings put over it, section by section."""
    out = dict(base)
    for key, value in top.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merged(out[key], value)
        else:
            out[key] = value
    return out


def _not_json(error: SettingsError) -> ConfigError:
    """A SEMSLAM_ variable whose value is not valid JSON, named."""
    found = re.search(r'field "([^"]+)"', str(error))
    field = found.group(1) if found else ""
    variable = _environment_variable((field,)) or f"{_ENV_PREFIX}{field.upper()}"
    return ConfigError(f"{variable}: not valid JSON (a section is set as a JSON object)")


def _set_by(variable: str, value: Any, loc: tuple[Any, ...] = ()) -> bool:
    """Whether the SEMSLAM_ ``variable`` holds ``value`` (the value that failed at ``loc``),
    as text or as JSON; a variable setting a whole section as a JSON object
    (``SEMSLAM_MAPPING='{"robust": "x"}'``) holds it at the rest of ``loc``."""
    raw = os.environ.get(variable)
    if raw is None:
        return False
    if isinstance(value, str) and raw == value:
        return True
    try:
        held = json.loads(raw)
    except ValueError:
        return False
    depth = len(variable[len(_ENV_PREFIX):].split("__"))
    for part in loc[depth:]:
        if not isinstance(held, dict) or str(part) not in held:
            return held == value
        held = held[str(part)]
    return held == value


def _environment_variable(loc: tuple[Any, ...]) -> str | None:
    """The SEMSLAM_ variable that set the field at ``loc`` (or a section holding it),
    as spelt in the environment; None when no variable did."""
    names = {name.upper(): name for name in os.environ if name.upper().startswith(_ENV_PREFIX)}
    parts = [str(p).upper() for p in loc]
    for n in range(len(parts), 0, -1):  # the most specific first
        name = names.get(_ENV_PREFIX + "__".join(parts[:n]))
        if name is not None:
            return name
    inside = sorted(n for n in names if n.startswith(_ENV_PREFIX + "__".join(parts) + "__"))
    return names[inside[0]] if inside else None  # a field of the section (cross-field check)


def _build(data: dict[str, Any], where: str) -> SemslamConfig:
    """``SemslamConfig(**data)`` (plus SEMSLAM_ variables), every failure one ConfigError
    naming the file (``where``) or the environment variable and the field."""
    try:
        return SemslamConfig(**data)
    except SettingsError as e:  # a SEMSLAM_ variable whose value is not valid JSON
        raise _not_json(e) from None
    except ValidationError as e:
        err = e.errors()[0]
        field = ".".join(str(p) for p in err["loc"])
        message = str(err["msg"]).removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":  # pydantic's "Extra inputs are not permitted"
            message = "not a setting semslam knows (`semslam dump-config` lists them)"
        variable = _environment_variable(tuple(err["loc"]))
        # a variable is blamed for a field only if it holds the value that failed; for a
        # section's cross-field check (its input the section) one of the section's is named
        failed = err.get("input")
        if variable is not None and (
            isinstance(failed, dict) or _set_by(variable, failed, tuple(err["loc"]))
        ):
            where = variable
        raise ConfigError(f"{where}: {field}: {message}") from None


def config_to_json(config: SemslamConfig) -> str:
    """The configuration as pretty JSON (what ``dump-config`` prints)."""
    return json.dumps(config.model_dump(mode="json"), indent=2) + "\n"


def with_overrides(config: SemslamConfig, **sections: dict[str, Any]) -> SemslamConfig:
    """``config`` with some fields of some sections replaced (None values are ignored),
    validated like a config file; e.g. ``with_overrides(c, mapping={"robust": "none"})``."""
    data = config.model_dump()
    for section, fields in sections.items():
        data[section].update({k: v for k, v in fields.items() if v is not None})
    return _build(data, "configuration")
