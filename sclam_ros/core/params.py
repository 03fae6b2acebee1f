"""The one typed home of every user-facing parameter.

The node, the CLI and the YAML files in launch_configs/config/ all read this dataclass, so a
name, a default, a unit or a validity rule is written down exactly once.

A parameters file is a standard ROS 2 one::

    sclam:                      # the node name (``/**`` also matches)
      ros__parameters:
        wheel_radius_left: 0.125
        ...
"""
from __future__ import annotations

import contextlib
import dataclasses
import difflib
import glob
import math
import os
import tempfile
from dataclasses import dataclass, field, fields
from pathlib import Path

import yaml

NODE_NAME = "sclam"

# The calibration parameter names, in the order of the state vector (k then l).
CALIBRATION_KEYS = (
    "wheel_radius_left",
    "wheel_radius_right",
    "wheel_base",
    "laser_x",
    "laser_y",
    "laser_yaw",
)
ODOMETRY_KEYS = CALIBRATION_KEYS[:3]
LASER_KEYS = CALIBRATION_KEYS[3:]


# Bounds of a plausible wheeled ground robot (m): generous, they only catch garbage.
MAX_WHEEL_RADIUS = 5.0
MAX_ROBOT_SIZE = 20.0


class ParamsError(ValueError):
    """A parameter file or value that cannot be used; the message says which and why."""


def _positive(name, value):
    if not (math.isfinite(value) and value > 0):
        return f"{name} must be a finite number > 0, got {value!r}"
    return None


def _within(bound, positive=False):
    """A check for a length or angle of a wheeled ground robot: |value| <= bound (and > 0
    when ``positive``). Beyond it a value is a typo or garbage, not a robot, and a finite but
    absurd one (a radius of 1e300 m) overflows the solver instead of failing clearly."""

    def check(name, value):
        if positive and not (math.isfinite(value) and 0 < value <= bound):
            return f"{name} must be a number in (0, {bound:g}], got {value!r}"
        if not (math.isfinite(value) and abs(value) <= bound):
            return f"{name} must be a number in [-{bound:g}, {bound:g}], got {value!r}"
        return None

    return check


def _non_negative(name, value):
    if not (math.isfinite(value) and value >= 0):
        return f"{name} must be a finite number >= 0, got {value!r}"
    return None


def _sign(name, value):
    if value not in (1.0, -1.0):
        return f"{name} must be 1 or -1, got {value!r}"
    return None


def _non_empty(name, value):
    if not value:
        return f"{name} must not be empty"
    return None


def _joint_names(name, value):
    if not all(isinstance(v, str) and v for v in value):
        return f"{name} must be a list of non-empty joint names, got {list(value)!r}"
    if len(set(value)) != len(value):
        return f"{name} names a joint twice: {list(value)!r}"
    return None


def _param(default, doc, check=None, unit=""):
    return field(default=default, metadata={"doc": doc, "check": check, "unit": unit})


