"""The binary detector: threshold, missed detections (mu) per tick, Poisson false alarms."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from service.core.errors import ConfigError
from sim_bridge.detector import BinaryDetector, DetectorParams


def ticks(detector: BinaryDetector, concentration: float, n_ticks: int) -> np.ndarray:
    """Per-tick detection (the max of ten 10 Hz readings thresholded), as the service observes."""
    out = np.empty(n_ticks, dtype=bool)
    for k in range(n_ticks):
        readings = []
        for _ in range(10):
            readings.append(detector.read(concentration))
            detector.advance(0.1)
        out[k] = max(readings) >= detector.params.threshold
    return out


def test_a_perfect_detector_is_a_threshold() -> None:
    detector = BinaryDetector(DetectorParams(threshold=2.0), np.random.default_rng(0))
    assert ticks(detector, 2.0, 50).all()
    assert not ticks(detector, 1.99, 50).any()
    assert detector.read(3.5) == 3.5  # readings pass through untouched


def test_missed_detections_happen_with_probability_1_minus_mu_per_tick() -> None:
    mu = 0.7
    detector = BinaryDetector(DetectorParams(detection_probability=mu), np.random.default_rng(1))
    detected = ticks(detector, 5.0, 4000)
    assert detected.mean() == pytest.approx(mu, abs=0.03)  # binomial sd 0.007
    while detector.sensitive:
        detector.advance(1.0)
    assert detector.read(5.0) == 0.0  # a miss reports nothing


def test_false_alarms_arrive_at_the_configured_rate() -> None:
    rate_hz = 0.05
    detector = BinaryDetector(DetectorParams(false_alarm_rate_hz=rate_hz), np.random.default_rng(2))
    detected = ticks(detector, 0.0, 20_000)  # 20,000 s
    assert detected.sum() == pytest.approx(rate_hz * 20_000, rel=0.15)  # Poisson sd ~3 %


def test_same_seed_same_detections() -> None:
    params = DetectorParams(detection_probability=0.5, false_alarm_rate_hz=0.1)
    a = ticks(BinaryDetector(params, np.random.default_rng(3)), 1.5, 200)
    b = ticks(BinaryDetector(params, np.random.default_rng(3)), 1.5, 200)
    assert np.array_equal(a, b)


def test_a_slow_sensor_reads_through_a_first_order_lag() -> None:
    # a step of 2 units at t = 0, time constant 1 s: 2 (1 - exp(-t)) at t = 1 s, 2 s
    detector = BinaryDetector(DetectorParams(threshold=1.0, response_s=1.0), np.random.default_rng(0))
    assert detector.lags
    readings = []
    for _ in range(20):
        detector.sense(2.0, 0.1)
        detector.advance(0.1)
        readings.append(detector.read(0.0))  # the instantaneous value is not what it reads
    assert readings[9] == pytest.approx(2 * (1 - np.exp(-1.0)))
    assert readings[19] == pytest.approx(2 * (1 - np.exp(-2.0)))
    # the odour gone, the reading decays: still a detection 0.5 s later (2 x 0.86 x 0.61 = 1.05)
    for _ in range(5):
        detector.sense(0.0, 0.1)
    assert detector.detect(0.0)
    assert not BinaryDetector(DetectorParams(), np.random.default_rng(0)).lags


def test_reading_noise_has_its_stated_spread_and_leaves_the_misses_alone() -> None:
    params = DetectorParams(threshold=2.0, detection_probability=0.7)
    noisy = BinaryDetector(replace(params, noise_std=0.1), np.random.default_rng(4))
    quiet = BinaryDetector(params, np.random.default_rng(4))
    readings, blind = [], []
    for _ in range(2000):
        readings.append(noisy.read(3.0) - (3.0 if noisy.sensitive else 0.0))
        blind.append((noisy.sensitive, quiet.sensitive))
        noisy.advance(1.0)
        quiet.advance(1.0)
    assert np.std(readings) == pytest.approx(0.2, rel=0.05)  # 0.1 of the threshold of 2
    assert abs(np.mean(readings)) < 0.02
    assert all(a == b for a, b in blind)


@pytest.mark.parametrize(
    ("field", "value"),
    [("threshold", 0.0), ("detection_probability", 0.0), ("detection_probability", 1.5),
     ("false_alarm_rate_hz", -1.0), ("hold_s", 0.0), ("response_s", -1.0),
     ("noise_std", -0.1)],
)  # fmt: skip
def test_bad_detector_parameters_are_refused(field: str, value: float) -> None:
    with pytest.raises(ConfigError, match=field):
        DetectorParams(**{field: value})
