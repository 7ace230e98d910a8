"""``oslim preflight``: listen to the vehicle as the service would, and say what it would lack.

Before a field run an engineer wants to know, with the vehicle on the bench or at the slipway,
that the service will hear what it needs: the autopilot's heartbeat, a position, the flow and the
chemical sensor, at the rates a 1 Hz map needs, and that ``mavlink.guided_mode`` is the GUIDED
mode of this autopilot. The preflight opens the same MAVLink connection as ``oslim serve`` (with
signing, when configured), sends the onboard computer's HEARTBEAT, asks the autopilot for the
same streams, opens its Zenoh session, and decodes every message with the service's own decoder
for a few seconds. It never sends a setpoint. Then each check is judged: a FAIL is something the
search cannot work without, a WARN something that will cost it.

``Tally`` and ``assess`` are pure (tests drive them with made-up telemetry); ``listen`` is the edge.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

from service.app.gate import CommandGate
from service.app.service import request_streams
from service.core.config import Config
from service.core.errors import LinkError
from service.core.grid import Grid
from service.core.samples import ChemSample, DetectionSample, FlowSample, Position
from service.edges.mavlink_link import LinkCounters, MavlinkLink
from service.edges.signing import SigningCounters, load_signing_key
from service.edges.telemetry import Heartbeat, Rejected, Telemetry, TelemetrySettings, decode
from service.edges.zenoh_link import ZenohLink

MIN_RATE_HZ = 1.0
"""Slowest stream the 1 Hz map can live with: every tick needs a position, a flow and a reading."""
STILL_FLOW_MPS = 0.05
"""A mean flow slower than this reads as no flow at all (a sensor unplugged, or not calibrated)."""
ALWAYS_SHARE = 0.9
"""A detector at or above its threshold this share of the time is set wrong (or stands in odour)."""

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
PX4_OFFBOARD = 6 << 16
"""PX4's custom_mode for OFFBOARD: main mode 6 in bits 16-23."""
ARDUPILOT_GUIDED: dict[int, tuple[str, int]] = {
    1: ("Plane", 15),
    2: ("Copter", 4),
    3: ("Copter", 4),
    4: ("Copter (helicopter)", 4),
    10: ("Rover", 15),
    11: ("Rover (boat)", 15),
    12: ("Sub", 4),
    13: ("Copter", 4),
    14: ("Copter", 4),
    15: ("Copter", 4),
    29: ("Copter", 4),
}
"""MAV_TYPE -> (ArduPilot firmware, custom_mode of its GUIDED)."""


class Status(StrEnum):
    PASS = "PASS"
    WARN = "WARN"
    FAIL = "FAIL"


@dataclass(frozen=True)
class Check:
    name: str
    status: Status
    detail: str


@dataclass
class Stream:
    """Arrivals of one MAVLink message kind that the decoder turned into telemetry."""

    count: int = 0
    first_s: float = math.nan
    last_s: float = math.nan

    def add(self, time_s: float) -> None:
        if self.count == 0:
            self.first_s = time_s
        self.count += 1
        self.last_s = time_s

    def rate_hz(self, window_s: float) -> float:
        """Arrivals per second: over the span between the first and last when there are several."""
        if self.count >= 3 and self.last_s > self.first_s:
            return (self.count - 1) / (self.last_s - self.first_s)
        return self.count / window_s


@dataclass
class Tally:
    """What ``window_s`` seconds of listening heard, as the service's decoder saw it."""

    window_s: float
    streams: dict[str, Stream] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    heartbeat: Heartbeat | None = None
    position: Position | None = None
    flow_sum: tuple[float, float] = (0.0, 0.0)
    flow_count: int = 0
    chem_min: float = math.inf
    chem_max: float = -math.inf
    chem_count: int = 0
    chem_above: int = 0
    detections: int = 0
    detections_on: int = 0
    link: LinkCounters | None = None
    signing: SigningCounters | None = None
    zenoh: tuple[int, int] | str | None = None
    """Routers and peers the Zenoh session reached, or why it did not open (None: not tried)."""

    def add(self, kind: str, item: Telemetry | Rejected, threshold: float) -> None:
        """Count one decoded message of MAVLink type ``kind``."""
        if isinstance(item, Rejected):
            key = f"{item.message}: {item.reason}"
            self.rejected[key] = self.rejected.get(key, 0) + 1
            return
        if isinstance(item, Heartbeat):
            # the first autopilot heard is the vehicle, as for the service's command gate
            if self.heartbeat is None or item.system == self.heartbeat.system:
                self.heartbeat = item
            return
        self.streams.setdefault(kind, Stream()).add(item.time_s)
        if isinstance(item, Position):
            self.position = item
        elif isinstance(item, FlowSample):
            self.flow_sum = (self.flow_sum[0] + item.flow_x, self.flow_sum[1] + item.flow_y)
            self.flow_count += 1
        elif isinstance(item, ChemSample):
            self.chem_min, self.chem_max = min(self.chem_min, item.value), max(self.chem_max, item.value)
            self.chem_count += 1
            self.chem_above += item.value >= threshold
        elif isinstance(item, DetectionSample):
            self.detections += 1
            self.detections_on += item.detected

    def ignored(self, *kinds: str) -> str:
        """``; heard but ignored: ...`` for the rejected messages of ``kinds`` ("" when none was)."""
        reasons = [f"{k} x{n}" for k, n in sorted(self.rejected.items()) if k.split(":")[0] in kinds]
        return f"; heard but ignored: {', '.join(reasons)}" if reasons else ""

    def rate(self, *kinds: str) -> tuple[str, float]:
        """The fastest of ``kinds`` heard, and its rate (("", 0) when none was)."""
        heard = [(k, self.streams[k].rate_hz(self.window_s)) for k in kinds if k in self.streams]
        return max(heard, key=lambda kr: kr[1], default=("", 0.0))


