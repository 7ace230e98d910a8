import itertools
import json
import math
from collections import deque
from collections.abc import Callable

import numpy as np
import pytest

from service.core.config import (
    DeclarationConfig,
    PlanningConfig,
    PlanningMethod,
    build_config,
)
from service.core.grid import Grid
from service.core.mapping.belief import FloatArray
from service.core.mapping.hmm import HmmMapper
from service.core.mapping.mapper import SourceMapper
from service.core.mission import (
    CrossCheck,
    Mission,
    MissionOutput,
    MissionState,
    PlumeFound,
    PlumeLost,
    SourceDeclared,
)
from service.core.mission.declaring import PROBE_REACH, RESMELL_WAIT_S
from service.core.mission.mission import TRACE_SLACK_M
from service.core.observation import Observation
from service.core.planning import PLANNERS
from service.core.planning.base import VehicleState, Waypoint


class ScriptedMapper(SourceMapper):
    """A mapper whose source map the test sets; its detection model is a fixed random table."""

    name = "scripted"

    def __init__(self, grid: Grid, seed: int = 0) -> None:
        super().__init__(grid)
        self._table = np.random.default_rng(seed).uniform(0.0, 0.5, size=(grid.size, *grid.shape))

    def set(self, pi: FloatArray) -> None:
        self._pi = pi / pi.sum()

    def peak_at(self, cell: int, peak: float = 0.5) -> None:
        pi = np.full(self.grid.shape, (1.0 - peak) / max(self.grid.size - 1, 1))
        pi.flat[cell] = peak
        self.set(pi)

    def _assimilate(self, cell: int, detected: bool, at: tuple[float, float]) -> None:
        pass

    def detection_likelihood(self, cell: int) -> FloatArray:
        out: FloatArray = self._table[cell]
        return out

    def odour_kernel(self) -> FloatArray:
        """Odour from a source in the vehicle's row upflow (West) of it, or in its cell."""
        n, m = self.grid.shape
        kernel = np.zeros((2 * n - 1, 2 * m - 1))
        kernel[n - 1, :m] = 0.5
        return kernel


PAPERS_PLANNING = PlanningConfig(
    lost_after_s=20.0,
    lone_contact_hits=0,
    lone_contact_lost_after_s=20.0,
)
"""The planning these tests were written against: the papers' mechanisms without the later guard
(looking for the plume again after lone contacts); a test of it turns it on."""

PAPERS_DECLARATION = DeclarationConfig(upflow_pass_m=0.0, check_width_m=0.0)
"""The declaration these tests were written against: the papers' rules without the later guards
(no upflow pass or check across the flow)."""

NEVER = PAPERS_DECLARATION.model_copy(
    update={"probability": 1.0, "hmm_probability": 1.0, "upflow_pass_m": 1e9}
)
"""Declaration off, for tests of the other states: no upflow pass 1e9 m long is ever made (and the
hmm, which makes none, would need all of the map in one cell)."""

# -- independent references ---------------------------------------------------------------------


def overlaps(grid: Grid, row: int, col: int) -> bool:
    """Does cell (row, col) overlap an obstacle rectangle with positive area?"""
    x0 = grid.x_min + col * grid.cell_width_m
    y0 = grid.y_min + row * grid.cell_height_m
    x1, y1 = x0 + grid.cell_width_m, y0 + grid.cell_height_m
    return any(
        min(x1, bx1) > max(x0, bx0) and min(y1, by1) > max(y0, by0) for bx0, by0, bx1, by1 in grid.obstacles
    )


def in_rectangle(grid: Grid, x: float, y: float) -> bool:
    return any(bx0 <= x <= bx1 and by0 <= y <= by1 for bx0, by0, bx1, by1 in grid.obstacles)


def assert_safe_waypoint(grid: Grid, w: Waypoint) -> None:
    assert grid.x_min <= w.x <= grid.x_max, w
    assert grid.y_min <= w.y <= grid.y_max, w
    assert not in_rectangle(grid, w.x, w.y), w
    col = min(int((w.x - grid.x_min) / grid.cell_width_m), grid.columns - 1)
    row = min(int((w.y - grid.y_min) / grid.cell_height_m), grid.rows - 1)
    # a point on a cell boundary belongs to both cells: neither may be an obstacle cell
    cols = {col, max(col - 1, 0)} if math.isclose((w.x - grid.x_min) / grid.cell_width_m % 1, 0) else {col}
    rows = {row, max(row - 1, 0)} if math.isclose((w.y - grid.y_min) / grid.cell_height_m % 1, 0) else {row}
    assert not any(overlaps(grid, r, c) for r in rows for c in cols), w


def assert_clear_leg(grid: Grid, a: tuple[float, float], b: tuple[float, float]) -> None:
    for t in np.linspace(0.0, 1.0, 101):
        x, y = a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])
        assert not in_rectangle(grid, x, y), (a, b)


def free_mask(grid: Grid) -> np.ndarray:
    return np.array([[not overlaps(grid, r, c) for c in range(grid.columns)] for r in range(grid.rows)])


