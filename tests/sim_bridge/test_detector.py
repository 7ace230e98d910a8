"""The binary detector: threshold, missed detections (mu) per tick, Poisson false alarms."""

from __future__ import annotations

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


@pytest.mark.parametrize(
    ("field", "value"),
    [("threshold", 0.0), ("detection_probability", 0.0), ("detection_probability", 1.5),
     ("false_alarm_rate_hz", -1.0), ("hold_s", 0.0)],
)  # fmt: skip
def test_bad_detector_parameters_are_refused(field: str, value: float) -> None:
    with pytest.raises(ConfigError, match=field):
        DetectorParams(**{field: value})
