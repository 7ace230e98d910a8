"""``oslim bench compare``: two suite runs paired mission by mission, with an exact sign test on the
outcomes and a signed-rank test on the times."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from service.cli import main
from service.tools.bench import compare
from service.tools.bench.search import MissionResult


def _write(path: Path, outcomes: dict[tuple[str, int], tuple[bool, bool, float]]) -> Path:
    """A missions file: (class, seed) -> (correct, wrong, time_s)."""
    rows = [
        {"class": name, "seed": seed, "correct": ok, "wrong": wrong, "time_s": t}
        for (name, seed), (ok, wrong, t) in outcomes.items()
    ]
    path.write_text("".join(json.dumps(row) + "\n" for row in rows), encoding="utf-8")
    return path


def test_the_sign_test_is_the_exact_binomial_tail() -> None:
    assert compare.sign_test(0, 0) == 1.0
    # six changed missions all lost: 2 x (1/2)^6
    assert compare.sign_test(0, 6) == pytest.approx(2 / 64)
    # 1 gained, 5 lost: 2 x (1 + 6) / 64
    assert compare.sign_test(1, 5) == pytest.approx(14 / 64)
    assert compare.sign_test(3, 3) == pytest.approx(1.0)


def test_the_signed_rank_test_is_the_exact_wilcoxon_tail() -> None:
    assert compare.signed_rank_test([]) == 1.0
    assert compare.signed_rank_test([0.0, 0.0]) == 1.0  # ties at zero say nothing
    # eight differences of one sign, distinct sizes: only the all-negative and all-positive of the
    # 2^8 equally likely sign patterns have a rank sum as extreme
    assert compare.signed_rank_test([-1.0, -2.0, -3.0, -4.0, -5.0, -6.0, -7.0, -8.0]) == pytest.approx(
        2 / 256
    )
    # ranks 1-4 with signs - - + +: W+ = 7 of 10; of the 16 patterns, 10 have a rank sum of 3 or
    # less, or 7 or more
    assert compare.signed_rank_test([-1.0, -2.0, 3.0, 4.0, 0.0]) == pytest.approx(10 / 16)


def test_a_time_saving_on_every_mission_is_beyond_the_noise(tmp_path: Path) -> None:
    a = _write(tmp_path / "a.jsonl", {("steady", s): (True, False, 100.0 + s) for s in range(8)})
    b = _write(tmp_path / "b.jsonl", {("steady", s): (True, False, 99.0 - s) for s in range(8)})
    result = compare.compare(compare.load_missions(a), compare.load_missions(b))
    total = result.total
    assert (total.gained, total.lost, total.both) == (0, 0, 8)
    assert total.time_change_s == pytest.approx(-8.0)  # differences -1, -3, ..., -15
    assert total.time_p_value == pytest.approx(2 / 256)
    assert "within the noise" in result.verdict()  # the outcomes did not change
    assert "beyond the noise" in result.time_verdict()
    assert result.time_verdict().startswith("median -8.0 s over the 8 missions both succeeded in")


def test_missions_are_paired_by_class_and_seed(tmp_path: Path) -> None:
    a = _write(tmp_path / "a.jsonl", {
        ("steady", 0): (True, False, 100.0), ("steady", 1): (False, False, 300.0),
        ("steady", 2): (True, False, 120.0), ("patchy", 0): (False, True, 90.0),
        ("patchy", 1): (False, False, 400.0), ("patchy", 9): (True, False, 50.0),
    })  # fmt: skip
    b = _write(tmp_path / "b.jsonl", {
        ("steady", 0): (True, False, 90.0), ("steady", 1): (True, False, 250.0),
        ("steady", 2): (False, False, 300.0), ("patchy", 0): (True, False, 80.0),
        ("patchy", 1): (True, False, 200.0), ("slow-flow", 0): (True, False, 10.0),
    })  # fmt: skip
    result = compare.compare(compare.load_missions(a), compare.load_missions(b))
    assert (result.only_a, result.only_b) == (1, 1)
    patchy, steady = result.classes
    assert (patchy.name, patchy.missions, patchy.a, patchy.b, patchy.gained, patchy.lost) == (
        "patchy",
        2,
        0,
        2,
        2,
        0,
    )
    assert (patchy.wrong_a, patchy.wrong_b) == (1, 0)
    assert patchy.time_change_s is None  # no mission succeeded on both sides
    assert (patchy.both, patchy.time_p_value) == (0, 1.0)
    assert (steady.a, steady.b, steady.gained, steady.lost) == (2, 2, 1, 1)
    assert steady.time_change_s == pytest.approx(-10.0)
    total = result.total
    assert (total.missions, total.gained, total.lost) == (5, 3, 1)
    assert total.p_value == pytest.approx(compare.sign_test(3, 1))
    assert result.worst("a") == ("patchy", 0.0)
    assert "within the noise" in result.verdict()


def test_a_one_sided_change_is_beyond_the_noise(tmp_path: Path) -> None:
    a = _write(tmp_path / "a.jsonl", {("steady", s): (False, False, 300.0) for s in range(8)})
    b = _write(tmp_path / "b.jsonl", {("steady", s): (True, False, 100.0) for s in range(8)})
    result = compare.compare(compare.load_missions(a), compare.load_missions(b))
    assert result.total.p_value == pytest.approx(2 / 256)
    assert "beyond the noise" in result.verdict()


def test_a_broken_file_is_refused_with_its_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = _write(tmp_path / "good.jsonl", {("steady", 0): (True, False, 100.0)})
    bad = tmp_path / "bad.jsonl"
    bad.write_text(
        '{"class": "steady", "seed": 0, "correct": true, "wrong": false, "time_s": 1}\n{"seed": 1}\n'
    )
    with pytest.raises(SystemExit, match=r"bad.jsonl, line 2: not a mission line"):
        main(["bench", "compare", str(good), str(bad)])
    other = _write(tmp_path / "other.jsonl", {("patchy", 0): (True, False, 100.0)})
    with pytest.raises(SystemExit, match="no mission"):
        main(["bench", "compare", str(good), str(other)])
    twice = tmp_path / "twice.jsonl"
    twice.write_text((good.read_text()) * 2)
    with pytest.raises(SystemExit, match="appears twice"):
        main(["bench", "compare", str(good), str(twice)])


def test_a_mission_line_carries_the_outcome() -> None:
    result = MissionResult(7, 0.0, 0.0, True, False, 80.0, 5.0, 5.0, 7.1, 120.0, 30.0, confidence=0.9,
                           radius_m=3.0, vehicle_speed_mps=1.2)  # fmt: skip
    row = compare.mission_row("meander", result, 250.0)
    assert row["class"] == "meander"
    assert row["seed"] == 7
    assert row["wrong"] is True
    assert row["correct"] is False
    assert row["failure"] == "wrong"
    assert row["limit_s"] == 250.0
    assert row["vehicle_speed_mps"] == 1.2
    json.dumps(row)  # a JSON line


def test_the_suite_writes_its_missions_for_compare(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A suite run with --missions, compared with itself: every mission pairs and none changes."""
    missions = tmp_path / "missions.jsonl"
    missions.write_text("stale\n")  # a rerun starts the file anew
    assert main(["bench", "suite", "--runs", "2", "--class", "steady", "--jobs", "1", "--json",
                 "--missions", str(missions)]) == 0  # fmt: skip
    suite_rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    rows = [json.loads(line) for line in missions.read_text().splitlines()]
    assert [(r["class"], r["seed"]) for r in rows] == [("steady", 0), ("steady", 1)]
    assert sum(r["correct"] for r in rows) / 2 == suite_rows[0]["success_rate"]
    assert main(["bench", "compare", str(missions), str(missions), "--json"]) == 0
    steady, total = (json.loads(line) for line in capsys.readouterr().out.splitlines())
    assert steady["class"] == "steady"
    assert total["class"] == "all"
    assert (total["missions"], total["gained"], total["lost"], total["p_value"]) == (2, 0, 0, 1.0)
    succeeded = sum(r["correct"] for r in rows)
    assert (total["both_succeeded"], total["time_p_value"]) == (succeeded, 1.0)
    assert main(["bench", "compare", str(missions), str(missions)]) == 0
    text = capsys.readouterr().out
    assert "2 missions paired" in text
    assert "verdict: B - A = +0 of 2 missions" in text
    if succeeded:
        assert (
            f"time: median +0.0 s over the {succeeded} missions both succeeded in; signed-rank p = 1:" in text
        )
    else:
        assert "time: no mission succeeded on both sides" in text