def bfs(free: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    n, m = free.shape
    seen = np.zeros_like(free)
    seen[start] = True
    queue = deque([start])
    while queue:
        r, c = queue.popleft()
        for dr, dc in itertools.product((-1, 0, 1), repeat=2):
            rr, cc = r + dr, c + dc
            if not (0 <= rr < n and 0 <= cc < m) or not free[rr, cc] or seen[rr, cc]:
                continue
            if dr and dc and not (free[r + dr, c] and free[r, c + dc]):
                continue
            seen[rr, cc] = True
            queue.append((rr, cc))
    out: np.ndarray = seen & free
    return out


def random_area(rng: np.random.Generator) -> Grid:
    m, n = int(rng.integers(3, 11)), int(rng.integers(3, 11))
    lx, ly = float(rng.uniform(1.0, 5.0)), float(rng.uniform(1.0, 5.0))
    x0, y0 = float(rng.uniform(-50, 50)), float(rng.uniform(-50, 50))
    boxes = []
    for _ in range(int(rng.integers(0, 6))):
        bx, by = x0 + rng.uniform(0, m * lx), y0 + rng.uniform(0, n * ly)
        boxes.append((bx, by, bx + rng.uniform(0.2, 3) * lx, by + rng.uniform(0.2, 3) * ly))
    return Grid(x0, x0 + m * lx, y0, y0 + n * ly, columns=m, rows=n, obstacles=tuple(boxes))


class Vehicle:
    """A vehicle that reaches its current target in one tick and then takes the next one."""

    def __init__(self, x: float, y: float) -> None:
        self.x, self.y = x, y
        self.queue: list[Waypoint] = []

    def follow(self, waypoints: tuple[Waypoint, ...] | None) -> None:
        if waypoints is not None:
            self.queue = list(waypoints)

    def move(self) -> None:
        if self.queue:
            w = self.queue.pop(0)
            self.x, self.y = w.x, w.y

    @property
    def state(self) -> VehicleState:
        return VehicleState(self.x, self.y, 0.0)


# -- safety invariants over many random maps ----------------------------------------------------


@pytest.mark.parametrize("method", sorted(PLANNERS))
def test_no_unsafe_waypoint_on_random_maps(method: str) -> None:
    rng = np.random.default_rng(sum(map(ord, method)))
    planning = PlanningConfig(method=PlanningMethod(method), mldp_steps=4, lost_after_s=3.0)
    emitted = started_inside = 0
    states: set[MissionState] = set()
    for trial in range(80):
        grid = random_area(rng)
        mapper = ScriptedMapper(grid, seed=trial)
        mission = Mission(grid, mapper, planning, NEVER)
        # anywhere, including inside obstacles and a little outside the area
        vx = float(rng.uniform(grid.x_min - 3, grid.x_max + 3))
        vy = float(rng.uniform(grid.y_min - 3, grid.y_max + 3))
        vehicle = Vehicle(vx, vy)
        started_inside += in_rectangle(grid, vx, vy)
        for t in range(15):
            mapper.set(rng.random(grid.shape) ** 4)
            flow = rng.normal(0.0, 1.0, size=2)
            obs = Observation(
                float(t), vehicle.x, vehicle.y, float(flow[0]), float(flow[1]), bool(rng.random() < 0.3)
            )
            before = (vehicle.x, vehicle.y)
            out = mission.step(obs, vehicle.state)
            states.add(out.state)
            if out.waypoints is not None:
                emitted += 1
                assert out.waypoints, "an emitted plan is never empty"
                for w in out.waypoints:
                    assert_safe_waypoint(grid, w)
                legs = [(w.x, w.y) for w in out.waypoints]
                # the leg from the vehicle too, unless it is inside an obstacle (no leg can be clear)
                if not in_rectangle(grid, *before):
                    legs = [before, *legs]
                for a, b in itertools.pairwise(legs):
                    assert_clear_leg(grid, a, b)
            vehicle.follow(out.waypoints)
            vehicle.move()
    # the cases that matter were met: every state, and vehicles starting inside an obstacle
    assert emitted > 400
    assert states == {MissionState.FIND, MissionState.TRACE, MissionState.LOST}
    assert started_inside > 3


def test_reaches_the_estimate_whenever_a_path_exists() -> None:
    rng = np.random.default_rng(2024)
    reached = fell_back = 0
    for trial in range(60):
        grid = random_area(rng)
        free = free_mask(grid)
        if not free.any():
            continue
        row, col = (int(v) for v in rng.choice(np.argwhere(free)))
        start = (row, col)
        goal = int(rng.integers(0, grid.size))
        mapper = ScriptedMapper(grid, seed=trial)
        mapper.peak_at(goal)
        mission = Mission(grid, mapper, PAPERS_PLANNING, NEVER)
        x, y = grid.centre(start[0] * grid.columns + start[1])
        vehicle = Vehicle(x, y)
        visited: set[int] = set()
        gx, gy = grid.centre(goal)
        for t in range(2 * grid.size + 2):
            # odour at the estimate: the trace's goal is the estimate itself (TRACE_SLACK_M)
            obs = Observation(float(t), gx, gy, 0.3, 0.1, True)
            out = mission.step(obs, vehicle.state)
            assert mission.state is MissionState.TRACE
            vehicle.follow(out.waypoints)
            vehicle.move()
            visited.add(grid.cell_of(vehicle.x, vehicle.y))
        reach = bfs(free, start)
        here = grid.cell_of(vehicle.x, vehicle.y)
        if reach.flat[goal]:
            # at the estimate, an undeclared mission probes the cells around it (within
            # PROBE_REACH rows and columns) and comes back, so the vehicle ends at the goal or
            # among those cells, having reached it
            assert goal in visited, f"trial {trial}: never reached goal {goal}, which was reachable"
            (hr, hc), (gr, gc) = grid.row_col(here), grid.row_col(goal)
            assert max(abs(hr - gr), abs(hc - gc)) <= PROBE_REACH, (
                f"trial {trial}: stopped in {here}, goal {goal}"
            )
            reached += 1
        else:
            # no path: the mission went to the reachable cell nearest the estimate, without error
            # (and from there probes upflow, so it need not end there)
            gx, gy = grid.centre(goal)
            dist = [math.dist(grid.centre(int(c)), (gx, gy)) for c in np.flatnonzero(reach)]
            assert reach.flat[here]
            nearest = min(math.dist(grid.centre(c), (gx, gy)) for c in visited)
            assert nearest == pytest.approx(min(dist))
            fell_back += 1
    assert reached > 20
    assert fell_back > 5


# -- the state machine --------------------------------------------------------------------------

AREA = Grid(0.0, 100.0, -50.0, 50.0, columns=20, rows=20)  # 5 m cells
SOURCE = AREA.cell_of(22.0, 3.0)


def mission_with(mapper: SourceMapper, **declaration: object) -> Mission:
    planning = PAPERS_PLANNING.model_copy(update={"lost_after_s": 10.0})
    decl = PAPERS_DECLARATION.model_copy(update=declaration)
    return Mission(AREA, mapper, planning, decl)


def test_find_trace_lose_recover_declare() -> None:
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.05)
    # the rule, not the visit gate, is under test here: the vehicle is far from the estimate
    mission = mission_with(mapper, probability=0.8, radius_m=5.0, visit_radius_m=1e6)
    v = VehicleState(90.0, -40.0)
    flow = (1.0, 0.0)

    holds: list[bool] = []

    def tick(t: float, detected: bool = False) -> tuple:  # type: ignore[type-arg]
        out = mission.step(Observation(t, v.x, v.y, *flow, detected), v)
        holds.append(out.hold)
        return out.state, out.events, out.waypoints

    # FIND: no flow history at the first tick, so hold; then a leg chosen by the map
    state, events, wps = tick(0.0)
    assert state is MissionState.FIND
    assert events == ()
    assert wps == (Waypoint(v.x, v.y),)
    assert holds[-1]  # a point to stop on, not a path (an autopilot's setpoint need not lead)
    state, events, wps = tick(1.0)
    assert state is MissionState.FIND
    assert wps is not None
    assert not holds[-1]
    # a leg clear of obstacles is flown straight to its end, not along A*'s cells
    (end,) = wps
    assert math.dist((end.x, end.y), (v.x, v.y)) >= 5.0
    assert tick(2.0)[2] is None  # nothing changed: keep flying
    # the first detection: TRACE toward the estimate
    state, events, wps = tick(5.0, detected=True)
    assert state is MissionState.TRACE
    assert events == (PlumeFound(5.0, 90.0, -40.0, first=True),)
    assert wps is not None
    assert (wps[-1].x, wps[-1].y) == AREA.centre(SOURCE)
    # no detection for lost_after_s: LOST, reported; the vehicle flies on toward the estimate
    assert tick(14.0)[0] is MissionState.TRACE
    state, events, wps = tick(15.0)
    assert state is MissionState.LOST
    assert events == (PlumeLost(15.0, 90.0, -40.0, last_detection_s=5.0),)
    assert wps is None  # the estimate did not move: the path to it is flown on, unchanged
    # a detection ends LOST
    state, events, _ = tick(20.0, detected=True)
    assert state is MissionState.TRACE
    assert events == (PlumeFound(20.0, 90.0, -40.0, first=False),)
    # the map is not sure yet: no declaration
    for t in range(21, 35):
        assert tick(float(t), detected=True)[0] is MissionState.TRACE
    mapper.peak_at(SOURCE, 0.9)  # now it is: declared
    state, events, wps = tick(35.0, detected=True)
    assert state is MissionState.DECLARED
    x, y = AREA.centre(SOURCE)
    (declared,) = events
    assert isinstance(declared, SourceDeclared)
    assert declared == SourceDeclared(
        35.0, x, y, AREA.paper_number(SOURCE), declared.probability, declared.mass
    )
    assert declared.probability == pytest.approx(0.9)
    # radius 5 m on 5 m cells: the cell and its four side neighbours, (1 - 0.9) / 399 each
    assert declared.mass == pytest.approx(0.9 + 4 * 0.1 / 399)
    assert wps == (Waypoint(v.x, v.y),)  # hold where it is
    assert holds[-1]
    # declared is final: no more waypoints or events, the map keeps updating
    state, events, wps = tick(36.0, detected=True)
    assert (state, events, wps) == (MissionState.DECLARED, (), None)
    assert holds[-1]


