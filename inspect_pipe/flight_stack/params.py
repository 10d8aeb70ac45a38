"""Parameters of the onboard stack, each declared once with default, bounds and unit.

``StackParams.validate()`` checks every bound; ``describe()`` lists them (used by docs and
``--help`` texts). Field names carry the unit.
"""

from __future__ import annotations

import dataclasses
import reprlib
from pathlib import Path
from dataclasses import dataclass, field, fields


def param(default: float, lo: float, hi: float, unit: str, doc: str = ""):
    return field(default=default, metadata={"min": lo, "max": hi, "unit": unit, "doc": doc})


def _check(obj) -> None:
    for f in fields(obj):
        meta = f.metadata
        if "min" not in meta:
            continue
        value = getattr(obj, f.name)
        if not (meta["min"] <= value <= meta["max"]):
            raise ValueError(
                f"{type(obj).__name__}.{f.name}={value} outside [{meta['min']}, {meta['max']}] {meta['unit']}"
            )


@dataclass(frozen=True)
class EstimationParams:
    flow_min_quality: int = param(
        1, 0, 255, "1", "PX4Flow quality below which flow is not used: PX4's EKF2_OF_QMIN and its in-air default "
        "(quality 0 is no flow); between it and 255 a reading's noise goes from flow_noise_worst_rad_s to "
        "flow_noise_rad_s and the gate refuses what disagrees. At 40, a 9.5 s link-loss hold 3 m over a floor of "
        "low texture (quality ~26) refused 5 readings in 6 and drifted 0.41 m (0.14 m at 1; "
        "docs/flight.md, Session 34)"
    )
    flow_timeout_s: float = param(0.08, 0.01, 1.0, "s", "flow older than this is N/A")
    sonar_timeout_s: float = param(0.35, 0.05, 2.0, "s", "sonar older than this is N/A (10 Hz)")
    tof_timeout_s: float = param(0.1, 0.01, 1.0, "s", "TeraRanger older than this is N/A")
    imu_timeout_s: float = param(
        0.25, 0.02, 2.0, "s", "IMU older than this is N/A: nothing to integrate, the obstacle memory forgets (telemetry lost)"
    )
    sonar_max_range_m: float = param(4.9, 1.0, 7.0, "m", "HRLV-EZ4 usable range")
    tof_max_range_m: float = param(13.8, 1.0, 14.0, "m", "TeraRanger One usable range")
    height_jump_m: float = param(
        0.15, 0.05, 2.0, "m", "a bottom or front range this far from the observer's prediction is another "
        "surface (a floor step, a pillar's edge), not motion"
    )
    sonar_clamp_zone_m: float = param(
        0.35, 0.0, 2.0, "m", "a bottom sonar range below this may be its clamp (it reads 0.30 m when closer, "
        "+-0.01 m of noise): no floor step is taken, and the PX4Flow's speed, which that range scales, is not "
        "used (at 0.4 a box top 0.39 m below was taken for the clamp and the altitude lost 0.5 m)"
    )
    height_step_settle_samples: int = param(
        2, 0, 10, "samples", "after a floor step, height samples whose surprise is still the floor's (beam on the edge)"
    )
    # Speed observers (observers.SpeedObserver, one per axis): a Kalman filter of speed and
    # accelerometer bias with the IMU as input. Sources: docs/flight.md, State estimation.
    accel_noise_m_s2: float = param(
        0.1, 0.001, 5.0, "m/s^2/sqrt(Hz)", "speed observers: noise of the IMU's heading-frame acceleration "
        "(accelerometer noise, vibration, attitude-estimate noise x g)"
    )
    bias_walk_m_s2: float = param(
        0.03, 0.0, 1.0, "m/s^2/sqrt(s)", "speed observers: how fast the accelerometer's heading-frame bias "
        "wanders (the attitude estimate's drift and transients x g); learnt in ~3 s from the flow"
    )
    speed_noise_m_s: float = param(
        0.1, 0.001, 2.0, "m/s", "speed observers: noise of one range rate (a sonar's: a slope over 0.45 s, 0.015 m "
        "samples at 5 m give 0.05 m/s, consecutive slopes share 4 of 5 samples: x2; the height's) and the least "
        "of a flow reading's"
    )
    flow_noise_rad_s: float = param(
        0.05, 0.001, 1.0, "rad/s", "speed observers: angular noise of one PX4Flow reading of quality 255 (PX4's "
        "EKF2_OF_N_MIN; its image noise and the rotation its gyro leaves in); its speed noise is the angular noise x "
        "the range it sees, as PX4's EKF2 takes flow in rad/s, and at least speed_noise_m_s"
    )
    flow_noise_worst_rad_s: float = param(
        0.1, 0.001, 1.0, "rad/s", "speed observers: angular noise of a PX4Flow reading at flow_min_quality (PX4's "
        "EKF2_OF_N_MAX), linear in quality between the two as EKF2 weighs it. With one noise for every quality "
        "and flow refused below 80, low texture dropped the bottom flow at random and a link-loss hold drifted 0.32 m "
        "(0.07 m with this and flow_min_quality 40; docs/flight.md)"
    )
    observer_gate_sigma: float = param(
        4.0, 1.0, 20.0, "sigma", "speed observers: an innovation beyond this many standard deviations is not used (5 in a row: restart)"
    )
    alarm_climb_m_s: float = param(0.2, 0.01, 1.0, "m/s", "the '+val.' of the alarm modes: the steady alarm descent speed")
    alarm_descent_delay_s: float = param(
        1.0, 0.0, 10.0, "s", "alarm modes: '+val.' is filled in (the descent begins) once the alarm mode has lasted this long"
    )
    alarm_vz_leak_m_s2: float = param(
        0.01, 0.0, 1.0, "m/s^2", "mode -2: the carried vertical speed relaxes towards zero at this rate (about the "
        "vertical bias a short floor calibration leaves, which no sensor of mode -2 can see)"
    )
    alarm_slope_max_turn_rad: float = param(
        0.02, 0.0, 0.5, "rad", "alarm modes: range rates are not used while the heading turns more than this in their window"
    )
    carried_noise_sigma: float = param(
        1.0, 0.0, 10.0, "sigma", "alarm modes: a speed loop leaves alone an error within this many standard deviations "
        "of the random walk the IMU's own measured noise has put into the carried speed since a measurement last held it "
        "(1 against 2 on analysis seeds 309 and 311: 2 left real drifts unbraked, 14 episodes lost 5 cm of clearance)"
    )
    memory_keep_s: float = param(
        8.0, 0.0, 30.0, "s", "obstacle memory: an echo is forgotten after this long without a measured horizontal speed "
        "(the alarm modes; 0: no memory)"
    )
    memory_keep_travel_m: float = param(
        4.0, 0.1, 20.0, "m", "obstacle memory: or after this much travel (odometry drift: the measured odometry's "
        "worst error over 4 m of travel, median 0.07 m, p90 0.19 m, against 0.08 / 0.15 m over 2 m; campaign seed 11)"
    )
    body_radius_m: float = param(
        0.27, 0.0, 1.0, "m", "the vehicle's half-size (arm and rotor, AscTec Hummingbird): a remembered surface that "
        "left a sonar's beam stays until the vehicle has moved sideways of it by this plus the beam's half-width at its range, "
        "or up or down by this"
    )
    memory_max_angle_deg: float = param(60.0, 0.0, 89.0, "deg", "obstacle memory: surfaces facing an axis within this angle count for it")
    stuck_samples: int = param(
        3, 2, 100, "samples", "a PX4Flow or range sensor repeating its reading bit for bit this many times running, "
        "while the IMU says it changed (flow_stuck_imu_dv_m_s, sonar_stuck_travel_m), is stuck (one count for both "
        "since session 30: the flows' 5 and the sonars' 3: of the 228 stuck-reading episodes of seed 283, 3 changed, by under 1 cm)"
    )
    flow_stuck_imu_dv_m_s: float = param(
        0.15, 0.01, 2.0, "m/s", "a flow repeating its speed while the IMU-integrated speed changed by this much is stuck"
    )
    oblique_keep_s: float = param(1.0, 0.0, 30.0, "s", "a wall fitted to two oblique sonar readings is kept this long unless renewed")
    sonar_stuck_travel_m: float = param(
        0.1, 0.01, 2.0, "m", "a range sensor repeating its range while the vehicle moved this far along its axis is stuck "
        "(reads as silent)"
    )
    observer_pole_1_s: float = param(
        1.5, 0.1, 20.0, "1/s", "range observers: triple pole of the height's range / rate / accelerometer-bias "
        "observer (gains 3L, 3L^2, L^3); the front range, carried by the x observer's speed, takes 3L of each residual"
    )


