"""The scheduler, the state at mid-exposure and replay timing, on injected clocks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from inspect_pipe.capture import CaptureConfig, ManualClock, RateScheduler, TrajectoryFeed, TrueState, VehicleState, read_sweep, run_capture
from inspect_pipe.capture._geometry import rotation_from_rpy, rpy_from_rotation
from inspect_pipe.capture.sources.replay import ReplaySource


def test_deadlines_do_not_drift_and_late_ones_are_skipped_and_counted():
    clock = ManualClock(100.0)
    s = RateScheduler(10.0, clock)
    ticks = [s.wait() for _ in range(5)]
    assert [t.deadline_s for t in ticks] == pytest.approx([100.0, 100.1, 100.2, 100.3, 100.4], abs=1e-12)
    assert all(t.late_s == 0 and t.skipped == 0 for t in ticks)
    clock.advance(0.33)  # a stall to 100.73: deadlines 100.5 and 100.6 are a whole period late
    t = s.wait()
    assert t.skipped == 2 and t.deadline_s == pytest.approx(100.7) and t.late_s == pytest.approx(0.03)
    assert s.skipped_total == 2
    clock.advance(0.05)  # back in time for the next one: no skip, no lateness
    t = s.wait()
    assert t.skipped == 0 and t.deadline_s == pytest.approx(100.8) and t.late_s == 0.0 and clock.now() == pytest.approx(100.8)


def _state(t, x, yaw):
    return VehicleState(t, (x, 0.0, 1.0), 12.0 - x, 1.0, (1.0, 0.0, 0.0), 1, "flying", t > 0.5,
                        TrueState((x, 0.0, 1.0), rotation_from_rpy(0.0, 0.0, yaw), (1.0, 0.0, 0.0)))


def test_state_is_interpolated_at_mid_exposure():
    feed = TrajectoryFeed([_state(0.0, 10.0, 0.0), _state(0.02, 10.02, 0.2), _state(0.04, 10.04, 0.4)])
    s = feed.state_at(0.025)
    assert s.position_m[0] == pytest.approx(10.025) and s.dist_front_m == pytest.approx(1.975)
    assert rpy_from_rotation(s.truth.R_world_body)[2] == pytest.approx(0.25, abs=1e-9)  # slerp
    assert feed.state_at(0.05) is None and feed.state_at(-0.01) is None  # never extrapolated
    gap = TrajectoryFeed([_state(0.0, 10.0, 0.0), _state(2.0, 12.0, 0.0)], max_gap_s=0.5)
    assert gap.state_at(1.0) is None  # a telemetry gap is not papered over


def test_replay_plays_at_the_recorded_timing(sim_sweep, tmp_path):
    # GIVEN a recorded sweep with frames every 0.1 s, the first at some t
    rec = read_sweep(sim_sweep)
    clock = ManualClock(500.0)
    # WHEN it is replayed at 2x on an injected clock
    src = ReplaySource(sim_sweep, clock=clock, speed=2.0)
    # (simulated time stands still while the writer works: wait for it rather than count drops
    # that only a loaded test machine would produce)
    res = run_capture(src, tmp_path / "re", clock=clock, config=CaptureConfig(wait_for_writer=True))
    out = read_sweep(tmp_path / "re")
    # THEN every frame comes at its recorded offset / 2 after the start, exactly, and keeps its state
    assert len(out.frames) == len(rec.frames) and res.drops == 0
    t0 = out.frames[0].t_host_s
    for a, b in zip(rec.frames, out.frames):
        assert b.t_host_s - t0 == pytest.approx((a.t_s - rec.frames[0].t_s) / 2, abs=1e-6)
        assert b.position_m == a.position_m and b.fsm == a.fsm
        assert np.allclose(b.truth.H_wall_m_to_frame, a.truth.H_wall_m_to_frame)
    assert max(abs(j) for j in res.jitter_s) < 1e-6
    assert out.meta.source["kind"] == "replay" and math.isclose(out.meta.camera.K[0, 0], rec.meta.camera.K[0, 0])
