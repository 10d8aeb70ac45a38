"""Pure conversions between the onboard stack's messages and MAVLink fields (no I/O).

Frames. The hold's world frame is x forward (north), y left, z up; MAVLink's local frame is NED
with north = world x, so east = -y and down = -z. Body axes: the stack's FLU (X forward, Y left,
Z up), MAVLink's FRD. Between the two, attitude keeps its roll and negates pitch and yaw.
Speeds of the stack are in the heading frame (body axes with roll and pitch removed).

Optical flow (``OPTICAL_FLOW_RAD``) follows the PX4 convention: linear motion along the sensor's
+X induces positive ``integrated_y``, along -Y (left) positive ``integrated_x``; rotation shows in
both the flow and the ``integrated_*gyro`` fields and is subtracted. The bottom unit (sensor id 0)
has the vehicle's X and Y; the front unit (sensor id 1) is mounted with its X up, so its
``integrated_y`` is the vertical speed and ``integrated_x`` the speed to the left along the wall.
"""

from __future__ import annotations

import enum
import math
from typing import NamedTuple
from dataclasses import dataclass

from inspect_pipe.flight_stack.messages import SpeedCommand

__all__ = [
    "ArduCopterMode",
    "Autopilot",
    "DistanceSlot",
    "G",
    "LandedState",
    "Px4Mode",
    "VELOCITY_ONLY_MASK",
    "attitude_from_world",
    "distance_slot",
    "FlowFromRad",
    "flow_from_rad",
    "flow_to_rad",
    "heading_accel_from_imu",
    "imu_from_world",
    "velocity_setpoint_ned",
    "speed_command_from_ned",
]

G = 9.81


class Autopilot(str, enum.Enum):
    PX4 = "px4"  # offboard mode
    ARDUPILOT = "ardupilot"  # guided mode (ArduCopter)


def px4_custom_mode(main: int, sub: int = 0) -> int:
    return (main << 16) | (sub << 24)


def px4_main_mode(custom_mode: int) -> int:
    return (custom_mode >> 16) & 0xFF


# MAVLink's enums and the autopilots' mode tables come from pymavlink (the ``common`` dialect and
# ``mavutil``), resolved on first use so that the pure conversions of this module need no
# pymavlink: ``mc.MAV_CMD_NAV_LAND``, ``mc.MAV_RESULT_ACCEPTED`` ... are ``common``'s constants;
# ``Px4Mode`` (PX4 main modes, custom_mode bits 16..23), ``PX4_AUTO_*`` (AUTO sub-modes, bits
# 24..31), ``ArduCopterMode`` (mavutil.mode_mapping_acm) and ``LandedState`` (MAV_LANDED_STATE)
# are built from them. Without pymavlink, using one is a one-line error saying how to install it.


def _common():
    from inspect_pipe.flight.mavlink_endpoint import require_pymavlink

    return require_pymavlink("mavlink")


def _mavutil():
    _common()  # the one-line error when pymavlink is missing
    from pymavlink import mavutil

    return mavutil


def _build(name: str):
    if name.startswith("MAV_"):
        return getattr(_common(), name)
    if name == "Px4Mode":
        prefix = "PX4_CUSTOM_MAIN_MODE_"
        mu = _mavutil()
        return enum.IntEnum(name, {k[len(prefix):]: getattr(mu, k) for k in dir(mu) if k.startswith(prefix)})
    if name.startswith("PX4_AUTO_"):
        return getattr(_mavutil(), "PX4_CUSTOM_SUB_MODE_AUTO_" + name[len("PX4_AUTO_"):])
    if name == "ArduCopterMode":
        return enum.IntEnum(name, {mode: number for number, mode in sorted(_mavutil().mode_mapping_acm.items())})
    if name == "LandedState":
        entries = _common().enums["MAV_LANDED_STATE"]
        return enum.IntEnum(name, {e.name[len("MAV_LANDED_STATE_"):]: v for v, e in sorted(entries.items()) if not e.name.endswith("_ENUM_END")})
    if name == "VELOCITY_ONLY_MASK":  # SET_POSITION_TARGET_LOCAL_NED: velocity and yaw rate only
        c = _common()
        return (c.POSITION_TARGET_TYPEMASK_X_IGNORE | c.POSITION_TARGET_TYPEMASK_Y_IGNORE | c.POSITION_TARGET_TYPEMASK_Z_IGNORE
                | c.POSITION_TARGET_TYPEMASK_AX_IGNORE | c.POSITION_TARGET_TYPEMASK_AY_IGNORE | c.POSITION_TARGET_TYPEMASK_AZ_IGNORE
                | c.POSITION_TARGET_TYPEMASK_YAW_IGNORE)
    if name == "DISTANCE_SENSORS":
        return _distance_sensors()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __getattr__(name: str):
    value = _build(name)
    globals()[name] = value  # once: later look-ups are plain module attributes
    return value


