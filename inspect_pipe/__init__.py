"""inspect_pipe: supervised-autonomy MAV inspection of cargo holds.

Packages: ``flight_stack`` (onboard, tick-based), ``flight`` (simulator, links, scenarios),
``capture`` (cameras and sweeps), ``mosaic`` (homography mosaicing), ``saliency_defects``
(defect detection), ``report`` (survey report).
"""

from importlib.metadata import PackageNotFoundError, version as _dist_version

try:  # the installed distribution's version (pyproject.toml), one source of truth
    __version__ = _dist_version("inspect-pipe")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
__all__ = ["__version__"]
