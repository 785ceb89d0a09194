"""The RobChair Storm platform specification: geometry, drive train, sensor mounts and motor step tests.

Loaded from ``assets/robchair.toml`` (Table 9.1 of the thesis plus documented estimates) into frozen
dataclasses and validated where it enters (:mod:`robchair.platform.config`): a missing field, an unknown
key, a wrong type or an impossible value (a negative radius, ``encoder_on = "axle"``) raises
:class:`robchair.platform.errors.ConfigError` whose message names the file, the line, the field, the value and
what was expected.

Frames: REP-103/REP-105. ``base_link`` lies on the floor midway between the driven-wheel contact points.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from robchair.platform.config import ConfigSource, ConfigTable, bounds, load_dataclass, load_toml
from robchair.platform.errors import ConfigError
from robchair.platform.frames import rotation_axis_angle, rotation_rpy, se3
from robchair.platform.paths import ASSETS

DEFAULT_SPEC_PATH = ASSETS / "robchair.toml"
QUADRATURE_FACTOR = 4  # a quadrature decoder counts both edges of both channels
ENCODER_LOCATIONS = ("motor", "wheel")
LASER_FRAME = "laser_link"  # REP-105 frame of the Hokuyo laser and the key of its mount


@dataclass(frozen=True)
class Body:
    """The chair body (everything but the wheels) as a box for collision and inertia.

    Attributes:
        height: Overall height, m (Table 9.1).
        width: Overall width, m (Table 9.1).
        depth: Overall depth (length), m (Table 9.1).
        mass: Mass without the four wheels, kg.
        centre_x: x of the footprint centre relative to ``base_link``, m.
        com_xyz: Centre of mass relative to ``base_link``, m.
    """

    height: float = field(metadata=bounds(gt=0))
    width: float = field(metadata=bounds(gt=0))
    depth: float = field(metadata=bounds(gt=0))
    mass: float = field(metadata=bounds(gt=0))
    centre_x: float = 0.0
    com_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Drive:
    """The differential drive train (driven wheels, motors, gearboxes, encoders)."""

    wheel_radius: float = field(metadata=bounds(gt=0))
    wheel_separation: float = field(metadata=bounds(gt=0))
    max_motor_rpm: float = field(metadata=bounds(gt=0))
    gear_ratio: float = field(metadata=bounds(gt=0))
    encoder_ppr: int = field(metadata=bounds(gt=0))
    encoder_on: str = field(default="motor", metadata=bounds(choices=ENCODER_LOCATIONS))
    wheel_width: float = field(default=0.06, metadata=bounds(gt=0))
    wheel_mass: float = field(default=3.0, metadata=bounds(gt=0))
    wheel_x: float = 0.0


@dataclass(frozen=True)
class Caster:
    """One passive swivel caster; (x, y) is its swivel axis relative to ``base_link``."""

    name: str
    x: float
    y: float
    radius: float = field(metadata=bounds(gt=0))
    width: float = field(metadata=bounds(gt=0))
    trail: float = field(metadata=bounds(ge=0))
    mass: float = field(metadata=bounds(gt=0))


@dataclass(frozen=True)
class Joint:
    """A revolute joint (a servo) that turns a mounted frame about ``axis`` of its own mount frame."""

    name: str
    axis: tuple[float, float, float]
    lower: float
    upper: float


@dataclass(frozen=True)
class Mount:
    """Pose of a sensor frame in its parent frame (URDF convention: rpy = fixed-axis roll, pitch, yaw).

    Attributes:
        parent: Parent frame name (``base_link``).
        xyz: Translation, m.
        rpy: Roll, pitch, yaw, rad. Positive pitch tilts the x axis down.
        joint: Optional servo turning the frame about ``joint.axis`` (angle 0 = the pose above).
    """

    parent: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    joint: Joint | None = None

    def rotation(self, joint_angle: float = 0.0) -> np.ndarray:
        """Rotation matrix (3, 3) of the frame in its parent, with the servo at ``joint_angle`` rad."""
        r = rotation_rpy(*self.rpy)
        if joint_angle != 0.0:
            if self.joint is None:
                raise ConfigError(f"mount has no joint; cannot turn it by joint_angle={joint_angle!r}")
            r = r @ rotation_axis_angle(self.joint.axis, joint_angle)
        return r

    def transform(self, joint_angle: float = 0.0) -> np.ndarray:
        """Homogeneous transform (4, 4) parent <- frame, with the servo at ``joint_angle`` rad."""
        return se3(self.rotation(joint_angle), self.xyz)


@dataclass(frozen=True)
class SonarArrays:
    """Geometry of the two sonar arrays and the servo convention (thesis 5.2, SPEC section 3).

    Attributes:
        outer_sonar_deg: Sonar 1 (left) points ``+outer_sonar_deg`` and sonar 3 (right)
            ``-outer_sonar_deg`` from the middle sonar 2, deg.
        servo_centre_deg: Servo command at which the array faces along its mount's x axis (joint
            angle 0), deg on the servo's 0..180 scale.
        sonar_offsets_m: Position (3, 3) of sonars 1, 2, 3 in the array frame, m.
    """

    outer_sonar_deg: float = field(metadata=bounds(gt=0, lt=90))
    servo_centre_deg: float = field(metadata=bounds(ge=0, le=180))
    sonar_offsets_m: tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]

    def joint_angle(self, servo_deg: float) -> float:
        """Joint angle in rad of the array's mount for a servo command of ``servo_deg`` deg."""
        return math.radians(servo_deg - self.servo_centre_deg)

    def servo_deg(self, joint_angle: float) -> float:
        """Servo command in deg that turns the array's mount to ``joint_angle`` rad."""
        return math.degrees(joint_angle) + self.servo_centre_deg


