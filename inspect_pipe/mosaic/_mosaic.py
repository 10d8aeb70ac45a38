"""The mosaic step: register a frame source, blend each group, write ``OUT/``."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

import inspect_pipe

from ._blas import with_one_blas_thread
from ._blend import BlendParams, CanvasTooLarge, render
from inspect_pipe._files import write_json, write_png
from ._register import FrameSource, Registration, RegisterParams, register
from ._sweep_input import SweepSource, control_point_geometry, take_off_frames, wall_geometry

FORMAT = "inspect_pipe.mosaic/1"


@dataclass(frozen=True)
class MosaicParams:
    register: RegisterParams = field(default_factory=RegisterParams)
    blend: BlendParams = field(default_factory=BlendParams)


@dataclass
class MosaicOutput:
    """What was written, for the caller to report on."""

    out_dir: Path
    images: list[Path]
    registration: Registration
    H: dict[int, np.ndarray]  # frame -> mosaic px of its group's image
    group_of: dict[int, int]
    problems: list[str]  # bad-input findings, one line each (first is the headline)
    n_input: int = 0
    warnings: list[str] = field(default_factory=list)  # a sweep's skipped lines and unplaceable frames: the mosaic stands
    #: False: the result had problems and OUT holds an earlier mosaic made without any, which was
    #: kept (``_publish.staged``); nothing of this run is in OUT.
    published: bool = True

    @property
    def n_placed(self) -> int:
        return len(self.H)


def _image_name(group: int) -> str:
    return "mosaic.png" if group == 0 else f"mosaic_group{group}.png"


@with_one_blas_thread
def run_mosaic(
    source: FrameSource,
    out_dir: Path,
    *,
    params: MosaicParams = MosaicParams(),
    progress: Callable[[str, int, int], None] | None = None,
    extra: dict | None = None,
) -> MosaicOutput:
    """Mosaic ``source`` into ``out_dir``: ``mosaic.png`` (largest group), ``mosaic_group<k>.png``
    for other groups, and ``mosaic.json``. Never raises on bad frames: they are listed."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    reg = register(source, params=params.register, progress=progress)
    H_all: dict[int, np.ndarray] = {}
    group_of: dict[int, int] = {}
    images: list[Path] = []
    groups_json = []
    model_of: dict[int, str] = {}
    unplaced = dict(reg.unplaced)
    # Each group's image is encoded and written in a thread while the next group blends (cv2's
    # PNG encoder releases the GIL; Haltbrekken's three groups: 2.7 s of PNG).
    written = []
    with ThreadPoolExecutor(max_workers=1) as writer:  # waits for the writes, even when a group fails
        for g, group in enumerate(reg.groups):
            if progress:
                progress("blending", g + 1, len(reg.groups))
            try:
                distorted = _distorted(group.camera, reg.size_wh)
                load = _undistorting(source.load, group.camera) if distorted else source.load
                mosaic, Hc = render(load, {f: group.H[f] for f in group.keyframes}, reg.size_wh, vignetting=reg.vignetting,
                                    params=params.blend, thumbnails=None if distorted else reg.thumbnails)
                k0 = group.keyframes[0]
                shift = Hc[k0] @ np.linalg.inv(group.H[k0])  # the canvas offset, for frames not blended
                for f in group.frames:
                    if f not in Hc:
                        h = shift @ group.H[f]
                        Hc[f] = h / h[2, 2]
            except CanvasTooLarge as err:
                for f in group.frames:
                    unplaced[f] = f"group layout implausible: {err}"
                continue
            k = len(images)
            path = out_dir / _image_name(k)
            # PNG level 1: 0.21 s against 0.35 s at level 3 on synth_rust_sweep, 6 % larger
            written.append(writer.submit(write_png, path, mosaic, compression=1))
            images.append(path)
            for f, h in Hc.items():
                H_all[f] = h
                group_of[f] = k
            groups_json.append({
                "id": k, "image": path.name, "size_wh": [int(mosaic.shape[1]), int(mosaic.shape[0])],
                "n_frames": len(group.frames), "n_keyframes": len(group.keyframes), "rms_px": round(group.rms_px, 4),
                **_model_json(group, reg.size_wh),
            })
            model_of.update({f: group.model for f in group.frames})
    for w in written:
        w.result()  # a failed write raises here, before mosaic.json names the image
    single_frame = len(source) == 1 and 0 in reg.n_features  # readable, nothing to register it to
    if single_frame:  # one image is its own mosaic
        img = source.load(0)
        h, w = img.shape[:2]
        path = out_dir / _image_name(0)
        bgra = np.dstack([img if img.ndim == 3 else np.repeat(img[..., None], 3, 2), np.full((h, w), 255, np.uint8)])
        write_png(path, bgra)
        images.append(path)
        H_all[0], group_of[0] = np.eye(3), 0
        groups_json.append({"id": 0, "image": path.name, "size_wh": [w, h], "n_frames": 1, "rms_px": 0.0})
        unplaced.pop(0, None)

    doc = {
        "format": FORMAT,
        "software": f"inspect_pipe {inspect_pipe.__version__}",
        "mosaic": images[0].name if images else None,
        "frames": [
            {"index": f, "file": source.name(f), "H": H_all[f].tolist(), "group": group_of[f], "image": _image_name(group_of[f]),
             "model": model_of.get(f, "homography")}
            for f in sorted(H_all)
        ],
        "unplaced": [{"index": f, "file": source.name(f), "reason": r} for f, r in sorted(unplaced.items())],
        "groups": groups_json,
        "n_input_frames": len(source),
        "pairs": {"matched": len(reg.pairs), "rejected": len(reg.failures)},
        "vignetting": None if reg.vignetting is None else {
            "model": "1/(1 + a r^2 + b r^4), r = radius / half-diagonal", **asdict(reg.vignetting)
        },
        "params": asdict(params),
    }
    if extra:
        doc.update(extra)
    write_json(out_dir / "mosaic.json", doc)

    problems = _problems(source, unplaced, H_all, single_frame)
    problems += [f"group {g['id']}: {g['note']}" for g in groups_json if "contradicts" in g.get("note", "")]
    return MosaicOutput(out_dir, images, reg, H_all, group_of, problems, len(source))


