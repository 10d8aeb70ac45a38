"""Change since the last survey: two runs of one wall, registered on the wall, their registers matched.

1. **Same wall, placed.** Each run's mosaic is drawn on one wall raster (``grid_m`` per pixel) through
   its ``wall_from_mosaic`` (wall coordinates first). SIFT features of the two rasters, matched and
   fitted by a RANSAC similarity, refine the new survey onto the old one (image features second).
   Different survey identities (vessel, hold, wall), walls that do not overlap, or fewer than
   ``min_matches`` consistent features or a refinement beyond ``max_shift_m`` mean two different
   walls: an error before anything is written.
2. **Matching.** Register entries of a class whose outlines (the new ones moved by the refinement)
   come within ``match_gap_m`` of each other are one defect; a group may hold several entries on
   either side (a patch registered in pieces). A one-sided group is checked against the other
   survey's detection mask (detect/mosaic.<class>.mask.png): where that survey detected it too,
   below the register's limits or screened out, its detected area there is its area in that survey.
3. **Status.** ``new`` (nothing there before), ``gone`` (nothing there now), else ``grown`` /
   ``shrunk`` when the probability-weighted detected area over the group's place (the sum of the
   class probability over the dilated outlines of both surveys) changed by more than the noise
   (``noise_abs_m2`` plus ``noise_rel`` of the larger), else ``unchanged``. The thresholded register
   areas vary more between flights (a patch near the operating point: 61 -> 34 cm², where the
   weighted area went 63 -> 45 cm²). A group registered by one survey only is ``new`` / ``gone``
   only when the weighted test agrees (the other survey's weighted area over its place is smaller
   by more than the noise); else ``unchanged``, with a note: a patch near the detector's operating
   point that one flight registers and the next leaves out (demo wall 5, flights 11 and 12: 32 cm²
   registered, then not, its map peaking at 230 and 180 against 203). One-sided groups smaller than
   ``new_min_m2`` are within the noise: listed under ``below_noise``, not as changes. The noise
   figures come from flights of unchanged walls (docs/report.md, bench/bench_compare.py).
4. **Coverage.** Weighted areas are summed only where both mosaics imaged the wall: a patch at the
   edge of one flight's coverage is not "shrunk" for what that flight did not see (demo wall 10,
   flights 21 and 23: 22 % of a patch outside one mosaic read as 231 -> 334 cm², "grown"). A group
   with less than ``min_common_fraction`` of its outlines on that common wall is not compared
   (``not_compared``): one survey did not see it, so it is neither gone nor unchanged there.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

import inspect_pipe
from inspect_pipe.errors import InputError

from ._geo import WallMap, read_json
from ._register import REGISTER_FORMAT, Defect

CHANGES_FORMAT = "inspect_pipe.changes/1"
STATUSES = ("new", "grown", "shrunk", "unchanged", "gone")
STATUS_COLOURS = {"new": (0, 0, 230), "grown": (0, 140, 255), "shrunk": (230, 120, 0), "unchanged": (60, 170, 60), "gone": (140, 140, 140)}


@dataclass(frozen=True)
class CompareParams:
    grid_m: float = 0.003  # wall raster for registration, matching and crops
    min_matches: int = 40  # consistent SIFT matches needed to call it the same wall
    max_shift_m: float = 0.25  # refinement (translation) allowed on top of the wall coordinates
    max_rotation_deg: float = 3.0
    match_gap_m: float = 0.03  # outlines this close: the same defect
    # noise, measured between two flights of an unchanged wall (docs/report.md): an area change counts
    # beyond noise_abs_m2 + noise_rel x the larger area; an entry seen by one survey only, below new_min_m2, is noise
    noise_abs_m2: float = 4e-4  # 4 cm²
    noise_rel: float = 0.25
    new_min_m2: float = 8e-4  # 8 cm²
    evidence_fraction: float = 0.3  # a one-sided entry the other survey detected over this share of its outline was there
    min_common_fraction: float = 0.5  # a defect with less of its outline on the wall both surveys imaged is not compared


@dataclass
class SurveyRun:
    root: Path
    register_path: Path
    doc: dict
    defects: list[Defect]
    wall: WallMap
    mosaic: np.ndarray  # BGRA
    masks: dict[str, np.ndarray]  # class -> mosaic-sized bool (the run's detection)
    probs: dict[str, np.ndarray] = field(default_factory=dict)  # class -> mosaic-sized uint8 probability

    @property
    def survey(self) -> dict:
        return self.doc.get("survey") or {}


def load_survey_run(path: Path) -> SurveyRun:
    """A run directory of ``inspect-pipe run`` with its register (report/defects.json)."""
    from inspect_pipe.pipeline import RunStore
    from inspect_pipe.pipeline._store import read_png

    path = Path(path)
    if not path.is_dir():
        raise InputError(str(path), "not found" if not path.exists() else "not a directory", "give a run directory written by inspect-pipe run")
    reg = path / "report" / "defects.json"
    if not reg.is_file():
        if (path / "sweep.json").is_file() or (path / "frames.jsonl").is_file():  # a capture, not a run of it
            raise InputError(str(path), "a sweep, not a run", f"run inspect-pipe run {path} -o RUN first and compare RUN")
        if not (path / "mosaic" / "mosaic.json").is_file() or not (path / "detect").is_dir():
            raise InputError(str(path), "not a run directory (no mosaic/ and detect/ of inspect-pipe run)",
                             "give a run directory written by inspect-pipe run")
        raise InputError(str(reg), "missing: the run has no register", f"run inspect-pipe report {path} -o {path / 'report'} first")
    doc = read_json(reg)
    if doc.get("format") != REGISTER_FORMAT or not isinstance(doc.get("defects"), list):
        raise InputError(str(reg), f"field 'format': {doc.get('format')!r}", f"expected {REGISTER_FORMAT!r} with a list of defects")
    from inspect_pipe.formats import RegisterJson, validate

    validate(RegisterJson, doc, str(reg), "docs/report.md describes the register")  # names the field, as report and review do
    defects = [Defect.from_json(d, str(reg)) for d in doc["defects"] if isinstance(d, dict)]
    store = RunStore(path)
    mdoc = store.load_mosaic_json()
    mosaic = store.load_mosaic_image()
    if mdoc.get("wall_from_mosaic") is None:
        raise InputError(str(store.mosaic_dir / "mosaic.json"), "no wall coordinates (a mosaic of a plain image folder)",
                         "compare needs runs of sweeps, whose mosaics are placed on the wall")
    wall = WallMap.from_mosaic_json(mdoc, str(store.mosaic_dir / "mosaic.json"), mosaic_hw=mosaic.shape[:2])
    masks, probs = {}, {}
    for k in ("corrosion", "crack"):
        for kind, into in (("mask", masks), ("prob", probs)):
            p = store.class_map_path("mosaic", k, kind)
            if p.is_file():  # a map that is there must be whole and the mosaic's size, as the report demands
                m = read_png(p, cv2.IMREAD_GRAYSCALE)
                if m.shape != mosaic.shape[:2]:
                    raise InputError(str(p), f"{m.shape[1]}x{m.shape[0]} px, the mosaic {mosaic.shape[1]}x{mosaic.shape[0]}",
                                     f"run `inspect-pipe run ... --rerun-from detect` on {path}")
                into[k] = m > 0 if kind == "mask" else m
    return SurveyRun(path, reg, doc, defects, wall, mosaic, masks, probs)


@dataclass
class Grid:
    """The common wall raster: px (x right, y down) <-> wall (u right, v up)."""

    u0: float
    v1: float
    m: float
    w: int
    h: int

    @property
    def from_wall(self) -> np.ndarray:
        return np.array([[1 / self.m, 0, -self.u0 / self.m], [0, -1 / self.m, self.v1 / self.m], [0, 0, 1.0]])

    def px(self, uv) -> np.ndarray:
        p = np.asarray(uv, float).reshape(-1, 2)
        return np.c_[(p[:, 0] - self.u0) / self.m, (self.v1 - p[:, 1]) / self.m]

    def wall(self, xy) -> np.ndarray:
        p = np.asarray(xy, float).reshape(-1, 2)
        return np.c_[self.u0 + p[:, 0] * self.m, self.v1 - p[:, 1] * self.m]


def _extent(run: SurveyRun) -> tuple[float, float, float, float]:
    ys, xs = np.nonzero(run.mosaic[:, :, 3] > 0)
    if len(xs) == 0:
        raise InputError(str(run.root / "mosaic" / "mosaic.png"), "no covered pixel")
    pts = run.wall.to_wall(np.array([[xs.min(), ys.min()], [xs.max(), ys.min()], [xs.max(), ys.max()], [xs.min(), ys.max()]], float))
    return float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max())


def _to_grid(run: SurveyRun, grid: Grid, A: np.ndarray | None = None):
    """The run's mosaic (BGRA) and class masks on the grid; ``A`` (3x3, grid px -> grid px) after."""
    M = grid.from_wall @ run.wall.wall_from_mosaic
    if A is not None:
        M = A @ M
    img = cv2.warpPerspective(run.mosaic, M, (grid.w, grid.h), flags=cv2.INTER_AREA, borderValue=(0, 0, 0, 0))
    masks = {k: cv2.warpPerspective(m.astype(np.uint8), M, (grid.w, grid.h), flags=cv2.INTER_NEAREST) > 0 for k, m in run.masks.items()}
    probs = {k: cv2.warpPerspective(m, M, (grid.w, grid.h), flags=cv2.INTER_LINEAR).astype(np.float32) / 255.0 for k, m in run.probs.items()}
    return img, masks, probs