@dataclass(frozen=True)
class StepResponse:
    """Metrics of one measured open-loop step response of a wheel motor (SPEC section 5).

    Attributes:
        t_r: Rise time, s, as measured (the thesis does not state its definition).
        t_p: Peak time, s.
        M_p: Maximum overshoot as a fraction of the final value (0 < M_p < 1).
        name: Label, e.g. ``"motor 1"``.
        channel: Roboteq channel (1 = left, 2 = right).
        step_fraction: Size of the command step as a fraction of the maximum motor speed.
    """

    t_r: float = field(metadata=bounds(gt=0))
    t_p: float = field(metadata=bounds(gt=0))
    M_p: float = field(metadata=bounds(gt=0, lt=1))
    name: str = ""
    channel: int = field(default=1, metadata=bounds(ge=1))
    step_fraction: float = field(default=0.1, metadata=bounds(gt=0, le=1))


@dataclass(frozen=True)
class RobChairSpec:
    """The whole platform. Convenience properties forward the drive-train numbers of Table 9.1."""

    body: Body
    drive: Drive
    casters: tuple[Caster, ...]
    mounts: Mapping[str, Mount]
    motor_steps: tuple[StepResponse, ...]
    sonar_arrays: SonarArrays
    source: str = field(default="", compare=False)

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickle / deep-copy support: ``mounts`` is a read-only ``mappingproxy``, which cannot be pickled."""
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        values["mounts"] = dict(self.mounts)
        return (_spec_from_fields, (values,))

    @property
    def wheel_radius(self) -> float:
        return self.drive.wheel_radius

    @property
    def wheel_separation(self) -> float:
        return self.drive.wheel_separation

    @property
    def max_motor_rpm(self) -> float:
        return self.drive.max_motor_rpm

    @property
    def gear_ratio(self) -> float:
        return self.drive.gear_ratio

    @property
    def encoder_ppr(self) -> int:
        return self.drive.encoder_ppr

    @property
    def encoder_on(self) -> str:
        return self.drive.encoder_on

    @property
    def counts_per_wheel_rev(self) -> float:
        """Encoder counts (quadrature x4) per wheel revolution: 116 000 with the encoder on the motor."""
        per_shaft_rev = self.drive.encoder_ppr * QUADRATURE_FACTOR
        return per_shaft_rev * (self.drive.gear_ratio if self.drive.encoder_on == "motor" else 1.0)

    @property
    def total_mass(self) -> float:
        """Body + two driven wheels + casters, kg."""
        return self.body.mass + 2 * self.drive.wheel_mass + sum(c.mass for c in self.casters)

    @property
    def laser_mount(self) -> Mount:
        """The Hokuyo laser's mount, ``mounts.laser_link`` (base_link <- laser_link).

        Raises:
            ConfigError: the spec has no ``laser_link`` mount.
        """
        try:
            return self.mounts[LASER_FRAME]
        except KeyError:
            raise ConfigError(
                f"mounts.{LASER_FRAME}: missing (the laser needs a table with parent, xyz, rpy)"
            ) from None

    def step_for_channel(self, channel: int) -> StepResponse:
        """The measured step response of Roboteq ``channel`` (1 or 2)."""
        for s in self.motor_steps:
            if s.channel == channel:
                return s
        raise ConfigError(f"motor_steps: no step response for channel {channel!r}")


# --------------------------------------------------------------------------------------------- loading


def _spec_from_fields(values: dict[str, Any]) -> RobChairSpec:
    return RobChairSpec(**{**values, "mounts": MappingProxyType(values["mounts"])})


def load_spec(path: Path | str | None = None) -> RobChairSpec:
    """Load and validate the platform spec.

    Args:
        path: TOML file; ``None`` loads ``assets/robchair.toml``.

    Raises:
        ConfigError: The file is missing, is not TOML, or a field is missing, unknown or invalid
            (message in the dialect of :mod:`robchair.platform.config`: file, line, field, value,
            expectation).
    """
    p = Path(path) if path is not None else DEFAULT_SPEC_PATH
    data, source = load_toml(p, what="spec file")
    return spec_from_dict(data, source=source)


def spec_from_dict(data: Mapping[str, Any], source: ConfigSource | str = "<dict>") -> RobChairSpec:
    """Build a validated :class:`RobChairSpec` from the parsed TOML tables (see ``load_spec``)."""
    src = source if isinstance(source, ConfigSource) else ConfigSource(source)
    top = ConfigTable(data, src)
    sections = {"body", "drive", "casters", "mounts", "motor_steps", "sonar_arrays"}
    top.keys(sections, required=sections)
    body = load_dataclass(Body, top.table("body"))
    drive = load_dataclass(Drive, top.table("drive"))
    casters = tuple(
        load_dataclass(Caster, t) if "trail" in t else load_dataclass(Caster, t, trail=0.0)
        for t in top.tables("casters")
    )
    names = [c.name for c in casters]
    if len(set(names)) != len(names):
        raise top.problem("casters", f"names must be unique, got {names!r}")
    mounts_tbl = top.table("mounts")
    mounts = {str(k): _parse_mount(mounts_tbl.table(k)) for k in mounts_tbl.data}
    for needed in ("kinect_link", "sonar_array_left", "sonar_array_right"):
        if needed not in mounts:
            raise src.missing(mounts_tbl.field(needed), "a table with parent, xyz, rpy")
    steps = tuple(_parse_step(t) for t in top.tables("motor_steps"))
    if not steps:
        raise top.invalid("motor_steps", "at least one measured step response ([[motor_steps]])")
    channels = [s.channel for s in steps]
    if len(set(channels)) != len(channels):
        raise top.problem("motor_steps", f"channels must be unique, got {channels!r}")
    return RobChairSpec(
        body=body,
        drive=drive,
        casters=casters,
        mounts=MappingProxyType(mounts),
        motor_steps=steps,
        sonar_arrays=load_dataclass(SonarArrays, top.table("sonar_arrays")),
        source=src.name,
    )


def _parse_mount(t: ConfigTable) -> Mount:
    t.keys({"parent", "xyz", "rpy", "joint"}, required={"parent", "xyz", "rpy"})
    joint = None
    if "joint" in t:
        jt = t.table("joint")
        jt.keys({"name", "axis", "lower", "upper"})
        axis = jt.vector("axis", 3)
        norm = math.sqrt(sum(a * a for a in axis))
        if not norm > 0:
            raise jt.invalid("axis", "a non-zero vector")
        lower = jt.number("lower")
        upper = jt.number("upper", gt=lower)
        joint = Joint(
            name=jt.string("name"),
            axis=(axis[0] / norm, axis[1] / norm, axis[2] / norm),
            lower=lower,
            upper=upper,
        )
    xyz, rpy = t.vector("xyz", 3), t.vector("rpy", 3)
    return Mount(
        parent=t.string("parent"), xyz=(xyz[0], xyz[1], xyz[2]), rpy=(rpy[0], rpy[1], rpy[2]), joint=joint
    )


@functools.cache
def default_spec() -> RobChairSpec:
    """The platform spec of ``assets/robchair.toml``, loaded once (the spec is immutable).

    Raises:
        ConfigError: As :func:`load_spec`.
    """
    return load_spec()


def _parse_step(t: ConfigTable) -> StepResponse:
    step = load_dataclass(StepResponse, t)
    if "name" not in t:  # the label follows the channel
        step = dataclasses.replace(step, name=f"motor {step.channel}")
    return step
