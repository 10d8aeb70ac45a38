"""Fault injection (issue 23, item 1), shared by bench/bench_faults.py (many runs) and
tests/reliability/test_faults.py (a few).

Faults, each against a reference made once by an uninterrupted run on the same input:

    kill:CMD      SIGKILL at a random moment of ``capture`` (sim source), ``import``, ``mosaic``,
                  ``detect``, ``report`` or ``run`` (the real CLI in a subprocess)
    disk-full     the output on a tmpfs too small for it (ENOSPC), then the rerun on one with room
    read-only     the output folder on a read-only filesystem, then the rerun on a writable one
    camera-lost   the camera vanishes after a random frame of a capture
    link-died     the autopilot's MAVLink link falls silent at a random moment of a capture
    corrupt       random JPEG/PNG frames of a sweep truncated or bit-flipped before the mosaic

The promise checked for every fault: no file half-written (every file of the output parses or
decodes; atomic writes leave only their hidden ``.NAME.*.tmp``), the rerun finishes, and its
result equals the uninterrupted run's (mosaic.json frames and H; the register's entries; a
sweep's frame lines and image bytes). ``disk-full`` and ``read-only`` additionally fail with one
``error:`` line and exit code 2. Mounting a tmpfs needs root; without it those two are skipped
and say so.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", PYTHONPATH=str(ROOT),
           COLUMNS="200", NO_COLOR="1")
CLI = [sys.executable, "-c", "from cli.main import app; app()"]


def cli(args: list, *, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run(CLI + [str(a) for a in args], env=ENV, capture_output=True, text=True, timeout=timeout)


# =============================================================================== the input


SCENARIO = """format: inspect_pipe.scenario/1
name: fault_wall
duration_s: {duration}
seed: 3
world:
  hold: {{length_m: 12, width_m: 10, height_m: 16}}
  front_wall_texture: {{image: wall.png, m_per_px: 0.004, origin_uv: [3.8, 2.0]}}
vehicle:
  start: {{position: [10.5, 0.0, 0], yaw: 0}}
camera: {{fps: 10, width: 320, height: 240, hfov_deg: 60}}
operator:
  - {{t: 0.3, button: takeoff}}
  - {{t: 1.5, stick: {{vx: 0, vy: -0.25, vz: 0, yaw_rate: 0}}}}