def _same_identity(old: SurveyRun, new: SurveyRun) -> None:
    for key in ("imo", "vessel", "hold", "wall"):
        a, b = old.survey.get(key), new.survey.get(key)
        if a and b and str(a).strip().lower() != str(b).strip().lower():
            raise InputError(f"{old.register_path} and {new.register_path}", f"two different walls: survey {key} {a!r} and {b!r}",
                             "compare two surveys of the same wall")


def register_mosaics(old: SurveyRun, new: SurveyRun, params: CompareParams) -> tuple[Grid, np.ndarray, dict]:
    """The grid over both mosaics, the refinement A (new grid px -> old grid px, 3x3) and its figures.
    Raises InputError when the two are not one wall."""
    where = f"{old.root} and {new.root}"
    a, b = _extent(old), _extent(new)
    u0, v0, u1, v1 = min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])
    ou = max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    smaller = min((a[2] - a[0]) * (a[3] - a[1]), (b[2] - b[0]) * (b[3] - b[1]))
    if smaller <= 0 or ou < 0.25 * smaller:
        raise InputError(where, f"two different walls: their mosaics overlap on {ou:.2f} m² of the wall ({100 * ou / max(smaller, 1e-9):.0f} % of the smaller)",
                         "compare two surveys of the same wall")
    grid = Grid(u0, v1, params.grid_m, int(math.ceil((u1 - u0) / params.grid_m)) + 1, int(math.ceil((v1 - v0) / params.grid_m)) + 1)
    if grid.w * grid.h > 40e6:
        raise InputError(where, f"the wall raster would be {grid.w} x {grid.h} px", "the mosaics' wall maps are implausible")
    oi, _, _ = _to_grid(old, grid)
    ni, _, _ = _to_grid(new, grid)
    sift = cv2.SIFT_create(nfeatures=8000)
    ga = cv2.cvtColor(oi[:, :, :3], cv2.COLOR_BGR2GRAY)
    gb = cv2.cvtColor(ni[:, :, :3], cv2.COLOR_BGR2GRAY)
    ka, da = sift.detectAndCompute(ga, (oi[:, :, 3] > 0).astype(np.uint8) * 255)
    kb, db = sift.detectAndCompute(gb, (ni[:, :, 3] > 0).astype(np.uint8) * 255)
    good = []
    if da is not None and db is not None and len(ka) >= 2 and len(kb) >= 2:
        for pair in cv2.BFMatcher(cv2.NORM_L2).knnMatch(db, da, k=2):
            if len(pair) == 2 and pair[0].distance < 0.75 * pair[1].distance:
                m = pair[0]
                pa, pb = np.array(ka[m.trainIdx].pt), np.array(kb[m.queryIdx].pt)
                if np.hypot(*(pa - pb)) * params.grid_m <= params.max_shift_m:  # wall coordinates first: a match is near
                    good.append((pb, pa))
    inliers = 0
    A2 = None
    if len(good) >= 3:
        src = np.float32([g[0] for g in good])
        dst = np.float32([g[1] for g in good])
        A2, inl = cv2.estimateAffinePartial2D(src, dst, method=cv2.RANSAC, ransacReprojThreshold=2.0, maxIters=5000, confidence=0.999, refineIters=20)
        inliers = int(inl.sum()) if inl is not None else 0
    if A2 is None or inliers < params.min_matches:
        raise InputError(where, f"two different walls: only {inliers} image features of the two mosaics agree in wall coordinates (need {params.min_matches})",
                         "compare two surveys of the same wall, each run with its register")
    scale = float(math.hypot(A2[0, 0], A2[1, 0]))
    rot = math.degrees(math.atan2(A2[1, 0], A2[0, 0]))
    centre = np.array([grid.w / 2, grid.h / 2])
    shift = float(np.hypot(*((A2[:, :2] @ centre + A2[:, 2]) - centre))) * params.grid_m
    if shift > params.max_shift_m or abs(rot) > params.max_rotation_deg or abs(scale - 1) > 0.03:
        raise InputError(where, f"the two mosaics agree only after moving one by {100 * shift:.0f} cm, {rot:.1f} deg, scale {scale:.3f}",
                         "their wall coordinates disagree: different walls, or a wall fit gone wrong")
    A = np.vstack([A2, [0, 0, 1]])
    res = np.array([np.hypot(*((A2[:, :2] @ s + A2[:, 2]) - d)) for s, d in good])
    fig = {"matches": len(good), "inliers": inliers, "shift_m": round(shift, 4), "rotation_deg": round(rot, 3), "scale": round(scale, 5),
           "residual_median_m": round(float(np.median(res[res < 2.0])) * params.grid_m, 4) if (res < 2.0).any() else None}
    return grid, A, fig


