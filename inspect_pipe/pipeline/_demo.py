"""The demo: a textured wall with known defects, a simulated inspection flight over it, the whole
pipeline, and the found defects compared with the truth.

The wall is built at run time: painted steel (procedural, seeded) with corrosion patches cut out of
the CC0 Virginia Tech corrosion images (``defects/vt_corrosion_cs``, their masks kept as ground
truth) and, when present, cracks from ``defects/crackforest`` (research-only: read from the data
folder at run time, never shipped). Without the data folder the shipped CC0 scenario wall
(``scenarios/assets/wall_vt88.jpg`` and its mask) is used.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from inspect_pipe.errors import InputError

REPO = Path(__file__).resolve().parents[2]
SHIPPED_WALL = REPO / "scenarios" / "assets" / "wall_vt88.jpg"
SHIPPED_MASK = REPO / "scenarios" / "assets" / "wall_vt88_defects.png"


@dataclass(frozen=True)
class TruthDefect:
    id: str
    cls: str
    centroid_wall_m: tuple[float, float]
    area_m2: float
    bbox_wall_m: tuple[float, float, float, float]
    source: str

    def to_json(self) -> dict:
        return {"id": self.id, "class": self.cls, "centroid_wall_m": [round(x, 4) for x in self.centroid_wall_m],
                "area_m2": round(self.area_m2, 6), "bbox_wall_m": [round(x, 4) for x in self.bbox_wall_m], "source": self.source}


@dataclass(frozen=True)
class DemoWall:
    image: Path
    mask: Path  # 255 = defect (any class)
    labels: Path  # 16-bit instance labels, 0 = none
    m_per_px: float
    origin_uv: tuple[float, float]
    truth: tuple[TruthDefect, ...]
    source: str


def paint(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Worn grey-green paint with enough texture at every scale for registration."""
    img = np.zeros((h, w), np.float32)
    for sigma, amp in ((1.2, 5.0), (4.0, 7.0), (16.0, 9.0), (60.0, 10.0)):
        n = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), sigma)
        img += amp * n / (n.std() + 1e-6)
    for _ in range(int(h * w / 700)):  # paint blemishes, dirt, drips
        c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        ax = (int(rng.integers(2, 7)), int(rng.integers(2, 7)))
        cv2.ellipse(img, c, ax, float(rng.uniform(0, 180)), 0, 360, float(rng.choice([-1, 1]) * rng.uniform(10, 22)), -1)
    base = np.array([112, 124, 104], np.float32)  # BGR
    out = base[None, None, :] + img[:, :, None] * np.array([1.0, 0.95, 0.9], np.float32)
    return np.clip(out, 0, 255).astype(np.uint8)


def _components(mask: np.ndarray, min_px: int) -> list[np.ndarray]:
    n, lab, st, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    return [lab == k for k in range(1, n) if st[k, 4] >= min_px]