def assess(tally: Tally, config: Config, recorder: tuple[bool, str]) -> list[Check]:
    """Each check of the preflight, judged from what was heard; ``recorder`` is whether the run
    files can be written, and why not."""
    return [
        _autopilot(tally, config),
        _guided(tally, config),
        _position(tally, config),
        _flow(tally, config),
        _chemical(tally, config),
        _link(tally, config),
        _zenoh(tally, config),
        Check("recorder", Status.PASS if recorder[0] else Status.FAIL, recorder[1]),
        _commanding(tally, config),
    ]


def _autopilot(tally: Tally, config: Config) -> Check:
    hb = tally.heartbeat
    if hb is None:
        return Check(
            "autopilot",
            Status.FAIL,
            f"no autopilot HEARTBEAT in {tally.window_s:g} s on {config.mavlink.url}: check mavlink.url "
            "(port, baud) and that the autopilot sends there (udpin hears only what is sent to it); "
            "stop oslim serve first, which may hold the port",
        )
    kind = f"MAV_TYPE {hb.vehicle_type}"
    if hb.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        what = f"ArduPilot {ARDUPILOT_GUIDED.get(hb.vehicle_type, (kind, 0))[0]}"
    elif hb.autopilot == MAV_AUTOPILOT_PX4:
        what = f"PX4 {kind}"
    else:
        what = f"autopilot {hb.autopilot} {kind}"
    armed = "armed" if hb.armed else "disarmed"
    return Check(
        "autopilot", Status.PASS, f"system {hb.system}: {what}, {armed}, custom_mode {hb.custom_mode}"
    )


def _guided(tally: Tally, config: Config) -> Check:
    hb, mode = tally.heartbeat, config.mavlink.guided_mode
    if hb is None:
        return Check("guided mode", Status.WARN, "not checked: no autopilot heard")
    expected: tuple[str, int] | None = None
    if hb.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        expected = ARDUPILOT_GUIDED.get(hb.vehicle_type)
    elif hb.autopilot == MAV_AUTOPILOT_PX4:
        expected = ("PX4 (OFFBOARD)", PX4_OFFBOARD)
    if expected is None:
        return Check(
            "guided mode",
            Status.WARN,
            f"mavlink.guided_mode = {mode}: GUIDED of this autopilot and MAV_TYPE {hb.vehicle_type} is not "
            "known here; check it, or the service will never command",
        )
    name, value = expected
    if mode != value:
        return Check(
            "guided mode",
            Status.FAIL,
            f"mavlink.guided_mode = {mode}, but {name}'s GUIDED is custom_mode {value}: "
            "the service would never command this vehicle",
        )
    return Check("guided mode", Status.PASS, f"mavlink.guided_mode = {mode}, {name}'s GUIDED")


