"""MAVLink enums and mode tables come from pymavlink; without it, one clear line."""

from __future__ import annotations

import importlib.util
import sys

import pytest

from inspect_pipe.errors import InputError

CODEC = "inspect_pipe.flight.mavlink_codec"


def _fresh_codec(monkeypatch):
    """A new copy of the codec module (its lazily filled attributes empty)."""
    name = CODEC + "_fresh"
    spec = importlib.util.spec_from_file_location(name, importlib.util.find_spec(CODEC).origin)
    mod = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, mod)
    spec.loader.exec_module(mod)
    return mod


def test_constants_and_mode_tables_are_pymavlinks(monkeypatch):
    pytest.importorskip("pymavlink", reason="needs the [mavlink] extra")
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import common

    mc = _fresh_codec(monkeypatch)
    assert mc.MAV_CMD_NAV_TAKEOFF == common.MAV_CMD_NAV_TAKEOFF == 22
    assert mc.MAV_RESULT_ACCEPTED == 0 and mc.MAV_AUTOPILOT_PX4 == 12 and mc.MAV_FRAME_BODY_FRD == 12
    assert mc.VELOCITY_ONLY_MASK == 1 | 2 | 4 | 64 | 128 | 256 | 1024  # velocity and yaw rate only
    # PX4: main modes as mavutil's px4_map encodes them, AUTO sub-modes in bits 24..31
    for name, (_, main, sub) in mavutil.px4_map.items():
        if sub == 0:
            assert mc.Px4Mode[name] == main
    assert mc.px4_custom_mode(mc.Px4Mode.AUTO, mc.PX4_AUTO_LAND) == (4 << 16) | (6 << 24)
    assert (mc.PX4_AUTO_LOITER, mc.PX4_AUTO_TAKEOFF) == (3, 2)
    assert mc.px4_main_mode(mc.px4_custom_mode(mc.Px4Mode.OFFBOARD)) == 6
    assert {m.name: m.value for m in mc.ArduCopterMode} == {v: k for k, v in mavutil.mode_mapping_acm.items()}
    assert (mc.ArduCopterMode.GUIDED, mc.ArduCopterMode.LAND, mc.ArduCopterMode.BRAKE) == (4, 9, 17)
    assert [m.name for m in mc.LandedState] == ["UNDEFINED", "ON_GROUND", "IN_AIR", "TAKEOFF", "LANDING"]
    assert mc.distance_slot(common.MAV_DISTANCE_SENSOR_LASER, common.MAV_SENSOR_ROTATION_PITCH_270) is mc.DistanceSlot.BOTTOM_TOF
    for slot, (_, kind, orient, _, _) in mc.DISTANCE_SENSORS.items():
        assert mc.distance_slot(kind, orient) is slot
    with pytest.raises(AttributeError):
        mc.NOT_A_MAVLINK_NAME


def test_without_pymavlink_the_pure_conversions_work_and_an_enum_is_one_clear_line(monkeypatch):
    for name in [m for m in sys.modules if m == "pymavlink" or m.startswith("pymavlink.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "pymavlink", None)  # import pymavlink -> ImportError
    mc = _fresh_codec(monkeypatch)
    assert mc.px4_custom_mode(6) == 6 << 16 and mc.Autopilot("px4") is mc.Autopilot.PX4
    with pytest.raises(InputError, match=r"pymavlink is not installed.*pip install 'inspect-pipe\[mavlink\]'"):
        mc.MAV_CMD_NAV_LAND
    with pytest.raises(InputError, match="pymavlink is not installed"):
        mc.ArduCopterMode


def test_the_capture_state_tracker_reads_landed_state_and_sensor_orientation_by_pymavlinks_names():
    pytest.importorskip("pymavlink", reason="needs the [mavlink] extra")
    from pymavlink.dialects.v20 import common as c

    from inspect_pipe.capture._vehicle_feed import AutopilotStateTracker

    t = AutopilotStateTracker()
    words = []
    for state in (c.MAV_LANDED_STATE_ON_GROUND, c.MAV_LANDED_STATE_TAKEOFF, c.MAV_LANDED_STATE_IN_AIR, c.MAV_LANDED_STATE_LANDING,
                  c.MAV_LANDED_STATE_UNDEFINED, 77):
        t.on_message(c.MAVLink_extended_sys_state_message(0, state), 1.0)
        words.append(t.landed_state)
    assert words == ["landed", "taking_off", "flying", "landing", None, None]
