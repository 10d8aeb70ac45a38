"""Exact geometry of a hold (floor, four walls, open top, axis-aligned boxes) for ground truth:
clearances along the world axes and the distance to the nearest surface. Pure Python floats."""

from __future__ import annotations

import math

from inspect_pipe.flight.scenario import World
from inspect_pipe.flight_stack.messages import message

__all__ = ["Clearances", "HoldGeometry"]


@message
class Clearances:
    """True clearance from the vehicle's centre along each world direction (m); ``inf`` upwards
    of an open top is not reported."""

    front: float
    back: float
    left: float
    right: float
    down: float


class HoldGeometry:
    def __init__(self, world: World) -> None:
        h = world.hold
        self.length, self.half_w, self.height = h.length_m, h.width_m / 2.0, h.height_m
        self.boxes = [(b.min_m, b.max_m) for b in world.boxes]

    def clearances(self, x: float, y: float, z: float) -> Clearances:
        front, back = self.length - x, x
        left, right = self.half_w - y, y + self.half_w
        down = z
        for (x0, y0, z0), (x1, y1, z1) in self.boxes:
            in_y = y0 <= y <= y1
            in_z = z0 <= z <= z1
            in_x = x0 <= x <= x1
            if in_y and in_z:
                if x <= x0:
                    front = min(front, x0 - x)
                elif x >= x1:
                    back = min(back, x - x1)
            if in_x and in_z:
                if y <= y0:
                    left = min(left, y0 - y)
                elif y >= y1:
                    right = min(right, y - y1)
            if in_x and in_y and z >= z1:
                down = min(down, z - z1)
        return Clearances(front, back, left, right, down)

    def wall_distance(self, x: float, y: float, z: float) -> float:
        """Distance to the nearest wall or box (not the floor)."""
        d = min(self.length - x, x, self.half_w - y, y + self.half_w)
        for (x0, y0, z0), (x1, y1, z1) in self.boxes:
            dx = max(x0 - x, 0.0, x - x1)
            dy = max(y0 - y, 0.0, y - y1)
            dz = max(z0 - z, 0.0, z - z1)
            d = min(d, math.sqrt(dx * dx + dy * dy + dz * dz))
        return d

    def side_distance(self, x: float, y: float, z: float) -> float:
        """Like :meth:`wall_distance`, but a box whose top is straight below the centre counts as
        floor (a surface to land on), not as an obstacle: the nearest of :meth:`surface_distances`."""
        return min(self.surface_distances(x, y, z))

    def surface_distances(self, x: float, y: float, z: float) -> list[float]:
        """The distance to each wall and each box, one by one (the four walls, then the boxes in
        order; ``inf`` for a box whose top is straight below, which counts as floor)."""
        out = [self.length - x, x, self.half_w - y, y + self.half_w]
        for (x0, y0, z0), (x1, y1, z1) in self.boxes:
            dx = max(x0 - x, 0.0, x - x1)
            dy = max(y0 - y, 0.0, y - y1)
            if dx == 0.0 and dy == 0.0 and z >= z1:
                out.append(math.inf)
                continue
            dz = max(z0 - z, 0.0, z - z1)
            out.append(math.sqrt(dx * dx + dy * dy + dz * dz))
        return out

    def floor_distance(self, z: float) -> float:
        return z
