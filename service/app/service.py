"""``oslim serve``: the asyncio wiring of the onboard service.

Tasks, all on one event loop:
- *read*: MAVLink messages (from the link's reader thread) -> typed telemetry -> the command gate
  and the tick aggregator; rejected values are counted and logged once per reason;
- *heartbeat*: HEARTBEAT as the onboard computer at 1 Hz; stream requests when the autopilot
  is first heard and whenever the link comes back;
- *tick*: at every tick (absolute deadlines, no drift) the aggregated observation goes through
  the mission step (mapper, state machine, planner); maps, estimate, path and observation are
  published over Zenoh and recorded to MCAP; events become STATUSTEXT and log lines;
- *setpoints*: the current target, re-sent at ``mavlink.setpoint_rate_hz`` only while the gate
  allows it (armed, GUIDED, link alive) and only if it is a safe point.

The numerical work (mapper, mission) is the same pure code the benchmarks and replay run.

Start-up order (so that a failure leaves nothing half-started): configuration, signing key and
restart snapshot are read first, then the MAVLink link, then Zenoh, and the MCAP recorder last,
so no run file is created for a service that did not start. Each edge is an (async) context
manager and closes what it opened if a later one fails.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import signal
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service.app.gate import CommandGate, GateState
from service.core.config import Config
from service.core.grid import Grid
from service.core.mapping import mapper_from_config
from service.core.mission import Mission, MissionOutput, PlumeFound, PlumeLost, SourceDeclared
from service.core.planning.base import VehicleState, Waypoint
from service.core.planning.safety import is_safe_point
from service.core.samples import Position
from service.core.tick import Tick, TickAggregator
from service.edges.mavlink_link import MavlinkLink
from service.edges.recorder import Recorder
from service.edges.signing import load_signing_key
from service.edges.snapshot import Snapshot, SnapshotWriter, fingerprint, map_digest, read_snapshot
from service.edges.telemetry import Heartbeat, Rejected, TelemetrySettings, decode
from service.edges.zenoh_link import ZenohLink

log = logging.getLogger("oslim")

SILENT_TICKS = 5
"""Ticks without a position, flow or chemical reading before the service warns about it."""

STREAMS = {"LOCAL_POSITION_NED": 32, "WIND": 168, "WIND_COV": 231}
"""Messages the service asks the autopilot for (MAVLink message ids)."""


class Clock:
    """Service time in seconds: monotonic, scaled by ``speed`` (> 1 runs faster than real time)."""

    def __init__(self, speed: float = 1.0) -> None:
        if not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"speed must be a positive number, got {speed}")
        self.speed = speed
        self._origin = time.monotonic()
        self._offset_s = 0.0

    def now(self) -> float:
        return (time.monotonic() - self._origin) * self.speed + self._offset_s

    def resume_at(self, time_s: float) -> None:
        """Make ``now()`` continue from ``time_s`` (a restored snapshot's time)."""
        self._offset_s += time_s - self.now()

    async def sleep_until(self, t: float) -> None:
        delay = (t - self.now()) / self.speed
        if delay > 0:
            await asyncio.sleep(delay)


@dataclass
class ServiceStats:
    """What the service did, for the end-of-run summary and the sim's performance figures."""

    ticks: int = 0
    observations: int = 0
    gaps: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    setpoints: int = 0
    unsafe_targets: int = 0
    latency_ms: list[float] = field(default_factory=list)
    """Tick start to the tick's setpoint on the wire (only ticks that commanded)."""
    tick_ms: list[float] = field(default_factory=list)
    """Processing time of each tick (observation to published, recorded and commanded)."""
    jitter_ms: list[float] = field(default_factory=list)
    """How late each tick started against its deadline (wall clock)."""
    events: list[dict[str, Any]] = field(default_factory=list)
    state: str = "search"
    mcap: str | None = None
    link: dict[str, int] = field(default_factory=dict)
    """MAVLink input that never became telemetry: unparsable frames, rejected signatures, drops."""
    restored_ticks: int | None = None
    """Mapper ticks restored from the snapshot at start-up (None: started with a flat map)."""

    def summary(self) -> dict[str, Any]:
        def pct(values: list[float], q: float) -> float | None:
            return round(float(np.percentile(values, q)), 3) if values else None

        return {
            "ticks": self.ticks,
            "observations": self.observations,
            "gaps": dict(self.gaps),
            "rejected": dict(self.rejected),
            "link": dict(self.link),
            "restored_ticks": self.restored_ticks,
            "setpoints": self.setpoints,
            "unsafe_targets": self.unsafe_targets,
            "latency_ms_median": pct(self.latency_ms, 50),
            "latency_ms_p99": pct(self.latency_ms, 99),
            "tick_ms_median": pct(self.tick_ms, 50),
            "tick_ms_p99": pct(self.tick_ms, 99),
            "jitter_ms_median": pct(self.jitter_ms, 50),
            "jitter_ms_p99": pct(self.jitter_ms, 99),
        }


class Service:
    """One run of the onboard service with one configuration."""

    def __init__(self, config: Config, *, clock: Clock | None = None) -> None:
        self.config = config
        self.clock = clock or Clock()
        self.grid = Grid.from_config(config.area)
        self.mapper = mapper_from_config(config, self.grid)
        self.mission = Mission.from_config(config, self.grid, self.mapper)
        self.gate = CommandGate(config.mavlink.guided_mode, config.mavlink.link_timeout_s)
        self.aggregator = TickAggregator(
            config.sensor.threshold, max_position_age_s=2.0 * config.mapping.tick_s
        )
        self.settings = TelemetrySettings(
            chem_name=config.sensor.name,
            detection_name=config.sensor.detection_name,
            max_flow_mps=config.sensor.max_flow_mps,
            origin=(config.mavlink.origin[0], config.mavlink.origin[1]) if config.mavlink.origin else None,
        )
        self.stats = ServiceStats()
        self.target: Waypoint | None = None
        self.declared: SourceDeclared | None = None
        self.started = asyncio.Event()
        """Set once the MAVLink, Zenoh and MCAP edges are all open."""
        self.tick_wall: deque[tuple[float, float]] = deque(maxlen=4096)
        """(tick time_s rounded to ms, wall-clock time.time() when the tick started): for latency probes."""
        self._position: Position | None = None
        self._silent: dict[str, int] = {}
        self._heading_rad = 0.0
        self._gate_state = GateState(False, "starting")
        self._link_was_alive = False
        self._link: MavlinkLink | None = None
        self._zenoh: ZenohLink | None = None
        self._recorder: Recorder | None = None
        self._signing_key = (
            load_signing_key(config.mavlink.signing_key_file) if config.mavlink.signing_key_file else None
        )
        self._snapshots: SnapshotWriter | None = None
        self._fingerprint = fingerprint(config)
        self._link_problems_logged = 0
        if config.service.snapshot_path:
            self._snapshots = SnapshotWriter(config.service.snapshot_path)
            self._snapshots.check()
            snapshot = read_snapshot(config.service.snapshot_path, config)
            if snapshot is not None:
                self._restore(snapshot)

    def _restore(self, snapshot: Snapshot) -> None:
        try:
            self.mapper.restore_state(snapshot.mapper)
            self.mission.restore_state(snapshot.mission)
        except (KeyError, TypeError, ValueError) as exc:
            # a half-restored mapper is worse than a flat one: start again from scratch
            log.warning("snapshot: not restored (%s), starting with a flat map", exc)
            self.mapper = mapper_from_config(self.config, self.grid)
            self.mission = Mission.from_config(self.config, self.grid, self.mapper)
            return
        self.clock.resume_at(snapshot.time_s)
        self.stats.restored_ticks = snapshot.ticks
        self.stats.state = str(self.mission.state)
        log.info(
            "snapshot: restored %d ticks, mission %s, estimate cell %d, map %s", snapshot.ticks,
            self.mission.state, self.mapper.estimate().cell, map_digest(self.mapper.likelihood),
        )  # fmt: skip

    async def run(self, stop: asyncio.Event) -> ServiceStats:
        """Run until ``stop`` is set; then stop commanding, flush and close everything."""
        cfg = self.config
        link_edge = MavlinkLink(
            cfg.mavlink.url,
            clock=self.clock.now,
            queue_size=cfg.mavlink.queue_size,
            signing_key=self._signing_key,
            signing_link_id=cfg.mavlink.signing_link_id,
        )
        async with (
            link_edge as link,
            ZenohLink.from_config(cfg, self.grid) as zenoh_link,
        ):
            with Recorder(cfg) as recorder:  # last: no run file for a service that did not start
                self._recorder = recorder
                self.stats.mcap = str(recorder.path)
                self._zenoh, self._link = zenoh_link, link
                log.info(
                    "serving vehicle %s: mapper %s, planner %s, grid %d x %d", cfg.vehicle.id,
                    cfg.mapping.method, cfg.planning.method, self.grid.columns, self.grid.rows,
                )  # fmt: skip
                self.started.set()
                tasks = [
                    asyncio.create_task(self._read(link), name="read"),
                    asyncio.create_task(self._heartbeat(link), name="heartbeat"),
                    asyncio.create_task(self._ticks(), name="tick"),
                    asyncio.create_task(self._setpoints(link), name="setpoints"),
                ]
                waiter = asyncio.create_task(stop.wait(), name="stop")
                done, _ = await asyncio.wait([waiter, *tasks], return_when=asyncio.FIRST_COMPLETED)
                self.target = None  # stop commanding before anything else
                for task in [waiter, *tasks]:
                    task.cancel()
                await asyncio.gather(waiter, *tasks, return_exceptions=True)
                for task in done:
                    if task is not waiter and not task.cancelled() and task.exception() is not None:
                        raise task.exception()  # type: ignore[misc]
                self._note_link(link)
            log.info("stopped: %s", self.stats.summary())
        return self.stats

    # -- tasks --------------------------------------------------------------------------------

    async def _read(self, link: MavlinkLink) -> None:
        async for stamp, msg in link:
            item = decode(msg, stamp, self.settings)
            if item is None:
                continue
            if isinstance(item, Rejected):
                key = f"{item.message}: {item.reason}"
                if key not in self.stats.rejected:
                    log.warning("ignored %s (counted from now on)", key)
                self.stats.rejected[key] = self.stats.rejected.get(key, 0) + 1
            elif isinstance(item, Heartbeat):
                self.gate.heard(item)
                if self.gate.system == item.system:
                    link.adopt_system(item.system)
            else:
                if isinstance(item, Position):
                    self._track_heading(item)
                self.aggregator.add(item)

    async def _heartbeat(self, link: MavlinkLink) -> None:
        while True:
            link.send_heartbeat()
            now = self.clock.now()
            alive = self.gate.link_alive(now)
            if alive and not self._link_was_alive and self.gate.system is not None:
                streams = dict(STREAMS)
                if self.settings.origin is not None:
                    streams["GLOBAL_POSITION_INT"] = 33
                for msg_id in streams.values():
                    link.request_interval(self.gate.system, msg_id, self.config.mavlink.stream_hz)
                log.info("autopilot %d heard: requested %s at %.1f Hz", self.gate.system, ", ".join(streams),
                         self.config.mavlink.stream_hz)  # fmt: skip
            self._link_was_alive = alive
            await self.clock.sleep_until(now + 1.0)

    async def _ticks(self) -> None:
        tick_s = self.config.mapping.tick_s
        deadline = self.clock.now() + tick_s
        while True:
            await self.clock.sleep_until(deadline)
            started = time.perf_counter()
            self.tick_wall.append((round(deadline, 3), time.time()))
            self.stats.jitter_ms.append(max(0.0, (self.clock.now() - deadline) / self.clock.speed * 1e3))
            self._tick(self.aggregator.close(deadline), started)
            if self._link is not None:
                self._note_link(self._link)
            self.stats.tick_ms.append((time.perf_counter() - started) * 1e3)
            deadline += tick_s
            if self.clock.now() > deadline:  # fell behind: skip missed deadlines, do not burst
                deadline = self.clock.now() + tick_s

    async def _setpoints(self, link: MavlinkLink) -> None:
        period = 1.0 / self.config.mavlink.setpoint_rate_hz
        while True:
            now = self.clock.now()
            self._update_gate(now)
            self._command(now)
            await self.clock.sleep_until(now + period)

    # -- one tick -------------------------------------------------------------------------------

    def _tick(self, tick: Tick, started: float) -> None:
        self.stats.ticks += 1
        for gap in tick.gaps:
            self.stats.gaps[gap] = self.stats.gaps.get(gap, 0) + 1
        self._report_silent_streams(tick)
        obs = tick.observation
        if obs is None:
            log.debug("tick %.1f: no observation (missing %s)", tick.time_s, ", ".join(tick.gaps))
            if self._recorder is not None:
                self._recorder.write_event(
                    tick.time_s, "gap", "missing " + ", ".join(tick.gaps), missing=list(tick.gaps)
                )
            return
        self.stats.observations += 1
        vehicle = VehicleState(obs.x, obs.y, self._heading_rad)
        out = self.mission.step(obs, vehicle)
        self.stats.state = str(out.state)
        if out.waypoints is not None:
            self.target = out.waypoints[0] if out.waypoints else None
        self._publish(obs, out)
        for event in out.events:
            self._announce(event)
        if self._snapshots is not None:
            self._snapshots.write(
                Snapshot(
                    fingerprint=self._fingerprint,
                    time_s=tick.time_s,
                    ticks=(self.stats.restored_ticks or 0) + self.stats.observations,
                    wall_time=time.time(),
                    mapper=self.mapper.save_state(),
                    mission=self.mission.save_state(),
                )
            )
        now = self.clock.now()
        self._update_gate(now)
        if self._command(now):
            self.stats.latency_ms.append((time.perf_counter() - started) * 1e3)

    def _report_silent_streams(self, tick: Tick) -> None:
        """One warning when a stream has been silent for SILENT_TICKS ticks, one line when it is back."""
        for stream in ("position", "flow", "chemical"):
            if stream in tick.gaps:
                self._silent[stream] = self._silent.get(stream, 0) + 1
                if self._silent[stream] == SILENT_TICKS:
                    log.warning("no %s readings for %d ticks: the map is not updated", stream, SILENT_TICKS)
            elif self._silent.pop(stream, 0) >= SILENT_TICKS:
                log.info("%s readings are back", stream)

    def _publish(self, obs: Any, out: MissionOutput) -> None:
        slim, plume = self.mapper.likelihood, self.mapper.plume
        state = str(out.state)
        path = [(w.x, w.y) for w in out.waypoints] if out.waypoints is not None else None
        if self._zenoh is not None:
            try:
                self._zenoh.publish_obs(obs)
                self._zenoh.publish_maps(obs.time_s, slim, plume)
                self._zenoh.publish_estimate(obs.time_s, state, out.estimate)
                if path is not None:
                    self._zenoh.publish_path(obs.time_s, path)
            except Exception as exc:  # publishing must never stop the mission
                log.error("zenoh publish failed: %s", exc)
        if self._recorder is not None:
            self._recorder.tick(obs, slim, plume, estimate=out.estimate, state=state, path=path)

    def _note_link(self, link: MavlinkLink) -> None:
        """Copy the link's counters of input it threw away; one log line when their total grows
        (at most one per 10 ticks), so a stream of garbage is reported but cannot flood the log."""
        c = link.counters
        counts = {"unparsable": c.bad_data, "read_errors": c.read_errors, "dropped": c.dropped}
        signing = link.signing
        if signing is not None:
            counts["unsigned"] = signing.unsigned
            counts["bad_signature"] = signing.bad_signature
        self.stats.link = counts
        total = c.bad_data + c.read_errors + c.dropped
        if total > self._link_problems_logged and (
            self._link_problems_logged == 0 or self.stats.ticks % 10 == 0
        ):
            log.warning("mavlink: ignored input so far: %s", counts)
            self._link_problems_logged = total

    def _announce(self, event: PlumeFound | PlumeLost | SourceDeclared) -> None:
        if isinstance(event, PlumeFound):
            name, text = "plume_found", f"OSLIM plume found at {event.x:.1f},{event.y:.1f}"
        elif isinstance(event, PlumeLost):
            name, text = "plume_lost", f"OSLIM plume lost at {event.x:.1f},{event.y:.1f}"
        else:
            self.declared = event
            rules = "+".join(str(r) for r in event.rules)
            name, text = "source_declared", f"OSLIM source at {event.x:.1f},{event.y:.1f} ({rules})"
        # the log and the recording also say how the cell was checked; STATUSTEXT carries 50 characters
        detail = text if not isinstance(event, SourceDeclared) else f"{text}, check {event.check}"
        log.info("%s (t=%.1f s)", detail, event.time_s)
        self.stats.events.append({"time_s": event.time_s, "name": name, "x": event.x, "y": event.y})
        if self._link is not None:
            self._link.send_statustext(text)
        if self._recorder is not None:
            self._recorder.write_event(event.time_s, name, detail, x=event.x, y=event.y)

    # -- commanding -----------------------------------------------------------------------------

    def _update_gate(self, now: float) -> None:
        state = self.gate.state(now)
        if state != self._gate_state:
            was = self._gate_state
            self._gate_state = state
            if state.allowed:
                log.info("commanding: %s", state.reason)
            elif was.allowed:
                log.warning("stopped commanding: %s", state.reason)
            else:
                log.info("not commanding: %s", state.reason)
            if state.allowed and was.reason.startswith("link lost") and self._link is not None:
                self._link.send_statustext("OSLIM link restored, commanding again")

    def _command(self, now: float) -> bool:
        """Send the current target if allowed and safe; True when a setpoint went out."""
        target, link, system = self.target, self._link, self.gate.system
        if target is None or link is None or system is None or not self._gate_state.allowed:
            return False
        if not is_safe_point(self.grid, target.x, target.y):
            self.stats.unsafe_targets += 1
            log.error("refused unsafe target (%.2f, %.2f)", target.x, target.y)
            self.target = None
            return False
        cfg = self.config.mavlink
        link.send_setpoint(
            system, int(now * 1000), target.x, target.y, cfg.altitude_m, cfg.setpoint_type_mask
        )
        self.stats.setpoints += 1
        if self._recorder is not None:
            self._recorder.write_setpoint(now, target.x, target.y, cfg.altitude_m)
        return True

    def _track_heading(self, position: Position) -> None:
        last = self._position
        if last is not None:
            dx, dy = position.x - last.x, position.y - last.y
            if math.hypot(dx, dy) > 0.05:
                self._heading_rad = math.atan2(dy, dx)
        self._position = position


async def serve(
    config: Config, stop: asyncio.Event | None = None, *, clock: Clock | None = None
) -> ServiceStats:
    """Run the service until ``stop`` (or SIGINT / SIGTERM when ``stop`` is not given)."""
    service = Service(config, clock=clock)
    if stop is None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError):
                loop.add_signal_handler(sig, stop.set)
    return await service.run(stop)
