"""The plume benchmark returns measured figures (the full 10,000-puff run is marked slow)."""

from __future__ import annotations

import pytest

from service.core.errors import ConfigError
from sim_bridge.plume_bench import measure_plume


def test_small_bench_reports_consistent_figures() -> None:
    result = measure_plume(puffs=500, steps=10, repeats=3)
    assert result.live_puffs == pytest.approx(500, abs=2)
    assert result.steps_per_s == pytest.approx(1e3 / result.median_step_ms)
    assert result.real_time_factor == pytest.approx(result.steps_per_s * 0.1)
    assert result.worst_real_time_factor <= result.real_time_factor
    with pytest.raises(ConfigError):
        measure_plume(puffs=0)


@pytest.mark.slow
def test_ten_thousand_puffs_at_10_hz_run_faster_than_real_time() -> None:
    result = measure_plume(puffs=10_000, dt_s=0.1, steps=100, repeats=5)
    assert result.live_puffs == pytest.approx(10_000, abs=2)
    assert result.real_time_factor > 1.0, result
