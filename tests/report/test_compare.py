"""inspect-pipe compare: two surveys of one wall registered on the wall, their registers matched,
new / grown / unchanged told apart; different walls and a run without a register refused."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.pipeline import RunStore
from inspect_pipe.pipeline._store import write_json
from inspect_pipe.report import CoverageParams, ReportParams, report_from_run, write_report
from inspect_pipe.report._compare import CompareParams, classify

from .conftest import make_run

runner = CliRunner()


def _register(store: RunStore) -> None:
    rep = report_from_run(store, store.report_dir, ReportParams(pdf=False, coverage=CoverageParams(max_m_per_px=0.01)))
    write_report(rep, store.report_dir, log=lambda s: None)


def _second_survey(src: RunStore, root: Path, *, shift_m=(0.012, -0.008)) -> RunStore:
    """The same wall flown again: the odometry placed the mosaic 1.2 cm right and 0.8 cm low; the
    corrosion rectangle grew from 40 x 20 to 56 x 34 px; a new 30 x 30 px patch appeared."""
    shutil.copytree(src.root, root, ignore=shutil.ignore_patterns("report"))
    store = RunStore(root)
    doc = json.loads((store.mosaic_dir / "mosaic.json").read_text())
    W = np.asarray(doc["wall_from_mosaic"], float)
    W[0, 2] += shift_m[0]
    W[1, 2] += shift_m[1]
    doc["wall_from_mosaic"] = W.tolist()
    write_json(store.mosaic_dir / "mosaic.json", doc)
    corr = store.load_class_map("mosaic", "corrosion", "mask")
    corr[52:86, 92:148] = 255
    corr[80:110, 400:430] = 255
    store.save_class_map("mosaic", "corrosion", "mask", corr)
    store.save_class_map("mosaic", "corrosion", "prob", np.where(corr > 0, 240, 10).astype(np.uint8))
    return store


@pytest.fixture(scope="module")
def surveys(tmp_path_factory):
    root = tmp_path_factory.mktemp("cmp")
    old = make_run(root / "old", painted=True)
    _register(old)
    new = _second_survey(old, root / "new")
    _register(new)
    return old, new


def test_new_and_grown_defects_are_found_and_the_rest_is_unchanged(surveys, tmp_path):
    old, new = surveys
    r = runner.invoke(app, ["compare", str(old.root), str(new.root), "-o", str(tmp_path / "out"), "--no-pdf"])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "out" / "changes.json").read_text())
    assert doc["format"] == "inspect_pipe.changes/1"
    by = {}
    for e in doc["entries"]:
        by.setdefault(e["status"], []).append(e)
        assert set(e) >= {"status", "old_id", "new_id", "centroid_wall_m", "area_old_m2", "area_new_m2"}
    assert sorted(by) == ["grown", "new", "unchanged"], doc["entries"]
    (new_,), (grown,), (same,) = by["new"], by["grown"], by["unchanged"]
    # the new patch at mosaic px (414.5, 94.5) of the old survey's wall map: u 5.07, v 2.53
    assert new_["centroid_wall_m"] == pytest.approx([3.0 + 414.5 * 0.005, 3.0 - 94.5 * 0.005], abs=0.01)
    assert new_["old_id"] is None and new_["area_new_m2"] == pytest.approx(900 * 0.005**2, rel=0.05)
    assert grown["area_old_m2"] == pytest.approx(800 * 0.005**2, rel=0.05) and grown["area_new_m2"] == pytest.approx(56 * 34 * 0.005**2, rel=0.05)
    assert grown["old_id"] and grown["new_id"] and same["old_id"] and same["new_id"]
    # grown/shrunk is judged on the probability-weighted area over the place, which the fixture's
    # 0.94 inside / 0.04 outside maps make close to the mask areas
    assert grown["prob_area_new_m2"] > 2 * grown["prob_area_old_m2"] and abs(same["prob_area_new_m2"] - same["prob_area_old_m2"]) < 1e-4
    # the 1.2 cm / 0.8 cm odometry offset of the second survey is taken out by the image refinement
    reg = doc["registration"]
    assert reg["inliers"] >= 40 and reg["shift_m"] == pytest.approx(np.hypot(0.012, 0.008), abs=0.004)
    html = (tmp_path / "out" / "report.html").read_text()
    assert "change_map.png" in html and "crops/C1.png" in html
    assert cv2.imread(str(tmp_path / "out" / "change_map.png")) is not None
    crop = cv2.imread(str(tmp_path / "out" / "crops" / "C1.png"))
    assert crop is not None and crop.shape[1] > crop.shape[0]  # old | new side by side


def test_two_runs_of_different_walls_one_line_exit_2_nothing_written(surveys, tmp_path):
    old, _ = surveys
    other = make_run(tmp_path / "other", seed=7, painted=True)  # another wall, same place in wall coordinates
    _register(other)
    out = tmp_path / "out"
    r = runner.invoke(app, ["compare", str(old.root), str(other.root), "-o", str(out)])
    assert r.exit_code == 2 and not out.exists()
    line = r.output.strip()
    assert line.count("\n") == 0 and line.startswith("error:") and "two different walls" in line and "image features" in line
    # other survey identities: refused before any image work
    other2 = make_run(tmp_path / "other2", survey={"vessel": "MV Other", "hold": "2", "wall": "front"}, painted=True)
    _register(other2)
    r = runner.invoke(app, ["compare", str(old.root), str(other2.root), "-o", str(out)])
    assert r.exit_code == 2 and "survey vessel 'MV Test' and 'MV Other'" in r.output and not out.exists()


def test_run_without_a_register_one_line_exit_2(surveys, tmp_path):
    old, _ = surveys
    bare = make_run(tmp_path / "bare")  # mosaic and detections, no report
    out = tmp_path / "out"
    r = runner.invoke(app, ["compare", str(old.root), str(bare.root), "-o", str(out)])
    assert r.exit_code == 2 and not out.exists()
    assert "report/defects.json: missing: the run has no register" in r.output and r.output.strip().count("\n") == 0


def test_area_change_within_the_noise_is_unchanged():
    p = CompareParams(noise_abs_m2=4e-4, noise_rel=0.20)
    assert classify(0.0100, 0.0120, p) == "unchanged"  # +20 cm²: within 4 cm² + 20 % of 120 cm²
    assert classify(0.0100, 0.0135, p) == "grown"  # +35 cm²: beyond 4 + 27 cm²
    assert classify(0.0100, 0.0050, p) == "shrunk"
    assert classify(0.0, 0.002, p) == "new" and classify(0.002, 0.0, p) == "gone"


def test_a_folder_mosaic_without_wall_coordinates_is_refused(surveys, tmp_path):
    old, _ = surveys
    folder = make_run(tmp_path / "folder", painted=True)
    _register(folder)
    doc = json.loads((folder.mosaic_dir / "mosaic.json").read_text())
    del doc["wall_from_mosaic"]
    write_json(folder.mosaic_dir / "mosaic.json", doc)
    r = runner.invoke(app, ["compare", str(old.root), str(folder.root), "-o", str(tmp_path / "out")])
    assert r.exit_code == 2 and "no wall coordinates" in r.output and not (tmp_path / "out").exists()


def _flown_again(src: RunStore, root: Path, edit) -> RunStore:
    """The same wall flown again, 1.2 cm / 0.8 cm off in odometry; ``edit(mosaic, corr_mask, corr_prob)``
    changes what that flight saw (in place) before its register is drawn."""
    shutil.copytree(src.root, root, ignore=shutil.ignore_patterns("report"))
    store = RunStore(root)
    doc = json.loads((store.mosaic_dir / "mosaic.json").read_text())
    W = np.asarray(doc["wall_from_mosaic"], float)
    W[0, 2] += 0.012
    W[1, 2] -= 0.008
    doc["wall_from_mosaic"] = W.tolist()
    write_json(store.mosaic_dir / "mosaic.json", doc)
    mosaic = cv2.imread(str(store.mosaic_dir / "mosaic.png"), cv2.IMREAD_UNCHANGED)
    corr = store.load_class_map("mosaic", "corrosion", "mask")
    prob = store.load_class_map("mosaic", "corrosion", "prob")
    edit(mosaic, corr, prob)
    cv2.imwrite(str(store.mosaic_dir / "mosaic.png"), mosaic)
    store.save_class_map("mosaic", "corrosion", "mask", corr)
    store.save_class_map("mosaic", "corrosion", "prob", prob)
    _register(store)
    return store


def _compare(old: RunStore, new: RunStore, out: Path) -> tuple[dict, str]:
    r = runner.invoke(app, ["compare", str(old.root), str(new.root), "-o", str(out), "--no-pdf"])
    assert r.exit_code == 0, r.output
    return json.loads((out / "changes.json").read_text()), r.output


@pytest.mark.parametrize("prob_there, status", [(200, "unchanged"), (10, "gone")])
def test_a_patch_one_flight_leaves_out_is_gone_only_where_its_map_no_longer_shows_it(surveys, tmp_path, prob_there, status):
    # GIVEN a second flight whose detection leaves the 200 cm² corrosion patch out of its register:
    # its map still shows it a little below the operating point (200 against 240: a faint patch
    # flown again, the detector's flight-to-flight spread), or no longer at all (10: repainted)
    old, _ = surveys
    x, y, w, h = 100, 60, 40, 20

    def edit(mosaic, corr, prob):
        corr[y:y + h, x:x + w] = 0
        prob[y:y + h, x:x + w] = prob_there

    new = _flown_again(old, tmp_path / "new", edit)
    # WHEN the two surveys are compared
    doc, _ = _compare(old, new, tmp_path / "out")
    corr = [e for e in doc["entries"] if e["class"] == "corrosion"]
    # THEN it is gone only when the new map no longer shows it; else unchanged, and the note says why
    assert [e["status"] for e in corr] == [status], corr
    if status == "unchanged":
        assert corr[0]["new_id"] is None and "below the register's limits" in corr[0]["note"]
        assert corr[0]["prob_area_new_m2"] == pytest.approx(200 / 240 * corr[0]["prob_area_old_m2"], rel=0.1)
    assert doc["counts"]["gone"] == (status == "gone")


@pytest.mark.parametrize("cut_px, expect", [(120, "unchanged"), (95, "not compared")])
def test_a_defect_at_the_edge_of_one_surveys_coverage_is_compared_on_the_wall_both_imaged(surveys, tmp_path, cut_px, expect):
    # GIVEN a second flight with a gap in its coverage from mosaic column ``cut_px`` to 200 (rows 30-110):
    # the 40 px wide corrosion patch (columns 100-139, rows 60-79) half in the gap, or all but its first 5 px
    old, _ = surveys

    def edit(mosaic, corr, prob):
        for m in (mosaic[:, :, 3], corr, prob):
            m[30:110, cut_px:200] = 0

    new = _flown_again(old, tmp_path / "new", edit)
    doc, output = _compare(old, new, tmp_path / "out")
    corr = [e for e in doc["entries"] if e["class"] == "corrosion"]
    assert ("1 not compared" in output) == (expect == "not compared"), output
    if expect == "unchanged":
        # THEN half the patch is not "shrunk": its weighted areas are summed where both surveys imaged the wall
        assert [e["status"] for e in corr] == ["unchanged"], corr
        assert corr[0]["area_new_m2"] == pytest.approx(corr[0]["area_old_m2"] / 2, rel=0.2)  # the register's own area halved
        assert corr[0]["prob_area_new_m2"] == pytest.approx(corr[0]["prob_area_old_m2"], rel=0.1)
    else:
        # THEN a patch the new survey did not image is neither gone nor unchanged: not compared, and said so
        assert corr == [] and doc["counts"]["gone"] == 0
        (nc,) = [e for e in doc["not_compared"] if e["class"] == "corrosion"]
        assert nc["old_id"] and "not compared" in nc["note"] and "both surveys imaged" in nc["note"]
        assert nc["status"] == "gone"  # what the registers alone say; the note says why it is no verdict
