"""Table I's data columns: which readings count this tick.

A reading is N/A when it is older than its sensor's timeout, out of its range, of too low a
quality (flow), or stuck: repeating its value bit for bit while the vehicle's own motion says it
should have changed (:class:`~inspect_pipe.flight_stack.observers.StuckCheck`). The state
estimation (``estimation.MAVStateUpdater``) asks :class:`SensorHealth` for the valid sensor set,
which :func:`~inspect_pipe.flight_stack.estimation.select_mode` maps to the mode.
"""

from __future__ import annotations

import dataclasses

from inspect_pipe.flight_stack.messages import Measurements, RangeReading, message
from inspect_pipe.flight_stack.observers import SpeedObserver, StuckCheck
from inspect_pipe.flight_stack.params import EstimationParams

# The height below which a bottom range sensor's reading is its clamp, within its noise: the HRLV
# sonar reports 0.30 m when closer (+-0.006 m), the TeraRanger One 0.20 m (+-0.02 m). Judged at
# 0.35 m, a hover the controller had just arrested at 0.33 m after a battery sag's dip was a
# touchdown; so was a 0.35 m TeraRanger threshold 0.27 m above the floor.
SONAR_FLOOR_M = 0.32
TOF_FLOOR_M = 0.25
# Reading delays, sample to delivery (datasheet figures, as the simulator delivers them; docs/flight.md,
# Simulator): the HRLV-EZ4's 10 Hz ranging and the TeraRanger One's. Readings are back-dated by them.
SONAR_LATENCY_S = 0.05
TOF_LATENCY_S = 0.01

__all__ = ["SONAR_FLOOR_M", "SONAR_LATENCY_S", "TOF_FLOOR_M", "TOF_LATENCY_S", "ReadingLedger", "SensorHealth", "SensorStatus", "fresh_range"]


@message
class SensorStatus:
    """Which sensors are valid this tick (the data columns of Table I)."""

    bottom_px: bool
    bottom_tof: bool
    front_px: bool


def fresh_range(r: RangeReading | None, now: float, timeout: float, max_range: float) -> bool:
    """A range reading within its sensor's timeout and range."""
    return r is not None and now - r.stamp_s <= timeout and r.range_m is not None and r.range_m <= max_range


class ReadingLedger:
    """Which reading each use of a sensor has taken: a measurement counts once."""

    def __init__(self) -> None:
        self._stamps: dict[str, float] = {}

    def new(self, name: str, stamp_s: float) -> bool:
        """Whether ``stamp_s`` is a reading not yet used for ``name``, and from now on a used one."""
        if self._stamps.get(name) == stamp_s:
            return False
        self._stamps[name] = stamp_s
        return True