"""


@dataclass
class Fixture:
    root: Path
    scenario: Path
    times: dict[str, float] = field(default_factory=dict)  # uninterrupted seconds per command

    @property
    def ref(self) -> Path:
        return self.root / "ref"


def build(root: Path, duration_s: float = 5.0, only: tuple[str, ...] | None = None) -> Fixture:
    """The scenario, and every command's (or ``only`` these commands') uninterrupted reference run on it."""
    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.standard_normal((400, 600, 3)).astype(np.float32), (0, 0), 3)
    cv2.imwrite(str(root / "wall.png"), np.clip(128 + 45 * img / img.std(), 0, 255).astype(np.uint8))
    sc = root / "fault_wall.yaml"
    sc.write_text(SCENARIO.format(duration=duration_s))
    fx = Fixture(root, sc)
    ref = fx.ref
    if ref.exists():
        shutil.rmtree(ref)
    ref.mkdir()
    for name, argv in commands(fx, ref).items():
        if only is not None and name not in only:
            continue
        t0 = time.perf_counter()
        if name == "footage":
            _footage(fx)
            continue
        r = cli(argv)
        fx.times[name] = time.perf_counter() - t0
        if r.returncode != 0:
            raise RuntimeError(f"reference {name} failed: {r.stdout[-500:]} {r.stderr[-500:]}")
    return fx


def commands(fx: Fixture, out: Path) -> dict[str, list]:
    """Each command's arguments writing under ``out``, reading the references' outputs (in this
    order the references are made)."""
    ref = fx.ref
    return {
        "capture": ["capture", "--source", f"sim:{fx.scenario}", "-o", out / "sweep", "-q"],
        "fly": ["fly", "--scenario", fx.scenario, "--log", out / "flight.jsonl", "--sweep", out / "flown", "--tlog", out / "f.tlog"],
        "footage": [],
        "import": ["import", ref / "DCIM", "--log", ref / "f.tlog", "-o", out / "imported", "-q"],
        "mosaic": ["mosaic", ref / "sweep", "-o", out / "mosaic", "-q"],
        "detect": ["detect", "run", ref / "mosaic" / "mosaic.png", "-o", out / "detect", "--engine", "saliency", "-q"],
        "run": ["run", ref / "sweep", "-o", out / "run", "--no-pdf", "--workers", "1", "--engine", "saliency", "-q"],
        "report": ["report", ref / "run", "-o", out / "report", "--no-pdf", "-q"],
    }


def _footage(fx: Fixture) -> None:
    sys.path.insert(0, str(ROOT / "tools"))
    from sweep_to_footage import write_drone_footage  # noqa: E402

    write_drone_footage(fx.ref / "flown", fx.ref / "DCIM", clock_offset_s=-1.2, utc_offset_h=0.0)


# =============================================================================== checks


def whole_files(out: Path) -> list[str]:
    """Files under ``out`` that are not whole: a JSON that does not parse, an image that does not
    decode, a frames.jsonl line cut in the middle (other than its last line: the reader skips that
    one, by design). Hidden ``.NAME.*.tmp`` files of interrupted atomic writes are not outputs."""
    bad = []
    if not out.exists():
        return bad
    for p in out.rglob("*"):
        if not p.is_file() or (p.name.startswith(".") and p.name.endswith(".tmp")):
            continue
        try:
            if p.suffix == ".json" or p.name == "COMPLETE":
                json.loads(p.read_text())
            elif p.suffix in (".png", ".jpg", ".jpeg"):
                if cv2.imread(str(p), cv2.IMREAD_UNCHANGED) is None:
                    bad.append(f"{p}: does not decode")
            elif p.suffix == ".jsonl":
                lines = p.read_bytes().split(b"\n")
                for line in lines[:-1]:
                    if line.strip():
                        json.loads(line)
        except (ValueError, UnicodeDecodeError) as err:
            bad.append(f"{p}: {err.__class__.__name__}")
    return bad


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def _pixels(p: Path) -> str:
    """sha256 of the decoded pixels: the capture's writer picks its PNG compression by its queue
    (under load it stores), so equal frames may differ in bytes, never in pixels."""
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    return "undecodable" if img is None else hashlib.sha256(img.tobytes()).hexdigest()


def sweep_sig(s: Path) -> list:
    from inspect_pipe.capture import read_sweep

    sw = read_sweep(s)
    return [(f.index, round(f.t_s, 6), None if f.position_m is None else tuple(round(x, 6) for x in f.position_m), _pixels(f.image_path))
            for f in sw.frames]


def mosaic_sig(d: Path) -> list:
    doc = json.loads((d / "mosaic.json").read_text())
    return [(f["index"], f["group"], np.round(np.asarray(f["H"], float), 6).tolist()) for f in doc["frames"]] + [_sha(d / doc["mosaic"])]


def detect_sig(d: Path) -> list:
    doc = json.loads((d / "defects.json").read_text())
    return [(r["class"], r["area_px"], r["bbox_xywh"]) for r in doc["regions"]]


def register_sig(d: Path) -> list:
    doc = json.loads((d / "defects.json").read_text())
    return [(e["id"], e["class"], e["status"], e["polygon_wall_m"], e["area_m2"]) for e in doc["defects"]]


def signature(name: str, out: Path):
    if name == "capture":
        return sweep_sig(out / "sweep")
    if name == "import":
        return sweep_sig(out / "imported")
    if name == "mosaic":
        return mosaic_sig(out / "mosaic")
    if name == "detect":
        return detect_sig(out / "detect")
    if name == "report":
        return register_sig(out / "report")
    if name == "run":
        return [mosaic_sig(out / "run" / "mosaic"), register_sig(out / "run" / "report")]
    raise KeyError(name)


# =============================================================================== faults


@dataclass
class Result:
    fault: str
    injected: bool  # the fault happened (a process killed while running, a write refused ...)
    recovered: bool  # the rerun finished and equals the reference
    lost: int = 0  # files half-written, frames or entries missing from the rerun
    detail: str = ""


def kill(fx: Fixture, name: str, work: Path, rng: np.random.Generator, frac: tuple[float, float] = (0.05, 0.95)) -> Result:
    """SIGKILL ``name`` at a uniformly random moment of its uninterrupted duration (the fraction
    ``frac`` of it), then rerun."""
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    argv = commands(fx, work)[name]
    at = float(rng.uniform(*frac)) * fx.times[name]
    proc = subprocess.Popen(CLI + [str(a) for a in argv], env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        proc.wait(timeout=at)
        injected = False  # finished before the moment drawn (the machine was fast this time)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        injected = True
    bad = whole_files(work)
    if name == "capture" and (work / "sweep").exists():  # the killed sweep reads up to its last whole frame
        from inspect_pipe.capture import read_sweep

        try:
            part = sweep_sig(work / "sweep")
            ref = signature("capture", fx.ref)
            if part != ref[: len(part)]:
                bad.append("killed sweep: its frames are not the reference's first frames")
            read_sweep(work / "sweep")
        except Exception as err:  # noqa: BLE001
            bad.append(f"killed sweep unreadable: {err}")
        shutil.move(str(work / "sweep"), str(work / "sweep.killed"))  # capture never writes into a used folder: a new one
    if name == "import" and (work / "imported").exists():
        # import renames its finished temporary folder into place: a kill after the rename leaves
        # the whole sweep (equal to the reference); like capture, it never writes into a used folder
        if signature("import", work) != signature("import", fx.ref):
            bad.append("killed import: its sweep is not the reference's")
        shutil.move(str(work / "imported"), str(work / "imported.killed"))
    r = cli(argv)
    if r.returncode != 0:
        return Result(f"kill:{name}", injected, False, len(bad) + 1, f"rerun failed: {(r.stdout + r.stderr).strip()[-300:]}")
    same = signature(name, work) == signature(name, fx.ref)
    return Result(f"kill:{name}", injected, same and not bad, len(bad) + (0 if same else 1),
                  f"at {at:.2f} s; " + ("; ".join(bad[:3]) if bad else "") + ("" if same else " rerun differs from the reference"))


def _mount(path: Path, size_kib: int | None, ro: bool = False) -> bool:
    path.mkdir(parents=True, exist_ok=True)
    opts = ("ro," if ro else "") + (f"size={size_kib}k" if size_kib else "size=64m")
    return subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(path)], capture_output=True).returncode == 0


def _umount(path: Path) -> None:
    subprocess.run(["umount", "-l", str(path)], capture_output=True)


def can_mount(tmp: Path) -> bool:
    p = tmp / "mount_probe"
    ok = _mount(p, 64)
    if ok:
        _umount(p)
    return ok


def _du_kib(p: Path) -> int:
    return sum(f.stat().st_size for f in p.rglob("*") if f.is_file()) // 1024 + 64


def disk_full(fx: Fixture, name: str, work: Path, rng: np.random.Generator, *, read_only: bool = False) -> Result:
    """``name`` writing to a tmpfs with a random fraction of the room it needs (or a read-only
    one): one ``error:`` line, exit 2, no half-written file; then the rerun on a filesystem with
    room equals the reference."""
    fault = ("read-only:" if read_only else "disk-full:") + name
    if work.exists():
        _umount(work)
        shutil.rmtree(work, ignore_errors=True)
    need = _du_kib(fx.ref / {"mosaic": "mosaic", "run": "run", "report": "report", "detect": "detect", "import": "imported",
                             "capture": "sweep"}[name])
    size = max(16, int(need * float(rng.uniform(0.05, 0.9))))
    if not _mount(work, size, ro=read_only):
        return Result(fault, False, False, 0, "cannot mount a tmpfs here (needs root)")
    try:
        r = cli(commands(fx, work)[name])
        lines = [x for x in (r.stdout + r.stderr).strip().splitlines() if x.strip()]
        errors = [x for x in lines if x.startswith("error:")]
        injected = r.returncode != 0
        one_line = r.returncode == 2 and len(errors) == 1 and "Traceback" not in r.stderr
        bad = whole_files(work)
        detail = f"{size} KiB of {need}: " + (errors[0][:160] if errors else f"rc {r.returncode} {lines[-1:] if lines else ''}")
    finally:
        _umount(work)
    if not injected:
        return Result(fault, False, True, 0, detail + " (fitted: no fault)")
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    r2 = cli(commands(fx, work)[name])
    same = r2.returncode == 0 and signature(name, work) == signature(name, fx.ref)
    if not one_line:
        bad.append("not one error line with exit 2: " + " | ".join(lines[-3:])[:300])
    return Result(fault, True, same and not bad, len(bad) + (0 if same else 1), detail + ("; " + "; ".join(bad[:2]) if bad else ""))


def camera_lost(fx: Fixture, work: Path, rng: np.random.Generator) -> Result:
    """The simulated camera vanishes after a random frame: the capture ends with that reason, its
    sweep holds every frame before the loss, each equal to the reference's."""
    from inspect_pipe.capture import CaptureConfig, ManualClock, SourceLost, run_capture
    from inspect_pipe.capture.sources.sim import SimSource
    from inspect_pipe.flight import load_scenario

    if work.exists():
        shutil.rmtree(work)
    ref = signature("capture", fx.ref)
    k = int(rng.integers(1, len(ref)))

    class Vanishing(SimSource):
        n = 0

        def grab(self, deadline_s):
            if self.n >= k:
                raise SourceLost("sim camera: unplugged (fault injection)")
            self.n += 1
            return super().grab(deadline_s)

    clock = ManualClock(0.0)
    src = Vanishing(load_scenario(fx.scenario), clock=clock)
    res = run_capture(src, work / "sweep", clock=clock, config=CaptureConfig(rate_hz=10, time_base="simulation_s", wait_for_writer=True))
    bad = whole_files(work)
    got = sweep_sig(work / "sweep")
    same = got == ref[:k]
    return Result("camera-lost", True, same and not bad, len(bad) + (k - len(got) if not same else 0),
                  f"lost after frame {k}: {len(got)} frames, stop: {getattr(res.reason, 'value', res.reason)}")