@dataclass(frozen=True)
class BehaviorParams:
    attenuation_start_m: float = param(1.5, 0.5, 5.0, "m", "attenuated_go starts slowing here")
    safe_distance_m: float = param(1.0, 0.4, 4.0, "m", "minimum distance allowed to an obstacle")
    response_time_s: float = param(
        0.3, 0.0, 2.0, "s", "speed-loop lag used to predict where the vehicle stops: the behaviours' stop lines, and "
        "the height the controller holds when a vertical command ends (altitude + vz x this)"
    )
    brake_decel_m_s2: float = param(1.2, 0.2, 5.0, "m/s^2", "deceleration assumed when stopping")
    position_gain_1_s: float = param(
        2.5, 0.1, 5.0, "1/s", "speed per metre of position error: prevent_collision's back-off per metre inside the safe "
        "distance (beyond the dead band; at 1.6 a vehicle found 0.2 m inside once its range sensors came back, a blind "
        "drift, was still 0.13 m inside a second later), waiting_for_connectivity's speed back to the held point, "
        "limit_max_height's descent per metre above the ceiling and ensure_reference_surface_detection's return per "
        "metre beyond the reference range (1.0 and 0.6 /s of their own before session 30; neither acts in the campaign)"
    )
    hold_speed_max_m_s: float = param(
        0.4, 0.05, 1.0, "m/s", "the position holds move at most this fast: prevent_collision backing away (Fig. 6 E-F) "
        "and waiting_for_connectivity's station keeping"
    )
    oblique_margin_m_s: float = param(
        0.1, 0.0, 1.0, "m/s", "a range closing this much faster than the speed along its sensor's axis: an oblique "
        "surface (prevent_collision, and the estimator's oblique-wall fit)"
    )
    repulsion_deadband_m: float = param(
        0.05, 0.0, 0.3, "m", "inside the safe distance by less than this and not moving in: hold (0), no repulsion"
    )
    link_loss_deadband_m: float = param(
        0.2, 0.0, 0.5, "m",
        "while the link is lost (waiting_for_connectivity): the repulsion's dead band; the vehicle holds "
        "station a little inside the safe distance instead of backing away",
    )
    link_loss_rest_m_s: float = param(
        0.1, 0.0, 1.0, "m/s", "waiting_for_connectivity: hover until the speed estimate is below this, then hold that point"
    )
    covered_half_angle_deg: float = param(
        15.0, 0.0, 45.0, "deg", "half-width of the horizontal sonars' beams (the reading is the nearest echo in it): "
        "motion within it of an axis is seen; the estimator's oblique-wall fit uses it too, and the reach of a floor edge "
        "heard below (the downward sonar is the same HRLV)"
    )
    blind_attenuation_start_m: float = param(
        3.0, 1.0, 6.0, "m", "within this distance of the nearer wall a diagonal push between the beams flies only its "
        "component along the axis nearer its direction"
    )
    inspect_speed_m_s: float = param(0.2, 0.05, 0.5, "m/s", "fixed speed in inspection mode")
    stick_deadband_m_s: float = param(0.05, 0.0, 0.5, "m/s", "stick commands below this are zero (joystick centre noise)")
    floor_attenuation_start_m: float = param(1.0, 0.5, 3.0, "m", "descents slow from this height down to floor_clearance_m")
    floor_clearance_m: float = param(0.6, 0.4, 2.0, "m", "lowest height the user may fly down to")
    max_height_m: float = param(10.0, 1.0, 14.0, "m", "limit_max_height ceiling")
    max_height_margin_m: float = param(0.5, 0.1, 2.0, "m", "limit_max_height acts this far below")
    reference_range_m: float = param(4.5, 1.0, 5.0, "m", "keep floor or front wall within this")
    low_battery_percent: float = param(20.0, 0.0, 100.0, "%", "low_battery_land below this charge")
    max_speed_m_s: float = param(1.0, 0.1, 3.0, "m/s", "largest horizontal speed command")
    max_vertical_speed_m_s: float = param(0.6, 0.1, 2.0, "m/s", "largest vertical speed command (the HRLV's 10 Hz height still follows it)")


