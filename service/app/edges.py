"""What the service needs of its edges (protocols), and the real ones opened in start-up order.

The ``Service`` only sees these protocols, so tests can hand it in-memory fakes
(``tests/service/app/test_service_fakes.py``). ``open_edges`` opens the real ones, each connection
owned by its own context manager: the MAVLink link first, then Zenoh, and the MCAP recorder last,
so no run file is created for a service that did not start; a failure closes what was opened.
The Foxglove live view (``foxglove.listen``) opens just before the recorder, whose writes it
mirrors.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from service.core.config import Config
from service.core.grid import Grid
from service.edges.foxglove_live import open_live_view
from service.edges.mavlink_link import LinkCounters, MavlinkLink
from service.edges.recorder import Recorder
from service.edges.signing import SigningCounters
from service.edges.zenoh_link import ZenohLink

if TYPE_CHECKING:
    import numpy.typing as npt

    from service.core.mapping.mapper import Estimate
    from service.core.observation import Observation

Point = tuple[float, float]


class VehicleLink(Protocol):
    """The MAVLink side: messages in (``async for (time_s, msg)``), commands out."""

    @property
    def counters(self) -> LinkCounters: ...

    @property
    def signing(self) -> SigningCounters | None: ...

    def __aiter__(self) -> AsyncIterator[tuple[float, Any]]: ...

    def adopt_system(self, system: int) -> None: ...

    def send_heartbeat(self) -> None: ...

    def request_interval(self, target_system: int, message_id: int, rate_hz: float) -> None: ...

    def request_param(self, target_system: int, name: str) -> None: ...

    def send_speed(self, target_system: int, speed_mps: float) -> None: ...

    def send_setpoint(
        self, target_system: int, time_ms: int, x_m: float, y_m: float, altitude_m: float, type_mask: int
    ) -> None: ...

    def send_statustext(self, text: str, severity: int = 6) -> None: ...


class MapPublisher(Protocol):
    """The live maps for subscribers (Zenoh)."""

    def publish_obs(self, obs: Observation) -> None: ...

    def publish_maps(self, time_s: float, slim: npt.ArrayLike, plume: npt.ArrayLike) -> None: ...

    def publish_estimate(self, time_s: float, state: str, estimate: Estimate) -> None: ...

    def publish_path(self, time_s: float, waypoints: Sequence[Point]) -> None: ...


class RunRecorder(Protocol):
    """The run's recording (MCAP); each write says whether it was recorded."""

    @property
    def path(self) -> Path | None: ...

    def tick(
        self,
        obs: Observation,
        slim: npt.ArrayLike,
        plume: npt.ArrayLike,
        *,
        estimate: Estimate | None = None,
        state: str | None = None,
        path: Sequence[Point] | None = None,
    ) -> bool: ...

    def write_setpoint(self, time_s: float, x: float, y: float, z: float) -> bool: ...

    def write_event(self, time_s: float, name: str, text: str = "", **detail: Any) -> bool: ...

    def write_messages(self, records: Sequence[tuple[str, bytes]]) -> bool: ...


class LiveFeed(Protocol):
    """The live view (Foxglove WebSocket): it mirrors the recording, so the service writes to it
    only through the recorder; the service knows where it listens."""

    @property
    def port(self) -> int: ...


@dataclass(frozen=True)
class Edges:
    """The open edges of one run of the service; ``live`` is None while the live view is off
    (``foxglove.listen`` empty)."""

    link: VehicleLink
    maps: MapPublisher
    recorder: RunRecorder
    live: LiveFeed | None = None


EdgeOpener = Callable[
    ["Config", "Grid", Callable[[], float], bytes | None], contextlib.AbstractAsyncContextManager[Edges]
]
"""How a service run gets its edges: (configuration, grid, clock, signing key) -> open edges."""


@contextlib.asynccontextmanager
async def open_edges(
    config: Config, grid: Grid, clock: Callable[[], float], signing_key: bytes | None
) -> AsyncIterator[Edges]:
    """The real edges: MAVLink (pymavlink), Zenoh, the Foxglove live view (``foxglove.listen``;
    it mirrors the recording) and the MCAP recorder, in that order."""
    link_edge = MavlinkLink.from_config(config.mavlink, clock=clock, signing_key=signing_key)
    async with link_edge as link, ZenohLink.from_config(config, grid) as zenoh_link:
        with (
            open_live_view(config.foxglove.listen) as live,
            Recorder(config, mirror=live) as recorder,  # last: no run file for a service that did not start
        ):
            yield Edges(link, zenoh_link, recorder, live)
