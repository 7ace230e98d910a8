"""The service against in-memory fakes of its edges: no sockets, no pymavlink, no Zenoh, no file."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from service.api import Search
from service.app.edges import Edges
from service.app.service import PARAM_ASKS, ROVER_PARAMS, STREAMS, Clock, Service
from service.core.config import Config, build_config
from service.core.errors import LinkError
from service.core.observation import Observation
from service.core.planning.base import Waypoint
from service.core.planning.lead import STALL_S
from service.edges.foxglove_scene import VEHICLE_TOPIC
from service.edges.mavlink_link import LinkCounters
from service.edges.signing import SigningCounters
from service.edges.telemetry import Heartbeat

SPEED = 40.0  # service seconds per wall second: a 1 s tick every 25 ms
ARMED = 128  # MAV_MODE_FLAG_SAFETY_ARMED


class FakeMessage:
    """Duck-types a pymavlink message: ``get_type``, the source ids and the fields."""

    def __init__(self, kind: str, **fields: Any) -> None:
        self._kind = kind
        self.__dict__.update(fields)

    def get_type(self) -> str:
        return self._kind

    def get_srcSystem(self) -> int:  # noqa: N802 - pymavlink's name
        return 1

    def get_srcComponent(self) -> int:  # noqa: N802 - pymavlink's name
        return 1


@dataclass
class FakeLink:
    """MAVLink in from a queue; everything sent is kept as (what, arguments)."""

    counters: LinkCounters = field(default_factory=LinkCounters)
    signing: SigningCounters | None = None
    inbox: asyncio.Queue[tuple[float, Any] | None] = field(default_factory=asyncio.Queue)
    sent: list[tuple[str, tuple[Any, ...]]] = field(default_factory=list)
    fail_with: Exception | None = None

    async def __aiter__(self) -> AsyncIterator[tuple[float, Any]]:
        while (item := await self.inbox.get()) is not None:
            yield item
        if self.fail_with is not None:
            raise self.fail_with

    def adopt_system(self, system: int) -> None:
        self.sent.append(("adopt", (system,)))

    def send_heartbeat(self) -> None:
        self.sent.append(("heartbeat", ()))

    def request_interval(self, target_system: int, message_id: int, rate_hz: float) -> None:
        self.sent.append(("interval", (target_system, message_id, rate_hz)))

    def request_param(self, target_system: int, name: str) -> None:
        self.sent.append(("param", (target_system, name)))

    def send_speed(self, target_system: int, speed_mps: float) -> None:
        self.sent.append(("speed", (target_system, speed_mps)))

    def send_setpoint(
        self, target_system: int, time_ms: int, x_m: float, y_m: float, altitude_m: float, type_mask: int
    ) -> None:
        self.sent.append(("setpoint", (target_system, time_ms, x_m, y_m, altitude_m, type_mask)))

    def send_statustext(self, text: str, severity: int = 6) -> None:
        self.sent.append(("statustext", (text,)))

    def of(self, what: str) -> list[tuple[Any, ...]]:
        return [args for kind, args in self.sent if kind == what]


@dataclass
class FakeMaps:
    """What would go out over Zenoh."""

    slim: list[np.ndarray[Any, Any]] = field(default_factory=list)
    estimates: list[tuple[float, str, Any]] = field(default_factory=list)
    observations: list[Observation] = field(default_factory=list)
    paths: list[Sequence[tuple[float, float]]] = field(default_factory=list)

    def publish_obs(self, obs: Observation) -> None:
        self.observations.append(obs)

    def publish_maps(self, time_s: float, slim: Any, plume: Any) -> None:
        self.slim.append(np.array(slim))

    def publish_estimate(self, time_s: float, state: str, estimate: Any) -> None:
        self.estimates.append((time_s, state, estimate))

    def publish_path(self, time_s: float, waypoints: Sequence[tuple[float, float]]) -> None:
        self.paths.append(waypoints)


@dataclass
class FakeRecorder:
    """What would go into the MCAP file."""

    path: Path | None = None
    ticks: list[Observation] = field(default_factory=list)
    events: list[str] = field(default_factory=list)
    setpoints: list[tuple[float, float, float, float]] = field(default_factory=list)
    scene: list[str] = field(default_factory=list)
    """The topics of the drawable (Foxglove) messages."""

    def tick(self, obs: Observation, slim: Any, plume: Any, **_: Any) -> bool:
        self.ticks.append(obs)
        return True

    def write_setpoint(self, time_s: float, x: float, y: float, z: float) -> bool:
        self.setpoints.append((time_s, x, y, z))
        return True

    def write_event(self, time_s: float, name: str, text: str = "", **detail: Any) -> bool:
        self.events.append(name)
        return True

    def write_messages(self, records: Sequence[tuple[str, bytes]]) -> bool:
        self.scene.extend(topic for topic, _ in records)
        return True


async def until(condition: Callable[[], bool], timeout_s: float = 10.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not condition():
            await asyncio.sleep(0.005)


async def vehicle(service: Service, link: FakeLink, *, armed: bool = True, mav_type: int = 10) -> None:
    """A vehicle in GUIDED driving east through odour: heartbeat at 1 Hz, the rest at 5 Hz (an
    ArduPilot rover unless ``mav_type`` says otherwise)."""
    clock, k = service.clock, 0
    while True:
        t = clock.now()
        if k % 5 == 0:
            link.inbox.put_nowait((t, FakeMessage(
                "HEARTBEAT", type=mav_type, autopilot=3, base_mode=ARMED if armed else 0,
                custom_mode=service.config.mavlink.guided_mode,
            )))  # fmt: skip
        # LOCAL_POSITION_NED is north, east: map x = 10 + 0.5 t east, y = 0
        link.inbox.put_nowait((t, FakeMessage("LOCAL_POSITION_NED", x=0.0, y=10.0 + 0.5 * t)))
        link.inbox.put_nowait((t, FakeMessage("WIND_COV", wind_x=0.0, wind_y=-0.5)))  # toward the west
        link.inbox.put_nowait(
            (t, FakeMessage("NAMED_VALUE_FLOAT", name=b"CHEM", value=2.0 if k % 2 else 0.0))
        )
        k += 1
        await clock.sleep_until(t + 0.2)


def fakes() -> tuple[FakeLink, FakeMaps, FakeRecorder, Edges]:
    link, maps, recorder = FakeLink(), FakeMaps(), FakeRecorder()
    return link, maps, recorder, Edges(link, maps, recorder)


def guided_service(config: Config, edges: Edges) -> Service:
    """A service whose gate has heard an armed autopilot in GUIDED: it may command at once."""
    service = Service(config, clock=Clock(SPEED))
    service.gate.heard(Heartbeat(0.0, 1, 1, 10, 3, config.mavlink.guided_mode, armed=True))
    service._update_gate(edges, 0.5)
    return service


def beside_the_wang_obstacle() -> tuple[FakeLink, FakeRecorder, Edges, Service]:
    """A commanding service (``guided_service``) in an area with the wang scenarios' obstacle,
    told of a vehicle at (60, 3), just east of it."""
    config = build_config({"area": {"obstacles": [[36.25, 0.25, 56.25, 7.75]]}})
    link, _, recorder, edges = fakes()
    service = guided_service(config, edges)
    service.search.add_position(0.5, 60.0, 3.0)
    return link, recorder, edges, service


def test_the_service_maps_publishes_records_and_commands_over_fake_edges() -> None:
    link, maps, recorder, edges = fakes()

    async def body() -> None:
        service = Service(Config(), clock=Clock(SPEED))
        stop = asyncio.Event()
        run = asyncio.create_task(service.run_with(edges, stop))
        driver = asyncio.create_task(vehicle(service, link))
        await until(lambda: service.stats.observations >= 6 and len(recorder.setpoints) >= 3)
        stop.set()
        stats = await run
        driver.cancel()
        assert stats is service.stats
        assert service.target is None  # stopped commanding

    asyncio.run(body())
    assert link.of("heartbeat")
    assert {args[1] for args in link.of("interval")} == set(STREAMS.values())
    assert all(args[0] == 1 for args in link.of("interval"))  # to the autopilot heard
    # every observation is published and recorded once, with its maps
    assert recorder.ticks == maps.observations
    assert len(maps.slim) == len(maps.estimates) == len(recorder.ticks) >= 6
    # the maps are what the search computes from the same observations: nothing else feeds them
    replayed = Search(Config())
    for obs, slim in zip(recorder.ticks, maps.slim, strict=True):
        replayed.update_map(obs)
        np.testing.assert_array_equal(slim, replayed.likelihood)
    # every tick also records what Foxglove draws: the vehicle among it, once per tick
    assert recorder.scene.count(VEHICLE_TOPIC) == len(recorder.ticks)
    first = recorder.ticks[0]
    assert first.flow_x == pytest.approx(-0.5)
    assert first.flow_y == pytest.approx(0.0)
    # setpoints sent are the recorded ones, in the area, and at the configured altitude
    setpoints = link.of("setpoint")
    assert len(setpoints) == len(recorder.setpoints)
    for (_, _, x, y, z, mask), (_, rx, ry, rz) in zip(setpoints, recorder.setpoints, strict=True):
        assert (x, y, z) == (rx, ry, rz) == (x, y, Config().mavlink.altitude_m)
        assert 0.0 <= x <= 100.0
        assert -50.0 <= y <= 50.0
        assert mask == Config().mavlink.setpoint_type_mask


def test_a_disarmed_vehicle_is_mapped_but_not_commanded() -> None:
    link, _, recorder, edges = fakes()

    async def body() -> None:
        service = Service(Config(), clock=Clock(SPEED))
        stop = asyncio.Event()
        run = asyncio.create_task(service.run_with(edges, stop))
        driver = asyncio.create_task(vehicle(service, link, armed=False))
        await until(lambda: service.stats.observations >= 4)
        stop.set()
        await run
        driver.cancel()

    asyncio.run(body())
    assert len(recorder.ticks) >= 4
    assert link.of("setpoint") == []
    assert recorder.setpoints == []


def test_a_failing_edge_stops_the_run_with_its_own_error() -> None:
    link, _, recorder, edges = fakes()
    link.fail_with = LinkError("serial device gone")

    async def body() -> None:
        service = Service(Config(), clock=Clock(SPEED))
        run = asyncio.create_task(service.run_with(edges, asyncio.Event()))
        await until(lambda: service.stats.ticks >= 2)
        link.inbox.put_nowait(None)  # the link's stream ends with the error
        with pytest.raises(LinkError, match="serial device gone"):
            await run
        assert run.done()

    asyncio.run(body())
    assert recorder.events.count("gap") >= 2  # ticks without telemetry were recorded as gaps


def test_a_link_that_closes_ends_the_run() -> None:
    link, _, _, edges = fakes()

    async def body() -> None:
        service = Service(Config(), clock=Clock(SPEED))
        link.inbox.put_nowait(None)
        stats = await asyncio.wait_for(service.run_with(edges, asyncio.Event()), 5.0)
        assert stats.observations == 0

    asyncio.run(body())


def test_a_target_beside_an_obstacle_goes_out_where_the_mission_planned_it() -> None:
    # the mission plans on 1.25 m model cells; the obstacle ends at x = 56.25 m, halfway across the
    # area's 2.5 m cell 55-57.5 m: (57.1, 3) is free on the mission's grid and must be sent
    link, recorder, edges, service = beside_the_wang_obstacle()
    search = service.search
    # the mission's plan, staged: its planners never plan into an obstacle, and the service's own
    # check is the last line of defence
    search._plan = (Waypoint(57.1, 3.0),)
    assert service.target == Waypoint(57.1, 3.0)
    assert service._command(edges, 0.5)
    assert [(x, y) for _, _, x, y, _, _ in link.of("setpoint")] == [(57.1, 3.0)]
    search._plan = (Waypoint(56.0, 3.0),)  # inside the rectangle: refused, and commanding stops
    assert not service._command(edges, 1.0)
    assert service.stats.unsafe_targets == 1
    assert service.target is None
    assert not service._command(edges, 1.5)  # and stays stopped until the mission plans again
    assert service.stats.unsafe_targets == 1
    assert len(recorder.setpoints) == 1


def test_commanding_resumes_when_the_mission_plans_again_after_a_refusal() -> None:
    link, _, edges, service = beside_the_wang_obstacle()
    search = service.search
    search._plan = (Waypoint(56.0, 3.0),)  # staged inside the obstacle: refused
    assert not service._command(edges, 0.5)
    assert service.target is None
    # the next tick's observation makes the mission plan again (a plume-finding leg)
    search.add_position(0.9, 60.0, 3.0)
    search.add_flow(0.9, 1.0, 0.0)
    search.add_chemical(0.9, 0.0)
    service._tick(edges, 1.0, 0.0)
    assert service.target == search.plan[0]
    assert len(link.of("setpoint")) == 1  # the tick commanded the new plan's target at once
    assert service.stats.unsafe_targets == 1


def test_an_autopilot_that_stops_short_is_led_and_told_of_once() -> None:
    # Rover holds 2 m short of a guided target (WP_RADIUS): once the search has seen it stop short,
    # the setpoints sent lead the vehicle through its targets; the log and the recording say so once
    config = Config()
    link, _, recorder, edges = fakes()
    service = guided_service(config, edges)
    search = service.search
    search._plan = (Waypoint(52.0, 0.0),)  # the mission's plan: one point 2 m east of the vehicle
    for k in range(int(2 * STALL_S) + 4):  # the vehicle stays put at (50, 0) while commanded
        search.add_position(0.5 * k, 50.0, 0.0)
        assert service._command(edges, 0.5 * k)
    assert search.arrival_radius_m == pytest.approx(2.0)
    sent = [(x, y) for _, _, x, y, _, _ in link.of("setpoint")]
    assert sent[0] == (52.0, 0.0)
    assert sent[-1] == (pytest.approx(52.0 + 2.0 + 0.3), 0.0)  # through the target, to stop just past it
    assert recorder.events.count("arrival_radius") == 1


def run_with_vehicle(
    seconds: float,
    *,
    mav_type: int = 10,
    answer_after: int | None = None,
    answers: dict[str, float] | None = None,
) -> tuple[FakeLink, FakeRecorder, Service]:
    """The service ``seconds`` (service time) with ``vehicle``; the autopilot answers each parameter
    of ``answers`` at its ``answer_after``-th request (None: it never answers)."""
    link, _, recorder, edges = fakes()
    service = Service(Config(), clock=Clock(SPEED))
    wanted = answers or {}

    async def autopilot_params() -> None:
        answered: set[str] = set()
        while answer_after is not None and len(answered) < len(wanted):
            asked = [name for _, name in link.of("param")]
            for name, value in wanted.items():
                if name not in answered and asked.count(name) >= answer_after:
                    reply = FakeMessage("PARAM_VALUE", param_id=name.encode(), param_value=value)
                    link.inbox.put_nowait((service.clock.now(), reply))
                    answered.add(name)
            await asyncio.sleep(0.002)

    async def body() -> None:
        stop = asyncio.Event()
        run = asyncio.create_task(service.run_with(edges, stop))
        tasks = [
            asyncio.create_task(vehicle(service, link, mav_type=mav_type)),
            asyncio.create_task(autopilot_params()),
        ]
        await service.clock.sleep_until(seconds)
        stop.set()
        await run
        for task in tasks:
            task.cancel()

    asyncio.run(body())
    return link, recorder, service


@pytest.mark.parametrize("radius_m", [0.5, 2.0])
def test_an_ardupilot_rover_is_asked_for_its_acceptance_radius_until_it_answers(radius_m: float) -> None:
    # the first request is lost, the second answered; the answer is said in the recording, and the
    # setpoints stay the plan's own points: a Rover since 4.3 drives onto its guided targets, and
    # only a vehicle seen to stop short of them is led
    answers = {"WP_RADIUS": radius_m}
    link, recorder, service = run_with_vehicle(PARAM_ASKS + 4.0, answer_after=2, answers=answers)
    asked = [name for _, name in link.of("param")]
    assert asked.count("WP_RADIUS") == 2
    assert asked.count("WP_SPEED") == PARAM_ASKS  # never answered: asked each round
    assert recorder.events.count("autopilot_radius") == 1
    assert service.search.arrival_radius_m == 0.0
    assert "arrival_radius" not in recorder.events


def test_an_autopilot_that_never_answers_is_asked_a_few_times() -> None:
    link, _, service = run_with_vehicle(PARAM_ASKS + 4.0)
    assert sorted(link.of("param")) == sorted([(1, name) for name in ROVER_PARAMS] * PARAM_ASKS)
    assert service.search.arrival_radius_m == 0.0
    assert link.of("speed") == []


def test_a_rover_at_sitl_cruise_speed_is_asked_to_slow_down_while_commanded() -> None:
    # SITL's rover.parm: WP_SPEED 0, so guided targets are driven at CRUISE_SPEED 5 m/s; the service
    # asks for vehicle.max_speed_mps (2 m/s) with every setpoint stream, again every SPEED_EVERY_S
    answers = {"WP_RADIUS": 3.0, "WP_SPEED": 0.0, "CRUISE_SPEED": 5.0}
    link, recorder, _ = run_with_vehicle(16.0, answer_after=1, answers=answers)
    sent = link.of("speed")
    assert len(sent) >= 2
    assert set(sent) == {(1, 2.0)}
    assert recorder.events.count("speed_cap") == 1


@pytest.mark.parametrize(
    "answers",
    [{"WP_SPEED": 1.5, "CRUISE_SPEED": 5.0}, {"WP_SPEED": 0.0, "CRUISE_SPEED": 1.0}, {"CRUISE_SPEED": 5.0}],
    ids=["wp-speed-slower", "cruise-slower", "wp-speed-unknown"],
)
def test_a_slower_or_unknown_speed_is_left_alone(answers: dict[str, float]) -> None:
    link, recorder, _ = run_with_vehicle(12.0, answer_after=1, answers=answers)
    assert link.of("speed") == []
    assert "speed_cap" not in recorder.events


def test_a_vehicle_that_flies_onto_its_targets_is_not_asked() -> None:
    link, _, _ = run_with_vehicle(4.0, mav_type=12)  # ArduSub
    assert link.of("param") == []


def test_a_detection_stream_with_a_response_time_is_warned_of_once(caplog: pytest.LogCaptureFixture) -> None:
    # sensor.response_s undoes a slow sensor's lag on its readings (CHEM); a sensor that sends only
    # its own detection (CHEM_DET) cannot be helped, and the log says so once
    link, _, _, edges = fakes()
    service = Service(build_config({"sensor": {"response_s": 2.0}}), clock=Clock(SPEED))

    async def body() -> None:
        stop = asyncio.Event()
        run = asyncio.create_task(service.run_with(edges, stop))
        for k in range(3):
            detection = FakeMessage("NAMED_VALUE_INT", name=b"CHEM_DET", value=k % 2)
            link.inbox.put_nowait((service.clock.now(), detection))
        await service.clock.sleep_until(2.0)
        stop.set()
        await run

    with caplog.at_level("WARNING", logger="oslim"):
        asyncio.run(body())
    warned = [r.getMessage() for r in caplog.records if "cannot be undone" in r.getMessage()]
    assert warned == ["CHEM_DET is a detection, not a reading: sensor.response_s (2.00 s) cannot be undone "
                      "for it; send the reading as CHEM"]  # fmt: skip
