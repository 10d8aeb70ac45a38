"""Campaign runs: deterministic per seed (also across processes), summary schema, and a failure
written as a scenario that replays to the same collision."""

from __future__ import annotations

import json

from inspect_pipe.campaign import CampaignConfig, EpisodeSpec, fly_episode, fly_scenario, run_campaign, write_failure
from inspect_pipe.flight import load_scenario

REQUIRED = ("collision_free", "min_clearance_p001_m", "overshoot_max_m", "stuck_episodes", "link_loss_hover_s_max")


def _strip(summary: dict) -> dict:
    s = json.loads(json.dumps(summary["shields"]))
    for v in s.values():
        v.pop("cpu_time_s")
    return s


def test_summary_schema_and_determinism_across_worker_counts(tmp_path):
    a = run_campaign(CampaignConfig(episodes=3, seed=5, out=tmp_path / "a", workers=1, report=False))
    b = run_campaign(CampaignConfig(episodes=3, seed=5, out=tmp_path / "b", workers=2, report=False))
    on_disk = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert on_disk["episodes"] == 3 and on_disk["seed"] == 5
    assert set(on_disk["shields"]) == {"ours", "px4_like", "ardupilot_like"}
    for s in on_disk["shields"].values():
        for k in REQUIRED:
            assert k in s
        assert 0.0 <= s["collision_free"] <= 1.0
        assert s["episodes"] == 3
    assert _strip(a) == _strip(b)
    lines = (tmp_path / "a" / "episodes.jsonl").read_text().splitlines()
    assert len(lines) == 9


def _backwards_into_the_wall() -> EpisodeSpec:
    # No rear sensor (as on the paper's platform): flying backwards into the back wall collides.
    doc = {
        "format": "inspect_pipe.scenario/1", "name": "backwards", "duration_s": 12, "seed": 4,
        "world": {"hold": {"length_m": 10, "width_m": 8, "height_m": 8}},
        "vehicle": {"start": {"position": [2.0, 0.5, 0]}},
        "operator": [{"t": 0.5, "button": "takeoff"}, {"t": 4.0, "stick": {"vx": -0.6}}],
        "faults": [{"t": 1.0, "duration_s": 20, "fault": "packet_loss", "sensor": "left_sonar", "rate": 0.05}],
    }
    return EpisodeSpec(0, 9, "wall_push", doc, ("dropout",))


def test_a_failure_is_written_as_a_scenario_that_replays_exactly(tmp_path):
    spec = _backwards_into_the_wall()
    res = fly_episode(spec, "ours")
    assert res.collided
    path = write_failure(spec, "ours", res, tmp_path / "failures")
    replay = fly_scenario(load_scenario(path), "ours")
    assert replay.collided_at_s == res.collided_at_s


def test_report_has_table_and_plots(tmp_path):
    run_campaign(CampaignConfig(episodes=1, seed=2, out=tmp_path, workers=1, shields=("ours", "ardupilot_like")))
    page = (tmp_path / "report.html").read_text()
    assert "collision-free share" in page and "ardupilot_like" in page
    assert (tmp_path / "min_clearance_cdf.png").stat().st_size > 1000
