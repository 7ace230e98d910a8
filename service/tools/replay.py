"""``oslim replay RUN.mcap``: recompute a run's maps from its recording and compare bit for bit.

The recording holds the resolved configuration and every observation the mapper consumed
(``recorder``). Replay builds the same ``service.api.Search`` from that configuration, feeds the
observations to its maps tick by tick (``Search.update_map``), and compares its pi and alpha
with the recorded ``slim`` and ``plume`` grids (float32 as recorded, compared bit for bit) and
its estimate with the recorded one (JSON floats, exact). A file cut short by a crash is
replayed up to its last complete record.
"""

from __future__ import annotations

import argparse
import json
import struct
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from mcap.exceptions import McapError
from mcap.stream_reader import CRCValidationError

from service.api import Search
from service.core.config import build_config
from service.core.errors import OslimError
from service.edges.grid_message import decode_grid
from service.edges.messages import observation_from_json
from service.edges.recorder import (
    CONFIG_TOPIC,
    ESTIMATE_TOPIC,
    OBS_TOPIC,
    PLUME_TOPIC,
    SLIM_TOPIC,
    RecordedMessage,
    RecordingReader,
)
from service.tools.progress import progress_bar

_ESTIMATE_FIELDS = ("cell", "x", "y", "probability", "entropy")


class ReplayError(OslimError):
    """The recording cannot be replayed (no configuration, an unreadable message)."""


@dataclass(frozen=True)
class Mismatch:
    """One recorded output that the replay did not reproduce."""

    tick: int
    topic: str
    detail: str


@dataclass(frozen=True)
class ReplayReport:
    """What ``replay`` compared and found."""

    path: str
    ticks: int
    grids_compared: int
    estimates_compared: int
    max_abs_diff: float
    """Largest |recorded - recomputed| over all compared grid cells (float32 values)."""
    complete: bool
    """False when the file had no footer (cut short by a crash); replay used what was there."""
    mismatches: tuple[Mismatch, ...] = field(default=())

    @property
    def ok(self) -> bool:
        """Everything recorded was reproduced, and there was at least one grid to compare."""
        return not self.mismatches and self.grids_compared > 0

    def summary(self) -> str:
        status = "OK" if self.ok else "FAILED"
        lines = [
            f"replay {self.path}: {status}",
            f"  ticks {self.ticks}, grids compared {self.grids_compared}, estimates compared "
            f"{self.estimates_compared}, mismatches {len(self.mismatches)}, "
            f"max abs difference {self.max_abs_diff:.9g}",
        ]
        if not self.complete:
            lines.append("  file has no footer (cut short): replayed up to its last complete record")
        if self.grids_compared == 0:
            lines.append("  no recorded grid to compare")
        lines += [f"  tick {m.tick} {m.topic}: {m.detail}" for m in self.mismatches[:10]]
        if len(self.mismatches) > 10:
            lines.append(f"  ... and {len(self.mismatches) - 10} more")
        return "\n".join(lines)


def replay(path: str | Path, progress: Callable[[int], None] | None = None) -> ReplayReport:
    """Replay the recording at ``path`` and compare every recorded map and estimate;
    ``progress(1)`` is called after every replayed tick, if given."""
    reader = RecordingReader(path)
    session = _Session()
    messages = reader.messages()
    while True:
        try:
            message = next(messages)
        except StopIteration:
            break
        except (McapError, CRCValidationError, struct.error, KeyError) as exc:
            raise ReplayError(f"{path}: unreadable MCAP: {exc}") from None
        ticks = session.ticks
        session.consume(message)
        if progress is not None and session.ticks > ticks:
            progress(session.ticks - ticks)
    return ReplayReport(
        path=str(path),
        ticks=session.ticks,
        grids_compared=session.grids,
        estimates_compared=session.estimates,
        max_abs_diff=session.max_abs_diff,
        complete=reader.complete,
        mismatches=tuple(session.mismatches),
    )


