"""EXIF and XMP of sweep images: written through Pillow, read back by Pillow from PNG and JPEG."""

from __future__ import annotations

import io
from xml.etree import ElementTree as ET

import cv2
import numpy as np
import pytest
from PIL import ExifTags, Image

from inspect_pipe.capture._exif import XMP_NS, ImageMeta, embed

META = ImageMeta(make="v4l2", model="UVC Camera (046d:0825)", software="inspect-pipe 0.1.0",
                 datetime_utc="2026-11-25T00:12:13.456789+00:00", exposure_s=0.0025, width=64, height=48,
                 xmp={"frame_index": 17, "t_s": 12.345678, "fsm": "inspection", "quote": 'a"<b>&'})


@pytest.mark.parametrize("ext", ["png", "jpg"])
def test_pillow_reads_back_time_exposure_camera_and_xmp(ext):
    img = (np.arange(64 * 48 * 3) % 251).astype(np.uint8).reshape(48, 64, 3)
    ok, buf = cv2.imencode("." + ext, img)
    assert ok
    data = embed(buf.tobytes(), META)
    im = Image.open(io.BytesIO(data))
    im.load()
    assert im.size == (64, 48)
    exif = im.getexif()
    assert exif[ExifTags.Base.Make] == "v4l2" and exif[ExifTags.Base.Model] == "UVC Camera (046d:0825)"
    assert exif[ExifTags.Base.Software] == "inspect-pipe 0.1.0"
    assert exif[ExifTags.Base.DateTime] == "2026:11:25 00:12:13"
    sub = exif.get_ifd(ExifTags.IFD.Exif)
    assert float(sub[ExifTags.Base.ExposureTime]) == pytest.approx(0.0025)
    assert sub[ExifTags.Base.DateTimeOriginal] == "2026:11:25 00:12:13"
    assert sub[ExifTags.Base.SubsecTimeOriginal] == "456789" and sub[ExifTags.Base.OffsetTimeOriginal] == "+00:00"
    assert (sub[ExifTags.Base.ExifImageWidth], sub[ExifTags.Base.ExifImageHeight]) == (64, 48)
    assert ExifTags.IFD.GPSInfo not in exif  # no GPS in a cargo hold
    xmp = im.info.get("XML:com.adobe.xmp") or im.info.get("xmp")
    xmp = xmp.decode() if isinstance(xmp, bytes) else xmp
    desc = ET.fromstring(xmp[xmp.index("<x:xmpmeta"):xmp.index("</x:xmpmeta>") + len("</x:xmpmeta>")]).find(".//{*}Description")
    fields = {k.split("}")[1]: v for k, v in desc.attrib.items() if k.startswith("{" + XMP_NS)}
    assert fields == {"frame_index": "17", "t_s": "12.345678", "fsm": "inspection", "quote": 'a"<b>&'}
    # the pixels are untouched by the insertion
    back = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(back, cv2.imdecode(buf, cv2.IMREAD_COLOR))


def test_not_an_image_stream_is_refused():
    with pytest.raises(ValueError, match="not a PNG or JPEG"):
        embed(b"GIF89a....", META)