def _position(tally: Tally, config: Config) -> Check:
    kind, rate = tally.rate("LOCAL_POSITION_NED", "GLOBAL_POSITION_INT")
    if not kind:
        hint = "" if config.mavlink.origin else " (GLOBAL_POSITION_INT is used only with mavlink.origin set)"
        ignored = tally.ignored("LOCAL_POSITION_NED", "GLOBAL_POSITION_INT")
        return Check(
            "position", Status.FAIL, f"no usable LOCAL_POSITION_NED{hint}: the map cannot be updated{ignored}"
        )
    pos = tally.position
    assert pos is not None
    area = config.area
    where = f"at ({pos.x:.1f}, {pos.y:.1f}) m (x East, y North)"
    text = f"{kind} {rate:.1f} Hz, {where}"
    inside = area.x_min <= pos.x <= area.x_max and area.y_min <= pos.y <= area.y_max
    if rate < MIN_RATE_HZ:
        return Check("position", Status.WARN, f"{text}: slower than the map's {MIN_RATE_HZ:g} Hz")
    if not inside:
        return Check(
            "position",
            Status.WARN,
            f"{text}, outside the search area [{area.x_min:g}, {area.x_max:g}] x [{area.y_min:g}, "
            f"{area.y_max:g}]: the map learns nothing out there (is [area] in this frame?)",
        )
    return Check("position", Status.PASS, f"{text}, inside the search area")


def _flow(tally: Tally, config: Config) -> Check:
    kind, rate = tally.rate("WIND", "WIND_COV")
    if not kind:
        ignored = tally.ignored("WIND", "WIND_COV")
        return Check(
            "flow",
            Status.FAIL,
            f"no usable WIND or WIND_COV: the map cannot tell where odour comes from{ignored}",
        )
    n = tally.flow_count
    fx, fy = tally.flow_sum[0] / n, tally.flow_sum[1] / n
    speed = math.hypot(fx, fy)
    bearing = math.degrees(math.atan2(fx, fy)) % 360.0
    text = f"{kind} {rate:.1f} Hz, mean {speed:.2f} m/s toward bearing {bearing:.0f} deg"
    if rate < MIN_RATE_HZ:
        return Check("flow", Status.WARN, f"{text}: slower than the map's {MIN_RATE_HZ:g} Hz")
    if speed < STILL_FLOW_MPS:
        return Check(
            "flow", Status.WARN, f"{text}: reads as still; is the flow sensor connected and calibrated?"
        )
    return Check("flow", Status.PASS, text)


def _chemical(tally: Tally, config: Config) -> Check:
    sensor = config.sensor
    kind, rate = tally.rate("NAMED_VALUE_FLOAT", "NAMED_VALUE_INT")
    if not kind:
        return Check(
            "chemical",
            Status.FAIL,
            f"no usable NAMED_VALUE_FLOAT {sensor.name!r} nor NAMED_VALUE_INT {sensor.detection_name!r} "
            f"(sensor.name, sensor.detection_name){tally.ignored('NAMED_VALUE_FLOAT', 'NAMED_VALUE_INT')}",
        )
    if kind == "NAMED_VALUE_FLOAT":
        share = tally.chem_above / tally.chem_count
        text = (
            f"{sensor.name} {rate:.1f} Hz, readings {tally.chem_min:.3g} to {tally.chem_max:.3g}, "
            f"{share:.0%} at or above sensor.threshold {sensor.threshold:g}"
        )
    else:
        share = tally.detections_on / tally.detections
        text = f"{sensor.detection_name} {rate:.1f} Hz, {share:.0%} detections"
    if rate < MIN_RATE_HZ:
        return Check("chemical", Status.WARN, f"{text}: slower than the map's {MIN_RATE_HZ:g} Hz")
    if share >= ALWAYS_SHARE:
        return Check(
            "chemical", Status.WARN, f"{text}: a detection nearly all the time; is sensor.threshold right?"
        )
    return Check("chemical", Status.PASS, text)


def _link(tally: Tally, config: Config) -> Check:
    problems: list[str] = []
    counters = tally.link
    if counters is not None and counters.bad_data + counters.read_errors:
        problems.append(
            f"{counters.bad_data + counters.read_errors} corrupt or unreadable frames (baud rate?)"
        )
    if counters is not None and counters.dropped:
        problems.append(f"{counters.dropped} messages dropped (queue full)")
    if tally.rejected:
        problems.append("ignored: " + ", ".join(f"{k} x{v}" for k, v in sorted(tally.rejected.items())))
    signing = tally.signing
    if config.mavlink.signing_key_file:
        if signing is None or signing.good == 0:
            return Check(
                "link",
                Status.FAIL,
                "signing is on (mavlink.signing_key_file) but no correctly signed message was heard: "
                "same key on the autopilot?",
            )
        if signing.unsigned + signing.bad_signature:
            problems.append(
                f"{signing.unsigned} unsigned and {signing.bad_signature} wrongly signed messages ignored"
            )
    if problems:
        return Check("link", Status.WARN, "; ".join(problems))
    received = 0 if counters is None else counters.received
    if received == 0:
        return Check("link", Status.PASS, "no messages received, none corrupt")
    signed = ", all signed" if config.mavlink.signing_key_file else ""
    return Check("link", Status.PASS, f"{received} messages, none corrupt or ignored{signed}")


