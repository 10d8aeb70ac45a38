"""Per-pixel feature maps: saliency conspicuity, corrosion colour/roughness, crack ridge/line evidence.

Every feature is a *local* function of the image (finite support, fixed normalisation constants,
no per-image statistics), so a tile processed with enough margin gives the same values as the
whole image. Itti-style per-image normalisation N(.) is deliberately replaced by fixed scales:
the learned likelihood tables calibrate each feature, and global normalisation would make a
pixel's probability depend on what else happens to be in the frame (and break tiling).

Shapes: image (H, W, 3) uint8 BGR or (H, W) uint8 grey in; every feature (H, W) float32 out at
level 0, (ceil(H/2), ceil(W/2)) at level 1.
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

#: Orientations (rad) of the orientation conspicuity and line orientations for crack evidence.
ORI_THETAS = tuple(np.arange(4) * np.pi / 4)
LINE_THETAS = tuple(np.arange(12) * np.pi / 12)
LINE_LEN_PX = 11  # 11x11 is the largest kernel OpenCV filters directly (13+ switches to a DFT, 20x slower)

#: Side (px at the features' level) of the box the region features (``*_mean``, ``val_std``) average.
REGION = 31
#: Side (px at half the features' resolution) of the structure tensor's averaging box.
COH_BOX = 3
#: Sides (px at the features' level) of the boxes of the local colour statistics: standard
#: deviations over 7 and 15 px (``*_std7``, ``*_std15``), gradient energy over 15 px (``*_grad15``).
STAT_BOXES = (7, 15)
#: Side (px at the features' level) of the box whose mean the relative colour features (``*_rel``)
#: subtract: a local grey world over about a quarter of a frame at half resolution.
REL_BOX = 127
#: Sides (px at the features' level) of the boxes pooling the texture energies of the finest band
#: (``ctex_*``, ``ctex_*_mean``) and of the next band (``ctex2_*``).
CTEX_BOXES = (5, 17)
CTEX2_BOX = 9
#: Channels of the texture energies: red chromaticity R / (R + G + B) and HSV value. The colour
#: opponents' bands scored as well on validation images but read per-pixel chroma noise as texture
#: (synthetic rust with independent channel noise was lost), so they are not features.
CTEX_CHANNELS = ("r", "v")

#: Names of the features, in the order of :func:`compute_features`'s output.
FEATURE_NAMES: tuple[str, ...] = (
    # saliency conspicuity (centre-surround over the Gaussian pyramid)
    "int_cs",  # signed intensity contrast (negative: centre darker than surround)
    "int_cs_abs",  # unsigned intensity contrast
    "rg_cs",  # signed red-green opponent contrast (rust raises R)
    "by_cs",  # signed blue-yellow opponent contrast
    "sat_cs",  # signed HSV-saturation contrast (rust raises S)
    "ori_cs",  # orientation contrast: steerable 2nd-derivative energy centre-surround, 4 orientations
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
    "lab_a_mean",  # CIELAB a* averaged over 31 px (region colour)
    "lab_b_mean",  # CIELAB b* averaged over 31 px
    "val_mean",  # HSV value averaged over 31 px
    "val_std",  # local standard deviation of HSV value over 31 px (region roughness)
    "rough_mean",  # fine texture energy averaged over 31 px
    # local colour statistics at the features' level (rust is mottled; paint, concrete, sky are even)
    "lab_a_std7",  # standard deviation of a* over 7 px
    "lab_b_std7",  # same of b*
    "rchrom_std7",  # same of the red chromaticity
    "val_std7",  # same of the HSV value
    "lab_a_std15", "lab_b_std15", "rchrom_std15", "val_std15",  # the same over 15 px
    "lab_a_grad15",  # gradient magnitude of a* (Sobel) averaged over 15 px
    "lab_b_grad15", "rchrom_grad15",  # same of b*, of the red chromaticity
    "lab_a_rel",  # a* minus its mean over 127 px (local grey world: colour relative to the scene's)
    "lab_b_rel",  # b* minus its mean over 127 px
    "rchrom_rel",  # red chromaticity minus its mean over 127 px
    "val_rel",  # HSV value over its mean over 127 px
    # texture energy at the image's full resolution: |finest Laplacian band| of the red chromaticity
    # (x 255) and the value, pooled 2 x 2, then over 5 and 17 px at the features' level; the next
    # band (half resolution) over 9 px
    "ctex_r", "ctex_v", "ctex_r_mean", "ctex_v_mean", "ctex2_r", "ctex2_v",
    # cracks: thin, dark, elongated
    "ridge1",  # sigma^2 * largest Hessian eigenvalue at sigma 1 px (dark valley > 0)
    "ridge2",  # same at sigma 2 px
    "ridge3",  # same at sigma 3 px (computed at half resolution, sigma 1.5)
    "dark",  # local darkness z-score (mean_15 - I) / (std_15 + eps)
    "line",  # dark line evidence: local mean - min over 12 orientations of the 11 px line mean
    "line2",  # same at half resolution (22 px lines)
    "coh",  # structure-tensor coherence over a 6 px box (elongation)
)

#: The colour evidence among them (the corrosion cascade's colour model; see ``zc`` context maps).
COLOUR_FEATURES = frozenset({
    "rg_cs", "by_cs", "sat_cs", "hs", "rchrom", "lab_a", "lab_b", "sat_mean", "rchrom_mean",
    "lab_a_mean", "lab_b_mean", "lab_a_std7", "lab_b_std7", "rchrom_std7", "lab_a_std15", "lab_b_std15",
    "rchrom_std15", "lab_a_grad15", "lab_b_grad15", "rchrom_grad15", "lab_a_rel", "lab_b_rel", "rchrom_rel",
    "ctex_r", "ctex_r_mean", "ctex2_r",
})
#: The statistics of the per-pixel maps lab_a, lab_b, rchrom and val (computed together).
STAT_FEATURES = frozenset(f"{m}_{k}" for m in ("lab_a", "lab_b", "rchrom", "val")
                          for k in ("std7", "std15", "grad15", "rel")) & frozenset(FEATURE_NAMES)
CTEX_FEATURES = tuple(f"ctex{k}_{c}{m}" for k, m in (("", ""), ("", "_mean"), ("2", "")) for c in CTEX_CHANNELS)

#: Hue-saturation table geometry for the corrosion colour model.
N_HUE = 20
N_SAT = 12


@dataclass(frozen=True)
class FeatureStack:
    """Feature maps of one image: ``maps[k]`` is feature ``names[k]``, each (H, W) float32 (views
    into the padded maps, not copies); ``data`` stacks them into one (F, H, W) array."""

    names: tuple[str, ...]
    maps: tuple[np.ndarray, ...]
    level: int = 0  # pyramid level the maps are sampled at (1: half resolution)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.maps[self.names.index(name)]

    def as_dict(self) -> dict[str, np.ndarray]:
        return dict(zip(self.names, self.maps))

    @property
    def data(self) -> np.ndarray:
        return np.stack(self.maps) if self.maps else np.zeros((0, 0, 0), np.float32)

    @property
    def shape(self) -> tuple[int, int]:
        return self.maps[0].shape if self.maps else (0, 0)


def check_image(image: np.ndarray) -> None:
    """Raise ValueError unless ``image`` is a non-empty 8-bit grey or 3-channel array."""
    if not isinstance(image, np.ndarray) or image.size == 0:
        raise ValueError("empty image")
    if image.dtype != np.uint8:
        raise ValueError(f"expected 8-bit pixels, got {image.dtype}")
    if min(image.shape[:2]) < 2:  # the features' gradients and reflect padding need two pixels a side
        raise ValueError(f"image {image.shape[1]}x{image.shape[0]} is too small (sides >= 2 px)")
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


def _centre_surround(pyr: list, *, signed: bool, more: tuple = ()) -> np.ndarray:
    """Sum over (c, s) of C(c) - S(s) (or its magnitude), at level 1; ``more``: further pyramids
    whose terms join the sum (the orientation channels). Each centre level's terms are summed at
    that level and carried to the next finer one by one 2x bilinear step (coarse to fine), so a
    level-1-sized array is resized 3 times, not 6 per pyramid."""
    acc = None
    for c in sorted(CENTRES, reverse=True):
        part = None
        for p in (pyr, *more):
            for d in DELTAS:
                diff = cv2.subtract(p[c], _to_level(p[c + d], p[c].shape))
                if not signed:
                    diff = np.abs(diff)
                part = diff if part is None else cv2.add(part, diff)
        acc = part if acc is None else cv2.add(part, _to_level(acc, part.shape))
    for lv in range(min(CENTRES) - 1, 0, -1):  # centres above level 1: carry down to it
        acc = _to_level(acc, pyr[lv].shape)
    return acc


def _hessian(img: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(dxx, dyy, dxy) of ``img`` smoothed by a Gaussian of ``sigma`` px."""
    g = cv2.GaussianBlur(img, (0, 0), sigma) if sigma > 0 else img
    return (cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3), cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3),
            cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3))


