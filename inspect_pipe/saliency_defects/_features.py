"""Per-pixel feature maps: saliency conspicuity, corrosion colour/roughness, crack ridge/line evidence.

Every feature is a *local* function of the image (finite support, fixed normalisation constants,
no per-image statistics), so a tile processed with enough margin gives the same values as the
whole image. Itti-style per-image normalisation N(.) is deliberately replaced by fixed scales:
the learned likelihood tables calibrate each feature, and global normalisation would make a
pixel's probability depend on what else happens to be in the frame (and break tiling).

Shapes: image (H, W, 3) uint8 BGR or (H, W) uint8 grey in; every feature (H, W) float32 out.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: Pyramid geometry (Itti, Koch & Niebur 1998, reduced to fit the 10 Hz budget):
#: centre levels c and surround levels s = c + delta.
CENTRES = (1, 2, 3)
DELTAS = (2, 3)
TOP_LEVEL = max(CENTRES) + max(DELTAS)  # 6
#: Input is padded to a multiple of this so every pyramid level has an exact size (2x ratios).
ALIGN = 2**TOP_LEVEL
#: Pixels of context a feature needs on each side for tiled processing to match the whole image
#: (the Gaussian pyramid's weights beyond this are below float noise for the tables' bins).
SUPPORT_PX = 4 * ALIGN

#: Gabor orientations (rad) for orientation conspicuity and line orientations for crack evidence.
GABOR_THETAS = tuple(np.arange(4) * np.pi / 4)
LINE_THETAS = tuple(np.arange(12) * np.pi / 12)
LINE_LEN_PX = 11  # 11x11 is the largest kernel OpenCV filters directly (13+ switches to a DFT, 20x slower)

#: Names of the features, in the order of :func:`compute_features`'s output.
FEATURE_NAMES: tuple[str, ...] = (
    # saliency conspicuity (centre-surround over the Gaussian pyramid)
    "int_cs",  # signed intensity contrast (negative: centre darker than surround)
    "int_cs_abs",  # unsigned intensity contrast
    "rg_cs",  # signed red-green opponent contrast (rust raises R)
    "by_cs",  # signed blue-yellow opponent contrast
    "sat_cs",  # signed HSV-saturation contrast (rust raises S)
    "ori_cs",  # orientation contrast: Gabor energy centre-surround, 4 orientations
    "sym",  # isotropic symmetry: blob-ness min(|l1|,|l2|) of the Hessian, signed, levels 1-3
    # corrosion: colour and roughness
    "hs",  # joint hue-saturation bin (categorical; index into an NH x NS table)
    "val",  # HSV value (brightness)
    "rchrom",  # red chromaticity R / (R + G + B)
    "rough",  # texture energy: local mean |I - G_1(I)| (fine-scale roughness, GLCM-energy proxy)
    "rough2",  # local standard deviation of I at level 2 (coarse roughness)
    "lab_a",  # CIELAB a* (green-red), smoothed
    "lab_b",  # CIELAB b* (blue-yellow), smoothed
    "sat_mean",  # HSV saturation averaged over 31 px (colour of the surrounding region)
    "rchrom_mean",  # red chromaticity averaged over 31 px
    # cracks: thin, dark, elongated
    "ridge1",  # sigma^2 * largest Hessian eigenvalue at sigma 1 px (dark valley > 0)
    "ridge2",  # same at sigma 2 px
    "ridge3",  # same at sigma 3 px (computed at half resolution, sigma 1.5)
    "dark",  # local darkness z-score (mean_15 - I) / (std_15 + eps)
    "line",  # dark line evidence: local mean - min over 12 orientations of the 11 px line mean
    "line2",  # same at half resolution (22 px lines)
    "coh",  # structure-tensor coherence at sigma 2 px (elongation)
)

#: Hue-saturation table geometry for the corrosion colour model.
N_HUE = 20
N_SAT = 12


@dataclass(frozen=True)
class FeatureStack:
    """Feature maps of one image: ``data[k]`` is feature ``names[k]``, each (H, W) float32."""

    names: tuple[str, ...]
    data: np.ndarray  # (F, H, W) float32

    def __getitem__(self, name: str) -> np.ndarray:
        return self.data[self.names.index(name)]

    @property
    def shape(self) -> tuple[int, int]:
        return self.data.shape[1], self.data.shape[2]


def check_image(image: np.ndarray) -> None:
    """Raise ValueError unless ``image`` is a non-empty 8-bit grey or 3-channel array."""
    if not isinstance(image, np.ndarray) or image.size == 0:
        raise ValueError("empty image")
    if image.dtype != np.uint8:
        raise ValueError(f"expected 8-bit pixels, got {image.dtype}")
    if image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3)):
        return
    raise ValueError(f"expected a grey or 3-channel BGR image, got shape {image.shape}")


def _pad_to(img: np.ndarray, align: int) -> np.ndarray:
    h, w = img.shape[:2]
    ph, pw = (-h) % align, (-w) % align
    if ph or pw:
        img = cv2.copyMakeBorder(img, 0, ph, 0, pw, cv2.BORDER_REFLECT_101)
    return img


def _pyramid(img: np.ndarray, top: int) -> list[np.ndarray]:
    levels = [img]
    for _ in range(top):
        levels.append(cv2.pyrDown(levels[-1]))
    return levels


def _to_level(m: np.ndarray, shape_hw: tuple[int, int]) -> np.ndarray:
    if m.shape == shape_hw:
        return m
    return cv2.resize(m, (shape_hw[1], shape_hw[0]), interpolation=cv2.INTER_LINEAR)


def _centre_surround(pyr: list[np.ndarray], *, signed: bool) -> np.ndarray:
    """Sum over (c, s) of C(c) - S(s) (or its magnitude), accumulated at level 1."""
    target = pyr[1].shape
    acc = np.zeros(target, np.float32)
    for c in CENTRES:
        for d in DELTAS:
            diff = pyr[c] - _to_level(pyr[c + d], pyr[c].shape)
            if not signed:
                diff = np.abs(diff)
            acc += _to_level(diff, target)
    return acc


_GABOR = [
    cv2.getGaborKernel((7, 7), 1.5, th, 4.0, 0.5, 0.0, ktype=cv2.CV_32F) for th in GABOR_THETAS
]
for _k in _GABOR:
    _k -= _k.mean()  # zero DC: no response to flat brightness


def _line_kernels(n: int) -> list[np.ndarray]:
    ks = []
    c = n // 2
    for th in LINE_THETAS:
        k = np.zeros((n, n), np.float32)
        # a 1-px line through the centre, drawn antialiased would blur it; sample along the line
        for t in np.linspace(-c, c, 4 * n):
            x = int(round(c + t * np.cos(th)))
            y = int(round(c - t * np.sin(th)))
            k[y, x] = 1.0
        ks.append(k / k.sum())
    return ks


_LINES = _line_kernels(LINE_LEN_PX)


def _hessian_eigs(img: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (l1 >= l2) of the sigma^2-normalised Hessian of ``img``."""
    g = cv2.GaussianBlur(img, (0, 0), sigma) if sigma > 0 else img
    dxx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3)
    dyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3)
    dxy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3)
    s2 = np.float32(max(sigma, 0.7) ** 2)
    half_tr = (dxx + dyy) * 0.5
    root = cv2.sqrt((dxx - dyy) * (dxx - dyy) * 0.25 + dxy * dxy)
    return (half_tr + root) * s2, (half_tr - root) * s2