def test_mass_rule_declares_and_says_so() -> None:
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.9)
    mission = mission_with(mapper, probability=0.8, visit_radius_m=1e6)
    v = VehicleState(50.0, 0.0)
    out = mission.step(Observation(0.0, v.x, v.y, 1.0, 0.0, False), v)
    assert out.state is MissionState.FIND  # no rule is judged before the first detection
    out = mission.step(Observation(1.0, v.x, v.y, 1.0, 0.0, True), v)
    assert out.state is MissionState.DECLARED
    (found, declared) = out.events
    assert isinstance(found, PlumeFound)
    assert isinstance(declared, SourceDeclared)
    assert declared.mass >= 0.8


def test_no_rule_fires_before_the_vehicle_visits_the_estimate() -> None:
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.9)
    mission = mission_with(mapper, probability=0.8, visit_radius_m=3.0)
    far = VehicleState(50.0, 0.0)
    sx, sy = AREA.centre(SOURCE)
    assert math.dist((far.x, far.y), (sx, sy)) > 3.0
    mission.step(Observation(0.0, far.x, far.y, 1.0, 0.0, True), far)
    assert mission.state is MissionState.TRACE  # the map is sure, but nobody has looked there
    near = VehicleState(sx + 2.0, sy)
    out = mission.step(Observation(1.0, near.x, near.y, 1.0, 0.0, True), near)
    assert out.state is MissionState.DECLARED


def test_time_comes_only_from_the_observation() -> None:
    mapper = ScriptedMapper(AREA)
    mission = mission_with(mapper)
    v = VehicleState(50.0, 0.0)
    first = mission.step(Observation(10.0, v.x, v.y, 1.0, 0.0, False), v)
    assert first.waypoints is not None
    repeat = mission.step(Observation(10.0, v.x, v.y, 1.0, 0.0, True), v)
    assert repeat.waypoints is None
    assert repeat.events == ()
    assert repeat.state is MissionState.FIND  # the repeated tick's detection was not taken
    earlier = mission.step(Observation(9.0, v.x, v.y, 1.0, 0.0, True), v)
    assert earlier.events == ()


def test_unreachable_estimate_is_handled_without_error() -> None:
    # the estimate sits inside a walled-off pocket: go to the nearest reachable cell and hold
    walls = (
        (40.0, 0.0, 60.0, 5.0),
        (40.0, 15.0, 60.0, 20.0),
        (40.0, 0.0, 45.0, 20.0),
        (55.0, 0.0, 60.0, 20.0),
    )
    grid = Grid(0.0, 100.0, -50.0, 50.0, columns=20, rows=20, obstacles=walls)
    pocket = grid.cell_of(50.0, 10.0)
    assert not grid.obstacle_mask.flat[pocket]
    mapper = ScriptedMapper(grid)
    mapper.peak_at(pocket)
    mission = Mission(grid, mapper, PAPERS_PLANNING, NEVER)
    vehicle = Vehicle(5.0, -45.0)
    for t in range(60):
        # a flow toward the West: the pocket lies upflow of the odour met at the start
        out = mission.step(Observation(float(t), vehicle.x, vehicle.y, -1.0, 0.0, t == 0), vehicle.state)
        vehicle.follow(out.waypoints)
        vehicle.move()
    here = grid.cell_of(vehicle.x, vehicle.y)
    assert math.dist(grid.centre(here), grid.centre(pocket)) == pytest.approx(10.0)  # just outside a wall


