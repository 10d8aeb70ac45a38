"""The simulator measures what real sensors measure (issue 19, item 1): specific force with
gravity and tilt, an attitude estimate with its own error, PX4Flow angular flow with imperfect
gyro compensation, sonars that miss at shallow incidence, four motors behind an attitude-first
mixer."""

from __future__ import annotations

import json
import math
import statistics

import pytest

from inspect_pipe.flight import parse_scenario, run_scenario
from inspect_pipe.flight.flight_log import record_to_json
from inspect_pipe.flight.scenario import Box, Hold, SensorName, World
from inspect_pipe.flight.sensors import AttitudeError, AttitudeSpec, SensorFaults, SensorSuite
from inspect_pipe.flight.vehicle_sim import QuadrotorSim, mix
from inspect_pipe.flight_stack.messages import G_M_S2, ImuReading

WORLD = World(Hold(10.0, 8.0, 8.0))

HOVER = {
    "format": "inspect_pipe.scenario/1",
    "name": "honesty",
    "duration_s": 14,
    "seed": 5,
    "world": {"hold": {"length_m": 10, "width_m": 8, "height_m": 8}},
    "vehicle": {"start": {"position": [4.0, 0, 0]}},
    "operator": [{"t": 0.5, "button": "takeoff"}],
}


def _fly(doc):
    ticks = []
    result = run_scenario(parse_scenario(doc), on_tick=ticks.append)
    return result, ticks


@pytest.fixture(scope="module")
def hover():
    return _fly(HOVER)


def test_imu_reads_specific_force_with_gravity_in_the_body_frame(hover):
    _, ticks = hover
    # GIVEN the vehicle landed before take-off: the accelerometer reads +g up, not zero
    rest = [r.imu for r in ticks if r.t < 0.4 and r.imu is not None]
    assert statistics.fmean(i.fz_m_s2 for i in rest) == pytest.approx(G_M_S2, abs=0.15)
    # AND in flight the specific force turned by the TRUE attitude, less gravity, is the true
    # acceleration (to the noise), whereas turned by the ESTIMATE it is off by about g x error
    flying = [r for r in ticks if r.t > 6.0]
    true_acc, est_acc, att_err = [], [], []
    for prev, r in zip(flying, flying[1:]):
        a_true = (r.vel_true[0] - prev.vel_true[0]) / 0.02
        c, s = math.cos(r.yaw_true), math.sin(r.yaw_true)
        a_true_h = c * a_true + s * (r.vel_true[1] - prev.vel_true[1]) / 0.02
        truth = ImuReading(r.t, r.imu.fx_m_s2, r.imu.fy_m_s2, r.imu.fz_m_s2, None, r.rpy_true[0], r.rpy_true[1])
        true_acc.append(truth.heading_accel()[0] - a_true_h)
        est_acc.append(r.imu.heading_accel()[0] - a_true_h)
        att_err.append(r.imu.pitch_rad - r.rpy_true[1])
    assert abs(statistics.fmean(true_acc)) < 0.06  # the accelerometer's own bias
    expected_from_attitude = G_M_S2 * statistics.fmean(att_err)
    assert statistics.fmean(est_acc) - statistics.fmean(true_acc) == pytest.approx(expected_from_attitude, abs=0.01)


def test_attitude_estimate_is_its_own_quantity_and_hard_manoeuvres_disturb_it(hover):
    _, calm = hover
    err = [r.imu.roll_rad - r.rpy_true[0] for r in calm if r.t > 6.0]
    # THEN the estimate is neither the truth nor far from it
    assert 0.0005 < statistics.fmean(abs(e) for e in err) < 0.03

    # AND a sustained 2 m/s^2 braking (2 s) leaves the filter part of the apparent tilt a/g
    def pitch_error(accel_x: float, pitch_rate: float = 0.0) -> float:
        e = AttitudeError(AttitudeSpec(), seed=3)
        for _ in range(100):
            out = e.advance(0.02, (accel_x, 0.0), (0.0, pitch_rate), 0.1)
        return out[1]

    spec = AttitudeSpec()
    expected = -spec.accel_coupling * 2.0 / G_M_S2 * (1.0 - math.exp(-2.0 / spec.accel_tau_s))
    assert pitch_error(2.0) - pitch_error(0.0) == pytest.approx(expected, rel=0.1)
    # AND a fast rotation leaves the gyro scale error's residue (seed 3: a 0.8 % scale error)
    assert abs(pitch_error(0.0, 2.0) - pitch_error(0.0)) > 0.001


def _still(yaw: float, faults: SensorFaults = SensorFaults(), rates=(0.0, 0.0, 0.0), seconds: float = 2.0):
    sim = QuadrotorSim(WORLD, (7.0, 0.0, 1.0), yaw, seed=1)
    sim.data.qvel[3:6] = rates  # spinning in place: no translation
    suite = SensorSuite(seed=1)
    got = []
    for k in range(int(seconds * 400)):
        sim.t += 1 / 400
        suite.sample(sim, frozenset(), faults)
        if k % 8 == 0:
            got.append(suite.read(sim.t, sim))
    return got


def test_flow_gyro_compensation_leaves_only_its_error():
    # GIVEN the vehicle pitching at 1 rad/s without moving, 1.08 m above the floor
    m = [x.bottom_flow for x in _still(0.0, rates=(0.0, 1.0, 0.0))[50:] if x.bottom_flow and x.bottom_flow.quality]
    vx = statistics.fmean(f.vx_m_s for f in m)
    # THEN uncompensated it would read the rotation times the distance (1 m/s); compensated by a
    # gyro with a 2 % scale error what is left is centimetres, not zero
    assert abs(vx) < 0.1
    assert abs(vx) > 0.001


