"""Typed messages passed between the onboard nodes, one tick at a time.

Body axes follow the paper: X longitudinal (forward), Y lateral (left), Z vertical (up); speeds are
expressed in the heading frame (body axes with roll and pitch removed), which is what a
gyro-compensated PX4Flow reports.
"""

from __future__ import annotations

import enum
import math
from dataclasses import MISSING, dataclass, fields


class EstimationMode(enum.IntEnum):
    """Table I of the paper: which sensors the state estimate is built from."""

    BOTTOM = 0  # bottom PX4Flow (+ TeraRanger in range)
    BOTTOM_FRONT = 1  # both PX4Flow sensors
    TOF_FRONT = 2  # TeraRanger height, front PX4Flow speeds
    FRONT = 3  # front PX4Flow only; height integrated
    ALARM_TOF = -1  # TeraRanger only: no speed reference, descend
    ALARM_NONE = -2  # nothing: descend


class Button(enum.Enum):
    """Joystick buttons of the base station."""

    TAKEOFF = "takeoff"
    LAND = "land"
    GO_AHEAD = "go_ahead"
    INSPECTION_MODE_ON = "inspection_mode_on"
    INSPECTION_MODE_OFF = "inspection_mode_off"


def message(cls):
    """A message class: ``dataclass(frozen=True, slots=True)``, with an ``__init__`` that stores
    each field through its slot's descriptor instead of the generated one's ``object.__setattr__``
    call per field. The same frozen value, made in half the time: the stack and the simulator make
    about 35 messages a tick, and the frozen ``__init__`` alone was 7 % of a campaign's CPU."""
    cls = dataclass(frozen=True, slots=True)(cls)
    names = [f.name for f in fields(cls)]
    env = {f"_set_{n}": getattr(cls, n).__set__ for n in names}
    args = []
    for f in fields(cls):
        if f.default is MISSING:
            args.append(f.name)
        else:
            env[f"_default_{f.name}"] = f.default
            args.append(f"{f.name}=_default_{f.name}")
    body = "".join(f"    _set_{n}(self, {n})\n" for n in names) or "    pass\n"
    exec(f"def __init__(self, {', '.join(args)}):\n{body}", env)  # noqa: S102 - source built from field names
    init = env["__init__"]
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__doc__ = cls.__init__.__doc__
    cls.__init__ = init
    return cls


@message
class SpeedCommand:
    """A speed set-point in the heading frame (m/s, rad/s)."""

    vx_m_s: float = 0.0
    vy_m_s: float = 0.0
    vz_m_s: float = 0.0
    yaw_rate_rad_s: float = 0.0

    def is_zero(self, eps: float = 1e-6) -> bool:
        return (
            abs(self.vx_m_s) < eps
            and abs(self.vy_m_s) < eps
            and abs(self.vz_m_s) < eps
            and abs(self.yaw_rate_rad_s) < eps
        )


HOVER = SpeedCommand()


@message
class RangeReading:
    """One range-finder sample; ``range_m`` is None when nothing echoed within range.

    ``stamp_s`` is the onboard receive time; the sensor's latency is a known parameter.
    """

    stamp_s: float
    range_m: float | None


@message
class BottomFlow:
    """Bottom-looking PX4Flow: metric flow, the speed over the floor (m/s; 0 without its sonar's
    range, which scales it), the image's quality 0..255, and the angular flow it scaled (rad/s,
    the body rotation taken out by the unit's gyro; MAVLink ``OPTICAL_FLOW_RAD``), which the unit
    measures with or without a range. None where the source gives no angular flow."""

    stamp_s: float
    vx_m_s: float
    vy_m_s: float
    quality: int
    rate_x_rad_s: float | None = None
    rate_y_rad_s: float | None = None
    scaled: bool = True  # the metric flow had its sonar's range (else it reads 0)