def test_with_the_hmm_mapper_end_to_end() -> None:
    # a real mapper, every planner: the mission runs and stays safe on the paper's grid
    grid = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25, obstacles=((60.0, 10.0, 80.0, 17.5),))
    for method in sorted(PLANNERS):
        mapper = HmmMapper(grid)
        # declaration off: a declared mission holds, and this test is about the moving states
        mission = Mission(grid, mapper, PlanningConfig(method=PlanningMethod(method)), NEVER)
        vehicle = Vehicle(70.0, -40.0)
        for t in range(20):
            detected = 8 <= t <= 12
            out = mission.step(Observation(float(t), vehicle.x, vehicle.y, 1.0, 0.0, detected), vehicle.state)
            if out.waypoints is not None:
                for w in out.waypoints:
                    assert_safe_waypoint(grid, w)
            vehicle.follow(out.waypoints)
            vehicle.move()
        assert mission.state in (MissionState.TRACE, MissionState.LOST)


def test_states_are_the_zenoh_estimate_states() -> None:
    # DESIGN.md: estimate.state is one of search, trace, lost, declared
    assert [s.value for s in MissionState] == ["search", "trace", "lost", "declared"]


def test_from_config() -> None:
    config = build_config({}, ["planning.method=apf", "declaration.check_upflow_m=2.5"])
    mission = Mission.from_config(config, AREA, ScriptedMapper(AREA))
    assert mission.planner.name == "apf"
    assert mission.state is MissionState.FIND
    with pytest.raises(ValueError, match="different grid"):
        Mission.from_config(config, AREA, ScriptedMapper(Grid(0.0, 1.0, 0.0, 1.0, columns=1, rows=1)))


def test_find_chooses_a_new_leg_when_the_mean_flow_turns() -> None:
    mapper = ScriptedMapper(AREA)
    mission = Mission(AREA, mapper, PlanningConfig(), NEVER)
    v = VehicleState(50.0, 0.0)
    for t in range(6):
        out = mission.step(Observation(float(t), v.x, v.y, 1.0, 0.0, False), v)
    assert out.waypoints is None  # flying the leg chosen at t = 1
    # single noisy ticks across do not change it (the mean flow is still East) ...
    out = mission.step(Observation(6.0, v.x, v.y, 0.0, 3.0, False), v)
    assert out.waypoints is None
    # ... a lasting turn to North does
    chosen = [
        t
        for t in range(7, 20)
        if mission.step(Observation(float(t), v.x, v.y, 0.0, 1.0, False), v).waypoints is not None
    ]
    assert len(chosen) == 1


def test_a_lost_plume_is_traced_on_toward_the_estimate() -> None:
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.3)  # however much of the map the estimate holds
    planning = PAPERS_PLANNING.model_copy(update={"lost_after_s": 10.0})
    mission = Mission(AREA, mapper, planning, NEVER)
    v = VehicleState(90.0, -40.0)
    mission.step(Observation(4.0, v.x, v.y, 1.0, 0.0, False), v)  # a tick of flow
    assert mission.step(Observation(5.0, v.x, v.y, 1.0, 0.0, True), v).waypoints is not None
    assert mission.step(Observation(14.0, v.x, v.y, 1.0, 0.0, False), v).state is MissionState.TRACE
    elsewhere = AREA.cell_of(62.0, 23.0)
    mapper.peak_at(elsewhere, 0.3)  # the misses moved the estimate
    out = mission.step(Observation(15.0, v.x, v.y, 1.0, 0.0, False), v)
    assert out.state is MissionState.LOST
    assert out.waypoints is not None
    assert (out.waypoints[-1].x, out.waypoints[-1].y) == AREA.centre(elsewhere)


@pytest.mark.parametrize(
    ("lone_contact_hits", "hits", "looks_on"), [(0, 1, False), (1, 1, True), (1, 2, False)]
)
def test_a_lone_detection_in_find_goes_back_to_find(
    lone_contact_hits: int, hits: int, looks_on: bool
) -> None:
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.05)
    planning = PlanningConfig(
        lost_after_s=10.0,
        lone_contact_hits=lone_contact_hits,
        lone_contact_lost_after_s=4.0,
    )
    mission = Mission(AREA, mapper, planning, NEVER)
    flow = (1.0, 0.0)
    v = VehicleState(90.0, -40.0)
    mission.step(Observation(0.0, v.x, v.y, *flow, False), v)
    leg = mission.step(Observation(1.0, v.x, v.y, *flow, False), v).waypoints
    assert leg is not None  # the first leg
    v = VehicleState(90.0, -20.0)  # part way along it
    for k in range(hits):
        out = mission.step(Observation(5.0 + k, v.x, v.y, *flow, True), v)
        assert out.state is MissionState.TRACE
    last = 5.0 + hits - 1
    wait = 4.0 if looks_on else 10.0  # a lone contact waits lone_contact_lost_after_s
    assert mission.step(Observation(last + wait - 0.5, v.x, v.y, *flow, False), v).state is MissionState.TRACE
    out = mission.step(Observation(last + wait, v.x, v.y, *flow, False), v)
    assert PlumeLost(last + wait, v.x, v.y, last) in out.events
    if looks_on:  # back to FIND: a new leg from here
        assert out.state is MissionState.FIND
        assert out.waypoints is not None
        (end,) = out.waypoints
        assert math.dist((end.x, end.y), (v.x, v.y)) >= 5.0
        # a later contact is traced as before (and is not the mission's first)
        out = mission.step(Observation(30.0, v.x, v.y, *flow, True), v)
        assert out.state is MissionState.TRACE
        assert out.events == (PlumeFound(30.0, v.x, v.y, first=False),)
    else:  # lost, and flying on toward the estimate
        assert out.state is MissionState.LOST
        assert out.waypoints is None  # the estimate did not move: the path to it is flown on


def fly(mission: Mission, vehicle: Vehicle, ticks: int, odour: Callable[[int], bool]) -> set[int]:
    """The cells a vehicle flying ``mission`` visits in ``ticks`` ticks of an eastward flow (odour
    at tick t when ``odour(t)``); every waypoint must be safe."""
    grid = mission.grid
    visited = set()
    for t in range(ticks):
        obs = Observation(float(t), vehicle.x, vehicle.y, 1.0, 0.0, odour(t))
        out = mission.step(obs, vehicle.state)
        for w in out.waypoints or ():
            assert_safe_waypoint(grid, w)
        vehicle.follow(out.waypoints)
        vehicle.move()
        visited.add(grid.cell_of(vehicle.x, vehicle.y))
    return visited


