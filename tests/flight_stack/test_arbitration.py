"""Arbitration composites filled with scripted stub behaviours."""

from __future__ import annotations

import pytest

from inspect_pipe.flight_stack.arbitration import MotorSchema, Multiplexer, Subsumption
from inspect_pipe.flight_stack.messages import (
    AxisVector,
    BehaviorInputs,
    Clearance,
    EstimationMode,
    SpeedCommand,
    StateEstimate,
)


class Scripted:
    """A behaviour that returns a fixed vector and counts its lifecycle calls."""

    def __init__(self, name: str, vector: AxisVector | None) -> None:
        self.name, self.vector = name, vector
        self.activations = 0
        self.updates = 0

    def activate(self) -> None:
        self.activations += 1

    def update(self, inputs, dt):
        self.updates += 1
        return self.vector


def _inputs(inspection: bool = False) -> BehaviorInputs:
    est = StateEstimate(1.0, 1.0, 0.0, 0.0, 0.0, EstimationMode.BOTTOM)
    return BehaviorInputs(0.0, est, Clearance(), SpeedCommand(), True, inspection, False, 100.0, True)


def test_subsumption_suppresses_per_axis_and_names_contributors():
    # GIVEN a high behaviour commanding X only over a low one commanding every axis
    high = Scripted("high", AxisVector(vx_m_s=-0.2))
    low = Scripted("low", AxisVector(0.4, 0.1, 0.0, 0.3))
    out = Subsumption([high, low]).evaluate(_inputs(), 0.02)
    # THEN X comes from the high one, the other axes from the low one, and both are named
    assert out.vector == AxisVector(-0.2, 0.1, 0.0, 0.3)
    assert out.sources == ("high", "low")


def test_subsumption_fully_suppressed_behaviour_still_runs_but_is_not_named():
    high = Scripted("high", AxisVector(1.0, 2.0, 3.0, 4.0))
    low = Scripted("low", AxisVector(0.4, 0.1, 0.0, 0.3))
    out = Subsumption([high, low]).evaluate(_inputs(), 0.02)
    assert out.sources == ("high",)
    assert low.updates == 1  # keeps its state current while suppressed


def test_motor_schema_is_the_weighted_sum_of_commanded_axes():
    a = Scripted("a", AxisVector(vx_m_s=0.4, vz_m_s=-0.1))
    b = Scripted("b", AxisVector(vx_m_s=-0.2))
    c = Scripted("c", None)
    out = MotorSchema([(a, 1.0), (b, 0.5), (c, 1.0)]).evaluate(_inputs(), 0.02)
    assert out.vector.vx_m_s == pytest.approx(0.3)
    assert out.vector.vz_m_s == pytest.approx(-0.1)
    assert out.vector.vy_m_s is None
    assert out.sources == ("a", "b")


def test_multiplexer_selects_by_input_and_activates_on_switch():
    go, inspect = Scripted("go", AxisVector(vx_m_s=0.4)), Scripted("inspect", AxisVector(vy_m_s=0.2))
    mux = Multiplexer(lambda i: i.inspection_mode, {False: go, True: inspect})
    assert mux.evaluate(_inputs(False), 0.02).sources == ("go",)
    assert mux.evaluate(_inputs(False), 0.02).sources == ("go",)
    assert mux.evaluate(_inputs(True), 0.02).sources == ("inspect",)
    assert (go.activations, inspect.activations) == (1, 1)
    assert go.updates == 2  # the unselected branch does not run


def test_nothing_commanded_gives_none():
    assert Subsumption([Scripted("a", None), MotorSchema([(Scripted("b", AxisVector()), 1.0)])]).evaluate(_inputs(), 0.02) is None
