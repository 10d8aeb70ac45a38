"""Tiny ONNX files written byte by byte (protobuf wire format), for tests of damaged or
mismatched models without the ``onnx`` package (only in the [train] extra): a one-node graph,
and an existing model's ``metadata_props`` replaced."""

from __future__ import annotations

import json


def _varint(x: int) -> bytes:
    out = bytearray()
    while True:
        b, x = x & 0x7F, x >> 7
        out.append(b | (0x80 if x else 0))
        if not x:
            return bytes(out)


def _read_varint(buf: bytes, i: int) -> tuple[int, int]:
    x = shift = 0
    while True:
        b = buf[i]
        i += 1
        x |= (b & 0x7F) << shift
        shift += 7
        if b < 0x80:
            return x, i


def _field(num: int, payload: bytes | str) -> bytes:  # length-delimited
    data = payload.encode() if isinstance(payload, str) else payload
    return _varint(num << 3 | 2) + _varint(len(data)) + data


def _int_field(num: int, x: int) -> bytes:
    return _varint(num << 3) + _varint(x)


def _metadata(meta: dict | str) -> bytes:  # ModelProto.metadata_props (14): StringStringEntryProto
    value = meta if isinstance(meta, str) else json.dumps(meta)
    return _field(14, _field(1, "inspect_pipe") + _field(2, value))


def with_metadata(model: bytes, meta: dict | str) -> bytes:
    """``model`` (a serialised ModelProto) with its metadata_props replaced by ``inspect_pipe``: ``meta``."""
    out, i = bytearray(), 0
    while i < len(model):
        key, j = _read_varint(model, i)
        num, wire = key >> 3, key & 7
        if wire == 0:
            _, k = _read_varint(model, j)
        elif wire == 2:
            n, k = _read_varint(model, j)
            k += n
        elif wire == 1:
            k = j + 8
        elif wire == 5:
            k = j + 4
        else:
            raise ValueError(f"wire type {wire}")
        if num != 14:
            out += model[i:k]
        i = k
    return bytes(out) + _metadata(meta)


def _value_info(name: str, shape) -> bytes:
    dims = b"".join(_field(1, _int_field(1, d) if isinstance(d, int) else _field(2, d)) for d in shape)
    tensor = _int_field(1, 1) + _field(2, dims)  # float32, shape
    return _field(1, name) + _field(2, _field(1, tensor))


def one_node_model(op: str, in_shape, out_shape, meta: dict | str) -> bytes:
    """image -> ``op`` -> prob (opset 13), with the given shapes (ints fixed, strings free)."""
    node = _field(1, "image") + _field(2, "prob") + _field(3, "n0") + _field(4, op)
    graph = _field(1, node) + _field(2, "g") + _field(11, _value_info("image", in_shape)) + _field(12, _value_info("prob", out_shape))
    return _int_field(1, 7) + _field(7, graph) + _field(8, _field(1, "") + _int_field(2, 13)) + _metadata(meta)
