"""Report files: images, COCO, the register, HTML (Jinja2) and the same HTML as PDF (WeasyPrint)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np

from inspect_pipe._files import atomic_write, write_json, write_png

COLOURS = {"corrosion": (0, 120, 255), "crack": (255, 0, 200)}  # BGR
STATUS_COLOURS = {"confirmed": (0, 170, 0), "rejected": (128, 128, 128)}
TEMPLATE = "report_template.html"


def _bgr(mosaic_bgra: np.ndarray) -> np.ndarray:
    bgr = mosaic_bgra[:, :, :3].copy()
    bgr[mosaic_bgra[:, :, 3] == 0] = (235, 235, 235)
    return bgr


def overlay_image(report, max_w: int = 1600) -> np.ndarray:
    img = _bgr(report.inputs.mosaic)
    s = min(1.0, max_w / img.shape[1])
    small = cv2.resize(img, (int(img.shape[1] * s), int(img.shape[0] * s)), interpolation=cv2.INTER_AREA)
    for d in report.defects:
        if not d.redetected or not d.polygon_mosaic_px:
            continue
        col = STATUS_COLOURS.get(d.status, COLOURS.get(d.cls, (0, 0, 255)))
        poly = (np.asarray(d.polygon_mosaic_px, float) * s).round().astype(np.int32)
        cv2.polylines(small, [poly], True, col, 2, cv2.LINE_AA)
        x, y = poly.min(0)
        cv2.putText(small, d.id, (int(x), max(12, int(y) - 3)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(small, d.id, (int(x), max(12, int(y) - 3)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, col, 1, cv2.LINE_AA)
    return small


def crop_images(report, d, img: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(crop around the defect with its outline, context thumbnail with a box); ``img``: the
    mosaic as BGR on a light background (computed when not given)."""
    img = _bgr(report.inputs.mosaic) if img is None else img
    H, W = img.shape[:2]
    x, y, w, h = d.bbox_mosaic_xywh
    m = max(16, int(0.25 * max(w, h)))
    x0, y0, x1, y1 = max(0, x - m), max(0, y - m), min(W, x + w + m), min(H, y + h + m)
    crop = img[y0:y1, x0:x1].copy()
    poly = np.asarray(d.polygon_mosaic_px, np.int32) - np.array([x0, y0])
    cv2.polylines(crop, [poly], True, COLOURS.get(d.cls, (0, 0, 255)), 1, cv2.LINE_AA)
    s = 240 / max(crop.shape[:2])
    crop = cv2.resize(crop, (max(1, int(crop.shape[1] * s)), max(1, int(crop.shape[0] * s))),
                      interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_NEAREST)
    scale_bar(crop, s / report.wall.m_per_px)
    ctx_half = max(3 * max(w, h), int(0.4 / report.wall.m_per_px))  # at least 0.8 m of wall around it
    cx, cy = x + w // 2, y + h // 2
    cx0, cy0, cx1, cy1 = max(0, cx - ctx_half), max(0, cy - ctx_half), min(W, cx + ctx_half), min(H, cy + ctx_half)
    ctx = img[cy0:cy1, cx0:cx1].copy()
    cv2.rectangle(ctx, (x - cx0 - 4, y - cy0 - 4), (x - cx0 + w + 4, y - cy0 + h + 4), (0, 0, 255), max(2, ctx_half // 80))
    s = 240 / max(ctx.shape[:2])
    ctx = cv2.resize(ctx, (max(1, int(ctx.shape[1] * s)), max(1, int(ctx.shape[0] * s))), interpolation=cv2.INTER_AREA)
    scale_bar(ctx, s / report.wall.m_per_px)
    return crop, ctx


def _nice_length_m(max_m: float) -> float:
    """The longest of 1, 2, 5 x 10^k metres not above ``max_m``."""
    best = 0.001
    for e in range(-3, 2):
        for f in (1, 2, 5):
            if f * 10.0 ** e <= max_m:
                best = f * 10.0 ** e
    return best


def scale_bar(img: np.ndarray, px_per_m: float) -> np.ndarray:
    """Draw a scale bar (a round length near a quarter of the width) in the lower-left corner."""
    if not np.isfinite(px_per_m) or px_per_m <= 0:
        return img
    h, w = img.shape[:2]
    L = _nice_length_m(0.3 * w / px_per_m)
    n = int(round(L * px_per_m))
    x0, y0 = 8, h - 10
    text = f"{L * 100:g} cm" if L < 1 else f"{L:g} m"
    cv2.rectangle(img, (x0 - 3, y0 - 20), (x0 + max(n, 60) + 3, y0 + 5), (255, 255, 255), -1)
    cv2.line(img, (x0, y0), (x0 + n, y0), (0, 0, 0), 3)
    for x in (x0, x0 + n):
        cv2.line(img, (x, y0 - 4), (x, y0 + 3), (0, 0, 0), 2)
    cv2.putText(img, text, (x0 + 2, y0 - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return img


class FrameCropper:
    """Crops of a defect from the original sweep frames that saw it: among the frames whose
    footprint holds the defect's whole box (else its centre), the ``candidates`` whose centres are
    closest to it are cut out (undistorted, as the mosaic used them) and the sharpest by variance
    of the Laplacian is kept."""

    def __init__(self, report, candidates: int = 4, cache: int = 48) -> None:
        from inspect_pipe.mosaic import SweepSource

        from ._geo import frame_footprint_px

        self.report = report
        self.source = SweepSource(report.inputs.sweep) if report.inputs.sweep is not None else None
        self.views = [(v, frame_footprint_px(v.H, v.size_wh)) for v in report.views]
        self.candidates = candidates
        self._cache: dict[int, np.ndarray | None] = {}
        self._order: list[int] = []
        self._size = cache

    def _load(self, idx: int) -> np.ndarray | None:
        if idx not in self._cache:
            try:
                img = self.source.load(idx)
            except Exception:  # noqa: BLE001 - an unreadable frame is just not a candidate
                img = None
            self._cache[idx] = img
            self._order.append(idx)
            if len(self._order) > self._size:
                self._cache.pop(self._order.pop(0), None)
        return self._cache[idx]

    def crop(self, d):
        """(BGR crop with outline and scale bar, frame index, Laplacian variance, frames tried) or None."""
        if self.source is None or not d.polygon_mosaic_px:
            return None
        x, y, w, h = d.bbox_mosaic_xywh
        corners = [(x, y), (x + w, y), (x + w, y + h), (x, y + h)]
        c = (x + w / 2, y + h / 2)
        full, centre = [], []
        for v, fp in self.views:
            poly = fp.astype(np.float32).reshape(-1, 1, 2)
            if cv2.pointPolygonTest(poly, c, False) < 0:
                continue
            fc = fp.mean(0)
            dist = float(np.hypot(fc[0] - c[0], fc[1] - c[1]))
            (full if all(cv2.pointPolygonTest(poly, (float(a), float(b)), False) >= 0 for a, b in corners) else centre).append((dist, v))
        cands = sorted(full or centre, key=lambda t: t[0])[: self.candidates]
        best = None
        for _, v in cands:
            img = self._load(v.index)
            if img is None:
                continue
            Hinv = np.linalg.inv(v.H)
            poly = cv2.perspectiveTransform(np.asarray(d.polygon_mosaic_px, np.float64).reshape(-1, 1, 2), Hinv).reshape(-1, 2)
            bx0, by0 = poly.min(0)
            bx1, by1 = poly.max(0)
            m = max(16.0, 0.25 * max(bx1 - bx0, by1 - by0))
            fh, fw = img.shape[:2]
            X0, Y0 = int(max(0, bx0 - m)), int(max(0, by0 - m))
            X1, Y1 = int(min(fw, bx1 + m + 1)), int(min(fh, by1 + m + 1))
            if X1 - X0 < 8 or Y1 - Y0 < 8:
                continue
            patch = img[Y0:Y1, X0:X1]
            grey = patch if patch.ndim == 2 else cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY)
            sharp = float(cv2.Laplacian(grey, cv2.CV_64F).var())
            if best is None or sharp > best[2]:
                best = (v, (X0, Y0, X1, Y1), sharp, poly)
        if best is None:
            return None
        v, (X0, Y0, X1, Y1), sharp, poly = best
        img = self._load(v.index)
        patch = img[Y0:Y1, X0:X1].copy()
        if patch.ndim == 2:
            patch = cv2.cvtColor(patch, cv2.COLOR_GRAY2BGR)
        s = 240 / max(patch.shape[:2])
        out = cv2.resize(patch, (max(1, int(patch.shape[1] * s)), max(1, int(patch.shape[0] * s))),
                         interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_CUBIC)
        cv2.polylines(out, [((poly - [X0, Y0]) * s).round().astype(np.int32)], True, COLOURS.get(d.cls, (0, 0, 255)), 1, cv2.LINE_AA)
        # frame px -> mosaic px scale at the defect (H's Jacobian), mosaic px -> metres
        cx, cy = poly.mean(0)
        J = _jacobian(v.H, cx, cy)
        m_per_frame_px = self.report.wall.m_per_px * float(np.sqrt(abs(np.linalg.det(J))))
        scale_bar(out, s / m_per_frame_px)
        return out, v.index, sharp, len(cands)


def _jacobian(H: np.ndarray, x: float, y: float) -> np.ndarray:
    p = H @ np.array([x, y, 1.0])
    w = p[2]
    return np.array([[H[0, 0] * w - p[0] * H[2, 0], H[0, 1] * w - p[0] * H[2, 1]],
                     [H[1, 0] * w - p[1] * H[2, 0], H[1, 1] * w - p[1] * H[2, 1]]]) / (w * w)


def coverage_image(report, max_w: int = 900) -> np.ndarray:
    cov = report.coverage
    img = np.full(cov.usable.shape + (3,), (60, 60, 220), np.uint8)  # gap: red
    img[cov.imaged & ~cov.usable] = (0, 200, 255)  # imaged but not usable: amber
    img[cov.usable] = (90, 190, 90)  # usable: green
    s = max(1.0, min(4.0, max_w / img.shape[1]))
    img = cv2.resize(img, (int(img.shape[1] * s), int(img.shape[0] * s)), interpolation=cv2.INTER_NEAREST)
    g = report.coverage.grid
    n = max(1, int(round(report.params.rating.area_size_m / g.cell_m)))  # area grid lines and names
    for a in report.rating.areas:
        c0 = int(round((a.u0_m - g.u0_m) / g.cell_m * s))
        r0 = int(round((g.v_top_m - a.v1_m) / g.cell_m * s))
        cv2.rectangle(img, (c0, r0), (c0 + int(n * s), r0 + int(n * s)), (40, 40, 40), 1)
        cv2.putText(img, f"{a.name} {a.rating}", (c0 + 4, r0 + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (20, 20, 20), 1, cv2.LINE_AA)
    for d in report.defects:
        u, v = d.centroid_wall_m
        cv2.circle(img, (int((u - g.u0_m) / g.cell_m * s), int((g.v_top_m - v) / g.cell_m * s)), 3, (0, 0, 0), -1)
    return img


def mosaic_png_path(report) -> Path:
    """mosaic.png of the run: beside mosaic.json (``inputs.mosaic_where``), under the name it gives."""
    name = report.inputs.mosaic_doc.get("mosaic") or "mosaic.png"
    return Path(report.inputs.mosaic_where).resolve().parent / str(name)


def coco(report, out: Path | None = None) -> dict:
    """COCO instances of the mosaic; ``file_name`` is the mosaic's path relative to ``out``
    (where coco.json is written), so a COCO tool opened on that folder finds the image."""
    m = report.inputs.mosaic
    png = mosaic_png_path(report)
    file_name = os.path.relpath(png, Path(out).resolve()) if out is not None else png.name
    cats = [{"id": 1, "name": "corrosion", "supercategory": "defect"}, {"id": 2, "name": "crack", "supercategory": "defect"}]
    ids = {c["name"]: c["id"] for c in cats}
    anns = []
    for d in report.defects:
        if d.status == "rejected" or not d.redetected or d.cls not in ids:
            continue
        poly = [float(c) for p in d.polygon_mosaic_px for c in p]
        anns.append({
            "id": len(anns) + 1, "image_id": 1, "category_id": ids[d.cls], "segmentation": [poly],
            "area": float(d.area_px), "bbox": [float(x) for x in d.bbox_mosaic_xywh], "iscrowd": 0,
            "attributes": {"defect_id": d.id, "status": d.status, "confidence": round(d.confidence, 4),
                           "area_m2": round(d.area_m2, 6), "centroid_wall_m": [round(x, 4) for x in d.centroid_wall_m]},
        })
    return {
        "info": {"description": "inspect_pipe defect register of a wall mosaic (rejected entries left out); detector "
                                f"{report.trace.get('detector_engine')} engine, {report.trace.get('model_file')} v{report.trace.get('model_version')}",
                 "version": report.trace["software"], "date_created": report.trace["created_utc"]},
        "licenses": [],
        "images": [{"id": 1, "file_name": file_name, "width": int(m.shape[1]), "height": int(m.shape[0])}],
        "categories": cats, "annotations": anns,
    }


def _frames_text(ix) -> str:
    from ._register import _ranges

    r = _ranges(ix)
    return r if len(r) < 60 else r[:57] + "..."


def render_html(report, assets: dict) -> str:
    import jinja2

    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(Path(__file__).parent)), autoescape=True)
    tpl = env.get_template(TEMPLATE)
    from ._screen import confirmation_text

    return tpl.render(r=report, assets=assets, frames_text=_frames_text, cov=report.coverage.to_json(),
                      confirmation=confirmation_text(report.params.register))  # the JSON record stays in defects.json


def render_pdf(html: str, base: Path, path: Path) -> str | None:
    """Write ``path`` from the HTML; None, or why it could not."""
    try:
        import weasyprint
    except ImportError as err:
        return f"WeasyPrint is not installed ({err}); pip install 'inspect-pipe[report]'"
    except OSError as err:  # missing Pango/HarfBuzz shared libraries
        return f"WeasyPrint cannot load its system libraries ({err}); on Debian: apt-get install libpango-1.0-0 libpangoft2-1.0-0"
    try:
        pdf = weasyprint.HTML(string=html, base_url=str(base)).write_pdf()
    except Exception as err:  # noqa: BLE001 - any renderer failure leaves the HTML report standing
        return f"WeasyPrint failed: {err.__class__.__name__}: {err}"
    atomic_write(path, pdf)
    return None


def render_all(report, out: Path, *, log=print) -> dict:
    from ._report import register_files

    a = out / "assets"
    (a / "crops").mkdir(parents=True, exist_ok=True)
    write_png(a / "overlay.png", overlay_image(report))
    write_png(a / "coverage.png", coverage_image(report))
    defects = []
    bgr = _bgr(report.inputs.mosaic)
    cropper = FrameCropper(report)
    report.crop_info = {}
    for d in report.defects:
        if d.redetected and d.polygon_mosaic_px:
            crop, ctx = crop_images(report, d, bgr)
            fc = cropper.crop(d)
            if fc is not None:  # from the sharpest original frame that saw it
                crop, idx, sharp, n = fc
                report.crop_info[d.id] = {"frame": idx, "sharpness": round(sharp, 1), "of": n}
            else:  # a folder mosaic: no frames to go back to
                report.crop_info[d.id] = {"frame": None}
            write_png(a / "crops" / f"{d.id}.png", crop)
            write_png(a / "crops" / f"{d.id}_context.png", ctx)
            d = d.__class__(**{**d.__dict__, "crop": f"assets/crops/{d.id}.png", "context": f"assets/crops/{d.id}_context.png",
                               "crop_frame": report.crop_info[d.id]["frame"]})
        defects.append(d)
    report.defects = defects
    reg, csv_text = register_files(report)
    write_json(out / "defects.json", reg)
    atomic_write(out / "defects.csv", csv_text.encode())
    write_json(out / "coco.json", coco(report, out))
    write_json(out / "coverage.json", {"format": "inspect_pipe.coverage/1", **report.coverage.to_json(),
                                       "separate_mosaics": report.separate})
    if report.separate:
        n = sum(g["n_frames"] for g in report.separate)
        log(f"warning: {n} placed frames in {len(report.separate)} separate mosaic(s) "
            f"({', '.join(g['image'] for g in report.separate)}) are not inspected in this report: no image pair ties them "
            "to the main mosaic (fly across the gap again, or run inspect-pipe detect on those images)")
    write_json(out / "rating.json", {"format": "inspect_pipe.rating/1", **report.rating.to_json()})
    assets = {"overlay": "assets/overlay.png", "coverage": "assets/coverage.png"}
    html = render_html(report, assets)
    atomic_write(out / "report.html", html.encode())
    written = {"html": out / "report.html", "defects_json": out / "defects.json", "defects_csv": out / "defects.csv",
               "coco": out / "coco.json", "pdf": None}
    if report.params.pdf:
        why = render_pdf(html, out, out / "report.pdf")
        if why is None:
            written["pdf"] = out / "report.pdf"
        else:
            log(f"warning: {out / 'report.pdf'} not written: {why}; report.html has the same content")
    return written
