"""Episode generator: reproducible per seed, valid scenarios, within the issue's ranges."""

from __future__ import annotations

import json

from inspect_pipe.campaign import generate_episode
from inspect_pipe.campaign.generator import SCRIPT_KINDS


def test_same_seed_and_index_give_the_same_episode():
    a = [json.dumps(generate_episode(7, i).doc, sort_keys=True) for i in range(20)]
    b = [json.dumps(generate_episode(7, i).doc, sort_keys=True) for i in reversed(range(20))][::-1]
    assert a == b
    c = [json.dumps(generate_episode(8, i).doc, sort_keys=True) for i in range(20)]
    assert sum(x != y for x, y in zip(a, c)) == 20


def test_episodes_are_valid_scenarios_within_the_catalogue():
    kinds, faults = set(), set()
    for i in range(150):
        spec = generate_episode(1, i)
        sc = spec.scenario()  # parses: valid input for `inspect-pipe fly --scenario`
        h = sc.world.hold
        assert 8 <= h.length_m <= 30 and 6 <= h.width_m <= 20 and 6 <= h.height_m <= 15 + 4.5
        for b in sc.world.boxes:
            top = b.max_m[2]
            assert 0.3 <= top <= 1.5 or top == h.height_m  # coamings/steps, or full-height pillars/passages
        for f in sc.faults:
            faults.add(f.kind.value)
            if f.kind.value == "packet_loss":
                assert 0.0 <= f.rate <= 0.1
            if f.kind.value == "gust":
                assert sum(w * w for w in f.wind_m_s[:2]) ** 0.5 <= 2.0 + 1e-6
            if f.kind.value in ("sensor_dropout", "range_loss"):
                assert 0.2 <= f.duration_s <= 3.0
            if f.kind.value == "link_loss":
                assert 0.2 <= f.duration_s <= 10.0
        assert 0.7 <= sc.vehicle.mass_scale <= 1.3 and 0.7 <= sc.vehicle.thrust_scale <= 1.3
        kinds.add(spec.kind)
        assert sc.duration_s < 120
    assert kinds == set(SCRIPT_KINDS)
    assert {"sensor_dropout", "packet_loss", "stuck_reading", "spurious_max_range", "range_loss",
            "flow_quality_zero", "link_loss", "battery_sag", "gust"} <= faults