def _dark_line(grey: np.ndarray) -> np.ndarray:
    local = cv2.blur(grey, (LINE_LEN_PX, LINE_LEN_PX))
    lo = None
    for k in _LINES:
        r = cv2.filter2D(grey, -1, k, borderType=cv2.BORDER_REFLECT_101)
        lo = r if lo is None else np.minimum(lo, r)
    return local - lo


def compute_features(image: np.ndarray) -> FeatureStack:
    """All features of an 8-bit BGR (or grey) image; see :data:`FEATURE_NAMES`.

    Colour features of a grey image are those of a neutral grey (zero opponent contrast,
    zero saturation).
    """
    check_image(image)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    h, w = image.shape[:2]
    img = _pad_to(image, ALIGN)
    ph, pw = img.shape[:2]
    if img.ndim == 2:
        bgr = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    else:
        bgr = img
    f = bgr.astype(np.float32) * np.float32(1 / 255)
    b, g, r = cv2.split(f)
    grey = cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV_FULL)  # H in 0..255 for the full circle
    sat = hsv[:, :, 1].astype(np.float32) * np.float32(1 / 255)

    full = (ph, pw)
    out: dict[str, np.ndarray] = {}

    # ---- saliency conspicuity over the Gaussian pyramid ----
    pyr_i = _pyramid(grey, TOP_LEVEL)
    cs = _centre_surround(pyr_i, signed=True)
    out["int_cs"] = cs
    out["int_cs_abs"] = _centre_surround(pyr_i, signed=False)
    rg = r - g
    by = b - (r + g) * np.float32(0.5)
    out["rg_cs"] = _centre_surround(_pyramid(rg, TOP_LEVEL), signed=True)
    out["by_cs"] = _centre_surround(_pyramid(by, TOP_LEVEL), signed=True)
    out["sat_cs"] = _centre_surround(_pyramid(sat, TOP_LEVEL), signed=True)
    ori = np.zeros(pyr_i[1].shape, np.float32)
    for k in _GABOR:
        pyr_o = [np.abs(cv2.filter2D(lv, -1, k)) if i >= 1 else None for i, lv in enumerate(pyr_i)]
        pyr_o[0] = pyr_o[1]  # level 0 is never a centre or surround; placeholder
        ori += _centre_surround(pyr_o, signed=False)
    out["ori_cs"] = ori
    sym = np.zeros(pyr_i[1].shape, np.float32)
    for lv in (1, 2, 3):
        l1, l2 = _hessian_eigs(pyr_i[lv], 1.0)
        # both eigenvalues large and of one sign: rotationally symmetric blob (pit, rust spot)
        blob = np.where(l1 * l2 > 0, np.sign(l1) * np.minimum(np.abs(l1), np.abs(l2)), 0.0)
        sym += _to_level(blob.astype(np.float32), pyr_i[1].shape)
    out["sym"] = sym
    for name in ("int_cs", "int_cs_abs", "rg_cs", "by_cs", "sat_cs", "ori_cs", "sym"):
        out[name] = _to_level(out[name], full)

    # ---- corrosion: colour and roughness ----
    hsv_s = cv2.GaussianBlur(hsv, (0, 0), 1.0)
    hbin = (hsv_s[:, :, 0].astype(np.int32) * N_HUE) >> 8
    sbin = (hsv_s[:, :, 1].astype(np.int32) * N_SAT) >> 8
    out["hs"] = (hbin * N_SAT + sbin).astype(np.float32)
    out["val"] = cv2.GaussianBlur(hsv[:, :, 2].astype(np.float32) * np.float32(1 / 255), (0, 0), 1.0)
    out["rchrom"] = cv2.GaussianBlur(r / (r + g + b + np.float32(0.03)), (0, 0), 1.0)
    lab = cv2.cvtColor(cv2.GaussianBlur(bgr, (0, 0), 1.0), cv2.COLOR_BGR2LAB)
    out["lab_a"] = lab[:, :, 1].astype(np.float32)
    out["lab_b"] = lab[:, :, 2].astype(np.float32)
    out["sat_mean"] = cv2.blur(sat, (31, 31))
    out["rchrom_mean"] = cv2.blur(out["rchrom"], (31, 31))
    hp = np.abs(grey - cv2.GaussianBlur(grey, (0, 0), 1.0))
    out["rough"] = cv2.blur(hp, (9, 9))
    l2i = pyr_i[2]
    m = cv2.blur(l2i, (5, 5))
    var = cv2.blur(l2i * l2i, (5, 5)) - m * m
    out["rough2"] = _to_level(cv2.sqrt(np.maximum(var, 0)), full)

    # ---- cracks: thin, dark, elongated ----
    for name, s in (("ridge1", 1.0), ("ridge2", 2.0)):
        out[name] = _hessian_eigs(grey, s)[0]
    out["ridge3"] = _to_level(_hessian_eigs(pyr_i[1], 1.5)[0], full)
    mu = cv2.blur(grey, (15, 15))
    sd = cv2.sqrt(np.maximum(cv2.blur(grey * grey, (15, 15)) - mu * mu, 0))
    out["dark"] = (mu - grey) / (sd + np.float32(0.02))
    out["line"] = _dark_line(grey)
    out["line2"] = _to_level(_dark_line(pyr_i[1]), full)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    jxx = cv2.GaussianBlur(gx * gx, (0, 0), 2.0)
    jyy = cv2.GaussianBlur(gy * gy, (0, 0), 2.0)
    jxy = cv2.GaussianBlur(gx * gy, (0, 0), 2.0)
    root = cv2.sqrt((jxx - jyy) ** 2 + 4 * jxy * jxy)
    out["coh"] = root / (jxx + jyy + np.float32(1e-4))

    data = np.empty((len(FEATURE_NAMES), h, w), np.float32)
    for k, name in enumerate(FEATURE_NAMES):
        data[k] = out.pop(name)[:h, :w]  # pop: the padded maps are freed as the stack fills
    return FeatureStack(FEATURE_NAMES, data)
