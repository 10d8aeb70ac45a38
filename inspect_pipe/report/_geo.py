"""Mosaic pixels -> wall metres -> ship terms (frame numbers, height above the tank top).

Pure functions on arrays plus two small typed records read from ``mosaic.json`` and the sweep's
survey metadata. Wall frame (``SPEC.md``): ``u`` metres right from the wall's left edge, ``v`` up
from the floor (the tank top).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from inspect_pipe.errors import InputError


@dataclass(frozen=True)
class WallMap:
    """Mosaic pixel (x right, y down) -> wall (u, v) m, with how it was obtained."""

    wall_from_mosaic: np.ndarray  # 3x3
    m_per_px: float
    fit_rms_m: float | None = None  # residual of the odometry fit (mosaic.json wall_fit)
    fit_max_m: float | None = None
    source: str = "mosaic.json"

    def to_wall(self, pts_px: np.ndarray) -> np.ndarray:
        """(N, 2) mosaic px -> (N, 2) wall m."""
        p = np.asarray(pts_px, float).reshape(-1, 2)
        q = np.c_[p, np.ones(len(p))] @ self.wall_from_mosaic.T
        return q[:, :2] / q[:, 2:3]

    def to_mosaic(self, pts_m: np.ndarray) -> np.ndarray:
        p = np.asarray(pts_m, float).reshape(-1, 2)
        q = np.c_[p, np.ones(len(p))] @ np.linalg.inv(self.wall_from_mosaic).T
        return q[:, :2] / q[:, 2:3]

    def area_scale(self, at_px: np.ndarray) -> float:
        """m^2 per mosaic pixel at a mosaic point (|det| of the map's Jacobian)."""
        x, y = np.asarray(at_px, float).ravel()[:2]
        e = 0.5
        pts = self.to_wall(np.array([[x - e, y], [x + e, y], [x, y - e], [x, y + e]]))
        J = np.c_[pts[1] - pts[0], pts[3] - pts[2]]
        return float(abs(np.linalg.det(J)))

    @classmethod
    def from_mosaic_json(cls, doc: dict, where: str, *, m_per_px_override: float | None = None, mosaic_hw=None) -> "WallMap":
        """From ``mosaic.json``; without ``wall_from_mosaic`` (a folder mosaic), only with an explicit
        ``m_per_px_override``: u right from the mosaic's left edge, v up from its bottom edge."""
        W = doc.get("wall_from_mosaic")
        if W is not None:
            try:
                A = np.asarray(W, float)
            except (TypeError, ValueError):
                A = None
            if A is None or A.shape != (3, 3) or not np.all(np.isfinite(A)) or abs(np.linalg.det(A)) < 1e-18:
                raise InputError(where, "field 'wall_from_mosaic': not an invertible 3x3 matrix of numbers")
            mpp = doc.get("m_per_px")
            if not isinstance(mpp, (int, float)) or not mpp > 0:
                raise InputError(where, f"field 'm_per_px': {mpp!r} is not a positive number")
            fit = doc.get("wall_fit") if isinstance(doc.get("wall_fit"), dict) else {}
            return cls(A / A[2, 2], float(mpp), _num(fit.get("rms_m")), _num(fit.get("max_m")), "mosaic.json (fitted to odometry)")
        if m_per_px_override is None:
            raise InputError(
                where, "field 'wall_from_mosaic': missing (a mosaic of a plain folder has no wall coordinates)",
                "mosaic a sweep, or give --m-per-px to report in metres from the mosaic's lower-left corner",
            )
        h = float(mosaic_hw[0]) if mosaic_hw is not None else 0.0
        s = float(m_per_px_override)
        A = np.array([[s, 0.0, 0.0], [0.0, -s, h * s], [0.0, 0.0, 1.0]])
        return cls(A, s, None, None, f"--m-per-px {s:g} (no odometry)")


def _num(x) -> float | None:
    return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) else None


