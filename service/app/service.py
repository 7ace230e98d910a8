"""``oslim serve``: the asyncio wiring of the onboard service.

Tasks, all on one event loop:
- *read*: MAVLink messages (from the link's reader thread) -> typed telemetry -> the command gate
  and the tick aggregator; rejected values are counted and logged once per reason;
- *heartbeat*: HEARTBEAT as the onboard computer at 1 Hz; stream requests when the autopilot
  is first heard and whenever the link comes back; an ArduPilot rover or boat is asked for its
  acceptance radius (``WP_RADIUS``) until it answers, for the log (setpoints lead a vehicle only
  once it is seen to stop short of its targets: ``planning.lead``);
- *tick*: at every tick (absolute deadlines, no drift) the aggregated observation goes through
  the mission step (mapper, state machine, planner); maps, estimate, path and observation are
  published over Zenoh and recorded to MCAP; events become STATUSTEXT and log lines;
- *setpoints*: the current target, re-sent at ``mavlink.setpoint_rate_hz`` only while the gate
  allows it (armed, GUIDED, link alive) and only if it is a safe point.

The numerical work goes through ``service.api.Search`` (mapper, mission, tick aggregation), the
same as the benchmarks, replay and users' own programs. The tasks run in one
``asyncio.TaskGroup``: one that fails stops the others, and its error is the run's.

The service receives its edges (``service.app.edges``: protocols for the MAVLink link, the map
publisher and the recorder), so it runs as well against in-memory fakes. Start-up order (so that
a failure leaves nothing half-started): configuration, signing key and restart snapshot are read
first, then ``open_edges`` opens the MAVLink link, Zenoh, and the MCAP recorder last.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import signal
import time
from collections import deque
from collections.abc import Coroutine
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from service.api import Search, Step
from service.app.edges import EdgeOpener, Edges, VehicleLink, open_edges
from service.app.gate import CommandGate, GateState
from service.core.config import Config
from service.core.mapping.mapper import SourceMapper
from service.core.mission import MissionEvent, PlumeFound, PlumeLost, SourceDeclared
from service.core.planning.base import Waypoint
from service.core.planning.safety import is_safe_point
from service.core.samples import DetectionSample
from service.edges.foxglove_scene import SceneBuilder
from service.edges.signing import load_signing_key
from service.edges.snapshot import Snapshot, SnapshotWriter, fingerprint, map_digest, read_snapshot
from service.edges.telemetry import Heartbeat, ParamValue, Rejected, TelemetrySettings, decode

log = logging.getLogger("oslim")

SILENT_TICKS = 5
"""Ticks without a position, flow or chemical reading before the service warns about it."""

STREAMS = {"LOCAL_POSITION_NED": 32, "WIND": 168, "WIND_COV": 231}
"""Messages the service asks the autopilot for (MAVLink message ids)."""

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
ROVER_TYPES = frozenset({10, 11})
"""MAV_TYPE of an ArduPilot Rover (ground rover, surface boat), whose parameters are asked for."""
ROVER_PARAMS = ("WP_RADIUS", "WP_SPEED", "CRUISE_SPEED")
"""Asked of a Rover as the link comes up: its acceptance radius (logged), and the guided speed it
drives at (``WP_SPEED``, or ``CRUISE_SPEED`` while that is 0), which ``vehicle.max_speed_mps`` caps."""
PARAM_ASKS = 5
"""How many times (one a second) the parameters not yet answered are asked for."""
SPEED_EVERY_S = 5.0
"""While commanding, the speed cap is sent again this often: Rover applies it only to a guided
target it is driving to, and forgets it when GUIDED is entered again."""


def request_streams(link: VehicleLink, system: int, settings: TelemetrySettings, rate_hz: float) -> list[str]:
    """Ask autopilot ``system`` for ``STREAMS`` (and GLOBAL_POSITION_INT when an origin is set) at
    ``rate_hz``; the names asked for."""
    streams = dict(STREAMS)
    if settings.origin is not None:
        streams["GLOBAL_POSITION_INT"] = 33
    for message_id in streams.values():
        link.request_interval(system, message_id, rate_hz)
    return list(streams)


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
        self.search = Search(config)
        self.grid = self.search.grid
        self.gate = CommandGate(config.mavlink.guided_mode, config.mavlink.link_timeout_s)
        self.settings = TelemetrySettings.from_config(config)
        self.stats = ServiceStats()
        self.scene = SceneBuilder(
            min(self.grid.cell_width_m, self.grid.cell_height_m), config.declaration.radius_m
        )
        """The Foxglove-drawable messages of each tick (recorded, and live with ``foxglove.listen``)."""
        self._halted = False
        """Commanding has stopped for good (the run is ending)."""
        self._refused = False
        """The plan's setpoint was refused as unsafe: nothing is commanded until the next plan."""
        self.declared: SourceDeclared | None = None
        self.edges: Edges | None = None
        """The open edges while the service runs (for probes and tests; the tasks get them passed)."""
        self.started = asyncio.Event()
        """Set once the MAVLink, Zenoh and MCAP edges are all open."""
        self.tick_wall: deque[tuple[float, float]] = deque(maxlen=4096)
        """(tick time_s rounded to ms, wall-clock time.time() when the tick started): for latency probes."""
        self._silent: dict[str, int] = {}
        self._gate_state = GateState(False, "starting")
        self._link_was_alive = False
        self._radius_told = 0.0
        self._param_asks = 0
        self._lag_warned = False
        self._params: dict[str, float] = {}
        """``ROVER_PARAMS`` as the autopilot answered them."""
        self._speed_cap: float | None = None
        """The guided speed asked of a Rover that drives faster than ``vehicle.max_speed_mps``."""
        self._speed_sent: float | None = None
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

    @property
    def mapper(self) -> SourceMapper:
        """The search's mapper (its maps are what the service publishes)."""
        return self.search.mapper

    def _restore(self, snapshot: Snapshot) -> None:
        try:
            self.search.mapper.restore_state(snapshot.mapper)
            self.search.mission.restore_state(snapshot.mission)
        except (KeyError, TypeError, ValueError) as exc:
            # a half-restored mapper is worse than a flat one: start again from scratch
            log.warning("snapshot: not restored (%s), starting with a flat map", exc)
            self.search = Search(self.config)
            return
        self.clock.resume_at(snapshot.time_s)
        self.stats.restored_ticks = snapshot.ticks
        self.stats.state = str(self.search.state)
        log.info(
            "snapshot: restored %d ticks, mission %s, estimate cell %d, map %s", snapshot.ticks,
            self.search.state, self.search.estimate().cell, map_digest(self.search.mapper.likelihood),
        )  # fmt: skip

    async def run(self, stop: asyncio.Event, *, opener: EdgeOpener = open_edges) -> ServiceStats:
        """Open the edges (``opener``, by default the real ones), run until ``stop`` is set; then
        stop commanding, flush and close everything."""
        async with opener(self.config, self.grid, self.clock.now, self._signing_key) as edges:
            return await self.run_with(edges, stop)

    async def run_with(self, edges: Edges, stop: asyncio.Event) -> ServiceStats:
        """Run the service's tasks over open ``edges`` until ``stop`` is set or a task ends; a
        task's error is raised (the first one, when several fail together)."""
        cfg = self.config
        self.edges = edges
        self.stats.mcap = None if edges.recorder.path is None else str(edges.recorder.path)
        log.info(
            "serving vehicle %s: mapper %s, planner %s, grid %d x %d", cfg.vehicle.id,
            cfg.mapping.method, cfg.planning.method, self.grid.columns, self.grid.rows,
        )  # fmt: skip
        self.started.set()
        ended = asyncio.Event()  # stop was set, or a task returned (a link that closed)
        try:
            async with asyncio.TaskGroup() as tasks:
                for name, job in (
                    ("read", self._read(edges)),
                    ("heartbeat", self._heartbeat(edges.link)),
                    ("tick", self._ticks(edges)),
                    ("setpoints", self._setpoints(edges)),
                    ("stop", stop.wait()),
                ):
                    tasks.create_task(_ends_run(job, ended), name=name)
                await ended.wait()
                self._halted = True  # stop commanding before anything else
                raise _Stop
        except* _Stop:
            pass
        except* BaseException as group:
            self._halted = True
            raise _first(group) from None
        finally:
            self._note_link(edges.link)
            log.info("stopped: %s", self.stats.summary())
        return self.stats

    @property
    def target(self) -> Waypoint | None:
        """The first waypoint of the search's plan, which the service commands while the gate
        allows; None with no plan, once the run is ending, or after the plan's setpoint was
        refused as unsafe (until the mission plans again)."""
        plan = self.search.plan
        if self._halted or self._refused or not plan:
            return None
        return plan[0]

    # -- tasks --------------------------------------------------------------------------------

    async def _read(self, edges: Edges) -> None:
        link = edges.link
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
            elif isinstance(item, ParamValue):
                self._on_param(edges, item)
            else:
                if isinstance(item, DetectionSample):
                    self._warn_unlagged()
                self.search.add(item)

    def _warn_unlagged(self) -> None:
        """Say once that a sensor's own detection cannot have its response time undone (only its
        reading can, in the tick aggregator)."""
        response_s = self.config.sensor.response_s
        if response_s <= 0 or self._lag_warned:
            return
        self._lag_warned = True
        log.warning("%s is a detection, not a reading: sensor.response_s (%.2f s) cannot be undone for it; "
                    "send the reading as %s", self.settings.detection_name, response_s,
                    self.settings.chem_name)  # fmt: skip

    async def _heartbeat(self, link: VehicleLink) -> None:
        while True:
            link.send_heartbeat()
            now = self.clock.now()
            alive = self.gate.link_alive(now)
            if alive and not self._link_was_alive and self.gate.system is not None:
                rate_hz = self.config.mavlink.stream_hz
                streams = request_streams(link, self.gate.system, self.settings, rate_hz)
                log.info("autopilot %d heard: requested %s at %.1f Hz", self.gate.system, ", ".join(streams),
                         rate_hz)  # fmt: skip
            if alive:
                self._ask_params(link)
            self._link_was_alive = alive
            await self.clock.sleep_until(now + 1.0)

    async def _ticks(self, edges: Edges) -> None:
        tick_s = self.config.mapping.tick_s
        deadline = self.clock.now() + tick_s
        while True:
            await self.clock.sleep_until(deadline)
            started = time.perf_counter()
            self.tick_wall.append((round(deadline, 3), time.time()))
            self.stats.jitter_ms.append(max(0.0, (self.clock.now() - deadline) / self.clock.speed * 1e3))
            self._tick(edges, deadline, started)
            self._note_link(edges.link)
            self.stats.tick_ms.append((time.perf_counter() - started) * 1e3)
            deadline += tick_s
            if self.clock.now() > deadline:  # fell behind: skip missed deadlines, do not burst
                deadline = self.clock.now() + tick_s

    async def _setpoints(self, edges: Edges) -> None:
        period = 1.0 / self.config.mavlink.setpoint_rate_hz
        while True:
            now = self.clock.now()
            self._update_gate(edges, now)
            self._command(edges, now)
            await self.clock.sleep_until(now + period)

    # -- one tick -------------------------------------------------------------------------------

    def _tick(self, edges: Edges, time_s: float, started: float) -> None:
        step = self.search.tick(time_s)
        gaps = self.search.gaps
        self.stats.ticks += 1
        for gap in gaps:
            self.stats.gaps[gap] = self.stats.gaps.get(gap, 0) + 1
        self._report_silent_streams(gaps)
        if step is None:
            log.debug("tick %.1f: no observation (missing %s)", time_s, ", ".join(gaps))
            edges.recorder.write_event(time_s, "gap", "missing " + ", ".join(gaps), missing=list(gaps))
            return
        self.stats.observations += 1
        self.stats.state = str(step.state)
        if step.waypoints is not None:
            self._refused = False
        self._publish(edges, step)
        for event in step.events:
            self._announce(edges, event)
        if self._snapshots is not None:
            self._snapshots.write(
                Snapshot(
                    fingerprint=self._fingerprint,
                    time_s=time_s,
                    ticks=(self.stats.restored_ticks or 0) + self.stats.observations,
                    wall_time=time.time(),
                    mapper=self.search.mapper.save_state(),
                    mission=self.search.mission.save_state(),
                )
            )
        now = self.clock.now()
        self._update_gate(edges, now)
        if self._command(edges, now):
            self.stats.latency_ms.append((time.perf_counter() - started) * 1e3)

    def _report_silent_streams(self, gaps: tuple[str, ...]) -> None:
        """One warning when a stream has been silent for SILENT_TICKS ticks, one line when it is back."""
        for stream in ("position", "flow", "chemical"):
            if stream in gaps:
                self._silent[stream] = self._silent.get(stream, 0) + 1
                if self._silent[stream] == SILENT_TICKS:
                    log.warning("no %s readings for %d ticks: the map is not updated", stream, SILENT_TICKS)
            elif self._silent.pop(stream, 0) >= SILENT_TICKS:
                log.info("%s readings are back", stream)

    def _publish(self, edges: Edges, step: Step) -> None:
        obs = step.observation
        slim, plume = self.search.likelihood, self.search.plume
        state = str(step.state)
        path = list(step.waypoints) if step.waypoints is not None else None
        try:
            edges.maps.publish_obs(obs)
            edges.maps.publish_maps(obs.time_s, slim, plume)
            edges.maps.publish_estimate(obs.time_s, state, step.estimate)
            if path is not None:
                edges.maps.publish_path(obs.time_s, path)
        except Exception as exc:  # publishing must never stop the mission
            log.error("zenoh publish failed: %s", exc)
        edges.recorder.tick(obs, slim, plume, estimate=step.estimate, state=state, path=path)
        scene = self.scene.tick(
            obs, self.search.heading_rad, estimate=step.estimate, state=state, path=path, events=step.events
        )
        edges.recorder.write_messages(scene)

    def _note_link(self, link: VehicleLink) -> None:
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

    def _announce(self, edges: Edges, event: MissionEvent) -> None:
        if isinstance(event, PlumeFound):
            name, text = "plume_found", f"OSLIM plume found at {event.x:.1f},{event.y:.1f}"
        elif isinstance(event, PlumeLost):
            name, text = "plume_lost", f"OSLIM plume lost at {event.x:.1f},{event.y:.1f}"
        else:
            self.declared = event
            name, text = "source_declared", f"OSLIM source at {event.x:.1f},{event.y:.1f} ({event.mass:.0%})"
        # the log and the recording also say how the cell was checked; STATUSTEXT carries 50 characters
        detail = text if not isinstance(event, SourceDeclared) else f"{text}, check {event.check}"
        log.info("%s (t=%.1f s)", detail, event.time_s)
        self.stats.events.append({"time_s": event.time_s, "name": name, "x": event.x, "y": event.y})
        edges.link.send_statustext(text)
        edges.recorder.write_event(event.time_s, name, detail, x=event.x, y=event.y)

    # -- commanding -----------------------------------------------------------------------------

    def _update_gate(self, edges: Edges, now: float) -> None:
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
            if state.allowed and was.reason.startswith("link lost"):
                edges.link.send_statustext("OSLIM link restored, commanding again")

    def _command(self, edges: Edges, now: float) -> bool:
        """Send the current target if allowed and safe; True when a setpoint went out."""
        system = self.gate.system
        if not self._gate_state.allowed:
            self._speed_sent = None  # GUIDED entered again forgets the speed: ask at once
            return False
        if self.target is None or system is None:
            return False
        # the plan's first waypoint, or a point ahead of an autopilot that stops short of it
        point = self.search.setpoint(now)
        if point is None:
            return False
        target = Waypoint(*point)
        # the mission plans on the model grid and its safety rule used that grid's obstacle cells:
        # an area cell that an obstacle covers only in part is partly free there (every obstacle
        # rectangle is refused on either grid)
        if not is_safe_point(self.search.model_grid, target.x, target.y):
            self.stats.unsafe_targets += 1
            log.error("refused unsafe target (%.2f, %.2f)", target.x, target.y)
            self._refused = True
            return False
        cfg = self.config.mavlink
        edges.link.send_setpoint(
            system, int(now * 1000), target.x, target.y, cfg.altitude_m, cfg.setpoint_type_mask
        )
        self.stats.setpoints += 1
        edges.recorder.write_setpoint(now, target.x, target.y, cfg.altitude_m)
        self._tell_radius(edges, now)
        due = self._speed_sent is None or now - self._speed_sent >= SPEED_EVERY_S
        if self._speed_cap is not None and due:
            edges.link.send_speed(system, self._speed_cap)
            self._speed_sent = now
        return True

    def _ask_params(self, link: VehicleLink) -> None:
        """Ask an ArduPilot Rover for ``ROVER_PARAMS`` not yet answered, once a second
        (``PARAM_ASKS`` rounds at most: a lost request is asked again)."""
        hb = self.gate.last
        if hb is None or hb.autopilot != MAV_AUTOPILOT_ARDUPILOTMEGA or hb.vehicle_type not in ROVER_TYPES:
            return
        wanted = [name for name in ROVER_PARAMS if name not in self._params]
        if not wanted or self._param_asks >= PARAM_ASKS:
            return
        self._param_asks += 1
        for name in wanted:
            link.request_param(hb.system, name)

    def _on_param(self, edges: Edges, param: ParamValue) -> None:
        """A parameter the autopilot answered. ``WP_RADIUS`` is said in the log and the recording,
        not taken for how far short the vehicle stops: Rover 4.3 and later drive a guided target to
        the point and stop within it only as the approach ends, and setpoints led by it from the
        start send such a vehicle past every point (docs/search-steps.md, step 48). The speeds set
        the cap (``_cap_speed``)."""
        if param.name not in ROVER_PARAMS or param.name in self._params or param.system != self.gate.system:
            return
        if not 0.0 <= param.value <= 100.0:
            log.warning("ignored the autopilot's %s = %g (not a distance or speed)", param.name, param.value)
            return
        self._params[param.name] = param.value
        if param.name == "WP_RADIUS":
            text = (
                f"autopilot's {param.name} is {param.value:.2f} m; setpoints lead the vehicle only if it is"
                " seen to stop short of its targets"
            )
            log.info("%s", text)
            edges.recorder.write_event(param.time_s, "autopilot_radius", text, radius_m=param.value)
        else:
            self._cap_speed(edges, param.time_s)

    def _cap_speed(self, edges: Edges, now: float) -> None:
        """Once the Rover's guided speed is known (``WP_SPEED``, or ``CRUISE_SPEED`` while it is 0):
        if it is faster than ``vehicle.max_speed_mps``, ask for that speed while commanding. The
        map is updated once a second on cells of a metre or so, and the search was measured at
        0.5-2 m/s; at 5 m/s (SITL's CRUISE_SPEED) it reaches sources and fails to name them (step
        48). A slower vehicle is never sped up."""
        wp_speed = self._params.get("WP_SPEED")
        speed = wp_speed if wp_speed else self._params.get("CRUISE_SPEED")
        if self._speed_cap is not None or wp_speed is None or speed is None:
            return
        cap = self.search.speed_mps(speed)
        if cap >= speed:
            return
        self._speed_cap = cap
        text = f"autopilot drives at {speed:.1f} m/s in GUIDED: asked for {cap:.1f} m/s"
        text += " (vehicle.max_speed_mps)"
        log.warning("%s", text)
        edges.recorder.write_event(now, "speed_cap", text, speed_mps=speed, cap_mps=cap)

    def _tell_radius(self, edges: Edges, now: float) -> None:
        """Say once (and again if it grows) that the autopilot stops short of its targets."""
        radius = self.search.arrival_radius_m
        if radius <= self._radius_told + 0.1:
            return
        self._radius_told = radius
        text = f"autopilot stops {radius:.1f} m short of its targets (seen stopping short): "
        text += "setpoints now lead it"
        log.warning("%s", text)
        edges.recorder.write_event(now, "arrival_radius", text, radius_m=radius)


class _Stop(Exception):  # noqa: N818 - a signal inside run_with, never seen outside
    """Raised inside the task group when ``stop`` is set: it cancels the tasks."""


async def _ends_run(job: Coroutine[Any, Any, Any], ended: asyncio.Event) -> None:
    """Run ``job``; when it returns, the run ends."""
    await job
    ended.set()


def _first(group: BaseExceptionGroup[BaseException]) -> BaseException:
    """The first error of a task group's failure (others are logged): callers see a task's own
    exception (``LinkError``...), as they did before the tasks ran in a group."""
    errors = [e for e in _leaves(group) if not isinstance(e, _Stop)]
    for extra in errors[1:]:
        log.error("also failed: %r", extra)
    return errors[0] if errors else group


def _leaves(error: BaseException) -> list[BaseException]:
    if isinstance(error, BaseExceptionGroup):
        return [leaf for e in error.exceptions for leaf in _leaves(e)]
    return [error]


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
