"""A folder of images with a calibrated camera (``mosaic --camera``): frames undistorted with the
camera's K and distortion before registration, and the mosaic rectified with its focal length
and principal point, as a sweep's are."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from ._io import FolderSource, read_image
from ._mosaic import MosaicOutput, MosaicParams, run_mosaic
from ._register import FrameError


class UndistortedFolderSource(FolderSource):
    """:class:`FolderSource` whose frames are undistorted with ``camera`` (a ``CameraModel``),
    fitted to the first image's size (same aspect ratio: scaled; another one: ``InputError``,
    raised here, before anything is written)."""

    def __init__(self, folder: Path, camera) -> None:
        from inspect_pipe.capture._calibration import fit_camera

        super().__init__(folder)
        img = read_image(self.paths[0])
        h, w = img.shape[:2]
        self.camera = fit_camera(camera, w, h, frames=f"the images of {self.folder}")
        K, dist = np.asarray(self.camera.K, float), np.asarray(self.camera.dist, float)
        self._maps = cv2.initUndistortRectifyMap(K, dist, None, K, (w, h), cv2.CV_32FC1) if np.any(dist) else None

    def load(self, i: int) -> np.ndarray:
        img = super().load(i)
        if self._maps is None:
            return img
        if img.shape[:2] != self._maps[0].shape[:2]:
            h, w = self._maps[0].shape[:2]
            raise FrameError(f"size {img.shape[1]}x{img.shape[0]} differs from the first image's {w}x{h}")
        return cv2.remap(img, self._maps[0], self._maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    @property
    def focal_px(self) -> float:
        return float((self.camera.K[0, 0] + self.camera.K[1, 1]) / 2)

    @property
    def principal_px(self) -> tuple[float, float]:
        return float(self.camera.K[0, 2]), float(self.camera.K[1, 2])


def run_mosaic_folder(
    folder: Path,
    out_dir: Path,
    *,
    params: MosaicParams = MosaicParams(),
    progress: Callable[[str, int, int], None] | None = None,
    camera=None,
) -> MosaicOutput:
    """Mosaic a folder of images; with ``camera`` (a calibrated ``CameraModel``) its frames are
    undistorted, the mosaic rectified with its K, and mosaic.json records the camera used. The
    folder is checked before anything is written; the mosaic is written as ``_publish.staged``
    writes it: a result with problems never replaces a good earlier mosaic."""
    from ._publish import check_out, staged

    check_out(out_dir)
    extra = None
    if camera is None:
        source = FolderSource(folder)
    else:
        source = UndistortedFolderSource(folder, camera)
        params = replace(params, register=replace(params.register, focal_px=source.focal_px, principal_px=source.principal_px))
        extra = {"input": {"kind": "folder", "path": str(folder), "camera": source.camera.to_json()},
                 "frame_size_wh": [source.camera.width, source.camera.height]}
    return staged(out_dir, lambda d: run_mosaic(source, d, params=params, progress=progress, extra=extra))
