"""The RobChair URDF, generated from the platform spec (``assets/robchair.toml``), never hand-copied.

Links: ``base_link`` (on the floor midway between the driven wheels, REP-105; its collision is a low
chassis box, a backrest and a mast, so the Kinect above it is not inside any collision shape), two
driven wheels on continuous joints, two front casters, ``kinect_link`` (fixed) and the two sonar arrays
on revolute servo joints about their mount's joint axis.

Casters and the load: with four wheels on a rigid floor PyBullet is free to put the weight on the
casters, and a caster with friction drags the chair sideways or stalls it. Here each caster is a sphere
of the caster's radius fixed at its contact point (swivel axis minus the trail) with zero lateral,
rolling and spinning friction (set by :func:`apply_contact_dynamics`): it can only push up, like an
ideal swivel caster. The body's centre of mass (spec ``body.com_xyz``) sits just ahead of the driven axle,
so by the lever rule the driven wheels carry most of the weight; a test checks the contact forces.

Driven wheels: Bullet's cylinder-plane contacts flicker between the two rim edges and make the chair
yaw (2 deg over 3 m of straight driving), so each driven wheel touches the floor as a sphere of the
tyre's radius (one stable contact point on the tyre's centre line). A sphere is 2 r wide, though, and
would make the chair 0.92 m wide against the spec's 0.64 m. So contacts are split by collision filter
(:func:`apply_contact_dynamics`): the wheel spheres touch only the floor, and ``base_link`` carries a
*tyre guard* per wheel, a cylinder of the tyre's radius and width on the wheel's axle, that touches
everything but the floor. The caster spheres get the same split (a sphere of 0.10 m at y = 0.25 m
would reach 0.35 m, outside the footprint): a caster guard cylinder of the caster's radius and width,
facing straight ahead, meets the scene. The chair's collision footprint is then the spec's: 0.64 m
wide (tyre outer faces), 0.84 m long (rear of the tyres / chassis to the footrest), casters inside it.
"""

from __future__ import annotations

import hashlib
import math
import tempfile
from pathlib import Path
from xml.sax.saxutils import quoteattr

from robchair.platform.spec import RobChairSpec

WHEEL_JOINTS = ("left_wheel_joint", "right_wheel_joint")
SENSOR_LINK_MASS = 0.2  # kg; small but not tiny, so the servo joints stay well conditioned
CHASSIS_CLEARANCE = 0.08  # m floor clearance of the chassis box (under the footrest and batteries)
SEAT_HEIGHT = 0.55  # m, top of the chassis/seat box
BACKREST_TOP = 1.15  # m
WHEEL_FRICTION = 1.0
SERVO_MAX_VELOCITY = math.radians(300.0)  # rad/s, a hobby servo's 0.2 s / 60 deg
SERVO_MAX_TORQUE = 2.0  # N m


def _f(*values: float) -> str:
    return " ".join(f"{v:.6g}" for v in values)