@dataclass
class Change:
    status: str
    cls: str
    old_ids: list[str]
    new_ids: list[str]
    centroid_wall_m: tuple[float, float]
    area_old_m2: float
    area_new_m2: float
    bbox_grid: tuple[int, int, int, int]  # x0, y0, x1, y1 on the grid
    note: str = ""
    crop: str | None = None
    prob_area_old_m2: float | None = None  # probability-weighted detected area over the group's place (the grown/shrunk test)
    prob_area_new_m2: float | None = None

    def to_json(self) -> dict:
        return {"status": self.status, "class": self.cls,
                "old_id": self.old_ids[0] if self.old_ids else None, "new_id": self.new_ids[0] if self.new_ids else None,
                "old_ids": self.old_ids, "new_ids": self.new_ids,
                "centroid_wall_m": [round(self.centroid_wall_m[0], 3), round(self.centroid_wall_m[1], 3)],
                "area_old_m2": round(self.area_old_m2, 6), "area_new_m2": round(self.area_new_m2, 6),
                "prob_area_old_m2": None if self.prob_area_old_m2 is None else round(self.prob_area_old_m2, 6),
                "prob_area_new_m2": None if self.prob_area_new_m2 is None else round(self.prob_area_new_m2, 6),
                "note": self.note, "crop": self.crop}