@dataclass(frozen=True)
class ControlParams:
    tick_hz: float = param(50.0, 10.0, 500.0, "Hz", "rate of estimation, behaviours and control")
    speed_kp_1_s: float = param(2.2, 0.0, 20.0, "1/s", "XY speed PID: m/s^2 per m/s")
    speed_ki_1_s2: float = param(
        5.0, 0.0, 20.0, "1/s^2", "XY speed PIDs' integral, on the speed's deviation from the command's reference "
        "model: the trim against drag and the air's slowly varying push that the feed-forward and the disturbance "
        "observers miss; 5 (from 3, session 28): Fig. 7's lateral passes 9/60 -> 4/60 off 0.20 +- 0.01 m/s on "
        "seeds 301-320, 0/60 on fresh 321-340"
    )
    speed_integrate_band_m_s: float = param(
        0.3, 0.0, 10.0, "m/s", "XY speed PID integrates only deviations from the command's reference model within this "
        "(integral separation: a stop the model has not followed, a restarted speed estimate)"
    )
    speed_drag_ff_1_s: float = param(
        0.15, 0.0, 2.0, "1/s", "XY feed-forward m/s^2 per commanded m/s (nominal rotor drag / mass)"
    )
    vz_kp_1_s: float = param(3.0, 0.0, 20.0, "1/s", "vertical speed PID: m/s^2 per m/s")
    vz_ki_1_s2: float = param(
        3.0, 0.0, 20.0, "1/s^2", "vertical speed PID's integral on the deviation from the command's reference model: "
        "the hover trim (mass and thrust error); at the XY loops' 5 the register bench's walls lost two known defects "
        "and gained two other entries (session 28), and at 6 a landing after an alarm descent met the floor too fast"
    )
    height_kp_1_s2: float = param(3.0, 0.0, 20.0, "1/s^2", "height PID: m/s^2 per m")
    height_ki_1_s3: float = param(0.8, 0.0, 20.0, "1/s^3", "height PID integral: the hover trim while holding height")
    height_kd_1_s: float = param(2.8, 0.0, 20.0, "1/s", "height PID damping on the measured vertical speed")
    height_integral_band_m: float = param(0.1, 0.0, 5.0, "m", "height PID integrates within this error")
    integral_limit_m_s2: float = param(2.0, 0.0, 10.0, "m/s^2", "XY speed integrator clamp (about 11 deg of tilt)")
    vertical_trim_limit_m_s2: float = param(
        6.0, 0.0, 10.0, "m/s^2", "vertical trim range, of the speed integrator and of the disturbance observer: "
        "+-30 % mass or thrust needs ~4.2 m/s^2"
    )
    accel_observer_tau_s: float = param(
        0.25, 0.0, 5.0, "s", "disturbance observers (IMU), vertical and horizontal: time constant (0: off)"
    )
    accel_observer_xy_limit_m_s2: float = param(
        1.5, 0.0, 10.0, "m/s^2", "horizontal disturbance observers: largest wind force it makes up (0: off)"
    )
    accel_observer_xy_band_m_s2: float = param(
        0.1, 0.0, 2.0, "m/s^2", "horizontal disturbance observers: what the attitude estimate's transient can show "
        "(g x 0.6 deg: 5 % of a/g at 2 m/s^2) is left to the integrators; only the excess is a disturbance "
        "(tried on the paper scenarios: 0.17 drifted Fig. 5 mode 3 by 0.251 m, 0.1: 0.240 m, sweep 0.199/0.206 m/s)"
    )
    accel_observer_noise_sigma: float = param(
        3.0, 0.0, 10.0, "sigma", "horizontal disturbance observers: a push within this many standard deviations of "
        "what the IMU's own noise gives them is left out too (the noise measured in flight: rotor vibration of 1.4 "
        "m/s^2 a tick made them push 0.3-0.7 m/s^2 at random, unseen in an alarm mode; docs/flight.md)"
    )
    accel_observer_lag_s: float = param(
        0.06, 0.0, 1.0, "s", "disturbance observers: attitude and motor lag between set-point and acceleration"
    )
    accel_observer_drag_1_s: float = param(
        0.4, 0.0, 5.0, "1/s", "disturbance observers: nominal rotor drag deceleration per m/s of speed"
    )
    max_tilt_rad: float = param(0.3, 0.05, 0.6, "rad", "largest roll/pitch set-point (3 m/s^2 horizontal; the firmware allows 0.6)")
    max_vertical_accel_m_s2: float = param(4.0, 0.5, 15.0, "m/s^2", "vertical acceleration command limit around the trim (thrust-to-weight 2.2 leaves ~12)")
    takeoff_trim_ramp_m_s3: float = param(
        2.0, 0.0, 20.0, "m/s^3", "taking off without lifting after 1 s: extra growth of the vertical trim"
    )
    hover_thrust_frac: float = param(0.4545, 0.1, 0.9, "1", "nominal thrust to hover / max thrust")


