"""MuJoCo quadrotor in a cargo hold, with the autopilot firmware's attitude controller.

The vehicle is an AscTec Hummingbird-like quadrotor built from primitive shapes (0.71 kg with the
inspection payload, thrust-to-weight 2.2). The firmware tracks roll, pitch, yaw rate and collective
thrust set-points (``AttitudeSetpoint``) at the physics rate: its PD attitude law, acting on the
autopilot's attitude ESTIMATE (``attitude_error`` away from the truth), asks for body
torques and a collective thrust, and a mixer turns them into four motor thrusts in the "+"
layout, attitude first (roll and pitch are scaled down only when no collective fits them in the
motors' range, then the collective is chosen closest to the set-point, then yaw gets what is left:
PX4's and ArduPilot's desaturation order). Each motor has its own first-order lag and its own
maximum (a weak motor runs out of authority), its thrust gains ground effect near the floor, and
its drag torque turns the vehicle. Rotor drag and a slowly varying air disturbance act on the
body. Headless, deterministic for a seed.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np

from inspect_pipe.flight.scenario import World
from inspect_pipe.flight_stack.messages import AttitudeSetpoint

__all__ = ["AttitudeFirmware", "QuadrotorSim", "VehicleModel", "build_mjcf", "mix"]

G = 9.81


@dataclass(frozen=True)
class VehicleModel:
    mass_kg: float = 0.71
    thrust_to_weight: float = 2.2
    arm_m: float = 0.17
    rotor_radius_m: float = 0.1
    leg_height_m: float = 0.08  # centre height when landed
    drag_linear_n_s_m: float = 0.25  # rotor drag, N per m/s
    drag_quadratic_n_s2_m2: float = 0.05
    motor_time_constant_s: float = 0.03
    rotor_torque_m: float = 0.0245  # rotor drag torque per newton of thrust (k_M / k_F of the Hummingbird)
    disturbance_force_n: float = 0.03  # std of the air disturbance
    disturbance_time_constant_s: float = 2.0

    @property
    def max_thrust_n(self) -> float:
        return self.thrust_to_weight * self.mass_kg * G


@dataclass(frozen=True)
class AttitudeFirmware:
    """PD attitude control as in the autopilot firmware (natural frequency, damping)."""

    omega_rp_rad_s: float = 28.0
    zeta_rp: float = 0.8
    omega_yaw_rad_s: float = 8.0
    zeta_yaw: float = 0.9
    max_tilt_rad: float = 0.6


def mix(
    thrust_n: float, tx: float, ty: float, tz: float, arm_m: float, torque_m: float, motor_max_n: list[float]
) -> tuple[float, float, float, float]:
    """Motor thrusts (N) for a collective ``thrust_n`` and body torques (N m), "+" layout (motors
    at +x, +y, -x, -y; 0 and 2 make +torque_m x thrust of yaw torque, 1 and 3 the opposite), each
    within [0, ``motor_max_n[i]``]. Attitude first: roll and pitch are scaled down only as far as
    no collective fits them in, the collective is the one closest to ``thrust_n`` that does, and
    yaw gets what headroom is left."""
    k2 = 2.0 * arm_m
    r0, r1, r2, r3 = -ty / k2, tx / k2, ty / k2, -tx / k2
    m0, m1, m2, m3 = motor_max_n
    if m0 == m1 == m2 == m3:
        # Equal ranges (the firmware's mixer plans with the nominal one): the spread must fit.
        lo_v = min(r0, r1, r2, r3)
        hi_v = max(r0, r1, r2, r3)
        if hi_v - lo_v > m0:
            s = m0 / (hi_v - lo_v)
            r0, r1, r2, r3 = s * r0, s * r1, s * r2, s * r3
            lo_v, hi_v = min(r0, r1, r2, r3), max(r0, r1, r2, r3)
        lo, hi = -lo_v, m0 - hi_v
    else:
        rp = (r0, r1, r2, r3)
        s = 1.0
        for i in range(4):
            for j in range(4):
                gap = rp[j] - rp[i]
                if gap > 0.0 and motor_max_n[j] < s * gap:
                    s = motor_max_n[j] / gap  # motor j at its top while motor i is at zero
        r0, r1, r2, r3 = s * r0, s * r1, s * r2, s * r3
        lo = max(-r0, -r1, -r2, -r3)
        hi = min(m0 - r0, m1 - r1, m2 - r2, m3 - r3)
    c = 0.25 * thrust_n
    c = lo if c < lo else hi if c > hi else c
    b0, b1, b2, b3 = c + r0, c + r1, c + r2, c + r3
    yw = tz / (4.0 * torque_m)
    k = 1.0
    if yw > 0.0:  # motors 0 and 2 up, 1 and 3 down
        for b, mx in ((b0, m0), (b2, m2)):
            if b + k * yw > mx:
                k = max(0.0, (mx - b) / yw)
        for b in (b1, b3):
            if b - k * yw < 0.0:
                k = max(0.0, b / yw)
    elif yw < 0.0:
        for b in (b0, b2):
            if b + k * yw < 0.0:
                k = max(0.0, -b / yw)
        for b, mx in ((b1, m1), (b3, m3)):
            if b - k * yw > mx:
                k = max(0.0, (b - mx) / yw)
    y = k * yw
    out0, out1, out2, out3 = b0 + y, b1 - y, b2 + y, b3 - y
    return (
        0.0 if out0 < 0.0 else m0 if out0 > m0 else out0,
        0.0 if out1 < 0.0 else m1 if out1 > m1 else out1,
        0.0 if out2 < 0.0 else m2 if out2 > m2 else out2,
        0.0 if out3 < 0.0 else m3 if out3 > m3 else out3,
    )


def build_mjcf(world: World, vehicle: VehicleModel, start: tuple[float, float, float], yaw: float, timestep_s: float) -> str:
    h = world.hold
    L, W, H = h.length_m, h.width_m, h.height_m
    t = 0.1
    env = [
        f'<geom name="floor" type="box" pos="{L / 2} 0 {-t / 2}" size="{L / 2 + t} {W / 2 + t} {t / 2}"/>',
        f'<geom name="back_wall" type="box" pos="{-t / 2} 0 {H / 2}" size="{t / 2} {W / 2 + t} {H / 2}"/>',
        f'<geom name="front_wall" type="box" pos="{L + t / 2} 0 {H / 2}" size="{t / 2} {W / 2 + t} {H / 2}"/>',
        f'<geom name="left_wall" type="box" pos="{L / 2} {W / 2 + t / 2} {H / 2}" size="{L / 2 + t} {t / 2} {H / 2}"/>',
        f'<geom name="right_wall" type="box" pos="{L / 2} {-W / 2 - t / 2} {H / 2}" size="{L / 2 + t} {t / 2} {H / 2}"/>',
    ]
    for i, b in enumerate(world.boxes):
        c = [(b.min_m[k] + b.max_m[k]) / 2 for k in range(3)]
        s = [(b.max_m[k] - b.min_m[k]) / 2 for k in range(3)]
        env.append(f'<geom name="box{i}" type="box" pos="{c[0]} {c[1]} {c[2]}" size="{s[0]} {s[1]} {s[2]}"/>')
    a, r, lh = vehicle.arm_m, vehicle.rotor_radius_m, vehicle.leg_height_m
    m = vehicle.mass_kg
    parts = [
        f'<geom name="core" type="box" size="0.06 0.06 0.03" mass="{m * 0.62:.4f}"/>',
        f'<geom name="payload" type="box" pos="0.04 0 -0.035" size="0.04 0.03 0.015" mass="{m * 0.1:.4f}"/>',
    ]
    for k, (dx, dy) in enumerate([(a, 0), (0, a), (-a, 0), (0, -a)]):
        parts.append(f'<geom name="arm{k}" type="capsule" fromto="0 0 0 {dx} {dy} 0" size="0.008" mass="{m * 0.03:.4f}"/>')
        parts.append(
            f'<geom name="rotor{k}" type="cylinder" pos="{dx} {dy} 0.02" size="{r} 0.005" mass="{m * 0.035:.4f}"/>'
        )
    for k, (dx, dy) in enumerate([(0.07, 0.07), (-0.07, 0.07), (-0.07, -0.07), (0.07, -0.07)]):
        parts.append(
            f'<geom name="leg{k}" type="capsule" fromto="{dx} {dy} -0.03 {dx} {dy} {-lh + 0.006}" size="0.006" mass="{m * 0.005:.4f}"/>'
        )
    qw, qz = math.cos(yaw / 2), math.sin(yaw / 2)
    x, y, z = start
    return f"""
