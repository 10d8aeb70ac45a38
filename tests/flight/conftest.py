"""Flies each scenario of ``scenarios/`` at most once per test session."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import pytest

from inspect_pipe.flight import FlightResult, TickRecord, load_scenario, run_scenario

SCENARIOS = Path(__file__).resolve().parents[2] / "scenarios"


@dataclass(frozen=True)
class Flight:
    result: FlightResult
    ticks: list[TickRecord]

    def between(self, t0: float, t1: float) -> list[TickRecord]:
        return [r for r in self.ticks if t0 <= r.t <= t1]

    def at(self, t: float) -> TickRecord:
        return min(self.ticks, key=lambda r: abs(r.t - t))


@functools.lru_cache(maxsize=None)
def fly(name: str) -> Flight:
    ticks: list[TickRecord] = []
    result = run_scenario(load_scenario(SCENARIOS / f"{name}.yaml"), on_tick=ticks.append)
    return Flight(result, ticks)


@pytest.fixture
def scenarios_dir() -> Path:
    return SCENARIOS


@pytest.fixture(name="fly")
def fly_fixture():
    """``fly(name)`` -> :class:`Flight` of ``scenarios/<name>.yaml`` (flown once per session)."""
    return fly
