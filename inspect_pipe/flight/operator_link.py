"""The operator's joystick at the base station and the WiFi link to the vehicle.

The base station sends the stick state and the buttons pressed since its last message at
``rate_hz``; messages arrive ``latency_s`` later unless a ``link_loss`` fault is active (then they
are lost, buttons included). Onboard, the link is OK while the last message is younger than
``timeout_s``.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from inspect_pipe.flight.scenario import ButtonEvent, Fault, FaultKind, StickEvent
from inspect_pipe.flight_stack.messages import HOVER, Button, OperatorInput, SpeedCommand

__all__ = ["LinkSpec", "OperatorLink"]


@dataclass(frozen=True)
class LinkSpec:
    rate_hz: float = 20.0
    latency_s: float = 0.03
    timeout_s: float = 0.25


class OperatorLink:
    def __init__(self, events: tuple[StickEvent | ButtonEvent, ...], faults: tuple[Fault, ...], spec: LinkSpec | None = None) -> None:
        self.spec = spec or LinkSpec()
        self.events = list(events)
        self.losses = [f for f in faults if f.kind is FaultKind.LINK_LOSS]
        self._next_event = 0
        self._stick = HOVER
        self._pending: set[Button] = set()
        self._next_send = 0.0
        self._in_flight: deque[tuple[float, SpeedCommand, frozenset[Button]]] = deque()
        self._rx_stick = HOVER
        self._rx_buttons: set[Button] = set()
        self._last_rx: float | None = None
        self.last_sent_ok: float | None = None

    def link_down(self, t: float) -> bool:
        return any(f.active(t) for f in self.losses)

    def advance(self, t: float) -> None:
        """Base station side up to time ``t``: apply joystick events, send messages."""
        while self._next_event < len(self.events) and self.events[self._next_event].t_s <= t:
            e = self.events[self._next_event]
            self._next_event += 1
            if isinstance(e, StickEvent):
                self._stick = e.stick
            else:
                self._pending.add(e.button)
        while self._next_send <= t:
            ts = self._next_send
            self._next_send += 1.0 / self.spec.rate_hz
            if self.link_down(ts):
                self._pending.clear()  # lost with the message
                continue
            self._in_flight.append((ts + self.spec.latency_s, self._stick, frozenset(self._pending)))
            self._pending.clear()
            self.last_sent_ok = ts

    def receive(self, now: float) -> OperatorInput:
        """Onboard side: what has arrived by ``now``."""
        q = self._in_flight
        while q and q[0][0] <= now:
            arrival, stick, buttons = q.popleft()
            self._rx_stick = stick
            self._rx_buttons |= buttons
            self._last_rx = arrival
        ok = self._last_rx is not None and now - self._last_rx <= self.spec.timeout_s
        buttons = frozenset(self._rx_buttons)
        self._rx_buttons.clear()
        return OperatorInput(stick=self._rx_stick if ok else HOVER, buttons=buttons, link_ok=ok)

    @property
    def stick(self) -> SpeedCommand:
        """The stick as the operator holds it now (base station side)."""
        return self._stick
