import errno
import json
import logging
import os
import selectors
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from service.core.config import Config, build_config
from service.core.errors import ConfigError
from service.core.mapping.mapper import Estimate
from service.core.observation import Observation
from service.edges.foxglove_scene import SCHEMAS as SCENE_SCHEMAS
from service.edges.foxglove_scene import VEHICLE_TOPIC, SceneBuilder
from service.edges.grid_message import decode_grid
from service.edges.recorder import (
    CONFIG_TOPIC,
    ESTIMATE_TOPIC,
    EVENT_TOPIC,
    OBS_TOPIC,
    PATH_TOPIC,
    PLUME_TOPIC,
    SETPOINT_TOPIC,
    SLIM_TOPIC,
    RecordedMessage,
    Recorder,
    RecordingReader,
)
from service.tools.replay import replay

CONFIG = build_config({}, ["vehicle.id=auv-3", "area.columns=9", "area.rows=5", "mapping.method=hmm"])
SHAPE = (5, 9)
STARTED_NS = 1_704_164_645_250_000_000  # 2024-01-02T03:04:05.25Z
TIMEOUT_S = 30.0


def clock() -> int:
    return STARTED_NS


def obs_of(k: int) -> Observation:
    """Floats that a lossy recording would not keep (0.1 + 0.2, thirds, tiny numbers)."""
    return Observation(time_s=k + 0.1 + 0.2, x=3.0 + k / 3.0, y=-7.0 - 1e-13 * k, flow_x=1e-300,
                       flow_y=-(0.5 + k / 7.0), detected=k % 3 == 0)  # fmt: skip


def maps_of(k: int) -> tuple[np.ndarray[Any, np.dtype[np.float64]], np.ndarray[Any, np.dtype[np.float64]]]:
    slim = np.random.default_rng(k).random(SHAPE)
    return slim, slim[::-1, ::-1] / 7.0


def by_topic(messages: list[RecordedMessage]) -> dict[str, list[RecordedMessage]]:
    out: dict[str, list[RecordedMessage]] = {}
    for message in messages:
        out.setdefault(message.topic, []).append(message)
    return out


def record_run(directory: Path, ticks: int, config: Config = CONFIG) -> Path:
    with Recorder(config, directory=directory, clock_ns=clock) as rec:
        for k in range(ticks):
            slim, plume = maps_of(k)
            estimate = Estimate(cell=k + 1, x=1.5, y=-2.5, probability=1 / 3, entropy=2.0 + k)
            assert rec.tick(obs_of(k), slim, plume, estimate=estimate, state="search", path=[(1.0, 2.0)])
            assert rec.write_setpoint(k + 0.5, 4.0, 5.0, -1.0)
        assert rec.write_event(ticks + 0.3, "source_declared", "source at (1.5, -2.5)", x=1.5, y=-2.5)
        assert rec.ticks == ticks
    assert rec.path is not None
    return rec.path


def test_file_is_named_after_the_vehicle_and_utc_start_and_never_overwritten(tmp_path: Path) -> None:
    first = record_run(tmp_path / "new" / "runs", 1)  # the directory is created
    second = record_run(tmp_path / "new" / "runs", 1)
    assert first.name == "auv-3_20240102T030405Z.mcap"
    assert second.name == "auv-3_20240102T030405Z-1.mcap"


def test_everything_recorded_reads_back_exactly(tmp_path: Path) -> None:
    path = record_run(tmp_path, 4)
    reader = RecordingReader(path)
    topics = by_topic(list(reader.messages()))
    assert reader.complete
    [config] = topics[CONFIG_TOPIC]
    assert build_config(json.loads(config.data)) == CONFIG
    assert [json.loads(m.data) for m in topics[OBS_TOPIC]] == [
        {
            "time_s": o.time_s,
            "x": o.x,
            "y": o.y,
            "flow_x": o.flow_x,
            "flow_y": o.flow_y,
            "detected": o.detected,
        }
        for o in map(obs_of, range(4))
    ]
    for k in range(4):
        slim, plume = maps_of(k)
        assert np.array_equal(decode_grid(topics[SLIM_TOPIC][k].data), slim.astype(np.float32))
        assert np.array_equal(decode_grid(topics[PLUME_TOPIC][k].data), plume.astype(np.float32))
    # the tick number ties each output to its observation
    for topic in (OBS_TOPIC, SLIM_TOPIC, PLUME_TOPIC, ESTIMATE_TOPIC, PATH_TOPIC):
        assert [m.sequence for m in topics[topic]] == [1, 2, 3, 4]
    assert json.loads(topics[ESTIMATE_TOPIC][2].data) == {
        "time_s": obs_of(2).time_s, "state": "search", "cell": 3, "x": 1.5, "y": -2.5,
        "probability": 1 / 3, "entropy": 4.0,
    }  # fmt: skip
    assert json.loads(topics[PATH_TOPIC][0].data) == {
        "time_s": 0.30000000000000004,
        "waypoints": [[1.0, 2.0]],
    }
    assert json.loads(topics[SETPOINT_TOPIC][1].data) == {"time_s": 1.5, "x": 4.0, "y": 5.0, "z": -1.0}
    assert json.loads(topics[EVENT_TOPIC][0].data) == {
        "time_s": 4.3, "name": "source_declared", "text": "source at (1.5, -2.5)", "x": 1.5, "y": -2.5,
    }  # fmt: skip
    assert {m.log_time_ns for m in topics[OBS_TOPIC]} == {STARTED_NS}