@dataclass(frozen=True)
class FlightMachineParams:
    takeoff_climb_m_s: float = param(0.5, 0.1, 2.0, "m/s", "take-off climb speed")
    flying_height_m: float = param(
        0.5, 0.2, 2.0, "m", "taking_off -> flying above this, descending -> landing below it (and mode -1's jolt is "
        "the floor only below it)"
    )
    takeoff_high_thrust_s: float = param(4.0, 0.5, 20.0, "s", "or after this long at high thrust")
    hover_height_m: float = param(1.0, 0.5, 5.0, "m", "height held after take-off")
    descend_speed_m_s: float = param(0.4, 0.1, 1.5, "m/s", "descending (land requested) until flying_height_m")
    touchdown_confirm_s: float = param(0.2, 0.0, 2.0, "s", "landing: ground-like height and speed this long = touchdown")
    landing_speed_m_s: float = param(0.25, 0.05, 1.0, "m/s", "final landing speed (below the 1 m/s a floor contact counts as a crash)")
    impact_accel_m_s2: float = param(
        3.0, 0.5, 30.0, "m/s^2", "IMU upward jolt that means touchdown; where no height is measured, also the floor's "
        "lasting push: the vertical disturbance observer's value fallen this far below its level when a height was "
        "last measured (a touchdown too soft for a jolt, OnboardStack._floor_holds)"
    )
    impact_noise_sigma: float = param(
        5.0, 0.0, 20.0, "sigma", "... and beyond this many RMS of the IMU's recent unexplained lift in flight (vibration)"
    )
    landing_ramp_s: float = param(1.5, 0.2, 20.0, "s", "thrust ramp-down after touchdown")


