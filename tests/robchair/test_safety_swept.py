"""The safety layer's swept-footprint check: turns, arcs and reversing near walls (issue 22's contacts).

The check (:func:`robchair.platform.safety.swept_distances`) samples the footprint along the twist's
arc; here it is compared with independent geometry: shapely's distance to the union of the footprint
at 4000 poses with the hulls between them, and a turn in place beside a wall worked out by hand.
"""

from __future__ import annotations

import itertools
import math
import re

import numpy as np
import pytest
from shapely import affinity
from shapely.geometry import MultiPoint, Polygon
from shapely.ops import unary_union

from robchair.platform.safety import (
    SWEEP_MAX_POSES,
    SWEEP_STEP_M,
    Footprint,
    SafetyInputs,
    SafetyLayer,
    SafetyLimits,
    StopReason,
    swept_clearance,
    swept_distances,
)
from robchair.platform.spec import load_spec


@pytest.fixture(scope="module")
def spec():
    return load_spec()


@pytest.fixture(scope="module")
def fp(spec):
    return Footprint.from_spec(spec)


def _exact_swept(fp: Footprint, v: float, w: float, duration: float, n: int = 4000) -> Polygon:
    """The swept footprint as a shapely polygon: the rectangle at n + 1 poses along the arc, each pair of
    neighbours joined by their convex hull (the motion between two poses 1/n apart is that close to a
    straight push)."""
    rect = Polygon([(fp.rear_x, -fp.half_width), (fp.front_x, -fp.half_width),
                    (fp.front_x, fp.half_width), (fp.rear_x, fp.half_width)])  # fmt: skip
    placed = []
    for t in np.linspace(0.0, duration, n + 1):
        th = w * t
        x, y = (v / w * math.sin(th), v / w * (1 - math.cos(th))) if abs(w) > 1e-12 else (v * t, 0.0)
        placed.append(affinity.translate(affinity.rotate(rect, th, origin=(0, 0), use_radians=True), x, y))
    hulls = [MultiPoint(list(a.exterior.coords) + list(b.exterior.coords)).convex_hull
             for a, b in itertools.pairwise(placed)]  # fmt: skip
    return unary_union(hulls)


@pytest.mark.parametrize(
    ("v", "w", "duration"),
    [
        (0.0, 1.2, 0.9),
        (0.0, -2.0, 1.5),
        (0.4, 0.8, 0.8),
        (-0.3, -0.6, 1.0),
        (0.5, 0.0, 0.7),
        (0.2, -1.5, 1.2),
    ],
)
def test_swept_clearance_bounds_the_exact_sweep(fp, v, w, duration) -> None:
    rng = np.random.default_rng(7)
    swept = _exact_swept(fp, v, w, duration)
    pts = rng.uniform(-1.6, 1.6, size=(400, 2))
    exact = np.array([swept.exterior.distance(MultiPoint([p]).geoms[0]) if not swept.contains(
        MultiPoint([p]).geoms[0]) else 0.0 for p in pts])  # fmt: skip
    outside = exact > 0.0
    assert outside.sum() > 100 and (~outside).sum() > 10
    _, _, bound = swept_distances(pts[:1], v, w, duration, fp)
    # half a step of the fastest footprint point (SWEEP_STEP_M, longer when the poses are capped)
    assert bound <= 0.5 * max(SWEEP_STEP_M, (abs(v) + fp.reach * abs(w)) * duration / SWEEP_MAX_POSES) + 1e-12
    for p, d in zip(pts[outside], exact[outside]):
        lower = swept_clearance(p[None], v, w, duration, fp)
        # a lower bound, within the sampling bound of the exact distance
        assert lower <= d + 1e-6
        assert lower >= d - bound - 1e-6
    for p in pts[~outside]:
        assert swept_clearance(p[None], v, w, duration, fp) <= 1e-6


