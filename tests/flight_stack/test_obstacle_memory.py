"""The obstacle memory: a wall heard face-on keeps its perpendicular distance while the vehicle
yaws and moves; old or far-travelled echoes are forgotten."""

from __future__ import annotations

import math

import pytest

from inspect_pipe.flight_stack.obstacle_memory import ObstacleMemory


def test_wall_heard_face_on_keeps_its_perpendicular_distance_while_yawing_and_moving():
    m = ObstacleMemory(keep_s=8.0, keep_travel_m=2.0, max_angle_deg=60.0)
    m.advance(0.0, 0.0, 0.0, 0.0)
    m.add(0.0, 0.0, 1.2, 0.0)  # front echo, face-on, 1.2 m
    yaw = math.radians(40.0)
    # the front sonar now hears the same wall obliquely, farther than 1.2 m; the memory says 1.2
    assert m.clearance(0.5, 0.0, yaw) == pytest.approx(1.2)
    # 1 s forward at 0.2 m/s along the yawed body x: 0.2 * cos(40 deg) closer to the wall
    m.advance(0.5, 0.0, 0.0, yaw)  # at rest until 0.5 s
    m.advance(1.5, 0.2, 0.0, yaw)
    assert m.clearance(1.5, 0.0, yaw) == pytest.approx(1.2 - 0.2 * math.cos(yaw), abs=1e-9)
    # the left axis (130 deg) does not face the wall; the right one (-50 deg) does
    assert m.clearance(1.5, math.pi / 2, yaw) is None
    assert m.clearance(1.5, -math.pi / 2, yaw) == pytest.approx(1.2 - 0.2 * math.cos(yaw), abs=1e-9)


def test_echoes_are_forgotten_after_keep_s_unmeasured_travel_or_a_change_of_altitude():
    m = ObstacleMemory(keep_s=3.0, keep_travel_m=1.0, body_radius_m=0.27)
    m.advance(0.0, 0.0, 0.0, 0.0, altitude_m=1.5)
    m.add(0.0, 0.0, 2.0, 0.0)
    # GIVEN a measured hover: the echo stays however long (a fixed 8 s forgot a corner pillar
    # heard while hovering before the sweep slid past it: campaign seed 173)
    m.advance(30.0, 0.0, 0.0, 0.0, altitude_m=1.5)
    assert m.clearance(30.0, 0.0, 0.0) == pytest.approx(2.0)
    # WHEN the speed is no longer measured (an alarm mode): it goes after keep_s of that
    m.advance(32.9, 0.0, 0.0, 0.0, altitude_m=1.5, measured=False)
    assert m.clearance(32.9, 0.0, 0.0) == pytest.approx(2.0)
    m.advance(33.1, 0.0, 0.0, 0.0, altitude_m=1.5, measured=False)
    assert m.clearance(33.1, 0.0, 0.0) is None
    # AND a wall on the left goes after keep_travel_m of travel along it
    m.add(33.1, math.pi / 2, 2.0, 0.0)
    m.advance(34.2, -1.0, 0.0, 0.0, altitude_m=1.5)  # 1.1 m backwards, along the wall
    assert m.clearance(34.2, math.pi / 2, 0.0) is None
    # AND a surface heard at 1.5 m is kept within the vehicle's half-size up or down, not beyond
    m.add(34.2, 0.0, 1.2, 0.0)
    m.advance(35.0, 0.0, 0.0, 0.0, altitude_m=1.75)
    assert m.clearance(35.0, 0.0, 0.0) == pytest.approx(1.2)
    m.advance(36.0, 0.0, 0.0, 0.0, altitude_m=1.8)
    assert m.clearance(36.0, 0.0, 0.0) is None


def test_the_newest_echo_of_a_direction_replaces_the_older():
    m = ObstacleMemory()
    m.advance(0.0, 0.0, 0.0, 0.0)
    m.add(0.0, 0.0, 1.0, 0.0)
    m.add(0.1, 0.0, 3.0, math.radians(3.0))  # same 10-degree bin: the obstacle has gone
    assert m.clearance(0.2, 0.0, 0.0) == pytest.approx(3.0, rel=1e-3)


