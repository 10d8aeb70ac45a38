"""``inspect-pipe campaign``: runs, replays, and refuses bad input with one line and exit 2."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from cli.main import app

runner = CliRunner()


def test_campaign_cli_writes_the_summary(tmp_path):
    r = runner.invoke(app, ["campaign", "--episodes", "1", "--seed", "3", "-o", str(tmp_path / "c"), "--workers", "1", "--no-report"])
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "c" / "summary.json").read_text())
    assert s["episodes"] == 1 and set(s["shields"]) == {"ours", "px4_like", "ardupilot_like"}


def test_campaign_cli_bad_input(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    for args in (["--episodes", "0", "-o", str(tmp_path / "o")], ["--episodes", "1", "-o", str(f)],
                 ["--episodes", "1", "--shields", "dji", "-o", str(tmp_path / "o")], ["--episodes", "1"],
                 ["--replay", str(tmp_path / "missing.yaml")], ["--replay", str(f), "--shield", "nope"]):
        r = runner.invoke(app, ["campaign", *args])
        assert r.exit_code == 2, (args, r.output)
        assert r.output.strip().startswith("error:") and len(r.output.strip().splitlines()) == 1


def test_campaign_cli_replays_a_scenario(scenarios_dir):
    r = runner.invoke(app, ["campaign", "--replay", str(scenarios_dir / "link_loss.yaml"), "--shield", "px4_like"])
    assert r.exit_code == 0, r.output
    assert "completed" in r.output