def test_without_its_sonar_a_px4flow_still_measures_angular_flow():
    # GIVEN every range sensor lost (range_loss) while the vehicle yaws at 0.5 rad/s in place,
    # 1.08 m above the floor and looking at the front wall
    lost = _still(0.0, SensorFaults(range_loss=True), rates=(0.0, 0.0, 0.5))[50:]
    flows = [x.front_flow for x in lost if x.front_flow] + [x.bottom_flow for x in lost if x.bottom_flow]
    # THEN no metric flow (its scale is the lost sonar's range), but the image's quality and the
    # angular flow, gyro compensated, are there: what is left of the rotation is the unit's gyro error
    assert flows and all(not f.scaled and f.vx_m_s == 0.0 for f in flows if hasattr(f, "vx_m_s"))
    assert all(not f.scaled and f.vy_m_s == 0.0 for f in flows if hasattr(f, "vz_m_s"))
    assert statistics.fmean(f.quality for f in flows) > 100
    yaw_flow = statistics.fmean(f.rate_y_rad_s for f in flows if hasattr(f, "vz_m_s"))
    assert abs(yaw_flow) < 0.05  # 0.5 rad/s uncompensated
    # AND with the sonars the same units scale it: metric = angular x range (+ the unit's small bias)
    live = [x.bottom_flow for x in _still(0.0)[50:] if x.bottom_flow and x.bottom_flow.quality]
    assert all(f.scaled for f in live)
    assert statistics.fmean(abs(f.vx_m_s - f.rate_x_rad_s * 1.08) for f in live) < 0.01


def test_flow_quality_falls_on_low_texture():
    good = [x.bottom_flow.quality for x in _still(0.0)[50:] if x.bottom_flow]
    poor = [x.bottom_flow.quality for x in _still(0.0, SensorFaults(low_texture={SensorName.BOTTOM_FLOW: 0.8}))[50:] if x.bottom_flow]
    assert statistics.fmean(good) > 150
    # a quality that wanders about 40: the stack takes such readings (flow_min_quality 1, as PX4's EKF2_OF_QMIN)
    # but weighs them as noisy, near EKF2_OF_N_MAX
    assert 25 < statistics.fmean(poor) < 60


def test_sonar_misses_echoes_at_shallow_incidence():
    # GIVEN the left sonar 4 m from the left wall, head-on, then turned 60 deg away from it
    def missed(yaw):
        r = [x.left_sonar for x in _still(yaw, seconds=6.0) if x.left_sonar is not None]
        return sum(x.range_m is None for x in r) / len(r)

    assert missed(0.0) == 0.0
    # THEN the fan's rays meet the plate 45-75 deg off its normal and most echoes are lost
    assert missed(math.radians(60)) > 0.5


def test_the_downward_sonar_hears_a_box_top_under_its_beams_rim_and_the_laser_does_not():
    # GIVEN the sensors 1.08 m above the floor, beside a 0.3 m box whose edge is 0.1 m to their
    # side (inside the sonar's +-15 deg cone 0.78 m above its top: 0.21 m; beside the laser's ray)
    world = World(Hold(14.0, 10.0, 8.0), boxes=(Box((5.0, 0.1, 0.0), (6.0, 3.0, 0.3)),))
    sim = QuadrotorSim(world, (5.5, 0.0, 1.0), 0.0, seed=1)
    suite = SensorSuite(seed=1)
    got = []
    for _ in range(800):
        sim.t += 1 / 400
        suite.sample(sim, frozenset())
        got.append(suite.read(sim.t, sim))
    sonar = [x.bottom_sonar.range_m for x in got[200:] if x.bottom_sonar and x.bottom_sonar.range_m]
    tof = [x.bottom_tof.range_m for x in got[200:] if x.bottom_tof and x.bottom_tof.range_m]
    # THEN the sonar reports the box top (its first echo: the rim ray's slant to it is 0.81 m) and
    # the TeraRanger the floor (1.08 m); a single downward ray read the floor for both
    assert sonar and max(sonar) < 0.85
    assert tof and min(tof) > 1.0


def test_mixer_keeps_attitude_first_and_a_weak_motor_runs_out_of_authority():
    limit = [3.8] * 4
    # GIVEN a full-thrust demand with a large roll torque: the collective gives way, not the roll
    m = mix(15.0, 0.5, 0.0, 0.0, 0.17, 0.0245, limit)
    assert 0.17 * (m[1] - m[3]) == pytest.approx(0.5, rel=1e-6)
    assert sum(m) < 15.0
    # AND yaw gets only the headroom left
    m = mix(15.0, 0.5, 0.0, 0.2, 0.17, 0.0245, limit)
    assert 0.17 * (m[1] - m[3]) == pytest.approx(0.5, rel=1e-6)
    assert 0.0245 * (m[0] - m[1] + m[2] - m[3]) < 0.2
    # AND a 60 % weak front motor: the vehicle cannot hold its attitude and comes down hard or tilts
    _, weak = _fly({**HOVER, "faults": [{"t": 7, "duration_s": 7, "fault": "weak_motor", "rate": 0.6}]})
    _, ok = _fly(HOVER)

    def worst_tilt(ticks):
        return max(abs(r.rpy_true[1]) for r in ticks if r.t > 7.0)

    assert worst_tilt(weak) > 3 * worst_tilt(ok)


def test_flight_log_has_imu_and_both_attitudes(hover):
    _, ticks = hover
    line = json.loads(json.dumps(record_to_json(ticks[-1])))
    assert set(line["imu"]) == {"ax", "ay", "az"} and line["imu"]["az"] == pytest.approx(G_M_S2, abs=1.0)
    assert set(line["att_est"]) == {"roll", "pitch"} and set(line["att_true"]) == {"roll", "pitch"}
    assert line["att_est"] != line["att_true"]