<mujoco model="cargo_hold">
  <option timestep="{timestep_s}" integrator="Euler" gravity="0 0 {-G}">
    <flag energy="disable" warmstart="enable"/>
  </option>
  <default><geom friction="0.8 0.01 0.001" rgba="0.6 0.6 0.6 1"/></default>
  <worldbody>
    {''.join(env)}
    <body name="mav" pos="{x} {y} {z + lh}" quat="{qw} 0 0 {qz}">
      <freejoint/>
      {''.join(parts)}
    </body>
  </worldbody>
</mujoco>"""


class QuadrotorSim:
    """Physics and firmware. ``set_setpoint`` then ``step(n)`` physics steps; state read back
    from properties. Ray casts for the sensors use the MuJoCo scene."""

    def __init__(
        self,
        world: World,
        start: tuple[float, float, float],
        yaw: float = 0.0,
        *,
        vehicle: VehicleModel | None = None,
        firmware: AttitudeFirmware | None = None,
        physics_hz: float = 200.0,
        seed: int = 0,
    ) -> None:
        self.vehicle = vehicle or VehicleModel()
        self.firmware = firmware or AttitudeFirmware()
        self.dt = 1.0 / physics_hz
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(world, self.vehicle, start, yaw, self.dt))
        self.data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, self.data)
        self.body = self.model.body("mav").id
        inertia = self.model.body_inertia[self.body]
        self.ixx, self.iyy, self.izz = (float(v) for v in inertia)
        self.mass = float(self.model.body_subtreemass[self.body])
        self.rng = random.Random(seed * 7919 + 1)
        self.t = 0.0
        self.setpoint = AttitudeSetpoint()
        self.thrust_n = 0.0
        self.yaw_sp = yaw
        self._dist = [0.0, 0.0, 0.0]
        self._ray_vec = np.zeros(3)
        self._ray_pnt = np.zeros(3)
        self._geomid = np.zeros(1, dtype=np.int32)
        self._xfrc = self.data.xfrc_applied[self.body]
        self._xmat = self.data.xmat[self.body]  # views into MjData: they follow the simulation
        self._last_hit: tuple | None = None
        self._geom_pos, self._geom_size = self.model.geom_pos.tolist(), self.model.geom_size.tolist()  # the scene is static
        # (quaternion, (roll, pitch, yaw)) of the last attitude worked out: the controller, the
        # sensors and the runner all ask for the attitude of the same physics state.
        self._att: tuple[list[float], tuple[float, float, float]] | None = None
        # Faults the scenario injects: wind (world frame, m/s) seen through the rotor drag, and
        # the share of maximum thrust still available (battery sag).
        self.wind_m_s = (0.0, 0.0, 0.0)
        self.thrust_available = 1.0
        # Each motor's share of its nominal maximum thrust (a weak motor: below 1). Motors 0..3 at
        # +x (front), +y (left), -x, -y; 0 and 2 turn one way, 1 and 3 the other.
        self.motor_health = [1.0, 1.0, 1.0, 1.0]
        self.motor_n = [0.0, 0.0, 0.0, 0.0]  # each motor's thrust (N), after its lag
        # The autopilot's attitude estimate less the truth (roll, pitch; rad), set by the sensor
        # suite's attitude model: the firmware's attitude law acts on its estimate, so a vehicle
        # "level" by its estimate is tilted by this and accelerates at g x error.
        self.attitude_error = (0.0, 0.0)

    # ------------------------------------------------------------------ state
    @property
    def position(self) -> tuple[float, float, float]:
        q = self.data.qpos
        return (float(q[0]), float(q[1]), float(q[2]))

    @property
    def velocity(self) -> tuple[float, float, float]:
        v = self.data.qvel
        return (float(v[0]), float(v[1]), float(v[2]))

    @property
    def body_rates(self) -> tuple[float, float, float]:
        v = self.data.qvel
        return (float(v[3]), float(v[4]), float(v[5]))

    def euler(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) in rad, ZYX convention."""
        quat = self.data.qpos[3:7].tolist()
        att = self._att
        if att is not None and att[0] == quat:
            return att[1]
        return self._attitude(quat)

    def _attitude(self, quat: list[float]) -> tuple[float, float, float]:
        """Euler angles of the unit quaternion ``quat`` (w, x, y, z), remembered for ``euler``."""
        w, x, y, z = quat
        roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        sin_pitch = 2 * (w * y - z * x)
        sin_pitch = sin_pitch if sin_pitch < 1.0 else 1.0  # min(1.0, .), max(-1.0, .) without the calls
        sin_pitch = sin_pitch if sin_pitch > -1.0 else -1.0
        pitch = math.asin(sin_pitch)
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        rpy = (roll, pitch, yaw)
        self._att = (quat, rpy)
        return rpy

    def rotation(self) -> np.ndarray:
        return self.data.xmat[self.body].reshape(3, 3)

    def kinematics(self) -> tuple[list[float], list[float]]:
        """The velocity (m/s, world) with the body rates (rad/s) as (vx, vy, vz, p, q, r), and
        the body-to-world rotation row by row (9 values): what the sensors read, in one go."""
        return self.data.qvel.tolist(), self._xmat.tolist()

    # ------------------------------------------------------------------ control and physics
    def set_setpoint(self, sp: AttitudeSetpoint) -> None:
        self.setpoint = sp

    def step(self, n: int = 1, after_step: Callable[["QuadrotorSim"], None] | None = None) -> None:
        """``n`` physics steps holding the current set-point; ``after_step(self)`` after each
        (the sensors sample there), or only once ``sim.t`` reaches ``after_step.next_due_s`` when
        the callable has that attribute (read again after each call: only the call moves it).
        The air disturbance changes once per call."""
        m, d = self.model, self.data
        fw, veh = self.firmware, self.vehicle
        dt = self.dt
        wrp, zrp = fw.omega_rp_rad_s, fw.zeta_rp
        kp_rp, kd_rp = wrp * wrp, 2 * zrp * wrp
        kp_y, kd_y = fw.omega_yaw_rad_s ** 2, 2 * fw.zeta_yaw * fw.omega_yaw_rad_s
        alpha = dt / (veh.motor_time_constant_s + dt)
        tmax = veh.max_thrust_n
        c1, c2 = veh.drag_linear_n_s_m, veh.drag_quadratic_n_s2_m2
        dist_a = n * dt / veh.disturbance_time_constant_s
        dist_s = veh.disturbance_force_n * math.sqrt(2 * dist_a)
        dist = self._dist
        for k in range(3):
            dist[k] += -dist_a * dist[k] + dist_s * self.rng.gauss(0.0, 1.0)
        qpos, qvel = d.qpos, d.qvel
        xfrc, body_R = self._xfrc, self._xmat
        ixx, iyy, izz = self.ixx, self.iyy, self.izz
        sp = self.setpoint
        roll_sp = max(-fw.max_tilt_rad, min(fw.max_tilt_rad, sp.roll_rad))
        pitch_sp = max(-fw.max_tilt_rad, min(fw.max_tilt_rad, sp.pitch_rad))
        # A sagging battery lowers what every command gives; a weak motor gives its share of the
        # command (the firmware does not know: its mixer plans with the nominal range).
        avail = self.thrust_available
        thrust_sp = max(0.0, min(1.0, sp.thrust_frac)) * tmax * avail
        motor_max = [0.25 * tmax * avail] * 4
        h0, h1, h2, h3 = self.motor_health
        arm, km = veh.arm_m, veh.rotor_torque_m
        r_ge = veh.rotor_radius_m / 4.0
        z_rotor = 0.02  # rotor plane above the body origin
        yaw_rate_sp = sp.yaw_rate_rad_s
        yaw_sp_step = yaw_rate_sp * dt
        wx, wy, wz = self.wind_m_s
        m0, m1, m2, m3 = self.motor_n
        err_r, err_p = self.attitude_error
        armed = thrust_sp > 0.0 or self.thrust_n > 0.01
        # Air disturbance: only while armed, constant over the call.
        fx, fy, fz = dist if armed else (0.0, 0.0, 0.0)
        pi, two_pi = math.pi, 2 * math.pi
        if after_step is None:
            due = math.inf
        else:
            due = getattr(after_step, "next_due_s", -math.inf)
        t, yaw_sp = self.t, self.yaw_sp
        roll, pitch, yaw = self.euler()
        z = float(qpos[2])
        zr_min = 2.0 * r_ge
        for _ in range(n):
            vx, vy, vz, p, q, r = qvel.tolist()
            vx, vy, vz = vx - wx, vy - wy, vz - wz  # air-relative: drag pushes towards the wind
            speed = math.sqrt(vx * vx + vy * vy + vz * vz)
            cd = c1 + c2 * speed
            if armed:
                yaw_sp += yaw_sp_step
                yaw_err = (yaw_sp - yaw + pi) % two_pi - pi
                tx = ixx * (kp_rp * (roll_sp - roll - err_r) - kd_rp * p)
                ty = iyy * (kp_rp * (pitch_sp - pitch - err_p) - kd_rp * q)
                tz = izz * (kp_y * yaw_err + kd_y * (yaw_rate_sp - r))
                cmd = mix(thrust_sp, tx, ty, tz, arm, km, motor_max)
            else:
                yaw_sp = yaw
                cmd = (0.0, 0.0, 0.0, 0.0)
            # Motor lag, each motor giving its health's share of its command.
            u0, u1, u2, u3 = cmd
            m0 += alpha * (h0 * u0 - m0)
            m1 += alpha * (h1 * u1 - m1)
            m2 += alpha * (h2 * u2 - m2)
            m3 += alpha * (h3 * u3 - m3)
            # Ground effect (Cheeseman and Bennett): T / T_inf = 1 / (1 - (R / 4z)^2) over the floor,
            # taken no closer than z = R / 2, where the formula stops holding.
            zr = z + z_rotor
            zr = zr if zr > zr_min else zr_min
            ge = 1.0 / (1.0 - (r_ge / zr) ** 2)
            T = ge * (m0 + m1 + m2 + m3)
            tx = ge * arm * (m1 - m3)
            ty = ge * arm * (m2 - m0)
            tz = ge * km * (m0 - m1 + m2 - m3)
            # Thrust along the body z axis, drag and disturbance (world frame); torques rotated
            # from the body to the world frame.
            R = body_R.tolist()
            xfrc[0] = R[2] * T + fx - cd * vx
            xfrc[1] = R[5] * T + fy - cd * vy
            xfrc[2] = R[8] * T + fz - cd * vz
            xfrc[3] = R[0] * tx + R[1] * ty + R[2] * tz
            xfrc[4] = R[3] * tx + R[4] * ty + R[5] * tz
            xfrc[5] = R[6] * tx + R[7] * ty + R[8] * tz
            mujoco.mj_step(m, d)
            t += dt
            q_now = qpos.tolist()
            z = q_now[2]
            roll, pitch, yaw = self._attitude(q_now[3:7])
            if t + 1e-9 >= due:
                self.t, self.thrust_n, self.yaw_sp = t, T, yaw_sp
                after_step(self)  # type: ignore[misc]
                due = getattr(after_step, "next_due_s", -math.inf)
                t = self.t
            self.thrust_n = T
        self.t, self.yaw_sp = t, yaw_sp
        self.motor_n = [m0, m1, m2, m3]

    # ------------------------------------------------------------------ sensing
    def ray(self, origin: tuple[float, float, float], direction_body: tuple[float, float, float]) -> float | None:
        """Distance along a body-frame direction from ``origin`` (world) to the scene, or None."""
        return self.first_echo(origin, (direction_body,))

    def first_echo(self, origin: tuple[float, float, float], directions_body, accept=None) -> float | None:
        """Nearest hit (m) over rays along body-frame directions from ``origin`` (world), or None
        if none hits; ``incidence_rad`` then describes that ray (the first of equally near ones).
        ``accept(incidence_rad) -> bool``, when given, decides for each ray that hits whether its
        echo is heard (a sonar misses at shallow incidence)."""
        R0, R1, R2, R3, R4, R5, R6, R7, R8 = self._xmat.tolist()
        m, d, body = self.model, self.data, self.body
        v, pnt, geomid = self._ray_vec, self._ray_pnt, self._geomid
        pnt[0], pnt[1], pnt[2] = origin
        best = None
        for dx, dy, dz in directions_body:
            # The direction in the world frame.
            ux = R0 * dx + R1 * dy + R2 * dz
            uy = R3 * dx + R4 * dy + R5 * dz
            uz = R6 * dx + R7 * dy + R8 * dz
            v[0], v[1], v[2] = ux, uy, uz
            dist = mujoco.mj_ray(m, d, pnt, v, None, True, body, geomid)
            if dist >= 0 and (best is None or dist < best):
                if accept is not None and not accept(self._incidence(origin, (ux, uy, uz), float(dist), int(geomid[0]))):
                    continue
                best = dist
                hit = (ux, uy, uz), int(geomid[0])
        if best is None:
            return None
        best = float(best)
        self._last_hit = (origin, hit[0], best, hit[1])
        return best

    def _incidence(self, pnt, v, dist: float, g: int) -> float:
        """Angle between a ray and the normal of the surface it hit (rad); the hit face is the one
        of the (axis-aligned box) geom the hit point is farthest out on."""
        (cx, cy, cz), (hx, hy, hz) = self._geom_pos[g], self._geom_size[g]
        out = (abs(pnt[0] + dist * v[0] - cx) / hx, abs(pnt[1] + dist * v[1] - cy) / hy, abs(pnt[2] + dist * v[2] - cz) / hz)
        k = 0 if out[0] >= out[1] and out[0] >= out[2] else 1 if out[1] >= out[2] else 2  # the first of equals, as max()
        return math.acos(min(1.0, abs(float(v[k]))))

    def incidence_rad(self) -> float:
        """Incidence of the last ray that hit (see ``_incidence``)."""
        if self._last_hit is None:
            return 0.0
        return self._incidence(*self._last_hit)
