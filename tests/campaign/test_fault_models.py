"""Simulator fault models added for the campaign: each does what the scenario format says, and a
bad fault is refused naming the field."""

from __future__ import annotations

import math

import pytest

from inspect_pipe.errors import InputError
from inspect_pipe.flight import parse_scenario
from inspect_pipe.flight.scenario import Hold, SensorName, World
from inspect_pipe.flight.sensors import SensorFaults, SensorSuite
from inspect_pipe.flight.vehicle_sim import QuadrotorSim

WORLD = World(Hold(10.0, 8.0, 8.0))


def _readings(yaw: float, faults: SensorFaults, seconds: float = 2.0):
    sim = QuadrotorSim(WORLD, (7.0, 0.0, 1.0), yaw, seed=1)
    suite = SensorSuite(seed=1)
    got = []
    for k in range(int(seconds * 400)):
        sim.t += 1 / 400  # the vehicle stays put: sensors only
        suite.sample(sim, frozenset(), faults)
        if k % 8 == 0:
            got.append(suite.read(sim.t, sim))
    return got


def test_spurious_max_range_only_at_grazing_incidence():
    f = SensorFaults(spurious_max_range={SensorName.FRONT_FLOW: 1.0})
    square = {m.front_sonar.range_m for m in _readings(0.0, f) if m.front_sonar}
    assert max(square) < 3.1  # 3 m ahead, head-on: true echoes
    oblique = {m.front_sonar.range_m for m in _readings(math.radians(50), f) if m.front_sonar}
    assert oblique == {5.0}


def test_stuck_range_loss_flow_quality_and_packet_loss():
    stuck = _readings(0.0, SensorFaults(stuck=frozenset({SensorName.LEFT_SONAR})))
    assert len({m.left_sonar.range_m for m in stuck if m.left_sonar}) == 1
    assert len({m.left_sonar.stamp_s for m in stuck if m.left_sonar}) > 5  # freshly stamped
    lost = _readings(0.0, SensorFaults(range_loss=True))
    assert all(m.front_sonar is None and m.bottom_tof is None for m in lost)
    q = _readings(0.0, SensorFaults(flow_quality_zero=frozenset({SensorName.BOTTOM_FLOW})))
    assert {m.bottom_flow.quality for m in q if m.bottom_flow} == {0}
    half = _readings(0.0, SensorFaults(packet_loss={SensorName.BOTTOM_TOF: 0.5}), seconds=4.0)
    stamps = {m.bottom_tof.stamp_s for m in half if m.bottom_tof}
    assert 120 < len(stamps) < 280  # about half of 400 samples


BASE = {
    "format": "inspect_pipe.scenario/1", "name": "f", "duration_s": 12, "seed": 2,
    "world": {"hold": {"length_m": 12, "width_m": 10, "height_m": 8}},
    "vehicle": {"start": {"position": [4.0, 0, 0]}},
    "operator": [{"t": 0.5, "button": "takeoff"}],
}


@pytest.mark.parametrize("fault, field", [
    ({"t": 1, "duration_s": 1, "fault": "packet_loss", "sensor": "left_sonar"}, "faults[0].rate"),
    ({"t": 1, "duration_s": 1, "fault": "gust"}, "faults[0].wind_m_s"),
    ({"t": 1, "duration_s": 1, "fault": "flow_quality_zero", "sensor": "left_sonar"}, "faults[0].sensor"),
    ({"t": 1, "duration_s": 1, "fault": "range_loss", "sensor": "left_sonar"}, "faults[0].sensor"),
    ({"t": 1, "duration_s": 1, "fault": "battery_sag", "rate": 1.5}, "faults[0].rate"),
])
def test_bad_faults_are_refused(fault, field):
    with pytest.raises(InputError, match=field.replace("[", r"\[").replace("]", r"\]")):
        parse_scenario({**BASE, "faults": [fault]})


def test_gust_pushes_and_mass_error_acts():
    from inspect_pipe.flight import run_scenario

    from inspect_pipe.flight_stack.params import ControlParams, StackParams

    def drift(doc, params=None):
        pos = []
        run_scenario(parse_scenario(doc), params=params, on_tick=lambda r: pos.append(r.pos_true))
        return max(p[0] for p in pos)

    gust = {**BASE, "faults": [{"t": 5, "duration_s": 3, "fault": "gust", "wind_m_s": [2.0, 0, 0]}]}
    # With the wind-rejecting disturbance observer off, the gust moves the vehicle downwind
    no_observer = StackParams(control=ControlParams(accel_observer_xy_limit_m_s2=0.0))
    pushed = drift(gust, no_observer) - drift(BASE, no_observer)
    assert pushed > 0.05
    # AND with it on (the default), the vehicle gives way less than half as far
    assert drift(gust) - drift(BASE) < 0.5 * pushed


def _thrust_and_height(doc):
    from inspect_pipe.flight import run_scenario

    rows = []
    run_scenario(parse_scenario(doc), on_tick=lambda r: rows.append((r.t, r.out.setpoint.thrust_frac, r.pos_true[2])))
    late = [r for r in rows if r[0] >= rows[-1][0] - 2.0]
    return sum(r[1] for r in late) / len(late), rows[-1][2]


