import math

import numpy as np
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


def test_a_slow_sensors_readings_are_turned_back_into_what_it_met() -> None:
    # tau = 0.4 s, readings every 0.2 s (half the time constant apart). A filament of 1.5 units met
    # for 0.2 s reads only 1.5 (1 - exp(-0.5)) = 0.59, below the threshold of 1; inverted, 1.5
    tau, dt = 0.4, 0.2
    gain = 1.0 - math.exp(-dt / tau)
    agg = TickAggregator(threshold=1.0, response_s=tau)
    agg.add(Position(0.0, 0.0, 0.0))
    agg.add(FlowSample(0.0, 1.0, 0.0))
    agg.add(ChemSample(0.0, 0.0))
    agg.add(ChemSample(dt, 1.5 * gain))
    obs = agg.close(0.5).observation
    assert obs is not None
    assert obs.detected
    # odour held at 5 brings the reading to 4; then the vehicle leaves it and the reading
    # decays, still at or above the threshold in the next tick's first readings: nothing met there
    agg.add(ChemSample(0.4, 4.0 - gain))
    agg.add(ChemSample(0.6, 4.0))
    agg.add(FlowSample(0.6, 1.0, 0.0))
    obs = agg.close(0.6).observation
    assert obs is not None
    assert obs.detected
    readings = [4.0 * math.exp(-k * dt / tau) for k in range(1, 5)]
    assert sum(r >= 1.0 for r in readings) == 2
    for k, reading in enumerate(readings, start=1):
        agg.add(ChemSample(0.6 + k * dt, reading))
    agg.add(FlowSample(1.0, 1.0, 0.0))
    obs = agg.close(1.5).observation
    assert obs is not None
    assert not obs.detected


def test_the_inversion_does_not_turn_a_slow_sensors_noise_into_odour() -> None:
    # tau = 2 s, readings at 5 Hz with noise of 0.1 of the threshold and no odour. Inverted over
    # 0.2 s the noise would be about 13 times as large (a false detection in most ticks); over
    # tau / 2 it is about 3 times, 0.3 of the threshold
    rng = np.random.default_rng(7)
    agg = TickAggregator(threshold=1.0, response_s=2.0)
    detections = 0
    for tick in range(1, 1001):
        agg.add(Position(float(tick), 0.0, 0.0))
        agg.add(FlowSample(float(tick), 1.0, 0.0))
        for k in range(5):
            agg.add(ChemSample(tick - 1 + 0.2 * (k + 1), 0.1 * float(rng.standard_normal())))
        obs = agg.close(float(tick)).observation
        assert obs is not None
        detections += obs.detected
    assert detections < 10


def test_an_instantaneous_sensors_readings_are_taken_as_they_come() -> None:
    agg = TickAggregator(threshold=1.0)
    agg.add(Position(0.2, 1.0, 0.0))
    agg.add(FlowSample(0.5, 1.0, 0.0))
    agg.add(ChemSample(0.5, 0.0))
    agg.add(ChemSample(0.7, 0.9))
    obs = agg.close(1.0).observation
    assert obs is not None
    assert not obs.detected
