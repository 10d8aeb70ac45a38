"""Behaviour arbitration of the paper's hybrid competitive-cooperative framework.

Three composites, each a node like a behaviour, so a tree of them is the ``MAV_behaviors`` node:

* :class:`Subsumption`: children in priority order; a higher child suppresses the lower ones on
  the axes it commands (per axis, so a wall ahead suppresses only the longitudinal user command).
* :class:`MotorSchema`: cooperation within one level, the weighted sum of the children's vectors.
* :class:`Multiplexer`: selects one child by an input (e.g. inspection mode).

A node's ``evaluate(inputs, dt)`` returns an :class:`Output` (vector and the names of the
behaviours that shaped it) or None when it commands nothing.
"""

from __future__ import annotations

from typing import Callable, Hashable, Protocol, Sequence

from inspect_pipe.flight_stack.messages import AxisVector, BehaviorInputs, message

__all__ = ["Behavior", "Leaf", "MotorSchema", "Multiplexer", "Node", "Output", "Subsumption"]


@message
class Output:
    vector: AxisVector
    sources: tuple[str, ...]


class Behavior(Protocol):
    """One behaviour: ``activate`` on entry, ``update`` each tick (None: not commanded)."""

    name: str

    def activate(self) -> None: ...

    def update(self, inputs: BehaviorInputs, dt: float) -> AxisVector | None: ...


class Node(Protocol):
    def activate(self) -> None: ...

    def evaluate(self, inputs: BehaviorInputs, dt: float) -> Output | None: ...


class Leaf:
    """Wraps a behaviour as a node of the arbitration tree."""

    def __init__(self, behavior: Behavior) -> None:
        self.behavior = behavior

    def activate(self) -> None:
        self.behavior.activate()

    def evaluate(self, inputs: BehaviorInputs, dt: float) -> Output | None:
        vec = self.behavior.update(inputs, dt)
        if vec is None or vec.is_empty():
            return None
        return Output(vec, (self.behavior.name,))


def _node(x: Node | Behavior) -> Node:
    return x if hasattr(x, "evaluate") else Leaf(x)  # type: ignore[arg-type,return-value]


class Subsumption:
    """Priority suppression, per axis; ``children`` highest priority first."""

    def __init__(self, children: Sequence[Node | Behavior]) -> None:
        self.children = [_node(c) for c in children]

    def activate(self) -> None:
        for c in self.children:
            c.activate()

    def evaluate(self, inputs: BehaviorInputs, dt: float) -> Output | None:
        # Every child runs every tick: a suppressed behaviour still keeps its state current.
        outs = [c.evaluate(inputs, dt) for c in self.children]
        axes: list[float | None] = [None, None, None, None]
        winners: list[Output | None] = [None, None, None, None]
        for out in outs:
            if out is None:
                continue
            for i, a in enumerate(out.vector.axes()):
                if axes[i] is None and a is not None:
                    axes[i] = a
                    winners[i] = out
        sources: list[str] = []
        for out in outs:
            if out is not None and any(w is out for w in winners):
                sources.extend(s for s in out.sources if s not in sources)
        if not sources:
            return None
        return Output(AxisVector(*axes), tuple(sources))


class MotorSchema:
    """Cooperation: weighted sum of the children's vectors, per commanded axis."""

    def __init__(self, children: Sequence[tuple[Node | Behavior, float]]) -> None:
        self.children = [(_node(c), w) for c, w in children]

    def activate(self) -> None:
        for c, _ in self.children:
            c.activate()

    def evaluate(self, inputs: BehaviorInputs, dt: float) -> Output | None:
        axes: list[float | None] = [None, None, None, None]
        sources: list[str] = []
        for child, weight in self.children:
            out = child.evaluate(inputs, dt)
            if out is None:
                continue
            for i, a in enumerate(out.vector.axes()):
                if a is not None:
                    axes[i] = (axes[i] or 0.0) + weight * a
            sources.extend(s for s in out.sources if s not in sources)
        if not sources:
            return None
        return Output(AxisVector(*axes), tuple(sources))


class Multiplexer:
    """Flow control: ``select(inputs)`` picks which child runs; a newly picked child is activated."""

    def __init__(self, select: Callable[[BehaviorInputs], Hashable], branches: dict[Hashable, Node | Behavior]) -> None:
        self.select = select
        self.branches = {k: _node(v) for k, v in branches.items()}
        self._current: Hashable | None = None

    def activate(self) -> None:
        self._current = None

    def evaluate(self, inputs: BehaviorInputs, dt: float) -> Output | None:
        key = self.select(inputs)
        if key not in self.branches:
            return None
        if key != self._current:
            self.branches[key].activate()
            self._current = key
        return self.branches[key].evaluate(inputs, dt)
