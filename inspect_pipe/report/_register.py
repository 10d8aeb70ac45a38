"""The defect register: one entry per physical defect, merged across the mosaic's detection and
the overlapping keyframes' detections, located in wall metres, with a surveyor's status that a
later run keeps (JSON/CSV round trip)."""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from inspect_pipe.errors import InputError

from ._geo import Survey, WallMap

STATUSES = ("suggested", "confirmed", "rejected")
REGISTER_FORMAT = "inspect_pipe.defect_register/1"
CSV_COLUMNS = ("id", "class", "status", "note", "u_m", "v_m", "area_m2", "length_m", "confidence",
               "frame_range", "height_above_tank_top_m", "severity", "location", "wall", "frame", "from_centreline_m", "side",
               "n_frames", "frames", "polygon_wall_m", "beyond_survey")


@dataclass(frozen=True)
class RegisterParams:
    merge_gap_m: float = 0.03  # fragments of one class closer than this are one defect
    min_area_m2: float = 2e-4  # corrosion smaller than 1.4 x 1.4 cm is speckle
    min_crack_length_m: float = 0.05
    max_crack_width_m: float = 0.02  # mean detected width (area / length): wider is a blob, not a crack
    edge_margin_m: float = 0.02  # detections this close to the mosaic's edge are seam and border artefacts
    frame_vote_min: int = 2  # keyframe evidence outside the mosaic's own decision: at least 2 frames ...
    frame_vote_fraction: float = 0.5  # ... and half of the keyframes that see the pixel
    match_m: float = 0.05  # a previous entry is the same defect if centroids are this close (same class)
    polygon_tolerance_m: float = 0.003
    # screening (_screen.py): seams and plate edges, confirmation across keyframes
    seam_straight_rms_m: float = 0.003  # a crack this close to a straight line (RMS) may be a seam ...
    seam_length_m: float = 0.30  # ... it is one when itself this long ...
    seam_extension_m: float = 0.30  # ... or when the crack response goes on along the line this far each side ...
    seam_prob: float = 0.02  # ... at this probability (the default network's calibrated crack map: its raw 0.25) ...
    seam_support: float = 0.5  # ... over this fraction of that extension
    confirm_fraction: float = 0.5  # keyframes that saw an entry: at least this share must have found it ...
    confirm_tolerance_m: float = 0.01  # ... within this distance of its pixels (keyframe and mosaic segment a defect a little differently)
    confirm_min_seen: int = 1  # ... when at least this many keyframes saw it (its whole box inside the frame)


