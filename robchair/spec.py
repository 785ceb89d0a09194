"""The RobChair Storm platform specification: geometry, drive train, sensor mounts and motor step tests.

Loaded from ``assets/robchair.toml`` (Table 9.1 of the thesis plus documented estimates) into frozen
dataclasses and validated where it enters: a missing field, an unknown key, a wrong type or an
impossible value (a negative radius, ``encoder_on = "axle"``) raises :class:`robchair.errors.ConfigError`
whose message names the field, the value and what was expected.

Frames: REP-103/REP-105. ``base_link`` lies on the floor midway between the driven-wheel contact points.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from robchair.errors import ConfigError
from robchair.paths import ASSETS

DEFAULT_SPEC_PATH = ASSETS / "robchair.toml"
QUADRATURE_FACTOR = 4  # a quadrature decoder counts both edges of both channels
ENCODER_LOCATIONS = ("motor", "wheel")


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

    height: float
    width: float
    depth: float
    mass: float
    centre_x: float = 0.0
    com_xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Drive:
    """The differential drive train (driven wheels, motors, gearboxes, encoders)."""

    wheel_radius: float
    wheel_separation: float
    max_motor_rpm: float
    gear_ratio: float
    encoder_ppr: int
    encoder_on: str = "motor"
    wheel_width: float = 0.06
    wheel_mass: float = 3.0
    wheel_x: float = 0.0


@dataclass(frozen=True)
class Caster:
    """One passive swivel caster; (x, y) is its swivel axis relative to ``base_link``."""

    name: str
    x: float
    y: float
    radius: float
    width: float
    trail: float
    mass: float


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
        roll, pitch, yaw = self.rpy
        r = _rot_z(yaw) @ _rot_y(pitch) @ _rot_x(roll)
        if joint_angle != 0.0:
            if self.joint is None:
                raise ConfigError(f"mount has no joint; cannot turn it by joint_angle={joint_angle!r}")
            r = r @ _axis_angle(np.asarray(self.joint.axis, dtype=float), joint_angle)
        return r

    def transform(self, joint_angle: float = 0.0) -> np.ndarray:
        """Homogeneous transform (4, 4) parent <- frame, with the servo at ``joint_angle`` rad."""
        t = np.eye(4)
        t[:3, :3] = self.rotation(joint_angle)
        t[:3, 3] = self.xyz
        return t


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

    t_r: float
    t_p: float
    M_p: float
    name: str = ""
    channel: int = 1
    step_fraction: float = 0.1


@dataclass(frozen=True)
class RobChairSpec:
    """The whole platform. Convenience properties forward the drive-train numbers of Table 9.1."""

    body: Body
    drive: Drive
    casters: tuple[Caster, ...]
    mounts: Mapping[str, Mount]
    motor_steps: tuple[StepResponse, ...]
    source: str = field(default="", compare=False)

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickle / deep-copy support: ``mounts`` is a read-only ``mappingproxy``, which cannot be pickled."""
        fields = (self.body, self.drive, self.casters, dict(self.mounts), self.motor_steps, self.source)
        return (_spec_from_fields, fields)

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

    def step_for_channel(self, channel: int) -> StepResponse:
        """The measured step response of Roboteq ``channel`` (1 or 2)."""
        for s in self.motor_steps:
            if s.channel == channel:
                return s
        raise ConfigError(f"motor_steps: no step response for channel {channel!r}")


# --------------------------------------------------------------------------------------------- loading


def _spec_from_fields(
    body: Body, drive: Drive, casters: Any, mounts: Any, steps: Any, source: str
) -> RobChairSpec:
    return RobChairSpec(body, drive, casters, MappingProxyType(mounts), steps, source)


def load_spec(path: Path | str | None = None) -> RobChairSpec:
    """Load and validate the platform spec.

    Args:
        path: TOML file; ``None`` loads ``assets/robchair.toml``.

    Raises:
        ConfigError: The file is missing, is not TOML, or a field is missing, unknown or invalid.
    """
    p = Path(path) if path is not None else DEFAULT_SPEC_PATH
    try:
        with p.open("rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError as exc:
        raise ConfigError(f"spec file {str(p)!r} does not exist") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"spec file {str(p)!r} is not valid TOML: {exc}") from exc
    return spec_from_dict(data, source=str(p))