def _poly_grid(d: Defect, grid: Grid, T: np.ndarray | None = None) -> np.ndarray:
    p = grid.px(np.asarray(d.polygon_wall_m, float))
    if T is not None:
        p = (np.c_[p, np.ones(len(p))] @ T.T)[:, :2]
    return p


def _fill(shape, polys) -> np.ndarray:
    m = np.zeros(shape, np.uint8)
    for p in polys:
        cv2.fillPoly(m, [np.round(p).astype(np.int32)], 1)
        cv2.polylines(m, [np.round(p).astype(np.int32)], True, 1)
    return m > 0


def match_registers(old: SurveyRun, new: SurveyRun, grid: Grid, A: np.ndarray, params: CompareParams,
                    old_masks: dict, new_masks: dict, old_probs: dict | None = None, new_probs: dict | None = None,
                    common: np.ndarray | None = None) -> tuple[list[Change], list[Change], list[Change]]:
    """(changes, below_noise, not_compared): groups of entries of one class whose outlines come within
    ``match_gap_m``; the new register is moved by the refinement ``A``. ``common``: the grid pixels both
    surveys imaged; a group with less than ``min_common_fraction`` of its outlines there is not compared
    (one survey did not see it), and the weighted areas are summed over that common part only."""
    shape = (grid.h, grid.w)
    if common is None:
        common = np.ones(shape, bool)
    gap = max(1, int(round(params.match_gap_m / grid.m)))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * gap + 1, 2 * gap + 1))
    changes: list[Change] = []
    below: list[Change] = []
    outside: list[Change] = []
    olds = [d for d in old.defects if d.redetected and d.status != "rejected" and len(d.polygon_wall_m) >= 3]
    news = [d for d in new.defects if d.redetected and d.status != "rejected" and len(d.polygon_wall_m) >= 3]
    for cls in sorted({d.cls for d in olds + news}):
        o = [(d, _poly_grid(d, grid)) for d in olds if d.cls == cls]
        n = [(d, _poly_grid(d, grid, A)) for d in news if d.cls == cls]
        items = [("old", d, p) for d, p in o] + [("new", d, p) for d, p in n]
        fills = [cv2.dilate(_fill(shape, [p]).astype(np.uint8), kernel) > 0 for _, _, p in items]
        parent = list(range(len(items)))

        def find(i):
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        boxes = [(p[:, 0].min() - gap, p[:, 1].min() - gap, p[:, 0].max() + gap, p[:, 1].max() + gap) for _, _, p in items]
        for i in range(len(items)):
            for j in range(i + 1, len(items)):
                bi, bj = boxes[i], boxes[j]
                if bi[0] > bj[2] or bj[0] > bi[2] or bi[1] > bj[3] or bj[1] > bi[3]:
                    continue
                if (fills[i] & fills[j]).any():
                    parent[find(i)] = find(j)
        groups: dict[int, list[int]] = {}
        for i in range(len(items)):
            groups.setdefault(find(i), []).append(i)
        for members in groups.values():
            og = [items[i] for i in members if items[i][0] == "old"]
            ng = [items[i] for i in members if items[i][0] == "new"]
            a_old = sum(d.area_m2 for _, d, _ in og)
            a_new = sum(d.area_m2 for _, d, _ in ng)
            region = np.zeros(shape, bool)
            for i in members:
                region |= fills[i]
            own = _fill(shape, [p for _, _, p in og + ng])
            seen_by_both = float((own & common).sum()) / max(1, int(own.sum()))
            region &= common  # what one survey did not image is neither there nor gone in it
            note = ""
            if not og:  # did the old survey detect it, below the register's limits?
                a_old, note = _evidence(region, _fill(shape, [p for _, _, p in ng]), old_masks.get(cls), grid, params, "old")
            if not ng:
                a_new, note = _evidence(region, _fill(shape, [p for _, _, p in og]), new_masks.get(cls), grid, params, "new")
            side = ng if ng else og
            w = [max(d.area_m2, 1e-9) for _, d, _ in side]
            cents = [p.mean(0) for _, _, p in side]
            c = np.average(np.array(cents), axis=0, weights=w)
            cu, cv = grid.wall(c)[0]
            allp = np.vstack([p for _, _, p in og + ng])
            bbox = (int(allp[:, 0].min()), int(allp[:, 1].min()), int(math.ceil(allp[:, 0].max())), int(math.ceil(allp[:, 1].max())))
            # grown / shrunk on the probability-weighted area over the group's place in both surveys:
            # steadier between flights than the thresholded register areas (docs/report.md)
            po = pn = None
            if old_probs and new_probs and cls in old_probs and cls in new_probs:
                po = float(old_probs[cls][region].sum()) * grid.m ** 2
                pn = float(new_probs[cls][region].sum()) * grid.m ** 2
            ids = [d.id for _, d, _ in og], [d.id for _, d, _ in ng]
            if seen_by_both < params.min_common_fraction:
                # one survey did not see it: no change can be told, and the weighted areas over a common
                # part this small say nothing; the status is what the two registers alone say
                share = "none" if seen_by_both < 0.005 else f"only {100 * seen_by_both:.0f} %"
                outside.append(Change(classify(a_old, a_new, params), cls, *ids, (float(cu), float(cv)), a_old, a_new, bbox,
                                      f"not compared: {share} of its outline lies on the wall both surveys imaged", None, po, pn))
                continue
            status, note = _status(a_old, a_new, po, pn, params, note, "old" if not og else "new")
            ch = Change(status, cls, *ids, (float(cu), float(cv)), a_old, a_new, bbox, note, None, po, pn)
            if status in ("new", "gone") and max(a_old, a_new) < params.new_min_m2:
                below.append(ch)
            else:
                changes.append(ch)
    changes.sort(key=lambda c: (STATUSES.index(c.status), -abs(c.area_new_m2 - c.area_old_m2)))
    return changes, below, outside