def _distorted(camera, size_wh: tuple[int, int], tolerance_px: float = 0.5) -> bool:
    """Whether the group's homographies are for undistorted pixels (the distortion found matters)."""
    return camera is not None and camera.max_distortion_px(size_wh) > tolerance_px


def _undistorting(load: Callable[[int], np.ndarray], camera) -> Callable[[int], np.ndarray]:
    import cv2

    dist = np.array([camera.k1, camera.k2, 0.0, 0.0])
    return lambda i: cv2.undistort(load(i), camera.K, dist)


def _model_json(group, size_wh: tuple[int, int]) -> dict:
    """What global model placed a group's frames, and the camera it used or found."""
    out: dict = {"model": group.model}
    if group.camera is not None:
        cam = group.camera
        out["camera"] = {"focal_px": round(float(cam.f), 2), "principal_px": [float(cam.cx), float(cam.cy)],
                         "k1": float(cam.k1), "k2": float(cam.k2),
                         "distortion_applied": _distorted(cam, size_wh)}
    if group.note:
        out["note"] = group.note
    if group.odometry is not None:
        out["odometry_prior"] = group.odometry
    return out


_BAD_INPUT_MARKS = ("unreadable", "truncated", "not a ", "empty file", "cannot read", "unsupported", "size ")


def _problems(source: FrameSource, unplaced: dict[int, str], H: dict[int, np.ndarray], single: bool) -> list[str]:
    """One line per bad-input finding, naming the file (its path where the source has one) or the
    folder, and what to do."""
    where = getattr(source, "path", None)
    folder = getattr(source, "folder", None)

    def named(f: int) -> str:
        return str(where(f)) if callable(where) else source.name(f)

    out = []
    if single:
        out.append(f"{named(0)}: only one image; a mosaic needs at least two overlapping images")
    bad = [(f, r) for f, r in sorted(unplaced.items()) if r.startswith(_BAD_INPUT_MARKS)]
    if bad:
        f, r = bad[0]
        more = f" (and {len(bad) - 1} more, listed in mosaic.json)" if len(bad) > 1 else ""
        out.append(f"{named(f)}: {r}{more} (replace or remove it and run again)")
    if not H and len(source) > 1:
        out.append(f"{folder or 'the input'}: no two of the {len(source)} images overlap enough to register; nothing "
                   "mosaicked (consecutive images, by name, should share a third of their view or more)")
    return out


