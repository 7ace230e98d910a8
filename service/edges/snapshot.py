"""The restart snapshot: the map state, written atomically every tick, restored at start-up.

A companion computer gets rebooted and a service gets killed; the map it built must survive.
After every tick that changed the map, the mapper's state (``SourceMapper.save_state``) and the
mission's phase and detection memory (``Mission.save_state``) go to ``service.snapshot_path`` as
one ``.npz`` file (no pickle: ``numpy.load(allow_pickle=False)`` reads it back). The file is
written under a temporary name, fsynced and renamed over the old one (``os.replace`` is atomic on
POSIX), so a SIGKILL or power cut leaves the previous snapshot or the new one, never half of one.

At start-up a snapshot is restored only when it was made with the same vehicle, area, sensor and
mapping settings (``fingerprint``); otherwise it is ignored with one warning line and the map
starts flat. The service clock then resumes at the snapshot's time, so the first tick after the
restart is one ``tick_s`` after the last one before it: the time the service was down is not
mapped (nothing was observed), rather than being read as one long tick of the current flow.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import os
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from service.core.errors import ConfigError

if TYPE_CHECKING:
    from service.core.config import Config

log = logging.getLogger(__name__)

FORMAT: Final = "oslim-snapshot-1"
_META: Final = "meta"


def map_digest(likelihood: np.ndarray[Any, Any]) -> str:
    """Short hash of a map's exact bytes: logged at restore, so a restart can be checked."""
    return hashlib.sha256(np.ascontiguousarray(likelihood, dtype=np.float64).tobytes()).hexdigest()[:16]


def fingerprint(config: Config) -> str:
    """Hash of the settings a map depends on (a map made under others must not be restored)."""
    sections = ("vehicle", "area", "sensor", "mapping")
    shaping = {name: getattr(config, name).model_dump(mode="json") for name in sections}
    return hashlib.sha256(json.dumps(shaping, sort_keys=True).encode()).hexdigest()


@dataclass(frozen=True)
class Snapshot:
    """One saved map state. ``time_s`` is the service time of the tick that made it."""

    fingerprint: str
    time_s: float
    ticks: int
    wall_time: float
    mapper: dict[str, np.ndarray[Any, Any]]
    mission: dict[str, Any]


def encode(snapshot: Snapshot) -> bytes:
    """The ``.npz`` bytes of ``snapshot``: the mapper's arrays plus one JSON metadata entry."""
    meta = {
        "format": FORMAT,
        "fingerprint": snapshot.fingerprint,
        "time_s": snapshot.time_s,
        "ticks": snapshot.ticks,
        "wall_time": snapshot.wall_time,
        "mission": snapshot.mission,
    }
    buffer = io.BytesIO()
    arrays: dict[str, Any] = {f"mapper_{k}": np.asarray(v) for k, v in snapshot.mapper.items()}
    arrays[_META] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def decode(data: bytes) -> Snapshot:
    """Inverse of ``encode``; ValueError when the bytes are not a snapshot of this format."""
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
        meta = json.loads(arrays.pop(_META).tobytes())
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise ValueError(f"not a snapshot: {exc}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ValueError(f"not a {FORMAT} file")
    return Snapshot(
        fingerprint=str(meta["fingerprint"]),
        time_s=float(meta["time_s"]),
        ticks=int(meta["ticks"]),
        wall_time=float(meta["wall_time"]),
        mapper={k.removeprefix("mapper_"): v for k, v in arrays.items() if k.startswith("mapper_")},
        mission=dict(meta["mission"]),
    )


class SnapshotWriter:
    """Writes snapshots to one path atomically. The first I/O error is logged once and stops
    further writes (``failure`` says why); the service goes on without restart protection."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.written = 0
        self.failure: str | None = None
        self._tmp = self.path.with_name(f".{self.path.name}.tmp")

    def check(self) -> None:
        """At start-up: ConfigError naming the key if the directory cannot be written."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(self._tmp, "wb"):
                pass
            self._tmp.unlink()
        except OSError as exc:
            raise ConfigError(
                f"service.snapshot_path: cannot write in {self.path.parent}: {exc.strerror or exc}"
            ) from None

    def write(self, snapshot: Snapshot) -> bool:
        """Replace the snapshot file with ``snapshot``; False (after one error line) on failure."""
        if self.failure is not None:
            return False
        try:
            with open(self._tmp, "wb") as file:
                file.write(encode(snapshot))
                file.flush()
                os.fsync(file.fileno())
            os.replace(self._tmp, self.path)  # atomic: readers see the old or the new file
        except OSError as exc:
            self.failure = str(exc)
            log.error("snapshot: %s: writing stopped (%s)", self.path, exc)
            with contextlib.suppress(OSError):
                self._tmp.unlink()
            return False
        self.written += 1
        return True


def read_snapshot(path: str | Path, config: Config) -> Snapshot | None:
    """The snapshot at ``path`` if there is one made under ``config``'s map settings, else None
    (with one log line saying why it was not used)."""
    file = Path(path)
    try:
        data = file.read_bytes()
    except FileNotFoundError:
        log.info("snapshot: none at %s, starting with a flat map", file)
        return None
    except OSError as exc:
        raise ConfigError(f"service.snapshot_path: cannot read {file}: {exc.strerror or exc}") from None
    try:
        snapshot = decode(data)
    except ValueError as exc:
        log.warning("snapshot: ignored %s (%s), starting with a flat map", file, exc)
        return None
    if snapshot.fingerprint != fingerprint(config):
        log.warning("snapshot: ignored %s: made with other vehicle, area, sensor or mapping settings", file)
        return None
    age = time.time() - snapshot.wall_time
    log.info("snapshot: restoring %s (tick %d, %.0f s old)", file, snapshot.ticks, age)
    return snapshot
