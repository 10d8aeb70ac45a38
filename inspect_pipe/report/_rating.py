"""Coating condition by IMO MSC.1/Circ.1330 Table 1 (ballast tanks, double-side skins) or its
crude-oil-tank variant MSC.1/Circ.1399 (4.1.3): per area under consideration, and for the wall
as its worst area (never an average).

| | GOOD | FAIR | POOR |
|---|---|---|---|
| breakdown of coating or area rusted | < 3 % (1399: < 5 %) | up to 20 % | > 20 % |
| area of hard rust scale (1399: total paint failure) | none | < 10 % | >= 10 % |
| local breakdown or rust on edges or welds | < 20 % | < 50 % | >= 50 % |

Breakdown is every corrosion pixel of the register's entries; hard rust scale is the corrosion
the detector puts in condition state poor or severe (the VT condition states, AASHTO: fair is
surface rust, poor pack rust and pitting, severe section loss) when the engine has a condition-state
head, otherwise corrosion at least ``hard_rust_prob`` probable (stated in the report). The areas
under consideration are the plate fields between ship frames (side shells) or stiffeners
(bulkheads) where the survey plan gives them, by ``area_size_m`` bands up from the tank top;
``area_size_m`` squares without a plan.

Edges and welds are not measured from a wall mosaic: unless a percentage is given they are
"not assessed", which makes the rating provisional.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

GOOD, FAIR, POOR, NOT_RATED = "GOOD", "FAIR", "POOR", "NOT RATED"
_ORDER = {GOOD: 0, FAIR: 1, POOR: 2}


@dataclass(frozen=True)
class RatingScheme:
    """Thresholds of one circular's Table 1 (percent of the area under consideration)."""

    name: str
    breakdown_good_below: float  # GOOD if breakdown < this
    breakdown_poor_above: float  # POOR if breakdown > this
    hard_rust_poor_at: float  # POOR if hard rust >= this; GOOD needs none
    edges_good_below: float
    edges_poor_at: float
    hard_rust_label: str = "hard rust scale"

    def rate(self, breakdown_pct: float, hard_rust_pct: float, edges_pct: float | None) -> str:
        """GOOD / FAIR / POOR; the worst of the criteria measured."""
        if breakdown_pct > self.breakdown_poor_above or hard_rust_pct >= self.hard_rust_poor_at:
            worst = POOR
        elif breakdown_pct >= self.breakdown_good_below or hard_rust_pct > 0.0:
            worst = FAIR
        else:
            worst = GOOD
        if edges_pct is not None:
            e = POOR if edges_pct >= self.edges_poor_at else FAIR if edges_pct >= self.edges_good_below else GOOD
            worst = max(worst, e, key=_ORDER.__getitem__)
        return worst


SCHEMES = {
    "MSC.1/Circ.1330": RatingScheme("MSC.1/Circ.1330", 3.0, 20.0, 10.0, 20.0, 50.0),
    "MSC.1/Circ.1399": RatingScheme("MSC.1/Circ.1399", 5.0, 20.0, 10.0, 20.0, 50.0, "total paint failure"),
}


@dataclass(frozen=True)
class RatingParams:
    scheme: str = "MSC.1/Circ.1330"
    area_size_m: float = 1.0  # side of a square area under consideration
    min_imaged_fraction: float = 0.5  # an area less imaged than this is NOT RATED
    hard_rust_prob: float = 0.9  # corrosion pixels at least this probable count as hard rust scale
    edges_welds_pct: float | None = None  # measured elsewhere; None = not assessed (provisional)
    # Percentages are reported to 0.1 %: a hard rust figure that rounds to 0.0 (under 0.05 %, about
    # 3 cm^2 of a 0.7 m^2 plate field: condition-state speckle) counts as none, so a rating is never
    # decided by a figure the report shows as 0.0.
    hard_rust_none_below_pct: float = 0.05


@dataclass(frozen=True)
class AreaRating:
    name: str  # "A1".. row letter from the top, column number from the left
    u0_m: float
    v0_m: float
    u1_m: float
    v1_m: float
    imaged_m2: float
    breakdown_pct: float | None
    hard_rust_pct: float | None
    edges_welds_pct: float | None
    rating: str
    provisional: bool
    label: str = ""  # plate field in ship terms ("Fr. 143-144"), where the plan gives frames or stiffeners
    severity_pct: dict | None = None  # fair / poor / severe, % of the imaged area (engines with condition states)

    def to_json(self) -> dict:
        d = dict(self.__dict__)
        for k, v in d.items():
            if isinstance(v, float):
                d[k] = round(v, 4)
        return d


@dataclass(frozen=True)
class WallRating:
    scheme: str
    rating: str
    provisional: bool
    worst_area: str | None
    areas: tuple[AreaRating, ...] = field(default_factory=tuple)
    note: str = ""

    def to_json(self) -> dict:
        return {
            "scheme": self.scheme, "rating": self.rating, "provisional": self.provisional,
            "worst_area": self.worst_area, "note": self.note, "areas": [a.to_json() for a in self.areas],
        }


