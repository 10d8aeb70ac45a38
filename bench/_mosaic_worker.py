"""Run one mosaicer on one folder in a fresh process (the parent measures time and peak memory).

    python -m bench._mosaic_worker ours FRAMES OUT [--focal-px F]
    python -m bench._mosaic_worker stitcher FRAMES OUT
Prints one JSON line with the result.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path


def ours(frames: Path, out: Path, focal: float | None) -> dict:
    from inspect_pipe.mosaic import FolderSource, MosaicParams, RegisterParams, run_mosaic

    t, c = time.perf_counter(), time.process_time()
    res = run_mosaic(FolderSource(frames), out, params=MosaicParams(register=RegisterParams(focal_px=focal)))
    return {"time_s": time.perf_counter() - t, "cpu_s": time.process_time() - c, "placed": res.n_placed, "n": len(FolderSource(frames)),
            "groups": [len(g.frames) for g in res.registration.groups],
            "rms_px": [g.rms_px for g in res.registration.groups]}


def stitcher(frames: Path, out: Path) -> dict:
    import cv2

    from inspect_pipe.mosaic import FolderSource

    # Timed like ours, end to end: the frames read and decoded, the result written (a PNG, as ours).
    t = time.perf_counter()
    src = FolderSource(frames)
    imgs = [src.load(i) for i in range(len(src))]
    imgs = [cv2.cvtColor(im, cv2.COLOR_GRAY2BGR) if im.ndim == 2 else im for im in imgs]
    t_stitch = time.perf_counter()
    st = cv2.Stitcher_create(cv2.Stitcher_SCANS)
    try:
        status, pano = st.stitch(imgs)
    except cv2.error as err:
        return {"time_s": time.perf_counter() - t, "placed": 0, "n": len(imgs), "status": f"exception: {str(err).splitlines()[-1][:80]}"}
    stitch_s = time.perf_counter() - t_stitch
    component = [int(i) for i in st.component()] if status == cv2.Stitcher_OK else []
    placed = len(component)
    if status == cv2.Stitcher_OK:
        out.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out / "stitcher.png"), pano, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    return {"time_s": time.perf_counter() - t, "stitch_s": stitch_s, "placed": placed, "n": len(imgs), "status": int(status),
            "component": component}


def main() -> None:
    mode, frames, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
    focal = float(sys.argv[5]) if len(sys.argv) > 5 and sys.argv[4] == "--focal-px" else None
    res = ours(frames, out, focal) if mode == "ours" else stitcher(frames, out)
    print(json.dumps(res))


if __name__ == "__main__":
    main()