@dataclass(frozen=True)
class Defect:
    id: str
    cls: str
    polygon_wall_m: tuple[tuple[float, float], ...]
    centroid_wall_m: tuple[float, float]
    bbox_wall_m: tuple[float, float, float, float]  # u0, v0, u1, v1
    area_m2: float
    length_m: float | None  # cracks
    confidence: float  # mean P(defect) over the region on the mosaic, 0..1
    frames: tuple[int, ...]  # sweep frames whose footprint holds the centroid
    keyframes_detected: tuple[int, ...]  # keyframes whose own detection found it
    keyframes_seen: tuple[int, ...]  # keyframes that saw it
    polygon_mosaic_px: tuple[tuple[int, int], ...]
    bbox_mosaic_xywh: tuple[int, int, int, int]
    area_px: int
    frame_range: str | None = None
    height_above_tank_top_m: float | None = None
    status: str = "suggested"
    note: str = ""
    redetected: bool = True  # False: kept from a previous run because the surveyor decided on it
    crop: str | None = None
    context: str | None = None
    crop_frame: int | None = None  # the sweep frame the crop was cut from (the sharpest that saw it); None: from the mosaic
    location: dict | None = None  # in ship terms (inspect_pipe.ship.Location.to_json); None without a survey plan
    detected_cls: str | None = None  # the detector's class when a surveyor reclassified the entry (``cls`` is then theirs)
    severity: dict | None = None  # corrosion with condition states: {"state": fair|poor|severe, "fractions": {...}}
    # the detection goes on past the edge of the surveyed region (the mosaic, less edge_margin_m):
    # the area, box and centroid are of the surveyed part only, the area a lower bound
    beyond_survey: bool = False

    def to_json(self) -> dict:
        r = lambda x: round(float(x), 4)  # noqa: E731
        return {
            "id": self.id, "class": self.cls, "status": self.status, "note": self.note,
            "polygon_wall_m": [[r(u), r(v)] for u, v in self.polygon_wall_m],
            "centroid_wall_m": [r(self.centroid_wall_m[0]), r(self.centroid_wall_m[1])],
            "bbox_wall_m": [r(x) for x in self.bbox_wall_m],
            "area_m2": round(self.area_m2, 6), "length_m": None if self.length_m is None else r(self.length_m),
            "confidence": r(self.confidence),
            "frames": list(self.frames), "keyframes_detected": list(self.keyframes_detected),
            "keyframes_seen": list(self.keyframes_seen),
            "frame_range": self.frame_range,
            "height_above_tank_top_m": None if self.height_above_tank_top_m is None else r(self.height_above_tank_top_m),
            "polygon_mosaic_px": [list(p) for p in self.polygon_mosaic_px],
            "bbox_mosaic_xywh": list(self.bbox_mosaic_xywh), "area_px": self.area_px,
            "redetected": self.redetected, "crop": self.crop, "context": self.context, "crop_frame": self.crop_frame,
            "location": self.location, "detected_class": self.detected_cls, "severity": self.severity,
            "beyond_survey": self.beyond_survey,
        }

    @classmethod
    def from_json(cls, d: dict, where: str) -> "Defect":
        try:
            return cls(
                id=str(d["id"]), cls=str(d["class"]),
                polygon_wall_m=tuple((float(u), float(v)) for u, v in d["polygon_wall_m"]),
                centroid_wall_m=(float(d["centroid_wall_m"][0]), float(d["centroid_wall_m"][1])),
                bbox_wall_m=tuple(float(x) for x in d.get("bbox_wall_m") or (0, 0, 0, 0)),  # type: ignore[arg-type]
                area_m2=float(d["area_m2"]), length_m=None if d.get("length_m") is None else float(d["length_m"]),
                confidence=float(d.get("confidence", 0.0)), frames=tuple(int(x) for x in d.get("frames", ())),
                keyframes_detected=tuple(int(x) for x in d.get("keyframes_detected", ())),
                keyframes_seen=tuple(int(x) for x in d.get("keyframes_seen", ())),
                polygon_mosaic_px=tuple((int(x), int(y)) for x, y in d.get("polygon_mosaic_px", ())),
                bbox_mosaic_xywh=tuple(int(x) for x in d.get("bbox_mosaic_xywh") or (0, 0, 0, 0)),  # type: ignore[arg-type]
                area_px=int(d.get("area_px", 0)), frame_range=d.get("frame_range"),
                height_above_tank_top_m=d.get("height_above_tank_top_m"),
                status=check_status(d.get("status"), where, str(d["id"])), note=str(d.get("note") or ""),
                redetected=bool(d.get("redetected", True)), crop=d.get("crop"), context=d.get("context"),
                crop_frame=d.get("crop_frame") if isinstance(d.get("crop_frame"), int) else None,
                location=d.get("location") if isinstance(d.get("location"), dict) else None,
                detected_cls=str(d["detected_class"]) if d.get("detected_class") else None,
                severity=d.get("severity") if isinstance(d.get("severity"), dict) else None,
                beyond_survey=d.get("beyond_survey") is True,
            )
        except (KeyError, TypeError, ValueError, IndexError) as err:
            raise InputError(where, f"defect {d.get('id', '?')!r}: field {err} missing or malformed") from None


def check_status(s, where: str, ident: str) -> str:
    if s not in STATUSES:
        raise InputError(where, f"defect {ident}: field 'status' is {s!r}", f"one of {', '.join(STATUSES)}")
    return s


# ------------------------------------------------------------------------------------ building


@dataclass(frozen=True)
class FrameView:
    """A sweep frame placed in the mosaic: its index, H (frame px -> mosaic px), size."""

    index: int
    H: np.ndarray
    size_wh: tuple[int, int]


@dataclass(frozen=True)
class KeyframeDetection:
    view: FrameView
    masks: dict[str, np.ndarray]  # class -> (h, w) bool in frame px


def _warp(mask: np.ndarray, H: np.ndarray, shape_hw) -> np.ndarray:
    return cv2.warpPerspective(mask.astype(np.uint8), H, (shape_hw[1], shape_hw[0]), flags=cv2.INTER_NEAREST) > 0