class SensorHealth:
    """The valid sensor set each tick, and the readings of stuck range sensors left out."""

    def __init__(self, params: EstimationParams) -> None:
        p = self.p = params
        self._stuck = {k: StuckCheck(p.stuck_samples, p.flow_stuck_imu_dv_m_s) for k in ("bottom", "front")}
        # Horizontal sonars: stuck once the vehicle's own speed along the axis says the range
        # should have changed.
        self._range_stuck = {
            k: StuckCheck(p.stuck_samples, p.sonar_stuck_travel_m)
            for k in ("front", "left", "right", "bottom_sonar", "bottom_tof")
        }
        # Per downward range sensor: the vertical speed carried by the IMU alone since its reading
        # last changed (the height estimate it feeds cannot judge it: see without_stuck_ranges).
        self._vz_free: dict[str, float] = {"bottom_sonar": 0.0, "bottom_tof": 0.0}
        self._last_down_range: dict[str, float | None] = {"bottom_sonar": None, "bottom_tof": None}
        self._was_stuck = {"bottom": False, "front": False}
        self._newly_stuck = {"bottom": False, "front": False}

    def status(self, now: float, m: Measurements, obs: tuple[SpeedObserver, ...]) -> SensorStatus:
        """Table I's columns: a flow is valid with its quality and its own sonar, and not stuck
        against the IMU's change of speed (``obs``: the speed observers, x, y, z)."""
        p = self.p
        b_sonar = fresh_range(m.bottom_sonar, now, p.sonar_timeout_s, p.sonar_max_range_m)
        f_sonar = fresh_range(m.front_sonar, now, p.sonar_timeout_s, p.sonar_max_range_m)
        bf, ff = m.bottom_flow, m.front_flow
        # A metric flow needs its own sonar's echo, which scales it (without one it reads 0,
        # whatever its image's quality).
        b_flow = bf is not None and bf.scaled and now - bf.stamp_s <= p.flow_timeout_s and bf.quality >= p.flow_min_quality
        f_flow = ff is not None and ff.scaled and now - ff.stamp_s <= p.flow_timeout_s and ff.quality >= p.flow_min_quality
        imu = m.imu
        ax, ay, az = (imu.ax_m_s2, imu.ay_m_s2, imu.az_m_s2) if imu is not None else (0.0, 0.0, 0.0)
        bx, by, bz = (o.b for o in obs)
        b_stuck = b_flow and self._stuck["bottom"].check(
            bf.stamp_s, (bf.vx_m_s, bf.vy_m_s), (ax - bx, ay - by), reference=(obs[0].v, obs[1].v)  # type: ignore[union-attr]
        )
        f_stuck = f_flow and self._stuck["front"].check(
            ff.stamp_s, (ff.vy_m_s, ff.vz_m_s), (ay - by, az - bz), reference=(obs[1].v, None)  # type: ignore[union-attr]
        )
        self._newly_stuck = {"bottom": b_stuck and not self._was_stuck["bottom"], "front": f_stuck and not self._was_stuck["front"]}
        self._was_stuck = {"bottom": b_stuck, "front": f_stuck}
        b_flow, f_flow = b_flow and not b_stuck, f_flow and not f_stuck
        return SensorStatus(
            bottom_px=b_flow and b_sonar,
            bottom_tof=fresh_range(m.bottom_tof, now, p.tof_timeout_s, p.tof_max_range_m),
            front_px=f_flow and f_sonar,
        )

    def restart_after_stuck_flow(self, obs: tuple[SpeedObserver, ...]) -> None:
        """A flow found stuck has fed its repeated value into the estimate since it stuck (the
        check needs the IMU to disagree by ``flow_stuck_imu_dv_m_s`` first); the observers that
        take over restart from what it would read now instead (``StuckCheck.likely_value``).
        Continuing from the stuck value, the front range observer of mode 2 (then the source of
        vx there) needed a second to find the real speed, and the vehicle flew 0.15 m past the
        stop line meanwhile."""
        ox, oy, oz = obs
        if self._newly_stuck["bottom"]:
            vx, vy = self._stuck["bottom"].likely_value()
            ox.restart(vx)
            oy.restart(vy)
        if self._newly_stuck["front"]:
            vy, vz = self._stuck["front"].likely_value()
            oy.restart(vy)
            oz.restart(vz)

    def without_stuck_ranges(self, m: Measurements, az: float, dt: float, obs: tuple[SpeedObserver, ...]) -> Measurements:
        """``m`` without the readings of stuck range sensors. A range sensor repeating its range
        bit for bit while the vehicle has moved along its axis by more than ``sonar_stuck_travel_m``
        is stuck: its readings count as missing until they change. Horizontal sonars: a silent
        sector, no user motion into it (safety campaign: a left sonar stuck at 1.65 m while the
        operator pushed at 0.77 m/s towards the wall; the stop came when it recovered, 0.15 m
        inside the line).

        The downward ones (bottom sonar, TeraRanger) are judged by the vertical speed the IMU
        alone carries from the moment their reading last changed (``az``: the IMU's vertical
        acceleration this tick, heading frame): the height estimate they feed follows a stuck
        reading, and so does its rate. In mode -1 a TeraRanger stuck at 2.45 m pinned the
        height, the estimate's vertical speed stayed at the alarm descent's "+val." while the
        vehicle fell, the speed loop kept lowering the thrust, and the vehicle hit the floor at
        1.47 m/s (found by hand, 2026-11-28; the campaign draws one stuck sensor at a time, and
        with a flow alive the TeraRanger does not measure the height). Dropped, the TeraRanger
        leaves mode -2 and its alarm descent. A reading at the sensor's clamp (the sonar's 0.30
        m, the TeraRanger's 0.20 m: on the floor, in a take-off) repeats by design."""
        vx, vy = obs[0].v, obs[1].v
        drop = {}
        for name, r, speed in (("front", m.front_sonar, vx), ("left", m.left_sonar, vy), ("right", m.right_sonar, -vy)):
            if r is not None and r.range_m is not None and self._range_stuck[name].check(r.stamp_s, (r.range_m,), (speed,)):
                drop[f"{name}_sonar"] = None
        az -= obs[2].b
        for name, r, clamp_m in (("bottom_sonar", m.bottom_sonar, SONAR_FLOOR_M), ("bottom_tof", m.bottom_tof, TOF_FLOOR_M)):
            if r is None or r.range_m is None or r.range_m <= clamp_m:
                self._last_down_range[name] = None
                continue
            if r.range_m != self._last_down_range[name]:
                self._vz_free[name] = obs[2].v  # the estimate while the reading still moved
                self._last_down_range[name] = r.range_m
            else:
                self._vz_free[name] += az * dt
            if self._range_stuck[name].check(r.stamp_s, (r.range_m,), (self._vz_free[name],)):
                drop[name] = None
        return dataclasses.replace(m, **drop) if drop else m