def _paste_corrosion(item, img: np.ndarray, labels: np.ndarray, occupied: np.ndarray, size_m: tuple[float, float],
                     m_per_px: float, label: int, rng, margin: int) -> bool:
    """Blend the largest labelled corrosion patch of a VT image into ``img`` at a free place, its
    longest side drawn from ``size_m`` (wall metres); its pixels get ``label`` in ``labels``. False when the image
    has no usable patch or no place is free."""
    src, gt = item.load()
    if src.ndim != 3:
        return False
    comps = [c for c in _components(gt, 1500) if c.mean() < 0.35]
    if not comps:
        return False
    comp = max(comps, key=lambda c: c.sum())
    ys, xs = np.nonzero(comp)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    s = rng.uniform(*size_m) / m_per_px / max(y1 - y0, x1 - x0)
    patch = cv2.resize(src[y0:y1, x0:x1], None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    pm = cv2.resize(comp[y0:y1, x0:x1].astype(np.float32), (patch.shape[1], patch.shape[0]), interpolation=cv2.INTER_LINEAR)
    at = _place(occupied, patch.shape[0], patch.shape[1], rng, margin)
    if at is None:
        return False
    y, x = at
    alpha = cv2.GaussianBlur(pm, (0, 0), 1.0)[:, :, None]
    roi = img[y:y + patch.shape[0], x:x + patch.shape[1]].astype(np.float32)
    img[y:y + patch.shape[0], x:x + patch.shape[1]] = (alpha * patch + (1 - alpha) * roi).astype(np.uint8)
    labels[y:y + patch.shape[0], x:x + patch.shape[1]][pm > 0.5] = label
    return True


def _place(occupied: np.ndarray, hh: int, ww: int, rng, margin: int) -> tuple[int, int] | None:
    H, W = occupied.shape
    for _ in range(200):
        y, x = int(rng.integers(margin, H - hh - margin)), int(rng.integers(margin, W - ww - margin))
        if not occupied[max(0, y - margin):y + hh + margin, max(0, x - margin):x + ww + margin].any():
            occupied[y:y + hh, x:x + ww] = True
            return y, x
    return None


def build_demo_wall(out_dir: Path, data: Path | None, *, size_m=(3.6, 2.4), m_per_px: float = 0.002,
                    origin_uv=(3.0, 3.0), n_corrosion: int = 9, n_cracks: int = 3, seed: int = 5) -> DemoWall:
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    vt = data / "defects" / "vt_corrosion_cs" if data else None
    if vt is None or not (vt / "images").is_dir():
        return _shipped_wall(out_dir, m_per_px=0.003, origin_uv=origin_uv)
    from inspect_pipe.saliency_defects import labelled_set

    W, H = int(round(size_m[0] / m_per_px)), int(round(size_m[1] / m_per_px))
    img = paint(H, W, rng)
    labels = np.zeros((H, W), np.uint16)
    occupied = np.zeros((H, W), bool)
    truth: list[tuple[str, str, str]] = []
    items = labelled_set(vt, split="eval")
    rng.shuffle(items)
    margin = int(0.12 / m_per_px)
    for it in items:
        if sum(t[1] == "corrosion" for t in truth) >= n_corrosion:
            break
        if not _paste_corrosion(it, img, labels, occupied, (0.12, 0.30), m_per_px, len(truth) + 1, rng, margin):
            continue
        truth.append((f"T{len(truth) + 1:02d}", "corrosion", f"vt_corrosion_cs/{it.stem}"))
    cf = data / "defects" / "crackforest"
    if n_cracks and (cf / "image").is_dir():
        for it in labelled_set(cf, split="eval")[: n_cracks * 3]:
            if sum(t[1] == "crack" for t in truth) >= n_cracks:
                break
            src, gt = it.load()
            comps = _components(cv2.dilate(gt.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0, 400)
            if not comps:
                continue
            comp = max(comps, key=lambda c: c.sum()) & gt
            ys, xs = np.nonzero(comp)
            y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
            m = comp[y0:y1, x0:x1]
            m = cv2.dilate(m.astype(np.uint8), np.ones((2, 2), np.uint8)) > 0  # hair lines 2-4 mm wide on the wall
            at = _place(occupied, m.shape[0], m.shape[1], rng, margin)
            if at is None:
                continue
            y, x = at
            a = cv2.GaussianBlur(m.astype(np.float32), (0, 0), 0.6)[:, :, None]
            roi = img[y:y + m.shape[0], x:x + m.shape[1]].astype(np.float32)
            img[y:y + m.shape[0], x:x + m.shape[1]] = (roi * (1 - 0.8 * a)).astype(np.uint8)
            truth.append((f"T{len(truth) + 1:02d}", "crack", f"crackforest/{it.stem}"))
            labels[y:y + m.shape[0], x:x + m.shape[1]][m] = len(truth)
    return _finish(out_dir, img, labels, truth, m_per_px, origin_uv, "built from ../shared/data (CC0 VT corrosion + CrackForest at run time)")


@dataclass(frozen=True)
class WallChange:
    """A change made by ``edit_demo_wall``: a defect that appeared or grew between two surveys."""

    kind: str  # "new" or "grown"
    truth_id: str  # its id on the edited wall
    centroid_wall_m: tuple[float, float]
    area_old_m2: float
    area_new_m2: float

    def to_json(self) -> dict:
        return {"kind": self.kind, "truth": self.truth_id, "centroid_wall_m": [round(x, 4) for x in self.centroid_wall_m],
                "area_old_m2": round(self.area_old_m2, 6), "area_new_m2": round(self.area_new_m2, 6)}


def edit_demo_wall(wall: DemoWall, out_dir: Path, data: Path, *, n_new: int = 3, n_grow: int = 2, grow: float = 1.4,
                   seed: int = 1) -> tuple[DemoWall, list[WallChange]]:
    """The same wall a while later: ``n_new`` corrosion patches appeared (cut from VT corrosion
    images of the evaluation split not on the wall yet) and ``n_grow`` corrosion patches grew
    (pasted again ``grow`` times larger over themselves, about their centroid). Returns the
    edited wall (its truth holds every defect) and the changes."""
    rng = np.random.default_rng(seed)
    img = cv2.imread(str(wall.image))
    labels = cv2.imread(str(wall.labels), cv2.IMREAD_UNCHANGED).astype(np.uint16)
    old_area = {k: int((labels == k).sum()) for k in range(1, int(labels.max()) + 1)}
    truth = [(t.id, t.cls, t.source) for t in wall.truth]
    changes: list[tuple[str, int]] = []
    corr = [k for k, t in enumerate(wall.truth, start=1) if t.cls == "corrosion"]
    for k in list(rng.permutation(corr))[:n_grow]:
        ys, xs = np.nonzero(labels == k)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        patch, m = img[y0:y1, x0:x1].copy(), (labels[y0:y1, x0:x1] == k).astype(np.float32)
        big = cv2.resize(patch, None, fx=grow, fy=grow, interpolation=cv2.INTER_LINEAR)
        bm = cv2.resize(m, (big.shape[1], big.shape[0]), interpolation=cv2.INTER_LINEAR)
        cy, cx = int(round(ys.mean())), int(round(xs.mean()))
        ty, tx = cy - int(round((ys.mean() - y0) * grow)), cx - int(round((xs.mean() - x0) * grow))
        H, W = labels.shape
        sy0, sx0 = max(0, -ty), max(0, -tx)
        ty0, tx0 = max(0, ty), max(0, tx)
        ty1, tx1 = min(H, ty + big.shape[0]), min(W, tx + big.shape[1])
        big, bm = big[sy0:sy0 + ty1 - ty0, sx0:sx0 + tx1 - tx0], bm[sy0:sy0 + ty1 - ty0, sx0:sx0 + tx1 - tx0]
        a = cv2.GaussianBlur(bm, (0, 0), 1.0)[:, :, None]
        roi = img[ty0:ty1, tx0:tx1].astype(np.float32)
        img[ty0:ty1, tx0:tx1] = (a * big + (1 - a) * roi).astype(np.uint8)
        sub = labels[ty0:ty1, tx0:tx1]
        sub[(bm > 0.5) & ((sub == 0) | (sub == k))] = k
        changes.append(("grown", int(k)))
    from inspect_pipe.saliency_defects import labelled_set

    used = {t.source for t in wall.truth}
    items = [it for it in labelled_set(data / "defects" / "vt_corrosion_cs", split="eval") if f"vt_corrosion_cs/{it.stem}" not in used]
    rng.shuffle(items)
    occupied = cv2.dilate((labels > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    margin = int(0.12 / wall.m_per_px)
    added = 0
    for it in items:
        if added >= n_new:
            break
        if not _paste_corrosion(it, img, labels, occupied, (0.10, 0.22), wall.m_per_px, len(truth) + 1, rng, margin):
            continue
        truth.append((f"T{len(truth) + 1:02d}", "corrosion", f"vt_corrosion_cs/{it.stem}"))
        changes.append(("new", len(truth)))
        added += 1
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    new_wall = _finish(out_dir, img, labels, truth, wall.m_per_px, wall.origin_uv, wall.source + f"; edited: {len(changes)} changes")
    by_id = {t.id: t for t in new_wall.truth}
    out = []
    for kind, k in changes:
        t = by_id[f"T{k:02d}"]
        out.append(WallChange(kind, t.id, t.centroid_wall_m, old_area.get(k, 0) * wall.m_per_px ** 2 if kind == "grown" else 0.0, t.area_m2))
    return new_wall, out


def _shipped_wall(out_dir: Path, *, m_per_px: float, origin_uv) -> DemoWall:
    if not SHIPPED_WALL.is_file():
        raise InputError(str(SHIPPED_WALL), "missing", "give --data ../shared/data to build the demo wall")
    img = cv2.imread(str(SHIPPED_WALL))
    mask = cv2.imread(str(SHIPPED_MASK), cv2.IMREAD_GRAYSCALE) > 127
    n, lab = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    truth = [(f"T{k:02d}", "corrosion", "scenarios/assets/wall_vt88_defects.png") for k in range(1, n)]
    return _finish(out_dir, img, lab.astype(np.uint16), truth, m_per_px, origin_uv, "shipped CC0 scenario wall (wall_vt88)")


def _finish(out_dir, img, labels, truth, m_per_px, origin_uv, source) -> DemoWall:
    u0, v0 = origin_uv
    out = []
    for k, (ident, cls, src) in enumerate(truth, start=1):
        ys, xs = np.nonzero(labels == k)
        if len(xs) == 0:
            continue
        u = u0 + (xs + 0.5) * m_per_px
        v = v0 - (ys + 0.5) * m_per_px
        out.append(TruthDefect(ident, cls, (float(u.mean()), float(v.mean())), float(len(xs) * m_per_px**2),
                               (float(u.min()), float(v.min()), float(u.max()), float(v.max())), src))
    paths = out_dir / "wall.png", out_dir / "wall_mask.png", out_dir / "wall_labels.png"
    cv2.imwrite(str(paths[0]), img)
    cv2.imwrite(str(paths[1]), (labels > 0).astype(np.uint8) * 255)
    cv2.imwrite(str(paths[2]), labels)
    (out_dir / "truth.json").write_text(json.dumps({
        "format": "inspect_pipe.demo_truth/1", "source": source, "m_per_px": m_per_px, "origin_uv": list(origin_uv),
        "size_px": [int(img.shape[1]), int(img.shape[0])], "defects": [t.to_json() for t in out]}, indent=1))
    return DemoWall(*paths, m_per_px, tuple(origin_uv), tuple(out), source)  # type: ignore[arg-type]


def demo_scenario(wall: DemoWall, path: Path, *, base: Path | None = None, duration_s: float | None = None, seed: int | None = None) -> Path:
    """The inspection-sweep scenario (three lawnmower passes at 1.5 m) over ``wall``; ``seed``
    another flight of it (sensor noise, wind: a second survey of the same wall)."""
    base = base or REPO / "scenarios" / "inspection_sweep_wall.yaml"
    doc = yaml.safe_load(base.read_text())
    doc["name"] = "demo_inspection"
    if seed is not None:
        doc["seed"] = int(seed)
    doc["world"]["front_wall_texture"] = {
        "image": str(wall.image.resolve()), "m_per_px": wall.m_per_px, "origin_uv": list(wall.origin_uv),
        "defects_mask": str(wall.mask.resolve()),
    }
    if duration_s is not None:
        doc["duration_s"] = duration_s
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


DEMO_SURVEY = {"vessel": "MV Demo Carrier (simulated)", "hold": "No. 3", "wall": "front wall", "side": "port",
               "member": "plating", "frame_spacing_m": 0.8, "reference_frame": 112}
#: The demo's survey plan (docs/ship.md): the simulated hold's front wall is the fore transverse
#: bulkhead of hold No. 3, stiffeners 0.7 m apart; the simulator's hold frame is the plan's.
DEMO_PLAN = {
    "format": "inspect_pipe.survey_plan/1",
    "vessel": {"name": "MV Demo Carrier (simulated)", "imo": "9074729", "class_society": "demo class"},
    "survey": {"type": "intermediate survey (demonstration)", "date": "2026-11-25", "rit_provider": "inspect_pipe simulator",
               "pilot": "scripted operator", "surveyor": "to be signed"},
    "compartment": {"name": "Cargo hold No. 3"},
    "hold": {"aft_bulkhead_frame": 112, "frame_spacing_m": 0.8, "tank_top_above_baseline_m": 1.6,
             "length_m": 12.0, "width_m": 10.0, "height_m": 16.0},
    "wall": {"name": "fore_transverse_bulkhead", "stiffener_spacing_m": 0.7},
    "equipment": {"drone": "supervised-autonomy MAV (simulated)", "camera": "752 x 480, 60 deg (simulated)",
                  "lighting": "on-board LED (simulated)"},
    "limitations": ["a simulated flight over a wall built from public images: a demonstration, not a survey"],
}


def _grown_masks(wall: DemoWall, truth, match_m: float) -> list[np.ndarray]:
    """Each true defect's mask on the wall (label N of the labels image for the defect "TNN"),
    grown by ``match_m``."""
    labels = cv2.imread(str(wall.labels), cv2.IMREAD_UNCHANGED)
    if labels is None:
        raise InputError(str(wall.labels), "unreadable", "rebuild the demo wall with --force")
    r = match_m / wall.m_per_px
    out = []
    for t in truth:
        dist = cv2.distanceTransform((labels != int(t.id.lstrip("T"))).astype(np.uint8), cv2.DIST_L2, 5)
        out.append(dist <= r)
    return out


def compare_with_truth(defects, truth, *, match_m: float = 0.15, wall: DemoWall | None = None) -> dict:
    """Match register entries (not rejected) to true defects of the same class.

    An entry is near a true defect when its centroid lies within ``match_m`` of the defect's
    mask (with ``wall``: its labels image) or else inside its box grown by ``match_m``. Each true
    defect first takes the closest entry near it; then every other entry near one or more of
    them joins the one whose centroid is closest, as a piece of it (a large patch is often
    registered as several regions: its area is their sum, its place their area-weighted
    centroid). Per defect: the pieces, the centroid error (m) and the relative area error
    (cracks: register area vs the true mask's); entries that are no piece of a defect are
    counted as other entries."""
    found = [d for d in defects if d.status != "rejected" and d.redetected]
    masks = _grown_masks(wall, truth, match_m) if wall is not None else None

    def inside(d, k: int) -> bool:
        t = truth[k]
        if d.cls != t.cls:
            return False
        u, v = d.centroid_wall_m
        if masks is not None:
            m = masks[k]
            x = int(math.floor((u - wall.origin_uv[0]) / wall.m_per_px))  # type: ignore[union-attr]
            y = int(math.floor((wall.origin_uv[1] - v) / wall.m_per_px))  # type: ignore[union-attr]
            return 0 <= y < m.shape[0] and 0 <= x < m.shape[1] and bool(m[y, x])
        u0, v0, u1, v1 = t.bbox_wall_m
        return u0 - match_m <= u <= u1 + match_m and v0 - match_m <= v <= v1 + match_m

    used: set[int] = set()
    pieces: dict[int, list[int]] = {}
    for k, t in enumerate(truth):
        cands = [(math.dist(d.centroid_wall_m, t.centroid_wall_m), i) for i, d in enumerate(found)
                 if i not in used and inside(d, k)]
        if cands:
            i = min(cands)[1]
            used.add(i)
            pieces[k] = [i]
    for i, d in enumerate(found):
        if i in used:
            continue
        near = [(math.dist(d.centroid_wall_m, truth[k].centroid_wall_m), k) for k in pieces if inside(d, k)]
        if near:
            pieces[min(near)[1]].append(i)
            used.add(i)
    rows = []
    for k, t in enumerate(truth):
        if k not in pieces:
            rows.append({"truth": t.id, "class": t.cls, "found": None})
            continue
        ds = [found[i] for i in pieces[k]]
        area = sum(d.area_m2 for d in ds)
        w = [max(d.area_m2, 1e-12) for d in ds]
        cu = float(np.average([d.centroid_wall_m[0] for d in ds], weights=w))
        cv = float(np.average([d.centroid_wall_m[1] for d in ds], weights=w))
        rows.append({"truth": t.id, "class": t.cls, "found": ds[0].id, "pieces": [d.id for d in ds],
                     "centroid_error_m": round(math.dist((cu, cv), t.centroid_wall_m), 4),
                     "area_true_m2": round(t.area_m2, 5), "area_found_m2": round(area, 5),
                     "area_error": round((area - t.area_m2) / t.area_m2, 4)})
    matched = [r for r in rows if r["found"]]
    return {
        "truth": len(truth), "found": len(found), "matched": len(matched),
        "false_alarms": len(found) - len(used),
        "median_centroid_error_m": float(np.median([r["centroid_error_m"] for r in matched])) if matched else None,
        "median_abs_area_error": float(np.median([abs(r["area_error"]) for r in matched])) if matched else None,
        "rows": rows,
    }
