"""The register from a run with known geometry: wall coordinates, sizes, ship terms, status round trip."""

from __future__ import annotations

import csv
import json
import os
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.errors import InputError
from inspect_pipe.report import CoverageParams, ReportParams, read_register, report_from_run, write_report

from .conftest import CRACK, make_run

runner = CliRunner()


def _report(store, out, **kw):
    kw.setdefault("coverage", CoverageParams(max_m_per_px=0.01))  # the fixture's 5 mm/px frames count as usable
    rep = report_from_run(store, out, ReportParams(pdf=False, **kw))
    write_report(rep, out, log=lambda s: None)
    return json.loads((out / "defects.json").read_text())


def test_defects_located_in_wall_metres_with_area_length_and_ship_frames(run_dir, tmp_path):
    # GIVEN a corrosion rectangle of 40 x 20 px and a 100 px crack at 5 mm per px
    doc = _report(run_dir, tmp_path / "rep")
    by = {d["class"]: d for d in doc["defects"]}
    c, k = by["corrosion"], by["crack"]
    # THEN the centroid is where the map puts pixel (119.5, 69.5), to 1 mm
    assert c["centroid_wall_m"] == pytest.approx([3.0 + 119.5 * 0.005, 3.0 - 69.5 * 0.005], abs=1e-3)
    assert c["area_m2"] == pytest.approx(800 * 0.005**2, rel=0.01)
    true_len = sum(np.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(CRACK, CRACK[1:])) * 0.005  # 0.514 m
    assert k["length_m"] == pytest.approx(true_len, rel=0.08)  # the skeleton's 8-neighbour steps run long on slanted stretches
    # wall u 3.48..3.70 m, 0.8 m frame spacing from Fr. 112 at u = 0: frame space 116
    assert c["frame_range"] == "Fr. 116-117"
    assert c["height_above_tank_top_m"] == pytest.approx(c["centroid_wall_m"][1], abs=1e-6)
    assert c["status"] == "suggested" and c["id"].startswith("D")
    # the frames whose footprint holds the centroid (frames 0 at x 0..200, y 0..150)
    assert c["frames"] == [0]
    assert len(c["polygon_wall_m"]) >= 4
    assert doc["wall_rating"]["rating"] in ("GOOD", "FAIR", "POOR")
    assert (tmp_path / "rep" / c["crop"]).is_file() and (tmp_path / "rep" / c["context"]).is_file()
    coco = json.loads((tmp_path / "rep" / "coco.json").read_text())
    assert {a["category_id"] for a in coco["annotations"]} == {1, 2}


def test_status_set_by_surveyor_survives_a_later_run(run_dir, tmp_path):
    out = tmp_path / "rep"
    doc = _report(run_dir, out)
    ids = {d["class"]: d["id"] for d in doc["defects"]}
    # WHEN the surveyor confirms the corrosion and rejects the crack in the CSV
    rows = list(csv.DictReader(open(out / "defects.csv")))
    for r in rows:
        r["status"] = "confirmed" if r["class"] == "corrosion" else "rejected"
        r["note"] = "checked on site" if r["class"] == "corrosion" else ""
    time.sleep(0.01)
    with open(out / "defects.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=rows[0].keys())
        w.writeheader()
        w.writerows(rows)
    os.utime(out / "defects.csv", (time.time() + 5, time.time() + 5))
    # THEN a new report keeps ids, statuses and notes, in JSON and CSV
    doc2 = _report(run_dir, out)
    by = {d["id"]: d for d in doc2["defects"]}
    assert by[ids["corrosion"]]["status"] == "confirmed" and by[ids["corrosion"]]["note"] == "checked on site"
    assert by[ids["crack"]]["status"] == "rejected"
    again = read_register(out / "defects.json", out / "defects.csv")
    assert {d.id: d.status for d in again} == {ids["corrosion"]: "confirmed", ids["crack"]: "rejected"}
    # rejected entries leave the COCO export
    coco = json.loads((out / "coco.json").read_text())
    assert [a["attributes"]["defect_id"] for a in coco["annotations"]] == [ids["corrosion"]]


def test_unknown_status_edited_by_hand_is_a_one_line_error_and_nothing_is_lost(run_dir, tmp_path):
    out = tmp_path / "rep"
    _report(run_dir, out)
    doc = json.loads((out / "defects.json").read_text())
    doc["defects"][0]["status"] = "maybe"
    (out / "defects.json").write_text(json.dumps(doc))
    os.utime(out / "defects.csv", (1, 1))  # the JSON is the newer edit
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    res = runner.invoke(app, ["report", str(run_dir.root), "-o", str(out), "--no-pdf"])
    assert res.exit_code == 2
    line = res.output.strip().splitlines()[-1]
    assert "defects.json" in line and "status'" in line and "maybe" in line
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


def test_unknown_status_in_csv_names_the_line(run_dir, tmp_path):
    out = tmp_path / "rep"
    _report(run_dir, out)
    text = (out / "defects.csv").read_text().replace(",suggested,", ",fixed,", 1)
    (out / "defects.csv").write_text(text)
    with pytest.raises(InputError, match=r"defects.csv: line 2 .*'status' is 'fixed'"):
        read_register(out / "defects.json", out / "defects.csv")


@pytest.mark.parametrize("spacing", [0, -0.8, "eight", 50])
def test_bad_frame_spacing_in_survey_is_a_one_line_error(tmp_path, spacing):
    store = make_run(tmp_path / "run", survey={"frame_spacing_m": spacing, "reference_frame": 112})
    res = runner.invoke(app, ["report", str(store.root), "-o", str(tmp_path / "rep"), "--no-pdf"])
    assert res.exit_code == 2
    line = res.output.strip().splitlines()[-1]
    assert "sweep.json" in line and "survey.frame_spacing_m" in line
    assert not (tmp_path / "rep" / "defects.json").exists()


def test_missing_step_output_names_the_file(run_dir, tmp_path):
    (run_dir.detect_dir / "defects.json").unlink()
    res = runner.invoke(app, ["report", str(run_dir.root), "-o", str(tmp_path / "rep"), "--no-pdf"])
    assert res.exit_code == 2
    assert "detect/defects.json: missing" in res.output
    (run_dir.mosaic_dir / "mosaic.json").unlink()
    res = runner.invoke(app, ["report", str(run_dir.root), "-o", str(tmp_path / "rep"), "--no-pdf"])
    assert res.exit_code == 2 and "mosaic.json: missing" in res.output
