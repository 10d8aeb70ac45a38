"""The review round trip without a browser: the pure edit/audit logic, the HTTP API (starlette's
TestClient), the CLI's bad input, and a later ``inspect-pipe run`` keeping the decisions."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cli.main import app
from inspect_pipe.errors import InputError
from inspect_pipe.report import read_register
from inspect_pipe.report._register import Defect, assign_ids
from inspect_pipe.report._review import (
    AUDIT_FORMAT, Edit, Review, ReviewError, append_audit, apply_edit, audit_record, parse_edit, pending, read_audit,
)

from .conftest import run_args

runner = CliRunner()


def _d(ident: str, cls: str, u: float, v: float, **kw) -> Defect:
    return Defect(id=ident, cls=cls, polygon_wall_m=((u, v), (u + 0.01, v), (u, v + 0.01)), centroid_wall_m=(u, v),
                  bbox_wall_m=(u, v, u + 0.01, v + 0.01), area_m2=1e-3, length_m=None, confidence=0.9, frames=(1,),
                  keyframes_detected=(), keyframes_seen=(), polygon_mosaic_px=((0, 0), (5, 0), (0, 5)),
                  bbox_mosaic_xywh=(0, 0, 5, 5), area_px=12, **kw)


def _snapshot(report: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(report.iterdir()) if p.is_file()}


# ------------------------------------------------------------------------------ pure logic


@pytest.mark.parametrize("doc, message", [
    ([1, 2], "not a JSON object"),
    ({"id": "D001", "field": "status"}, "'value' missing"),
    ({"id": "", "field": "status", "value": "confirmed"}, "'id' missing"),
    ({"id": "D001", "field": "area", "value": "1"}, "field 'field' is 'area'"),
    ({"id": "D001", "field": "status", "value": "ok"}, "status 'ok'"),
    ({"id": "D001", "field": "class", "value": "dent"}, "class 'dent'"),
    ({"id": "D001", "field": "note", "value": "x" * 501}, "note of 501 characters"),
    ({"id": "D001", "field": "note", "value": "a", "by": "me"}, "unknown field 'by'"),
    ({"id": "D001", "field": "note", "value": "pit \ud800"}, "not valid Unicode text"),  # JSON "\ud800": no file holds it
])
def test_a_malformed_edit_is_refused_with_one_line(doc, message):
    with pytest.raises(ReviewError) as err:
        parse_edit(doc)
    assert message in str(err.value) and "\n" not in str(err.value) and err.value.http == 400


def test_an_edit_changes_one_field_and_says_what_was_there_before():
    reg = [_d("D001", "corrosion", 1.0, 1.0), _d("D002", "crack", 2.0, 1.0)]
    out, before = apply_edit(reg, parse_edit({"id": "D002", "field": "status", "value": "rejected"}))
    assert before == "suggested" and [d.status for d in out] == ["suggested", "rejected"] and reg[1].status == "suggested"
    # the same value again: no change
    assert apply_edit(out, Edit("D002", "status", "rejected"))[1] is None
    # a note is kept on one line
    out, before = apply_edit(out, parse_edit({"id": "D001", "field": "note", "value": "pitting,\n  re-check\tnext survey"}))
    assert before == "" and out[0].note == "pitting, re-check next survey"
    # reclassified: the detector's class is kept beside the surveyor's, and dropped when set back
    out, before = apply_edit(out, Edit("D002", "class", "corrosion"))
    assert before == "crack" and (out[1].cls, out[1].detected_cls) == ("corrosion", "crack")
    out, _ = apply_edit(out, Edit("D002", "class", "crack"))
    assert (out[1].cls, out[1].detected_cls) == ("crack", None)
    with pytest.raises(ReviewError) as err:
        apply_edit(out, Edit("D404", "status", "confirmed"))
    assert err.value.http == 404 and "no entry 'D404'" in str(err.value)


def test_a_reclassified_entry_matches_the_detector_again_in_a_later_run():
    # GIVEN a crack the surveyor reclassified as corrosion and rejected, and a confirmed corrosion
    prev = [_d("D001", "corrosion", 1.0, 1.0, status="confirmed"),
            _d("D002", "corrosion", 2.0, 1.0, status="rejected", note="a weld bead", detected_cls="crack")]
    # WHEN the detector finds both again (as a corrosion and a crack, 2 cm away)
    new = [_d("N001", "crack", 2.02, 1.0), _d("N002", "corrosion", 1.01, 1.0)]
    out = {d.id: d for d in assign_ids(new, prev)}
    # THEN they keep their ids, the surveyor's class and decision
    assert sorted(out) == ["D001", "D002"]
    assert (out["D002"].cls, out["D002"].detected_cls, out["D002"].status, out["D002"].note) == ("corrosion", "crack", "rejected", "a weld bead")
    assert (out["D001"].cls, out["D001"].status) == ("corrosion", "confirmed")
    # AND a reclassified entry not found again is kept, not re-detected, even when still suggested
    out = assign_ids([], [replace(prev[1], status="suggested")])
    assert [(d.id, d.cls, d.redetected) for d in out] == [("D002", "corrosion", False)]
    # AND the field survives the register's JSON
    assert Defect.from_json(prev[1].to_json(), "x").detected_cls == "crack"


def test_audit_log_is_appended_and_a_cut_last_line_is_left_out(tmp_path):
    log = tmp_path / "audit.jsonl"
    for k in range(3):
        append_audit(log, audit_record(Edit(f"D00{k}", "status", "confirmed"), "suggested", "J. Smith", "2026-01-01T00:00:00.000Z"))
    with open(log, "ab") as fh:
        fh.write(b'{"format": "inspect_pipe.review_au')  # a crash mid-append
    recs = read_audit(log)
    assert [r["id"] for r in recs] == ["D000", "D001", "D002"]
    assert recs[0] == {"format": AUDIT_FORMAT, "t_utc": "2026-01-01T00:00:00.000Z", "reviewer": "J. Smith", "id": "D000",
                       "field": "status", "before": "suggested", "after": "confirmed"}
    log.write_text('{"id": "D1", "field": "status"}\nnot json\n{"id": "D2", "field": "status"}\n')
    with pytest.raises(InputError, match="line 2: not JSON"):
        read_audit(log)


def test_an_edit_logged_but_not_saved_is_finished_on_open(review_run):
    # GIVEN a crash after the audit line of an edit and before the register was replaced
    _, run = review_run
    rep = run / "report"
    append_audit(rep / "audit.jsonl", audit_record(Edit("D004", "status", "rejected"), "suggested", "J. Smith"))
    # and an older logged edit that a later hand edit overrode (the register no longer shows its 'before')
    append_audit(rep / "audit.jsonl", audit_record(Edit("D005", "note", "old"), "", "J. Smith"))
    doc = json.loads((rep / "defects.json").read_text())
    doc["defects"][4]["note"] = "typed in the CSV later"
    (rep / "defects.json").write_text(json.dumps(doc))
    assert [e.id for e in pending(read_register(rep / "defects.json"), read_audit(rep / "audit.jsonl"))] == ["D004"]
    with open(rep / "audit.jsonl", "ab") as fh:
        fh.write(b'{"format": "inspect_pipe.review_audit/1", "t_u')  # and a later append cut before its fsync
    # WHEN the review opens THEN the register is finished, the hand edit stays, the torn line is cut
    rv = Review.open(rep, "J. Smith")
    assert (rep / "audit.jsonl").read_bytes().endswith(b"}\n") and len(read_audit(rep / "audit.jsonl")) == 2
    rv.apply({"id": "D006", "field": "status", "value": "confirmed"})
    assert [r["id"] for r in read_audit(rep / "audit.jsonl")] == ["D004", "D005", "D006"]
    reg = {d.id: d for d in read_register(rep / "defects.json", rep / "defects.csv")}
    assert reg["D004"].status == "rejected" and reg["D005"].note == "typed in the CSV later"
    assert {d.id: d.status for d in rv.defects}["D004"] == "rejected"


def test_review_writes_the_audit_line_and_both_register_files(review_run):
    _, run = review_run
    rep = run / "report"
    rv = Review.open(rep, "J. Smith")
    rec = rv.apply({"id": "D013", "field": "class", "value": "corrosion"})
    rv.apply({"id": "D013", "field": "status", "value": "confirmed"})
    rv.apply({"id": "D002", "field": "note", "value": "coating breakdown at the weld"})
    assert rv.apply({"id": "D002", "field": "note", "value": "coating breakdown at the weld"}) is None  # no change, no line
    lines = (rep / "audit.jsonl").read_text().splitlines()
    assert len(lines) == 3 and json.loads(lines[0]) == rec
    assert (rec["reviewer"], rec["id"], rec["field"], rec["before"], rec["after"]) == ("J. Smith", "D013", "class", "crack", "corrosion")
    assert rec["t_utc"].endswith("Z") and rec["t_utc"][:2] == "20"
    doc = json.loads((rep / "defects.json").read_text())
    e = next(d for d in doc["defects"] if d["id"] == "D013")
    assert (e["class"], e["detected_class"], e["status"]) == ("corrosion", "crack", "confirmed")
    assert doc["traceability"]["sweep_id"] is None or doc["traceability"]  # the rest of the register is kept
    assert doc["wall_rating"] and doc["format"] == "inspect_pipe.defect_register/1"
    rows = {r.split(",")[0]: r for r in (rep / "defects.csv").read_text().splitlines()[1:]}
    assert rows["D013"].startswith("D013,corrosion,confirmed,") and "coating breakdown at the weld" in rows["D002"]
    # AND a refused edit writes nothing
    before = _snapshot(rep)
    with pytest.raises(ReviewError):
        rv.apply({"id": "D099", "field": "status", "value": "confirmed"})
    with pytest.raises(ReviewError):
        rv.apply({"id": "D001", "field": "status", "value": "maybe"})
    assert _snapshot(rep) == before


def test_an_entry_gone_from_the_register_on_disk_is_refused_and_the_rest_edits_what_is_there(review_run):
    # GIVEN a review open, and the register then rewritten by another writer (a later run) without D003
    _, run = review_run
    rep = run / "report"
    rv = Review.open(rep, "J. Smith")
    rv.apply({"id": "D001", "field": "status", "value": "confirmed"})
    doc = json.loads((rep / "defects.json").read_text())
    doc["defects"] = [d for d in doc["defects"] if d["id"] != "D003"]
    doc["defects"][1]["note"] = "written by the other writer"  # D002
    (rep / "defects.json").write_text(json.dumps(doc))
    (rep / "defects.csv").unlink()
    before = _snapshot(rep)
    # WHEN the surveyor edits D003 THEN it is refused (404) and nothing is written
    with pytest.raises(ReviewError) as err:
        rv.apply({"id": "D003", "field": "status", "value": "rejected"})
    assert err.value.http == 404 and "no entry 'D003'" in str(err.value)
    assert _snapshot(rep) == before
    # AND an edit of another entry goes onto the register as it is now
    rv.apply({"id": "D004", "field": "status", "value": "rejected"})
    reg = {d.id: d for d in read_register(rep / "defects.json", rep / "defects.csv")}
    assert "D003" not in reg and reg["D002"].note == "written by the other writer"
    assert (reg["D001"].status, reg["D004"].status) == ("confirmed", "rejected")
    assert len((rep / "audit.jsonl").read_text().splitlines()) == 2


def test_a_run_without_a_register_is_one_line(tmp_path):
    (tmp_path / "run" / "report").mkdir(parents=True)
    with pytest.raises(InputError, match="defects.json: not found: the run has no register"):
        Review.open(tmp_path / "run" / "report", "J. Smith")


# ------------------------------------------------------------------------------ HTTP


def _client(run: Path, **cfg):
    pytest.importorskip("starlette")
    from starlette.testclient import TestClient

    from inspect_pipe.review_app import ReviewConfig, ReviewServer, open_review

    rv, store, rcfg = open_review(run, "J. Smith")
    return TestClient(ReviewServer(rv, store, rcfg, ReviewConfig(**{"render_after_s": None, **cfg})).app())


def test_http_edits_answer_one_line_errors_and_write_nothing_on_bad_input(review_run):
    _, run = review_run
    rep = run / "report"
    with _client(run) as c:
        assert "Register review" in c.get("/").text and "<kbd>t</kbd>" in c.get("/").text
        state = c.get("/api/register").json()
        assert [e["id"] for e in state["entries"]][:2] == ["D001", "D002"] and len(state["entries"]) == 14
        assert state["reviewer"] == "J. Smith" and state["mosaic_wh"] and state["overlay"] == "assets/overlay.png"
        r = c.post("/api/edit", json={"id": "D001", "field": "status", "value": "confirmed"})
        assert r.status_code == 200 and r.json()["entry"]["status"] == "confirmed" and r.json()["audit_lines"] == 1
        before = _snapshot(rep)
        bad = [
            (c.post("/api/edit", json={"id": "D077", "field": "status", "value": "rejected"}), 404, "no entry 'D077'"),
            (c.post("/api/edit", json={"id": "D001", "field": "colour", "value": "red"}), 400, "field 'field' is 'colour'"),
            (c.post("/api/edit", content=b'{"id": "D001", "fie', headers={"content-type": "application/json"}), 400, "not valid JSON"),
            (c.post("/api/edit", content=b"id=D001", headers={"content-type": "application/x-www-form-urlencoded"}), 415, "send JSON"),
            (c.post("/api/edit", content=b"{" + b" " * 5000 + b"}", headers={"content-type": "application/json"}), 413, "at most 4096"),
        ]
        for resp, status, text in bad:
            body = resp.json()
            assert resp.status_code == status and list(body) == ["error"] and text in body["error"] and "\n" not in body["error"]
        assert _snapshot(rep) == before, "a refused edit wrote something"
        assert c.get("/assets/crops/D001.png").headers["content-type"] == "image/png"
        assert c.get("/assets/../defects.json").status_code == 404 and c.get("/assets/%2e%2e/defects.json").status_code == 404
        # WHEN asked to re-render THEN the report shows the decision
        out = c.post("/api/render").json()
        assert out["error"] is None and out["renders"] == 1
    html = (rep / "report.html").read_text()
    assert '<td>D001</td><td>corrosion</td><td class="confirmed">confirmed' in html
    assert len((rep / "audit.jsonl").read_text().splitlines()) == 1


def test_the_report_re_renders_by_itself_after_the_last_edit(review_run):
    import time

    _, run = review_run
    rep = run / "report"
    with _client(run, render_after_s=0.3) as c:
        c.post("/api/edit", json={"id": "D007", "field": "status", "value": "rejected"})
        assert c.get("/api/register").json()["dirty"] is True
        t0 = time.monotonic()
        while c.get("/api/register").json()["rendered"]["renders"] < 1:
            assert time.monotonic() - t0 < 60, "no render"
            time.sleep(0.2)
        state = c.get("/api/register").json()
        assert state["dirty"] is False and state["rendered"]["error"] is None and state["rendered"]["pdf"] is True
    assert '<td>D007</td><td>corrosion</td><td class="rejected">rejected' in (rep / "report.html").read_text()


def test_off_loopback_the_token_is_exchanged_once_for_a_cookie(review_run):
    _, run = review_run
    with _client(run, host="0.0.0.0", token="surveyor-token-123") as c:
        assert c.get("/api/register").status_code == 401
        assert c.post("/api/edit", json={"id": "D001", "field": "status", "value": "confirmed"}).status_code == 401
        assert c.get("/").status_code == 401 and 'id="login"' in c.get("/").text
        assert c.get("/api/register?token=surveyor-token-123").status_code == 400  # never in a URL
        assert c.post("/login", json={"token": "wrong-token-000000"}).status_code == 403
        r = c.post("/login", json={"token": "surveyor-token-123"})
        assert r.status_code == 200 and "ip_session" in r.cookies
        assert c.get("/api/register").status_code == 200
        assert c.post("/api/edit", json={"id": "D001", "field": "status", "value": "confirmed"}).status_code == 200
        c.post("/logout")
        assert c.get("/api/register").status_code == 401
    assert not (run / "report" / "audit.jsonl").read_text().count("surveyor-token")


# ------------------------------------------------------------------------------ CLI and later runs


def test_review_command_bad_input_is_one_line_exit_2(review_run, tmp_path):
    _, run = review_run
    (tmp_path / "bare" / "report").mkdir(parents=True)
    for args, text in [
        (["review", str(tmp_path / "nowhere"), "--reviewer", "J"], "not found"),
        (["review", str(tmp_path / "bare"), "--reviewer", "J"], "the run has no register"),
        (["review", str(run)], "--reviewer: missing and the survey plan names no surveyor"),
        (["review", str(run), "--reviewer", "J", "--host", "0.0.0.0", "--token", "short"], "--token: too short"),
        # an address not of this machine: refused before the banner and the token are printed
        (["review", str(run), "--reviewer", "J", "--host", "999.999.1.1"], "999.999.1.1:8766: cannot listen"),
    ]:
        res = runner.invoke(app, args)
        assert res.exit_code == 2, res.output
        assert text in res.output and len(res.output.strip().splitlines()) == 1 and "Traceback" not in res.output


def test_a_later_run_keeps_statuses_notes_and_classes(review_run):
    src, run = review_run
    rep = run / "report"
    rv = Review.open(rep, "J. Smith")
    for doc in [{"id": "D001", "field": "status", "value": "confirmed"}, {"id": "D002", "field": "status", "value": "rejected"},
                {"id": "D003", "field": "note", "value": "pitting near the bracket"},
                {"id": "D014", "field": "class", "value": "corrosion"}, {"id": "D014", "field": "status", "value": "confirmed"}]:
        rv.apply(doc)
    # WHEN inspect-pipe run is given again (report redone from the same detections)
    res = runner.invoke(app, run_args(src, run) + ["--rerun-from", "report", "--no-pdf"])
    assert res.exit_code == 0, res.output
    reg = {d.id: d for d in read_register(rep / "defects.json", rep / "defects.csv")}
    # THEN every decision is still there, on the same ids, and the reclassified crack is still corrosion
    assert len(reg) == 14 and all(d.redetected for d in reg.values())
    assert (reg["D001"].status, reg["D002"].status, reg["D003"].note) == ("confirmed", "rejected", "pitting near the bracket")
    assert (reg["D014"].cls, reg["D014"].detected_cls, reg["D014"].status) == ("corrosion", "crack", "confirmed")
    assert reg["D013"].cls == "crack" and reg["D004"].status == "suggested"
    html = (rep / "report.html").read_text()
    assert "reclassified (detected crack)" in html and '<td class="rejected">rejected' in html
    # AND the report says who reviewed it, how much, and where the log is, with its checksum
    assert "by J. Smith: 5 changes to the register" in html and "2 entries confirmed, 1 rejected, 1 reclassified, 11 not yet decided" in html
    trace = json.loads((rep / "defects.json").read_text())["traceability"]["review"]
    assert (trace["changes"], trace["reviewers"], trace["log"]) == (5, ["J. Smith"], "audit.jsonl") and len(trace["sha256"]) == 64
    # AND a run that finds every step done leaves them alone
    res = runner.invoke(app, run_args(src, run) + ["--no-pdf"])
    assert res.exit_code == 0 and read_register(rep / "defects.json", rep / "defects.csv")[13].cls == "corrosion"