@message
class FrontFlow:
    """Forward-looking PX4Flow: metric flow, the speed along the front wall (m/s; 0 without its
    sonar's range), the image's quality 0..255, and the angular flow (rad/s), as :class:`BottomFlow`."""

    stamp_s: float
    vy_m_s: float
    vz_m_s: float
    quality: int
    rate_y_rad_s: float | None = None
    rate_z_rad_s: float | None = None
    scaled: bool = True  # the metric flow had its sonar's range (else it reads 0)


G_M_S2 = 9.81  # standard gravity


@message
class ImuReading:
    """The autopilot's IMU and attitude estimate, as the companion computer receives them.

    ``f*_m_s2``: the accelerometer's specific force in the body frame (x forward, y left, z up;
    m/s^2), mean since the previous reading: gravity included (at rest and level it reads
    (0, 0, +9.81)), with the sensor's bias, noise and vibration. ``roll_rad``/``pitch_rad``: the
    autopilot's attitude ESTIMATE, not the truth; ``yaw_rad`` its heading (world frame, x forward,
    y left; None when the link does not carry it; gyro-integrated in a steel hold, so only changes
    over a few seconds are used). ``p/q/r_rad_s``: body rates from the gyro.

    ``ax_m_s2``/``ay_m_s2``/``az_m_s2``: the acceleration in the heading frame, worked out as the
    autopilot would: the specific force turned by the ESTIMATED roll and pitch, gravity removed.
    Every degree of attitude error is 0.17 m/s^2 of false horizontal acceleration.
    """

    stamp_s: float
    fx_m_s2: float
    fy_m_s2: float
    fz_m_s2: float
    yaw_rad: float | None = None
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    p_rad_s: float = 0.0
    q_rad_s: float = 0.0
    r_rad_s: float = 0.0

    @staticmethod
    def level(
        stamp_s: float, ax_m_s2: float, ay_m_s2: float, az_m_s2: float, yaw_rad: float | None = None
    ) -> "ImuReading":
        """What a level vehicle accelerating at (ax, ay, az) in the heading frame reads."""
        return ImuReading(stamp_s, ax_m_s2, ay_m_s2, az_m_s2 + G_M_S2, yaw_rad)

    def heading_accel(self) -> tuple[float, float, float]:
        """(ax, ay, az) in the heading frame: R_y(pitch) R_x(roll) f - (0, 0, g), estimated attitude."""
        cr, sr = math.cos(self.roll_rad), math.sin(self.roll_rad)
        cp, sp = math.cos(self.pitch_rad), math.sin(self.pitch_rad)
        fx, fy, fz = self.fx_m_s2, self.fy_m_s2, self.fz_m_s2
        fy2, fz2 = cr * fy - sr * fz, sr * fy + cr * fz
        return cp * fx + sp * fz2, fy2, -sp * fx + cp * fz2 - G_M_S2

    @property
    def ax_m_s2(self) -> float:
        return self.heading_accel()[0]

    @property
    def ay_m_s2(self) -> float:
        return self.heading_accel()[1]

    @property
    def az_m_s2(self) -> float:
        return self.heading_accel()[2]


@message
class Measurements:
    """The latest reading delivered by each sensor (None: never delivered).

    A reading whose stamp has not changed since the last tick is simply old; staleness is judged
    by the estimator against ``now``.
    """

    bottom_flow: BottomFlow | None = None
    bottom_sonar: RangeReading | None = None
    bottom_tof: RangeReading | None = None
    front_flow: FrontFlow | None = None
    front_sonar: RangeReading | None = None
    left_sonar: RangeReading | None = None
    right_sonar: RangeReading | None = None
    imu: ImuReading | None = None