def test_oblique_wall_from_two_sonars_recovers_the_perpendicular_distance():
    from inspect_pipe.flight_stack.obstacle_memory import oblique_wall

    h = math.radians(15.0)
    # GIVEN a wall 0.86 m away whose normal is 49 deg from the front axis (yawed at it): each
    # beam's nearest echo is at (angle - 15 deg) off the normal
    d, phi = 0.86, math.radians(49.0)
    r_front, r_left = d / math.cos(phi - h), d / math.cos(math.pi / 2 - phi - h)
    assert min(r_front, r_left) > 0.95  # either sonar alone says "outside the 1 m line"
    # THEN the fit finds the wall's normal and its perpendicular distance
    got = oblique_wall(r_front, r_left, h)
    assert got is not None
    assert got[0] == pytest.approx(phi) and got[1] == pytest.approx(d)
    # AND an inside corner (walls face-on at 1.0 m and 1.1 m) gives a wall across it, nearer
    # than both: the safe side of the ambiguity
    corner = oblique_wall(1.0, 1.1, h)
    assert corner is not None and corner[1] < 1.0
    # AND readings no single wall can explain (a far front, a near side) give nothing
    assert oblique_wall(5.0, 1.0, h) is None and oblique_wall(1.0, 5.0, h) is None


def test_an_inferred_surface_is_kept_only_as_long_as_asked():
    m = ObstacleMemory(keep_s=8.0, keep_travel_m=2.0)
    m.advance(0.0, 0.0, 0.0, 0.0)
    m.add(0.0, 0.0, 1.5, 0.0)  # heard: kept 8 s
    m.add(0.0, math.pi / 2, 1.2, 0.0, keep_s=1.0)  # inferred: kept 1 s
    assert m.clearance(0.9, math.pi / 2, 0.0) == pytest.approx(1.2)
    assert m.clearance(1.1, math.pi / 2, 0.0) is None
    assert m.clearance(1.1, 0.0, 0.0) == pytest.approx(1.5)


def test_a_surface_that_leaves_the_beams_edge_is_kept_until_the_vehicle_moves_sideways_of_it():
    # GIVEN a box heard 1.03 m ahead (seed 61 e338), a +-15 deg beam and a 0.27 m vehicle half-size
    m = ObstacleMemory(keep_s=8.0, keep_travel_m=2.0, jump_m=0.15, beam_half_rad=math.radians(15.0), body_radius_m=0.27)
    m.advance(0.0, 0.0, 0.0, 0.0)
    m.add(0.0, 0.0, 1.03, 0.0)
    # WHEN a drift of 3 cm sideways lets the far wall, 2.45 m ahead, into the beam instead
    m.advance(1.0, 0.0, 0.03, 0.0)
    m.add(1.0, 0.0, 2.45, 0.0)
    # THEN the box is still ahead
    assert m.clearance(1.0, 0.0, 0.0) == pytest.approx(1.03)
    # AND an echo nearer than it, or farther by less than the jump, replaces it as before
    m.add(1.1, 0.0, 1.10, 0.0)
    assert m.clearance(1.1, 0.0, 0.0) == pytest.approx(1.10)
    # AND once the vehicle has moved sideways by the beam's half-width there plus its half-size, the far echo counts
    release = 1.10 * math.sin(math.radians(15.0)) + 0.27
    m.advance(2.0, 0.0, 0.0, 0.0)
    m.advance(3.0, 0.0, release + 0.01, 0.0)
    m.add(3.0, 0.0, 2.45, 0.0)
    assert m.clearance(3.0, 0.0, 0.0) == pytest.approx(2.45)
    # AND a kept surface still goes after keep_s without a measured speed, and the next echo takes its place
    m.add(3.1, 0.0, 1.0, 0.0)
    m.advance(11.0, 0.0, 0.0, 0.0, measured=False)
    m.add(11.0, 0.0, 2.45, 0.0)
    assert m.clearance(11.0, 0.0, 0.0) == pytest.approx(1.0)
    m.advance(11.2, 0.0, 0.0, 0.0, measured=False)
    assert m.clearance(11.2, 0.0, 0.0) is None
    m.add(11.2, 0.0, 2.45, 0.0)
    assert m.clearance(11.2, 0.0, 0.0) == pytest.approx(2.45)


def test_without_the_beam_and_size_the_newest_echo_of_a_bin_wins():
    m = ObstacleMemory(keep_s=8.0, keep_travel_m=2.0)
    m.advance(0.0, 0.0, 0.0, 0.0)
    m.add(0.0, 0.0, 1.03, 0.0)
    m.add(0.5, 0.0, 2.45, 0.0)
    assert m.clearance(0.5, 0.0, 0.0) == pytest.approx(2.45)
