"""``oslim report``: a picture of a recorded run, drawn from the recording alone."""

import struct
from pathlib import Path

import numpy as np
import pytest

from service.api import Search
from service.cli import main
from service.core.config import build_config
from service.core.observation import Observation
from service.edges.foxglove_scene import SceneBuilder
from service.edges.recorder import Recorder
from service.tools.replay import replay
from service.tools.report import DPI, FIGSIZE_IN, ReportError, read_run

CONFIG = build_config({}, ["mapping.method=hmm", "area.columns=30", "area.rows=20", "vehicle.id=r1"])
EXPECTED_PX = (round(FIGSIZE_IN[0] * DPI), round(FIGSIZE_IN[1] * DPI))
SOURCE = (30.0, 10.0)


def observations() -> list[Observation]:
    """50 ticks of a vehicle zigzagging downflow of SOURCE, detecting near the plume's axis."""
    out = []
    for k in range(50):
        x, y = 40.0 + 1.2 * k, 10.0 + 25.0 * np.sin(k / 6.0)
        out.append(Observation(float(k), float(x), float(y), 1.0, 0.05, bool(abs(y - SOURCE[1]) < 6.0)))
    return out


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) from the PNG's IHDR chunk."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    return width, height


def record(directory: Path, *, declare: bool = True) -> Path:
    """A run recorded as the service records it, with the simulated source and a declaration."""
    search = Search(CONFIG)
    scene = SceneBuilder(cell_m=1.0, declared_radius_m=CONFIG.declaration.radius_m, source=SOURCE)
    states = ["search"] * 20 + ["trace"] * 30
    with Recorder(CONFIG, directory=directory) as rec:
        for obs, state in zip(observations(), states, strict=True):
            search.update_map(obs)
            estimate = search.estimate()
            rec.tick(obs, search.likelihood, search.plume, estimate=estimate, state=state)
            rec.write_messages(scene.tick(obs, 0.0, estimate=estimate, state=state))
        if declare:
            rec.write_event(obs.time_s, "source_declared", "declared", x=estimate.x, y=estimate.y)
    assert rec.path is not None
    return rec.path


def test_the_run_is_read_back_from_its_recording(tmp_path: Path) -> None:
    run = read_run(record(tmp_path))
    obs = observations()
    assert run.xy == [(o.x, o.y) for o in obs]
    assert run.detected == [o.detected for o in obs]
    assert run.states[:20] == ["search"] * 20
    assert run.states[20:] == ["trace"] * 30
    assert run.source == SOURCE
    assert run.declared is not None
    assert len(run.probability) == len(run.entropy) == len(obs)
    assert run.likelihood is not None
    assert run.likelihood.shape == (20, 30)
    assert np.isclose(run.likelihood.sum(), 1.0, atol=1e-4)


def test_the_drawable_channels_leave_replay_bit_for_bit(tmp_path: Path) -> None:
    report = replay(record(tmp_path))
    assert report.ok, report.summary()
    assert report.grids_compared == 100


def test_oslim_report_writes_a_png_of_the_expected_size(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = record(tmp_path)
    out = tmp_path / "run.png"
    assert main(["report", str(path), "-o", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert png_size(out) == EXPECTED_PX


def test_the_default_picture_sits_beside_the_recording(tmp_path: Path) -> None:
    path = record(tmp_path, declare=False)
    assert main(["report", str(path)]) == 0
    assert png_size(path.with_suffix(".png")) == EXPECTED_PX


def test_a_recording_without_observations_is_an_error(tmp_path: Path) -> None:
    with Recorder(CONFIG, directory=tmp_path) as rec:
        pass
    assert rec.path is not None
    with pytest.raises(ReportError, match="no observation"):
        read_run(rec.path)
    assert main(["report", str(tmp_path / "missing.mcap")]) == 2
