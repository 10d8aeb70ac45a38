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


def test_echoes_are_forgotten_after_keep_s_or_travel():
    m = ObstacleMemory(keep_s=3.0, keep_travel_m=1.0)
    m.advance(0.0, 0.0, 0.0, 0.0)
    m.add(0.0, 0.0, 2.0, 0.0)
    assert m.clearance(2.9, 0.0, 0.0) == pytest.approx(2.0)
    assert m.clearance(3.1, 0.0, 0.0) is None
    m.add(3.1, math.pi / 2, 2.0, 0.0)  # a wall on the left
    m.advance(3.1, 0.0, 0.0, 0.0)
    m.advance(4.2, -1.0, 0.0, 0.0)  # 1.1 m backwards, along the wall
    assert m.clearance(4.2, math.pi / 2, 0.0) is None


def test_the_newest_echo_of_a_direction_replaces_the_older():
    m = ObstacleMemory()
    m.advance(0.0, 0.0, 0.0, 0.0)
    m.add(0.0, 0.0, 1.0, 0.0)
    m.add(0.1, 0.0, 3.0, math.radians(3.0))  # same 10-degree bin: the obstacle has gone
    assert m.clearance(0.2, 0.0, 0.0) == pytest.approx(3.0, rel=1e-3)
