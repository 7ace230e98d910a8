"""MCAP recording of a run (DESIGN.md, MCAP contract): one file per run, every input and output.

Channels (all written by ``Recorder``; each message's ``sequence`` is the tick number, so replay
knows which maps follow which observation):

| topic            | encoding                   | payload                                                |
| ---------------- | -------------------------- | ------------------------------------------------------ |
| ``/oslim/config``   | json, schema oslim.Config  | the resolved configuration, once, first             |
| ``/oslim/obs``      | json                       | the tick's observation (``zenoh_link.obs_json``)    |
| ``/oslim/slim``     | protobuf foxglove.Grid     | pi after the tick                                   |
| ``/oslim/plume``    | protobuf foxglove.Grid     | alpha after the tick                                |
| ``/oslim/estimate`` | json                       | ``zenoh_link.estimate_json`` (optional per tick)    |
| ``/oslim/path``     | json                       | ``zenoh_link.path_json`` (optional per tick)        |
| ``/oslim/setpoint`` | json                       | ``{time_s, x, y, z}`` guided target, map frame      |
| ``/oslim/event``    | json                       | ``{time_s, name, text, ...}`` state changes etc.    |
| ``foxglove_scene``  | protobuf foxglove.*        | vehicle, track, plan, detections, markers, tf,      |
|                     |                            | ``/sim/source`` (``write_messages``, per tick)      |

With ``mirror`` (a ``foxglove_live.LiveView``) every channel and message also goes to the live
Foxglove view, byte for byte.

Crash safety: the file is chunked (zstd) and every ``tick`` / ``write_*`` call closes its chunk
and flushes it to the OS, so a crash, SIGKILL or SIGTERM leaves every completed call readable
(``RecordingReader`` reads such a file without its footer). A recording error after start-up
(disk full, file removed) is logged once and stops the recording; the caller goes on.
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import os
import struct
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Any, Final, Self

import numpy.typing as npt
from foxglove_schemas_protobuf.Grid_pb2 import Grid as GridProto
from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from service.core.errors import ConfigError
from service.core.grid import Grid
from service.edges.foxglove_scene import SCHEMAS as SCENE_SCHEMAS
from service.edges.grid_message import DEFAULT_FRAME_ID, SCHEMA_NAME, grid_payload
from service.edges.messages import (
    ESTIMATE_STATES,
    Waypoint,
    estimate_json,
    json_payload,
    obs_json,
    path_json,
)

if TYPE_CHECKING:
    from service.core.config import Config
    from service.core.mapping.mapper import Estimate
    from service.core.observation import Observation
    from service.edges.foxglove_live import LiveView

log = logging.getLogger(__name__)

CONFIG_TOPIC: Final = "/oslim/config"
OBS_TOPIC: Final = "/oslim/obs"
SLIM_TOPIC: Final = "/oslim/slim"
PLUME_TOPIC: Final = "/oslim/plume"
ESTIMATE_TOPIC: Final = "/oslim/estimate"
PATH_TOPIC: Final = "/oslim/path"
SETPOINT_TOPIC: Final = "/oslim/setpoint"
EVENT_TOPIC: Final = "/oslim/event"

_NUMBER = {"type": "number"}


def _object(title: str, properties: Mapping[str, Any], *, closed: bool = True) -> dict[str, Any]:
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": dict(properties),
        "required": list(properties),
        "additionalProperties": not closed,
    }


_JSON_SCHEMAS: Final[dict[str, dict[str, Any]]] = {
    OBS_TOPIC: _object(
        "oslim.Observation",
        {
            "time_s": _NUMBER,
            "x": _NUMBER,
            "y": _NUMBER,
            "flow_x": _NUMBER,
            "flow_y": _NUMBER,
            "detected": {"type": "boolean"},
        },
    ),
    ESTIMATE_TOPIC: _object(
        "oslim.Estimate",
        {
            "time_s": _NUMBER,
            "state": {"enum": sorted(ESTIMATE_STATES)},
            "cell": {"type": "integer"},
            "x": _NUMBER,
            "y": _NUMBER,
            "probability": _NUMBER,
            "entropy": _NUMBER,
        },
    ),
    PATH_TOPIC: _object(
        "oslim.Path",
        {
            "time_s": _NUMBER,
            "waypoints": {
                "type": "array",
                "items": {"type": "array", "items": _NUMBER, "minItems": 2, "maxItems": 2},
            },
        },
    ),
    SETPOINT_TOPIC: _object("oslim.Setpoint", {"time_s": _NUMBER, "x": _NUMBER, "y": _NUMBER, "z": _NUMBER}),
    EVENT_TOPIC: _object(
        "oslim.Event",
        {"time_s": _NUMBER, "name": {"type": "string"}, "text": {"type": "string"}},
        closed=False,
    ),
}

_LIBRARY: Final = "oslim recorder"


def _version() -> str:
    try:
        return metadata.version("oslim")
    except metadata.PackageNotFoundError:
        return "unknown"


def run_file_name(vehicle_id: str, started_ns: int) -> str:
    """``<vehicle_id>_<UTC yyyymmddThhmmssZ>.mcap``: sorts by start time, one per run."""
    started = datetime.fromtimestamp(started_ns / 1e9, UTC)
    return f"{vehicle_id}_{started:%Y%m%dT%H%M%SZ}.mcap"


class Recorder:
    """Owns the MCAP file of one run. ``with Recorder(config) as rec:`` opens it in
    ``recorder.dir`` and writes the configuration; then per tick::

        rec.tick(obs, search.likelihood, search.plume, estimate=est, state="search", path=wps)

    with exactly the observation the search fused and its maps right after it
    (replay recomputes them from these). ``write_setpoint`` / ``write_event`` at any time.
    Every call is flushed to the OS before it returns (measured 0.4 ms median, 0.9 ms max for a
    tick with two 100 x 100 grids, zstd). The methods are thread-safe, so
    ``asyncio.to_thread(rec.tick, ...)`` may keep file I/O off the loop if the disk is slow
    (the arrays must not change until it returns).

    Start-up errors (directory not creatable or not writable) raise ``ConfigError`` naming
    ``recorder.dir``. Later errors never raise: the recorder logs one error line, stops, and
    reports ``active == False`` with the reason in ``failure``.
    """

    def __init__(
        self,
        config: Config,
        *,
        directory: str | Path | None = None,
        clock_ns: Callable[[], int] = time.time_ns,
        frame_id: str = DEFAULT_FRAME_ID,
        compression: CompressionType = CompressionType.ZSTD,
        mirror: LiveView | None = None,
    ) -> None:
        self.config = config
        self._mirror = mirror
        self.grid = Grid.from_config(config.area)
        self.directory = Path(directory if directory is not None else config.recorder.dir)
        self.frame_id = frame_id
        self.path: Path | None = None
        self.failure: str | None = None
        self.ticks = 0
        self._clock_ns = clock_ns
        self._compression = compression
        self._lock = threading.Lock()
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}

    @property
    def active(self) -> bool:
        """True while the file is open and recording."""
        return self._writer is not None

    def __enter__(self) -> Self:
        started = self._clock_ns()
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._file, self.path = self._create(
                self.directory, run_file_name(self.config.vehicle.id, started)
            )
        except OSError as exc:
            reason = exc.strerror or str(exc)
            raise ConfigError(f"recorder.dir: cannot write to {self.directory}: {reason}") from None
        try:
            self._start(started)
        except OSError as exc:
            with contextlib.suppress(OSError):
                self._file.close()
            raise ConfigError(f"recorder.dir: cannot write {self.path}: {exc.strerror or exc}") from None
        log.info("recording to %s", self.path)
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Write the summary and footer and close the file (idempotent)."""
        with self._lock:
            writer, file = self._writer, self._file
            if writer is None or file is None:
                return
            try:
                writer.finish()  # type: ignore[no-untyped-call]  # mcap leaves it unannotated
                file.close()
            except OSError as exc:
                self._fail(f"finishing the file: {exc}")
                return
            self._writer, self._file = None, None
        log.info("recording closed: %s (%d ticks)", self.path, self.ticks)

    def tick(
        self,
        obs: Observation,
        slim: npt.ArrayLike,
        plume: npt.ArrayLike,
        *,
        estimate: Estimate | None = None,
        state: str | None = None,
        path: Sequence[Waypoint] | None = None,
    ) -> bool:
        """Record one tick: the observation, pi, alpha and optionally the estimate (with the
        mission ``state``) and the planned path. Returns whether it was recorded."""
        records = [
            (OBS_TOPIC, json_payload(obs_json(obs))),
            (SLIM_TOPIC, grid_payload(slim, self.grid, obs.time_s, frame_id=self.frame_id)),
            (PLUME_TOPIC, grid_payload(plume, self.grid, obs.time_s, frame_id=self.frame_id)),
        ]
        if estimate is not None:
            if state is None:
                raise ValueError("an estimate is recorded with the mission state")
            records.append((ESTIMATE_TOPIC, json_payload(estimate_json(obs.time_s, state, estimate))))
        if path is not None:
            records.append((PATH_TOPIC, json_payload(path_json(obs.time_s, path))))
        with self._lock:
            if self._writer is None:
                return False
            recorded = self._write(records, self.ticks + 1)
            self.ticks += int(recorded)
            return recorded

    def write_setpoint(self, time_s: float, x: float, y: float, z: float) -> bool:
        """Record a guided setpoint sent to the vehicle (map frame x East, y North, z up; metres)."""
        values = {"time_s": time_s, "x": x, "y": y, "z": z}
        return self._write_json(SETPOINT_TOPIC, {k: float(v) for k, v in values.items()})

    def write_event(self, time_s: float, name: str, text: str = "", **detail: Any) -> bool:
        """Record an event (``plume_found``, ``source_declared``, ...) with JSON-able details."""
        return self._write_json(EVENT_TOPIC, {"time_s": float(time_s), "name": name, "text": text, **detail})

    def write_messages(self, records: Sequence[tuple[str, bytes]]) -> bool:
        """Record serialised messages on ``foxglove_scene`` topics, numbered as the last tick."""
        with self._lock:
            if self._writer is None:
                return False
            return self._write(records, self.ticks)

    def _write_json(self, topic: str, value: dict[str, Any]) -> bool:
        payload = json_payload(value)
        with self._lock:
            if self._writer is None:
                return False
            return self._write([(topic, payload)], self.ticks)

    @staticmethod
    def _create(directory: Path, name: str) -> tuple[IO[bytes], Path]:
        """Create the run's file exclusively; a second run in the same second gets a suffix."""
        stem, suffix = name.rsplit(".", 1)
        for attempt in range(100):
            path = directory / (name if attempt == 0 else f"{stem}-{attempt}.{suffix}")
            try:
                return open(path, "xb"), path  # owned by the recorder until close()
            except FileExistsError:
                continue
        raise FileExistsError(f"too many runs named {name} in {directory}")

    def _start(self, started_ns: int) -> None:
        assert self._file is not None  # set by __enter__ just before
        if self._mirror is None:
            writer = Writer(self._file, compression=self._compression)
        else:
            writer = self._mirror.tee(self._file, compression=self._compression)
        writer.start(profile="", library=_LIBRARY)
        grid_schema = writer.register_schema(
            name=SCHEMA_NAME,
            encoding="protobuf",
            data=build_file_descriptor_set(GridProto).SerializeToString(),
        )
        config_schema = writer.register_schema(
            name="oslim.Config",
            encoding="jsonschema",
            data=json.dumps(type(self.config).model_json_schema()).encode(),
        )
        self._channels[CONFIG_TOPIC] = writer.register_channel(CONFIG_TOPIC, "json", config_schema)
        for topic in (SLIM_TOPIC, PLUME_TOPIC):
            self._channels[topic] = writer.register_channel(topic, "protobuf", grid_schema)
        for topic, schema in _JSON_SCHEMAS.items():
            schema_id = writer.register_schema(
                name=str(schema["title"]), encoding="jsonschema", data=json.dumps(schema).encode()
            )
            self._channels[topic] = writer.register_channel(topic, "json", schema_id)
        scene_schemas: dict[str, int] = {}
        for topic, message_type in SCENE_SCHEMAS.items():
            name = message_type.DESCRIPTOR.full_name
            if name not in scene_schemas:
                data = build_file_descriptor_set(message_type).SerializeToString()
                scene_schemas[name] = writer.register_schema(name=name, encoding="protobuf", data=data)
            self._channels[topic] = writer.register_channel(topic, "protobuf", scene_schemas[name])
        writer.add_metadata(
            "oslim",
            {
                "vehicle_id": self.config.vehicle.id,
                "version": _version(),
                "started_utc": datetime.fromtimestamp(started_ns / 1e9, UTC).isoformat(),
            },
        )
        config_json = json_payload(self.config.model_dump(mode="json"))
        now = self._clock_ns()
        writer.add_message(self._channels[CONFIG_TOPIC], log_time=now, data=config_json, publish_time=now)
        writer.flush()  # type: ignore[no-untyped-call]
        self._writer = writer

    def _write(self, records: Sequence[tuple[str, bytes]], sequence: int) -> bool:
        """Append and flush under the lock; on an OSError stop recording."""
        writer, file = self._writer, self._file
        # callers check ``active`` under the lock
        assert writer is not None
        assert file is not None
        try:
            now = self._clock_ns()
            for topic, payload in records:
                writer.add_message(
                    self._channels[topic], log_time=now, data=payload, publish_time=now, sequence=sequence
                )
            writer.flush()  # type: ignore[no-untyped-call]
            if os.fstat(file.fileno()).st_nlink == 0:
                # unlinking an open file does not fail writes: they would go nowhere
                raise FileNotFoundError(f"{self.path} was removed")
        except OSError as exc:
            self._fail(str(exc))
            return False
        return True

    def _fail(self, reason: str) -> None:
        """Stop recording after an I/O error: one error line, the file closed, state kept."""
        self.failure = reason
        self._writer = None
        file, self._file = self._file, None
        log.error("recorder: %s: recording stopped (%s)", self.path, reason)
        if file is not None:
            with contextlib.suppress(OSError):  # the tail is lost either way; already reported
                file.close()