def corrupt(fx: Fixture, work: Path, rng: np.random.Generator) -> Result:
    """Random frames of a reference sweep (PNG from capture, or JPEG from import) truncated or
    bit-flipped: ``mosaic --verify`` names them unplaced (their sha256 differs from the COMPLETE
    marker's) and places the same other frames as it places the sweep without them, every corner
    within 0.5 px."""
    if work.exists():
        shutil.rmtree(work)
    src = fx.ref / ("sweep" if rng.random() < 0.5 else "imported")
    sw, clean = work / "sweep", work / "clean"
    shutil.copytree(src, sw)
    shutil.copytree(src, clean)
    lines = (sw / "frames.jsonl").read_text().splitlines()
    n = len(lines)
    hit = sorted(rng.choice(np.arange(1, n - 1), size=int(rng.integers(1, 4)), replace=False).tolist())
    kinds = []
    for i in hit:
        p = sw / json.loads(lines[i])["image"]
        b = bytearray(p.read_bytes())
        if rng.random() < 0.5:
            b = b[: int(len(b) * rng.uniform(0.1, 0.9))]
            kinds.append(f"{p.suffix} truncated")
        else:
            for j in rng.integers(0, len(b), 64):
                b[j] ^= 0xFF
            kinds.append(f"{p.suffix} flipped")
        p.write_bytes(bytes(b))
    # the clean sweep: the same frames without the damaged ones
    (clean / "frames.jsonl").write_text("".join(x + "\n" for i, x in enumerate(lines) if i not in hit))
    (clean / "COMPLETE").unlink(missing_ok=True)
    r = cli(["mosaic", sw, "-o", work / "m", "--verify", "-q"])
    r2 = cli(["mosaic", clean, "-o", work / "m_clean", "-q"])
    if r.returncode != 0 or r2.returncode != 0:
        return Result("corrupt", True, False, 1, f"mosaic rc {r.returncode}/{r2.returncode}: {(r.stdout + r.stderr)[-300:]}")
    doc = json.loads((work / "m" / "mosaic.json").read_text())
    unplaced = {u["index"] for u in doc["unplaced"]}
    a = {f["index"]: np.asarray(f["H"], float) for f in doc["frames"]}
    cdoc = json.loads((work / "m_clean" / "mosaic.json").read_text())
    pos = [i for i in range(n) if i not in hit]  # the clean sweep's positions -> the damaged sweep's
    b = {pos[f["index"]]: np.asarray(f["H"], float) for f in cdoc["frames"]}
    # the same frames placed, each frame's corners within 0.5 px of the sweep without the damaged ones
    # (the robust estimators see another frame count, so the last digits may differ)
    w, h = json.loads((sw / "sweep.json").read_text())["camera"]["width"], json.loads((sw / "sweep.json").read_text())["camera"]["height"]
    c = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], float).T
    diff = max((float(np.abs((a[k] @ c)[:2] / (a[k] @ c)[2] - (b[k] @ c)[:2] / (b[k] @ c)[2]).max()) for k in a.keys() & b.keys()), default=0.0)
    same = a.keys() == b.keys() and diff <= 0.5
    bad = whole_files(work / "m")
    ok = set(hit) <= unplaced and same and not bad
    # lost: an output not whole, or a good frame the sweep without the damaged ones places and this
    # one does not (a placement beyond the tolerance is not recovered, but nothing is lost)
    lost = len(bad) + len(b.keys() - a.keys())
    return Result("corrupt", True, ok, lost,
                  f"{src.name}: frames {hit} ({', '.join(kinds)}), {len(set(hit) & unplaced)} unplaced, others within {diff:.3f} px"
                  + ("" if same else f"; placement differs from the sweep without them ({sorted(a.keys() ^ b.keys())})"))