@dataclass(frozen=True)
class StackParams:
    estimation: EstimationParams = field(default_factory=EstimationParams)
    behaviors: BehaviorParams = field(default_factory=BehaviorParams)
    control: ControlParams = field(default_factory=ControlParams)
    flight_machine: FlightMachineParams = field(default_factory=FlightMachineParams)

    def validate(self) -> "StackParams":
        for group in (self.estimation, self.behaviors, self.control, self.flight_machine):
            _check(group)
        return self

    def replace(self, **groups) -> "StackParams":
        return dataclasses.replace(self, **groups).validate()


def load_params(path: str | Path) -> StackParams:
    """Stack parameters from a YAML or JSON file ``{group: {name: value}}`` over the defaults
    (groups: estimation, behaviors, control, flight_machine). A missing or unreadable file, an
    unknown group or name, a value that is not a number, or one outside its declared bounds is an
    :class:`InputError` naming the file and the field (one line, exit 2 on the CLI)."""
    from inspect_pipe._yaml import load_yaml
    from inspect_pipe.errors import InputError

    src = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(src, "parameter file not found", "give the path of a YAML or JSON parameter file") from None
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(src, f"not a readable YAML/JSON file ({type(err).__name__})", "a mapping {group: {name: value}}") from None
    doc = load_yaml(text, src, "a mapping {group: {name: value}}")
    doc = {} if doc is None else doc
    if not isinstance(doc, dict):
        raise InputError(src, f"is {type(doc).__name__}", "a mapping {group: {name: value}}")
    defaults = StackParams()
    groups = {f.name: getattr(defaults, f.name) for f in fields(defaults)}
    new = {}
    for gname, values in doc.items():
        if gname not in groups:
            raise InputError(src, f"field '{gname}': unknown group", "one of " + ", ".join(groups))
        if not isinstance(values, dict):
            raise InputError(src, f"field '{gname}': is " + ("empty" if values is None else type(values).__name__), "a mapping {name: value}")
        group = groups[gname]
        known = {f.name: f for f in fields(group)}
        changes = {}
        for name, value in values.items():
            f = known.get(name)
            if f is None:
                raise InputError(src, f"field '{gname}.{name}': unknown parameter", f"one of the {gname} parameters (docs/flight.md)")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value:
                raise InputError(src, f"field '{gname}.{name}': is {reprlib.repr(value)}", "a number")
            m = f.metadata
            if "min" in m and not (m["min"] <= value <= m["max"]):
                raise InputError(src, f"field '{gname}.{name}': {value} outside [{m['min']}, {m['max']}] {m['unit']}", "a value within its bounds")
            if isinstance(getattr(group, name), int) and not isinstance(getattr(group, name), bool):
                if value != int(value):
                    raise InputError(src, f"field '{gname}.{name}': {value} is not an integer", "an integer")
                value = int(value)
            changes[name] = value
        new[gname] = dataclasses.replace(group, **changes)
    return defaults.replace(**new)


def describe(params: StackParams | None = None) -> list[tuple[str, float, float, float, str, str]]:
    """Rows (name, value, min, max, unit, doc) of every parameter."""
    params = params or StackParams()
    rows = []
    for group_field in fields(params):
        group = getattr(params, group_field.name)
        for f in fields(group):
            m = f.metadata
            rows.append(
                (f"{group_field.name}.{f.name}", getattr(group, f.name), m["min"], m["max"], m["unit"], m["doc"])
            )
    return rows