@dataclass(frozen=True)
class RecordedMessage:
    """One message read back: its channel topic, tick number, log time and raw payload."""

    topic: str
    sequence: int
    log_time_ns: int
    data: bytes


class RecordingReader:
    """Reads an OSLIM MCAP file in file order, including one cut short by a crash.

    A crash can leave a partial record at the end and no summary or footer. The record framing
    (opcode, 8-byte length) is walked first to find where the last complete record ends, and
    only that prefix is parsed. ``complete`` tells whether the footer was there.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.complete = False
        self.readable_bytes = 0

    def messages(self) -> Iterator[RecordedMessage]:
        with open(self.path, "rb") as file:
            self.readable_bytes, self.complete = _complete_prefix(file)
            file.seek(0)
            reader = StreamReader(_Prefix(file, self.readable_bytes), validate_crcs=True)
            channels: dict[int, Channel] = {}
            try:
                for record in reader.records:
                    if isinstance(record, Channel):
                        channels[record.id] = record
                    elif isinstance(record, Message):
                        yield RecordedMessage(
                            topic=channels[record.channel_id].topic,
                            sequence=record.sequence,
                            log_time_ns=record.log_time,
                            data=record.data,
                        )
            except (EndOfFile, struct.error):  # struct.error: a closing magic cut part-way
                if self.complete:
                    raise
                return  # the cut: everything complete before it has been read


_MAGIC_SIZE = 8
_RECORD_HEAD = struct.Struct("<BQ")


def _complete_prefix(file: IO[bytes]) -> tuple[int, bool]:
    """(bytes up to the end of the last complete record, whether a footer was reached)."""
    size = file.seek(0, io.SEEK_END)
    position = _MAGIC_SIZE
    while position + _RECORD_HEAD.size <= size:
        file.seek(position)
        opcode, length = _RECORD_HEAD.unpack(file.read(_RECORD_HEAD.size))
        end = position + _RECORD_HEAD.size + length
        if end > size:
            break
        position = end
        if opcode == Opcode.FOOTER:
            # complete only with the closing magic too; a file cut inside it reads as cut short
            return min(position + _MAGIC_SIZE, size), position + _MAGIC_SIZE <= size
    return position, False


class _Prefix(io.RawIOBase):
    """The first ``limit`` bytes of a binary file, as a readable raw stream."""

    def __init__(self, file: IO[bytes], limit: int) -> None:
        self._file = file
        self._left = limit

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        count = min(len(view), self._left)
        data = self._file.read(count)
        view[: len(data)] = data
        self._left -= len(data)
        return len(data)