def _zenoh(tally: Tally, config: Config) -> Check:
    z, reached = config.zenoh, tally.zenoh
    if reached is None:
        return Check("zenoh", Status.WARN, "not checked")
    if isinstance(reached, str):
        return Check("zenoh", Status.FAIL, f"{reached} (is the service running? it holds zenoh.listen)")
    routers, peers = reached
    text = f"session open ({z.mode}), connected to {routers} router(s) and {peers} peer(s)"
    if z.connect and routers + peers == 0:
        return Check("zenoh", Status.WARN, f"{text}: none of zenoh.connect {z.connect} answered")
    return Check("zenoh", Status.PASS, text)


def _commanding(tally: Tally, config: Config) -> Check:
    """What the command gate would say now (information: the pilot hands over later)."""
    gate = CommandGate(config.mavlink.guided_mode, config.mavlink.link_timeout_s)
    if tally.heartbeat is None:
        return Check("commanding", Status.PASS, "would not command: no autopilot heard")
    gate.heard(tally.heartbeat)
    state = gate.state(tally.heartbeat.time_s)
    verb = "would command now" if state.allowed else "would not command yet"
    return Check("commanding", Status.PASS, f"{verb}: {state.reason}")


def recorder_writable(directory: str) -> tuple[bool, str]:
    """Whether a run file can be written in ``directory`` (made if missing, as the recorder does)."""
    path = Path(directory)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".oslim-preflight-"):
            pass
    except OSError as exc:
        return False, f"recorder.dir {directory}: cannot write there ({exc.strerror or exc})"
    disk = os.statvfs(path)
    free_mb = disk.f_bavail * disk.f_frsize / 1e6
    return True, f"recorder.dir {path.resolve()} writable, {free_mb:,.0f} MB free"


async def listen(config: Config, window_s: float) -> Tally:
    """Hear the vehicle for ``window_s`` seconds as ``oslim serve`` would, commanding nothing."""
    mav = config.mavlink
    key = load_signing_key(mav.signing_key_file) if mav.signing_key_file else None
    settings = TelemetrySettings.from_config(config)
    tally = Tally(window_s)
    loop = asyncio.get_running_loop()
    async with MavlinkLink.from_config(mav, clock=loop.time, signing_key=key) as link:

        async def read() -> None:
            async for stamp, msg in link:
                item = decode(msg, stamp, settings)
                if item is not None:
                    tally.add(msg.get_type(), item, config.sensor.threshold)

        async def beat() -> None:
            asked = False
            while True:
                link.send_heartbeat()
                hb = tally.heartbeat
                if hb is not None and not asked:
                    link.adopt_system(hb.system)
                    request_streams(link, hb.system, settings, mav.stream_hz)
                    asked = True
                await asyncio.sleep(1.0)

        tasks = [asyncio.create_task(read()), asyncio.create_task(beat())]
        try:
            async with contextlib.AsyncExitStack() as stack:
                zenoh: ZenohLink | None = None
                try:
                    zenoh = await stack.enter_async_context(
                        ZenohLink.from_config(config, Grid.from_config(config.area))
                    )
                except LinkError as exc:
                    tally.zenoh = str(exc)
                await asyncio.sleep(window_s)
                if zenoh is not None:
                    tally.zenoh = zenoh.connected()
        finally:
            for task in tasks:
                task.cancel()
            for task in tasks:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        tally.link = link.counters
        tally.signing = link.signing
    return tally


def preflight(config: Config, window_s: float) -> list[Check]:
    """Listen, then judge every check."""
    tally = asyncio.run(listen(config, window_s))
    return assess(tally, config, recorder_writable(config.recorder.dir))


def render(checks: list[Check], config: Config, window_s: float) -> str:
    failed = sum(c.status is Status.FAIL for c in checks)
    warned = sum(c.status is Status.WARN for c in checks)
    lines = [f"oslim preflight: listened {window_s:g} s on {config.mavlink.url} (commanded nothing)"]
    lines += [f"  {c.status.value:4}  {c.name:<12} {c.detail}" for c in checks]
    verdict = "NOT READY" if failed else "ready"
    lines.append(f"verdict: {verdict} ({failed} failed, {warned} to look at)")
    return "\n".join(lines)


def as_json(checks: list[Check]) -> str:
    payload: dict[str, Any] = {
        "ready": not any(c.status is Status.FAIL for c in checks),
        "checks": [{"name": c.name, "status": c.status.value, "detail": c.detail} for c in checks],
    }
    return json.dumps(payload)