def test_turn_in_place_beside_a_wall_by_hand(fp) -> None:
    # a wall y = -y_w on the right, parallel; turning right (clockwise) by phi swings the front-right
    # corner (the footrest) out to y = r sin(alpha - phi); turning left swings the rear-right corner out
    y_w, w, duration = fp.half_width + 0.20, -1.0, 0.35
    phi = abs(w) * duration
    r, alpha = math.hypot(fp.front_x, fp.half_width), math.atan2(-fp.half_width, fp.front_x)
    assert alpha - phi > -math.pi / 2
    expected = y_w + r * math.sin(alpha - phi)  # the wall's distance to the swept corner
    assert 0.0 < expected < 0.05  # the turn comes much closer than the parallel gap (0.20 m)
    wall = np.stack([np.linspace(-1.5, 2.0, 3501), np.full(3501, -y_w)], axis=1)  # 1 mm spacing
    got = swept_clearance(wall, 0.0, w, duration, fp)
    assert expected - 0.5 * SWEEP_STEP_M - 1e-3 <= got <= expected + 1e-3
    r_rear, a_rear = math.hypot(fp.rear_x, fp.half_width), math.atan2(-fp.half_width, fp.rear_x)
    assert a_rear + phi < -math.pi / 2
    left = swept_clearance(wall, 0.0, -w, duration, fp)
    expected_left = y_w + r_rear * math.sin(a_rear + phi)
    assert expected_left - 0.5 * SWEEP_STEP_M - 1e-3 <= left <= expected_left + 1e-3


def _layer(spec) -> SafetyLayer:
    return SafetyLayer(SafetyLimits.from_spec(spec), spec.wheel_separation, Footprint.from_spec(spec))


def _rect(fp: Footprint, x: float, y: float, th: float) -> Polygon:
    return affinity.translate(affinity.rotate(Polygon([
        (fp.rear_x, -fp.half_width), (fp.front_x, -fp.half_width), (fp.front_x, fp.half_width),
        (fp.rear_x, fp.half_width)]), th, origin=(0, 0), use_radians=True), x, y)  # fmt: skip


def _drive(spec, v: float, w: float, world: np.ndarray | None, cycles: int = 30, fed: bool = True):
    """Drive the layer for ``cycles`` 50 ms cycles on a chair that follows its output exactly (arcs),
    among obstacle points ``world`` (N, 2; the chair starts at the origin facing +x). Returns the
    decisions and the smallest distance (shapely) between the footprint and the points over the run,
    each cycle's arc sampled at 20 poses."""
    layer, fp = _layer(spec), Footprint.from_spec(spec)
    x = y = th = 0.0
    obstacles = MultiPoint([tuple(p) for p in world]) if world is not None else None
    out, clear = [], math.inf
    for k in range(cycles):
        pts = None
        if world is not None and fed:
            c, s = math.cos(th), math.sin(th)
            q = world - (x, y)
            pts = np.stack([c * q[:, 0] + s * q[:, 1], c * q[:, 1] - s * q[:, 0]], axis=1)
        d = layer.filter(v, w, SafetyInputs(k * 50_000_000, obstacles_xy=pts), 0.05)
        out.append(d)
        for _ in range(20):
            dt = 0.05 / 20
            if abs(d.w) > 1e-12:
                x += d.v / d.w * (math.sin(th + d.w * dt) - math.sin(th))
                y -= d.v / d.w * (math.cos(th + d.w * dt) - math.cos(th))
            else:
                x, y = x + d.v * dt * math.cos(th), y + d.v * dt * math.sin(th)
            th += d.w * dt
            if obstacles is not None:
                clear = min(clear, _rect(fp, x, y, th).distance(obstacles))
    return out, clear, (x, y, th)


def _wall(p0, p1, step: float = 0.005) -> np.ndarray:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = max(2, round(float(np.hypot(*(p1 - p0))) / step) + 1)
    return p0 + np.linspace(0.0, 1.0, n)[:, None] * (p1 - p0)


