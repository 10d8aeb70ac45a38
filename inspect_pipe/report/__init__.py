"""The surveyor's report: defect register in wall metres and ship terms, coating rating by IMO
MSC.1/Circ.1330 Table 1 (or MSC.1/Circ.1399), coverage and gaps; HTML, PDF, CSV, JSON, COCO.

    report = report_from_run(RunStore(run_dir), out_dir, ReportParams())
    write_report(report, out_dir)
"""

from ._coverage import Coverage, CoverageParams, FrameQuality, WallGrid, compute_coverage, sharpness
from ._geo import Survey, WallMap, frame_footprint_px, parse_survey
from ._rating import FAIR, GOOD, NOT_RATED, POOR, SCHEMES, AreaRating, RatingParams, RatingScheme, WallRating, rate_wall
from ._register import (
    CSV_COLUMNS, REGISTER_FORMAT, STATUSES, Defect, FrameView, KeyframeDetection, RegisterParams, assign_ids,
    build_defects, merged_masks, read_csv_status, read_register, register_csv, register_json,
)
from ._report import REPORT_FORMAT, Report, ReportInputs, ReportParams, build_report, load_previous, report_from_run, write_report

__all__ = [
    "AreaRating", "CSV_COLUMNS", "Coverage", "CoverageParams", "Defect", "FAIR", "FrameQuality", "FrameView", "GOOD",
    "KeyframeDetection", "NOT_RATED", "POOR", "REGISTER_FORMAT", "REPORT_FORMAT", "RatingParams", "RatingScheme",
    "RegisterParams", "Report", "ReportInputs", "ReportParams", "SCHEMES", "STATUSES", "Survey", "WallGrid", "WallMap",
    "WallRating", "assign_ids", "build_defects", "build_report", "compute_coverage", "frame_footprint_px", "load_previous",
    "merged_masks", "parse_survey", "rate_wall", "read_csv_status", "read_register", "register_csv", "register_json",
    "report_from_run", "sharpness", "write_report",
]
