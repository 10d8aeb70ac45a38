"""Keypoints and descriptors for one frame.

The default detector is SIFT, chosen by measurement on the shared synthetic sweeps (189 frames,
512x384, rusty metal): ORB is ten times faster to detect (5 vs 56 ms a frame) and fine between
neighbours, but ORB's 31-pixel border and coarse localisation lost most pass-to-pass pairs (about a
third of a frame overlaps) and left 3-50 px cross-pass misalignment; SIFT registered them all, with
0.06 px neighbour and 0.09 px cross-pass RMS misalignment after global alignment. ORB and AKAZE
remain available by name (``--detector``) for fast previews.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

DETECTORS = ("orb", "sift", "akaze")


@dataclass(frozen=True)
class Features:
    """Keypoints of one frame: ``xy`` (N, 2) float32 pixel coordinates, ``desc`` (N, D) uint8
    descriptors (SIFT's are integers 0-255 stored as uint8; matched as float32, OpenCV's brute-force
    L2 on uint8 being 6x slower)."""

    xy: np.ndarray
    desc: np.ndarray
    binary: bool  # True: Hamming-distance descriptors (ORB, AKAZE); False: L2 (SIFT)

    def __len__(self) -> int:
        return len(self.xy)


def _make_detector(name: str, max_features: int, sensitive: bool = False):
    if name == "orb":
        return cv2.ORB_create(nfeatures=max_features, scaleFactor=1.2, nlevels=6, fastThreshold=5 if sensitive else 10), True
    if name == "sift":
        return cv2.SIFT_create(nfeatures=max_features, contrastThreshold=0.01 if sensitive else 0.04), False
    if name == "akaze":
        return cv2.xfeatures2d.AKAZE_create(threshold=0.0005), True
    raise ValueError(f"unknown detector {name!r}; choose one of {', '.join(DETECTORS)}")


def to_gray(image: np.ndarray) -> np.ndarray:
    """8-bit single-channel view of a BGR, BGRA or grey image."""
    if image.ndim == 2:
        return image
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def detect_features(
    gray: np.ndarray,
    *,
    detector: str = "sift",
    max_features: int = 1500,
    max_side_px: int = 2048,
    scale: float = 1.0,
    low_texture_features: int = 150,
    low_texture_side_px: int = 640,
    mode: str = "auto",
) -> Features:
    """Detect and describe keypoints on an 8-bit grey image (H, W); ``xy`` in its pixels.

    Frames are detected reduced by ``scale`` and to at most ``max_side_px`` (keypoints scaled
    back): SIFT doubles its input first, so a 512x384 frame detected at 0.625 costs half the time
    (73 -> 34 ms) for the same pair accuracy (see RegisterParams.detect_scale).
    When fewer than ``low_texture_features`` are found, detection is repeated on a contrast-limited
    histogram-equalised (CLAHE) image, at most 640 px on its longer side (noise averages out, the
    faint large-scale structure stays), with a detector four times as sensitive, and kept if it
    finds more: low-texture mud, paint or dim light still gives usable keypoints. (Haltbrekken ROV
    mud frames: 10 SIFT keypoints a frame, 0 of 18 neighbour pairs; with this fallback 17 of 18.)
    ``mode``: "auto" (as above), "normal" (never the fallback) or "low_texture" (always it: the
    whole sweep then shares one preprocessing, so frames at a texture boundary still match).
    """
    if mode == "low_texture":
        return _detect_scaled(gray, detector, max_features, low_texture_side_px, sensitive=True)
    feats = _detect_scaled(gray, detector, max_features, int(min(max_side_px, round(scale * max(gray.shape[:2])))), sensitive=False)
    if mode == "auto" and len(feats) < low_texture_features:
        again = _detect_scaled(gray, detector, max_features, low_texture_side_px, sensitive=True)
        if len(again) > len(feats):
            feats = again
    return feats


def _detect_scaled(gray: np.ndarray, detector: str, max_features: int, max_side_px: int, sensitive: bool) -> Features:
    h, w = gray.shape[:2]
    scale = min(1.0, max_side_px / max(h, w))
    img = cv2.resize(gray, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA) if scale < 1 else gray
    if sensitive:
        img = cv2.createCLAHE(clipLimit=3.0, tileGridSize=(8, 8)).apply(img)
    feats = _detect(img, detector, max_features, sensitive)
    if scale < 1:
        sx, sy = w / img.shape[1], h / img.shape[0]
        xy = (feats.xy + 0.5) * np.float32([sx, sy]) - 0.5
        feats = Features(xy.astype(np.float32), feats.desc, feats.binary)
    return feats


def _detect(gray: np.ndarray, detector: str, max_features: int, sensitive: bool) -> Features:
    det, binary = _make_detector(detector, max_features, sensitive)
    kps, desc = det.detectAndCompute(gray, None)
    if desc is None or not kps:
        width = 32 if binary else 128
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, width), np.uint8), binary)
    if len(kps) > max_features:  # AKAZE has no cap of its own: keep the strongest
        order = np.argsort([-k.response for k in kps])[:max_features]
        kps = [kps[i] for i in order]
        desc = desc[order]
    xy = np.array([k.pt for k in kps], dtype=np.float32)
    if not binary:  # SIFT's float descriptors hold integers 0-255 (OpenCV rounds them): a quarter of the memory as uint8
        desc = np.clip(np.rint(desc), 0, 255).astype(np.uint8)
    return Features(xy, desc, binary)