@message
class StateEstimate:
    """Output of MAV_state_updater.

    ``height_m`` is the clearance to the surface below (it steps when a box is overflown);
    ``altitude_m`` is the height above the take-off floor with floor discontinuities removed,
    the quantity the height controller holds.
    """

    height_m: float
    altitude_m: float
    vx_m_s: float
    vy_m_s: float
    vz_m_s: float
    mode: EstimationMode
    # The height below which the sensor measuring it reads its clamp (sonar 0.32 m, TeraRanger
    # 0.25 m, noise included): at or below it the vehicle may be standing on the floor. None: no
    # sensor measures the height.
    height_floor_m: float | None = None
    # Odometry: the speed estimate integrated in a frame fixed at switch-on, turned by the
    # autopilot's heading (x, y in m, yaw in rad); None without a heading. It drifts: good for
    # holding station over seconds, not for navigation.
    odometry: tuple[float, float, float] | None = None
    # In the alarm modes, where no sensor measures the speeds: how far (m/s, x, y, z) the carried
    # speeds may stray on the IMU's measured noise alone (``carried_noise_sigma`` standard
    # deviations of its random walk since a measurement last held them); the speed loops leave an
    # error within it alone. Zero where a sensor measures them.
    speed_noise_band_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)


@message
class Clearance:
    """Distance to the closest obstacle per direction (m), corrected to ``now`` for sensor age
    and latency; None when nothing is within the sensor's range or the sensor is silent."""

    front_m: float | None = None
    left_m: float | None = None
    right_m: float | None = None
    down_m: float | None = None
    # The sector's sonar has gone silent (no reading within its time-out): unknown, not free.
    # ``None`` with a fresh reading means nothing within range.
    front_stale: bool = False
    left_stale: bool = False
    right_stale: bool = False
    # How fast each sector's range shrinks, from its own samples (m/s, positive: closing; None:
    # too few samples). Differs from the speed along the sensor's axis when the surface is
    # oblique to it (yawed at a wall): then motion along another axis closes it.
    front_closing_m_s: float | None = None
    left_closing_m_s: float | None = None
    right_closing_m_s: float | None = None


@message
class OperatorInput:
    """What arrived from the base station: the stick and the buttons pressed since last tick."""

    stick: SpeedCommand = HOVER
    buttons: frozenset[Button] = frozenset()
    link_ok: bool = True


@message
class AttitudeSetpoint:
    """What the low-level attitude controller (autopilot firmware) tracks.

    Roll about X (positive: left side up, accelerates towards -Y), pitch about Y (positive: nose
    down, accelerates towards +X), yaw rate about Z; collective thrust as a fraction of maximum.
    """

    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rate_rad_s: float = 0.0
    thrust_frac: float = 0.0


@message
class AxisVector:
    """A behaviour's motion vector: speed per axis, None where the behaviour does not command."""

    vx_m_s: float | None = None
    vy_m_s: float | None = None
    vz_m_s: float | None = None
    yaw_rate_rad_s: float | None = None

    def axes(self) -> tuple[float | None, float | None, float | None, float | None]:
        return (self.vx_m_s, self.vy_m_s, self.vz_m_s, self.yaw_rate_rad_s)

    def is_empty(self) -> bool:
        return self.vx_m_s is None and self.vy_m_s is None and self.vz_m_s is None and self.yaw_rate_rad_s is None

    def to_command(self) -> SpeedCommand:
        """Axes nobody commanded mean hover on that axis."""
        return SpeedCommand(*(0.0 if a is None else a for a in self.axes()))

    @staticmethod
    def full(cmd: SpeedCommand) -> "AxisVector":
        return AxisVector(cmd.vx_m_s, cmd.vy_m_s, cmd.vz_m_s, cmd.yaw_rate_rad_s)


@message
class BehaviorInputs:
    """Everything a behaviour may look at in one tick."""

    now_s: float
    estimate: StateEstimate
    clearance: Clearance
    stick: SpeedCommand
    link_ok: bool
    inspection_mode: bool
    go_ahead_pressed: bool
    battery_percent: float
    flying: bool
    #: while the link is lost: waiting_for_connectivity's station-keeping command, which the safety layer
    #: bounds in the operator's place (None with the link up, in an alarm mode, or before the vehicle rests)
    station_keeping: SpeedCommand | None = None