def test_the_mcap_reader_sees_the_channels_and_schemas_foxglove_needs(tmp_path: Path) -> None:
    path = record_run(tmp_path, 3)
    with open(path, "rb") as file:
        reader = make_reader(file, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: c for c in summary.channels.values()}
        assert set(channels) == {CONFIG_TOPIC, OBS_TOPIC, SLIM_TOPIC, PLUME_TOPIC, ESTIMATE_TOPIC, PATH_TOPIC,
                                 SETPOINT_TOPIC, EVENT_TOPIC, *SCENE_SCHEMAS}  # fmt: skip
        for topic, channel in channels.items():
            schema = summary.schemas[channel.schema_id]
            if topic in SCENE_SCHEMAS:
                name = SCENE_SCHEMAS[topic].DESCRIPTOR.full_name
                assert name.startswith("foxglove.")
                encodings = (channel.message_encoding, schema.encoding, schema.name)
                assert encodings == ("protobuf", "protobuf", name)
                files = {f.name for f in FileDescriptorSet.FromString(schema.data).file}
                assert f"foxglove/{name.removeprefix('foxglove.')}.proto" in files
            elif topic in (SLIM_TOPIC, PLUME_TOPIC):
                assert (channel.message_encoding, schema.encoding, schema.name) == (
                    "protobuf", "protobuf", "foxglove.Grid"
                )  # fmt: skip
                files = {f.name for f in FileDescriptorSet.FromString(schema.data).file}
                assert "foxglove/Grid.proto" in files
            else:
                assert (channel.message_encoding, schema.encoding) == ("json", "jsonschema")
                assert json.loads(schema.data)["type"] == "object"
        assert summary.statistics is not None
        assert summary.statistics.channel_message_counts[channels[SLIM_TOPIC].id] == 3
        # the grids decode through the registered schema alone, as Foxglove decodes them
        grids = [
            proto
            for _, channel, _, proto in reader.iter_decoded_messages(
                topics=[SLIM_TOPIC], log_time_order=False
            )
        ]
    assert [decode_grid(g).shape for g in grids] == [SHAPE] * 3
    assert np.array_equal(decode_grid(grids[1]), maps_of(1)[0].astype(np.float32))