def run_mosaic_sweep(
    sweep_dir: Path,
    out_dir: Path,
    *,
    params: MosaicParams = MosaicParams(),
    progress: Callable[[str, int, int], None] | None = None,
    verify: bool = False,
    survey_plan=None,
    camera=None,
) -> MosaicOutput:
    """Mosaic a sweep: frames undistorted and rectified with the sweep's camera (``camera``, a
    calibrated ``CameraModel`` from ``--camera``, overrides it; fitted to the frames' size), and
    ``m_per_px`` / ``wall_from_mosaic`` added to mosaic.json (mosaic.png's frames only).

    A sweep cut by a crash (partial last line of frames.jsonl, a COMPLETE that lists more frames
    than are there) and frames that cannot be read (listed under ``unplaced`` with the reason)
    are ``warnings``: the whole frames are mosaicked. ``problems`` is left for a sweep of which
    nothing could be placed. ``verify`` checks every file against COMPLETE's sha256 first.
    ``survey_plan`` (``inspect_pipe.ship.SurveyPlan``) overrides the plan stored in the sweep.
    Written as ``_publish.staged`` writes: a result with problems never replaces a good earlier mosaic."""
    from dataclasses import replace

    from inspect_pipe.capture import read_sweep

    from ._publish import check_out, staged

    check_out(out_dir)
    sweep = read_sweep(sweep_dir, verify=verify)
    if survey_plan is not None:  # --survey: the surveyed wall and the take-off tie, over what the sweep stored
        sweep = replace(sweep, meta=replace(sweep.meta, survey_plan=survey_plan))
    if camera is not None:  # --camera: the calibration over the camera model stored in the sweep
        from inspect_pipe.capture._calibration import fit_camera

        fitted = fit_camera(camera, sweep.meta.width, sweep.meta.height, frames=f"the frames of {sweep_dir}")
        sweep = replace(sweep, meta=replace(sweep.meta, camera=fitted))
    sweep.require_frames()
    source = SweepSource(sweep)
    reg_params = replace(params.register, focal_px=source.focal_px, principal_px=source.principal_px)
    params = replace(params, register=reg_params)
    extra: dict = {"input": {"kind": "sweep", "path": str(sweep_dir), "complete": sweep.complete, "n_frames": len(sweep), "verified": verify,
                             "camera": sweep.meta.camera.to_json()}}
    if sweep.problems:
        extra["input"]["skipped"] = [str(p) for p in sweep.problems]
    return staged(out_dir, lambda d: _sweep_mosaic_into(sweep, source, d, params, progress, extra))


def _sweep_mosaic_into(sweep, source: SweepSource, out_dir: Path, params: MosaicParams, progress, extra: dict) -> MosaicOutput:
    """The mosaic of a read, checked sweep into ``out_dir`` (the staging folder), placed on its wall."""
    result = run_mosaic(source, out_dir, params=params, progress=progress, extra=extra)
    main = {f: h for f, h in result.H.items() if result.group_of[f] == 0}
    take_off = take_off_frames(source, main) if main else {}  # for the wall map's fit only, not blended
    geom = wall_geometry(sweep, main, source.focal_px, source.principal_px, take_off=take_off) if main else None
    by_points, unused_points = control_point_geometry(sweep, main, geom) if main else (None, [])
    geom = by_points or geom
    if geom is not None:
        import json

        doc = json.loads((out_dir / "mosaic.json").read_text())
        doc.update(geom.to_json())
        for f in doc["frames"]:
            rec = sweep.frames[f["index"]]
            f["t_s"] = rec.t_s
        write_json(out_dir / "mosaic.json", doc)
    if result.H:  # the mosaic stands: unreadable frames and skipped lines are warnings
        corrupt = [f"{Path(sweep.path) / sweep.frames[i].image}: {why} (unplaced)" for i, why in sorted(sweep.corrupt.items())]
        result.warnings.extend([str(p) for p in sweep.problems] + corrupt + result.problems + unused_points)
        result.problems = []
    elif sweep.problems:
        result.problems.append(str(sweep.problems[0]))
    return result
