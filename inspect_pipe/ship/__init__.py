"""Ship geometry, pure: the survey plan, the hold's walls and their frames, and where a point is in
ship terms (frame number, distance from the centreline, height above the tank top). Used by
capture/import (the plan stored in the sweep), the mosaic (odometry -> wall coordinates) and the
report (locations). See ``docs/ship.md``."""

from ._location import Location, ShipFrames, hold_from_takeoff, locate, plan_wall_frame
from ._plan import FORMAT, SurveyPlan, imo_check_digit_ok, load_survey_plan, parse_survey_plan
from ._walls import SIM_WALLS, Wall, WallFrame, wall_frame

__all__ = [
    "FORMAT",
    "Location",
    "SIM_WALLS",
    "ShipFrames",
    "SurveyPlan",
    "Wall",
    "WallFrame",
    "hold_from_takeoff",
    "imo_check_digit_ok",
    "load_survey_plan",
    "locate",
    "parse_survey_plan",
    "plan_wall_frame",
    "wall_frame",
]