def _box_inertia(m: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    return (m * (y * y + z * z) / 12, m * (x * x + z * z) / 12, m * (x * x + y * y) / 12)


def _inertial(mass: float, xyz: tuple[float, float, float], ixx: float, iyy: float, izz: float) -> str:
    return (
        f'<inertial><origin xyz="{_f(*xyz)}" rpy="0 0 0"/><mass value="{mass:.6g}"/>'
        f'<inertia ixx="{ixx:.6g}" ixy="0" ixz="0" iyy="{iyy:.6g}" iyz="0" izz="{izz:.6g}"/></inertial>'
    )


def _tyre_guard(xyz: tuple[float, float, float], radius: float, width: float) -> str:
    """Collision cylinder (axis y) of one tyre on ``base_link``: the tyre's volume against the scene."""
    return (
        f'<collision><origin xyz="{_f(*xyz)}" rpy="{math.pi / 2:.9f} 0 0"/>'
        f'<geometry><cylinder radius="{radius:.9g}" length="{width:.6g}"/></geometry></collision>'
    )


def _geom_box(xyz: tuple[float, float, float], size: tuple[float, float, float], color: str | None) -> str:
    g = f'<origin xyz="{_f(*xyz)}" rpy="0 0 0"/><geometry><box size="{_f(*size)}"/></geometry>'
    vis = f'<visual>{g}<material name="{color}"/></visual>' if color else ""
    return vis + f"<collision>{g}</collision>"


def build_urdf(spec: RobChairSpec, wheel_radius_scale: tuple[float, float] = (1.0, 1.0)) -> str:
    """The URDF text of the chair described by ``spec``.

    Args:
        spec: The platform spec.
        wheel_radius_scale: True radius of the (left, right) tyre relative to the spec's (tyre pressure
            and wear make real tyres differ by a few tenths of a percent; the odometry keeps using the
            spec's radius, which is what makes real odometry drift).
    """
    for k in wheel_radius_scale:
        if not (math.isfinite(k) and 0.5 < k < 1.5):
            raise ValueError(f"wheel_radius_scale {wheel_radius_scale!r}: expected factors near 1")
    b, d = spec.body, spec.drive
    x0 = b.centre_x - b.depth / 2  # rear edge of the footprint
    x1 = b.centre_x + b.depth / 2
    chassis_w = d.wheel_separation - d.wheel_width  # between the tyres
    chassis_h = SEAT_HEIGHT - CHASSIS_CLEARANCE
    back_depth = 0.08
    mast_x = spec.mounts["kinect_link"].xyz[0] if "kinect_link" in spec.mounts else x0 + 0.05
    mast_top = spec.mounts["kinect_link"].xyz[2] - 0.04 if "kinect_link" in spec.mounts else b.height - 0.1
    ixx, iyy, izz = _box_inertia(b.mass, b.depth, b.width, b.height)
    parts = [
        '<?xml version="1.0"?>',
        f"<!-- generated by sim/urdf.py from {spec.source or 'the spec'}; do not edit -->",
        '<robot name="robchair">',
        '<material name="frame"><color rgba="0.15 0.15 0.18 1"/></material>',
        '<material name="seat"><color rgba="0.1 0.3 0.6 1"/></material>',
        '<material name="tyre"><color rgba="0.05 0.05 0.05 1"/></material>',
        '<material name="sensor"><color rgba="0.8 0.4 0.1 1"/></material>',
        '<link name="base_link">',
        _inertial(b.mass, b.com_xyz, ixx, iyy, izz),
        _geom_box(
            ((x0 + x1) / 2, 0.0, CHASSIS_CLEARANCE + chassis_h / 2), (b.depth, chassis_w, chassis_h), "seat"
        ),
        _geom_box(
            (x0 + back_depth / 2 + 0.04, 0.0, (SEAT_HEIGHT + BACKREST_TOP) / 2),
            (back_depth, chassis_w, BACKREST_TOP - SEAT_HEIGHT),
            "seat",
        ),
        _geom_box(
            (mast_x, 0.0, (BACKREST_TOP + mast_top) / 2), (0.04, 0.04, mast_top - BACKREST_TOP), "frame"
        ),
        *(
            _tyre_guard(
                (d.wheel_x, sign * d.wheel_separation / 2, d.wheel_radius * scale),
                d.wheel_radius * scale,
                d.wheel_width,
            )
            for sign, scale in ((1.0, wheel_radius_scale[0]), (-1.0, wheel_radius_scale[1]))
        ),
        *(_tyre_guard((c.x - c.trail, c.y, c.radius), c.radius, c.width) for c in spec.casters),
        "</link>",
    ]
    # driven wheels: continuous joints about +y, so a positive wheel speed drives the chair forward
    wi = (
        d.wheel_mass * (3 * d.wheel_radius**2 + d.wheel_width**2) / 12,
        d.wheel_mass * d.wheel_radius**2 / 2,
    )
    for side, sign, scale in (("left", 1.0, wheel_radius_scale[0]), ("right", -1.0, wheel_radius_scale[1])):
        radius = d.wheel_radius * scale
        g = (
            f'<origin xyz="0 0 0" rpy="{math.pi / 2:.9f} 0 0"/>'
            f'<geometry><cylinder radius="{radius:.9g}" length="{d.wheel_width:.6g}"/></geometry>'
        )
        # floor contact as a sphere of the wheel's radius: one stable contact point on the tyre's centre
        # line; it touches only the floor (the tyre guard on base_link meets the scene, see the docstring)
        gc = f'<origin xyz="0 0 0" rpy="0 0 0"/><geometry><sphere radius="{radius:.9g}"/></geometry>'
        parts += [
            f'<link name="{side}_wheel">',
            _inertial(d.wheel_mass, (0, 0, 0), wi[0], wi[1], wi[0]),
            f'<visual>{g}<material name="tyre"/></visual><collision>{gc}</collision>',
            "</link>",
            f'<joint name="{side}_wheel_joint" type="continuous"><parent link="base_link"/>'
            f'<child link="{side}_wheel"/>'
            f'<origin xyz="{_f(d.wheel_x, sign * d.wheel_separation / 2)} {radius:.9g}"'
            ' rpy="0 0 0"/><axis xyz="0 1 0"/></joint>',
        ]
    for c in spec.casters:
        ci = 2 * c.mass * c.radius**2 / 5
        g = f'<origin xyz="0 0 0" rpy="0 0 0"/><geometry><sphere radius="{c.radius:.6g}"/></geometry>'
        parts += [
            f"<link name={quoteattr(c.name)}>",
            _inertial(c.mass, (0, 0, 0), ci, ci, ci),
            f'<visual>{g}<material name="tyre"/></visual><collision>{g}</collision>',
            "</link>",
            f'<joint name={quoteattr(c.name + "_joint")} type="fixed"><parent link="base_link"/>'
            f"<child link={quoteattr(c.name)}/>"
            f'<origin xyz="{_f(c.x - c.trail, c.y, c.radius)}" rpy="0 0 0"/></joint>',
        ]
    si = _box_inertia(SENSOR_LINK_MASS, 0.1, 0.1, 0.1)
    for name, mount in spec.mounts.items():
        size = (0.07, 0.25, 0.07) if name == "kinect_link" else (0.05, 0.12, 0.05)
        g = f'<origin xyz="0 0 0" rpy="0 0 0"/><geometry><box size="{_f(*size)}"/></geometry>'
        parts += [
            f"<link name={quoteattr(name)}>",
            _inertial(SENSOR_LINK_MASS, (0, 0, 0), *si),
            f'<visual>{g}<material name="sensor"/></visual>',
            "</link>",
        ]
        origin = f'<origin xyz="{_f(*mount.xyz)}" rpy="{_f(*mount.rpy)}"/>'
        if mount.joint is None:
            parts.append(
                f'<joint name={quoteattr(name + "_joint")} type="fixed">'
                f"<parent link={quoteattr(mount.parent)}/>"
                f"<child link={quoteattr(name)}/>{origin}</joint>"
            )
        else:
            j = mount.joint
            parts.append(
                f'<joint name={quoteattr(j.name)} type="revolute"><parent link={quoteattr(mount.parent)}/>'
                f'<child link={quoteattr(name)}/>{origin}<axis xyz="{_f(*j.axis)}"/>'
                f'<limit lower="{j.lower:.9g}" upper="{j.upper:.9g}" effort="{SERVO_MAX_TORQUE}" '
                f'velocity="{SERVO_MAX_VELOCITY:.6g}"/></joint>'
            )
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


def write_urdf(
    spec: RobChairSpec,
    directory: Path | str | None = None,
    wheel_radius_scale: tuple[float, float] = (1.0, 1.0),
) -> Path:
    """Write the URDF to a cache file named by its content hash (reused while the spec is unchanged)."""
    text = build_urdf(spec, wheel_radius_scale)
    digest = hashlib.sha1(text.encode()).hexdigest()[:12]
    folder = Path(directory) if directory is not None else Path(tempfile.gettempdir()) / "robchair-urdf"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"robchair-{digest}.urdf"
    if not path.exists():
        tmp = path.with_suffix(f".tmp{id(text)}")
        tmp.write_text(text)
        tmp.replace(path)  # atomic: parallel test workers never read half a file
    return path


def apply_contact_dynamics(client: int, body: int, spec: RobChairSpec, floor: int | None = None) -> None:
    """Friction per link and the floor/scene split of the chair's contacts.

    Grippy driven wheels, frictionless caster spheres (they may only push up). With ``floor`` (the
    floor plane's body id) the contacts are split by collision filter: the driven wheels' spheres
    and the casters' spheres collide with the floor only (group and mask 0 - PyBullet ORs the two
    group tests - plus an enabled pair with the floor); ``base_link`` (chassis, backrest, mast, tyre
    and caster guards) collides with everything but the floor (a disabled pair).

    Args:
        client: PyBullet client id.
        body: The chair's body id (from the URDF of :func:`build_urdf`).
        spec: The platform spec (caster names).
        floor: Body id of the floor plane; None leaves the collision filters alone.
    """
    import pybullet as p

    names = {
        p.getJointInfo(body, i, physicsClientId=client)[12].decode(): i
        for i in range(p.getNumJoints(body, physicsClientId=client))
    }
    for side in ("left_wheel", "right_wheel"):
        p.changeDynamics(
            body,
            names[side],
            lateralFriction=WHEEL_FRICTION,
            rollingFriction=0.0,
            spinningFriction=0.0,
            physicsClientId=client,
        )
    for c in spec.casters:
        p.changeDynamics(
            body,
            names[c.name],
            lateralFriction=0.0,
            rollingFriction=0.0,
            spinningFriction=0.0,
            physicsClientId=client,
        )
    p.changeDynamics(body, -1, lateralFriction=0.5, physicsClientId=client)
    if floor is not None:
        # an explicit pair filter overrides the group/mask test in PyBullet's filter callback
        p.setCollisionFilterPair(body, floor, -1, -1, 0, physicsClientId=client)
        for link in ("left_wheel", "right_wheel", *(c.name for c in spec.casters)):
            p.setCollisionFilterGroupMask(body, names[link], 0, 0, physicsClientId=client)
            p.setCollisionFilterPair(body, floor, names[link], -1, 1, physicsClientId=client)
