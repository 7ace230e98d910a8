"""A software MAVLink vehicle that behaves like an ArduPilot vehicle in GUIDED (DESIGN.md, stub contract).

System 1, component 1, MAVLink 2 (ardupilotmega dialect). It sends HEARTBEAT with
MAV_AUTOPILOT_ARDUPILOTMEGA, a rover or submarine type and ArduPilot's custom_mode; honours
SET_MODE and MAV_CMD_DO_SET_MODE, MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_SET_MESSAGE_INTERVAL and
MAV_CMD_REQUEST_MESSAGE with COMMAND_ACK, and in GUIDED MAV_CMD_DO_CHANGE_SPEED (kept until the mode
changes, as Rover does); answers PARAM_REQUEST_READ of a rover's WP_RADIUS (the world's arrival
radius), WP_SPEED and CRUISE_SPEED (its cruise speed) with PARAM_VALUE; streams
LOCAL_POSITION_NED, the flow at the vehicle as WIND (as ArduPilot) and WIND_COV (as PX4),
NAMED_VALUE_FLOAT "CHEM" and, when asked, NAMED_VALUE_INT "CHEM_DET"; drives toward the latest
SET_POSITION_TARGET_LOCAL_NED (MAV_FRAME_LOCAL_NED, type_mask 3576 or 3580) only while armed in
GUIDED. Anything malformed or unexpected is counted and ignored, never fatal.

Time is simulated: the world advances ``speed`` simulated seconds per wall second, stream
intervals are simulated time and time_boot_ms is the simulated time since the world started,
so ``speed > 1`` runs a whole mission faster than real time with the same message counts.

Socket I/O is the only asyncio here: the pymavlink socket is non-blocking and read from the
event loop's reader callback; the world steps in one task.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from types import MappingProxyType, ModuleType, TracebackType
from typing import Any, Self

from service.core.errors import ConfigError, LinkError
from service.edges import mavlink_dialect
from service.edges.signing import SigningCounters, enable_signing
from sim_bridge.autopilot import AUTOPILOTS, Autopilot, VehicleKind
from sim_bridge.world import World

log = logging.getLogger(__name__)

MAX_RATE_HZ = 50.0
"""Fastest stream rate honoured (ArduPilot's scheduler limit); faster requests are clamped."""
_MAX_CATCHUP_STEPS = 200
"""World steps done in one go before yielding; beyond this the simulation re-anchors (lags)."""
_MAX_READS = 500
"""Messages parsed per reader callback before yielding back to the loop."""
POSITION_TYPE_MASKS = frozenset({3576, 3580})
"""Position-only SET_POSITION_TARGET_LOCAL_NED masks: x, y, z (3576) and x, y (3580, Rover)."""


def _text(raw: str | bytes) -> str:
    """A MAVLink char[] field as text, without its NUL padding."""
    text = raw if isinstance(raw, str) else bytes(raw).decode(errors="replace")
    return text.rstrip("\x00")


class Stream(StrEnum):
    """The telemetry streams, named by the MAVLink message that carries them."""

    HEARTBEAT = "HEARTBEAT"
    LOCAL_POSITION_NED = "LOCAL_POSITION_NED"
    WIND = "WIND"
    WIND_COV = "WIND_COV"
    NAMED_VALUE_FLOAT = "NAMED_VALUE_FLOAT"
    NAMED_VALUE_INT = "NAMED_VALUE_INT"


DEFAULT_RATES_HZ: MappingProxyType[Stream, float] = MappingProxyType(
    {
        Stream.HEARTBEAT: 1.0,
        Stream.LOCAL_POSITION_NED: 5.0,
        Stream.WIND: 2.0,
        Stream.WIND_COV: 2.0,
        Stream.NAMED_VALUE_FLOAT: 10.0,
        Stream.NAMED_VALUE_INT: 0.0,
    }
)
"""Rates at start-up (0 = off), simulated Hz; SET_MESSAGE_INTERVAL with interval 0 returns to these."""


@dataclass(frozen=True)
class StubOptions:
    url: str = "udpout:127.0.0.1:14550"
    """pymavlink connection string; udpout speaks first, so a udpin service hears it."""
    speed: float = 1.0
    """Simulated seconds per wall-clock second."""
    kind: VehicleKind = VehicleKind.ROVER
    system_id: int = 1
    component_id: int = 1
    rates_hz: Mapping[Stream, float] = field(default_factory=lambda: dict(DEFAULT_RATES_HZ))
    """Start-up stream rates; missing streams take DEFAULT_RATES_HZ."""
    sensor_name: str = "CHEM"
    detection_name: str = "CHEM_DET"
    signing_key: bytes | None = field(default=None, repr=False)
    """MAVLink 2 signing key (32 bytes): sign all we send, ignore unsigned or wrongly signed input."""
    signing_link_id: int = 0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise ConfigError(f"stub speed must be positive, got {self.speed}")
        if not (1 <= self.system_id <= 255 and 0 <= self.component_id <= 255):
            raise ConfigError(
                f"stub ids out of range: system {self.system_id}, component {self.component_id}"
            )
        for name in (self.sensor_name, self.detection_name):
            if not 1 <= len(name.encode()) <= 10:
                raise ConfigError(f"named value {name!r} must be 1 to 10 bytes")
        for stream, rate in self.rates_hz.items():
            if not (math.isfinite(rate) and rate >= 0):
                raise ConfigError(f"stream rate of {stream} must be >= 0 Hz, got {rate}")


@dataclass(frozen=True)
class StubCounters:
    received: int = 0
    """Messages handled."""
    malformed: int = 0
    """Bytes or frames that did not parse (bad CRC, truncated, garbage) or had invalid fields."""
    unexpected: int = 0
    """Well-formed messages of a type a vehicle does not act on."""
    foreign: int = 0
    """Messages addressed to another system or component."""
    rejected_commands: int = 0
    """Commands acknowledged with anything but MAV_RESULT_ACCEPTED."""
    ignored_setpoints: int = 0
    """Setpoints ignored: not in GUIDED, another frame or type_mask, non-finite values."""


@dataclass(frozen=True)
class StatusText:
    time_s: float
    severity: int
    text: str


@dataclass(frozen=True)
class StubStatus:
    """A snapshot of the stub, for tests and ``oslim sim``."""

    time_s: float
    mode: int
    mode_name: str
    armed: bool
    x_m: float
    y_m: float
    heading_rad: float
    target_m: tuple[float, float] | None
    counters: StubCounters
    statustexts: tuple[StatusText, ...]
    rates_hz: Mapping[Stream, float]
    lag_events: int = 0
    """Times the simulation could not keep up with ``speed`` and slowed simulated time down."""


class VehicleStub:
    """The vehicle stub as an async context manager: entering opens the link and starts the world."""

    def __init__(self, world: World, options: StubOptions | None = None) -> None:
        self.world = world
        self.options = options or StubOptions()
        self._autopilot: Autopilot = AUTOPILOTS[self.options.kind]
        self._mode = self._autopilot.initial
        self._armed = False
        self._rates: dict[Stream, float] = {
            s: self.options.rates_hz.get(s, DEFAULT_RATES_HZ[s]) for s in Stream
        }
        self._due_s: dict[Stream, float] = dict.fromkeys(Stream, world.time_s)
        self._counters = StubCounters()
        self._texts: deque[StatusText] = deque(maxlen=50)
        self._sim_now_s = world.time_s
        self._mav: ModuleType | None = None
        self._conn: Any = None
        self._task: asyncio.Task[None] | None = None
        self._reader_fd: int | None = None
        self._poll_task: asyncio.Task[None] | None = None
        self._changed: asyncio.Condition | None = None
        self._lag_events = 0
        self._handlers: dict[str, Callable[[Any], None]] = {
            "HEARTBEAT": self._on_heartbeat,
            "SET_MODE": self._on_set_mode,
            "COMMAND_LONG": self._on_command,
            "COMMAND_INT": self._on_command,
            "SET_POSITION_TARGET_LOCAL_NED": self._on_position_target,
            "STATUSTEXT": self._on_statustext,
            "PARAM_REQUEST_READ": self._on_param_request,
        }
        self._senders: dict[Stream, Callable[[], None]] = {
            Stream.HEARTBEAT: self._send_heartbeat,
            Stream.LOCAL_POSITION_NED: self._send_position,
            Stream.WIND: self._send_wind,
            Stream.WIND_COV: self._send_wind_cov,
            Stream.NAMED_VALUE_FLOAT: self._send_chem,
            Stream.NAMED_VALUE_INT: self._send_detection,
        }

    # ----------------------------------------------------------------- lifecycle

    async def __aenter__(self) -> Self:
        mavutil = mavlink_dialect.mavutil()
        self._mav = mavlink_dialect.dialect()
        try:
            self._conn = await asyncio.to_thread(
                mavutil.mavlink_connection,
                self.options.url,
                source_system=self.options.system_id,
                source_component=self.options.component_id,
                autoreconnect=True,
            )
        except (OSError, ValueError) as exc:
            raise LinkError(f"stub cannot open {self.options.url}: {exc}") from exc
        if self.options.signing_key is not None:
            enable_signing(self._conn, self.options.signing_key, self.options.signing_link_id)
        loop = asyncio.get_running_loop()
        self._changed = asyncio.Condition()
        fd = getattr(self._conn, "fd", None)
        if isinstance(fd, int) and fd >= 0:
            loop.add_reader(fd, self._drain)
            self._reader_fd = fd
        else:  # no selectable descriptor (e.g. some serial ports): poll
            self._poll_task = asyncio.create_task(self._poll())
        self._task = asyncio.create_task(self._run(), name="vehicle-stub")
        log.info(
            "vehicle stub on %s: %s, system %d, speed x%g",
            self.options.url,
            self.options.kind.value,
            self.options.system_id,
            self.options.speed,
        )
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.close()

    async def close(self) -> None:
        """Stop the world and close the link (idempotent)."""
        for task in (self._task, self._poll_task):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        self._task = self._poll_task = None
        if self._reader_fd is not None:
            asyncio.get_running_loop().remove_reader(self._reader_fd)
            self._reader_fd = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    # ----------------------------------------------------------------- public state

    @property
    def guided(self) -> bool:
        return self._mode == self._autopilot.guided

    @property
    def signing(self) -> SigningCounters | None:
        """Signature checks of what the stub received; None when signing is off."""
        if self.options.signing_key is None or self._conn is None:
            return None
        return SigningCounters.of(self._conn)

    def status(self) -> StubStatus:
        v = self.world.vehicle
        return StubStatus(
            time_s=self._sim_now_s,
            mode=self._mode,
            mode_name=self._autopilot.mode_name(self._mode),
            armed=self._armed,
            x_m=v.x_m,
            y_m=v.y_m,
            heading_rad=v.heading_rad,
            target_m=self.world.target_m,
            counters=self._counters,
            statustexts=tuple(self._texts),
            rates_hz=MappingProxyType(dict(self._rates)),
            lag_events=self._lag_events,
        )

    async def wait_for(self, predicate: Callable[[StubStatus], bool], timeout_s: float | None) -> StubStatus:
        """Wait until ``predicate(status)`` holds; TimeoutError after ``timeout_s`` wall seconds."""
        if self._changed is None:
            raise LinkError("the stub is not running")
        changed = self._changed
        async with changed:
            await asyncio.wait_for(changed.wait_for(lambda: predicate(self.status())), timeout_s)
        return self.status()

    def set_rate(self, stream: Stream, rate_hz: float) -> None:
        """Change a stream's rate (simulated Hz, 0 = off), as SET_MESSAGE_INTERVAL does."""
        self._rates[stream] = min(max(rate_hz, 0.0), MAX_RATE_HZ)
        self._due_s[stream] = self._sim_now_s

    # ----------------------------------------------------------------- simulation loop

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        world, speed = self.world, self.options.speed
        wall0, sim0 = loop.time(), world.time_s
        while True:
            now = sim0 + (loop.time() - wall0) * speed
            steps = 0
            while world.time_s + world.dt_s <= now + 1e-9:
                world.driving = self.guided and self._armed
                world.step()
                steps += 1
                if steps >= _MAX_CATCHUP_STEPS:
                    # cannot keep up: slow simulated time down rather than jump
                    self._lag_events += 1
                    wall0, sim0 = loop.time(), world.time_s
                    now = world.time_s
                    break
            self._sim_now_s = max(self._sim_now_s, now)
            self._emit_due()
            await self._notify()
            next_s = min([world.time_s + world.dt_s, *(self._due_s[s] for s in Stream if self._rates[s] > 0)])
            delay = (next_s - sim0) / speed - (loop.time() - wall0)
            await asyncio.sleep(max(delay, 0.0))

    async def _notify(self) -> None:
        if self._changed is not None:
            async with self._changed:
                self._changed.notify_all()

    def _emit_due(self) -> None:
        now = self._sim_now_s
        for stream in Stream:
            rate = self._rates[stream]
            if rate <= 0 or self._due_s[stream] > now + 1e-9:
                continue
            self._send_stream(stream)
            interval = 1.0 / rate
            due = self._due_s[stream] + interval
            self._due_s[stream] = due if due > now else now + interval

    # ----------------------------------------------------------------- outgoing

    def _send(self, method: str, *args: Any) -> None:
        if self._conn is None:
            return
        try:
            getattr(self._conn.mav, f"{method}_send")(*args)
        except OSError as exc:  # e.g. no route; a vehicle keeps going
            log.debug("send %s failed: %s", method, exc)

    def _time_boot_ms(self) -> int:
        return int(self._sim_now_s * 1000.0) & 0xFFFFFFFF

    def _send_stream(self, stream: Stream) -> None:
        self._senders[stream]()

    def _send_heartbeat(self) -> None:
        mav = self._dialect
        base_mode = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.guided:
            base_mode |= mav.MAV_MODE_FLAG_GUIDED_ENABLED
        if self._armed:
            base_mode |= mav.MAV_MODE_FLAG_SAFETY_ARMED
        state = mav.MAV_STATE_ACTIVE if self._armed else mav.MAV_STATE_STANDBY
        mav_type = getattr(mav, self._autopilot.mav_type)
        self._send("heartbeat", mav_type, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base_mode, self._mode, state, 3)

    def _send_position(self) -> None:
        v = self.world.vehicle
        # extrapolate from the last world step to now, so fast streams are smooth
        ahead_s = max(self._sim_now_s - self.world.time_s, 0.0)
        believed_x, believed_y = self.world.position_reading()
        x_m, y_m = believed_x + v.vx_mps * ahead_s, believed_y + v.vy_mps * ahead_s
        # map ENU (x East, y North) -> NED (x North, y East)
        self._send("local_position_ned", self._time_boot_ms(), y_m, x_m, 0.0, v.vy_mps, v.vx_mps, 0.0)

    def _send_wind(self) -> None:
        u_east, u_north = self.world.flow_at_vehicle()
        # ArduPilot's WIND: the direction the flow comes FROM, compass degrees in [0, 360)
        direction_deg = math.degrees(math.atan2(-u_east, -u_north)) % 360.0
        self._send("wind", direction_deg, math.hypot(u_east, u_north), 0.0)

    def _send_wind_cov(self) -> None:
        u_east, u_north = self.world.flow_at_vehicle()
        time_usec = int(self._sim_now_s * 1e6)
        # PX4's WIND_COV: the velocity the flow moves toward, wind_x North, wind_y East
        self._send("wind_cov", time_usec, u_north, u_east, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def _send_chem(self) -> None:
        reading = self.world.chem_reading()
        self._send("named_value_float", self._time_boot_ms(), self.options.sensor_name.encode(), reading)

    def _send_detection(self) -> None:
        detected = int(self.world.chem_reading() >= self.world.detector.params.threshold)
        self._send("named_value_int", self._time_boot_ms(), self.options.detection_name.encode(), detected)

    def _ack(self, command: int, result: int, msg: Any) -> None:
        if result != self._dialect.MAV_RESULT_ACCEPTED:
            self._count(rejected_commands=1)
        self._send("command_ack", command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    # ----------------------------------------------------------------- incoming

    @property
    def _dialect(self) -> ModuleType:
        if self._mav is None:
            raise LinkError("the stub is not running")
        return self._mav

    def _count(self, **increments: int) -> None:
        counters = self._counters
        self._counters = replace(
            counters, **{name: getattr(counters, name) + n for name, n in increments.items()}
        )

    async def _poll(self) -> None:
        while True:
            self._drain()
            await asyncio.sleep(0.005)

    def _drain(self) -> None:
        """Reader callback: parse and handle what has arrived, never raising."""
        for _ in range(_MAX_READS):
            if self._conn is None:
                return
            try:
                msg = self._conn.recv_msg()
            except OSError as exc:
                log.debug("link read failed: %s", exc)
                return
            except Exception as exc:  # pymavlink raises many types on hostile input; none may stop us
                log.debug("unparsable input: %s", exc)
                self._count(malformed=1)
                continue
            if msg is None:
                return
            self._handle(msg)

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self._count(malformed=1)
            return
        if (
            msg.get_srcSystem() == self.options.system_id
            and msg.get_srcComponent() == self.options.component_id
        ):
            return  # our own echo (e.g. a looped-back broadcast)
        handler = self._handlers.get(kind)
        if handler is None:
            self._count(unexpected=1)
            return
        if not self._addressed_to_us(msg):
            self._count(foreign=1)
            return
        try:
            handler(msg)
        except (ValueError, TypeError, AttributeError, OverflowError) as exc:
            log.warning("ignored a malformed %s: %s", kind, exc)
            self._count(malformed=1)
            return
        self._count(received=1)

    def _addressed_to_us(self, msg: Any) -> bool:
        """Broadcast (0) or our ids; messages without a target (HEARTBEAT, STATUSTEXT) are for all."""
        system = getattr(msg, "target_system", 0)
        component = getattr(msg, "target_component", 0)
        return system in (0, self.options.system_id) and component in (0, self.options.component_id)

    def _on_heartbeat(self, msg: Any) -> None:
        """A companion or GCS heartbeat: nothing to do (ArduPilot only tracks it for failsafes)."""

    def _on_statustext(self, msg: Any) -> None:
        text = _text(msg.text)
        self._texts.append(StatusText(self._sim_now_s, int(msg.severity), text))
        log.info("STATUSTEXT from %d/%d: %s", msg.get_srcSystem(), msg.get_srcComponent(), text)

    def _params(self) -> dict[str, float]:
        """The parameters the stub has: a rover's acceptance radius (the world's arrival radius)
        and its guided speed, WP_SPEED and CRUISE_SPEED both the cruise speed; a submarine none."""
        radius = self._autopilot.radius_param
        if radius is None:
            return {}
        p = self.world.vehicle_params
        return {radius: p.arrival_radius_m, "WP_SPEED": p.speed_mps, "CRUISE_SPEED": p.speed_mps}

    def _on_param_request(self, msg: Any) -> None:
        """PARAM_VALUE for one of ``_params``, by name or index; as ArduPilot, no answer for a name it
        does not know."""
        params = self._params()
        names = list(params)
        if msg.param_index == -1:
            name = _text(msg.param_id)
        elif 0 <= msg.param_index < len(names):
            name = names[msg.param_index]
        else:
            return
        if name not in params:
            return
        real32 = self._dialect.MAV_PARAM_TYPE_REAL32
        self._send("param_value", name.encode(), params[name], real32, len(names), names.index(name))

    def pilot_mode(self, custom_mode: int) -> bool:
        """The pilot's mode switch (RC or ground station): False for a mode the vehicle lacks."""
        return self._set_mode(custom_mode)

    def pilot_arm(self, armed: bool) -> None:
        """The pilot arms or disarms the vehicle."""
        if armed != self._armed:
            log.info("%s by the pilot", "armed" if armed else "disarmed")
        self._armed = armed

    def _set_mode(self, custom_mode: int) -> bool:
        if custom_mode not in self._autopilot.modes:
            return False
        if custom_mode != self._mode:
            log.info(
                "mode %s -> %s", self._autopilot.mode_name(self._mode), self._autopilot.mode_name(custom_mode)
            )
            # ArduPilot drops the guided target and speed when the mode changes; a new GUIDED holds
            self.world.target_m = None
            self.world.speed_mps = None
        self._mode = custom_mode
        return True

    def _on_set_mode(self, msg: Any) -> None:
        mav = self._dialect
        ok = bool(msg.base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED) and self._set_mode(
            int(msg.custom_mode)
        )
        # ArduPilot acknowledges SET_MODE with the message id as the command
        self._ack(mav.MAVLINK_MSG_ID_SET_MODE, mav.MAV_RESULT_ACCEPTED if ok else mav.MAV_RESULT_FAILED, msg)

    def _on_command(self, msg: Any) -> None:
        mav = self._dialect
        commands: dict[int, Callable[[Any], int]] = {
            mav.MAV_CMD_DO_SET_MODE: self._cmd_set_mode,
            mav.MAV_CMD_COMPONENT_ARM_DISARM: self._cmd_arm_disarm,
            mav.MAV_CMD_SET_MESSAGE_INTERVAL: self._cmd_set_message_interval,
            mav.MAV_CMD_REQUEST_MESSAGE: self._cmd_request_message,
            mav.MAV_CMD_DO_CHANGE_SPEED: self._cmd_change_speed,
        }
        command = int(msg.command)
        params = (msg.param1, msg.param2, msg.param3, msg.param4)
        if not all(math.isfinite(p) for p in params):
            result = mav.MAV_RESULT_DENIED
        else:
            action = commands.get(command)
            result = action(msg) if action is not None else mav.MAV_RESULT_UNSUPPORTED
        self._ack(command, result, msg)

    def _cmd_set_mode(self, msg: Any) -> int:
        mav = self._dialect
        base_mode, custom_mode = int(msg.param1), msg.param2
        if not base_mode & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED or custom_mode != int(custom_mode):
            return int(mav.MAV_RESULT_DENIED)
        return int(mav.MAV_RESULT_ACCEPTED if self._set_mode(int(custom_mode)) else mav.MAV_RESULT_FAILED)

    def _cmd_arm_disarm(self, msg: Any) -> int:
        mav = self._dialect
        wanted = {1.0: True, 0.0: False}.get(float(msg.param1))
        if wanted is None:
            return int(mav.MAV_RESULT_DENIED)
        if wanted != self._armed:
            log.info("%s", "armed" if wanted else "disarmed")
        self._armed = wanted
        return int(mav.MAV_RESULT_ACCEPTED)

    def _cmd_change_speed(self, msg: Any) -> int:
        """Drive guided targets at param2 m/s (no faster than the cruise speed) until the mode
        changes; a speed of 0 or less keeps the current one. Only in GUIDED, as Rover."""
        mav = self._dialect
        if not self.guided:
            return int(mav.MAV_RESULT_FAILED)
        if msg.param2 > 0:
            self.world.speed_mps = float(msg.param2)
        return int(mav.MAV_RESULT_ACCEPTED)

    def _stream_of(self, message_id: float) -> Stream | None:
        mav = self._dialect
        ids = {getattr(mav, f"MAVLINK_MSG_ID_{stream.value}"): stream for stream in Stream}
        return ids.get(int(message_id)) if message_id == int(message_id) else None

    def _cmd_set_message_interval(self, msg: Any) -> int:
        mav = self._dialect
        stream = self._stream_of(msg.param1)
        interval_us = msg.param2
        if stream is None:
            return int(mav.MAV_RESULT_DENIED)
        if interval_us < 0:  # -1: stop the stream
            self.set_rate(stream, 0.0)
        elif interval_us == 0:  # 0: back to the default rate
            self.set_rate(stream, self.options.rates_hz.get(stream, DEFAULT_RATES_HZ[stream]))
        else:
            self.set_rate(stream, 1e6 / interval_us)
        return int(mav.MAV_RESULT_ACCEPTED)

    def _cmd_request_message(self, msg: Any) -> int:
        mav = self._dialect
        stream = self._stream_of(msg.param1)
        if stream is None:
            return int(mav.MAV_RESULT_DENIED)
        # after the COMMAND_ACK, as ArduPilot queues the requested message behind it
        asyncio.get_running_loop().call_soon(self._send_stream, stream)
        return int(mav.MAV_RESULT_ACCEPTED)

    def _on_position_target(self, msg: Any) -> None:
        mav = self._dialect
        usable = (
            msg.coordinate_frame == mav.MAV_FRAME_LOCAL_NED
            and msg.type_mask in POSITION_TYPE_MASKS
            and math.isfinite(msg.x)
            and math.isfinite(msg.y)
            and self.guided
        )
        if not usable:
            self._count(ignored_setpoints=1)
            return
        # NED (x North, y East) -> map ENU (x East, y North)
        self.world.target_m = (float(msg.y), float(msg.x))