def _cuts(n_cells: int, edges: list[int] | None, step: int) -> list[int]:
    """Cell indices where areas begin along one axis: the given edges (plate field boundaries,
    kept inside the grid), else every ``step`` cells."""
    if not edges:
        return list(range(0, n_cells, step))
    cuts = sorted({0, *(e for e in edges if 0 < e < n_cells)})
    return cuts


def rate_wall(
    imaged: np.ndarray,
    corrosion: np.ndarray,
    hard_rust: np.ndarray,
    *,
    origin_uv_m: tuple[float, float],
    cell_m: float,
    params: RatingParams = RatingParams(),
    severity: np.ndarray | None = None,
    u_edges_m: list[tuple[float, str]] | None = None,
) -> WallRating:
    """Rate a wall from boolean rasters on one grid of ``cell_m`` cells (row 0 at the top,
    ``origin_uv_m`` = wall (u, v) of the grid's top-left corner): where the wall was usably
    imaged, where corrosion (breakdown) was found, and where hard rust scale was found.
    ``severity``: the condition state (0 none, 1 fair, 2 poor, 3 severe) on the same grid, for the
    per-state breakdown. ``u_edges_m``: plate field boundaries along u with the name of the field
    that begins there (frames or stiffeners, from the survey plan); squares without them."""
    scheme = SCHEMES.get(params.scheme)
    if scheme is None:
        raise ValueError(f"unknown rating scheme {params.scheme!r}; one of {', '.join(SCHEMES)}")
    rows, cols = imaged.shape
    n = max(1, int(round(params.area_size_m / cell_m)))
    u0, v_top = origin_uv_m
    col_names: dict[int, str] = {}
    col_edges = None
    if u_edges_m:
        col_edges = []
        for u, name in u_edges_m:
            c = int(round((u - u0) / cell_m))
            col_edges.append(c)
            col_names[max(c, 0)] = name
    # rows: bands of area_size_m up from the tank top (v = 0), cut at the grid's top
    row_edges = [int(round((v_top - k * params.area_size_m) / cell_m)) for k in range(0, int(v_top / params.area_size_m) + 2)]
    rcuts = _cuts(rows, [r for r in row_edges if r > 0], n) if u_edges_m else _cuts(rows, None, n)
    ccuts = _cuts(cols, col_edges, n)
    areas = []
    provisional = params.edges_welds_pct is None
    for ar, r0 in enumerate(rcuts):
        r1 = rcuts[ar + 1] if ar + 1 < len(rcuts) else rows
        for ac, c0 in enumerate(ccuts):
            c1 = ccuts[ac + 1] if ac + 1 < len(ccuts) else cols
            sl = (slice(r0, r1), slice(c0, c1))
            im = imaged[sl]
            n_im = int(im.sum())
            name = f"{_row_name(ar)}{ac + 1}"
            label = ""
            if col_names:
                start = max((c for c in col_names if c <= c0), default=None)
                label = col_names.get(start, "") if start is not None else ""
            box = (u0 + c0 * cell_m, v_top - r1 * cell_m, u0 + c1 * cell_m, v_top - r0 * cell_m)
            if n_im == 0 or n_im < params.min_imaged_fraction * im.size:
                areas.append(AreaRating(name, *box, n_im * cell_m**2, None, None, params.edges_welds_pct, NOT_RATED, provisional, label))
                continue
            b = 100.0 * float((corrosion[sl] & im).sum()) / n_im
            h = 100.0 * float((hard_rust[sl] & im).sum()) / n_im
            sev = None
            if severity is not None:
                s_im = severity[sl][im & corrosion[sl]]
                sev = {k: round(100.0 * float((s_im == i + 1).sum()) / n_im, 2) for i, k in enumerate(("fair", "poor", "severe"))}
            h_rated = h if h >= params.hard_rust_none_below_pct else 0.0
            areas.append(AreaRating(name, *box, n_im * cell_m**2, b, h, params.edges_welds_pct,
                                    scheme.rate(b, h_rated, params.edges_welds_pct), provisional, label, sev))
    rated = [a for a in areas if a.rating != NOT_RATED]
    if not rated:
        return WallRating(scheme.name, NOT_RATED, provisional, None, tuple(areas), "no area imaged enough to rate")
    worst = max(rated, key=lambda a: (_ORDER[a.rating], a.breakdown_pct or 0.0, a.hard_rust_pct or 0.0))
    note = "wall rated by its worst area"
    if provisional:
        note += "; edges and welds not assessed: provisional"
    if len(rated) < len(areas):
        note += f"; {len(areas) - len(rated)} area(s) not imaged enough to rate"
    return WallRating(scheme.name, worst.rating, provisional, worst.name, tuple(areas), note)


def _row_name(i: int) -> str:
    s = ""
    i += 1
    while i:
        i, r = divmod(i - 1, 26)
        s = chr(65 + r) + s
    return s