def test_probes_beyond_an_obstacle_that_blocks_every_upflow_neighbour() -> None:
    # the estimate is the vehicle's own cell, against the downflow face of a wall, and the map's
    # rival lies upflow beyond the wall: only a look beyond the wall tells them apart, so the
    # mission flies round the wall to the first free cell upflow instead of holding at the face
    grid = Grid(0.0, 100.0, -50.0, 50.0, columns=20, rows=20, obstacles=((40.0, -10.0, 50.0, 10.0),))
    here = grid.cell_of(52.5, 2.5)
    beyond = grid.cell_of(37.5, 2.5)
    assert grid.obstacle_mask.flat[grid.cell_of(47.5, 2.5)]
    mapper = ScriptedMapper(grid)
    pi = np.zeros(grid.shape)
    pi.flat[here] = 0.55
    pi.flat[grid.cell_of(32.5, 2.5)] = 0.45
    mapper.set(pi)
    mission = Mission(grid, mapper, PlanningConfig(), NEVER)
    visited = fly(mission, Vehicle(*grid.centre(here)), ticks=30, odour=lambda t: True)
    assert beyond in visited


def test_an_estimate_inside_an_obstacle_is_probed_upflow_beyond_it() -> None:
    # odour met at the wall's downflow face, from a plume that crosses the wall, puts the estimate
    # inside it; the nearest free cells beside the wall tell nothing about it, so the mission
    # looks on the estimate's line just upflow of the wall, where a source beyond it would be met
    grid = Grid(0.0, 100.0, -50.0, 50.0, columns=20, rows=20, obstacles=((40.0, -5.0, 60.0, 5.0),))
    inside = grid.cell_of(52.5, 2.5)
    beyond = grid.cell_of(37.5, 2.5)
    assert grid.obstacle_mask.flat[inside]
    mapper = ScriptedMapper(grid)
    mapper.peak_at(inside)
    mission = Mission(grid, mapper, PlanningConfig(), NEVER)
    beside = Vehicle(52.5, 7.5)  # beside the wall, the free cell nearest the estimate
    visited = fly(mission, beside, ticks=40, odour=lambda t: t == 0)
    assert beyond in visited


def test_a_lost_vehicle_beside_an_obstacle_flies_on_to_the_estimate() -> None:
    # the wang scenarios' obstacle ends at x = 56.25, a cell centre; the vehicle loses the plume
    # just past it and flies round it toward the estimate instead of holding
    grid = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25, obstacles=((36.25, 0.25, 56.25, 7.75),))
    mapper = ScriptedMapper(grid)
    goal = grid.cell_of(20.0, 4.0)
    mapper.peak_at(goal)
    planning = PAPERS_PLANNING.model_copy(update={"lost_after_s": 2.0})
    mission = Mission(grid, mapper, planning, NEVER)
    vehicle = Vehicle(56.4, 10.5)
    states = set()
    for t in range(60):
        out = mission.step(Observation(float(t), vehicle.x, vehicle.y, 1.0, 0.0, t == 0), vehicle.state)
        states.add(mission.state)
        if out.waypoints is not None:
            for w in out.waypoints:
                assert_safe_waypoint(grid, w)
        vehicle.follow(out.waypoints)
        vehicle.move()
    assert MissionState.LOST in states
    assert math.dist((vehicle.x, vehicle.y), grid.centre(goal)) < 3.0


def start_check() -> tuple[ScriptedMapper, Mission, Vehicle, MissionOutput]:
    """A map sure of SOURCE, a mission with a 6 m check 3 m upflow, and the first tick: odour at
    the estimate's centre, where the vehicle is (the rule fires there)."""
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.9)
    mission = mission_with(mapper, probability=0.8, check_width_m=6.0, check_upflow_m=3.0)
    sx, sy = AREA.centre(SOURCE)
    vehicle = Vehicle(sx, sy)
    out = mission.step(Observation(0.0, sx, sy, 1.0, 0.0, True), vehicle.state)
    return mapper, mission, vehicle, out


def fly_dry_until_declared(
    mission: Mission, vehicle: Vehicle, out: MissionOutput, times: range
) -> tuple[MissionOutput, list[tuple[float, float]]]:
    """Fly the waypoints one per tick with no odour but on the estimate's line 1.5 m downflow of
    SOURCE's centre, where its check comes back to after its pass (a source's plume is there),
    until a declaration (or ``times`` run out); returns the last output and the points visited."""
    sx, sy = AREA.centre(SOURCE)
    visited = []
    for t in times:
        vehicle.follow(out.waypoints)
        vehicle.move()
        visited.append((vehicle.x, vehicle.y))
        back = (vehicle.x, vehicle.y) == (sx + 1.5, sy)
        out = mission.step(Observation(float(t), vehicle.x, vehicle.y, 1.0, 0.0, back), vehicle.state)
        if out.state is MissionState.DECLARED:
            break
    return out, visited


def test_the_upflow_check_crosses_the_flow_upflow_of_the_estimate_before_declaring() -> None:
    _, mission, vehicle, out = start_check()
    sx, sy = AREA.centre(SOURCE)
    assert out.state is MissionState.TRACE  # the rule fires, but the check comes first
    assert mission.checking
    assert out.waypoints is not None
    out, visited = fly_dry_until_declared(mission, vehicle, out, range(1, 10))
    assert out.state is MissionState.DECLARED
    # flow East: 3 m West of the centre, 6 m to one side, then the other, then back to the
    # estimate's line (a second crossing of it), then 1.5 m downflow of the centre, where odour
    # comes back: declared there
    assert visited == [(sx - 3.0, sy + 6.0), (sx - 3.0, sy - 6.0), (sx - 3.0, sy), (sx + 1.5, sy)]
    (declared,) = out.events
    assert isinstance(declared, SourceDeclared)
    assert (declared.x, declared.y) == (sx, sy)
    assert declared.check is CrossCheck.FLOWN
    assert not mission.checking  # flown: the check is over