def test_turning_in_place_into_a_wall_beside_stops(spec, fp) -> None:
    wall = _wall((-1.5, -(fp.half_width + 0.06)), (2.0, -(fp.half_width + 0.06)))  # 6 cm right, along
    out, clear, pose = _drive(spec, 0.0, -1.5, wall, cycles=60)
    assert any(d.stop is StopReason.OBSTACLE_SWEPT for d in out)
    # it turned to about where the footrest is the margin off the wall (0.053 rad), then stopped
    assert out[-1].stop is StopReason.OBSTACLE_SWEPT and pose[2] < -0.04
    assert clear >= _layer(spec).limits.sweep_margin_m - 0.5 * SWEEP_STEP_M
    # without the obstacle points (the layer before the check) the footrest swings into the wall
    _, clear_old, _ = _drive(spec, 0.0, -1.5, wall, fed=False)
    assert clear_old == 0.0


def test_a_chair_against_a_wall_can_turn_away_and_drive_along(spec, fp) -> None:
    # a wall ahead-right, 0.3 rad to the left of the chair's heading; the front-right corner (the
    # footrest) 1 cm off it: turning right would push the corner into it, turning left takes it away
    d = np.array([math.cos(0.3), math.sin(0.3)])
    normal = np.array([-d[1], d[0]])  # toward the chair
    base = np.array([fp.front_x, -fp.half_width]) - 0.01 * normal
    wall = _wall(base - 2.0 * d, base + 0.6 * d)
    assert fp.signed_distance(wall).min() == pytest.approx(0.01, abs=1e-3)
    toward, clear, _ = _drive(spec, 0.0, -1.0, wall)
    assert toward[0].stop is StopReason.OBSTACLE_SWEPT and clear > 0.009
    away, clear_away, pose = _drive(spec, 0.0, 1.0, wall)
    assert all(x.stop is None for x in away) and away[-1].w == pytest.approx(1.0)
    assert pose[2] > 0.8 and clear_away > 0.009  # it turned away, never closer than it started
    # reversing takes the corner back from the wall: allowed
    back, _, pose = _drive(spec, -0.3, 0.0, wall)
    assert all(x.stop is None for x in back) and pose[0] < -0.2


def test_driving_parallel_to_a_wall_closer_than_the_margin_is_allowed(spec, fp) -> None:
    wall = _wall((-1.5, fp.half_width + 0.01), (3.0, fp.half_width + 0.01))  # 1 cm left: inside the margin
    ahead, _, pose = _drive(spec, 0.4, 0.0, wall)
    assert all(d.stop is None for d in ahead) and ahead[-1].v == pytest.approx(0.4) and pose[0] > 0.3
    back, _, pose = _drive(spec, -0.4, 0.0, wall)
    assert all(d.stop is None for d in back) and pose[0] < -0.3
    # but not turning toward it
    left, clear, _ = _drive(spec, 0.0, 0.8, wall)
    assert left[0].stop is StopReason.OBSTACLE_SWEPT and clear > 0.009


def test_reversing_into_a_wall_behind_is_limited_then_stopped(spec, fp) -> None:
    wall = _wall((fp.rear_x - 0.25, -0.6), (fp.rear_x - 0.25, 0.6))  # 25 cm behind
    out, clear, pose = _drive(spec, -0.6, 0.0, wall, cycles=60)
    assert pose[0] < -0.15  # it reversed toward the wall
    assert clear >= _layer(spec).limits.sweep_margin_m - 0.5 * SWEEP_STEP_M
    assert any(d.swept_scale is not None and d.swept_scale < 1.0 for d in out)
    _, clear_old, _ = _drive(spec, -0.6, 0.0, wall, cycles=60, fed=False)
    assert clear_old == 0.0


def test_points_far_away_or_inside_the_footprint_change_nothing(spec, fp) -> None:
    far = np.array([[3.0, 0.0], [0.0, -3.0], [-3.0, 1.0]])
    inside = np.array([[0.1, 0.0], [fp.front_x - 0.01, fp.half_width - 0.01]])
    ref = [(d.v, d.w) for d in _drive(spec, 0.3, 1.0, None)[0]]
    for pts in (inside, np.zeros((0, 2))):
        layer = _layer(spec)
        out = [layer.filter(0.3, 1.0, SafetyInputs(k, obstacles_xy=pts), 0.05) for k in range(30)]
        assert [(d.v, d.w) for d in out] == ref and all(d.swept_scale == 1.0 for d in out)
    out, _, _ = _drive(spec, 0.3, 1.0, far)
    assert [(d.v, d.w) for d in out] == ref


