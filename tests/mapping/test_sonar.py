"""Sonar detection model (thesis 8.0.1/8.0.2), zone tables, five-zone fusion, servo rule, Fig. 5.7."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mapping import sonar
from mapping.errors import MappingError, SonarModelError

NAN = math.nan


def point_target_readings(range_m: float, bearing_deg: float) -> tuple[float, float, float]:
    """What sonars 1, 2, 3 (axes +30, 0, -30 deg) read for one point target, per the detection model."""
    seen = sonar.in_detection_area(range_m * 100.0, bearing_deg - np.array([30.0, 0.0, -30.0]))
    r1, r2, r3 = (range_m if s else NAN for s in seen)
    return r1, r2, r3


# --- detection model -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("x_cm", "top", "bottom"),
    [
        # by hand: -0.0031*2500 + 1.2082*50 - 14.2762 = 38.3838; 0.25 - 42.415 + 7.7197 = -34.4453
        (50.0, 38.3838, -34.4453),
        # -31 + 120.82 - 14.2762 = 75.5438; 1 - 84.83 + 7.7197 = -76.1103
        (100.0, 75.5438, -76.1103),
        # -1.24 + 24.164 - 14.2762 = 8.6478; 0.04 - 16.966 + 7.7197 = -9.2063
        (20.0, 8.6478, -9.2063),
    ],
)
def test_boundaries_match_thesis_equations_at_sample_points(x_cm, top, bottom):
    assert float(sonar.top_boundary_cm(x_cm)) == pytest.approx(top, abs=1e-9)
    assert float(sonar.bottom_boundary_cm(x_cm)) == pytest.approx(bottom, abs=1e-9)


@pytest.mark.parametrize("d_cm", [15.0, 20.0, 37.5, 50.0, 73.0, 100.0])
def test_half_aperture_bearing_lies_on_the_boundary_curve(d_cm):
    left, right = sonar.half_apertures_deg(d_cm)
    lr, rr = math.radians(float(left)), math.radians(float(right))
    # the beam edge at range d is where the circle of radius d meets the curve
    assert d_cm * math.sin(lr) == pytest.approx(float(sonar.top_boundary_cm(d_cm * math.cos(lr))), abs=1e-9)
    assert -d_cm * math.sin(rr) == pytest.approx(
        float(sonar.bottom_boundary_cm(d_cm * math.cos(rr))), abs=1e-9
    )


def test_a_range_asked_again_gets_the_same_edges_and_a_caller_cannot_change_them():
    """A repeated range (readings come in whole centimetres) returns the boundary-curve edges again
    (the same check as above: the circle meets the curve), whatever the previous caller did to its copy."""
    first_left, first_right = sonar.half_apertures_deg(42.0)
    first_left *= 0.0
    first_right += 90.0
    left, right = sonar.half_apertures_deg(42.0)
    lr, rr = math.radians(float(left)), math.radians(float(right))
    assert 42.0 * math.sin(lr) == pytest.approx(float(sonar.top_boundary_cm(42.0 * math.cos(lr))), abs=1e-9)
    assert -42.0 * math.sin(rr) == pytest.approx(
        float(sonar.bottom_boundary_cm(42.0 * math.cos(rr))), abs=1e-9
    )


def test_half_aperture_at_one_metre_is_bracketed_by_hand_points():
    # at 35 deg the point (81.9, 57.4) is under top(81.9) = 63.9 (inside); at 40 deg (76.6, 64.3) is over
    # top(76.6) = 60.1 (outside). Right side: 36 deg (80.9, -58.8) inside bottom(80.9) = -60.3, 38 deg
    # (78.8, -61.6) outside bottom(78.8) = -58.5.
    left, right = sonar.half_apertures_deg(100.0)
    assert 35.0 < float(left) < 40.0
    assert 36.0 < float(right) < 38.0


def test_under_fifteen_cm_the_widest_model_aperture_is_used():
    left, right = sonar.half_apertures_deg(np.array([3.0, 10.0, 14.9]))
    np.testing.assert_array_equal(left, sonar.WIDE_HALF_APERTURE_DEG[0])
    np.testing.assert_array_equal(right, sonar.WIDE_HALF_APERTURE_DEG[1])
    # the substitute is wider than the regression at 15 cm (the thesis: short range is wider)
    l15, r15 = sonar.half_apertures_deg(15.0)
    assert sonar.WIDE_HALF_APERTURE_DEG[0] > float(l15)
    assert sonar.WIDE_HALF_APERTURE_DEG[1] > float(r15)


@pytest.mark.parametrize("bad", [0.0, -5.0, 100.5, math.inf, math.nan])
def test_half_apertures_refuse_ranges_outside_the_model(bad):
    with pytest.raises(SonarModelError, match="range_cm"):
        sonar.half_apertures_deg(bad)


def test_in_detection_area_is_false_over_one_metre_and_true_on_axis():
    assert bool(sonar.in_detection_area(50.0, 0.0))
    assert bool(sonar.in_detection_area(100.0, 0.0))
    assert not bool(sonar.in_detection_area(101.0, 0.0))
    assert not bool(sonar.in_detection_area(50.0, 60.0))
    left, _ = sonar.half_apertures_deg(50.0)
    assert bool(sonar.in_detection_area(50.0, float(left) - 1e-6))
    assert not bool(sonar.in_detection_area(50.0, float(left) + 1e-6))


# --- zone tables -----------------------------------------------------------------------------------


def test_zone_tables_at_half_a_metre_follow_the_overlap_formulas():
    t = sonar.default_zone_tables()
    L, R = (float(v) for v in sonar.half_apertures_deg(50.0))
    np.testing.assert_allclose(t.alpha_deg[:, 50], [L, L - 30, 30 - R, -R, -30 - R], atol=1e-12)
    np.testing.assert_allclose(t.theta_deg[:, 50], [30, 30, L + R - 60, 30, 30], atol=1e-12)


def test_zones_tile_the_array_coverage_without_gaps_beyond_31_cm():
    t = sonar.default_zone_tables()
    for d in range(32, 101):
        a, th = t.alpha_deg[:, d], t.theta_deg[:, d]
        # zone 5 | 4 | 3 | 2 | 1 from right to left, each starting where the previous ends
        for k in range(4, 0, -1):
            assert a[k] + th[k] == pytest.approx(a[k - 1], abs=1e-9)
        L, R = (float(v) for v in sonar.half_apertures_deg(float(d)))
        assert a[4] == pytest.approx(-30 - R)
        assert a[0] + th[0] == pytest.approx(30 + L)
        assert th[2] == min(th)  # zone 3 is the smallest (thesis 5.2)


def test_zone_three_is_empty_where_the_beams_are_narrower_than_sixty_degrees():
    t = sonar.default_zone_tables()
    assert np.all(t.theta_deg[2, 15:32] == 0.0)
    assert np.all(t.theta_deg[2, 32:] > 0.0)


def test_zone_table_lookup_rounds_to_the_centimetre_and_validates():
    t = sonar.default_zone_tables()
    assert t.lookup(2, 0.504) == (t.alpha_deg[1, 50], t.theta_deg[1, 50])
    with pytest.raises(SonarModelError, match="zone=6"):
        t.lookup(6, 0.5)
    with pytest.raises(SonarModelError, match=r"range_m=1\.2"):
        t.lookup(3, 1.2)


# --- fusion ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("readings", "zone", "d"),
    [
        ((0.50, 0.80, NAN), 1, 0.50),  # only sonar 1 at the minimum
        ((0.50, 0.51, 0.90), 2, 0.50),  # 1 and 2 within 3 cm, 3 not
        ((0.50, 0.52, 0.49), 3, 0.49),  # all three within 3 cm of the smallest
        ((NAN, 0.60, 0.61), 4, 0.60),  # 2 and 3
        ((0.90, 0.70, 0.40), 5, 0.40),  # only sonar 3
        ((1.50, 0.50, 0.51), 4, 0.50),  # the 1.5 m reading is rejected, not used
    ],
)
def test_fusion_picks_the_zone_of_the_agreeing_sonars(readings, zone, d):
    res = sonar.fuse_array(*readings, threshold_m=0.03)
    assert res.zone == zone
    assert res.distance_m == d
    t = sonar.default_zone_tables()
    assert (res.alpha_deg, res.theta_deg) == t.lookup(zone, d)
    assert res.consistent


def test_fusion_reports_missing_and_rejected_readings():
    res = sonar.fuse_array(1.2, NAN, 0.0)
    assert res.zone is None
    assert math.isnan(res.distance_m)
    assert res.rejected == (True, False, False)
    assert res.missing == (False, True, True)
    assert not res.has_obstacle
    assert sonar.fusion_points(res).shape == (0, 3)


def test_sonar_two_alone_is_no_zone_but_keeps_the_obstacle_in_its_beam():
    res = sonar.fuse_array(0.80, 0.50, 0.80)
    L, R = (float(v) for v in sonar.half_apertures_deg(50.0))
    assert res.zone is None
    assert res.distance_m == 0.50
    assert not res.consistent
    assert res.alpha_deg == pytest.approx(-R)
    assert res.theta_deg == pytest.approx(L + R)


def test_outer_sonars_agreeing_without_the_middle_one_keep_both_outer_beams():
    res = sonar.fuse_array(0.50, 0.80, 0.50)  # e.g. two posts, one in each outer beam
    L, R = (float(v) for v in sonar.half_apertures_deg(50.0))
    assert res.zone is None and res.agreeing == (True, False, True)
    assert res.alpha_deg == pytest.approx(-30 - R)
    assert res.theta_deg == pytest.approx(60 + L + R)


def test_zone_three_where_it_is_geometrically_empty_falls_back_to_the_whole_coverage():
    res = sonar.fuse_array(0.20, 0.20, 0.20)
    L, R = (float(v) for v in sonar.half_apertures_deg(20.0))
    assert res.zone == 3
    assert not res.consistent
    assert res.alpha_deg == pytest.approx(-30 - R)
    assert res.theta_deg == pytest.approx(60 + L + R)


def test_fusion_refuses_negative_readings_and_bad_thresholds():
    with pytest.raises(SonarModelError, match="r2_m"):
        sonar.fuse_array(0.5, -0.1, 0.5)
    with pytest.raises(MappingError, match="threshold_m"):
        sonar.fuse_array(0.5, 0.5, 0.5, threshold_m=-1.0)


@settings(max_examples=150, deadline=None)
@given(d_cm=st.integers(32, 100), u=st.floats(1e-6, 1.0 - 1e-6))  # exact outer edges: float round-off
def test_a_point_target_lands_inside_the_fused_zone_interval(d_cm, u):
    L, R = (float(v) for v in sonar.half_apertures_deg(float(d_cm)))
    bearing = -30 - R + u * (60 + L + R)
    res = sonar.fuse_array(*point_target_readings(d_cm / 100.0, bearing))
    assert res.zone in (1, 2, 3, 4, 5)
    assert res.consistent
    assert res.alpha_deg - 1e-9 <= bearing <= res.alpha_deg + res.theta_deg + 1e-9


# --- the cylinder case -----------------------------------------------------------------------------


def test_inside_a_cylinder_zone_three_is_chosen_as_the_thesis_warns():
    # every sonar sees the wall at the radius: one reading cannot tell this from a target in zone 3
    res = sonar.fuse_array(0.60, 0.60, 0.60)
    assert res.zone == 3
    assert res.consistent
    assert not res.cylinder_suspected
    assert res.theta_deg == pytest.approx(sonar.default_zone_tables().theta_deg[2, 60])


def test_cylinder_check_flags_zone_three_that_survives_a_wide_sweep():
    check = sonar.CylinderCheck(threshold_m=0.03)
    theta3 = sonar.default_zone_tables().theta_deg[2, 60]  # ~11.6 deg
    flagged = []
    for heading in np.arange(80.0, 102.0, 2.0):  # inside the cylinder the readings never change
        out = check.update(sonar.fuse_array(0.60, 0.60, 0.60), float(heading))
        assert out.zone == 3
        flagged.append(out.cylinder_suspected)
        span = heading - 80.0
        assert out.cylinder_suspected == (span > theta3 + check.margin_deg)
    assert flagged[-1]
    L, R = (float(v) for v in sonar.half_apertures_deg(60.0))
    assert out.alpha_deg == pytest.approx(-30 - R)  # all five zones considered
    assert out.theta_deg == pytest.approx(60 + L + R)


def test_cylinder_check_never_flags_a_single_target_during_the_same_sweep():
    check = sonar.CylinderCheck(threshold_m=0.03)
    zones = []
    for heading in np.arange(80.0, 102.0, 2.0):
        target_bearing = 90.0 - heading  # a post straight ahead of servo angle 90
        res = check.update(sonar.fuse_array(*point_target_readings(0.60, target_bearing)), float(heading))
        zones.append(res.zone)
        assert not res.cylinder_suspected
    assert 3 in zones and set(zones) - {3}  # the target left zone 3 while the array turned


# --- servo rule ------------------------------------------------------------------------------------


def test_servo_rule_brings_a_zone_one_target_into_zone_three():
    servo = 90.0
    world_bearing = 140.0  # target 50 deg to the left of the array, 0.5 m away
    res = sonar.fuse_array(*point_target_readings(0.5, world_bearing - servo))
    assert res.zone == 1
    servo = sonar.servo_command_deg(res, servo)
    assert servo == pytest.approx(90.0 + res.alpha_deg + 15.0)
    res2 = sonar.fuse_array(*point_target_readings(0.5, world_bearing - servo))
    assert res2.zone == 3


def test_servo_rule_clamps_to_travel_limits_and_holds_without_obstacle():
    res = sonar.fuse_array(0.5, NAN, NAN)  # zone 1: bearing ~ +51 deg
    assert sonar.servo_command_deg(res, 170.0) == 180.0
    assert sonar.servo_command_deg(res, 90.0, max_step_deg=5.0) == 95.0
    assert sonar.servo_command_deg(sonar.fuse_array(NAN, NAN, NAN), 42.0) == 42.0


# --- Fig. 5.7 --------------------------------------------------------------------------------------


def test_cone_points_match_a_hand_computed_two_degree_zone():
    # theta = 2, alpha = 0, d = 1, ppc = 4: one ring (i = 0) at 1 deg from an axis at bearing 1 deg
    p = sonar.cone_points(1.0, 2.0, 0.0, ppc=4)
    c1, s1 = math.cos(math.radians(1)), math.sin(math.radians(1))
    expected = np.array(
        [
            [c1 * c1, s1 * c1, s1],  # j=0: straight up the ring
            [math.cos(math.radians(2)), math.sin(math.radians(2)), 0.0],  # j=1: left edge = alpha+theta
            [c1 * c1, s1 * c1, -s1],  # j=2: down
            [1.0, 0.0, 0.0],  # j=3: right edge = alpha
        ]
    )
    np.testing.assert_allclose(p, expected, atol=1e-12)


@pytest.mark.parametrize(("d", "theta", "alpha", "ppc"), [(0.5, 9.5, -3.4, 40), (0.8, 30.0, 36.0, 12)])
def test_cone_points_lie_at_distance_d_and_within_each_ring_aperture(d, theta, alpha, ppc):
    p = sonar.cone_points(d, theta, alpha, ppc)
    n_rings = math.ceil(theta / 2)
    assert p.shape == (n_rings * ppc, 3)
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), d, rtol=1e-12)
    rings = p.reshape(n_rings, ppc, 3)
    for i in range(n_rings):
        gamma = math.radians(alpha + theta / 2 - i)
        axis = np.array([math.cos(gamma), math.sin(gamma), 0.0])
        ang = np.degrees(np.arccos(np.clip(rings[i] @ axis / d, -1, 1)))
        np.testing.assert_allclose(ang, theta / 2 + i, atol=1e-9)
    # ring 0 spans exactly the zone [alpha, alpha + theta] in the horizontal plane
    az0 = np.degrees(np.arctan2(rings[0, :, 1], rings[0, :, 0]))
    assert az0.min() >= alpha - 1e-9 and az0.max() <= alpha + theta + 1e-9
    # whole cloud, as printed: within theta/2 + 2 i_max of the zone centre
    centre = math.radians(alpha + theta / 2)
    c = np.array([math.cos(centre), math.sin(centre), 0.0])
    ang_all = np.degrees(np.arccos(np.clip(p @ c / d, -1, 1)))
    assert ang_all.max() <= theta / 2 + 2 * (n_rings - 1) + 1e-9


def test_cone_points_validate_arguments():
    with pytest.raises(SonarModelError, match="ppc"):
        sonar.cone_points(1.0, 10.0, 0.0, ppc=0)
    with pytest.raises(SonarModelError, match="range_m"):
        sonar.cone_points(math.nan, 10.0, 0.0)
    assert sonar.cone_points(1.0, 0.0, 0.0).shape == (0, 3)


def test_array_points_give_a_finite_cloud_for_the_fused_zone():
    res, pts = sonar.array_points((0.5, 0.51, 0.9), ppc=40)
    assert res.zone == 2
    assert pts.shape == (15 * 40, 3)
    assert np.isfinite(pts).all()
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), 0.5)


def test_a_fused_sonar_cloud_goes_through_the_vhv_core_like_any_cloud():
    from mapping.grid import GridSpec
    from mapping.vhv import VHVMap

    res, pts = sonar.array_points((0.50, 0.50, 0.50), ppc=40)
    assert res.zone == 3  # straight ahead
    m = VHVMap(GridSpec(cell_size=0.05, size_x=2.0, size_y=2.0, centre=(0.0, 0.0)), tolerance=0.05)
    stats = m.insert(pts, sensor_origin=(0.0, 0.0, 0.0))
    assert stats.points_inserted == len(pts) == 5 * 40
    ahead = m.structures_at(0.48, 0.01)  # the cell just inside 0.5 m (all points are at 0.5 m)
    assert len(ahead) >= 1
    assert ahead.bottom.min() < 0.0 < ahead.top.max()  # the ring straddles the sonar's height
    s = m.structures()
    x, _ = m.spec.index_to_world(s.i, s.j)
    assert np.all(np.abs(x) <= 0.5 + 0.05)  # nothing placed beyond the measured range


def test_fusion_points_of_a_cone_met_again_are_the_points_cone_points_builds():
    res, pts = sonar.array_points((0.5, 0.51, 0.9), ppc=40)
    again = sonar.fusion_points(res, ppc=40)
    ref = sonar.cone_points(res.distance_m, res.theta_deg, res.alpha_deg, 40)
    assert again is pts  # built once per distinct cone
    assert np.array_equal(again, ref)
    assert not again.flags.writeable  # shared: a caller cannot change what the next one gets
    other = sonar.fusion_points(res, ppc=10)
    assert np.array_equal(other, sonar.cone_points(res.distance_m, res.theta_deg, res.alpha_deg, 10))
