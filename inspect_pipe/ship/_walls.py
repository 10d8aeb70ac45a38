"""The hold's walls and their wall frames (``docs/ship.md``, SPEC.md "Wall frames").

Hold (world) frame: origin on the tank top at the middle of the aft wall, ``x`` forward, ``y`` to
port, ``z`` up. Each wall has a frame as seen by the vehicle facing it: ``u`` metres to the right
from the wall's left edge, ``v`` metres up from the tank top.

    front (fore bulkhead)      u = W/2 - y      faced with heading   0 deg
    left  (port side shell)    u = x            faced with heading  90 deg
    back  (aft bulkhead)       u = W/2 + y      faced with heading 180 deg
    right (starboard shell)    u = L - x        faced with heading 270 deg

The tank top, seen from above with the bow up, has ``u = W/2 - y`` (to starboard) and ``v = x``.
Pure geometry: no I/O.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Wall", "WallFrame", "wall_frame"]


class Wall(str, enum.Enum):
    """A surface of the hold, named as the survey plan names it; ``.sim`` is the simulator's name."""

    FORE_TRANSVERSE_BULKHEAD = "fore_transverse_bulkhead"
    AFT_TRANSVERSE_BULKHEAD = "aft_transverse_bulkhead"
    PORT_SIDE_SHELL = "port_side_shell"
    STARBOARD_SIDE_SHELL = "starboard_side_shell"
    TANK_TOP = "tank_top"

    @property
    def sim(self) -> str:
        return _SIM_NAME[self]

    @property
    def is_bulkhead(self) -> bool:
        return self in (Wall.FORE_TRANSVERSE_BULKHEAD, Wall.AFT_TRANSVERSE_BULKHEAD)

    @property
    def is_side_shell(self) -> bool:
        return self in (Wall.PORT_SIDE_SHELL, Wall.STARBOARD_SIDE_SHELL)

    @property
    def title(self) -> str:
        return self.value.replace("_", " ")

    @classmethod
    def parse(cls, name: str) -> "Wall":
        """A plan name (``port_side_shell``) or a simulator name (``left``)."""
        for w in cls:
            if name in (w.value, _SIM_NAME[w]):
                return w
        raise ValueError(name)


_SIM_NAME = {
    Wall.FORE_TRANSVERSE_BULKHEAD: "front",
    Wall.AFT_TRANSVERSE_BULKHEAD: "back",
    Wall.PORT_SIDE_SHELL: "left",
    Wall.STARBOARD_SIDE_SHELL: "right",
    Wall.TANK_TOP: "floor",
}
SIM_WALLS = ("front", "back", "left", "right")


@dataclass(frozen=True)
class WallFrame:
    """One wall's frame: the affine map wall (u, v) m -> hold (x, y, z) m and back.

    ``origin`` is the hold point of (u, v) = (0, 0); ``e_u`` and ``e_v`` are unit vectors of the
    wall's axes in the hold; ``normal`` points from the wall into the hold (where the camera is)."""

    wall: Wall
    origin: np.ndarray  # (3,)
    e_u: np.ndarray  # (3,)
    e_v: np.ndarray  # (3,)
    normal: np.ndarray  # (3,) into the hold
    width_m: float | None  # extent of u, where the hold's dimensions give it
    facing_heading_rad: float  # vehicle heading that faces the wall (0 forward, +pi/2 port)

    def to_hold(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) wall m -> (N, 3) hold m (points on the wall plane)."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        return self.origin + uv[:, :1] * self.e_u + uv[:, 1:2] * self.e_v

    def to_wall(self, xyz: np.ndarray) -> np.ndarray:
        """(N, 3) hold m -> (N, 2) wall (u, v) of their orthogonal projection on the wall plane."""
        d = np.asarray(xyz, float).reshape(-1, 3) - self.origin
        return np.c_[d @ self.e_u, d @ self.e_v]

    def distance(self, xyz: np.ndarray) -> np.ndarray:
        """(N,) distance of hold points in front of the wall (positive inside the hold)."""
        return (np.asarray(xyz, float).reshape(-1, 3) - self.origin) @ self.normal

    def homography_to_frame(self, K: np.ndarray, R_world_cam: np.ndarray, c_world: np.ndarray) -> np.ndarray:
        """3x3 H: wall (u, v, 1) m -> undistorted frame pixels of a pinhole camera at ``c_world``
        with camera-to-hold rotation ``R_world_cam``. Exact: a plane through a pinhole."""
        M = np.c_[self.e_u, self.e_v, self.origin - np.asarray(c_world, float)]
        H = np.asarray(K, float) @ np.asarray(R_world_cam, float).T @ M
        return H / H[2, 2] if abs(H[2, 2]) > 1e-12 else H


def wall_frame(wall: Wall | str, length_m: float | None, width_m: float | None) -> WallFrame:
    """The frame of ``wall`` in a hold of ``length_m`` (x) by ``width_m`` (y). A dimension the wall
    needs but that is unknown raises ValueError naming it."""
    w = Wall.parse(wall) if isinstance(wall, str) else wall

    def need(value: float | None, what: str) -> float:
        if value is None:
            raise ValueError(f"the hold's {what} is needed for the {w.title}'s wall frame")
        return float(value)

    ex, ey, ez = np.eye(3)
    # The side shells' u needs no breadth (u = x, or L - x): without width_m their plane is put at
    # y = 0, which leaves (u, v) right and only distance() and homographies wrong (the simulator,
    # which uses those, always knows the hold).
    half_w = None if width_m is None else float(width_m) / 2
    if w is Wall.FORE_TRANSVERSE_BULKHEAD:
        L, W = need(length_m, "length_m"), need(width_m, "width_m")
        return WallFrame(w, np.array([L, W / 2, 0.0]), -ey, ez, -ex, W, 0.0)
    if w is Wall.PORT_SIDE_SHELL:
        return WallFrame(w, np.array([0.0, half_w or 0.0, 0.0]), ex, ez, -ey, length_m, math.pi / 2)
    if w is Wall.AFT_TRANSVERSE_BULKHEAD:
        W = need(width_m, "width_m")
        return WallFrame(w, np.array([0.0, -W / 2, 0.0]), ey, ez, ex, W, math.pi)
    if w is Wall.STARBOARD_SIDE_SHELL:
        L = need(length_m, "length_m")
        return WallFrame(w, np.array([L, -(half_w or 0.0), 0.0]), -ex, ez, ey, L, -math.pi / 2)
    W = need(width_m, "width_m")  # tank top, seen from above, bow up
    return WallFrame(w, np.array([0.0, W / 2, 0.0]), -ey, ex, ez, W, 0.0)
