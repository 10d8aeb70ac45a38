"""Footage and flight logs from any drone, afterwards (``inspect-pipe import``; docs/import.md).

- :func:`read_flight_log`: a PX4 ULog, ArduPilot DataFlash ``.bin`` or MAVLink ``.tlog`` as a
  :class:`FlightTrack` (pyulog, pymavlink).
- :func:`open_footage`: a folder of images (EXIF capture times) or a video (container times).
- :func:`find_offset`: the camera clock offset from image motion against the logged motion.
- :func:`import_footage`: all of it into a sweep (``inspect_pipe.sweep/1``).
- :func:`write_drone_footage`: a sweep's frames as a drone's JPEGs, camera clock shifted (tests, bench).
"""

from inspect_pipe.importer._align import Alignment, find_offset, image_motion
from inspect_pipe.importer._footage import Footage, FootageFrame, open_footage, resample, write_drone_footage
from inspect_pipe.importer._import import ImportResult, frame_states, import_footage
from inspect_pipe.importer._logs import FlightTrack, read_flight_log

__all__ = [
    "Alignment", "FlightTrack", "Footage", "FootageFrame", "ImportResult", "find_offset", "frame_states", "image_motion",
    "import_footage", "open_footage", "read_flight_log", "resample", "write_drone_footage",
]
