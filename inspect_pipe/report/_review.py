"""The surveyor's review of a register: one edit at a time (confirm, reject, reclassify, note),
each appended to an append-only audit log before the register files are replaced.

    review = Review.open(run_dir / "report", reviewer="J. Smith")
    record = review.apply({"id": "D003", "field": "status", "value": "confirmed"})

Crash safety: the audit line is written, flushed and fsync'd first; then ``defects.json`` and
``defects.csv`` are replaced atomically (``_files.atomic_write``). A crash between the two leaves an
audit line whose change the register lacks; :meth:`Review.open` finishes it (the register still
shows the line's ``before``), so the register and the log agree after a restart.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import threading
from dataclasses import dataclass, replace
from pathlib import Path

from inspect_pipe._files import write_json, atomic_write
from inspect_pipe.errors import InputError

from ._register import STATUSES, Defect, read_register, register_csv

AUDIT_FORMAT = "inspect_pipe.review_audit/1"
AUDIT_NAME = "audit.jsonl"
FIELDS = ("status", "class", "note")
CLASSES = ("corrosion", "crack")
MAX_NOTE = 500


class ReviewError(InputError):
    """A refused edit: ``http`` is the status the web page gets (400 malformed, 404 no such entry)."""

    def __init__(self, where: str, problem: str, hint: str = "", http: int = 400) -> None:
        super().__init__(where, problem, hint)
        self.http = http


@dataclass(frozen=True)
class Edit:
    id: str
    field: str  # status | class | note
    value: str


def parse_edit(doc: object) -> Edit:
    """``{"id": "D003", "field": "status|class|note", "value": "..."}``; anything else: ReviewError 400."""
    where = "edit request"
    if not isinstance(doc, dict):
        raise ReviewError(where, "not a JSON object", 'send {"id": ..., "field": ..., "value": ...}')
    extra = set(doc) - {"id", "field", "value"}
    if extra:
        raise ReviewError(where, f"unknown field {sorted(extra)[0]!r}", "only id, field and value")
    ident, fld, value = doc.get("id"), doc.get("field"), doc.get("value")
    if not isinstance(ident, str) or not ident:
        raise ReviewError(where, "field 'id' missing or not a string")
    if fld not in FIELDS:
        raise ReviewError(where, f"field 'field' is {fld!r}", f"one of {', '.join(FIELDS)}")
    if not isinstance(value, str):
        raise ReviewError(where, "field 'value' missing or not a string")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:  # a lone surrogate (JSON "\ud800"): no file could hold it
        raise ReviewError(where, "field 'value' is not valid Unicode text", "send text") from None
    if fld == "status" and value not in STATUSES:
        raise ReviewError(where, f"status {value!r}", f"one of {', '.join(STATUSES)}")
    if fld == "class" and value not in CLASSES:
        raise ReviewError(where, f"class {value!r}", f"one of {', '.join(CLASSES)}")
    if fld == "note":
        value = " ".join(value.split())  # one line: the CSV and the audit log stay one row per record
        if len(value) > MAX_NOTE:
            raise ReviewError(where, f"note of {len(value)} characters", f"at most {MAX_NOTE}")
    return Edit(ident, fld, value)


def field_value(d: Defect, fld: str) -> str:
    return {"status": d.status, "class": d.cls, "note": d.note}[fld]


def apply_edit(defects: list[Defect], edit: Edit, where: str = "register") -> tuple[list[Defect], str | None]:
    """(the register with ``edit`` applied, the value before); before None: nothing changed.
    Reclassifying keeps the detector's class in ``detected_cls`` (cleared when set back to it)."""
    ix = next((i for i, d in enumerate(defects) if d.id == edit.id), None)
    if ix is None:
        raise ReviewError(where, f"no entry {edit.id!r}", "reload the page: the register changed", http=404)
    d = defects[ix]
    before = field_value(d, edit.field)
    if before == edit.value:
        return defects, None
    if edit.field == "status":
        d = replace(d, status=edit.value)
    elif edit.field == "note":
        d = replace(d, note=edit.value)
    else:
        detected = d.detected_cls or d.cls
        d = replace(d, cls=edit.value, detected_cls=None if edit.value == detected else detected)
    out = list(defects)
    out[ix] = d
    return out, before


def utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def audit_record(edit: Edit, before: str, reviewer: str, t_utc: str | None = None) -> dict:
    return {"format": AUDIT_FORMAT, "t_utc": t_utc or utc_now(), "reviewer": reviewer, "id": edit.id,
            "field": edit.field, "before": before, "after": edit.value}


