import pytest

from service.core.observation import Observation
from service.core.samples import ChemSample, DetectionSample, FlowSample, Position
from service.core.tick import TickAggregator


def test_mean_flow_and_peak_reading() -> None:
    agg = TickAggregator(threshold=2.0)
    agg.add(Position(0.1, 10.0, 5.0))
    for t, (fx, fy) in enumerate([(1.0, 0.0), (2.0, 1.0), (0.0, -1.0), (1.0, 4.0)]):
        agg.add(FlowSample(0.2 * t, fx, fy))
    for value in (0.5, 2.5, 1.0):
        agg.add(ChemSample(0.5, value))
    agg.add(Position(0.9, 11.0, 5.5))
    tick = agg.close(1.0)
    # eq. 1-2: the mean of the tick's samples; the peak reading 2.5 >= 2.0 is a detection
    assert tick.observation == Observation(1.0, 11.0, 5.5, 1.0, 1.0, True)
    assert tick.gaps == ()
    assert tick.samples == 9


def test_below_threshold_is_a_non_detection() -> None:
    agg = TickAggregator(threshold=2.0)
    agg.add(Position(0.1, 0.0, 0.0))
    agg.add(FlowSample(0.2, 1.0, 0.0))
    agg.add(ChemSample(0.5, 1.99))
    obs = agg.close(1.0).observation
    assert obs is not None
    assert not obs.detected


def test_binary_detection_stream() -> None:
    agg = TickAggregator(threshold=2.0)
    agg.add(Position(0.1, 0.0, 0.0))
    agg.add(FlowSample(0.2, 1.0, 0.0))
    agg.add(DetectionSample(0.3, False))
    agg.add(DetectionSample(0.4, True))
    agg.add(DetectionSample(0.5, False))
    obs = agg.close(1.0).observation
    assert obs is not None
    assert obs.detected


@pytest.mark.parametrize("missing", ["position", "flow", "chemical"])
def test_silent_stream_gives_a_gap_not_an_observation(missing: str) -> None:
    agg = TickAggregator(threshold=1.0)
    if missing != "position":
        agg.add(Position(0.5, 0.0, 0.0))
    if missing != "flow":
        agg.add(FlowSample(0.5, 1.0, 0.0))
    if missing != "chemical":
        agg.add(ChemSample(0.5, 5.0))
    tick = agg.close(1.0)
    assert tick.observation is None
    assert tick.gaps == (missing,)


def test_samples_do_not_leak_into_the_next_tick_and_position_ages_out() -> None:
    agg = TickAggregator(threshold=1.0, max_position_age_s=2.0)
    agg.add(Position(0.5, 3.0, 4.0))
    agg.add(FlowSample(0.5, 1.0, 0.0))
    agg.add(ChemSample(0.5, 5.0))
    assert agg.close(1.0).observation is not None
    agg.add(FlowSample(1.5, 0.0, 2.0))
    agg.add(ChemSample(1.5, 0.0))
    second = agg.close(2.0).observation
    assert second == Observation(2.0, 3.0, 4.0, 0.0, 2.0, False)  # position carried, flow/chem fresh
    assert agg.close(2.4).gaps == ("flow", "chemical")
    agg.add(FlowSample(3.5, 0.0, 2.0))
    agg.add(ChemSample(3.5, 0.0))
    assert agg.close(4.0).gaps == ("position",)  # 3.5 s old


def test_local_position_preferred_over_global() -> None:
    agg = TickAggregator(threshold=1.0, max_position_age_s=2.0)
    agg.add(Position(0.2, 1.0, 2.0))
    agg.add(Position(0.5, 50.0, 60.0, local=False))  # ignored: a fresh local fix exists
    agg.add(FlowSample(0.5, 1.0, 0.0))
    agg.add(ChemSample(0.5, 0.0))
    obs = agg.close(1.0).observation
    assert obs is not None
    assert (obs.x, obs.y) == (1.0, 2.0)
    agg.add(Position(3.5, 50.0, 60.0, local=False))  # the local stream went quiet: global stands in
    agg.add(FlowSample(3.5, 1.0, 0.0))
    agg.add(ChemSample(3.5, 0.0))
    obs = agg.close(4.0).observation
    assert obs is not None
    assert (obs.x, obs.y) == (50.0, 60.0)
