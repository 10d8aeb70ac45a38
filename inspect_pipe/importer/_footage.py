"""Footage from another drone: a folder of images or a video, with each frame's time on the
camera's clock (UTC, seconds since 1970).

- Images: EXIF ``DateTimeOriginal`` + ``SubSecTimeOriginal`` + ``OffsetTimeOriginal``, read with
  Pillow (no pixel decoding). Without ``OffsetTimeOriginal`` the time is taken as UTC and the
  import says so.
- Video: frame times from the container (``cv2.VideoCapture``'s ``CAP_PROP_POS_MSEC``) after the
  file's creation time (PyAV reads ``creation_time`` from the container; ``--video-start`` when
  it has none).

Frames are resampled to 10 Hz: for each instant of a 10 Hz grid the nearest frame (within half
a period) is kept, once; a frame keeps its own time, so the vehicle state is interpolated at the
instant it was taken.

:func:`write_drone_footage` turns a sweep into what a drone leaves behind (JPEGs with EXIF times
shifted by a camera clock offset), for tests and benchmarks of the import.
"""

from __future__ import annotations

import datetime as _dt
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from inspect_pipe._images import imread, truncation
from inspect_pipe.errors import InputError

__all__ = ["Footage", "FootageFrame", "IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "open_footage", "parse_utc", "resample", "write_drone_footage"]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".avi", ".m4v", ".mts", ".ts", ".webm")
EXIF_IFD = 0x8769
DATETIME_ORIGINAL, OFFSET_TIME_ORIGINAL, SUBSEC_TIME_ORIGINAL = 0x9003, 0x9011, 0x9291


@dataclass(frozen=True)
class FootageFrame:
    t_camera_s: float  # UTC by the camera's clock, seconds since 1970
    name: str  # image file name, or "VIDEO#frame"
    path: Path | None = None  # image file
    video_index: int | None = None  # frame number in the video


@dataclass
class Footage:
    source: Path
    kind: str  # images | video
    frames: list[FootageFrame]  # all frames with a time, in time order
    width: int
    height: int
    time_note: str  # where the times come from

    def load(self, frames: list[FootageFrame], *, reduce: int = 1):
        """Yield (frame, BGR image) for ``frames`` (in time order); ``reduce`` 2/4/8 decodes a
        JPEG at that fraction of its size (grey), much faster."""
        if self.kind == "images":
            flag = {1: cv2.IMREAD_COLOR, 2: cv2.IMREAD_REDUCED_GRAYSCALE_2, 4: cv2.IMREAD_REDUCED_GRAYSCALE_4,
                    8: cv2.IMREAD_REDUCED_GRAYSCALE_8}[reduce]
            for f in frames:
                if why := truncation(f.path):
                    raise InputError(str(f.path), why, "copy it again from the card, or move it out of the folder")
                img = imread(str(f.path), flag)
                if img is None:
                    raise InputError(str(f.path), "cannot decode the image", "a JPEG, PNG or TIFF file")
                yield f, img
            return
        cap = cv2.VideoCapture(str(self.source))
        if not cap.isOpened():
            raise InputError(str(self.source), "the video decoder refuses the file", "a video OpenCV/FFmpeg can read")
        try:
            wanted = {f.video_index: f for f in frames}
            last = max(wanted) if wanted else -1
            k = 0
            while k <= last:
                if not cap.grab():
                    raise InputError(str(self.source), f"the video ended or broke at frame {k}", "a video OpenCV/FFmpeg can read")
                if k in wanted:
                    ok, img = cap.retrieve()
                    if not ok:
                        raise InputError(str(self.source), f"cannot decode frame {k}", "a video OpenCV/FFmpeg can read")
                    if reduce > 1:
                        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
                        img = cv2.resize(img, (img.shape[1] // reduce, img.shape[0] // reduce), interpolation=cv2.INTER_AREA)
                    yield wanted[k], img
                k += 1
        finally:
            cap.release()


def parse_utc(text: str, where: str = "--video-start") -> float:
    """ISO 8601 time (``2026-11-20T10:31:02.250Z``, ``+02:00`` offsets; no zone = UTC) -> unix s."""
    try:
        d = _dt.datetime.fromisoformat(text.strip().replace("Z", "+00:00").replace(" ", "T", 1))
    except ValueError:
        raise InputError(where, f"{text!r} is not an ISO 8601 time", "e.g. 2026-11-20T10:31:02.250Z") from None
    if d.tzinfo is None:
        d = d.replace(tzinfo=_dt.timezone.utc)
    return d.timestamp()


_OFFSET_RE = re.compile(r"^([+-])(\d{2}):?(\d{2})$")


def _exif_time(path: Path) -> tuple[float | None, bool, tuple[int, int]]:
    """(UTC s or None, whether the offset was given, (width, height)) from an image's EXIF."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            size = im.size
            exif = im.getexif()
            ifd = exif.get_ifd(EXIF_IFD)
    except Exception as err:  # PIL raises many kinds on damaged files
        raise InputError(str(path), f"not a readable image ({err.__class__.__name__})", "a JPEG, PNG or TIFF file") from None
    dto = ifd.get(DATETIME_ORIGINAL)
    if not isinstance(dto, str) or not dto.strip():
        return None, False, size
    try:
        d = _dt.datetime.strptime(dto.strip().rstrip("\x00"), "%Y:%m:%d %H:%M:%S")
    except ValueError:
        raise InputError(str(path), f"EXIF DateTimeOriginal {dto!r} is not 'YYYY:MM:DD HH:MM:SS'", "fix the camera's clock settings") from None
    sub = str(ifd.get(SUBSEC_TIME_ORIGINAL, "") or "").strip().rstrip("\x00").strip()
    frac = float("0." + sub) if sub.isdigit() else 0.0
    off = str(ifd.get(OFFSET_TIME_ORIGINAL, "") or "").strip().rstrip("\x00")
    m = _OFFSET_RE.match(off)
    tz = _dt.timezone.utc
    if m:
        sign = 1 if m.group(1) == "+" else -1
        tz = _dt.timezone(sign * _dt.timedelta(hours=int(m.group(2)), minutes=int(m.group(3))))
    return d.replace(tzinfo=tz).timestamp() + frac, bool(m), size


def _images(folder: Path) -> Footage:
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InputError(str(folder), "has no images (.jpg, .png, .tif)", "give a folder of the drone's photos or a video file")
    frames, sizes, no_offset = [], set(), 0
    for p in files:
        t, has_off, size = _exif_time(p)
        if t is None:
            raise InputError(str(p), "has no EXIF DateTimeOriginal (no capture time)", "import needs the camera's capture times; use the original files")
        no_offset += not has_off
        sizes.add(size)
        frames.append(FootageFrame(t, p.name, path=p))
    if len(sizes) > 1:
        raise InputError(str(folder), f"images of {len(sizes)} different sizes {sorted(sizes)}", "import one camera's images at one resolution")
    frames.sort(key=lambda f: f.t_camera_s)
    t = np.array([f.t_camera_s for f in frames])
    if len(t) > 1 and np.all(np.diff(t) == 0):
        raise InputError(str(folder), "every image has the same capture time", "the EXIF times must tell the frames apart")
    w, h = sizes.pop()
    note = "EXIF DateTimeOriginal + SubSecTimeOriginal + OffsetTimeOriginal"
    if no_offset:
        note += f" ({no_offset} image(s) without OffsetTimeOriginal: taken as UTC)"
    return Footage(folder, "images", frames, w, h, note)


def _video_creation_time(path: Path) -> float | None:
    try:
        import av
    except ImportError:
        return None
    try:
        with av.open(str(path)) as c:
            meta = dict(c.metadata)
            for s in c.streams.video:
                meta.update({k: v for k, v in s.metadata.items() if k not in meta})
    except Exception:
        return None
    text = meta.get("creation_time")
    if not text:
        return None
    try:
        return parse_utc(text)
    except InputError:
        return None


def _video(path: Path, video_start: str | None) -> Footage:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(str(path), "the video decoder refuses the file", "a video OpenCV/FFmpeg can read")
    times: list[float] = []
    w = h = 0
    try:
        while cap.grab():
            times.append(cap.get(cv2.CAP_PROP_POS_MSEC) * 1e-3)
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    finally:
        cap.release()
    if not times or w <= 0 or h <= 0:
        raise InputError(str(path), "the video decoder found no frames", "a video OpenCV/FFmpeg can read")
    if video_start is not None:
        start, note = parse_utc(video_start), f"--video-start {video_start} + container frame times"
    else:
        start = _video_creation_time(path)
        if start is None:
            raise InputError(str(path), "the video has no creation time", "give --video-start UTC (when the recording started)")
        note = "container creation_time + frame times"
    t = np.asarray(times)
    if len(t) > 1 and not np.all(np.diff(t) > 0):  # a container without usable timestamps
        fps = cv2.VideoCapture(str(path)).get(cv2.CAP_PROP_FPS)
        if not fps or fps <= 0:
            raise InputError(str(path), "the video's frame times are not increasing and it states no frame rate", "re-mux the video")
        t = np.arange(len(t)) / fps
        note += " (frame rate; the container's times were not increasing)"
    t = t - t[0]
    frames = [FootageFrame(float(start + ti), f"{path.name}#{k}", video_index=k) for k, ti in enumerate(t)]
    return Footage(path, "video", frames, w, h, note)


def open_footage(path: str | Path, *, video_start: str | None = None) -> Footage:
    path = Path(path)
    if not path.exists():
        raise InputError(str(path), "not found", "give a folder of images or a video file")
    if path.is_dir():
        if video_start is not None:  # each image carries its own time: a start time would be ignored in silence
            raise InputError(f"--video-start {video_start}", f"given with a folder of images ({path})",
                             "leave it out: each image's EXIF time is used (--time-offset moves them all)")
        return _images(path)
    if path.suffix.lower() in IMAGE_SUFFIXES:
        raise InputError(str(path), "is one image", "give the folder of images")
    return _video(path, video_start)


def resample(frames: list[FootageFrame], rate_hz: float = 10.0) -> list[FootageFrame]:
    """The frames nearest to a ``rate_hz`` grid over the footage (each at most once, within half a
    period); slower footage is kept whole."""
    if len(frames) < 2:
        return list(frames)
    t = np.array([f.t_camera_s for f in frames])
    period = 1.0 / rate_hz
    if np.median(np.diff(t)) >= period * 0.95:
        return list(frames)
    grid = np.arange(t[0], t[-1] + period / 2, period)
    idx = np.clip(np.searchsorted(t, grid), 1, len(t) - 1)
    left, right = t[idx - 1], t[idx]
    nearest = np.where(grid - left <= right - grid, idx - 1, idx)
    ok = np.abs(t[nearest] - grid) <= period / 2
    keep = sorted(set(nearest[ok].tolist()))
    return [frames[i] for i in keep]


def write_drone_footage(sweep_dir: str | Path, out_dir: str | Path, *, clock_offset_s: float, utc_offset_h: float = 0.0,
                        quality: int = 92) -> int:
    """Write a sweep's frames as JPEGs carrying only what a drone's camera writes: EXIF
    DateTimeOriginal / SubSecTimeOriginal / OffsetTimeOriginal (local time at ``utc_offset_h``) of
    the frame's UTC plus ``clock_offset_s`` (a camera clock that is off). Returns the count."""
    from PIL import Image

    from inspect_pipe.capture._sweep import read_sweep

    sw = read_sweep(sweep_dir)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tz = _dt.timezone(_dt.timedelta(hours=utc_offset_h))
    sign = "+" if utc_offset_h >= 0 else "-"
    mins = int(round(abs(utc_offset_h) * 60))
    off_text = f"{sign}{mins // 60:02d}:{mins % 60:02d}"
    n = 0
    for f in sw.frames:
        if f.t_utc is None:
            raise InputError(str(sw.path), f"frame {f.index} has no t_utc", "a sweep written by capture or fly --sweep")
        t = parse_utc(f.t_utc, str(sw.path)) + clock_offset_s
        local = _dt.datetime.fromtimestamp(t, tz)
        why = truncation(f.image_path)
        img = None if why else imread(str(f.image_path), cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(str(f.image_path), why or "cannot decode the image")
        pil = Image.fromarray(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
        exif = Image.Exif()
        exif[0x010F] = "SimDrone"  # Make
        exif[0x0110] = "inspect-pipe simulated camera"  # Model
        ifd = exif.get_ifd(EXIF_IFD)
        ifd[DATETIME_ORIGINAL] = local.strftime("%Y:%m:%d %H:%M:%S")
        ifd[SUBSEC_TIME_ORIGINAL] = f"{local.microsecond:06d}"
        ifd[OFFSET_TIME_ORIGINAL] = off_text
        pil.save(out / f"DJI_{f.index + 1:04d}.JPG", "JPEG", quality=quality, exif=exif)
        n += 1
    return n