def test_odour_upflow_of_the_estimate_calls_the_check_off() -> None:
    _, mission, vehicle, out = start_check()
    sx, sy = AREA.centre(SOURCE)
    vehicle.follow(out.waypoints)
    vehicle.move()  # on the check's first turning point, 3 m upflow
    assert (vehicle.x, vehicle.y) == (sx - 3.0, sy + 6.0)
    out = mission.step(Observation(1.0, vehicle.x, vehicle.y, 1.0, 0.0, True), vehicle.state)
    # odour 3 m upflow: not declared; the rule fires again at once (the scripted map does not
    # move), so a new check starts from here, and it must be flown whole before a declaration
    assert out.state is MissionState.TRACE
    assert out.events == ()
    out, visited = fly_dry_until_declared(mission, vehicle, out, range(2, 20))
    assert out.state is MissionState.DECLARED
    assert visited[-2:] == [(sx - 3.0, sy), (sx + 1.5, sy)]  # the new check's end, then odour at the cell


def test_a_cell_whose_odour_does_not_come_back_after_the_check_is_not_declared() -> None:
    # the end of a plume swung aside: the check's pass meets no odour upflow, and none comes back
    # to the cell either, so the check is called off (and the rule, firing again on the scripted
    # map, starts a new one)
    _, mission, vehicle, out = start_check()
    sx, sy = AREA.centre(SOURCE)
    called_off = 4 + int(RESMELL_WAIT_S) + 1  # the pass (3 ticks), the way back, then the wait
    for t in range(1, called_off + 1):
        vehicle.follow(out.waypoints)
        vehicle.move()
        out = mission.step(Observation(float(t), vehicle.x, vehicle.y, 1.0, 0.0, False), vehicle.state)
        assert out.state is not MissionState.DECLARED
    assert (vehicle.x, vehicle.y) == (sx + 1.5, sy)  # it waited where the check came back to
    assert out.waypoints is not None
    first = out.waypoints[0]
    assert (first.x, first.y) == (sx - 3.0, sy + 6.0)  # a new check from its first turning point


def test_a_snapshot_with_the_old_checks_tally_is_restored_without_it() -> None:
    # before step 39 of docs/search-steps.md the snapshot kept the checks' tally
    # ("check_passes"); a service restarted on such a snapshot ignores it
    mapper, mission, vehicle, _ = start_check()
    sx, sy = AREA.centre(SOURCE)
    state = json.loads(json.dumps(mission.save_state()))  # as the snapshot stores it
    assert "check_passes" not in state

    def dry_ticks_to_declare(saved: dict[str, object]) -> int:
        restarted = mission_with(mapper, probability=0.8, check_width_m=6.0, check_upflow_m=3.0)
        restarted.restore_state(saved)
        here = Vehicle(vehicle.x, vehicle.y)
        first = restarted.step(Observation(2.0, here.x, here.y, 1.0, 0.0, False), here.state)
        done, visited = fly_dry_until_declared(restarted, here, first, range(3, 30))
        assert done.state is MissionState.DECLARED
        return len(visited)

    old = {**state, "check_passes": [[sx, sy, -1, sx - 3.0, sy + 6.0]]}
    assert dry_ticks_to_declare(old) == dry_ticks_to_declare(state)


def endurance_mission(mapper: SourceMapper, endurance_s: float) -> Mission:
    """A mission with a 2 m upflow pass, a 6 m check 3 m upflow, the rule at 0.8, and
    ``endurance_s`` of endurance."""
    planning = PAPERS_PLANNING.model_copy(update={"lost_after_s": 10.0})
    decl = PAPERS_DECLARATION.model_copy(
        update={"probability": 0.8, "upflow_pass_m": 2.0, "check_width_m": 6.0, "check_upflow_m": 3.0}
    )
    return Mission(AREA, mapper, planning, decl, endurance_s=endurance_s, tick_s=1.0)


def fly_until(
    mission: Mission,
    vehicle: Vehicle,
    times: range,
    odour: Callable[[int, Vehicle], bool] = lambda t, v: False,
) -> list[MissionOutput]:
    """From SOURCE's centre with odour at t = 0, fly the waypoints one per tick (``odour`` says
    when a tick smells); the outputs of each tick from t = 0."""
    sx, sy = AREA.centre(SOURCE)
    out = mission.step(Observation(0.0, sx, sy, 1.0, 0.0, True), vehicle.state)
    outs = [out]
    for t in times:
        vehicle.follow(out.waypoints)
        vehicle.move()
        out = mission.step(
            Observation(float(t), vehicle.x, vehicle.y, 1.0, 0.0, odour(t, vehicle)), vehicle.state
        )
        outs.append(out)
    return outs


def test_the_last_tick_of_the_endurance_names_an_estimate_the_map_is_sure_of() -> None:
    # the upflow pass is made (t = 1) and the rule's check flown, but no odour comes back before
    # the endurance runs out: it began a tick before the first one (t = -1), so the tick at 7 is
    # the last to end within 8 s, and names the estimate on the map's mass alone
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.9)
    mission = endurance_mission(mapper, endurance_s=8.0)
    sx, sy = AREA.centre(SOURCE)
    outs = fly_until(mission, Vehicle(sx, sy), range(1, 8))
    assert mission.save_state()["started_s"] == -1.0
    assert all(o.state is not MissionState.DECLARED for o in outs[:-1])
    assert outs[-1].state is MissionState.DECLARED
    (declared,) = outs[-1].events
    assert isinstance(declared, SourceDeclared)
    assert declared.check is CrossCheck.ENDURANCE
    assert (declared.time_s, declared.x, declared.y) == (7.0, sx, sy)
    assert declared.mass == pytest.approx(0.9)  # within 3 m of its centre on 5 m cells: the cell alone


def test_the_endurance_names_nothing_unsure_unpassed_or_with_odour_upflow() -> None:
    sx, sy = AREA.centre(SOURCE)
    # unsure: 0.5 of the map at the estimate, below declaration.final_probability (0.8)
    unsure = ScriptedMapper(AREA)
    unsure.peak_at(SOURCE, 0.5)
    outs = fly_until(endurance_mission(unsure, endurance_s=8.0), Vehicle(sx, sy), range(1, 12))
    assert all(o.state is not MissionState.DECLARED for o in outs)
    # odour 3 m upflow of the estimate (the check's first leg) since it became the estimate
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.9)
    mission = endurance_mission(mapper, endurance_s=8.0)
    outs = fly_until(
        mission, Vehicle(sx, sy), range(1, 12), odour=lambda t, v: v.x <= sx - 2.0 and abs(v.y - sy) < 1
    )
    assert all(o.state is not MissionState.DECLARED for o in outs)
    # the upflow pass not made: the map is sure of a cell the vehicle never went upflow of
    far = AREA.cell_of(80.0, -40.0)
    sure = ScriptedMapper(AREA)
    sure.peak_at(far, 0.95)
    mission = endurance_mission(sure, endurance_s=3.0)
    for t in range(6):
        out = mission.step(Observation(float(t), sx, sy, 1.0, 0.0, t == 0), VehicleState(sx, sy))
        assert out.state is not MissionState.DECLARED
    # and without an endurance the sure map of the first test waits for its check
    mission = endurance_mission(mapper, endurance_s=0.0)
    assert all(
        o.state is not MissionState.DECLARED for o in fly_until(mission, Vehicle(sx, sy), range(1, 12))
    )