def spec_from_dict(data: Mapping[str, Any], source: str = "<dict>") -> RobChairSpec:
    """Build a validated :class:`RobChairSpec` from the parsed TOML tables (see ``load_spec``)."""
    _only_keys(data, "", {"body", "drive", "casters", "mounts", "motor_steps"}, required=True)
    body = _parse_body(_table(data, "body"))
    drive = _parse_drive(_table(data, "drive"))
    casters = tuple(_parse_caster(c, f"casters[{i}]") for i, c in enumerate(_array(data, "casters")))
    names = [c.name for c in casters]
    if len(set(names)) != len(names):
        raise ConfigError(f"casters: names must be unique, got {names!r}")
    mounts_tbl = _table(data, "mounts")
    mounts = {str(k): _parse_mount(v, f"mounts.{k}") for k, v in mounts_tbl.items()}
    for needed in ("kinect_link", "sonar_array_left", "sonar_array_right"):
        if needed not in mounts:
            raise ConfigError(f"mounts.{needed}: missing (expected a table with parent, xyz, rpy)")
    steps = tuple(_parse_step(s, f"motor_steps[{i}]") for i, s in enumerate(_array(data, "motor_steps")))
    if not steps:
        raise ConfigError("motor_steps: empty (expected at least one measured step response)")
    channels = [s.channel for s in steps]
    if len(set(channels)) != len(channels):
        raise ConfigError(f"motor_steps: channels must be unique, got {channels!r}")
    return RobChairSpec(
        body=body,
        drive=drive,
        casters=casters,
        mounts=MappingProxyType(mounts),
        motor_steps=steps,
        source=source,
    )


def _parse_body(t: Mapping[str, Any]) -> Body:
    where = "body"
    _only_keys(t, where, {"height", "width", "depth", "mass", "centre_x", "com_xyz"})
    return Body(
        height=_pos(t, where, "height"),
        width=_pos(t, where, "width"),
        depth=_pos(t, where, "depth"),
        mass=_pos(t, where, "mass"),
        centre_x=_num(t, where, "centre_x", default=0.0),
        com_xyz=_vec3(t, where, "com_xyz", default=(0.0, 0.0, 0.0)),
    )


def _parse_drive(t: Mapping[str, Any]) -> Drive:
    where = "drive"
    _only_keys(
        t,
        where,
        {
            "wheel_radius",
            "wheel_separation",
            "max_motor_rpm",
            "gear_ratio",
            "encoder_ppr",
            "encoder_on",
            "wheel_width",
            "wheel_mass",
            "wheel_x",
        },
    )
    ppr = _req(t, where, "encoder_ppr")
    if isinstance(ppr, bool) or not isinstance(ppr, int) or ppr <= 0:
        raise ConfigError(f"{where}.encoder_ppr = {ppr!r}: expected a positive integer")
    on = t.get("encoder_on", "motor")
    if on not in ENCODER_LOCATIONS:
        raise ConfigError(f"{where}.encoder_on = {on!r}: expected one of {ENCODER_LOCATIONS}")
    return Drive(
        wheel_radius=_pos(t, where, "wheel_radius"),
        wheel_separation=_pos(t, where, "wheel_separation"),
        max_motor_rpm=_pos(t, where, "max_motor_rpm"),
        gear_ratio=_pos(t, where, "gear_ratio"),
        encoder_ppr=ppr,
        encoder_on=on,
        wheel_width=_pos(t, where, "wheel_width", default=0.06),
        wheel_mass=_pos(t, where, "wheel_mass", default=3.0),
        wheel_x=_num(t, where, "wheel_x", default=0.0),
    )


def _parse_caster(t: Any, where: str) -> Caster:
    if not isinstance(t, Mapping):
        raise ConfigError(f"{where} = {t!r}: expected a table")
    _only_keys(t, where, {"name", "x", "y", "radius", "width", "trail", "mass"})
    return Caster(
        name=_str(t, where, "name"),
        x=_num(t, where, "x"),
        y=_num(t, where, "y"),
        radius=_pos(t, where, "radius"),
        width=_pos(t, where, "width"),
        trail=_nonneg(t, where, "trail", default=0.0),
        mass=_pos(t, where, "mass"),
    )


def _parse_mount(t: Any, where: str) -> Mount:
    if not isinstance(t, Mapping):
        raise ConfigError(f"{where} = {t!r}: expected a table with parent, xyz, rpy")
    _only_keys(t, where, {"parent", "xyz", "rpy", "joint"})
    joint = None
    if "joint" in t:
        jt = t["joint"]
        jw = f"{where}.joint"
        if not isinstance(jt, Mapping):
            raise ConfigError(f"{jw} = {jt!r}: expected a table with name, axis, lower, upper")
        _only_keys(jt, jw, {"name", "axis", "lower", "upper"})
        axis = _vec3(jt, jw, "axis")
        norm = math.sqrt(sum(a * a for a in axis))
        if not norm > 0:
            raise ConfigError(f"{jw}.axis = {list(axis)!r}: expected a non-zero vector")
        lower, upper = _num(jt, jw, "lower"), _num(jt, jw, "upper")
        if not lower < upper:
            raise ConfigError(f"{jw}: lower = {lower!r} must be below upper = {upper!r}")
        joint = Joint(
            name=_str(jt, jw, "name"),
            axis=(axis[0] / norm, axis[1] / norm, axis[2] / norm),
            lower=lower,
            upper=upper,
        )
    return Mount(
        parent=_str(t, where, "parent"), xyz=_vec3(t, where, "xyz"), rpy=_vec3(t, where, "rpy"), joint=joint
    )


