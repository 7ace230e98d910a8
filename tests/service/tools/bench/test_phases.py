"""``oslim bench phases``: where suite missions' time goes."""

from __future__ import annotations

import json

import pytest

from service.cli import main
from service.tools.bench import phases
from service.tools.bench.suite import SuiteMission
from sim_bridge.generator import SUITE_DIR


def marks(**given: object) -> phases.Phases:
    base: dict[str, object] = {
        "vehicle": "rover",
        "limit_s": 300.0,
        "correct": False,
        "first_odour_s": None,
        "at_source_s": None,
        "rule_at_source_s": None,
        "last_check_s": None,
        "checks": 0,
        "check_ticks": 0,
        "declared_s": None,
    }
    return phases.Phases(**{**base, **given})  # type: ignore[arg-type]


def test_the_spans_run_between_the_marks_and_stop_at_a_missing_one() -> None:
    declared = marks(
        correct=True, first_odour_s=40.0, at_source_s=70.0, rule_at_source_s=85.0,
        last_check_s=95.0, checks=2, check_ticks=40, declared_s=121.0,
    )  # fmt: skip
    assert (declared.to_source_s, declared.to_rule_s, declared.vouching_s) == (30.0, 15.0, 26.0)
    assert declared.at_source_to_declared_s == 51.0
    passed_unsmelt = marks(first_odour_s=90.0, at_source_s=60.0)  # drove by the source before any odour
    assert passed_unsmelt.to_source_s == 0.0
    assert passed_unsmelt.to_rule_s is None
    assert passed_unsmelt.vouching_s is None
    assert marks().to_source_s is None


def test_the_summary_takes_each_phase_median_over_the_missions_that_got_there() -> None:
    missions = [
        marks(correct=True, first_odour_s=10.0, at_source_s=30.0, rule_at_source_s=40.0,
              last_check_s=40.0, checks=1, check_ticks=20, declared_s=60.0, limit_s=200.0),
        marks(correct=True, first_odour_s=20.0, at_source_s=60.0, rule_at_source_s=90.0,
              last_check_s=100.0, checks=2, check_ticks=50, declared_s=130.0, limit_s=300.0),
        marks(first_odour_s=50.0, limit_s=400.0),
        marks(limit_s=500.0),
    ]  # fmt: skip
    row = phases.summary("steady", missions).as_row()
    assert (row["group"], row["missions"], row["correct"], row["median_limit_s"]) == ("steady", 4, 2, 350.0)
    assert (row["median_first_odour_s"], row["first_odour_missions"]) == (20.0, 3)
    assert (row["median_to_source_s"], row["to_source_missions"]) == (30.0, 2)  # 20 and 40
    assert (row["median_to_rule_s"], row["median_vouching_s"]) == (20.0, 25.0)  # 10 and 30; 20 and 30
    assert (row["median_at_source_to_declared_s"], row["checks"], row["check_ticks"]) == (50.0, 3, 70)
    empty = phases.summary("none", []).as_row()
    assert (empty["median_first_odour_s"], empty["first_odour_missions"]) == (None, 0)


def test_the_kind_rows_hold_only_the_classes_that_drew_both_kinds() -> None:
    rover, auv = marks(vehicle="rover"), marks(vehicle="auv")
    by_class = {"wang-laminar": [rover, rover], "steady": [rover, auv, auv], "patchy": [auv]}
    assert [(name, len(missions)) for name, missions in phases.groups(by_class)] == [
        ("all", 6),
        ("rover", 1),
        ("auv", 2),
    ]
    assert phases.groups({"wang-laminar": [rover]}) == []  # one class of one kind: its own row says it all


def test_a_declared_mission_marks_its_phases_in_order() -> None:
    mission = phases.mission_phases(SuiteMission(str(SUITE_DIR / "wang-laminar.toml"), 0))
    assert mission.correct
    assert mission.vehicle in ("rover", "auv")
    assert mission.first_odour_s is not None
    assert mission.at_source_s is not None
    assert mission.rule_at_source_s is not None
    assert mission.last_check_s is not None
    assert mission.declared_s is not None
    assert mission.at_source_s <= mission.rule_at_source_s <= mission.last_check_s < mission.declared_s
    assert mission.checks >= 1
    assert mission.vouching_s is not None
    assert mission.check_ticks >= mission.vouching_s


def test_the_time_scale_stretches_or_cuts_the_limit_the_mission_runs_to() -> None:
    full = phases.mission_phases(SuiteMission(str(SUITE_DIR / "wang-laminar.toml"), 0))
    cut = phases.mission_phases(SuiteMission(str(SUITE_DIR / "wang-laminar.toml"), 0, time_scale=0.1))
    assert cut.limit_s == pytest.approx(0.1 * full.limit_s)
    assert full.declared_s is not None
    assert full.declared_s > cut.limit_s
    assert not cut.correct
    assert cut.declared_s is None


def test_json_gives_the_class_then_each_vehicle_kind(capsys: pytest.CaptureFixture[str]) -> None:
    # steady seeds 2 and 3 draw a rover and an AUV
    args = [
        "bench",
        "phases",
        "--class",
        "steady",
        "--runs",
        "2",
        "--first-seed",
        "2",
        "--jobs",
        "1",
        "--json",
    ]
    assert main(args) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(row["group"], row["missions"]) for row in rows] == [("steady", 2), ("rover", 1), ("auv", 1)]
    assert rows[0]["correct"] == rows[1]["correct"] + rows[2]["correct"]


def test_an_unknown_class_is_named() -> None:
    with pytest.raises(SystemExit, match="unknown class 'nowhere'"):
        main(["bench", "phases", "--class", "nowhere"])
