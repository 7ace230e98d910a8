import json
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType

from service.api import Search
from service.cli import main
from service.core.config import Config, build_config
from service.core.grid import Grid
from service.core.mapping import MAPPERS, mapper_from_config
from service.core.observation import Observation
from service.edges.recorder import Recorder
from service.tools.replay import ReplayError, replay

TICKS = 50
SOURCE = (30.0, 10.0)


def observations(seed: int = 2) -> list[Observation]:
    """A vehicle sweeping across the flow downstream of SOURCE; detections near the plume axis."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(TICKS):
        x = 40.0 + 1.2 * k
        y = 10.0 + 25.0 * np.sin(k / 6.0)
        flow_y = 0.1 * rng.normal()
        detected = abs(y - SOURCE[1]) < 6.0 and rng.random() < 0.7
        out.append(Observation(float(k), float(x), float(y), 1.0, float(flow_y), bool(detected)))
    return out


def record(
    directory: Path,
    config: Config,
    *,
    corrupt_tick: int | None = None,
    compression: CompressionType = CompressionType.ZSTD,
) -> Path:
    """Record a run exactly as the service does: update, then record the obs and the maps."""
    search = Search(config)
    with Recorder(config, directory=directory, compression=compression) as rec:
        for tick, obs in enumerate(observations(), start=1):
            search.update_map(obs)
            slim = np.array(search.likelihood)
            if tick == corrupt_tick:
                # one cell off by one float32 ulp: the smallest change a recording can hold
                slim32 = slim.astype(np.float32)
                slim[3, 4] = np.nextafter(slim32[3, 4], np.float32(1.0))
            rec.tick(
                obs, slim, search.plume, estimate=search.estimate(), state="search", path=[(obs.x, obs.y)]
            )
    assert rec.path is not None
    return rec.path


def config_for(method: str) -> Config:
    return build_config({}, [f"mapping.method={method}", "area.columns=30", "area.rows=20", "vehicle.id=r1"])


@pytest.mark.parametrize("method", sorted(MAPPERS))
def test_replay_reproduces_every_recorded_map_bit_for_bit(tmp_path: Path, method: str) -> None:
    report = replay(record(tmp_path, config_for(method)))
    assert report.ok, report.summary()
    assert (report.ticks, report.grids_compared, report.estimates_compared) == (TICKS, 2 * TICKS, TICKS)
    assert report.max_abs_diff == 0.0
    assert report.complete


def test_the_recorded_run_is_not_trivial(tmp_path: Path) -> None:
    """The comparison means something only if the maps moved away from uniform."""
    config = config_for("hmm")
    mapper = mapper_from_config(config, Grid.from_config(config.area))
    for obs in observations():
        mapper.update(obs)
    assert sum(o.detected for o in observations()) >= 5
    assert mapper.likelihood.max() > 3.0 / mapper.grid.size


def test_oslim_replay_exits_0_and_prints_the_summary(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = record(tmp_path, config_for("hmm"))
    assert main(["replay", str(path)]) == 0
    out = capsys.readouterr().out
    assert "OK" in out
    assert "ticks 50, grids compared 100, estimates compared 50, mismatches 0, max abs difference 0" in out
    assert main(["replay", "--json", str(path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary == {
        "path": str(path), "ticks": 50, "grids_compared": 100, "estimates_compared": 50,
        "max_abs_diff": 0.0, "complete": True, "ok": True, "mismatches": 0,
    }  # fmt: skip


def test_one_corrupted_grid_value_is_reported_and_fails(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = record(tmp_path, config_for("hmm"), corrupt_tick=30)
    report = replay(path)
    assert not report.ok
    [mismatch] = report.mismatches
    assert (mismatch.tick, mismatch.topic) == (30, "/oslim/slim")
    assert "1 cells differ" in mismatch.detail
    assert "row 3 column 4" in mismatch.detail
    assert 0.0 < report.max_abs_diff < 1e-6
    assert main(["replay", str(path)]) == 1
    out = capsys.readouterr().out
    assert "FAILED" in out
    assert "mismatches 1" in out
    assert "tick 30 /oslim/slim" in out


def test_a_file_cut_short_replays_what_it_holds(tmp_path: Path) -> None:
    path = record(tmp_path, config_for("hmm"))
    data = path.read_bytes()
    cut = tmp_path / "crashed.mcap"
    cut.write_bytes(data[: len(data) * 6 // 10])
    report = replay(cut)
    assert report.ok, report.summary()
    assert not report.complete
    assert 0 < report.ticks < TICKS
    assert report.grids_compared >= 2 * report.ticks - 2
    assert "cut short" in report.summary()


def test_damaged_bytes_are_an_unreadable_file_not_a_pass(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = record(tmp_path, config_for("hmm"), compression=CompressionType.NONE)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x40  # inside a chunk: its CRC no longer matches
    path.write_bytes(bytes(data))
    with pytest.raises(ReplayError, match="unreadable"):
        replay(path)
    assert main(["replay", str(path)]) == 2
    assert "unreadable" in capsys.readouterr().err


def test_a_recording_without_grids_does_not_pass(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with Recorder(config_for("hmm"), directory=tmp_path) as rec:
        pass
    assert rec.path is not None
    assert main(["replay", str(rec.path)]) == 1
    assert "no recorded grid" in capsys.readouterr().out


def test_a_missing_file_is_an_error(tmp_path: Path) -> None:
    assert main(["replay", str(tmp_path / "nope.mcap")]) == 2


def test_replay_counts_every_tick_it_replays(tmp_path: Path) -> None:
    """The progress callback (a line on a terminal) hears of each replayed tick once."""
    path = record(tmp_path, config_for("hmm"))
    done: list[int] = []
    report = replay(path, done.append)
    assert done == [1] * report.ticks
    assert report.ticks == TICKS
