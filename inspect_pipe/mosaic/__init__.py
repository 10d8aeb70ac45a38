"""Homography mosaicing of a wall sweep (pure cores; file adapters in ``_io``).

``run_mosaic(source, out_dir)`` is the step; ``register`` and ``render`` are the array-level
cores that tests drive directly.
"""

from ._align import AlignParams
from ._blend import BlendParams, render
from ._features import DETECTORS, detect_features
from ._homography import MatchParams, match_pair
from ._io import FolderSource, read_image
from ._live import LiveMosaic, LiveParams, Placement
from ._live_feed import LiveFeed, LiveStatus
from ._mosaic import FORMAT, MosaicOutput, MosaicParams, run_mosaic, run_mosaic_sweep
from ._folder_input import UndistortedFolderSource, run_mosaic_folder
from ._sweep_input import SweepSource, WallGeometry, is_sweep, wall_geometry
from ._register import FrameError, FrameSource, Group, Registration, RegisterParams, register

__all__ = [
    "AlignParams", "BlendParams", "DETECTORS", "FORMAT", "FolderSource", "FrameError", "FrameSource",
    "Group", "LiveFeed", "LiveMosaic", "LiveParams", "LiveStatus", "MatchParams", "MosaicOutput", "MosaicParams", "Placement", "Registration", "RegisterParams",
    "SweepSource", "WallGeometry", "detect_features", "is_sweep", "match_pair", "read_image", "register",
    "render", "run_mosaic", "run_mosaic_folder", "run_mosaic_sweep", "UndistortedFolderSource", "wall_geometry",
]