def test_a_file_cut_anywhere_reads_up_to_its_last_complete_record(tmp_path: Path) -> None:
    path = record_run(tmp_path, 6)
    data = path.read_bytes()
    full = list(RecordingReader(path).messages())
    cut = tmp_path / "cut.mcap"
    counts = []
    for size in range(0, len(data), max(1, len(data) // 60)):
        cut.write_bytes(data[:size])
        reader = RecordingReader(cut)
        messages = list(reader.messages())
        assert not reader.complete
        assert messages == full[: len(messages)]
        counts.append(len(messages))
    assert counts == sorted(counts)
    assert counts[0] == 0
    assert counts[-1] == len(full)  # the last cuts fall in the summary, after the messages
    assert len(set(counts)) > 10
    # a cut inside the closing magic: every message is there, but the file is not complete
    cut.write_bytes(data[:-3])
    reader = RecordingReader(cut)
    assert list(reader.messages()) == full
    assert not reader.complete


def test_an_unwritable_directory_is_a_clear_error_at_start(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    config = build_config({}, [f"recorder.dir={json.dumps(str(blocker / 'runs'))}"])
    with pytest.raises(ConfigError, match=r"recorder.dir: cannot write to .*file/runs"), Recorder(config):
        pass


def test_a_removed_file_stops_the_recording_with_one_error_line(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    slim, plume = maps_of(0)
    with (
        caplog.at_level(logging.ERROR, logger="service.edges.recorder"),
        Recorder(CONFIG, directory=tmp_path) as rec,
    ):
        assert rec.tick(obs_of(0), slim, plume)
        assert rec.path is not None
        rec.path.unlink()
        assert not rec.tick(obs_of(1), slim, plume)
        assert not rec.active
        assert rec.failure is not None
        assert "removed" in rec.failure
        assert not rec.tick(obs_of(2), slim, plume)
        assert not rec.write_event(3.0, "plume_lost")
        assert not rec.write_setpoint(3.0, 1.0, 1.0, 0.0)
    assert len(caplog.records) == 1
    assert "recording stopped" in caplog.records[0].getMessage()
    assert rec.ticks == 1


def test_a_full_disk_stops_the_recording_and_keeps_what_was_written(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    slim, plume = maps_of(0)
    with (
        caplog.at_level(logging.ERROR, logger="service.edges.recorder"),
        Recorder(CONFIG, directory=tmp_path) as rec,
    ):
        assert rec.tick(obs_of(0), slim, plume)

        def no_space() -> None:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(rec._writer, "flush", no_space)  # the mcap writer's flush hits the disk
        assert not rec.tick(obs_of(1), slim, plume)
        assert not rec.active
        assert rec.failure is not None
        assert "No space left" in rec.failure
    assert len(caplog.records) == 1
    assert rec.path is not None
    messages = list(RecordingReader(rec.path).messages())
    assert [m.topic for m in messages] == [CONFIG_TOPIC, OBS_TOPIC, SLIM_TOPIC, PLUME_TOPIC]


def test_invalid_values_are_refused_before_anything_is_written(tmp_path: Path) -> None:
    slim, plume = maps_of(0)
    with Recorder(CONFIG, directory=tmp_path) as rec:
        with pytest.raises(ValueError, match="shape"):
            rec.tick(obs_of(0), slim.T, plume)
        estimate = Estimate(cell=1, x=0.0, y=0.0, probability=1.0, entropy=0.0)
        with pytest.raises(ValueError, match="mission state"):
            rec.tick(obs_of(0), slim, plume, estimate=estimate)
        assert rec.active
        assert rec.ticks == 0


CHILD = """
import sys
from service.api import Search
from service.edges.recorder import Recorder
sys.path.insert(0, sys.argv[2])
from test_recorder import CONFIG, obs_of

search = Search(CONFIG)
with Recorder(CONFIG, directory=sys.argv[1]) as rec:
    for k in range(1_000_000):
        obs = obs_of(k)
        search.update_map(obs)
        rec.tick(obs, search.likelihood, search.plume, estimate=search.estimate(), state="search")
        print(k, flush=True)
"""


def test_a_killed_recording_keeps_every_flushed_tick_and_replays(tmp_path: Path) -> None:
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(tmp_path), str(Path(__file__).parent)],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert child.stdout is not None
    flushed = -1
    try:
        with selectors.DefaultSelector() as selector:
            selector.register(child.stdout, selectors.EVENT_READ)
            while flushed < 5:
                assert selector.select(TIMEOUT_S), "the recording child printed nothing"
                line = child.stdout.readline()
                assert line, f"the recording child exited with {child.wait()}"
                flushed = int(line)
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(TIMEOUT_S)
        child.stdout.close()
    assert child.returncode == -signal.SIGKILL
    [path] = tmp_path.glob("auv-3_*.mcap")
    reader = RecordingReader(path)
    topics = by_topic(list(reader.messages()))
    assert not reader.complete
    recorded = [json.loads(m.data) for m in topics[OBS_TOPIC]]
    assert len(recorded) > flushed  # ticks 0..flushed were flushed before they were printed
    assert recorded == [{"time_s": o.time_s, "x": o.x, "y": o.y, "flow_x": o.flow_x, "flow_y": o.flow_y,
                         "detected": o.detected} for o in map(obs_of, range(len(recorded)))]  # fmt: skip
    report = replay(path)
    assert report.ok, report.summary()
    assert not report.complete
    assert report.ticks == len(recorded)
    assert report.grids_compared >= 2 * (flushed + 1)


def test_the_drawable_messages_decode_through_their_recorded_schemas(tmp_path: Path) -> None:
    scene = SceneBuilder(cell_m=1.0, declared_radius_m=3.0, source=(5.0, 6.0))
    with Recorder(CONFIG, directory=tmp_path, clock_ns=clock) as rec:
        for k in range(3):
            estimate = Estimate(cell=k + 1, x=1.5, y=-2.5, probability=0.25, entropy=2.0)
            slim, plume = maps_of(k)
            assert rec.tick(obs_of(k), slim, plume, estimate=estimate, state="trace")
            records = scene.tick(obs_of(k), 0.5, estimate=estimate, state="trace", path=[(2.0, 3.0)])
            assert rec.write_messages(records)
    assert rec.path is not None
    with open(rec.path, "rb") as file:
        reader = make_reader(file, decoder_factories=[DecoderFactory()])
        messages = reader.iter_decoded_messages(topics=list(SCENE_SCHEMAS))
        decoded = [(channel.topic, proto) for _, channel, _, proto in messages]
    counts: dict[str, int] = {}
    for topic, proto in decoded:
        counts[topic] = counts.get(topic, 0) + 1
        if topic in SCENE_SCHEMAS:
            assert proto.DESCRIPTOR.full_name == SCENE_SCHEMAS[topic].DESCRIPTOR.full_name
    assert all(counts[topic] == 3 for topic in SCENE_SCHEMAS)
    poses = [proto for topic, proto in decoded if topic == VEHICLE_TOPIC]
    assert (poses[2].pose.position.x, poses[2].pose.position.y) == (obs_of(2).x, obs_of(2).y)
    assert poses[2].frame_id == "map"
