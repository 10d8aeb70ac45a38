"""The campaign's metric definitions on scripted ground truth (no flight): overshoot against
lateral entries, link-loss braking against hover drift, and goals that cannot be judged."""

from __future__ import annotations

from inspect_pipe.campaign.generator import EpisodeSpec
from inspect_pipe.campaign.metrics import EpisodeMonitor
from inspect_pipe.campaign.run import _goals
from inspect_pipe.flight.geometry import Clearances
from inspect_pipe.flight.runner import TickRecord
from inspect_pipe.flight_stack.flight_machine import FlightState
from inspect_pipe.flight_stack.messages import AttitudeSetpoint, Clearance, EstimationMode, SpeedCommand, StateEstimate
from inspect_pipe.flight_stack.onboard import TickOutput

DT = 0.02


def _spec(faults=()) -> EpisodeSpec:
    doc = {
        "format": "inspect_pipe.scenario/1", "name": "scripted", "duration_s": 30, "seed": 1,
        "world": {"hold": {"length_m": 20, "width_m": 10, "height_m": 8}},
        "vehicle": {"start": {"position": [5.0, 0.0, 0]}},
        "operator": [{"t": 0.5, "button": "takeoff"}],
        "faults": list(faults),
    }
    return EpisodeSpec(0, 1, "wall_push", doc, ("clean",))


def _tick(t, *, x=5.0, y=0.0, vx=0.0, front=5.0, left=5.0, right=5.0, cmd=(0.0, 0.0), stick=(0.0, 0.0), link=True):
    est = StateEstimate(1.5, 1.5, vx, 0.0, 0.0, EstimationMode.BOTTOM_FRONT)
    out = TickOutput(
        setpoint=AttitudeSetpoint(), estimate=est, clearance=Clearance(),
        user_cmd=SpeedCommand(*stick), command=SpeedCommand(*cmd), behaviors=(),
        fsm=FlightState.FLYING, inspection_mode=False,
    )
    return TickRecord(
        t=t, pos_true=(x, y, 1.5), vel_true=(vx, 0.0, 0.0), yaw_true=0.0, out=out,
        dist_true=Clearances(front, 5.0, left, right, 1.5), battery_percent=90.0, link_ok=link, collided=False,
    )


def _monitor(spec: EpisodeSpec) -> EpisodeMonitor:
    return EpisodeMonitor(spec, spec.scenario(), "ours")


def test_a_surface_met_inside_the_line_is_a_lateral_entry_not_an_overshoot():
    m = _monitor(_spec())
    # GIVEN the vehicle sliding along +y past the end of a box: the distance to its right jumps
    # from 3 m to 0.85 m in one tick (the box's face comes into line), then it drifts 0.05 m closer
    dists = [3.0] * 10 + [0.85] * 10 + [0.80] * 10
    for k, d in enumerate(dists):
        m(_tick(1.0 + k * DT, right=d))
    r = m.finish(0.0)
    # THEN only the 0.05 m it closed beyond where the face appeared is overshoot
    assert abs(r.overshoot_m - 0.05) < 1e-9
    assert abs(r.lateral_entry_m - 0.15) < 1e-9


def test_an_approach_past_the_line_is_an_overshoot():
    m = _monitor(_spec())
    # GIVEN an approach that closes 2 cm per tick from 1.3 m down to 0.86 m
    for k in range(23):
        m(_tick(1.0 + k * DT, front=1.3 - 0.02 * k))
    r = m.finish(0.0)
    assert abs(r.overshoot_m - 0.14) < 1e-9 and r.lateral_entry_m is None


def test_link_loss_braking_is_reported_apart_from_the_hover_drift():
    spec = _spec([{"t": 2.0, "fault": "link_loss", "duration_s": 5.0}])
    m = _monitor(spec)
    t, x = 1.9, 5.0
    # GIVEN flying at 0.8 m/s with the stick forward when the link drops at t = 2 s; the hover
    # command comes at once; the vehicle brakes over 0.4 m, then creeps 0.1 m while hovering
    while t < 7.5:
        if t < 2.0:
            v = 0.8
        elif t < 3.0:
            v = 0.8 * (3.0 - t)  # braking: 0.4 m
        elif t < 5.0:
            v = 0.05  # hovering, creeping: 0.1 m
        else:
            v = 0.0
        x += v * DT
        cmd = (0.8, 0.0) if t < 2.0 else (0.0, 0.0)
        m(_tick(t, x=x, vx=v, cmd=cmd, stick=(0.8, 0.0), link=t < 2.0))
        t += DT
    r = m.finish(0.0)
    assert r.link_hover_s and r.link_hover_s[0] <= 0.03
    # THEN braking ~0.4 m (from the hover command until < 0.1 m/s) and drift ~0.1 m from rest
    assert abs(r.link_brake_m[0] - 0.39) < 0.03
    assert abs(r.link_drift_m[0] - 0.1) < 0.03


def test_ahead_of_the_baselines_is_not_judged_without_baselines():
    ours = {"collision_free": 1.0, "overshoot_max_m": 0.05, "link_loss_hover_s_max": 0.2,
            "link_loss_drift_m_max": 0.1, "stuck_episodes": 0,
            "subsets": {"dropout": {"collision_free": 1.0}, "link_loss": {"collision_free": 1.0}}}
    g = _goals({"ours": ours})
    assert g["ahead_on_dropout"]["met"] is None and g["ahead_on_link_loss"]["met"] is None
    worse = dict(ours, subsets={"dropout": {"collision_free": 0.9}, "link_loss": {"collision_free": 1.0}})
    g2 = _goals({"ours": worse, "px4_like": ours})
    assert g2["ahead_on_dropout"]["met"] is False and g2["ahead_on_link_loss"]["met"] is True
    # AND a tie with one baseline below 1.0 is not ahead of both (seed 47: 1 collision each in 396)
    tie = dict(ours, subsets={"dropout": {"collision_free": 0.99}, "link_loss": {"collision_free": 0.99}})
    other = dict(ours, subsets={"dropout": {"collision_free": 0.99}, "link_loss": {"collision_free": 0.95}})
    g3 = _goals({"ours": tie, "px4_like": tie, "ardupilot_like": other})
    assert g3["ahead_on_dropout"]["met"] is False and g3["ahead_on_link_loss"]["met"] is False


