"""``oslim bench model``: the mapper's P(detection) at the true source against the detector."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.cli import main
from service.tools.bench import reliability
from service.tools.bench.suite import SuiteMission
from sim_bridge.generator import SUITE_DIR


def test_bands_average_the_model_and_the_detector_over_their_ticks() -> None:
    ticks = reliability.Ticks(
        along_m=np.array([-5.0, -5.0, 0.5, 0.5, 0.5, 20.0, 5.0]),
        across_m=np.array([0.0, 1.0, 0.0, 1.9, 1.0, 0.5, 3.0]),
        predicted=np.array([0.1, 0.3, 0.6, 0.7, 0.8, 0.4, 0.2]),
        detected=np.array([False, False, True, False, True, True, False]),
    )
    by_label = {band.label: band for band in reliability.bands(ticks)}
    upflow = by_label["on the line, 10-3 m upflow"]
    assert (upflow.ticks, upflow.predicted, upflow.detected) == (2, pytest.approx(0.2), 0.0)
    at = by_label["on the line, within 1 m of the source"]
    assert (at.ticks, at.predicted, at.detected) == (3, pytest.approx(0.7), pytest.approx(2 / 3))
    assert by_label["on the line, 10-30 m downflow"].detected == 1.0
    assert by_label["2-5 m across, 1 m upflow to 30 m downflow"].ticks == 1
    empty = by_label["on the line, over 30 m downflow"]
    assert (empty.ticks, empty.predicted, empty.detected) == (0, None, None)


def test_a_mission_gives_the_models_chance_at_the_true_source_each_tick() -> None:
    """Upflow of the source (beyond the detector's footprint, 0.8 m, and the source cell's width)
    the model can only foresee a false alarm (0.1 by default), and the world's detector fires there
    rarely: the measure reads the model at the right cell."""
    ticks = reliability.mission_ticks(SuiteMission(str(SUITE_DIR / "steady.toml"), 0))
    assert ticks.predicted.size > 50
    assert ((ticks.predicted >= 0.0) & (ticks.predicted <= 1.0)).all()
    far_upflow = (ticks.along_m < -2.5) & (ticks.across_m < 2.0)
    assert far_upflow.any()
    assert ticks.predicted[far_upflow].max() < 0.12
    near = (np.abs(ticks.along_m) < 1.0) & (ticks.across_m < 2.0)
    assert ticks.predicted[near].mean() > 0.2


def test_json_gives_every_band_of_every_class(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "model", "--class", "steady", "--runs", "1", "--jobs", "1", "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [row["band"] for row in rows] == [band[0] for band in reliability.BANDS]
    assert {row["class"] for row in rows} == {"steady"}
    assert sum(row["ticks"] for row in rows) > 0


def test_an_unknown_class_is_named() -> None:
    with pytest.raises(SystemExit, match="unknown class 'nowhere'"):
        main(["bench", "model", "--class", "nowhere"])
