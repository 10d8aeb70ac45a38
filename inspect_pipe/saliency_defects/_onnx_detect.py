"""Learned defect segmentation on onnxruntime: model loading with metadata checks, tiled
inference with overlap, decisions and regions in the same form as the saliency engine.

No PyTorch here: the networks were trained and exported by ``_onnx_train``; the default,
``models/defects_unet_v5.onnx`` (EfficientNet-Lite1 encoder, U-Net decoder, int8), decides; the
condition states of the corrosion it decides come from the head of ``models/defects_unet_v6.onnx``
(the same recipe trained twice as long), run on the image at ``STATES_SCALE``. Every other network
given with ``--model`` (v1, the half-resolution U-Net without a head) gets v6's states the
same way; v6 given itself decides and keeps its own head. Its output
maps are at 1/2 resolution (metadata ``output.stride`` 2; a model with stride 1 or none gives
full-resolution maps) and are up-sampled here: the class probabilities and, for models with a
``severity`` record, the condition-state logits (fair, poor, severe) of corrosion pixels.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ._core import TILE_PX, calibration_lut, decide_u8, tiles, to_u8
from ._detect import SEVERITY_STATES, Detection, Region, regions_of
from ._features import check_image
from ._onnx_meta import ONNX_FORMAT, check_meta  # noqa: F401 - ONNX_FORMAT: re-exported (training, tests)

CLASSES = ("corrosion", "crack", "surface")
#: Network input: RGB / 255, then (x - mean) / std per channel.
INPUT_MEAN = (0.5, 0.5, 0.5)
INPUT_STD = (0.25, 0.25, 0.25)
#: The network pools 4 times: its input sides must be multiples of 16 (inputs are reflect-padded).
MULTIPLE_OF = 16
#: Smallest image side accepted (px): below, the deepest level is under 2 x 2 pixels.
MIN_SIDE_PX = 32
#: Speckle removal, as in the saliency engine (a 10 px hair line; an 8 x 8 px patch).
MIN_AREA_PX = {"corrosion": 64, "crack": 20, "surface": 64}
#: Scoring tolerance per class (px), the benchmark protocol.
TOL_PX = {"corrosion": 0.0, "crack": 2.0, "surface": 0.0}
LICENCE = (
    "Weights trained on research-only data (CrackForest: non-commercial research; VT corrosion "
    "condition state set: CC0 per its repository, unconfirmed; SD-saliency-900: research use). "
    "Research and evaluation use only."
)
#: Tiling (the core's grid and its TILE_PX): overlap margin (px, a multiple of MULTIPLE_OF); it
#: covers the encoder's receptive field, so tiles equal whole-image inference. EfficientNet-Lite0
#: (v3) needed 256 px (96 px, enough for the earlier network, left differences of up to 27 grey
#: levels; 192 px, 9); Lite1 (v4, v5, v6), four blocks deeper at 1/16, 320 px (256 px left up to 61 grey
#: levels on the surface map of an 1800 x 1400 image in 768 px tiles; 320 px, none).
MARGIN_PX = 320
#: Images up to this many pixels run in one pass.
WHOLE_MAX_PX = 2048 * 1536


@dataclass(frozen=True)
class OnnxModel:
    path: Path
    session: object  # onnxruntime.InferenceSession
    meta: dict
    classes: tuple[str, ...]
    thresholds_u8: dict[str, int]
    min_area_px: dict[str, int]
    #: Name of the condition-state output (logits of fair / poor / severe), None without one.
    severity_output: str | None = None
    #: Added to the condition-state logits before the arg-max (chosen on the validation images).
    severity_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: Per class, the calibration of its probability map: (operating point u8, gain) of
    #: ``_core.calibrate`` / ``calibration_lut``, fitted on the validation images (metadata
    #: ``calibration``). The maps this engine returns are calibrated; that class's threshold is 128.
    calibration: dict[str, tuple[int, float]] = field(default_factory=dict)
    #: The network whose head gives the condition state of each corrosion pixel this one decides
    #: (the shipped states network, v6, see :func:`with_condition_states`; this one's own head is
    #: then not read); None: this network's own head, if any.
    states_model: OnnxModel | None = None
    #: Scale of the image the ``states_model`` sees (its states are brought back to full size by
    #: nearest neighbour): the condition-state labels are coarse polygons, and a smaller input
    #: costs the second network a fraction (the shipped default: :data:`STATES_SCALE`).
    states_scale: float = 1.0

    @property
    def version(self) -> str:
        return str(self.meta.get("version", "?"))


@dataclass(frozen=True)
class _Decision:  # what regions_of / the CLI read of a class model
    threshold: float
    min_area_px: int


def load_onnx_model(path: Path, *, threads: int = 1) -> OnnxModel:
    """Open an exported model and check its metadata against what this code feeds it.
    Raises ValueError with a one-line reason (missing, not ONNX, wrong metadata or inputs)."""
    import onnxruntime as ort

    path = Path(path)
    if not path.is_file():
        raise ValueError("ONNX model file not found" if not path.exists() else "a directory, not an ONNX model file")
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.log_severity_level = 3
    try:
        sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
    except Exception as err:  # noqa: BLE001 - onnxruntime raises several unrelated types for a bad file
        first = str(err).strip().splitlines()[0][:160] if str(err).strip() else type(err).__name__
        raise ValueError(f"not a valid ONNX model ({first})") from None
    raw = sess.get_modelmeta().custom_metadata_map.get("inspect_pipe")
    if raw is None:
        raise ValueError("ONNX model has no 'inspect_pipe' metadata")
    try:
        meta = json.loads(raw)
    except json.JSONDecodeError:
        raise ValueError("ONNX model metadata 'inspect_pipe' is not JSON") from None
    check_meta(meta)  # types and bounds of every field read below (input convention too): a bad one is named here
    inp = meta["input"]
    ins, outs = sess.get_inputs(), sess.get_outputs()
    if len(ins) != 1 or len(ins[0].shape) != 4 or ins[0].shape[1] != 3 or ins[0].name != inp.get("name"):
        raise ValueError(f"ONNX model input {[(i.name, i.shape) for i in ins]} does not match its metadata")
    if any(isinstance(d, int) for k, d in enumerate(ins[0].shape) if k != 1):
        raise ValueError(f"ONNX model input {ins[0].shape} has a fixed batch or size (this code feeds any batch and any "
                         f"height and width, multiples of {MULTIPLE_OF}: export with dynamic axes)")
    classes = tuple(meta.get("classes", ()))
    sev = meta.get("severity")
    want = {meta.get("output", {}).get("name", "prob"): len(classes)}
    if sev is not None:
        if tuple(sev["states"]) != SEVERITY_STATES:
            raise ValueError(f"ONNX model metadata: severity states must be {', '.join(SEVERITY_STATES)}")
        want[sev.get("output")] = len(SEVERITY_STATES)
    got = {o.name: o.shape for o in outs}
    if not classes or len(outs) != len(want) or outs[0].name not in want or \
            any(k not in got or len(got[k]) != 4 or got[k][1] != n for k, n in want.items()):
        raise ValueError(f"ONNX model output {[(o.name, o.shape) for o in outs]} does not match classes {classes}"
                         + (" and the severity states" if sev is not None else ""))
    ops = meta.get("operating_points_u8", {})
    if set(ops) != set(classes):
        raise ValueError("ONNX model metadata: operating points do not cover its classes")
    bias = sev.get("logit_bias", (0.0, 0.0, 0.0)) if sev is not None else (0.0, 0.0, 0.0)  # 3 numbers: check_meta
    thresholds = {k: int(v) for k, v in ops.items()}
    cal = {}
    for k, c in (meta.get("calibration") or {}).items():
        ok = (k in classes and isinstance(c, dict) and isinstance(c.get("gain"), (int, float)) and 0.1 <= c["gain"] <= 100
              and c.get("operating_point_u8") == thresholds.get(k))
        if not ok:
            raise ValueError(f"ONNX model metadata: calibration of {k!r} must give a gain in [0.1, 100] at the class's operating point")
        cal[k] = (thresholds[k], float(c["gain"]))
        thresholds[k] = 128
    model = OnnxModel(path, sess, meta, classes, thresholds,
                      {k: int(meta.get("min_area_px", {}).get(k, MIN_AREA_PX.get(k, 64))) for k in classes},
                      sev.get("output") if sev is not None else None, tuple(float(b) for b in bias), cal)
    _probe(model)
    return model


def _probe(model: OnnxModel) -> None:
    """Run the network once on two blank 64 x 64 images: its outputs must have the batch, the
    channels and the size (64 / the metadata's stride) that the metadata says (a few ms)."""
    stride, side = _stride(model), 4 * MULTIPLE_OF
    try:
        prob, states = _run(model, np.zeros((2, 3, side, side), np.float32), severity=True)
    except Exception as err:  # noqa: BLE001 - onnxruntime's errors have no common base class
        first = str(err).strip().splitlines()[0][:160] if str(err).strip() else type(err).__name__
        raise ValueError(f"ONNX model does not run on a {side} x {side} image ({first})") from None
    want = {"prob": (2, len(model.classes), side // stride, side // stride)}
    if model.severity_output is not None:
        want["severity"] = (2, len(SEVERITY_STATES), side // stride, side // stride)
    for name, got in (("prob", prob), ("severity", states)):
        if name in want and (got is None or tuple(got.shape) != want[name]):
            raise ValueError(f"ONNX model output {name!r} is {None if got is None else tuple(got.shape)} for a {side} x {side} "
                             f"image, not {want[name]} as its metadata (classes, output stride {stride}) says")


def _prepare(image: np.ndarray, meta: dict) -> np.ndarray:
    """8-bit BGR or grey (H, W[, 1|3]) -> (3, H, W) float32 network input (channel by channel:
    RGB * scale, then (x - mean) / std; equal to the whole-array formula)."""
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    inp = meta["input"]
    chans = [image] * 3 if image.ndim == 2 else [image[:, :, 2], image[:, :, 1], image[:, :, 0]]  # BGR -> RGB
    scale = np.float32(inp.get("scale", 1 / 255))
    out = np.empty((3,) + image.shape[:2], np.float32)
    for c in range(3):
        np.multiply(chans[c], scale, out=out[c], dtype=np.float32)
        out[c] -= np.float32(inp["mean"][c])
        out[c] /= np.float32(inp["std"][c])
    return out


def _stride(model: OnnxModel) -> int:
    """Output stride of the network (1: full-resolution output; 2: the map is at 1/2 resolution
    and is up-sampled bilinearly here, half-pixel centres, as the training graph does)."""
    return int(model.meta.get("output", {}).get("stride", 1))


def _run(model: OnnxModel, xs: np.ndarray, *, severity: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """(N, 3, H, W) input of any H, W -> ((N, C, h, w) probabilities, (N, 3, h, w) condition-state
    logits or None) at the network's output resolution (h = ceil(H / 16) * 16 / stride; the
    caller up-samples and crops with :func:`_full_u8` / :func:`_full_states`). The severity
    output is computed only when asked for and the model has one."""
    _, _, h, w = xs.shape
    ph, pw = (-h) % MULTIPLE_OF, (-w) % MULTIPLE_OF
    if ph or pw:
        xs = np.pad(xs, ((0, 0), (0, 0), (0, ph), (0, pw)), mode="reflect")
    name = model.session.get_inputs()[0].name
    names = [model.session.get_outputs()[0].name]
    if severity and model.severity_output is not None:
        names.append(model.severity_output)
    out = model.session.run(names, {name: xs})
    return out[0], (out[1] if len(out) > 1 else None)


def _full_logits(logits: np.ndarray, stride: int, h: int, w: int) -> np.ndarray:
    """(3, h', w') condition-state logits at the output resolution -> (3, h, w), up-sampled
    bilinearly by ``stride`` (as in training) and cropped."""
    if stride != 1:
        logits = np.stack([cv2.resize(c, (c.shape[1] * stride, c.shape[0] * stride), interpolation=cv2.INTER_LINEAR)
                           for c in logits])
    return logits[:, :h, :w]


def _full_states(logits: np.ndarray, stride: int, h: int, w: int, bias=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(3, h', w') condition-state logits at the output resolution -> (h, w) uint8 state 1..3
    (fair, poor, severe) of every pixel: :func:`_full_logits` plus the model's ``bias``, arg-max."""
    z = _full_logits(logits, stride, h, w)
    a, b, c = (z[i] + np.float32(bias[i]) for i in range(3))
    out = np.where(b > a, np.uint8(2), np.uint8(1))  # the arg-max of three maps (first on ties),
    out[c > np.maximum(a, b)] = 3  # several times faster than np.argmax over the first axis
    return out


def onnx_severity_logits(image: np.ndarray, model: OnnxModel) -> np.ndarray:
    """(3, H, W) condition-state logits of a whole image (no bias; for choosing it on validation)."""
    _check(image)
    h, w = image.shape[:2]
    _, z = _run(model, _prepare(image, model.meta)[None], severity=True)
    if z is None:
        raise ValueError("ONNX model has no severity output")
    return _full_logits(z[0], _stride(model), h, w)


def _full_u8(p: np.ndarray, stride: int, h: int, w: int, cal: tuple[int, float] | None = None) -> np.ndarray:
    """One class's output map (float 0..1 at the output resolution) -> (h, w) uint8 at the
    input resolution: rounded to 0..255, up-sampled bilinearly by ``stride`` (cv2 and the
    training graph's bilinear up-sampling agree to within one grey level), cropped. With ``cal``
    (the class's (operating point, gain)) rounded to 16 bits instead, up-sampled, then calibrated
    to 8 bits (``_core.calibration_lut``)."""
    q = to_u8(p) if cal is None else np.clip(np.rint(p * np.float32(65535)), 0, 65535).astype(np.uint16)
    if stride != 1:
        q = cv2.resize(q, (q.shape[1] * stride, q.shape[0] * stride), interpolation=cv2.INTER_LINEAR)
    q = q[:h, :w]
    return q if cal is None else np.take(calibration_lut(*cal), q)


def _check(image: np.ndarray) -> None:
    check_image(image)
    h, w = image.shape[:2]
    if min(h, w) < MIN_SIDE_PX:
        raise ValueError(f"image {w}x{h} is too small for the network (sides >= {MIN_SIDE_PX} px)")


def onnx_maps(
    image: np.ndarray, model: OnnxModel, *, kinds=None, tile_px: int = TILE_PX, margin_px: int = MARGIN_PX,
    whole_max_px: int = WHOLE_MAX_PX, own_decision: bool = False,
) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """(per-class probability maps (H, W) uint8 of the classes ``kinds`` (default all of the
    model's), condition-state map (H, W) uint8 1..3 of every pixel or None: without a severity
    head, or when corrosion is not asked for). Images above ``whole_max_px`` pixels run in tiles
    of ``tile_px`` with ``margin_px`` overlap on each side (tile origins on the 16 px grid), so
    memory is bounded by the tile size. ``own_decision``: the caller decides corrosion on this
    model's own map at its operating point, so an attached states network is skipped on an image
    where nothing reaches it (:func:`_attached_states`)."""
    _check(image)
    if tile_px % MULTIPLE_OF or margin_px % MULTIPLE_OF:
        raise ValueError(f"tile and margin must be multiples of {MULTIPLE_OF} px")
    want = [(i, k) for i, k in enumerate(model.classes) if kinds is None or k in kinds]
    sev = model.severity_output is not None and any(k == "corrosion" for _, k in want)
    if model.severity_output is None and model.states_model is not None and any(k == "corrosion" for _, k in want):
        probs = onnx_maps(image, dataclasses.replace(model, states_model=None), kinds=kinds, tile_px=tile_px,
                          margin_px=margin_px, whole_max_px=whole_max_px)[0]
        return probs, _attached_states(image, model, probs["corrosion"] if own_decision else None, tile_px=tile_px,
                                       margin_px=margin_px, whole_max_px=whole_max_px)
    h, w = image.shape[:2]
    s = _stride(model)
    if h * w <= whole_max_px:
        p, z = _run(model, _prepare(image, model.meta)[None], severity=sev)
        return {k: _full_u8(p[0, i], s, h, w, model.calibration.get(k)) for i, k in want}, \
            (_full_states(z[0], s, h, w, model.severity_bias) if sev else None)
    out = {k: np.zeros((h, w), np.uint8) for _, k in want}
    states = np.zeros((h, w), np.uint8) if sev else None
    for (y0, y1, x0, x1), (ty0, ty1, tx0, tx1) in tiles(h, w, tile_px, margin_px):
        p, z = _run(model, _prepare(np.ascontiguousarray(image[ty0:ty1, tx0:tx1]), model.meta)[None], severity=sev)
        core = (slice(y0 - ty0, y1 - ty0), slice(x0 - tx0, x1 - tx0))
        for i, k in want:
            out[k][y0:y1, x0:x1] = _full_u8(p[0, i], s, ty1 - ty0, tx1 - tx0, model.calibration.get(k))[core]
        if sev:
            states[y0:y1, x0:x1] = _full_states(z[0], s, ty1 - ty0, tx1 - tx0, model.severity_bias)[core]
    return out, states


def scaled_input(image: np.ndarray, scale: float) -> np.ndarray | None:
    """``image`` resized by ``scale`` (area-averaged) for an attached states network, or None where
    it runs at full size (scale 1, or a short side that would fall below the smallest input)."""
    h, w = image.shape[:2]
    if scale == 1.0 or min(h, w) * scale < MIN_SIDE_PX:
        return None
    return cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)


def _attached_states(image: np.ndarray, model: OnnxModel, corrosion_u8: np.ndarray | None = None, **kw) -> np.ndarray:
    """Condition states 1..3 of every pixel from the network attached to ``model``
    (``states_model``), run on the image resized by ``states_scale`` (area-averaged; not below the
    network's smallest input) and brought back to full size by nearest neighbour. Given the
    corrosion map that ``model`` itself decides on, and no pixel of it reaches ``model``'s
    operating point, the second network is not run: only decided pixels keep a state, so every
    pixel gets 1 and the detection is the same."""
    h, w = image.shape[:2]
    if corrosion_u8 is not None and not (corrosion_u8 >= model.thresholds_u8["corrosion"]).any():
        return np.ones((h, w), np.uint8)
    small = scaled_input(image, model.states_scale)
    if small is not None:
        st = onnx_maps(small, model.states_model, kinds=("corrosion",), **kw)[1]
        return cv2.resize(st, (w, h), interpolation=cv2.INTER_NEAREST)
    return onnx_maps(image, model.states_model, kinds=("corrosion",), **kw)[1]


def onnx_probabilities_u8(image: np.ndarray, model: OnnxModel, *, kinds=None, tile_px: int = TILE_PX,
                          margin_px: int = MARGIN_PX, whole_max_px: int = WHOLE_MAX_PX) -> dict[str, np.ndarray]:
    """The per-class maps of :func:`onnx_maps` (no condition states)."""
    want = tuple(k for k in model.classes if kinds is None or k in kinds)
    m = model if model.severity_output is None else _no_severity(model)
    return onnx_maps(image, m, kinds=want, tile_px=tile_px, margin_px=margin_px, whole_max_px=whole_max_px)[0]


def _no_severity(model: OnnxModel) -> OnnxModel:
    return dataclasses.replace(model, severity_output=None, states_model=None)


def _detection(probs: dict[str, np.ndarray], model: OnnxModel, kinds, states: np.ndarray | None = None) -> Detection:
    """Decision, regions and the combined map from per-class maps; ``model`` gives per-class
    ``thresholds_u8`` and ``min_area_px`` (the onnx model or the fused parameters). With
    ``states`` (condition state 1..3 of every pixel) the decided corrosion pixels get their state
    in ``Detection.severity`` and corrosion regions their state fractions."""
    h, w = next(iter(probs.values())).shape
    mask = np.zeros((h, w), bool)
    regions: list[Region] = []
    severity = None
    for k in kinds:
        m, labels, stats, ids = decide_u8(probs[k], model.thresholds_u8[k], model.min_area_px[k])
        mask |= m
        st = states if k == "corrosion" else None
        if st is not None:
            severity = np.where(m, st, 0).astype(np.uint8)
        regions += regions_of(k, probs[k], labels, stats, ids, st)
    prob = probs[kinds[0]].copy() if len(kinds) == 1 else np.maximum.reduce([probs[k] for k in kinds])
    return Detection(prob, mask, {k: probs[k] for k in kinds}, tuple(regions), severity)


def _check_kinds(model: OnnxModel, kinds) -> None:
    for k in kinds:
        if k not in model.classes:
            raise ValueError(f"ONNX model has no class {k!r} (has {', '.join(model.classes)})")


def detect_onnx(image: np.ndarray, model: OnnxModel, *, kinds=("corrosion", "crack"), tile_px: int = TILE_PX) -> Detection:
    """Like :func:`detect` of the saliency engine, with the learned network. Grey images are
    accepted for every class (replicated to RGB). Raises ValueError for an unusable image."""
    _check_kinds(model, kinds)
    probs, states = onnx_maps(image, model, kinds=kinds, tile_px=tile_px, own_decision=True)
    return _detection(probs, model, kinds, states)


def detect_onnx_batch(images: list[np.ndarray], model: OnnxModel, *, kinds=("corrosion", "crack"),
                      batch: int = 4, tile_px: int = TILE_PX) -> list[Detection]:
    """Detections for a sweep's frames: frames of equal size (up to ``WHOLE_MAX_PX``) run
    ``batch`` at a time through one session call; others as with :func:`detect_onnx`."""
    _check_kinds(model, kinds)
    for im in images:
        _check(im)
    out: list[Detection | None] = [None] * len(images)
    groups: dict[tuple, list[int]] = {}
    for i, im in enumerate(images):
        if im.shape[0] * im.shape[1] <= WHOLE_MAX_PX:
            groups.setdefault(im.shape, []).append(i)
        else:
            out[i] = detect_onnx(im, model, kinds=kinds, tile_px=tile_px)
    for idx in groups.values():
        for s in range(0, len(idx), batch):
            part = idx[s:s + batch]
            sev = model.severity_output is not None and "corrosion" in kinds
            p, z = _run(model, np.stack([_prepare(images[i], model.meta) for i in part]), severity=sev)
            h, w = images[part[0]].shape[:2]
            s = _stride(model)
            attached = model.severity_output is None and model.states_model is not None and "corrosion" in kinds
            for j, i in enumerate(part):
                probs = {k: _full_u8(p[j, c], s, h, w, model.calibration.get(k)) for c, k in enumerate(model.classes) if k in kinds}
                states = _full_states(z[j], s, h, w, model.severity_bias) if sev else \
                    _attached_states(images[i], model, probs["corrosion"], tile_px=tile_px) if attached else None
                out[i] = _detection(probs, model, kinds, states)
    return out  # type: ignore[return-value]


#: Input scale of the condition-state network (:func:`with_condition_states`): the smallest of the
#: validation scales 0.25 / 0.375 / 0.5 within 0.005 of the best states figure with the default's
#: decisions (v6's states for v5's decisions: 0.575 / 0.621 / 0.625; the frame 43 / 46 / 48 ms;
#: docs/detect_onnx.md, "Condition states from v6"). 0.375 with v3, 0.5 with v4 and v5.
STATES_SCALE = 0.375


def default_onnx_path() -> Path:
    """The default network: v5 (EfficientNet-Lite1 U-Net, int8, trained with zoomed-out corrosion
    crops), which decides where each class is. Chosen on validation: mean F 0.863 against v4's
    0.854 and v1's 0.833 (corrosion 0.790 / 0.789 / 0.725), its corrosion F held at 1/2 of the
    photos' scale (0.791 against v4's 0.766), and on the rendered demo walls it outlines the
    corrosion patches v4 cut short (docs/detect_onnx.md). The condition states of the corrosion it
    decides come from :func:`condition_state_onnx_path`."""
    return Path(__file__).parent / "models" / "defects_unet_v5.onnx"


def with_condition_states(model: OnnxModel, *, threads: int = 1, scale: float | None = None) -> OnnxModel:
    """``model`` with the shipped condition-state network (v6, :func:`condition_state_onnx_path`)
    attached: each corrosion pixel ``model`` decides gets the state of v6's head, run on the image
    at ``scale`` (default ``STATES_SCALE``) of its size, with the logit offsets v6's metadata
    records for ``model``'s file (chosen on validation: mean F1 of fair / poor / severe 0.621 for
    the default v5's decisions, against 0.513 from v5's own head; 0.562 for v1's; docs/detect_onnx.md).
    A network's own head, if it has one, is then not read. v6 itself, or a network without a
    corrosion class, is returned as it is. Costs one more network pass, on images where corrosion
    is asked for and decided."""
    if "corrosion" not in model.classes or model.path.resolve() == condition_state_onnx_path().resolve():
        return model
    scale = STATES_SCALE if scale is None else scale
    states = load_onnx_model(condition_state_onnx_path(), threads=threads)
    if states.severity_output is None:
        raise ValueError("the condition-state network has no condition-state head")
    bias = attached_bias(states, model, scale)
    if bias is not None:
        states = dataclasses.replace(states, severity_bias=bias)
    return dataclasses.replace(model, severity_output=None, states_model=dataclasses.replace(states, states_model=None),
                               states_scale=scale)


def attached_bias(states: OnnxModel, decider: OnnxModel, scale: float) -> tuple[float, float, float] | None:
    """The logit offsets ``states``' metadata records for giving the states of ``decider``'s
    corrosion at ``scale`` (``severity.attached``: chosen on the validation images for that
    decider file, checked by its SHA-256), or None: its own offsets apply."""
    import hashlib

    recs = states.meta.get("severity", {}).get("attached", [])
    rec = next((a for a in recs if a.get("decider") == decider.path.name and float(a.get("scale", -1)) == float(scale)), None)
    if rec is None or rec.get("decider_sha256") != hashlib.sha256(decider.path.read_bytes()).hexdigest():
        return None
    b = rec.get("logit_bias")
    if not (isinstance(b, list) and len(b) == 3 and all(isinstance(x, (int, float)) for x in b)):
        raise ValueError(f"{states.path}: severity.attached logit_bias must be three numbers")
    return tuple(float(x) for x in b)


def condition_state_onnx_path() -> Path:
    """The network whose condition-state head gives the states of every other network's corrosion
    (:func:`with_condition_states`): v6, v5's recipe trained twice as long (``--max-steps 4480``),
    whose head is the best on validation (0.583 with its own decisions, v5's 0.513). It does not
    decide by default: on the rendered walls its decisions were less steady than v5's
    (docs/detect_onnx.md). ``--model defects_unet_v6.onnx`` decides with it, its own head at full size."""
    return Path(__file__).parent / "models" / "defects_unet_v6.onnx"