class DistanceSlot(str, enum.Enum):
    """Which of the stack's range readings a DISTANCE_SENSOR message fills."""

    BOTTOM_SONAR = "bottom_sonar"
    BOTTOM_TOF = "bottom_tof"
    FRONT_SONAR = "front_sonar"
    LEFT_SONAR = "left_sonar"
    RIGHT_SONAR = "right_sonar"


def _distance_sensors() -> dict[DistanceSlot, tuple[int, int, int, int, int]]:
    """(sensor id, type, orientation, min cm, max cm) the simulated vehicle sends for each slot;
    ``mc.DISTANCE_SENSORS``."""
    c = _common()
    sonar, laser = c.MAV_DISTANCE_SENSOR_ULTRASOUND, c.MAV_DISTANCE_SENSOR_LASER
    return {
        DistanceSlot.BOTTOM_SONAR: (0, sonar, c.MAV_SENSOR_ROTATION_PITCH_270, 30, 500),
        DistanceSlot.BOTTOM_TOF: (1, laser, c.MAV_SENSOR_ROTATION_PITCH_270, 20, 1400),
        DistanceSlot.FRONT_SONAR: (2, sonar, c.MAV_SENSOR_ROTATION_NONE, 30, 500),
        DistanceSlot.LEFT_SONAR: (3, sonar, c.MAV_SENSOR_ROTATION_YAW_270, 30, 500),
        DistanceSlot.RIGHT_SONAR: (4, sonar, c.MAV_SENSOR_ROTATION_YAW_90, 30, 500),
    }


def distance_slot(sensor_type: int, orientation: int) -> DistanceSlot | None:
    """The slot a DISTANCE_SENSOR fills, by where it looks (ids differ between autopilots)."""
    c = _common()
    if orientation == c.MAV_SENSOR_ROTATION_PITCH_270:
        return DistanceSlot.BOTTOM_TOF if sensor_type == c.MAV_DISTANCE_SENSOR_LASER else DistanceSlot.BOTTOM_SONAR
    return {
        c.MAV_SENSOR_ROTATION_NONE: DistanceSlot.FRONT_SONAR,
        c.MAV_SENSOR_ROTATION_YAW_270: DistanceSlot.LEFT_SONAR,
        c.MAV_SENSOR_ROTATION_YAW_90: DistanceSlot.RIGHT_SONAR,
    }.get(orientation)


def range_to_cm(range_m: float | None, max_cm: int) -> int:
    """None (no echo) is sent as one more than the maximum: out of range for every reader."""
    if range_m is None:
        return max_cm + 1
    return max(0, min(65535, int(round(range_m * 100.0))))


def range_from_cm(current_cm: int, min_cm: int, max_cm: int) -> float | None:
    if current_cm > max_cm or current_cm <= 0 or current_cm < min_cm:
        return None
    return current_cm / 100.0


# --------------------------------------------------------------------------- optical flow


@dataclass(frozen=True, slots=True)
class FlowRad:
    integrated_x: float
    integrated_y: float
    integrated_xgyro: float
    integrated_ygyro: float
    integration_time_us: int
    distance_m: float  # negative: unknown (no sonar echo)
    quality: int


def flow_to_rad(a_m_s: float, b_m_s: float, quality: int, distance_m: float | None, dt_s: float,
                gyro_x_rad_s: float = 0.0, gyro_y_rad_s: float = 0.0,
                rates_rad_s: tuple[float, float] | None = None) -> FlowRad:
    """Metric flow (bottom: vx, vy; front: vy, vz) -> angular flow over ``dt_s``.

    ``a`` goes to ``integrated_y`` (motion along the sensor's X), ``b`` to ``integrated_x``.
    Without a distance the unit has no metric flow: its angular flow ``rates_rad_s`` (a, b) is
    sent with ``distance`` -1 (unknown), as the PX4Flow does; without that either, quality 0.
    """
    gx, gy = gyro_x_rad_s * dt_s, gyro_y_rad_s * dt_s
    us = int(round(dt_s * 1e6))
    if distance_m is not None and distance_m > 0.0 and quality > 0:
        return FlowRad(b_m_s * dt_s / distance_m + gx, a_m_s * dt_s / distance_m + gy, gx, gy, us, distance_m, quality)
    if rates_rad_s is not None and quality > 0:
        ra, rb = rates_rad_s
        return FlowRad(rb * dt_s + gx, ra * dt_s + gy, gx, gy, us, -1.0, quality)
    return FlowRad(gx, gy, gx, gy, us, -1.0, 0)


