"""inspect_pipe: supervised-autonomy MAV inspection of cargo holds.

Packages: ``flight_stack`` (onboard, tick-based), ``flight`` (simulator, links, scenarios),
``capture`` (cameras and sweeps), ``mosaic`` (homography mosaicing), ``saliency_defects``
(defect detection), ``report`` (survey report).
"""

__version__ = "0.1.0"
__all__ = ["__version__"]
