"""The ``inspect_pipe`` metadata of an exported network (``defect_onnx/1``), as a schema: what
:func:`_onnx_detect.load_onnx_model` reads of it, with types and bounds, so that a damaged or
hand-edited file is refused when it is opened, naming the field, instead of failing later on an
image (or, worse, deciding with a stride or a normalisation the network was not trained with).
Fields this code does not read (training record, metrics, licence) pass through unchecked."""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, StrictInt, ValidationError

ONNX_FORMAT = "inspect_pipe.defect_onnx/1"


def _finite(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError("must be a finite number")
    return v


Number = Annotated[float, Field(strict=True), AfterValidator(_finite)]  # strict: no bool, no text
U8 = Annotated[StrictInt, Field(ge=0, le=255)]


class _Doc(BaseModel):
    model_config = ConfigDict(extra="allow")


class InputMeta(_Doc):
    name: str
    layout: Literal["NCHW"]
    channels: Literal["RGB"]
    multiple_of: Literal[16]
    scale: Annotated[Number, Field(gt=0)] = 1 / 255
    mean: tuple[Number, Number, Number]
    std: tuple[Annotated[Number, Field(gt=0)], Annotated[Number, Field(gt=0)], Annotated[Number, Field(gt=0)]]


class OutputMeta(_Doc):
    name: str = "prob"
    stride: Annotated[StrictInt, Field(ge=1, le=16)] = 1


class CalibrationMeta(_Doc):
    operating_point_u8: U8
    gain: Number  # its range, with the operating point, load_onnx_model checks


class AttachedMeta(_Doc):
    decider: str
    decider_sha256: str
    scale: Annotated[Number, Field(gt=0, le=1)]
    logit_bias: tuple[Number, Number, Number]


class SeverityMeta(_Doc):
    output: str
    states: tuple[str, ...]
    logit_bias: tuple[Number, Number, Number] = (0.0, 0.0, 0.0)
    attached: list[AttachedMeta] = []


class OnnxMeta(_Doc):
    format: Literal["inspect_pipe.defect_onnx/1"]
    classes: Annotated[list[str], Field(min_length=1)]
    input: InputMeta
    output: OutputMeta = OutputMeta()
    operating_points_u8: dict[str, U8]
    min_area_px: dict[str, Annotated[StrictInt, Field(ge=0, le=1_000_000)]] = {}
    calibration: dict[str, CalibrationMeta] | None = None
    severity: SeverityMeta | None = None


def check_meta(meta: object) -> None:
    """Raise ValueError("ONNX model metadata: field 'a.b': ...") for metadata outside the schema."""
    if not isinstance(meta, dict):
        raise ValueError(f"ONNX model metadata is {type(meta).__name__}, not a mapping")
    if meta.get("format") != ONNX_FORMAT:  # the one message older tools and files know
        raise ValueError(f"ONNX model format {str(meta.get('format'))[:40]!r}, expected {ONNX_FORMAT!r}")
    try:
        OnnxMeta.model_validate(meta)
    except ValidationError as err:
        e = err.errors(include_url=False)[0]
        where = ".".join(str(p) for p in e["loc"])
        raise ValueError(f"ONNX model metadata: field '{where}': {e['msg']}"[:300]) from None