def _status(a_old: float, a_new: float, po: float | None, pn: float | None, params: CompareParams, note: str,
            missing_from: str) -> tuple[str, str]:
    """(status, note): new / gone from the register areas (one side empty), else grown / shrunk /
    unchanged from the probability-weighted areas ``po``, ``pn`` when both maps are there. A group
    registered by one survey only stays new / gone only when the weighted test agrees; otherwise the
    other survey's map shows it there at a weighted area within the noise: a patch near the
    detector's operating point that one flight registers and the next leaves out, not a change."""
    status = classify(a_old, a_new, params)
    if po is None or pn is None:
        return status, note
    weighted = classify(po, pn, params)
    if status not in ("new", "gone"):
        return weighted, note
    if (status, weighted) in (("new", "grown"), ("gone", "shrunk")):
        return status, note
    return "unchanged", (f"registered by one survey only; the {missing_from} survey's detection map shows it there below the "
                         f"register's limits ({po * 1e4:.0f} -> {pn * 1e4:.0f} cm² weighted, within the noise)")


def _evidence(region, outline, mask, grid: Grid, params: CompareParams, which: str) -> tuple[float, str]:
    """Area the other survey detected inside ``region`` (m²), when it covers enough of ``outline``."""
    if mask is None:
        return 0.0, ""
    cover = float((mask & outline).sum()) / max(1, int(outline.sum()))
    if cover < params.evidence_fraction:
        return 0.0, ""
    area = float((mask & region).sum()) * grid.m ** 2
    return area, f"the {which} survey detected it too ({100 * cover:.0f} % of the outline) without a register entry"


