"""``messages.message``: a frozen, slotted dataclass whose ``__init__`` stores through the slots'
descriptors. It must behave as ``dataclass(frozen=True, slots=True)`` does."""

import dataclasses

import pytest

from inspect_pipe.flight_stack.messages import BottomFlow, SpeedCommand, message


@message
class _Sample:
    a: float
    b: int = 2
    c: tuple = ()


@dataclasses.dataclass(frozen=True, slots=True)
class _Plain:
    a: float
    b: int = 2
    c: tuple = ()


def test_message_is_a_frozen_slotted_dataclass():
    s = _Sample(1.0)
    assert dataclasses.is_dataclass(s) and not hasattr(s, "__dict__")
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.a = 3.0  # type: ignore[misc]
    assert [f.name for f in dataclasses.fields(s)] == ["a", "b", "c"]


def test_message_init_takes_arguments_as_the_generated_one():
    for args, kwargs in (((1.0,), {}), ((1.0, 5), {}), ((1.0,), {"c": (1,)}), ((), {"a": 0.5, "b": 7})):
        assert dataclasses.astuple(_Sample(*args, **kwargs)) == dataclasses.astuple(_Plain(*args, **kwargs))
    with pytest.raises(TypeError):
        _Sample()  # type: ignore[call-arg]
    with pytest.raises(TypeError):
        _Sample(1.0, 2, (), 4)  # type: ignore[call-arg]
    with pytest.raises(TypeError):
        _Sample(1.0, d=3)  # type: ignore[call-arg]


def test_message_equality_hash_repr_and_replace():
    s = SpeedCommand(0.2, vz_m_s=-0.1)
    assert s == SpeedCommand(0.2, 0.0, -0.1, 0.0) and hash(s) == hash(SpeedCommand(0.2, 0.0, -0.1))
    assert repr(s) == "SpeedCommand(vx_m_s=0.2, vy_m_s=0.0, vz_m_s=-0.1, yaw_rate_rad_s=0.0)"
    assert dataclasses.replace(s, vx_m_s=1.0) == SpeedCommand(1.0, 0.0, -0.1)
    f = BottomFlow(1.5, 0.1, -0.2, 200)
    assert (f.stamp_s, f.vx_m_s, f.vy_m_s, f.quality) == (1.5, 0.1, -0.2, 200)
