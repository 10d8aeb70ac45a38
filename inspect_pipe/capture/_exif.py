"""Camera metadata inside each image: EXIF (make, model, software, time, exposure) and an XMP
packet with the sweep-specific fields (frame index, capture time, intrinsics). No GPS: there is no
GPS in a cargo hold and we do not invent one.

PNG gets ``eXIf`` and ``iTXt XML:com.adobe.xmp`` chunks after IHDR; JPEG gets two APP1 segments.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from fractions import Fraction
from xml.sax.saxutils import escape

__all__ = ["ImageMeta", "embed", "exif_tiff", "xmp_packet"]

_ASCII, _LONG, _RATIONAL = 2, 4, 5


@dataclass(frozen=True)
class ImageMeta:
    make: str
    model: str
    software: str
    datetime_utc: str  # ISO 8601
    exposure_s: float
    width: int
    height: int
    xmp: dict  # flat key -> scalar, written as ip:key attributes


def _ifd(entries: list[tuple[int, int, object]], base: int) -> tuple[bytes, int]:
    """Big-endian IFD at offset ``base``; returns its bytes (with its data area) and where the
    next-IFD pointer sits (relative to ``base``)."""
    entries = sorted(entries, key=lambda e: e[0])
    n = len(entries)
    head = struct.pack(">H", n)
    data = b""
    data_off = base + 2 + 12 * n + 4
    body = b""
    for tag, typ, val in entries:
        if typ == _ASCII:
            raw = str(val).encode("ascii", "replace") + b"\0"
            count = len(raw)
        elif typ == _LONG:
            raw, count = struct.pack(">I", int(val)), 1
        elif typ == _RATIONAL:
            fr = Fraction(float(val)).limit_denominator(1_000_000)
            raw, count = struct.pack(">II", fr.numerator, fr.denominator), 1
        else:  # pragma: no cover - only the types above are used
            raise ValueError(typ)
        if len(raw) <= 4:
            field = raw.ljust(4, b"\0")
        else:
            field = struct.pack(">I", data_off + len(data))
            data += raw + (b"\0" if len(raw) % 2 else b"")
        body += struct.pack(">HHI", tag, typ, count) + field
    return head + body + b"\0\0\0\0" + data, 2 + 12 * n


def exif_tiff(m: ImageMeta) -> bytes:
    dt = m.datetime_utc[:19].replace("-", ":").replace("T", " ")
    subsec = m.datetime_utc[20:26] if len(m.datetime_utc) > 20 else "0"
    exif_entries = [
        (0x829A, _RATIONAL, max(m.exposure_s, 1e-6)),  # ExposureTime
        (0x9003, _ASCII, dt),  # DateTimeOriginal
        (0x9291, _ASCII, subsec),  # SubSecTimeOriginal
        (0x9011, _ASCII, "+00:00"),  # OffsetTimeOriginal
        (0xA002, _LONG, m.width),
        (0xA003, _LONG, m.height),
    ]
    ifd0_entries: list[tuple[int, int, object]] = [
        (0x010F, _ASCII, m.make),
        (0x0110, _ASCII, m.model),
        (0x0131, _ASCII, m.software),
        (0x0132, _ASCII, dt),
        (0x8769, _LONG, 0),  # ExifIFD pointer, patched below
    ]
    ifd0, _ = _ifd(ifd0_entries, 8)
    exif_off = 8 + len(ifd0)
    ifd0_entries[-1] = (0x8769, _LONG, exif_off)
    ifd0, _ = _ifd(ifd0_entries, 8)
    exif, _ = _ifd(exif_entries, exif_off)
    return b"MM\x00\x2a" + struct.pack(">I", 8) + ifd0 + exif


def xmp_packet(fields: dict) -> bytes:
    attrs = "".join(f'\n    ip:{k}="{escape(str(v), {chr(34): "&quot;"})}"' for k, v in fields.items())
    return (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n'
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">\n'
        f'  <rdf:Description rdf:about="" xmlns:ip="https://inspect-pipe.invalid/ns/capture/1/"{attrs}/>\n'
        "</rdf:RDF></x:xmpmeta>\n<?xpacket end=\"w\"?>"
    ).encode("utf-8")


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def embed(encoded: bytes, meta: ImageMeta) -> bytes:
    """Return the PNG or JPEG bytes with EXIF and XMP inserted."""
    tiff = exif_tiff(meta)
    xmp = xmp_packet(meta.xmp)
    if encoded[:8] == b"\x89PNG\r\n\x1a\n":
        ihdr_end = 8 + 12 + struct.unpack(">I", encoded[8:12])[0]
        extra = _png_chunk(b"eXIf", tiff) + _png_chunk(b"iTXt", b"XML:com.adobe.xmp\0\0\0\0\0" + xmp)
        return encoded[:ihdr_end] + extra + encoded[ihdr_end:]
    if encoded[:2] == b"\xff\xd8":
        app1 = b"Exif\0\0" + tiff
        xmp_seg = b"http://ns.adobe.com/xap/1.0/\0" + xmp
        segs = b"".join(b"\xff\xe1" + struct.pack(">H", len(p) + 2) + p for p in (app1, xmp_seg))
        pos = 2
        if encoded[2:4] == b"\xff\xe0":  # keep JFIF APP0 first
            pos = 4 + struct.unpack(">H", encoded[4:6])[0]
        return encoded[:pos] + segs + encoded[pos:]
    raise ValueError("not a PNG or JPEG stream")