@dataclass(frozen=True)
class Survey:
    """What is surveyed, in ship terms (from the sweep's ``survey`` metadata)."""

    vessel: str | None = None
    hold: str | None = None
    wall: str | None = None
    side: str | None = None
    member: str | None = None
    frame_spacing_m: float | None = None
    reference_frame: float | None = None  # ship frame number at wall u = reference_u_m
    reference_u_m: float = 0.0
    frames_increase_with_u: bool = True
    tank_top_v_m: float = 0.0  # wall v of the tank top (the hold's floor by default)

    @property
    def has_frames(self) -> bool:
        return self.frame_spacing_m is not None and self.reference_frame is not None

    def frame_at(self, u_m: float) -> float:
        """Ship frame number (fractional) at wall u."""
        assert self.frame_spacing_m and self.reference_frame is not None
        k = (u_m - self.reference_u_m) / self.frame_spacing_m
        return self.reference_frame + (k if self.frames_increase_with_u else -k)

    def frame_range(self, u_min: float, u_max: float) -> str | None:
        """'Fr. 112-113': the frame spaces the span [u_min, u_max] touches (frame n = the space
        from frame n to n+1); None without frame spacing."""
        if not self.has_frames:
            return None
        a, b = sorted((self.frame_at(u_min), self.frame_at(u_max)))
        lo, hi = math.floor(a), max(math.floor(a), math.ceil(b))
        hi = max(hi, lo + 1)
        return f"Fr. {lo}-{hi}"

    def height_above_tank_top(self, v_m: float) -> float:
        return v_m - self.tank_top_v_m

    def to_json(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def parse_survey(raw: Any, where: str) -> Survey:
    """Validate the sweep's ``survey`` dict; InputError naming ``where`` and the field."""
    if raw is None:
        return Survey()
    if not isinstance(raw, dict):
        raise InputError(where, "field 'survey': not an object")

    def text(k):
        v = raw.get(k)
        if v is None:
            return None
        if isinstance(v, (str, int, float)) and not isinstance(v, bool):
            return str(v)
        raise InputError(where, f"field 'survey.{k}': {v!r} is not text")

    spacing = raw.get("frame_spacing_m")
    if spacing is not None:
        if isinstance(spacing, str):
            try:
                spacing = float(spacing)
            except ValueError:
                raise InputError(where, f"field 'survey.frame_spacing_m': {raw['frame_spacing_m']!r} is not a number", "ship frame spacing in metres, e.g. 0.8") from None
        if isinstance(spacing, bool) or not isinstance(spacing, (int, float)) or not math.isfinite(spacing) or not 0.05 <= spacing <= 10.0:
            raise InputError(where, f"field 'survey.frame_spacing_m': {raw['frame_spacing_m']!r} is not a frame spacing", "a number of metres between 0.05 and 10, e.g. 0.8")
    ref = raw.get("reference_frame")
    ref_u = 0.0
    increase = True
    if isinstance(ref, dict):  # {"number": 112, "u_m": 0.0, "increasing": "right"}
        ref_u = raw_num(ref.get("u_m", 0.0), where, "survey.reference_frame.u_m")
        increase = ref.get("increasing", "right") != "left"
        ref = ref.get("number")
    if ref is not None:
        try:
            ref = float(ref)
        except (TypeError, ValueError):
            raise InputError(where, f"field 'survey.reference_frame': {raw.get('reference_frame')!r} is not a frame number", "the ship frame number at the wall's left edge, e.g. 112") from None
        if not math.isfinite(ref):
            raise InputError(where, "field 'survey.reference_frame': not finite")
    tank_top = raw.get("tank_top_v_m", 0.0)
    tank_top = raw_num(tank_top if tank_top is not None else 0.0, where, "survey.tank_top_v_m")
    return Survey(
        vessel=text("vessel"), hold=text("hold"), wall=text("wall"), side=text("side"), member=text("member"),
        frame_spacing_m=float(spacing) if spacing is not None else None, reference_frame=ref,
        reference_u_m=ref_u, frames_increase_with_u=increase, tank_top_v_m=tank_top,
    )


def raw_num(x, where: str, field: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise InputError(where, f"field '{field}': {x!r} is not a number")
    return float(x)


def frame_footprint_px(H: np.ndarray, size_wh: tuple[int, int]) -> np.ndarray:
    """(4, 2) mosaic px corners of a frame of ``size_wh`` mapped by H (frame px -> mosaic px)."""
    w, h = size_wh
    c = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], float) @ np.asarray(H, float).T
    return c[:, :2] / c[:, 2:3]


#: The run step that writes each of a run's JSON files (what to redo when one is damaged).
_WRITTEN_BY = {("mosaic", "mosaic.json"): "mosaic", ("detect", "defects.json"): "detect", ("report", "defects.json"): "report"}


def _redo_hint(path: Path) -> str:
    step = _WRITTEN_BY.get((path.parent.name, path.name))
    if step is None:
        return "re-create it with the command that wrote it"
    if step == "report":  # the register holds the surveyor's review: the report step reads it, never rewrites it blind
        return (f"the register is damaged: restore it from a copy, or move {path} and its defects.csv aside and run "
                f"inspect-pipe run INPUT -o {path.parent.parent} --rerun-from report for a new one (the review's "
                f"decisions stay in {path.parent / 'audit.jsonl'})")
    return f"the file is damaged: inspect-pipe run INPUT -o {path.parent.parent} --rerun-from {step} writes it again"


def read_json(path: Path) -> dict:
    import json

    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(str(path), "missing") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InputError(str(path), f"not valid JSON ({err.__class__.__name__})", _redo_hint(path)) from None
    if not isinstance(doc, dict):
        raise InputError(str(path), "not a JSON object", _redo_hint(path))
    return doc