def test_the_endurance_is_counted_from_the_first_tick_across_a_restart() -> None:
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.9)
    sx, sy = AREA.centre(SOURCE)
    mission = endurance_mission(mapper, endurance_s=8.0)
    vehicle = Vehicle(sx, sy)
    outs = fly_until(mission, vehicle, range(1, 4))
    saved = json.loads(json.dumps(mission.save_state()))
    restarted = endurance_mission(mapper, endurance_s=8.0)
    restarted.restore_state(saved)
    out = outs[-1]
    for t in range(4, 8):
        vehicle.follow(out.waypoints)
        vehicle.move()
        out = restarted.step(Observation(float(t), vehicle.x, vehicle.y, 1.0, 0.0, False), vehicle.state)
        assert (out.state is MissionState.DECLARED) == (t == 7)


@pytest.mark.parametrize("back_to", [MissionState.FIND, MissionState.LOST])
def test_a_check_that_starts_outside_trace_is_flown_in_trace(back_to: MissionState) -> None:
    # the rule fires while the mission looks for the plume again after a lone contact (FIND) or
    # casts (LOST):
    # the check is flown while tracing, whatever the state's own pattern was
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.05)
    lone = 1 if back_to is MissionState.FIND else 0
    planning = PAPERS_PLANNING.model_copy(
        update={"lone_contact_hits": lone, "lone_contact_lost_after_s": 5.0, "lost_after_s": 5.0}
    )
    decl = PAPERS_DECLARATION.model_copy(
        update={"probability": 0.8, "check_width_m": 6.0, "check_upflow_m": 3.0}
    )
    mission = Mission(AREA, mapper, planning, decl)
    far = VehicleState(90.0, -40.0)
    assert mission.step(Observation(0.0, far.x, far.y, 1.0, 0.0, True), far).state is MissionState.TRACE
    assert mission.step(Observation(5.0, far.x, far.y, 1.0, 0.0, False), far).state is back_to
    mapper.peak_at(SOURCE, 0.9)
    sx, sy = AREA.centre(SOURCE)
    vehicle = Vehicle(sx, sy)
    out = mission.step(Observation(6.0, sx, sy, 1.0, 0.0, False), vehicle.state)
    assert out.state is MissionState.TRACE
    assert out.events == ()
    assert out.waypoints is not None
    assert (out.waypoints[0].x, out.waypoints[0].y) == (sx - 3.0, pytest.approx(sy + 6.0))
    out, visited = fly_dry_until_declared(mission, vehicle, out, range(7, 20))
    assert out.state is MissionState.DECLARED
    assert visited[:2] == [(sx - 3.0, sy + 6.0), (sx - 3.0, sy - 6.0)]
    (declared,) = out.events
    assert isinstance(declared, SourceDeclared)
    assert declared.check is CrossCheck.FLOWN


def test_odour_at_the_estimate_does_not_call_the_check_off() -> None:
    _, mission, vehicle, out = start_check()
    sx, sy = AREA.centre(SOURCE)
    first_leg = out.waypoints
    # odour 1 m downflow of the centre is what a source there gives: the check goes on
    out = mission.step(Observation(1.0, sx + 1.0, sy, 1.0, 0.0, True), vehicle.state)
    assert out.state is MissionState.TRACE
    assert out.waypoints is None or out.waypoints == first_leg


def test_a_new_estimate_calls_the_check_off() -> None:
    mapper, mission, vehicle, out = start_check()
    sx, sy = AREA.centre(SOURCE)
    vehicle.follow(out.waypoints)
    vehicle.move()
    other = AREA.cell_of(sx - 20.0, sy)
    mapper.peak_at(other, 0.9)  # the map now names a cell 20 m upflow
    for t in range(1, 4):
        vehicle.follow(out.waypoints)
        vehicle.move()
        out = mission.step(Observation(float(t), vehicle.x, vehicle.y, 1.0, 0.0, False), vehicle.state)
        assert out.state is MissionState.TRACE
        assert out.events == ()
    # on its way to the new estimate, not on the old check's legs
    assert vehicle.x < sx - 3.0


@pytest.mark.parametrize("pass_m", [0.0, 2.0])
def test_the_pass_probe_flies_until_the_upflow_pass_is_made(pass_m: float) -> None:
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.5)
    decl = DeclarationConfig(probability=1.0, upflow_pass_m=pass_m)  # the rule never fires
    mission = Mission(AREA, mapper, PlanningConfig(), decl)
    cx, cy = AREA.centre(SOURCE)  # (22.5, 2.5) on 5 m cells; flow East, so upflow is West
    flow = (1.0, 0.0)
    v = VehicleState(cx, cy)
    out = mission.step(Observation(0.0, v.x, v.y, *flow, True), v)  # at the estimate, in odour
    assert out.waypoints is not None
    point = Waypoint(cx - 2.25, cy)  # just beyond the 2 m pass
    # the cell probe: with half the map on the estimate and the rest spread thin, odour just
    # downflow of it (East) tells the most (ScriptedMapper's odour reaches East along a row)
    probe = AREA.centre(SOURCE + 1)
    if pass_m == 0.0:  # no pass to make: the cell probe at once
        assert (out.waypoints[-1].x, out.waypoints[-1].y) == probe
        return
    assert out.waypoints == (point,)
    v = VehicleState(cx - 1.5, cy)  # on the way, still in the estimated cell: keep going
    out = mission.step(Observation(1.0, v.x, v.y, *flow, False), v)
    assert out.waypoints is None
    assert out.state is MissionState.TRACE
    v = VehicleState(cx - 2.25, cy)  # there: the pass is made, so the cell probe takes over
    out = mission.step(Observation(2.0, v.x, v.y, *flow, False), v)
    assert out.waypoints is not None
    assert (out.waypoints[-1].x, out.waypoints[-1].y) == probe


