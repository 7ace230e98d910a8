"""The sim_bridge for ArduPilot SITL: a MAVLink relay that adds the project's plume to a real autopilot.

SITL simulates the vehicle; it knows nothing of chemicals and a rover sends no flow. The bridge sits
between SITL and the service the way mavlink-router does: every frame from one side reaches the
other byte for byte (sequence numbers, signatures, messages outside our dialect and even bytes
that do not parse are passed on unchanged), so the service talks to the real autopilot. On the
way it reads the autopilot's LOCAL_POSITION_NED, runs the scenario's flow field and puff plume
(``sim_bridge.world``) at that position in simulated time, and injects toward the service, as a
separate component of the vehicle's system (MAV_COMP_ID_PERIPHERAL by default):

- NAMED_VALUE_FLOAT ``CHEM``: the detector's reading at the vehicle (what ``oslim stub`` sends);
- WIND: the flow at the vehicle as ArduPilot reports it (the direction it comes FROM, speed).

Map frame = SITL's local frame (DESIGN.md: local ENU relative to the autopilot's local origin), so
the scenario's source and area are used as they are; the vehicle starts wherever SITL put it.

Framing: pymavlink's parser in robust mode consumes every byte into exactly one item (a frame, an
unknown message or a run of bad bytes) and keeps an incomplete frame until its rest arrives. We
forward each item's original bytes, so injected frames only ever go *between* whole frames.

Flow control and loss: a TCP side applies backpressure (the reader waits while the other side's
writer drains), so nothing is lost between TCP endpoints. A UDP side cannot be slowed: received
datagrams wait in a bounded queue of ``queue_size`` and, when it is full, the *oldest* is dropped
and counted (``dropped``) - fresh telemetry matters more than stale. Outgoing UDP packs whole
frames into datagrams of at most ``_DATAGRAM_BYTES``.

asyncio only: sockets through asyncio streams and datagram endpoints, the world stepped in one task.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import StrEnum
from types import TracebackType
from typing import Any, Self

from service.core.errors import ConfigError, LinkError
from service.core.samples import Position
from service.edges import mavlink_dialect
from service.edges.telemetry import Heartbeat, TelemetrySettings, decode
from sim_bridge.world import World

log = logging.getLogger(__name__)

MAV_COMP_ID_PERIPHERAL = 158
"""Default component id of the injected sensor messages (MAVLink's generic peripheral)."""
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MSG_ID_LOCAL_POSITION_NED = 32
_DATAGRAM_BYTES = 1400
"""Largest outgoing UDP datagram: whole frames are packed up to this size (one Ethernet MTU)."""
_READ_BYTES = 65536
_MAX_CATCHUP_STEPS = 200
"""World steps done in one go; beyond this the simulation slows down rather than jump (counted)."""
_POSITION_RETRY_S = 3.0
"""Without a position for this long, LOCAL_POSITION_NED is asked of the autopilot again."""


class Scheme(StrEnum):
    """The pymavlink connection-string schemes the bridge speaks, on either side."""

    TCP = "tcp"
    """Connect to a TCP server (SITL serves 5760, 5762, 5763)."""
    TCPIN = "tcpin"
    """Listen for one TCP client (the latest client is the peer)."""
    UDPIN = "udpin"
    """Listen on UDP; replies go to whoever spoke last (nothing can be sent before that)."""
    UDPOUT = "udpout"
    """Send UDP to an address and hear its replies."""


@dataclass(frozen=True)
class Endpoint:
    scheme: Scheme
    host: str
    port: int

    @classmethod
    def parse(cls, url: str) -> Self:
        """``scheme:host:port`` as pymavlink writes it, e.g. ``tcp:127.0.0.1:5762``."""
        scheme, _, rest = url.partition(":")
        host, _, port = rest.rpartition(":")
        try:
            kind = Scheme(scheme)
            number = int(port)
        except ValueError:
            known = ", ".join(s.value for s in Scheme)
            raise ConfigError(f"{url!r}: expected SCHEME:HOST:PORT with SCHEME one of {known}") from None
        if not host or not 0 < number < 65536:
            raise ConfigError(f"{url!r}: expected SCHEME:HOST:PORT with a port in 1..65535")
        return cls(kind, host, number)

    def __str__(self) -> str:
        return f"{self.scheme.value}:{self.host}:{self.port}"


@dataclass(frozen=True)
class BridgeOptions:
    sitl_url: str = "tcp:127.0.0.1:5762"
    """SITL's side: its second serial port, where a companion on TELEM2 would be."""
    to_url: str = "udpout:127.0.0.1:14550"
    """The service's side; udpout reaches the service's default ``udpin:0.0.0.0:14550``."""
    component_id: int = MAV_COMP_ID_PERIPHERAL
    """Component id of the injected messages (the system id is the vehicle's)."""
    sensor_name: str = "CHEM"
    """NAMED_VALUE_FLOAT name of the injected reading (the service's ``sensor.name``)."""
    chem_rate_hz: float = 10.0
    """Injected NAMED_VALUE_FLOAT rate, simulated Hz (0 = off)."""
    wind_rate_hz: float = 2.0
    """Injected WIND rate, simulated Hz (0 = off, e.g. to use SITL's own windvane instead)."""
    position_rate_hz: float = 5.0
    """LOCAL_POSITION_NED rate asked of the autopilot for the bridge's own use (0 = never ask)."""
    speed: float = 1.0
    """Simulated seconds per wall second: SITL's ``--speedup``."""
    connect_timeout_s: float = 60.0
    """How long to keep trying to reach a ``tcp:`` endpoint (SITL may still be starting)."""
    queue_size: int = 10_000
    """Received chunks waiting per side; a full UDP queue drops its oldest (see the module doc)."""

    def __post_init__(self) -> None:
        Endpoint.parse(self.sitl_url)
        Endpoint.parse(self.to_url)
        if not 0 < self.component_id <= 255:
            raise ConfigError(f"component id must be in 1..255, got {self.component_id}")
        if not 1 <= len(self.sensor_name.encode()) <= 10:
            raise ConfigError(f"sensor name {self.sensor_name!r} must be 1 to 10 bytes")
        for key in ("chem_rate_hz", "wind_rate_hz", "position_rate_hz"):
            rate = getattr(self, key)
            if not (math.isfinite(rate) and 0 <= rate <= 50):
                raise ConfigError(f"{key} must be in [0, 50] Hz, got {rate}")
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise ConfigError(f"speed must be positive, got {self.speed}")
        if not (math.isfinite(self.connect_timeout_s) and self.connect_timeout_s > 0):
            raise ConfigError(f"connect_timeout_s must be positive, got {self.connect_timeout_s}")
        if self.queue_size < 10:
            raise ConfigError(f"queue_size must be at least 10, got {self.queue_size}")


@dataclass(frozen=True)
class SideCounters:
    frames: int = 0
    """Items forwarded from this side: frames, unknown messages and runs of bad bytes."""
    bytes: int = 0
    bad: int = 0
    """Items that were not valid frames of our dialect (forwarded all the same)."""
    dropped: int = 0
    """Datagrams lost: received while the queue was full, or to be sent before a udpin peer spoke."""


@dataclass(frozen=True)
class BridgeStatus:
    time_s: float
    """Simulated time of the bridge's world."""
    system_id: int | None
    """The vehicle's system id, from the autopilot's first HEARTBEAT."""
    position_m: tuple[float, float] | None
    """The vehicle's last position, map frame."""
    distance_m: float
    """Length of the vehicle's track (from its positions) since the bridge started."""
    chem_sent: int
    wind_sent: int
    last_chem: float | None
    sitl_winds: int
    """WIND messages the autopilot sent itself (WNDVN_TYPE set): the service then sees two flows."""
    from_sitl: SideCounters
    from_service: SideCounters
    lag_events: int


class _Link:
    """One side of the bridge: bytes in as chunks through a bounded queue, whole frames out."""

    def __init__(self, endpoint: Endpoint, name: str, queue_size: int) -> None:
        self.endpoint = endpoint
        self.name = name
        self._chunks: asyncio.Queue[bytes] = asyncio.Queue(maxsize=queue_size)
        self.dropped = 0
        self.closed: asyncio.Future[None] | None = None
        """Resolves with LinkError when a connection we depend on ends."""

    async def open(self, connect_timeout_s: float) -> None:
        raise NotImplementedError

    async def read(self) -> bytes:
        return await self._chunks.get()

    def _offer(self, data: bytes) -> None:
        """Queue a datagram; when full, drop the oldest (UDP cannot be slowed down)."""
        if self._chunks.full():
            self._chunks.get_nowait()
            self.dropped += 1
        self._chunks.put_nowait(data)

    def send(self, frames: list[bytes]) -> None:
        raise NotImplementedError

    async def drain(self) -> None:
        """Wait until the other end has taken what was sent (TCP); UDP returns at once."""

    async def close(self) -> None:
        raise NotImplementedError

    def _fail(self, reason: str) -> None:
        if self.closed is not None and not self.closed.done():
            self.closed.set_exception(LinkError(f"{self.name} ({self.endpoint}): {reason}"))


class _TcpLink(_Link):
    """``tcp:`` (connect, retrying until ``connect_timeout_s``) or ``tcpin:`` (serve the latest client)."""

    def __init__(self, endpoint: Endpoint, name: str, queue_size: int) -> None:
        super().__init__(endpoint, name, queue_size)
        self._writer: asyncio.StreamWriter | None = None
        self._server: asyncio.Server | None = None
        self._readers: set[asyncio.Task[None]] = set()

    async def open(self, connect_timeout_s: float) -> None:
        self.closed = asyncio.get_running_loop().create_future()
        host, port = self.endpoint.host, self.endpoint.port
        if self.endpoint.scheme is Scheme.TCPIN:
            self._server = await asyncio.start_server(self._accept, host, port)
            return
        loop = asyncio.get_running_loop()
        deadline = loop.time() + connect_timeout_s
        while True:
            try:
                reader, writer = await asyncio.open_connection(host, port)
                break
            except OSError as exc:
                if loop.time() >= deadline:
                    raise LinkError(f"{self.name}: cannot connect to {self.endpoint}: {exc}") from None
                await asyncio.sleep(0.2)  # SITL opens its ports a moment after it starts
        self._start(reader, writer, fatal=True)

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._writer is not None:
            self._writer.close()
        log.info("%s: client %s connected", self.name, writer.get_extra_info("peername"))
        self._start(reader, writer, fatal=False)

    def _start(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, fatal: bool) -> None:
        self._writer = writer
        task = asyncio.create_task(self._pump(reader, writer, fatal), name=f"{self.name}-reader")
        self._readers.add(task)
        task.add_done_callback(self._readers.discard)

    async def _pump(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, fatal: bool) -> None:
        try:
            while data := await reader.read(_READ_BYTES):
                await self._chunks.put(data)  # waits while the queue is full: backpressure
        except OSError as exc:
            log.debug("%s: read failed: %s", self.name, exc)
        if self._writer is writer:
            self._writer = None
        writer.close()
        if fatal:
            self._fail("connection closed")
        else:
            log.info("%s: client disconnected", self.name)

    def send(self, frames: list[bytes]) -> None:
        if self._writer is None:
            self.dropped += 1
            return
        self._writer.write(b"".join(frames))

    async def drain(self) -> None:
        writer = self._writer
        if writer is not None:
            try:
                await writer.drain()
            except OSError as exc:  # the peer went away; its reader reports it
                log.debug("%s: write failed: %s", self.name, exc)

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for task in list(self._readers):  # first, so our own hang-up is not reported as SITL's
            task.cancel()
        await asyncio.gather(*self._readers, return_exceptions=True)
        if self._writer is not None:
            self._writer.close()
            with contextlib.suppress(OSError):
                await self._writer.wait_closed()
            self._writer = None
        if self._server is not None:
            await self._server.wait_closed()
            self._server = None


class _UdpProtocol(asyncio.DatagramProtocol):
    def __init__(self, link: _UdpLink) -> None:
        self.link = link

    def datagram_received(self, data: bytes, addr: tuple[str | Any, int]) -> None:
        self.link.heard(data, addr)

    def error_received(self, exc: Exception) -> None:
        # e.g. ICMP port unreachable while the service is not up yet: not fatal
        log.debug("%s: %s", self.link.name, exc)


class _UdpLink(_Link):
    """``udpin:`` (bind; the peer is whoever spoke last) or ``udpout:`` (send to the address)."""

    def __init__(self, endpoint: Endpoint, name: str, queue_size: int) -> None:
        super().__init__(endpoint, name, queue_size)
        self._transport: asyncio.DatagramTransport | None = None
        self._peer: tuple[str, int] | None = None

    async def open(self, connect_timeout_s: float) -> None:
        loop = asyncio.get_running_loop()
        self.closed = loop.create_future()
        address = (self.endpoint.host, self.endpoint.port)
        try:
            if self.endpoint.scheme is Scheme.UDPIN:
                transport, _ = await loop.create_datagram_endpoint(
                    lambda: _UdpProtocol(self), local_addr=address
                )
            else:
                transport, _ = await loop.create_datagram_endpoint(
                    lambda: _UdpProtocol(self), remote_addr=address
                )
                self._peer = address
        except OSError as exc:
            raise LinkError(f"{self.name}: cannot open {self.endpoint}: {exc}") from None
        self._transport = transport

    def heard(self, data: bytes, addr: tuple[Any, int]) -> None:
        if self.endpoint.scheme is Scheme.UDPIN:
            self._peer = (str(addr[0]), int(addr[1]))
        self._offer(data)

    def send(self, frames: list[bytes]) -> None:
        transport = self._transport
        if transport is None or self._peer is None:
            self.dropped += 1
            return
        target = None if self.endpoint.scheme is Scheme.UDPOUT else self._peer
        batch: list[bytes] = []
        size = 0
        for frame in frames:
            if batch and size + len(frame) > _DATAGRAM_BYTES:
                transport.sendto(b"".join(batch), target)
                batch, size = [], 0
            batch.append(frame)
            size += len(frame)
        if batch:
            transport.sendto(b"".join(batch), target)

    async def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None


def _link(url: str, name: str, queue_size: int) -> _Link:
    endpoint = Endpoint.parse(url)
    if endpoint.scheme in (Scheme.TCP, Scheme.TCPIN):
        return _TcpLink(endpoint, name, queue_size)
    return _UdpLink(endpoint, name, queue_size)


def wind_fields(u_east_mps: float, u_north_mps: float) -> tuple[float, float]:
    """ArduPilot's WIND (direction the flow comes FROM, compass degrees in [0, 360); speed m/s)
    for a flow moving toward (East, North)."""
    direction_deg = math.degrees(math.atan2(-u_east_mps, -u_north_mps)) % 360.0
    return direction_deg, math.hypot(u_east_mps, u_north_mps)


class SitlBridge:
    """The bridge as an async context manager: entering connects both sides and starts relaying."""

    def __init__(self, world: World, options: BridgeOptions | None = None) -> None:
        self.world = world
        self.options = options or BridgeOptions()
        self._mav = mavlink_dialect.dialect()
        self._settings = TelemetrySettings(chem_name=self.options.sensor_name)
        self._sitl = _link(self.options.sitl_url, "sitl", self.options.queue_size)
        self._service = _link(self.options.to_url, "service", self.options.queue_size)
        self._counters = {"sitl": SideCounters(), "service": SideCounters()}
        self._autopilot: tuple[int, int] | None = None
        self._encoder: Any = None
        self._position: Position | None = None
        self._position_wall_s: float | None = None
        self._requested_wall_s: float | None = None
        self._boot_stamp: tuple[int, float] | None = None
        self._distance_m = 0.0
        self._chem_sent = self._wind_sent = self._sitl_winds = 0
        self._last_chem: float | None = None
        self._lag_events = 0
        self._sim_now_s = world.time_s
        self._tasks: list[asyncio.Task[None]] = []
        self._changed: asyncio.Condition | None = None

    # ----------------------------------------------------------------- lifecycle

    async def __aenter__(self) -> Self:
        self._changed = asyncio.Condition()
        try:
            await self._service.open(self.options.connect_timeout_s)
            await self._sitl.open(self.options.connect_timeout_s)
        except BaseException:
            await self._close_links()
            raise
        sitl_parser, service_parser = self._parser(), self._parser()
        self._tasks = [
            asyncio.create_task(self._relay(self._sitl, self._service, sitl_parser, True), name="from-sitl"),
            asyncio.create_task(
                self._relay(self._service, self._sitl, service_parser, False), name="from-service"
            ),
            asyncio.create_task(self._simulate(), name="bridge-world"),
        ]
        log.info(
            "sitl-bridge: %s <-> %s; injecting %s at %g Hz and WIND at %g Hz as component %d",
            self.options.sitl_url,
            self.options.to_url,
            self.options.sensor_name,
            self.options.chem_rate_hz,
            self.options.wind_rate_hz,
            self.options.component_id,
        )
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()

    async def close(self) -> None:
        """Stop relaying and close both sides (idempotent)."""
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        await self._close_links()

    async def _close_links(self) -> None:
        for link in (self._service, self._sitl):
            await link.close()
            if link.closed is None:
                continue
            if link.closed.done():
                if not link.closed.cancelled():
                    link.closed.exception()  # retrieved: serve() may never have looked
            else:
                link.closed.cancel()

    async def serve(self, stop: asyncio.Event) -> None:
        """Relay until ``stop`` is set; raises LinkError when SITL (or a ``tcp:`` service) hangs up."""
        waiters: list[asyncio.Future[Any]] = [asyncio.ensure_future(stop.wait()), *self._tasks]
        waiters += [f for f in (self._sitl.closed, self._service.closed) if f is not None]
        done, _ = await asyncio.wait(waiters, return_when=asyncio.FIRST_COMPLETED)
        waiters[0].cancel()
        for fut in done:
            if fut is not waiters[0] and not fut.cancelled() and fut.exception() is not None:
                raise fut.exception()  # type: ignore[misc]

    # ----------------------------------------------------------------- state

    def status(self) -> BridgeStatus:
        pos = self._position
        return BridgeStatus(
            time_s=self._sim_now_s,
            system_id=None if self._autopilot is None else self._autopilot[0],
            position_m=None if pos is None else (pos.x, pos.y),
            distance_m=self._distance_m,
            chem_sent=self._chem_sent,
            wind_sent=self._wind_sent,
            last_chem=self._last_chem,
            sitl_winds=self._sitl_winds,
            from_sitl=replace(self._counters["sitl"], dropped=self._sitl.dropped + self._service.dropped),
            from_service=self._counters["service"],
            lag_events=self._lag_events,
        )

    async def wait_for(
        self, predicate: Callable[[BridgeStatus], bool], timeout_s: float | None
    ) -> BridgeStatus:
        """Wait until ``predicate(status)`` holds; TimeoutError after ``timeout_s`` wall seconds."""
        if self._changed is None:
            raise LinkError("the bridge is not running")
        changed = self._changed
        async with changed:
            await asyncio.wait_for(changed.wait_for(lambda: predicate(self.status())), timeout_s)
        return self.status()

    async def _notify(self) -> None:
        if self._changed is not None:
            async with self._changed:
                self._changed.notify_all()

    # ----------------------------------------------------------------- relaying

    def _parser(self) -> Any:
        parser = self._mav.MAVLink(None)
        parser.robust_parsing = True  # every byte comes out as a frame or as bad data: none lost
        return parser

    async def _relay(self, src: _Link, dst: _Link, parser: Any, from_sitl: bool) -> None:
        side = "sitl" if from_sitl else "service"
        while True:
            chunk = await src.read()
            try:
                items = parser.parse_buffer(chunk) or []
            except Exception as exc:  # pymavlink on hostile input; the parser's buffer is lost
                log.warning("%s: unparsable input dropped: %s", side, exc)
                parser.buf, parser.buf_index = bytearray(), 0
                continue
            frames = [bytes(item.get_msgbuf()) for item in items]
            bad = sum(
                item.get_type() == "BAD_DATA" or item.get_type().startswith("UNKNOWN_") for item in items
            )
            c = self._counters[side]
            self._counters[side] = replace(
                c, frames=c.frames + len(frames), bytes=c.bytes + sum(map(len, frames)), bad=c.bad + bad
            )
            if frames:
                dst.send(frames)
            if from_sitl:
                for item in items:
                    self._inspect(item)
            await dst.drain()
            await asyncio.sleep(0)  # a non-empty queue never suspends: let the other tasks run

    def _inspect(self, msg: Any) -> None:
        """Learn the vehicle's identity and position from what the autopilot sends."""
        kind = msg.get_type()
        if kind not in ("HEARTBEAT", "LOCAL_POSITION_NED", "WIND"):
            return
        source = (msg.get_srcSystem(), msg.get_srcComponent())
        now = asyncio.get_running_loop().time()
        item = decode(msg, now, self._settings)
        if isinstance(item, Heartbeat) and self._autopilot is None:
            self._adopt(source)
        if source != self._autopilot:
            return
        if kind == "WIND":
            if self._sitl_winds == 0:
                log.warning(
                    "the autopilot sends WIND itself (WNDVN_TYPE set?): the service will see two flows; "
                    "set WNDVN_TYPE 0 or run the bridge with --wind-rate 0"
                )
            self._sitl_winds += 1
        elif isinstance(item, Heartbeat):
            self._request_position(now)
        elif isinstance(item, Position):
            last = self._position
            if last is not None:
                self._distance_m += math.hypot(item.x - last.x, item.y - last.y)
            self._position, self._position_wall_s = item, now
            self._boot_stamp = (int(msg.time_boot_ms), now)

    def _adopt(self, source: tuple[int, int]) -> None:
        self._autopilot = source
        self._encoder = self._mav.MAVLink(None, srcSystem=source[0], srcComponent=self.options.component_id)
        log.info("autopilot heard: system %d component %d", *source)

    def _request_position(self, now: float) -> None:
        """Ask for LOCAL_POSITION_NED when the autopilot is first heard and while none arrives."""
        rate = self.options.position_rate_hz
        if rate <= 0 or self._autopilot is None:
            return
        fresh = self._position_wall_s is not None and now - self._position_wall_s < _POSITION_RETRY_S
        asked = self._requested_wall_s is not None and now - self._requested_wall_s < _POSITION_RETRY_S
        if fresh or asked:
            return
        self._requested_wall_s = now
        system, component = self._autopilot
        message = self._mav.MAVLink_command_long_message(
            system, component, MAV_CMD_SET_MESSAGE_INTERVAL, 0,
            MSG_ID_LOCAL_POSITION_NED, round(1e6 / rate), 0, 0, 0, 0, 0,
        )  # fmt: skip
        self._sitl.send([self._encode(message)])

    def _encode(self, message: Any) -> bytes:
        encoder = self._encoder
        data: bytes = bytes(message.pack(encoder))
        encoder.seq = (encoder.seq + 1) % 256
        return data

    # ----------------------------------------------------------------- the simulated world

    async def _simulate(self) -> None:
        loop = asyncio.get_running_loop()
        world, speed = self.world, self.options.speed
        wall0, sim0 = loop.time(), world.time_s
        streams: list[tuple[float, Callable[[], None]]] = [
            (self.options.chem_rate_hz, self._send_chem),
            (self.options.wind_rate_hz, self._send_wind),
        ]
        active = [(1.0 / rate, send) for rate, send in streams if rate > 0]
        due = [world.time_s] * len(active)
        while True:
            now = sim0 + (loop.time() - wall0) * speed
            steps = 0
            while world.time_s + world.dt_s <= now + 1e-9:
                self._place_vehicle()
                world.step()
                steps += 1
                if steps >= _MAX_CATCHUP_STEPS:
                    self._lag_events += 1
                    wall0, sim0 = loop.time(), world.time_s
                    now = world.time_s
                    break
            self._sim_now_s = max(self._sim_now_s, now)
            if self._ready():
                self._place_vehicle()
                frames = []
                for k, (interval, send) in enumerate(active):
                    if due[k] <= now + 1e-9:
                        frames.append(send)
                        due[k] = due[k] + interval if due[k] + interval > now else now + interval
                for send in frames:
                    send()
            else:
                due = [now] * len(active)
            await self._notify()
            next_s = min([world.time_s + world.dt_s, *due])
            await asyncio.sleep(max((next_s - sim0) / speed - (loop.time() - wall0), 0.0))

    def _ready(self) -> bool:
        return self._encoder is not None and self._position is not None

    def _place_vehicle(self) -> None:
        pos = self._position
        if pos is not None:
            self.world.vehicle = replace(self.world.vehicle, x_m=pos.x, y_m=pos.y, vx_mps=0.0, vy_mps=0.0)

    def _time_boot_ms(self) -> int:
        """The autopilot's time_boot_ms, carried forward from its last position by the wall clock."""
        if self._boot_stamp is None:
            return 0
        boot_ms, at = self._boot_stamp
        ahead_ms = (asyncio.get_running_loop().time() - at) * self.options.speed * 1e3
        return int(boot_ms + ahead_ms) & 0xFFFFFFFF

    def _inject(self, message: Any) -> None:
        self._service.send([self._encode(message)])

    def _send_chem(self) -> None:
        reading = self.world.chem_reading()
        self._inject(
            self._mav.MAVLink_named_value_float_message(
                self._time_boot_ms(), self.options.sensor_name.encode(), reading
            )
        )
        self._last_chem = reading
        self._chem_sent += 1

    def _send_wind(self) -> None:
        direction_deg, speed_mps = wind_fields(*self.world.flow_at_vehicle())
        self._inject(self._mav.MAVLink_wind_message(direction_deg, speed_mps, 0.0))
        self._wind_sent += 1