def append_audit(path: Path, record: dict) -> None:
    """One JSON line, appended, flushed and fsync'd before this returns."""
    line = (json.dumps(record, ensure_ascii=False) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
    try:
        view = memoryview(line)
        while view:
            view = view[os.write(fd, view):]
        os.fsync(fd)
    finally:
        os.close(fd)


def read_audit(path: Path) -> list[dict]:
    """The audit records; a last line cut by a crash (no newline, not JSON) is left out."""
    if not path.exists():
        return []
    out = []
    lines = path.read_bytes().split(b"\n")
    for n, raw in enumerate(lines, start=1):
        if not raw.strip():
            continue
        try:
            rec = json.loads(raw)
        except ValueError:
            if n == len(lines):  # the unterminated tail of an interrupted append
                break
            raise InputError(str(path), f"line {n}: not JSON", "the audit log is append-only: restore it from a backup") from None
        if not isinstance(rec, dict) or rec.get("field") not in FIELDS or not isinstance(rec.get("id"), str):
            raise InputError(str(path), f"line {n}: not an audit record")
        out.append(rec)
    return out


def drop_torn_tail(path: Path) -> int:
    """Cut a last line without its newline (an append a crash interrupted before its fsync, so
    before its edit reached the register) so that the next record starts on a line of its own.
    Returns the bytes cut."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return 0
    if not data or data.endswith(b"\n"):
        return 0
    keep = data.rfind(b"\n") + 1
    with open(path, "r+b") as fh:
        fh.truncate(keep)
        fh.flush()
        os.fsync(fh.fileno())
    return len(data) - keep


def pending(defects: list[Defect], audit: list[dict]) -> list[Edit]:
    """Audit records whose change the register lacks: the last record of an (entry, field) whose
    ``before`` the register still shows (an edit interrupted between the log and the register)."""
    last: dict[tuple[str, str], dict] = {}
    for rec in audit:
        last[(rec["id"], rec["field"])] = rec
    by_id = {d.id: d for d in defects}
    out = []
    for (ident, fld), rec in last.items():
        d = by_id.get(ident)
        if d is not None and field_value(d, fld) == rec.get("before") != rec.get("after"):
            out.append(Edit(ident, fld, str(rec["after"])))
    return out


class Review:
    """A register under review: ``report_dir``'s defects.json / defects.csv and audit.jsonl."""

    def __init__(self, report_dir: Path, reviewer: str, doc: dict, defects: list[Defect]) -> None:
        self.dir = Path(report_dir)
        self.reviewer = reviewer
        self.doc = doc
        self.defects = defects
        self.lock = threading.Lock()
        self.edits = 0  # made in this session
        self._stamp = self._disk_stamp()

    @property
    def json_path(self) -> Path:
        return self.dir / "defects.json"

    @property
    def csv_path(self) -> Path:
        return self.dir / "defects.csv"

    @property
    def audit_path(self) -> Path:
        return self.dir / AUDIT_NAME

    def _disk_stamp(self) -> tuple:
        out = []
        for p in (self.json_path, self.csv_path):
            try:
                st = p.stat()
                out.append((st.st_mtime_ns, st.st_size, st.st_ino))
            except FileNotFoundError:
                out.append(None)
        return tuple(out)

    def reload_if_changed(self) -> None:
        """Another writer (a later ``run``, a hand edit of the CSV) replaced the register since we
        read or wrote it: edit what is on disk now, not the copy in memory."""
        if self._disk_stamp() != self._stamp:
            fresh = Review.open(self.dir, self.reviewer)
            self.doc, self.defects, self._stamp = fresh.doc, fresh.defects, fresh._stamp

    @classmethod
    def open(cls, report_dir: Path, reviewer: str) -> "Review":
        report_dir = Path(report_dir)
        j = report_dir / "defects.json"
        if not j.is_file():
            raise InputError(str(j), "not found: the run has no register", "run inspect-pipe run (or report) on it first")
        if not reviewer.strip():
            raise InputError("--reviewer", "empty", "the name that goes in the audit log")
        defects = read_register(j, report_dir / "defects.csv")
        doc = json.loads(j.read_text())
        rv = cls(report_dir, reviewer.strip(), doc, defects)
        drop_torn_tail(rv.audit_path)
        fix = pending(defects, read_audit(rv.audit_path))
        if fix:
            for e in fix:
                rv.defects, _ = apply_edit(rv.defects, e, str(j))
            rv._write_register()
        return rv

    def apply(self, doc: object) -> dict | None:
        """Validate and apply one edit request; returns its audit record (None: no change)."""
        edit = parse_edit(doc)
        with self.lock:
            self.reload_if_changed()
            new, before = apply_edit(self.defects, edit, str(self.json_path))
            if before is None:
                return None
            rec = audit_record(edit, before, self.reviewer)
            append_audit(self.audit_path, rec)
            self.defects = new
            self._write_register()
            self.edits += 1
            return rec

    def _write_register(self) -> None:
        doc = dict(self.doc)
        by_id = {d.id: d for d in self.defects}
        entries = []
        for e in doc.get("defects", []):
            d = by_id.get(str(e.get("id")))
            if d is not None:
                e = {**e, "status": d.status, "note": d.note, "class": d.cls, "detected_class": d.detected_cls}
            entries.append(e)
        doc["defects"] = entries
        step = ((doc.get("traceability") or {}).get("precision") or {}).get("position_step_m")
        dec = max(0, int(round(-math.log10(step)))) if isinstance(step, (int, float)) and step > 0 else 4  # as the report wrote it
        write_json(self.json_path, doc)
        atomic_write(self.csv_path, register_csv(self.defects, dec).encode())
        self.doc = doc
        self._stamp = self._disk_stamp()

    def entries(self) -> list[dict]:
        """What the page shows of each entry."""
        out = []
        for d in self.defects:
            out.append({"id": d.id, "class": d.cls, "detected_class": d.detected_cls, "status": d.status, "note": d.note,
                        "area_cm2": round(d.area_m2 * 1e4, 1), "length_cm": None if d.length_m is None else round(d.length_m * 100, 1),
                        "confidence": round(d.confidence, 2), "centroid_wall_m": [round(x, 3) for x in d.centroid_wall_m],
                        "bbox_mosaic_xywh": list(d.bbox_mosaic_xywh), "crop": d.crop, "context": d.context,
                        "redetected": d.redetected, "location": (d.location or {}).get("text")})
        return out


def review_summary(path: Path) -> dict | None:
    """What the report says of the review: reviewers, number of changes, first and last (UTC), and
    the log's sha256; None when nobody reviewed the register."""
    recs = read_audit(path)
    if not recs:
        return None
    import hashlib

    times = sorted(str(r.get("t_utc", "")) for r in recs)
    return {"log": path.name, "changes": len(recs), "reviewers": sorted({str(r.get("reviewer", "?")) for r in recs}),
            "first_utc": times[0], "last_utc": times[-1], "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