class _Session:
    """The replay state: the search rebuilt from the recorded configuration, and the tallies."""

    def __init__(self) -> None:
        self.search: Search | None = None
        self.tick = 0  # the sequence number of the last observation fed to the mapper
        self.ticks = 0
        self.grids = 0
        self.estimates = 0
        self.max_abs_diff = 0.0
        self.mismatches: list[Mismatch] = []

    def consume(self, message: RecordedMessage) -> None:
        if message.topic == CONFIG_TOPIC:
            if self.search is not None:
                raise ReplayError("the recording holds more than one configuration")
            self.search = Search(build_config(_json(message), origin="recorded configuration"))
        elif message.topic == OBS_TOPIC:
            try:
                obs = observation_from_json(_json(message))
            except (TypeError, ValueError) as exc:
                raise ReplayError(f"tick {message.sequence}: bad observation: {exc}") from None
            self._require_search().update_map(obs)
            self.tick = message.sequence
            self.ticks += 1
        elif message.topic in (SLIM_TOPIC, PLUME_TOPIC):
            if self._same_tick(message):
                search = self._require_search()
                self._compare_grid(
                    message, search.likelihood if message.topic == SLIM_TOPIC else search.plume
                )
        elif message.topic == ESTIMATE_TOPIC and self._same_tick(message):
            self._compare_estimate(message)

    def _require_search(self) -> Search:
        if self.search is None:
            raise ReplayError("the recording has no configuration before its first observation")
        return self.search

    def _same_tick(self, message: RecordedMessage) -> bool:
        if message.sequence == self.tick and self.ticks > 0:
            return True
        self._mismatch(message, f"recorded for tick {message.sequence}, but no observation of that tick")
        return False

    def _compare_grid(self, message: RecordedMessage, recomputed: npt.NDArray[np.float64]) -> None:
        self.grids += 1
        try:
            recorded = decode_grid(message.data)
        except ValueError as exc:
            self._mismatch(message, f"undecodable grid: {exc}")
            return
        expected = recomputed.astype(np.float32)
        if recorded.shape != expected.shape:
            self._mismatch(message, f"shape {recorded.shape}, replay has {expected.shape}")
            return
        diff = np.abs(recorded.astype(np.float64) - expected.astype(np.float64))
        finite = diff[np.isfinite(diff)]  # NaN / inf cells are caught by the bit comparison
        worst = float(finite.max()) if finite.size else 0.0
        self.max_abs_diff = max(self.max_abs_diff, worst)
        # bit for bit: also tells -0.0 from 0.0 and NaN from anything
        unequal = recorded.view(np.uint32) != expected.view(np.uint32)
        differing = int(np.count_nonzero(unequal))
        if differing:
            row, col = np.unravel_index(int(np.argmax(unequal)), unequal.shape)
            self._mismatch(
                message,
                f"{differing} cells differ, max abs {worst:.9g}; first at row {row} column {col}: "
                f"recorded {float(recorded[row, col]):.9g}, replay {float(expected[row, col]):.9g}",
            )

    def _compare_estimate(self, message: RecordedMessage) -> None:
        self.estimates += 1
        recorded = _json(message)
        recomputed = asdict(self._require_search().estimate())
        differing = [k for k in _ESTIMATE_FIELDS if recorded.get(k) != recomputed[k]]
        if differing:
            shown = ", ".join(f"{k} recorded {recorded.get(k)!r} replay {recomputed[k]!r}" for k in differing)
            self._mismatch(message, shown)

    def _mismatch(self, message: RecordedMessage, detail: str) -> None:
        self.mismatches.append(Mismatch(message.sequence, message.topic, detail))


def _json(message: RecordedMessage) -> dict[str, Any]:
    try:
        value = json.loads(message.data)
    except ValueError as exc:
        raise ReplayError(f"{message.topic} tick {message.sequence}: not JSON: {exc}") from None
    if not isinstance(value, dict):
        raise ReplayError(f"{message.topic} tick {message.sequence}: not a JSON object")
    return value


def run(args: argparse.Namespace) -> int:
    """Exit status 0 only when every recorded grid and estimate was reproduced."""
    path: Path = args.file
    if not path.is_file():
        raise ReplayError(f"{path}: no such file")
    with progress_bar(None, unit="tick", desc=f"replay {path.name}", quiet=args.json) as progress:
        report = replay(path, progress)
    if args.json:
        fields = {k: v for k, v in asdict(report).items() if k != "mismatches"}
        print(json.dumps({**fields, "ok": report.ok, "mismatches": len(report.mismatches)}))
    else:
        print(report.summary())
    return 0 if report.ok else 1