def merged_masks(
    mosaic_masks: dict[str, np.ndarray],
    keyframes: list[KeyframeDetection],
    *,
    params: RegisterParams = RegisterParams(),
) -> tuple[dict[str, np.ndarray], dict[str, list[tuple[int, np.ndarray]]]]:
    """Per class, the mosaic's decision united with keyframe evidence that at least
    ``frame_vote_min`` keyframes and ``frame_vote_fraction`` of those seeing a pixel agree on.
    Also returns, per class, each keyframe's (index, warped detection mask) for traceability."""
    out, warped = {}, {}
    for c, m in mosaic_masks.items():
        shape = m.shape
        votes = np.zeros(shape, np.uint16)
        seen = np.zeros(shape, np.uint16)
        warped[c] = []
        for kf in keyframes:
            if c not in kf.masks:
                continue
            h, w = kf.masks[c].shape
            seen += _warp(np.ones((h, w), np.uint8), kf.view.H, shape)
            wm = _warp(kf.masks[c], kf.view.H, shape)
            votes += wm
            warped[c].append((kf.view.index, wm))
        support = (votes >= params.frame_vote_min) & (votes >= params.frame_vote_fraction * np.maximum(seen, 1))
        out[c] = m | support if keyframes else m.copy()
    return out, warped


def _crack_length_px(comp: np.ndarray) -> float:
    from skimage.morphology import skeletonize

    sk = skeletonize(comp)
    if sk.sum() <= 1:
        return float(max(comp.shape))
    ys, xs = np.nonzero(sk)
    pts = set(zip(ys.tolist(), xs.tolist()))
    length = 0.0
    for y, x in pts:  # each skeleton edge once: right, down, down-right, down-left
        length += ((y, x + 1) in pts) + ((y + 1, x) in pts)
        length += math.sqrt(2) * (((y + 1, x + 1) in pts) + ((y + 1, x - 1) in pts))
    return length


def build_defects(
    masks: dict[str, np.ndarray],
    probs: dict[str, np.ndarray],
    wall: WallMap,
    views: list[FrameView],
    survey: Survey,
    *,
    keyframe_masks: dict[str, list[tuple[int, np.ndarray]]] | None = None,
    valid: np.ndarray | None = None,
    params: RegisterParams = RegisterParams(),
) -> list[Defect]:
    """Connected defects per class (fragments within ``merge_gap_m`` joined) -> Defect entries
    with provisional ids ``N001..`` (assign_ids gives the register's ids)."""
    defects: list[Defect] = []
    keyframe_masks = keyframe_masks or {}
    foot = [(v, _footprint_poly(v)) for v in views]
    if valid is not None:
        e = max(1, int(round(params.edge_margin_m / wall.m_per_px)))
        valid = cv2.erode(valid.astype(np.uint8), np.ones((2 * e + 1, 2 * e + 1), np.uint8), borderValue=0) > 0
    for c in sorted(masks):
        # detected pixels the edge of the surveyed region cut off: an entry joined to them goes on
        # beyond the survey (within merge_gap_m, as fragments are joined)
        cut = None if valid is None else (masks[c] & ~valid)
        m = masks[c] if valid is None else masks[c] & valid
        if not m.any():
            continue
        r = max(1, int(round(params.merge_gap_m / wall.m_per_px / 2)))
        joined = cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
        n, labels, stats, cents = cv2.connectedComponentsWithStats(joined, connectivity=8)
        prob = probs.get(c)
        for k in range(1, n):
            x, y, w, h, _ = stats[k]
            sub = (labels[y:y + h, x:x + w] == k) & m[y:y + h, x:x + w]
            area_px = int(sub.sum())
            if area_px == 0:
                continue
            ys, xs = np.nonzero(sub)
            cx, cy = xs.mean() + x, ys.mean() + y
            scale = wall.area_scale(np.array([cx, cy]))
            area_m2 = area_px * scale
            length = None
            if c == "crack":
                length = _crack_length_px(sub) * math.sqrt(scale)
                if length < params.min_crack_length_m or area_m2 / length > params.max_crack_width_m:
                    continue
            elif area_m2 < params.min_area_m2:
                continue
            # the outer boundary of the joined component, so one polygon holds every fragment
            cnts, _ = cv2.findContours((labels[y:y + h, x:x + w] == k).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cnt = max(cnts, key=cv2.contourArea)
            tol = max(1.0, params.polygon_tolerance_m / wall.m_per_px)
            poly = cv2.approxPolyDP(cnt, tol, True).reshape(-1, 2) + np.array([x, y])
            if len(poly) < 3:
                poly = np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]])
            poly_m = wall.to_wall(poly.astype(float))
            cent_m = wall.to_wall(np.array([[cx, cy]]))[0]
            conf = float(prob[y:y + h, x:x + w][sub].mean()) / 255.0 if prob is not None else 0.0
            frames = tuple(v.index for v, fp in foot if cv2.pointPolygonTest(fp, (float(cx), float(cy)), False) >= 0)
            det, seen = [], []
            # a keyframe found it when its own detection lies within confirm_tolerance_m of the entry's pixels
            t = max(1, int(round(params.confirm_tolerance_m / wall.m_per_px)))
            ty0, tx0 = max(0, y - t), max(0, x - t)
            near = np.zeros((min(m.shape[0], y + h + t) - ty0, min(m.shape[1], x + w + t) - tx0), np.uint8)
            near[y - ty0:y - ty0 + h, x - tx0:x - tx0 + w] = sub
            near = cv2.dilate(near, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * t + 1, 2 * t + 1))) > 0
            for idx, wm in keyframe_masks.get(c, []):
                view = next((v for v, fp in foot if v.index == idx), None)
                if view is None:
                    continue
                fp = next(fp for v, fp in foot if v.index == idx)
                # it saw the entry when the entry's whole box lies inside it: a defect the frame
                # border cuts may not be detected on that frame
                if all(cv2.pointPolygonTest(fp, (float(a), float(b)), False) >= 0 for a, b in ((x, y), (x + w, y), (x + w, y + h), (x, y + h))):
                    seen.append(idx)
                    if wm[ty0:ty0 + near.shape[0], tx0:tx0 + near.shape[1]][near].any():
                        det.append(idx)
            beyond = False
            if cut is not None:
                g = r + 1
                by0, bx0 = max(0, y - g), max(0, x - g)
                grown = np.zeros((min(m.shape[0], y + h + g) - by0, min(m.shape[1], x + w + g) - bx0), np.uint8)
                grown[y - by0:y - by0 + h, x - bx0:x - bx0 + w] = labels[y:y + h, x:x + w] == k
                grown = cv2.dilate(grown, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * g + 1, 2 * g + 1))) > 0
                beyond = bool(cut[by0:by0 + grown.shape[0], bx0:bx0 + grown.shape[1]][grown].any())
            u0, v0 = poly_m.min(0)
            u1, v1 = poly_m.max(0)
            defects.append(Defect(
                id=f"N{len(defects) + 1:03d}", cls=c,
                polygon_wall_m=tuple(map(tuple, poly_m.tolist())), centroid_wall_m=(float(cent_m[0]), float(cent_m[1])),
                bbox_wall_m=(float(u0), float(v0), float(u1), float(v1)), area_m2=float(area_m2), length_m=length,
                confidence=conf, frames=frames, keyframes_detected=tuple(det), keyframes_seen=tuple(seen),
                polygon_mosaic_px=tuple(map(tuple, poly.astype(int).tolist())), bbox_mosaic_xywh=(int(x), int(y), int(w), int(h)),
                area_px=area_px, frame_range=survey.frame_range(float(u0), float(u1)),
                height_above_tank_top_m=survey.height_above_tank_top(float(cent_m[1])),
                beyond_survey=beyond,
            ))
    return defects