def classify(a_old: float, a_new: float, params: CompareParams) -> str:
    if a_old <= 0:
        return "new"
    if a_new <= 0:
        return "gone"
    noise = params.noise_abs_m2 + params.noise_rel * max(a_old, a_new)
    if a_new - a_old > noise:
        return "grown"
    if a_old - a_new > noise:
        return "shrunk"
    return "unchanged"


@dataclass
class Comparison:
    old: SurveyRun
    new: SurveyRun
    grid: Grid
    A: np.ndarray
    registration: dict
    changes: list[Change]
    below_noise: list[Change]
    params: CompareParams
    old_img: np.ndarray = field(repr=False, default=None)  # BGRA on the grid
    new_img: np.ndarray = field(repr=False, default=None)  # BGRA on the grid, refined onto the old
    not_compared: list[Change] = field(default_factory=list)  # mostly outside the wall both surveys imaged


def compare_runs(old_dir: Path, new_dir: Path, params: CompareParams = CompareParams()) -> Comparison:
    """Everything ``changes.json`` and the report hold, computed without writing anything."""
    old, new = load_survey_run(old_dir), load_survey_run(new_dir)
    if Path(old_dir).resolve() == Path(new_dir).resolve():
        raise InputError(str(old_dir), "OLD_RUN and NEW_RUN are the same run", "give two surveys of the wall")
    _same_identity(old, new)
    grid, A, fig = register_mosaics(old, new, params)
    oi, om, op = _to_grid(old, grid)
    ni, nm, np_ = _to_grid(new, grid, A)
    common = (oi[:, :, 3] > 0) & (ni[:, :, 3] > 0)
    changes, below, outside = match_registers(old, new, grid, A, params, om, nm, op, np_, common)
    return Comparison(old, new, grid, A, fig, changes, below, params, oi, ni, outside)


