"""The MAVLink edge: one pymavlink connection owned by an async context manager.

pymavlink reads are blocking, so a reader thread receives messages and hands them to asyncio
through a bounded queue. Overflow policy: when the queue is full the *oldest* message is dropped
(and counted): fresh telemetry matters more than stale telemetry. Sends happen on the event
loop's thread only. The service identifies as the onboard computer (component 191) of the
vehicle's system, which it adopts from the first autopilot heartbeat (``adopt_system``).
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from types import TracebackType
from typing import TYPE_CHECKING, Any, Self

from service.core.errors import LinkError
from service.edges.mavlink_dialect import dialect, mavutil
from service.edges.signing import SigningCounters, enable_signing

if TYPE_CHECKING:
    from service.core.config import MavlinkConfig

log = logging.getLogger(__name__)

MAV_COMP_ID_ONBOARD_COMPUTER = 191
MAV_FRAME_LOCAL_NED = 1
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_DO_CHANGE_SPEED = 178
_UNUSED_TARGET_FIELDS = (0.0,) * 8
"""vx, vy, vz, afx, afy, afz, yaw, yaw_rate: ignored under a position-only type_mask."""


@dataclass
class LinkCounters:
    received: int = 0
    bad_data: int = 0
    dropped: int = 0
    read_errors: int = 0
    sent: int = 0
    by_type: dict[str, int] = field(default_factory=dict)


class MavlinkLink:
    """Messages in as ``async for (time_s, msg) in link``; typed sends out."""

    def __init__(
        self,
        url: str,
        *,
        clock: Callable[[], float] = time.monotonic,
        queue_size: int = 1000,
        source_system: int = 1,
        signing_key: bytes | None = None,
        signing_link_id: int = 1,
    ) -> None:
        self.url = url
        self.clock = clock
        self.counters = LinkCounters()
        self._queue_size = queue_size
        self._source_system = source_system
        self._signing_key = signing_key
        self._signing_link_id = signing_link_id
        self._conn: Any = None
        self._queue: asyncio.Queue[tuple[float, Any]] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._mav = dialect()

    @classmethod
    def from_config(
        cls, mavlink: MavlinkConfig, *, clock: Callable[[], float], signing_key: bytes | None
    ) -> MavlinkLink:
        """The link of ``[mavlink]``: its url, queue size and signing link id."""
        return cls(
            mavlink.url,
            clock=clock,
            queue_size=mavlink.queue_size,
            signing_key=signing_key,
            signing_link_id=mavlink.signing_link_id,
        )

    async def __aenter__(self) -> Self:
        self._loop = asyncio.get_running_loop()
        self._queue = asyncio.Queue(maxsize=self._queue_size)
        try:
            self._conn = mavutil().mavlink_connection(
                self.url,
                source_system=self._source_system,
                source_component=MAV_COMP_ID_ONBOARD_COMPUTER,
                dialect="ardupilotmega",
                autoreconnect=True,
            )
        except Exception as exc:  # pymavlink raises OSError, SerialException, ValueError...
            raise LinkError(f"cannot open MAVLink connection {self.url!r}: {exc}") from None
        if self._signing_key is not None:
            enable_signing(self._conn, self._signing_key, self._signing_link_id)
        self._thread = threading.Thread(target=self._read_loop, name="mavlink-reader", daemon=True)
        self._thread.start()
        log.info(
            "mavlink: opened %s as component %d%s", self.url, MAV_COMP_ID_ONBOARD_COMPUTER,
            ", signing" if self._signing_key is not None else "",
        )  # fmt: skip
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._stop.set()
        if self._thread is not None:
            await asyncio.to_thread(self._thread.join, 2.0)
        if self._conn is not None:
            self._conn.close()

    def _read_loop(self) -> None:
        conn = self._conn
        while not self._stop.is_set():
            try:
                msg = conn.recv_match(blocking=True, timeout=0.1)
            except Exception:  # a corrupt frame must never kill the reader
                self.counters.read_errors += 1
                log.debug("mavlink: read error", exc_info=True)
                continue
            if msg is None:
                continue
            stamp = self.clock()
            if msg.get_type() == "BAD_DATA":
                # unsigned and wrongly signed messages arrive here too (counted by pymavlink)
                self.counters.bad_data += 1
                continue
            if self._loop is not None and not self._loop.is_closed():
                try:
                    self._loop.call_soon_threadsafe(self._enqueue, stamp, msg)
                except RuntimeError:  # loop closed while we were reading
                    return

    def _enqueue(self, stamp: float, msg: Any) -> None:
        assert self._queue is not None
        if self._queue.full():
            self._queue.get_nowait()
            self.counters.dropped += 1
        self._queue.put_nowait((stamp, msg))
        self.counters.received += 1
        kind = msg.get_type()
        self.counters.by_type[kind] = self.counters.by_type.get(kind, 0) + 1

    async def __aiter__(self) -> AsyncIterator[tuple[float, Any]]:
        if self._queue is None:
            raise LinkError("link not open")
        while True:
            yield await self._queue.get()

    @property
    def signing(self) -> SigningCounters | None:
        """Signature checks so far; None when signing is off."""
        if self._signing_key is None or self._conn is None:
            return None
        return SigningCounters.of(self._conn)

    def adopt_system(self, system: int) -> None:
        """Speak as the onboard computer of ``system`` (the vehicle's system id)."""
        if self._conn is not None and self._conn.mav.srcSystem != system:
            self._conn.mav.srcSystem = system
            log.info("mavlink: adopted system id %d", system)

    def _send(self, msg: Any) -> None:
        if self._conn is None:
            raise LinkError("link not open")
        try:
            self._conn.mav.send(msg)
            self.counters.sent += 1
        except OSError as exc:
            # a udpin endpoint that has not heard its peer, or a serial link gone: not fatal
            log.debug("mavlink: send failed: %s", exc)

    def send_heartbeat(self) -> None:
        m = self._mav
        self._send(
            m.MAVLink_heartbeat_message(
                m.MAV_TYPE_ONBOARD_CONTROLLER, m.MAV_AUTOPILOT_INVALID, 0, 0, m.MAV_STATE_ACTIVE, 3
            )
        )

    def request_interval(self, target_system: int, message_id: int, rate_hz: float) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL (511) for one message, as COMMAND_LONG."""
        m = self._mav
        interval_us = round(1e6 / rate_hz)
        self._send(
            m.MAVLink_command_long_message(
                target_system, 1, MAV_CMD_SET_MESSAGE_INTERVAL, 0, message_id, interval_us, 0, 0, 0, 0, 0
            )
        )

    def request_param(self, target_system: int, name: str) -> None:
        """PARAM_REQUEST_READ of one parameter by name (the autopilot answers with PARAM_VALUE)."""
        m = self._mav
        self._send(m.MAVLink_param_request_read_message(target_system, 1, name.encode("ascii"), -1))

    def send_speed(self, target_system: int, speed_mps: float) -> None:
        """MAV_CMD_DO_CHANGE_SPEED (178) as COMMAND_LONG: ground speed ``speed_mps``, throttle unchanged."""
        m = self._mav
        self._send(
            m.MAVLink_command_long_message(
                target_system, 1, MAV_CMD_DO_CHANGE_SPEED, 0, 1, speed_mps, -1, 0, 0, 0, 0
            )
        )

    def send_setpoint(
        self, target_system: int, time_ms: int, x_m: float, y_m: float, altitude_m: float, type_mask: int
    ) -> None:
        """A position-only SET_POSITION_TARGET_LOCAL_NED for map-frame (x East, y North)."""
        m = self._mav
        self._send(
            m.MAVLink_set_position_target_local_ned_message(
                time_ms & 0xFFFFFFFF,
                target_system,
                1,
                MAV_FRAME_LOCAL_NED,
                type_mask,
                y_m,  # north
                x_m,  # east
                -altitude_m,  # down
                *_UNUSED_TARGET_FIELDS,
            )
        )

    def send_statustext(self, text: str, severity: int = 6) -> None:
        """STATUSTEXT (severity 6 = INFO), cut to the 50 characters MAVLink carries."""
        m = self._mav
        self._send(m.MAVLink_statustext_message(severity, text[:50].encode("ascii", errors="replace")))
