"""service.tools.bench.mapping: per-tick time of the papers' models or of a configuration's."""

from __future__ import annotations

import json

import pytest

from service.cli import main
from service.core.config import load_config
from service.core.mapping import MapperParams
from service.tools.bench import mapping


def test_measure_uses_the_given_model_with_the_given_window() -> None:
    params = MapperParams.from_config(load_config(None))
    result = mapping.measure("pomdp", 1_000, 7, 3, params=params, model="config/default.toml")
    assert (result.mapper, result.model, result.cells, result.window, result.ticks) == (
        "pomdp", "config/default.toml", 1_000, 7, 3,
    )  # fmt: skip
    assert 0.0 < result.median_ms <= result.p95_ms


def test_the_papers_models_are_the_default() -> None:
    result = mapping.measure("bayes", 1_000, 5, 2)
    assert result.model == mapping.PAPERS


def test_the_command_times_the_configured_model_with_its_own_window(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code = main(
        ["bench", "mapping", "--mapper", "pomdp", "--cells", "1000", "--ticks", "2", "--json",
         "--set", "mapping.window=12"]
    )  # fmt: skip
    assert code == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert rows[0]["model"] == "config/default.toml --set mapping.window=12"
    assert rows[0]["window"] == 12
    assert rows[-1]["limit"] == "memory_bandwidth"


def test_the_command_says_which_model_it_timed(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "mapping", "--mapper", "bayes", "--cells", "1000", "--ticks", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "model: the papers'"
    assert lines[2].split()[:3] == ["bayes", "1000", "200"]


def test_a_broken_configuration_names_the_key(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["bench", "mapping", "--cells", "1000", "--set", "mapping.window=abc"])
    assert code != 0
    assert "mapping.window" in capsys.readouterr().err