def _steered_energy(dxx: np.ndarray, dyy: np.ndarray, dxy: np.ndarray) -> list[np.ndarray]:
    """|second derivative| along the ORI_THETAS (0, 45, 90, 135 deg), steered from the three
    separable basis responses (Freeman & Adelson's steerable filters)."""
    half = (dxx + dyy) * np.float32(0.5)
    return [np.abs(dxx), np.abs(half + dxy), np.abs(dyy), np.abs(half - dxy)]


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


def _hessian_eigs(img: np.ndarray, sigma: float, hess=None) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (l1 >= l2) of the sigma^2-normalised Hessian of ``img`` (``hess``: its
    (dxx, dyy, dxy) at ``sigma`` when already computed)."""
    dxx, dyy, dxy = hess if hess is not None else _hessian(img, sigma)
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


def _ctex_bands(bgr: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """|Laplacian bands| of the red chromaticity (x 255) and the HSV value of an 8-bit BGR image
    (H, W even): band 0 (the image's resolution) pooled by 2 x 2 means and band 1 (half
    resolution), two lists of two (H/2, W/2) float32 maps. Few full-resolution temporaries: those
    are the frame's costliest pixels."""
    h, w = bgr.shape[:2]
    half = (w // 2, h // 2)
    b8, g8, r8 = cv2.split(bgr)
    total = cv2.add(cv2.add(cv2.add(b8, g8, dtype=cv2.CV_32F), r8, dtype=cv2.CV_32F), 8.0)
    rc = cv2.divide(r8, total, scale=255.0, dtype=cv2.CV_32F)
    del total
    v = cv2.max(cv2.max(b8, g8), r8).astype(np.float32)
    band0, band1 = [], []
    for x in (rc, v):
        x1 = cv2.pyrDown(x)
        up = cv2.pyrUp(x1, dstsize=(w, h))
        cv2.absdiff(x, up, dst=up)
        band0.append(cv2.resize(up, half, interpolation=cv2.INTER_AREA))
        del up
        band1.append(cv2.absdiff(x1, cv2.pyrUp(cv2.pyrDown(x1), dstsize=half)))
    return band0, band1


def compute_features(image: np.ndarray, names=None, *, level: int = 0, shared: dict | None = None) -> FeatureStack:
    """Features ``names`` (default all, see :data:`FEATURE_NAMES`) of an 8-bit BGR (or grey) image.

    ``level`` 0 computes them at full resolution; ``level`` 1 at half resolution (pyramid level 1,
    maps of ceil(H/2) x ceil(W/2)): the local filters then have twice the reach in image pixels and
    cost a quarter. The centre-surround maps live at pyramid level 1 either way. Only the
    requested features are computed; calls on one image may pass one ``shared`` dict to reuse the
    pyramids and centre-surround maps between levels. Colour features of a grey image are those
    of a neutral grey (zero opponent contrast, zero saturation).
    """
    check_image(image)
    names = FEATURE_NAMES if names is None else tuple(names)
    unknown = set(names) - set(FEATURE_NAMES)
    if unknown:
        raise ValueError(f"unknown features {sorted(unknown)}")
    if level not in (0, 1):
        raise ValueError(f"feature level must be 0 or 1, got {level}")
    want = set(names)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    h, w = image.shape[:2]
    sh = {} if shared is None else shared
    if "pyr_i" not in sh:
        img = _pad_to(image, ALIGN)
        bgr0 = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img
        grey0 = cv2.cvtColor(bgr0, cv2.COLOR_BGR2GRAY).astype(np.float32) * np.float32(1 / 255)
        # grey pyramid indexed by level: level 0 full resolution, each level half the previous
        sh["pyr_i"] = _pyramid(grey0, TOP_LEVEL)
        sh["bgr"] = [bgr0, cv2.pyrDown(bgr0)]
        sh["hess"] = {}  # level -> (dxx, dyy, dxy) at sigma 1
    pyr_i = sh["pyr_i"]
    bgr = sh["bgr"][level]
    grey = pyr_i[level]
    base = grey.shape
    out: dict[str, np.ndarray] = {}

    def rel(k: int) -> np.ndarray:  # grey at ``k`` levels above the base
        return pyr_i[level + k]

    def hess(lv: int):
        if lv not in sh["hess"]:
            sh["hess"][lv] = _hessian(pyr_i[lv], 1.0)
        return sh["hess"][lv]

    def cs(name: str, make):  # centre-surround maps at level 1, shared between levels
        key = "cs:" + name
        if key not in sh:
            sh[key] = make()
        return sh[key]

    # ---- saliency conspicuity over the Gaussian pyramid (accumulated at level 1) ----
    if "int_cs" in want:
        out["int_cs"] = cs("int_cs", lambda: _centre_surround(pyr_i, signed=True))
    if "int_cs_abs" in want:
        out["int_cs_abs"] = cs("int_cs_abs", lambda: _centre_surround(pyr_i, signed=False))
    if want & COLOUR_FEATURES:
        f = bgr.astype(np.float32) * np.float32(1 / 255)
        b, g, r = cv2.split(f)
        hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV_FULL)  # H in 0..255 for the full circle
        sat = hsv[:, :, 1].astype(np.float32) * np.float32(1 / 255)

        def colour_cs(name: str) -> np.ndarray:
            # colour planes of the level-1 image, pyramids above it
            f1 = sh["bgr"][1].astype(np.float32) * np.float32(1 / 255)
            b1, g1, r1 = cv2.split(f1)
            if name == "rg_cs":
                plane = r1 - g1
            elif name == "by_cs":
                plane = b1 - (r1 + g1) * np.float32(0.5)
            else:
                plane = cv2.cvtColor(sh["bgr"][1], cv2.COLOR_BGR2HSV_FULL)[:, :, 1].astype(np.float32) * np.float32(1 / 255)
            pyr = [None] + _pyramid(plane, TOP_LEVEL - 1)
            return _centre_surround(pyr, signed=True)

        for name in ("rg_cs", "by_cs", "sat_cs"):
            if name in want:
                out[name] = cs(name, lambda name=name: colour_cs(name))
    if "ori_cs" in want:
        def ori() -> np.ndarray:
            energies = [None] + [_steered_energy(*hess(lv)) for lv in range(1, TOP_LEVEL + 1)]
            chans = [[None if e is None else e[k] for e in energies] for k in range(len(ORI_THETAS))]
            return _centre_surround(chans[0], signed=False, more=tuple(chans[1:]))
        out["ori_cs"] = cs("ori_cs", ori)
    if "sym" in want:
        def sym() -> np.ndarray:
            acc = None
            for lv in (3, 2, 1):  # coarse to fine, carried down one level at a time
                l1, l2 = _hessian_eigs(pyr_i[lv], 1.0, hess(lv))
                # both eigenvalues large and of one sign: rotationally symmetric blob (pit, rust spot)
                blob = np.where(l1 * l2 > 0, np.sign(l1) * np.minimum(np.abs(l1), np.abs(l2)), 0.0)
                blob = blob.astype(np.float32)
                acc = blob if acc is None else cv2.add(blob, _to_level(acc, blob.shape))
            return acc
        out["sym"] = cs("sym", sym)
    for name in ("int_cs", "int_cs_abs", "rg_cs", "by_cs", "sat_cs", "ori_cs", "sym"):
        if name in out:
            out[name] = _to_level(out[name], base)

    # ---- corrosion: colour and roughness ----
    if "hs" in want:
        hsv_s = cv2.GaussianBlur(hsv, (0, 0), 1.0)
        hbin = (hsv_s[:, :, 0].astype(np.int32) * N_HUE) >> 8
        sbin = (hsv_s[:, :, 1].astype(np.int32) * N_SAT) >> 8
        out["hs"] = (hbin * N_SAT + sbin).astype(np.float32)
    px: dict[str, np.ndarray] = {}  # per-pixel maps that the local statistics below read
    if want & ({"val", "val_mean", "val_std"} | {n for n in STAT_FEATURES if n.startswith("val_")}):
        bb, gg, rr = cv2.split(bgr)
        v = cv2.max(cv2.max(bb, gg), rr).astype(np.float32) * np.float32(1 / 255)  # HSV value
        px["val"] = cv2.GaussianBlur(v, (0, 0), 1.0)
        if "val" in want:
            out["val"] = px["val"]
        if want & {"val_mean", "val_std"}:
            vm = cv2.blur(v, (REGION, REGION))
            out["val_mean"] = vm
            if "val_std" in want:
                out["val_std"] = cv2.sqrt(np.maximum(cv2.blur(v * v, (REGION, REGION)) - vm * vm, 0))
    if want & ({"rchrom", "rchrom_mean"} | {n for n in STAT_FEATURES if n.startswith("rchrom_")}):
        rchrom = cv2.GaussianBlur(r / (r + g + b + np.float32(0.03)), (0, 0), 1.0)
        px["rchrom"] = rchrom
        if "rchrom" in want:
            out["rchrom"] = rchrom
        if "rchrom_mean" in want:
            out["rchrom_mean"] = cv2.blur(rchrom, (REGION, REGION))
    if want & ({"lab_a", "lab_b", "lab_a_mean", "lab_b_mean"} | {n for n in STAT_FEATURES if n.startswith("lab_")}):
        lab = cv2.cvtColor(cv2.GaussianBlur(bgr, (0, 0), 1.0), cv2.COLOR_BGR2LAB)
        for k, name in ((1, "lab_a"), (2, "lab_b")):
            ch = lab[:, :, k].astype(np.float32)
            px[name] = ch
            if name in want:
                out[name] = ch
            if name + "_mean" in want:
                out[name + "_mean"] = cv2.blur(ch, (REGION, REGION))
    for name, x in px.items():
        for box in STAT_BOXES:  # colour variation over the box
            if f"{name}_std{box}" in want:
                m = cv2.blur(x, (box, box))
                var = cv2.subtract(cv2.blur(cv2.multiply(x, x), (box, box)), cv2.multiply(m, m))
                out[f"{name}_std{box}"] = cv2.sqrt(cv2.max(var, 0.0))
        if name + "_grad15" in want:  # colour edges per area
            mag = cv2.magnitude(cv2.Sobel(x, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(x, cv2.CV_32F, 0, 1, ksize=3))
            out[name + "_grad15"] = cv2.blur(mag, (STAT_BOXES[1], STAT_BOXES[1]))
        if name + "_rel" in want:  # relative to the surroundings' mean (illumination, white balance)
            m = cv2.blur(x, (REL_BOX, REL_BOX))
            out[name + "_rel"] = cv2.divide(x, cv2.add(m, 0.05)) if name == "val" else cv2.subtract(x, m)
    if "sat_mean" in want:
        out["sat_mean"] = cv2.blur(sat, (REGION, REGION))
    if want & {"rough", "rough_mean"}:
        hp = np.abs(grey - cv2.GaussianBlur(grey, (0, 0), 1.0))
        out["rough"] = cv2.blur(hp, (9, 9))
        if "rough_mean" in want:
            out["rough_mean"] = cv2.blur(out["rough"], (REGION, REGION))
    if want & set(CTEX_FEATURES):
        if "ctex" not in sh:  # computed at level 1 (band 0 pooled), shared between levels
            sh["ctex"] = _ctex_bands(sh["bgr"][0])
        pooled = [[_to_level(x, base) for x in chans] for chans in sh["ctex"]]  # at the features' level
        for prefix, suffix, chans, box in (("ctex_", "", pooled[0], CTEX_BOXES[0]), ("ctex_", "_mean", pooled[0], CTEX_BOXES[1]),
                                           ("ctex2_", "", pooled[1], CTEX2_BOX)):
            for c, x in zip(CTEX_CHANNELS, chans):
                if f"{prefix}{c}{suffix}" in want:
                    out[f"{prefix}{c}{suffix}"] = cv2.blur(x, (box, box))
    if "rough2" in want:
        l2i = rel(2)
        m = cv2.blur(l2i, (5, 5))
        var = cv2.blur(l2i * l2i, (5, 5)) - m * m
        out["rough2"] = _to_level(cv2.sqrt(np.maximum(var, 0)), base)

    # ---- cracks: thin, dark, elongated ----
    for name, s in (("ridge1", 1.0), ("ridge2", 2.0)):
        if name in want:
            out[name] = _hessian_eigs(grey, s, hess(level) if s == 1.0 else None)[0]
    if "ridge3" in want:
        out["ridge3"] = _to_level(_hessian_eigs(rel(1), 1.5)[0], base)
    if "dark" in want:
        mu = cv2.blur(grey, (15, 15))
        sd = cv2.sqrt(np.maximum(cv2.blur(grey * grey, (15, 15)) - mu * mu, 0))
        out["dark"] = (mu - grey) / (sd + np.float32(0.02))
    if "line" in want:
        out["line"] = _dark_line(grey)
    if "line2" in want:
        out["line2"] = _to_level(_dark_line(rel(1)), base)
    if "coh" in want:
        gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
        # tensor products averaged over 2 x 2 blocks, then a 3 x 3 box at half resolution (a 6 px
        # box in all); the coherence is brought back up bilinearly
        half = (base[1] // 2, base[0] // 2)

        def avg(a: np.ndarray) -> np.ndarray:
            return cv2.blur(cv2.resize(a, half, interpolation=cv2.INTER_AREA), (COH_BOX, COH_BOX))

        jxx = avg(cv2.multiply(gx, gx))
        jyy = avg(cv2.multiply(gy, gy))
        jxy2 = avg(cv2.multiply(gx, gy, scale=2.0))
        root = cv2.magnitude(cv2.subtract(jxx, jyy), jxy2)  # sqrt((jxx - jyy)^2 + 4 jxy^2)
        out["coh"] = _to_level(cv2.divide(root, cv2.add(cv2.add(jxx, jyy), 1e-4)), base)

    bh, bw = -(-h // 2**level), -(-w // 2**level)
    return FeatureStack(names, tuple(out[n][:bh, :bw] for n in names), level)