def _parse_step(t: Any, where: str) -> StepResponse:
    if not isinstance(t, Mapping):
        raise ConfigError(f"{where} = {t!r}: expected a table")
    _only_keys(t, where, {"name", "channel", "t_r", "t_p", "M_p", "step_fraction"})
    mp = _num(t, where, "M_p")
    if not 0.0 < mp < 1.0:
        raise ConfigError(f"{where}.M_p = {mp!r}: expected an overshoot fraction strictly between 0 and 1")
    frac = _pos(t, where, "step_fraction", default=0.1)
    if frac > 1.0:
        raise ConfigError(f"{where}.step_fraction = {frac!r}: expected a fraction in (0, 1]")
    ch = t.get("channel", 1)
    if isinstance(ch, bool) or not isinstance(ch, int) or ch < 1:
        raise ConfigError(f"{where}.channel = {ch!r}: expected a positive integer (1 = left, 2 = right)")
    return StepResponse(
        t_r=_pos(t, where, "t_r"),
        t_p=_pos(t, where, "t_p"),
        M_p=mp,
        name=str(t.get("name", f"motor {ch}")),
        channel=ch,
        step_fraction=frac,
    )


# --------------------------------------------------------------------------------------------- helpers


def _only_keys(t: Mapping[str, Any], where: str, allowed: set[str], required: bool = False) -> None:
    unknown = sorted(set(t) - allowed)
    if unknown:
        prefix = f"{where}." if where else ""
        raise ConfigError(
            f"{prefix}{unknown[0]}: unknown key (value {t[unknown[0]]!r}); expected one of {sorted(allowed)}"
        )
    if required:
        missing = sorted(allowed - set(t))
        if missing:
            raise ConfigError(f"{missing[0]}: missing table (expected [{missing[0]}])")


def _table(t: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    v = t[key]
    if not isinstance(v, Mapping):
        raise ConfigError(f"{key} = {v!r}: expected a table")
    return v


def _array(t: Mapping[str, Any], key: str) -> list[Any]:
    v = t[key]
    if not isinstance(v, list):
        raise ConfigError(f"{key} = {v!r}: expected an array of tables ([[{key}]])")
    return v


def _req(t: Mapping[str, Any], where: str, key: str) -> Any:
    if key not in t:
        raise ConfigError(f"{where}.{key}: missing field")
    return t[key]


_MISSING: Any = object()


def _num(t: Mapping[str, Any], where: str, key: str, default: Any = _MISSING) -> float:
    if key not in t and default is not _MISSING:
        return float(default)
    v = _req(t, where, key)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"{where}.{key} = {v!r}: expected a finite number")
    return float(v)


def _pos(t: Mapping[str, Any], where: str, key: str, default: Any = _MISSING) -> float:
    v = _num(t, where, key, default)
    if not v > 0:
        raise ConfigError(f"{where}.{key} = {v!r}: expected a positive number")
    return v


def _nonneg(t: Mapping[str, Any], where: str, key: str, default: Any = _MISSING) -> float:
    v = _num(t, where, key, default)
    if v < 0:
        raise ConfigError(f"{where}.{key} = {v!r}: expected a number >= 0")
    return v


def _str(t: Mapping[str, Any], where: str, key: str) -> str:
    v = _req(t, where, key)
    if not isinstance(v, str) or not v:
        raise ConfigError(f"{where}.{key} = {v!r}: expected a non-empty string")
    return v


def _vec3(t: Mapping[str, Any], where: str, key: str, default: Any = _MISSING) -> tuple[float, float, float]:
    if key not in t and default is not _MISSING:
        return tuple(default)  # type: ignore[return-value]
    v = _req(t, where, key)
    ok = (
        isinstance(v, list | tuple)
        and len(v) == 3
        and all(not isinstance(a, bool) and isinstance(a, int | float) and math.isfinite(a) for a in v)
    )
    if not ok:
        raise ConfigError(f"{where}.{key} = {v!r}: expected three finite numbers [x, y, z]")
    return (float(v[0]), float(v[1]), float(v[2]))


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _axis_angle(axis: np.ndarray, a: float) -> np.ndarray:
    """Rodrigues' rotation about the unit vector ``axis`` by ``a`` rad."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(a) * k + (1.0 - math.cos(a)) * (k @ k)