def test_sweep_scale_limits_before_it_stops(spec, fp) -> None:
    # a point 8 cm right of the chair's right side near the front: a fast right turn swings the side
    # into it, a tenth of it stops short
    layer = _layer(spec)
    p = np.array([[0.5, -fp.half_width - 0.08]])
    k, why = layer.sweep_scale(0.0, -2.0, p)
    assert 0.0 < k < 1.0 and "comes within" in why
    assert layer.sweep_scale(0.0, 2.0, p) == (1.0, "")  # the other way
    assert (
        swept_clearance(p, 0.0, -2.0 * k, layer.stopping_time(0.0, -2.0 * k), fp)
        >= layer.limits.sweep_margin_m
    )
    assert swept_clearance(p, 0.0, -2.0, layer.stopping_time(0.0, -2.0), fp) < layer.limits.sweep_margin_m


def test_stopping_time_brakes_the_rims_at_brake_decel(spec) -> None:
    layer = _layer(spec)
    lim = layer.limits
    assert layer.stopping_time(0.4, 0.0) == pytest.approx(lim.reaction_time_s + 0.4 / (2 * lim.brake_decel))
    yaw_decel = 2 * lim.brake_decel / spec.wheel_separation
    assert layer.stopping_time(0.0, -1.2) == pytest.approx(lim.reaction_time_s + 1.2 / (2 * yaw_decel))
    assert layer.stopping_time(0.0, 0.0) == pytest.approx(lim.reaction_time_s)


def test_footprint_rejects_a_bad_box() -> None:
    with pytest.raises(ValueError, match="rear_x < front_x"):
        Footprint(0.5, 0.2, 0.3)


def _speed_commands(emu) -> list[tuple[int, int]]:
    """(arrival time ns, RPM) of every ``!S`` the emulated Roboteq received."""
    return [
        (t, int(m.group(2)))
        for t, line in list(emu.received)
        if (m := re.fullmatch(r"!S (\d) (-?\d+)", line))
    ]


@pytest.mark.parametrize(("w", "blocked"), [(-0.8, True), (0.8, False)])
def test_emulated_chair_does_not_turn_its_footrest_into_an_echo(spec, w, blocked) -> None:
    # the real drivers on the emulated Roboteq and SRF08s, in the loop's own time (the SyncedClock):
    # the left array's three sonars hear an echo 6 cm ahead (just past the footrest's front edge), the
    # right array nothing. Turning right in place swings the chair's front-left forward into it: the
    # loop must hold the motors at zero; turning left swings it away: the chair turns
    from robchair.backends import get_backend
    from robchair.run_output import run_to_dir
    from robchair.sources import PolicySource

    backend = get_backend("emulated", {"timeout_s": 0.1})
    bus, emu = backend.extras["srf08_bus"], backend.extras["roboteq_emulator"]
    left = (0x70, 0x71, 0x72)  # robchair.backends.DEFAULT_SONAR_ADDRESSES[:3]: sonar_array_left
    bus.ranges = lambda addr, _t: 0.06 if addr in left else math.inf
    bus.groups = [frozenset(left), frozenset((0x73, 0x74, 0x75))]  # the arrays do not hear each other
    res = run_to_dir(backend, PolicySource(lambda o: (0.0, w)), 3.0, None, spec=spec)
    reasons = [s["reason"] for s in res.stops]
    theta = res.poses[-1][3]
    cmds = _speed_commands(emu)
    t0 = cmds[0][0]
    if blocked:
        assert "obstacle_swept" in reasons
        # the first readings arrive within 0.4 s: from then on every speed command is zero
        assert all(rpm == 0 for t, rpm in cmds if t - t0 > 400_000_000)
        assert abs(theta) < 0.02
    else:
        assert "obstacle_swept" not in reasons
        assert theta > 1.0