@pytest.mark.parametrize("key, value", [("mass_scale", 1.2), ("mass_scale", 1.3), ("thrust_scale", 0.7), ("mass_scale", 0.7)])
def test_mass_or_thrust_error_reaches_the_physics_and_the_height_loop_finds_the_trim(key, value):
    # GIVEN a vehicle heavier or weaker than the stack's nominal hover thrust assumes
    thrust0, z0 = _thrust_and_height({**BASE, "duration_s": 20})
    thrust, z = _thrust_and_height({**BASE, "duration_s": 20, "vehicle": {"start": {"position": [4.0, 0, 0]}, key: value}})
    # THEN the model error reaches the physics: hovering takes correspondingly more thrust
    ratio = value if key == "mass_scale" else 1.0 / value
    assert thrust / thrust0 == pytest.approx(ratio, rel=0.05)
    # AND the height loop finds that trim and holds the take-off height (it used to settle
    # 0.2-0.9 m low, or stay on the floor: the trim was capped at 2 m/s^2 and frozen on the ground)
    assert z == pytest.approx(z0, abs=0.1)


@pytest.mark.parametrize("key, value", [("mass_scale", 1.2), ("mass_scale", 1.3), ("thrust_scale", 0.7)])
def test_a_heavy_or_weak_vehicle_does_not_overshoot_the_hover_height_after_take_off(key, value):
    from inspect_pipe.flight import run_scenario

    # GIVEN a vehicle that does not lift at the nominal hover thrust: the take-off's ramp finds
    # the missing trim in the vertical integrator while it sits on the floor
    heights = []
    doc = {**BASE, "duration_s": 20, "vehicle": {"start": {"position": [4.0, 0, 0]}, key: value}}
    run_scenario(parse_scenario(doc), on_tick=lambda r: heights.append(r.pos_true[2]))
    # THEN the 1 m hover after take-off is reached without climbing past it by more than 0.1 m:
    # the trim is handed to the vertical disturbance observer as the take-off ends, not counted
    # twice (counted twice: 1.36, 1.66 and 2.26 m)
    assert max(heights) < 1.1
    assert heights[-1] == pytest.approx(1.0, abs=0.1)


def test_a_climb_asked_for_before_a_slow_take_off_reaches_its_hover_height_starts_from_that_height():
    from inspect_pipe.flight import run_scenario

    # GIVEN a vehicle 30 % heavier than nominal, slow to take off, and an operator who climbs at
    # 0.4 m/s for 1.3 s, 3.5 s after pressing take-off (meant: 0.52 m above the 1 m hover height),
    # while the take-off has not yet reached the hover height
    heights = []
    doc = {**BASE, "duration_s": 14, "vehicle": {"start": {"position": [4.0, 0, 0]}, "mass_scale": 1.3},
           "operator": [{"t": 0.5, "button": "takeoff"}, {"t": 4.0, "stick": {"vz": 0.4}}, {"t": 5.3, "stick": {"vz": 0.0}}]}
    run_scenario(parse_scenario(doc), on_tick=lambda r: heights.append((r.t, r.pos_true[2], r.out.fsm.name)))
    at_climb = next(z for t, z, _ in heights if t >= 4.1)
    assert at_climb < 0.9  # the take-off was still under way when the climb began
    # THEN the vehicle settles about 1.5 m up: the climb is added to the hover height, not spent
    # getting there (kept as a floor only: 1.15 m)
    final = heights[-1][1]
    assert final == pytest.approx(1.52, abs=0.12)
    assert max(z for _, z, _ in heights) < final + 0.15


@pytest.mark.parametrize("climb_s, above_m", [(0.0, 0.0), (0.5, 0.2)])
def test_after_an_alarm_descent_the_height_held_before_it_is_resumed_and_a_climb_during_it_added(climb_s, above_m):
    from inspect_pipe.flight import run_scenario

    # GIVEN a vehicle holding about 1.6 m when every range sensor is lost for 4 s (mode -2: the
    # alarm descent takes it down about 0.7 m), and an operator who, once the sensors are back,
    # climbs at 0.4 m/s for ``climb_s`` while the vehicle is still climbing back
    ops = [{"t": 0.5, "button": "takeoff"}, {"t": 5.0, "stick": {"vz": 0.4}}, {"t": 6.5, "stick": {"vz": 0.0}}]
    if climb_s:
        ops += [{"t": 13.5, "stick": {"vz": 0.4}}, {"t": 13.5 + climb_s, "stick": {"vz": 0.0}}]
    doc = {**BASE, "duration_s": 24, "operator": ops, "faults": [{"t": 9.0, "fault": "range_loss", "duration_s": 4.0}]}
    rows = []
    run_scenario(parse_scenario(doc), on_tick=lambda r: rows.append((r.t, r.pos_true[2])))
    before = [z for t, z in rows if 8.5 <= t <= 9.0]
    held = sum(before) / len(before)
    assert min(z for t, z in rows if 9.0 <= t <= 13.5) < held - 0.5  # the alarm descent happened
    # THEN it settles at the height held before the alarm, plus the operator's climb (0.4 m/s x
    # climb_s): the climb starts from the resumed height, not from where the descent ended
    assert rows[-1][1] == pytest.approx(held + above_m, abs=0.1)