def _footprint_poly(v: FrameView) -> np.ndarray:
    from ._geo import frame_footprint_px

    return frame_footprint_px(v.H, v.size_wh).astype(np.float32).reshape(-1, 1, 2)


def assign_ids(new: list[Defect], previous: list[Defect], *, params: RegisterParams = RegisterParams()) -> list[Defect]:
    """Give new entries the id, status and note of the previous entry of the same class whose
    centroid is within ``match_m`` (closest first); new ids continue after the largest used.
    A previous entry a surveyor reclassified matches on the detector's class and keeps the
    surveyor's (``detected_cls``). Previous entries a surveyor decided on (confirmed / rejected,
    or reclassified) that were not found again are kept, marked ``redetected = False``."""
    used = set()
    out = []
    pairs = []
    for i, d in enumerate(new):
        for j, p in enumerate(previous):
            if (p.detected_cls or p.cls) == d.cls:
                dist = math.dist(d.centroid_wall_m, p.centroid_wall_m)
                if dist <= params.match_m:
                    pairs.append((dist, i, j))
    match: dict[int, int] = {}
    for dist, i, j in sorted(pairs):
        if i not in match and j not in used:
            match[i] = j
            used.add(j)
    next_n = 1 + max((_id_number(p.id) for p in previous), default=0)
    for i, d in enumerate(new):
        if i in match:
            p = previous[match[i]]
            out.append(replace(d, id=p.id, status=p.status, note=p.note, redetected=True,
                               cls=p.cls if p.detected_cls else d.cls, detected_cls=p.detected_cls))
        else:
            out.append(replace(d, id=f"D{next_n:03d}", status="suggested", redetected=True))
            next_n += 1
    for j, p in enumerate(previous):
        if j not in used and (p.status != "suggested" or p.detected_cls):
            out.append(replace(p, redetected=False))
    return sorted(out, key=lambda d: _id_number(d.id))