def test_an_escape_into_a_pillar_within_the_stop_line_is_not_judged():
    from inspect_pipe.campaign.generator import Escape

    spec = _spec()
    # a full-height pillar whose face is 1.07 m to the right (-y) of the vehicle at (5, 0)
    spec.doc["world"]["boxes"] = [{"min": [4.0, -3.0, 0.0], "max": [6.0, -1.07, 8.0]}]
    into = Escape(1.0, 3.0, (0.0, -1.0), 0.3)
    away = Escape(1.0, 3.0, (0.0, 1.0), 0.3)
    m = _monitor(spec)
    # GIVEN the stick asks for 0.3 m towards the pillar: only 0.07 m are allowed by the 1 m line
    assert not m._escape_possible(5.0, 0.0, 1.5, into)
    # AND away from it, or along the hold with the pillar behind, the escape is possible
    assert m._escape_possible(5.0, 0.0, 1.5, away)
    assert m._escape_possible(5.0, 0.0, 1.5, Escape(1.0, 3.0, (1.0, 0.0), 0.3))


def _escape_sideways_possible(ahead_m: float, side_box_x: tuple[float, float], side_m: float) -> bool:
    """From (5, 0) at 1.5 m, 0.3 m along -y, with a wall ``ahead_m`` ahead (+x) and a box whose
    +y face is ``side_m`` to the right, spanning ``side_box_x`` along the hold."""
    from inspect_pipe.campaign.generator import Escape

    spec = _spec()
    spec.doc["world"]["boxes"] = [
        {"min": [5.0 + ahead_m, -3.0, 0.0], "max": [7.0, 3.0, 8.0]},
        {"min": [side_box_x[0], -3.0, 0.0], "max": [side_box_x[1], -side_m, 8.0]},
    ]
    return _monitor(spec)._escape_possible(5.0, 0.0, 1.5, Escape(1.0, 3.0, (0.0, -1.0), 0.3))


def test_an_escape_towards_a_pillar_is_judged_by_the_pillar_not_by_the_nearer_wall_ahead():
    # GIVEN a vehicle 0.94 m from the wall ahead (the nearest surface) and 1.25 m from a pillar's
    # face to its right, asked for 0.3 m towards it (campaign seed 127 e1033)
    # THEN it would end 0.95 m from the pillar, inside its stop line: not judged, although the
    # nearest surface (the wall ahead) stays where it was; from 1.40 m it is judged
    assert not _escape_sideways_possible(0.94, (4.0, 5.94), 1.25)
    assert _escape_sideways_possible(0.94, (4.0, 5.94), 1.40)


def test_an_escape_ending_within_five_centimetres_of_the_stop_line_is_not_judged():
    # GIVEN a vehicle in a corner, 1.05 m from the wall ahead and 1.31 m or 1.40 m from the side
    # wall, asked for 0.3 m of progress along it (seed 2, episode 1041)
    # THEN from 1.31 m the escape would end 1 cm from the line: a shield stopping 5 cm short of
    # it cannot make 0.3 m, so it is not judged; from 1.40 m it is
    assert not _escape_sideways_possible(1.05, (3.0, 7.0), 1.31)
    assert _escape_sideways_possible(1.05, (3.0, 7.0), 1.40)


def test_link_loss_hover_is_when_the_push_stops_being_obeyed_not_a_repulsion_across_it():
    spec = _spec([{"t": 2.0, "fault": "link_loss", "duration_s": 3.0}])
    m = _monitor(spec)
    # GIVEN the stick forward when the link drops at t = 2 s; 0.2 s later the forward command is
    # gone, but a collision repulsion sideways (+y, away from a pillar's corner) lasts until 2.4 s
    t = 1.9
    while t < 5.5:
        fwd = 0.4 if t < 2.2 else 0.0
        side = 0.1 if 2.0 <= t < 2.4 else 0.0
        m(_tick(t, cmd=(fwd, side), stick=(0.4, 0.0), link=t < 2.0))
        t += DT
    r = m.finish(0.0)
    # THEN the stick stopped being obeyed after 0.2 s (the hover time), the vehicle's command was
    # zero in every direction after 0.4 s (the stricter quantity)
    assert abs(r.link_hover_s[0] - 0.2) < 0.03
    assert abs(r.link_still_s[0] - 0.4) < 0.03


def test_a_maximum_judged_against_a_goal_is_rounded_up_not_to_the_nearest():
    from inspect_pipe.campaign.metrics import EpisodeResult, aggregate

    # GIVEN one episode 0.10007 m past the stop line (seed 1 e433) and a link-loss hover of exactly 0.3 s
    r = EpisodeResult(index=0, shield="ours", name="e", kind="push_yaw", subsets=["clean"], overshoot_m=0.10007)
    r.link_hover_s.append(0.1 + 0.2)  # 0.30000000000000004
    summary = aggregate([r])
    # THEN the overshoot reported is 0.101 and its goal of 0.10 is not met; the exact 0.3 s stays 0.3
    assert summary["overshoot_max_m"] == 0.101 and summary["link_loss_hover_s_max"] == 0.3
    g = _goals({"ours": summary})
    assert g["overshoot_max_m"]["met"] is False and g["link_loss_hover_s_max"]["met"] is True