class FakeAutopilot:
    """A PX4-like autopilot on loopback UDP: HEARTBEAT, ATTITUDE and LOCAL_POSITION_NED at 50 Hz,
    TIMESYNC answered on its boot clock; ``die`` silences it (the link dies)."""

    def __init__(self, peer) -> None:
        import socket
        import threading

        from pymavlink.dialects.v20 import common as C

        self.C, self.peer = C, peer
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.settimeout(0.01)
        self.mav = C.MAVLink(None, srcSystem=1, srcComponent=1)
        self.boot = time.monotonic() - 37.0
        self.die, self.stop = threading.Event(), threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        C, parser = self.C, self.C.MAVLink(None)
        while not self.stop.is_set():
            if self.die.is_set():
                time.sleep(0.01)
                continue
            t = time.monotonic() - self.boot
            ms = int(t * 1000)
            for m in (C.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3), C.MAVLink_attitude_message(ms, 0, 0, 0.0, 0, 0, 0),
                      C.MAVLink_local_position_ned_message(ms, 0.5 * t, 0.0, -1.0, 0.5, 0, 0)):
                self.sock.sendto(m.pack(self.mav), self.peer)
            try:
                data, _ = self.sock.recvfrom(2048)
                for m in parser.parse_buffer(data) or []:
                    if m.get_type() == "TIMESYNC" and m.tc1 == 0:
                        self.sock.sendto(C.MAVLink_timesync_message(int((time.monotonic() - self.boot) * 1e9), m.ts1).pack(self.mav), self.peer)
            except OSError:
                pass
            time.sleep(0.02)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(2)
        self.sock.close()