def test_a_vehicle_that_stops_short_of_the_pass_probe_has_made_the_pass() -> None:
    # an autopilot holds still inside its acceptance radius (ArduPilot's WP_RADIUS): 0.45 m short
    # of the probe's point the vehicle is 0.2 m short of the pass and will go no further
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.5)
    decl = DeclarationConfig(probability=1.0, upflow_pass_m=2.0)
    mission = Mission(AREA, mapper, PlanningConfig(), decl)
    cx, cy = AREA.centre(SOURCE)
    flow = (1.0, 0.0)
    out = mission.step(Observation(0.0, cx, cy, *flow, True), VehicleState(cx, cy))
    assert out.waypoints == (Waypoint(cx - 2.25, cy),)
    v = VehicleState(cx - 1.8, cy)
    out = mission.step(Observation(1.0, v.x, v.y, *flow, False), v)
    assert out.waypoints is None  # still on its way, as far as the mission can tell
    out = mission.step(Observation(2.0, v.x, v.y, *flow, False), v)  # it has not moved: stopped
    assert out.waypoints is not None
    assert (out.waypoints[-1].x, out.waypoints[-1].y) == AREA.centre(SOURCE + 1)  # the cell probe


def odour_mission(hits: list[bool], turn: float = 0.0) -> MissionOutput:
    """A mission with the check: the vehicle held at SOURCE's centre with odour in the ticks
    ``hits`` says while the map is flat, then one more tick with odour in which the map becomes
    sure of SOURCE; that tick's output. The flow is (1, -turn) m/s until the last 40 ticks and
    (1, turn) in them (East with ``turn`` 0)."""
    mapper = ScriptedMapper(AREA)
    mapper.peak_at(SOURCE, 0.05)
    mission = mission_with(mapper, probability=0.8, check_width_m=6.0)
    sx, sy = AREA.centre(SOURCE)
    vehicle = VehicleState(sx, sy)
    n = len(hits)
    for t, hit in enumerate(hits):
        fy = turn if t > n - 40 else -turn
        out = mission.step(Observation(float(t), sx, sy, 1.0, fy, hit), vehicle)
        assert out.state is MissionState.TRACE
    mapper.peak_at(SOURCE, 0.9)
    return mission.step(Observation(float(n), sx, sy, 1.0, turn, True), vehicle)


@pytest.mark.parametrize(
    ("hits", "turn"),
    [
        # odour in 4 ticks of 5 for 50 s: steady, as a strong plume is far downflow of its source too
        ([t % 5 != 4 for t in range(50)], 0.0),
        ([t % 2 == 0 for t in range(50)], 0.0),  # odour in half the ticks: a plume swung over it
        ([t % 5 != 4 for t in range(30)], 0.0),  # odour first met only 30 s ago
        ([t % 5 != 4 for t in range(50)], 0.5),  # under a flow that has turned 53 degrees
    ],
)
def test_odour_at_the_estimate_however_steady_is_checked_first(hits: list[bool], turn: float) -> None:
    out = odour_mission(hits, turn)
    assert out.state is MissionState.TRACE
    assert out.events == ()
    assert out.waypoints is not None  # to the check's first turning point: 3 m upflow, 6 m aside
    sx, sy = AREA.centre(SOURCE)
    assert math.hypot(out.waypoints[0].x - sx, out.waypoints[0].y - sy) == pytest.approx(math.hypot(3.0, 6.0))


def two_peaks(mapper: ScriptedMapper, greatest: int, second: int) -> None:
    pi = np.full(AREA.shape, 1e-4)
    pi.flat[greatest], pi.flat[second] = 0.5, 0.2
    mapper.set(pi)


def test_the_trace_goal_stays_upflow_of_the_last_odour() -> None:
    """A map whose greatest cell lies 40 m downflow of the odour (where no observation reached) sends
    the trace to its greatest cell upflow of the odour instead, in trace and in lost."""
    mapper = ScriptedMapper(AREA)
    downflow, upflow = AREA.cell_of(90.0, 0.0), AREA.cell_of(30.0, 0.0)
    two_peaks(mapper, downflow, upflow)
    mission = mission_with(mapper, probability=1.0, hmm_probability=1.0, upflow_pass_m=1e9)
    v = VehicleState(50.0, 0.5)
    mission.step(Observation(0.0, v.x, v.y, 1.0, 0.0, False), v)
    out = mission.step(Observation(1.0, v.x, v.y, 1.0, 0.0, True), v)
    assert mission.state is MissionState.TRACE
    assert mission.mapper.estimate().cell == AREA.paper_number(downflow)  # the published estimate stays
    assert out.waypoints is not None
    assert (out.waypoints[-1].x, out.waypoints[-1].y) == AREA.centre(upflow)
    downflow, upflow = AREA.cell_of(95.0, -10.0), AREA.cell_of(35.0, 10.0)  # the misses moved both
    two_peaks(mapper, downflow, upflow)
    out = mission.step(Observation(12.0, v.x, v.y, 1.0, 0.0, False), v)
    assert mission.state is MissionState.LOST
    assert out.waypoints is not None
    assert (out.waypoints[-1].x, out.waypoints[-1].y) == AREA.centre(upflow)


def test_a_trace_goal_just_downflow_of_the_odour_is_kept() -> None:
    """Within TRACE_SLACK_M downflow of the odour (2.5 m here) the greatest cell is the goal."""
    mapper = ScriptedMapper(AREA)
    near, upflow = AREA.cell_of(52.0, 2.0), AREA.cell_of(30.0, 0.0)
    assert AREA.centre(near)[0] - 50.0 <= TRACE_SLACK_M
    two_peaks(mapper, near, upflow)
    mission = mission_with(mapper, probability=1.0, hmm_probability=1.0, upflow_pass_m=1e9)
    v = VehicleState(50.0, 0.5)
    mission.step(Observation(0.0, v.x, v.y, 1.0, 0.0, False), v)
    out = mission.step(Observation(1.0, v.x, v.y, 1.0, 0.0, True), v)
    assert out.waypoints is not None
    assert (out.waypoints[-1].x, out.waypoints[-1].y) == AREA.centre(near)