@pytest.mark.parametrize(
    ("env", "user", "mode", "index"),
    [("random", "switch", "off", 6), ("office", "tremor", "shield", 6)],
)
def test_rebuilt_assist_eval_contact_is_avoided_with_the_swept_check(
    monkeypatch, env, user, mode, index
) -> None:
    # issue 22's `robchair assist-eval` episodes that ended in contact (out6b: switch on random floors,
    # off: the right footrest swung into the doorway's wall turning in place; tremor on the office,
    # shield: the right side brushed the door post on an arc). Rebuilt with the eval's own episode
    # (assist_eval.scenario + evaluation.run_episode): evaluation.drive feeds the swept check the points
    # around the chair (LocalMemory); with that feed taken away the contact comes back
    import robchair.assistance.evaluation as ev
    from robchair.commands.assist_eval import scenario
    from sim.user import preset

    sc = scenario(index, (0.8, 0.9), env)
    spec_ = load_spec()

    def episode():
        return ev.run_episode(sc["world"], spec_, sc["start"], sc["route"], mode, preset(user), seed=index)

    fed = episode()
    assert fed["collisions"] == 0
    assert fed["min_clearance_m"] > 0.0

    def unfed(stamp, **kw):
        kw["obstacles_xy"] = None
        return SafetyInputs(stamp, **kw)

    monkeypatch.setattr(ev, "SafetyInputs", unfed)
    assert episode()["collisions"] == 1  # the eval as it was: the contact


def test_local_memory_keeps_walls_out_of_the_lasers_view() -> None:
    # a return seen ahead is still there, in base_link, after the chair turned its back to it; returns
    # farther than the memory's radius are dropped; placement checked by hand (cell centres, 2.5 cm)
    from robchair.assistance.evaluation import MEMORY_CELL_M, MEMORY_RADIUS_M, LocalMemory

    mem = LocalMemory()
    first = mem.update(np.array([[1.0, 0.0], [0.0, 0.5]]), 2.0, 1.0, 0.0)
    seen = np.array([[1.0125, 0.0125], [0.0125, 0.5125]])
    assert np.allclose(np.sort(first, axis=0), np.sort(seen, axis=0))
    # turned by 180 deg at the same place, nothing in this scan: the two returns now lie behind / right
    now = mem.update(np.zeros((0, 2)), 2.0, 1.0, math.pi)
    assert np.allclose(np.sort(now, axis=0), np.sort(-seen, axis=0))
    # driven away beyond the radius: forgotten, for good
    assert len(mem.update(np.zeros((0, 2)), 2.0 + MEMORY_RADIUS_M + 1.5, 1.0, 0.0)) == 0
    assert len(mem.update(np.zeros((0, 2)), 2.0, 1.0, 0.0)) == 0
    # one point per cell however often it is seen
    for _ in range(3):
        kept = mem.update(np.array([[0.31, 0.31], [0.31 + MEMORY_CELL_M / 4, 0.31]]), 0.0, 0.0, 0.0)
    assert len(kept) == 1


def test_the_coarse_pass_decides_as_the_fine_poses_alone(spec, fp) -> None:
    # sweep_scale sorts the points with coarse poses first; deciding on the fine poses of every point
    # (written out here from swept_distances) must give the same scale for every case
    from robchair.platform.safety import SWEEP_KEEP_TOL_M, SWEEP_SCALES

    layer = _layer(spec)
    lim = layer.limits
    rng = np.random.default_rng(3)
    decided = set()
    for _ in range(150):
        v, w = rng.uniform(-0.6, 0.6), rng.uniform(-2.0, 2.0)
        pts = rng.uniform(-1.0, 1.4, size=(rng.integers(1, 40), 2))
        pts = pts[fp.signed_distance(pts) > 0.0]
        if len(pts) == 0:
            continue
        c0 = float(fp.signed_distance(pts).min())
        want = 0.0
        for k in SWEEP_SCALES:
            d_min, _, bound = swept_distances(pts, k * v, k * w, layer.stopping_time(k * v, k * w), fp)
            if d_min.min() >= min(lim.sweep_margin_m + bound, c0 - SWEEP_KEEP_TOL_M):
                want = k
                break
        assert layer.sweep_scale(v, w, pts)[0] == want
        decided.add(want)
    assert {0.0, 1.0} <= decided and len(decided) >= 3  # the cases stop, limit and pass