@dataclass
class SclamParams:
    """Parameters of ``sclam calibrate`` and ``sclam_node`` (SI units, radians)."""

    # --- inputs -------------------------------------------------------------------
    joint_states_topic: str = _param("/joint_states", "sensor_msgs/JointState topic", _non_empty)
    scan_topic: str = _param("/scan", "sensor_msgs/LaserScan topic", _non_empty)
    odometry_topic: str = _param(
        "",
        "nav_msgs/Odometry topic of the base's wheel odometry, read instead of "
        "joint_states_topic when set: its increments are turned back into wheel rotations "
        "with the nominal wheel_radius_left, wheel_radius_right and wheel_base, which must be "
        "those the odometry was computed with. Empty: read joint_states_topic",
    )
    left_wheel_joint: str = _param("left_wheel_joint", "JointState name of the left wheel", _non_empty)
    right_wheel_joint: str = _param("right_wheel_joint", "JointState name of the right wheel", _non_empty)
    # A skid-steer's wheels, e.g. [front_left_wheel_joint, rear_left_wheel_joint]: a side's
    # positions are averaged into one (io/messages.joint_state_to_raw), its wheel base is the
    # effective one (docs/robot_inputs.md#skid-steer). Tuples: a dataclass default must be
    # immutable, and rclpy declares them as arrays.
    left_wheel_joints: tuple = _param(
        (), "JointState names of the left side's wheels (skid-steer: two or more, averaged); "
        "empty: left_wheel_joint", _joint_names)
    right_wheel_joints: tuple = _param(
        (), "JointState names of the right side's wheels (skid-steer: two or more, averaged); "
        "empty: right_wheel_joint", _joint_names)
    ticks_per_revolution: float = _param(
        0.0,
        "encoder ticks per wheel revolution; JointState positions are cumulative ticks. "
        "0 means positions are wheel angles in radians",
        _non_negative,
    )
    encoder_wrap: float = _param(
        0.0,
        "counter modulus of the encoder (e.g. 65536 for a 16-bit counter); 0 = no wrap-around "
        "expected. Jumps larger than half of it are unwrapped",
        _non_negative,
        "ticks",
    )
    # A recording cannot be re-recorded with the driver fixed: these correct it instead
    # (sclam calibrate names the one to set when the laser sees the wheel turn the other way).
    left_encoder_sign: float = _param(
        1.0, "1, or -1 if the left wheel's position falls when the wheel rolls forward", _sign)
    right_encoder_sign: float = _param(
        1.0, "1, or -1 if the right wheel's position falls when the wheel rolls forward", _sign)
    # --- nominal calibration (starting values) -------------------------------------
    wheel_radius_left: float = _param(0.1, "left wheel radius", _within(MAX_WHEEL_RADIUS, True), "m")
    wheel_radius_right: float = _param(0.1, "right wheel radius", _within(MAX_WHEEL_RADIUS, True), "m")
    wheel_base: float = _param(
        0.5, "distance between the wheel contact points", _within(MAX_ROBOT_SIZE, True), "m")
    wheel_separation: float = _param(
        0.0,
        "geometric distance between the left and right wheels (a skid-steer's track), for "
        "diff_drive_controller's wheel_separation; wheel_base is then the effective one, wider "
        "by the sideways slip in turns (exported as wheel_separation_multiplier). 0: wheel_base",
        _non_negative, "m")
    laser_x: float = _param(0.0, "laser x on base_link", _within(MAX_ROBOT_SIZE), "m")
    laser_y: float = _param(0.0, "laser y on base_link", _within(MAX_ROBOT_SIZE), "m")
    laser_yaw: float = _param(0.0, "laser yaw on base_link", _within(2 * math.pi), "rad")
    # --- noise model ----------------------------------------------------------------
    wheel_noise: float = _param(
        0.02,
        "1σ of a wheel's angle increment per sqrt(radian turned), the slip/backlash model "
        "of the odometry edges; rescaled from the residuals after the fit",
        _positive,
        "rad/sqrt(rad)",
    )
    lateral_noise: float = _param(
        0.002,
        "1σ of sideways tyre slip per sqrt(metre travelled), which the wheel model cannot "
        "express; keeps odometry edges full rank",
        _positive,
        "m/sqrt(m)",
    )
    keyframe_interval: float = _param(
        0.5,
        "graph edges span this long: consecutive scans are merged (wheel increments add, scan "
        "matches compose). Long edges keep the regression-dilution bias of the wheel base "
        "small (see graph.merge_keyframes); 0 = one keyframe per scan",
        _non_negative,
        "s",
    )
    # --- scan matching --------------------------------------------------------------
    scan_voxel_size: float = _param(
        0.05, "KISS-ICP voxel size for planar indoor scans", _within(MAX_ROBOT_SIZE, True), "m"
    )
    scan_max_beams: float = _param(
        720,
        "scans with more beams are thinned to every k-th beam (the smallest k leaving at "
        "most this many) before scan matching: registration time grows with the beams, the "
        "precision of a 0.5 s edge hardly does; 0 = match all beams",
        _non_negative,
        "beams",
    )
    # --- online estimation (sclam_node, sclam calibrate --track) --------------------
    window_distance: float = _param(
        100.0,
        "distance travelled (mean of both wheels) that the sliding window of the wheel "
        "radii spans; cut short when a change of the radii is detected",
        _positive,
        "m",
    )
    base_frame: str = _param("base_link", "robot base frame (REP-105)", _non_empty)
    odom_frame: str = _param("odom", "odometry frame (REP-105)", _non_empty)

    # The names a parameters file set (from_dict fills it); empty for params built in code.
    # Not a field (no annotation): it is not a parameter, is not written to YAML and does not
    # make two equal parameter sets differ. Lets a default be told from a value the user chose,
    # e.g. to take the nominal laser pose from the recording's /tf_static only when unset.
    explicit_keys = frozenset()

    def validate(self) -> "SclamParams":
        """Raise ParamsError listing every invalid value."""
        problems = []
        for f in fields(self):
            check = f.metadata.get("check")
            value = getattr(self, f.name)
            if check is not None:
                problem = check(f.name, value)
                if problem:
                    problems.append(problem)
        left, right = self.wheel_joints()
        if set(left) & set(right):
            problems.append(f"a joint is named on both sides: {sorted(set(left) & set(right))}"
                            " (left_wheel_joint(s), right_wheel_joint(s))")
        if bool(self.left_wheel_joints) != bool(self.right_wheel_joints):
            problems.append("set left_wheel_joints and right_wheel_joints together (or neither: "
                            "left_wheel_joint, right_wheel_joint)")
        elif len(left) != len(right):
            problems.append(f"left_wheel_joints has {len(left)} joints, right_wheel_joints "
                            f"{len(right)}: name as many wheels on each side")
        if self.odometry_topic and (self.ticks_per_revolution or self.encoder_wrap):
            # One meaning for each value: the implied wheel angles are radians that never wrap.
            problems.append("with odometry_topic set, ticks_per_revolution and encoder_wrap "
                            "must be 0 (they describe a JointState's encoders)")
        if problems:
            raise ParamsError("invalid parameters:\n  " + "\n  ".join(problems))
        return self

    def wheel_joints(self) -> tuple:
        """((left joint names), (right joint names)): the skid-steer lists when set, else the
        two-wheel joints."""
        return (tuple(self.left_wheel_joints) or (self.left_wheel_joint,),
                tuple(self.right_wheel_joints) or (self.right_wheel_joint,))

    @property
    def wheels_per_side(self) -> int:
        return len(self.wheel_joints()[0])

    # --- calibration vector helpers --------------------------------------------------
    def calibration(self) -> dict:
        return {k: float(getattr(self, k)) for k in CALIBRATION_KEYS}

    def calibration_vector(self) -> tuple:
        """The six calibration values in CALIBRATION_KEYS order (the state vector's; callers
        that compute np.asarray it: this module stays free of numpy)."""
        return tuple(float(getattr(self, k)) for k in CALIBRATION_KEYS)

    def with_calibration(self, values: dict) -> "SclamParams":
        return dataclasses.replace(self, **{k: float(values[k]) for k in CALIBRATION_KEYS})

    # --- YAML -----------------------------------------------------------------------
    @classmethod
    def from_dict(cls, raw: dict, source: str = "parameters") -> "SclamParams":
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(raw) - set(known))
        if unknown:
            # Refused, not ignored: a misspelt nominal value would silently stay at its default.
            raise ParamsError(
                f"{source}: unknown parameter(s) {', '.join(map(with_suggestion, unknown))}; "
                f"known: {', '.join(sorted(known))}"
            )
        values = {}
        for name, value in raw.items():
            default = known[name].default
            try:
                if isinstance(default, str):
                    if not isinstance(value, str):
                        raise TypeError
                    values[name] = value
                elif isinstance(default, tuple):
                    if isinstance(value, str) or not isinstance(value, (list, tuple)):
                        raise TypeError
                    values[name] = tuple(value)
                else:
                    if isinstance(value, bool):
                        raise TypeError
                    values[name] = float(value)
            except (TypeError, ValueError):
                kind = "list" if isinstance(default, tuple) else type(default).__name__
                raise ParamsError(f"{source}: {name} must be a {kind}, got {value!r}") from None
        params = cls(**values).validate()
        params.explicit_keys = frozenset(raw)
        return params

    @classmethod
    def from_yaml(cls, path, node_name: str = NODE_NAME) -> "SclamParams":
        path = Path(path)
        doc = read_yaml_document(path)
        return cls.from_dict(ros_parameters_section(doc, node_name, str(path)), str(path))

    def to_yaml_dict(self, node_name: str = NODE_NAME) -> dict:
        return {node_name: {"ros__parameters": dataclasses.asdict(self)}}

    def yaml_text(self, node_name: str = NODE_NAME, header: str = "") -> str:
        return header + yaml.safe_dump(self.to_yaml_dict(node_name), sort_keys=False)

    def write_yaml(self, path, node_name: str = NODE_NAME, header: str = "") -> None:
        atomic_write_text(path, self.yaml_text(node_name, header))