# ------------------------------------------------------------------------------------ output


def _bgr(img: np.ndarray) -> np.ndarray:
    out = img[:, :, :3].copy()
    out[img[:, :, 3] == 0] = (235, 235, 235)
    return out


def change_map(c: Comparison, max_w: int = 1400) -> np.ndarray:
    base = _bgr(c.new_img)
    base = (0.55 * base + 0.45 * 255).astype(np.uint8)  # faded, so the marks stand out
    s = min(1.0, max_w / base.shape[1])
    img = cv2.resize(base, (int(base.shape[1] * s), int(base.shape[0] * s)), interpolation=cv2.INTER_AREA)
    for k, ch in enumerate(c.changes, start=1):
        col = STATUS_COLOURS[ch.status]
        x0, y0, x1, y1 = (np.array(ch.bbox_grid) * s).round().astype(int)
        pad = 6
        cv2.rectangle(img, (x0 - pad, y0 - pad), (x1 + pad, y1 + pad), col, 2 if ch.status == "unchanged" else 3, cv2.LINE_AA)
        cv2.putText(img, f"C{k}", (x1 + pad + 2, y0 + 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 4, cv2.LINE_AA)
        cv2.putText(img, f"C{k}", (x1 + pad + 2, y0 + 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, col, 1, cv2.LINE_AA)
    for k, ch in enumerate(c.not_compared, start=1):  # where one survey did not image the wall: thin black boxes
        x0, y0, x1, y1 = (np.array(ch.bbox_grid) * s).round().astype(int)
        cv2.rectangle(img, (x0 - 6, y0 - 6), (x1 + 6, y1 + 6), (40, 40, 40), 1, cv2.LINE_AA)
        cv2.putText(img, f"N{k}", (x1 + 8, y0 + 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (40, 40, 40), 1, cv2.LINE_AA)
    from ._render import scale_bar

    return scale_bar(img, s / c.grid.m)


def change_crops(c: Comparison, ch: Change, size: int = 220) -> np.ndarray:
    """Old | new, the same piece of wall, outlines of each survey's entries drawn."""
    from ._render import COLOURS, scale_bar

    x0, y0, x1, y1 = ch.bbox_grid
    m = max(20, int(0.4 * max(x1 - x0, y1 - y0)))
    X0, Y0 = max(0, x0 - m), max(0, y0 - m)
    X1, Y1 = min(c.grid.w, x1 + m), min(c.grid.h, y1 + m)
    outs = []
    for img, ids, reg, T in ((c.old_img, ch.old_ids, c.old.defects, None), (c.new_img, ch.new_ids, c.new.defects, c.A)):
        crop = _bgr(img[Y0:Y1, X0:X1])
        s = size / max(crop.shape[:2])
        crop = cv2.resize(crop, (max(1, int(crop.shape[1] * s)), max(1, int(crop.shape[0] * s))), interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_CUBIC)
        for d in reg:
            if d.id in ids:
                p = (_poly_grid(d, c.grid, T) - [X0, Y0]) * s
                cv2.polylines(crop, [np.round(p).astype(np.int32)], True, COLOURS.get(d.cls, (0, 0, 255)), 1, cv2.LINE_AA)
        outs.append(scale_bar(crop, s / c.grid.m))
    h = max(o.shape[0] for o in outs)
    pad = [cv2.copyMakeBorder(o, 0, h - o.shape[0], 0, 6, cv2.BORDER_CONSTANT, value=(255, 255, 255)) for o in outs]
    return np.hstack(pad)


def changes_doc(c: Comparison) -> dict:
    return {
        "format": CHANGES_FORMAT,
        "software": f"inspect_pipe {inspect_pipe.__version__}",
        "old_run": str(c.old.root.resolve()), "new_run": str(c.new.root.resolve()),
        "survey": {"old": c.old.survey, "new": c.new.survey},
        "registration": {"method": "wall coordinates of each mosaic, refined by a RANSAC similarity of SIFT matches on a "
                                   f"{c.grid.m * 1000:.0f} mm wall raster", **c.registration},
        "noise": {"area_abs_m2": c.params.noise_abs_m2, "area_rel": c.params.noise_rel, "new_min_m2": c.params.new_min_m2,
                  "rule": "grown/shrunk when the probability-weighted area (prob_area_*) changed by more than area_abs_m2 + area_rel x "
                          "the larger one; new/gone entries smaller than new_min_m2 are listed under below_noise"},
        "params": asdict(c.params),
        "entries": [ch.to_json() for ch in c.changes],
        "below_noise": [ch.to_json() for ch in c.below_noise],
        "not_compared": [ch.to_json() for ch in c.not_compared],
        "counts": {s: sum(ch.status == s for ch in c.changes) for s in STATUSES},
    }


def write_comparison(c: Comparison, out: Path, *, pdf: bool = True, log=print) -> dict:
    """OUT/changes.json, change_map.png, crops/C<k>.png, report.html and report.pdf."""
    import jinja2

    from inspect_pipe._files import atomic_write, write_json, write_png

    from ._render import render_pdf

    out = Path(out)
    (out / "crops").mkdir(parents=True, exist_ok=True)
    write_png(out / "change_map.png", change_map(c))
    for k, ch in enumerate(c.changes, start=1):
        ch.crop = f"crops/C{k}.png"
        write_png(out / ch.crop, change_crops(c, ch))
    doc = changes_doc(c)
    write_json(out / "changes.json", doc)
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(Path(__file__).parent)), autoescape=True)
    html = env.get_template("compare_template.html").render(c=c, doc=doc, colours={k: "#%02x%02x%02x" % v[::-1] for k, v in STATUS_COLOURS.items()})
    atomic_write(out / "report.html", html.encode())
    written = {"changes": out / "changes.json", "html": out / "report.html", "pdf": None}
    if pdf:
        why = render_pdf(html, out, out / "report.pdf")
        if why is None:
            written["pdf"] = out / "report.pdf"
        else:
            log(f"warning: {out / 'report.pdf'} not written: {why}; report.html has the same content")
    return written