def _id_number(ident: str) -> int:
    digits = "".join(ch for ch in ident if ch.isdigit())
    return int(digits) if digits else 0


# ------------------------------------------------------------------------------- files


def _ranges(ix) -> str:
    ix = sorted(ix)
    out, start, prev = [], None, None
    for i in ix:
        if start is None:
            start = prev = i
        elif i == prev + 1:
            prev = i
        else:
            out.append(f"{start}-{prev}" if prev != start else f"{start}")
            start = prev = i
    if start is not None:
        out.append(f"{start}-{prev}" if prev != start else f"{start}")
    return " ".join(out)


def _location_cells(loc: dict | None) -> list:
    if not loc:
        return ["", "", "", "", ""]
    blank = lambda x: "" if x is None else x  # noqa: E731
    return [loc.get("text", ""), blank(loc.get("wall")), blank(loc.get("frame")), blank(loc.get("from_centreline_m")), blank(loc.get("side"))]


def register_json(defects: list[Defect], extra: dict) -> dict:
    return {"format": REGISTER_FORMAT, "statuses": list(STATUSES), **extra, "defects": [d.to_json() for d in defects]}


def register_csv(defects: list[Defect], position_decimals: int = 4) -> str:
    """One row per entry; positions to ``position_decimals`` (the register's stated precision),
    areas to 1 cm² (0.1 cm² below 10 cm²), lengths to 1 cm."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    p = position_decimals
    for d in defects:
        w.writerow([
            d.id, d.cls, d.status, d.note, f"{d.centroid_wall_m[0]:.{p}f}", f"{d.centroid_wall_m[1]:.{p}f}",
            f"{d.area_m2:.4f}" if d.area_m2 >= 1e-3 else f"{d.area_m2:.5f}", "" if d.length_m is None else f"{d.length_m:.2f}", f"{d.confidence:.2f}",
            d.frame_range or "", "" if d.height_above_tank_top_m is None else f"{d.height_above_tank_top_m:.{p}f}",
            (d.severity or {}).get("state", ""), *_location_cells(d.location), len(d.frames), _ranges(d.frames), json.dumps([[round(u, 4), round(v, 4)] for u, v in d.polygon_wall_m]),
            "yes" if d.beyond_survey else "",
        ])
    return buf.getvalue()


def read_register(json_path: Path, csv_path: Path | None = None) -> list[Defect]:
    """A previous register with the surveyor's decisions. Both files are checked; where both
    exist, the statuses and notes of the more recently modified one win (a surveyor edits one)."""
    from ._geo import read_json

    doc = read_json(json_path)
    where = str(json_path)
    if doc.get("format") != REGISTER_FORMAT:
        raise InputError(where, f"field 'format': {doc.get('format')!r}", f"expected {REGISTER_FORMAT!r}")
    from inspect_pipe.formats import RegisterJson, validate

    validate(RegisterJson, doc, where, "docs/report.md describes the register")
    defects = [Defect.from_json(d, where) for d in doc["defects"]]
    if csv_path is not None and csv_path.exists():
        edits = read_csv_status(csv_path)
        if csv_path.stat().st_mtime > json_path.stat().st_mtime:
            by_id = {d.id: d for d in defects}
            for ident, (status, note) in edits.items():
                if ident not in by_id:
                    raise InputError(str(csv_path), f"row with id {ident!r}: no such defect in {json_path.name}")
                by_id[ident] = replace(by_id[ident], status=status, note=note)
            defects = list(by_id.values())
    return defects



def read_csv_status(path: Path) -> dict[str, tuple[str, str]]:
    try:
        text = path.read_text()
    except UnicodeDecodeError:
        raise InputError(str(path), "not UTF-8 text") from None
    rows = list(csv.DictReader(io.StringIO(text)))
    out = {}
    for n, row in enumerate(rows, start=2):
        if not row.get("id"):
            raise InputError(str(path), f"line {n}: field 'id' is empty")
        status = (row.get("status") or "").strip()
        if status not in STATUSES:
            raise InputError(str(path), f"line {n} (defect {row['id']}): field 'status' is {status!r}", f"one of {', '.join(STATUSES)}")
        out[row["id"].strip()] = (status, (row.get("note") or "").strip())
    return out
