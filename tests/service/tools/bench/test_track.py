"""``oslim bench track``: one suite mission tick by tick, in the true source's frame."""

from __future__ import annotations

import json
import math

import pytest

from service.cli import main
from service.tools.bench import track
from service.tools.bench.search import run_mission
from service.tools.bench.suite import SuiteMission, drawn_world, source_frame
from sim_bridge.generator import SUITE_DIR

WANG = SuiteMission(str(SUITE_DIR / "wang-laminar.toml"), 0)


def tick(time_s: float, state: str = "trace", detected: bool = False) -> track.TrackTick:
    return track.TrackTick(time_s, state, 0.0, 0.0, detected, 0.0, 0.0, 0.0, 0.0)


def test_shown_keeps_one_tick_a_period_each_detection_each_change_of_state_and_the_last() -> None:
    ticks = (
        tick(1, "search"),
        tick(2, "search"),
        tick(3, "trace", detected=True),
        tick(4),
        tick(5),
        tick(6),
        tick(7, "lost"),
        tick(8, "lost"),
        tick(9, "lost"),
        tick(10, "lost"),
        tick(11, "lost"),
        tick(12, "lost"),
    )
    assert [t.time_s for t in track.shown(ticks, 5.0)] == [1, 3, 5, 7, 10, 12]
    assert [t.time_s for t in track.shown(ticks, 0.0)] == list(range(1, 13))


def test_a_mission_is_tracked_in_the_sources_frame_to_its_declaration() -> None:
    mission = track.mission_track(WANG)
    assert mission.outcome == track.SUCCESS
    assert len(mission.ticks) == round(mission.time_s)
    assert mission.ticks[0].state == "search"
    assert mission.ticks[-1].state == "declared"
    first = next(t for t in mission.ticks if t.detected)
    assert mission.first_odour_s == first.time_s
    last = mission.ticks[-1]
    assert math.hypot(last.estimate_along_m, last.estimate_across_m) < 2.0  # the declared cell
    assert 0.0 < last.estimate_share <= last.mass <= 1.0 + 1e-9

    # the frame is a rotation about the source: distances to it are the world's
    drawn = drawn_world(WANG)
    sx, sy = source_frame(drawn, WANG.seed).source
    recorded = run_mission(drawn.scenario, WANG.seed, max_time_s=drawn.time_limit_s, record=True).trace
    assert recorded is not None
    for point, t in zip(recorded.track, mission.ticks, strict=True):
        assert math.hypot(t.along_m, t.across_m) == pytest.approx(math.hypot(point.x - sx, point.y - sy))
        assert t.detected == point.detected


def test_a_mission_cut_short_by_the_time_scale_ends_undeclared() -> None:
    mission = track.mission_track(SuiteMission(WANG.class_path, 0, time_scale=0.1))
    assert mission.outcome != track.SUCCESS
    assert mission.limit_s == pytest.approx(0.1 * track.mission_track(WANG).limit_s)
    assert all(t.state != "declared" for t in mission.ticks)


def test_json_gives_the_mission_then_the_ticks_shown(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "track", "--class", "wang-laminar", "--seed", "0", "--every", "20", "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert rows[0]["class"] == "wang-laminar"
    assert rows[0]["outcome"] == "success"
    times = [row["time_s"] for row in rows[1:]]
    assert times == sorted(times)
    assert rows[1]["time_s"] == 1.0
    assert rows[-1]["state"] == "declared"
    assert sum(row["detected"] for row in rows[1:]) == rows[0]["detections"]  # every detection is shown


def test_an_unknown_class_is_named() -> None:
    with pytest.raises(SystemExit, match="unknown class 'nowhere'"):
        main(["bench", "track", "--class", "nowhere", "--seed", "0"])