def read_yaml_document(path):
    """The YAML document in the parameters file ``path``; ParamsError (one line) if it is
    missing, a folder, unreadable, not text, not YAML or empty."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ParamsError(f"parameters file not found: {path}") from None
    except IsADirectoryError:
        raise ParamsError(f"{path} is a folder, not a parameters file") from None
    except OSError as exc:
        raise ParamsError(f"cannot read parameters file {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise ParamsError(f"{path}: not a text file, so not a YAML parameters file") from None
    except yaml.YAMLError as exc:
        # PyYAML's message spans lines (problem, then a context excerpt): keep its gist.
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ParamsError(f"{path}: not valid YAML{where}: {problem}") from None
    if doc is None:
        raise ParamsError(f"{path}: the parameters file is empty")
    return doc


def with_suggestion(name: str) -> str:
    """``name`` with the closest known parameter name, for typos: "wheel_bas (wheel_base?)"."""
    close = difflib.get_close_matches(name, [f.name for f in fields(SclamParams)], n=1)
    return f"{name} ({close[0]}?)" if close else name


def ros_parameters_section(doc, node_name: str, source: str) -> dict:
    """The ``ros__parameters`` mapping for ``node_name`` in a ROS 2 parameters document."""
    if not isinstance(doc, dict):
        raise ParamsError(f"{source}: expected a mapping '{node_name}: ros__parameters: ...'")
    merged = {}
    # ROS 2 applies wildcard sections first and the node's own section last.
    for key in ("/**", node_name, "/" + node_name):
        section = doc.get(key)
        if isinstance(section, dict) and isinstance(section.get("ros__parameters"), dict):
            merged.update(section["ros__parameters"])
    if not merged:
        raise ParamsError(
            f"{source}: no '{node_name}: ros__parameters:' (or '/**') section found; "
            f"top-level keys are {sorted(doc)}"
        )
    return merged


def _remove_stale_temps(path: Path) -> None:
    """Delete temporary files of earlier writes of ``path`` whose writer process is gone.

    A process killed between creating its temporary file and renaming it (SIGKILL, or
    SIGTERM without a handler: no ``finally`` runs) leaves the file behind. Each temporary
    file names its writer's pid, so a temporary file of a live writer (another process saving
    the same file right now) is left alone."""
    for tmp in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
        pid = tmp.name[len(path.name) + 2:].split(".", 1)[0]
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            os.kill(int(pid), 0)
            continue  # its writer is alive
        except ProcessLookupError:
            pass
        except OSError:  # e.g. alive under another user: not ours to judge
            continue
        with contextlib.suppress(FileNotFoundError):  # a concurrent save removed it first
            tmp.unlink()


def atomic_write_text(path, text: str) -> None:
    """Write ``text`` to ``path`` so that readers see the old file or the new one, never half,
    and leave no temporary file behind (nor one an earlier, killed save left)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_temps(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.",
                               suffix=".tmp")
    try:
        # mkstemp creates 0600; a calibration file is for everyone to read (umask decides).
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def check_parameter_value(name: str, value, default):
    """None if ``value`` is usable for the SclamParams field ``name``, else the reason."""
    if isinstance(default, str):
        if not isinstance(value, str):
            return f"{name} must be a string, got {type(value).__name__}"
    elif isinstance(default, tuple):
        if isinstance(value, str) or not isinstance(value, (list, tuple)):
            return f"{name} must be a list of joint names, got {type(value).__name__}"
        value = tuple(value)
    elif isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"{name} must be a number, got {type(value).__name__} {value!r}"
    field_ = {f.name: f for f in fields(SclamParams)}.get(name)
    check = field_.metadata.get("check") if field_ is not None else None
    if check is not None:
        return check(name, value if isinstance(default, (str, tuple)) else float(value))
    return None
