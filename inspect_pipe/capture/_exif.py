"""Camera metadata inside each image: EXIF (make, model, software, time, exposure) and an XMP
packet with the sweep-specific fields (frame index, capture time, intrinsics). No GPS: there is no
GPS in a cargo hold and we do not invent one.

Pillow writes the EXIF block and reads both back (``Image.getexif()``, ``im.info["XML:com.adobe.xmp"]``
or ``im.getxmp()``). The image itself is encoded by OpenCV (faster, and the writer's adaptive PNG
levels); the two blocks go into that stream as PNG ``eXIf`` and ``iTXt XML:com.adobe.xmp`` chunks
after IHDR, or as two JPEG APP1 segments, without re-encoding the pixels.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from fractions import Fraction
from xml.etree import ElementTree as ET

from PIL import ExifTags, Image
from PIL.TiffImagePlugin import IFDRational

__all__ = ["ImageMeta", "XMP_NS", "embed", "exif_tiff", "xmp_packet"]

XMP_NS = "https://inspect-pipe.invalid/ns/capture/1/"  # the ip: prefix of the sweep fields
_RDF = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
_X = "adobe:ns:meta/"
ET.register_namespace("x", _X)
ET.register_namespace("rdf", _RDF)
ET.register_namespace("ip", XMP_NS)


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


def exif_tiff(m: ImageMeta) -> bytes:
    """The EXIF block (a TIFF stream, no ``Exif\\0\\0`` header) written by Pillow: IFD0 with make,
    model, software and time; the Exif IFD with exposure, original time (with sub-seconds and
    the UTC offset) and the image size."""
    dt = m.datetime_utc[:19].replace("-", ":").replace("T", " ")
    subsec = m.datetime_utc[20:26] if len(m.datetime_utc) > 20 else "0"
    exif = Image.Exif()
    exif[ExifTags.Base.Make] = m.make
    exif[ExifTags.Base.Model] = m.model
    exif[ExifTags.Base.Software] = m.software
    exif[ExifTags.Base.DateTime] = dt
    exif[ExifTags.IFD.Exif] = {
        ExifTags.Base.ExposureTime: IFDRational(Fraction(max(m.exposure_s, 1e-6)).limit_denominator(1_000_000)),
        ExifTags.Base.DateTimeOriginal: dt,
        ExifTags.Base.SubsecTimeOriginal: subsec,
        ExifTags.Base.OffsetTimeOriginal: "+00:00",
        ExifTags.Base.ExifImageWidth: int(m.width),
        ExifTags.Base.ExifImageHeight: int(m.height),
    }
    raw = exif.tobytes()
    return raw[6:] if raw.startswith(b"Exif\0\0") else raw


def xmp_packet(fields: dict) -> bytes:
    """An XMP packet whose one rdf:Description carries ``fields`` as ip:KEY attributes."""
    meta = ET.Element(f"{{{_X}}}xmpmeta")
    rdf = ET.SubElement(meta, f"{{{_RDF}}}RDF")
    ET.SubElement(rdf, f"{{{_RDF}}}Description", {f"{{{_RDF}}}about": "", **{f"{{{XMP_NS}}}{k}": str(v) for k, v in fields.items()}})
    body = ET.tostring(meta, encoding="unicode")
    return ('<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>\n' + body + '\n<?xpacket end="w"?>').encode("utf-8")


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