def link_died(fx: Fixture, work: Path, rng: np.random.Generator, duration_s: float = 3.5) -> Result:
    """A capture stamping frames from a live autopilot whose link falls silent at a random moment:
    every frame is written and whole, the frames before the silence carry the state, the frames
    after it (past the tracker's 0.5 s gap) carry state null, never a state again, and the capture
    counts them."""
    import socket
    import threading

    from inspect_pipe.capture import CaptureConfig, MonotonicClock, run_capture
    from inspect_pipe.capture._vehicle_feed import MavlinkStateFeed
    from inspect_pipe.capture.sources.replay import ReplaySource

    if work.exists():
        shutil.rmtree(work)
    frames = work / "camera"  # the reference frames as a plain image folder (no state of their own)
    frames.mkdir(parents=True)
    for p in sorted((fx.ref / "sweep" / "images").iterdir()):
        shutil.copy(p, frames / p.name)
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    ap = FakeAutopilot(("127.0.0.1", port))
    die_at = float(rng.uniform(0.3, duration_s - 1.5))
    try:
        clock = MonotonicClock()
        feed = MavlinkStateFeed(f"udp:127.0.0.1:{port}", clock=clock.now)
        time.sleep(0.3)
        died: list[float] = []

        def die() -> None:
            died.append(clock.now())  # on the sweep's time base
            ap.die.set()

        killer = threading.Timer(die_at, die)
        killer.start()
        res = run_capture(ReplaySource(str(frames), clock=clock, rate_hz=10.0), work / "sweep", clock=clock,
                          config=CaptureConfig(rate_hz=10.0, duration_s=duration_s), state_feed=feed,
                          sweep_extra={"odometry_frame": "takeoff", "vehicle": feed.describe()})
        killer.cancel()
        feed.close()
    finally:
        ap.close()
    bad = whole_files(work)
    lines = [json.loads(x) for x in (work / "sweep" / "frames.jsonl").read_text().splitlines()]
    null = [x["state"] is None for x in lines]
    # the link never comes back: once a frame after the death is null, no later frame is stamped. (A
    # null frame before the death is the tracker reacting to a real silence: on a loaded machine the
    # fake autopilot's thread can be starved for longer than the tracker's gap, and its next message
    # rightly stamps the next frame.)
    t_dead = died[0] if died else math.inf
    wrong = [x["index"] for k, x in enumerate(lines)
             if k and null[k - 1] and not null[k] and lines[k - 1]["t_s"] >= t_dead]
    ok = (not bad and len(lines) == res.frames_written and res.frames_without_state == sum(null) and not wrong
          and sum(null) >= 3 and not null[0])
    return Result("link-died", True, ok, len(bad) + len(wrong),
                  f"silent at {die_at:.2f} s: {len(lines)} frames, {res.frames_without_state} without state"
                  + (f"; frames {wrong[:5]} stamped wrongly" if wrong else ""))


def one_round(fx: Fixture, work: Path, rng: np.random.Generator, *, mounts: bool) -> list[Result]:
    """One of each fault (13), each on a fresh work folder."""
    out = [kill(fx, name, work / f"kill_{name}", rng) for name in ("capture", "import", "mosaic", "detect", "report", "run")]
    if mounts:
        out += [disk_full(fx, name, work / f"full_{name}", rng) for name in ("mosaic", "run")]
        out += [disk_full(fx, name, work / f"ro_{name}", rng, read_only=True) for name in ("mosaic", "report")]
    out += [camera_lost(fx, work / "camera_lost", rng), link_died(fx, work / "link_died", rng), corrupt(fx, work / "corrupt", rng)]
    return out
