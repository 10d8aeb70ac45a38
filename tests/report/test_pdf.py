"""report.pdf rendered to PNG (pdftoppm): pages not blank, the register in it; coverage map."""

from __future__ import annotations

import json
import shutil
import subprocess

import cv2
import numpy as np
import pytest

from inspect_pipe.report import CoverageParams, ReportParams, report_from_run, write_report
from inspect_pipe.report._render import render_html

from .conftest import make_run


def _weasyprint_ok() -> str | None:
    from inspect_pipe.report._render import render_pdf

    try:
        import weasyprint  # noqa: F401
    except (ImportError, OSError) as err:
        return f"WeasyPrint unusable here: {err}"
    return None


def _pdf_ready(tool: str, run_dir, tmp_path):
    """(report of the test run, its output folder), or a skip naming what this machine lacks."""
    if shutil.which(tool) is None:
        pytest.skip(f"{tool} absent (make test installs poppler-utils where apt works)")
    why = _weasyprint_ok()
    if why:
        pytest.skip(why)
    out = tmp_path / "rep"
    return report_from_run(run_dir, out, ReportParams(coverage=CoverageParams(max_m_per_px=0.01))), out


def test_pdf_pages_are_not_blank_and_hold_the_register(run_dir, tmp_path):
    rep, out = _pdf_ready("pdftoppm", run_dir, tmp_path)
    written = write_report(rep, out, log=lambda s: None)
    assert written["pdf"] == out / "report.pdf"
    subprocess.run(["pdftoppm", "-r", "40", "-png", str(out / "report.pdf"), str(tmp_path / "page")], check=True)
    pages = sorted(tmp_path.glob("page*.png"))
    assert pages
    for p in pages:
        g = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        assert (g < 200).mean() > 0.005, f"{p.name} is blank"
    ids = [d["id"] for d in json.loads((out / "defects.json").read_text())["defects"]]
    if shutil.which("pdftotext"):
        text = subprocess.run(["pdftotext", str(out / "report.pdf"), "-"], capture_output=True, text=True, check=True).stdout
        assert "Defect register" in text and all(i in text for i in ids)
        assert "MSC.1/Circ.1330" in text and "Breakdown" in text


def test_pdf_unavailable_degrades_with_a_clear_message(run_dir, tmp_path, monkeypatch):
    import builtins

    real = builtins.__import__

    def no_weasy(name, *a, **k):
        if name == "weasyprint":
            raise ImportError("No module named 'weasyprint'")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_weasy)
    msgs = []
    rep = report_from_run(run_dir, tmp_path / "rep", ReportParams())
    written = write_report(rep, tmp_path / "rep", log=msgs.append)
    assert written["pdf"] is None and (tmp_path / "rep" / "report.html").is_file()
    assert "report.pdf not written" in msgs[0] and "inspect-pipe[report]" in msgs[0]


def test_coverage_marks_gaps_and_low_resolution(run_dir, tmp_path):
    # the fixture's frames are 5 mm/px: with a 3 mm/px limit nothing is usable, all is gap
    rep = report_from_run(run_dir, tmp_path / "a", ReportParams(pdf=False))
    assert rep.coverage.usable_fraction == 0.0 and rep.coverage.imaged.mean() > 0.95
    assert all("mm/px" in f.reason for f in rep.coverage.frames)
    rep = report_from_run(run_dir, tmp_path / "b", ReportParams(pdf=False, coverage=CoverageParams(max_m_per_px=0.01),
                                                                region_wall_m=(3.0, 0.65, 6.0, 3.0)))
    # frames cover u 3.0..5.6, v 1.65..3.0 of a 3.0 x 2.35 m region
    expected = (2.6 * 1.35) / (3.0 * 2.35)
    assert rep.coverage.usable_fraction == pytest.approx(expected, abs=0.01)
    assert rep.coverage.gaps and rep.coverage.gaps[0]["area_m2"] == pytest.approx(3.0 * 2.35 - 2.6 * 1.35, rel=0.02)


def test_a_long_register_keeps_each_row_whole_and_repeats_its_header(run_dir, tmp_path):
    import dataclasses

    # GIVEN a register of 45 entries (the run's entries repeated under new ids): several pages
    rep, out = _pdf_ready("pdftotext", run_dir, tmp_path)
    assert rep.defects
    many = [dataclasses.replace(rep.defects[k % len(rep.defects)], id=f"R{k:03d}", note=f"Q{k:03d}")
            for k in range(45)]
    write_report(dataclasses.replace(rep, defects=many), out, log=lambda s: None)
    text = subprocess.run(["pdftotext", "-layout", str(out / "report.pdf"), "-"], capture_output=True, text=True,
                          check=True).stdout
    pages = text.split("\f")
    # (the notes are printed in the register's status cells only; ids also head the crops)
    reg = [p for p in pages if any(f"Q{k:03d}" in p for k in range(45))]
    # THEN the register runs over more than one page, every page of it repeats the header,
    assert len(reg) >= 2
    assert all("Conf." in p and "Class" in p for p in reg)
    # AND each row's last line (the note in its status cell) is on a page that holds its id: no row is split
    for k in range(45):
        where_note = [i for i, p in enumerate(pages) if f"Q{k:03d}" in p]
        assert len(where_note) == 1 and f"R{k:03d}" in pages[where_note[0]], (k, where_note)


def test_frames_in_a_separate_mosaic_are_named_not_left_out_in_silence(run_dir, tmp_path):
    # GIVEN a run whose mosaic step also wrote a second, separate mosaic of 3 frames (no pair tied it to the main one)
    import json

    doc = json.loads((run_dir.mosaic_dir / "mosaic.json").read_text())
    doc["frames"] += [{"index": 10 + k, "file": f"images/x{k}.png", "H": [[1, 0, 40 * k], [0, 1, 0], [0, 0, 1]], "group": 1,
                       "image": "mosaic_group1.png"} for k in range(3)]
    (run_dir.mosaic_dir / "mosaic.json").write_text(json.dumps(doc))
    logged = []
    rep = report_from_run(run_dir, tmp_path / "r", ReportParams(pdf=False))
    write_report(rep, tmp_path / "r", log=logged.append)
    # THEN the report says which frames it did not inspect, at the top and under Coverage, and so do its files and log
    html = (tmp_path / "r" / "report.html").read_text()
    assert "separate mosaic: 3 placed frames (10-12) form mosaic_group1.png" in html
    assert 'id="separate"' in html and "3 frames (10-12) form mosaic_group1.png" in html
    cov = json.loads((tmp_path / "r" / "coverage.json").read_text())
    assert cov["separate_mosaics"] == [{"group": 1, "image": "mosaic_group1.png", "n_frames": 3, "frames": [10, 11, 12]}]
    reg = json.loads((tmp_path / "r" / "defects.json").read_text())
    assert reg["traceability"]["separate_mosaics"] == [{"group": 1, "image": "mosaic_group1.png", "n_frames": 3}]
    assert any("3 placed frames in 1 separate mosaic(s) (mosaic_group1.png) are not inspected" in m for m in logged)
    # AND a run with one mosaic says nothing of the kind
    rep = report_from_run(make_run(tmp_path / "one"), tmp_path / "r1", ReportParams(pdf=False))
    assert rep.separate == [] and "separate mosaic" not in render_html(rep, {"overlay": "", "coverage": ""})
