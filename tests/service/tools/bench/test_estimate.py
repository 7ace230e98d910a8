"""``oslim bench estimate``: where the map's estimate was while suite missions traced."""

from __future__ import annotations

import json

import pytest

from service.cli import main
from service.tools.bench import estimate
from service.tools.bench.suite import SuiteMission
from sim_bridge.generator import SUITE_DIR


def test_outcomes_sum_the_missions_of_each_ending_successes_first() -> None:
    ended = [
        ("undeclared_at_source", estimate.Places(traced=10, away_downflow=7, at_source=3, at_odour=6)),
        ("success", estimate.Places(traced=4, at_source_with_mass=4, at_odour=4)),
        ("undeclared_at_source", estimate.Places(traced=5, away_upflow_or_beside=5, flat=2)),
        ("never_detected", estimate.Places()),
    ]
    rows = [o.as_row() for o in estimate.outcomes(ended)]
    assert [(r["outcome"], r["missions"]) for r in rows] == [
        ("success", 1),
        ("never_detected", 1),
        ("undeclared_at_source", 2),
    ]
    u = rows[2]
    assert (u["traced"], u["away_downflow"], u["away_upflow_or_beside"]) == (15, 7, 5)
    assert (u["at_source"], u["at_odour"], u["flat"]) == (3, 6, 2)


def test_a_success_had_its_estimate_at_the_source_with_the_mass_and_every_tick_placed_once() -> None:
    outcome, places = estimate.mission_places(SuiteMission(str(SUITE_DIR / "wang-laminar.toml"), 0))
    assert outcome == estimate.SUCCESS
    assert places.traced > 10
    assert places.at_source_with_mass > 0  # the rule fired there before the check vouched for it
    at = places.at_source_with_mass + places.at_source
    assert at + places.away_downflow + places.away_upflow_or_beside == places.traced
    assert 0 < places.at_odour <= places.traced


def test_json_gives_each_ending_of_the_class(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "estimate", "--class", "steady", "--runs", "2", "--jobs", "1", "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert {row["class"] for row in rows} == {"steady"}  # one class: no "all" rows
    assert sum(row["missions"] for row in rows) == 2
    assert all(row["traced"] >= row["at_source_with_mass"] + row["away_downflow"] for row in rows)


def test_an_unknown_class_is_named() -> None:
    with pytest.raises(SystemExit, match="unknown class 'nowhere'"):
        main(["bench", "estimate", "--class", "nowhere"])