class FlowFromRad(NamedTuple):
    """An ``OPTICAL_FLOW_RAD`` message as the stack takes it: the metric flow (a, b; 0 without a
    distance), the quality, the angular flow (a, b, rad/s, gyro compensated; None when the
    message has no valid integration) and whether the metric flow has its distance's scale."""

    a_m_s: float
    b_m_s: float
    quality: int
    rate_a_rad_s: float | None
    rate_b_rad_s: float | None
    scaled: bool


def flow_from_rad(integrated_x: float, integrated_y: float, integrated_xgyro: float, integrated_ygyro: float,
                  integration_time_us: int, distance_m: float, quality: int) -> FlowFromRad:
    """Angular flow -> metric flow, gyro compensated; a distance of 0 or less (unknown) leaves the
    angular flow alone, unscaled."""
    dt = integration_time_us * 1e-6
    if dt <= 0.0 or not all(map(math.isfinite, (integrated_x, integrated_y, integrated_xgyro, integrated_ygyro))):
        return FlowFromRad(0.0, 0.0, 0, None, None, False)
    ra = (integrated_y - integrated_ygyro) / dt
    rb = (integrated_x - integrated_xgyro) / dt
    q = max(0, min(255, int(quality)))
    if not math.isfinite(distance_m) or distance_m <= 0.0:
        return FlowFromRad(0.0, 0.0, q, ra, rb, False)
    return FlowFromRad(ra * distance_m, rb * distance_m, q, ra, rb, True)


# --------------------------------------------------------------------------- attitude and IMU


def _rot_zyx(roll: float, pitch: float, yaw: float) -> tuple[tuple[float, float, float], ...]:
    """Rotation matrix body -> frame for ZYX Euler angles (rows)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )


def attitude_from_world(roll_w: float, pitch_w: float, yaw_w: float) -> tuple[float, float, float]:
    """World-frame (FLU/x-north-left-up) Euler angles -> MAVLink NED/FRD Euler angles."""
    return roll_w, -pitch_w, -yaw_w


def imu_from_world(accel_world: tuple[float, float, float], roll_w: float, pitch_w: float, yaw_w: float) -> tuple[float, float, float]:
    """World acceleration (m/s^2, gravity not included) -> accelerometer specific force, FRD."""
    ax, ay, az = accel_world
    a_ned = (ax, -ay, -az)
    f_ned = (a_ned[0], a_ned[1], a_ned[2] - G)
    R = _rot_zyx(*attitude_from_world(roll_w, pitch_w, yaw_w))
    # body = R^T f_ned
    return tuple(sum(R[i][j] * f_ned[i] for i in range(3)) for j in range(3))  # type: ignore[return-value]


def heading_accel_from_imu(f_frd: tuple[float, float, float], roll: float, pitch: float, yaw: float) -> tuple[float, float, float]:
    """Accelerometer specific force (FRD) and NED attitude -> acceleration in the stack's
    heading frame (x forward, y left, z up), gravity removed."""
    R = _rot_zyx(roll, pitch, yaw)
    a_ned = [sum(R[i][j] * f_frd[j] for j in range(3)) for i in range(3)]
    a_ned[2] += G
    # NED -> world (x north, y west, z up), then into the heading frame (world yaw = -yaw).
    ax, ay, az = a_ned[0], -a_ned[1], -a_ned[2]
    yw = -yaw
    c, s = math.cos(yw), math.sin(yw)
    return c * ax + s * ay, -s * ax + c * ay, az


# --------------------------------------------------------------------------- velocity set-points


def velocity_setpoint_ned(cmd: SpeedCommand, yaw_ned: float) -> tuple[float, float, float, float]:
    """Heading-frame speed command -> (vn, ve, vd, yaw_rate) for SET_POSITION_TARGET_LOCAL_NED."""
    yw = -yaw_ned
    c, s = math.cos(yw), math.sin(yw)
    vxw = c * cmd.vx_m_s - s * cmd.vy_m_s
    vyw = s * cmd.vx_m_s + c * cmd.vy_m_s
    return vxw, -vyw, -cmd.vz_m_s, -cmd.yaw_rate_rad_s


def speed_command_from_ned(vn: float, ve: float, vd: float, yaw_rate_ned: float, yaw_ned: float) -> SpeedCommand:
    """Inverse of :func:`velocity_setpoint_ned` (the simulated autopilot's side)."""
    vxw, vyw = vn, -ve
    yw = -yaw_ned
    c, s = math.cos(yw), math.sin(yw)
    return SpeedCommand(c * vxw + s * vyw, -s * vxw + c * vyw, -vd, -yaw_rate_ned)
