"""Vehicle kinematics: constant speed, turn-rate limit, heading control (pomdp-astar §III-B), obstacles."""

from __future__ import annotations

import itertools
import math

import pytest

from service.core.errors import ConfigError
from sim_bridge.vehicle import VehicleParams, VehicleState, segment_hits, step, wrap_angle

EAST, NORTH, SOUTH = 0.0, math.pi / 2, -math.pi / 2


def drive(
    state: VehicleState,
    target: tuple[float, float],
    params: VehicleParams,
    steps: int,
    obstacles: tuple[tuple[float, float, float, float], ...] = (),
    dt_s: float = 0.1,
) -> list[VehicleState]:
    out = [state]
    for _ in range(steps):
        out.append(step(out[-1], target, params, dt_s, obstacles))
    return out


def test_straight_at_constant_speed_then_stops_on_the_target() -> None:
    params = VehicleParams(speed_mps=2.0)
    path = drive(VehicleState(0.0, 0.0, EAST), (10.0, 0.0), params, 60)
    moved = [math.dist((a.x_m, a.y_m), (b.x_m, b.y_m)) for a, b in itertools.pairwise(path)]
    arrived = next(k for k, s in enumerate(path) if (s.x_m, s.y_m) == (10.0, 0.0))
    assert arrived == pytest.approx(50, abs=1)  # 10 m at 2 m/s in 0.1 s steps
    assert moved[: arrived - 1] == pytest.approx([0.2] * (arrived - 1))
    assert all((s.x_m, s.y_m, s.vx_mps, s.vy_mps) == (10.0, 0.0, 0.0, 0.0) for s in path[arrived + 1 :])


def test_heading_turns_toward_eq_10_target_heading_at_the_rate_limit() -> None:
    # target to the north-west (second quadrant: atan2, not arctan) and a 30 deg/s limit
    params = VehicleParams(speed_mps=1.0, max_turn_rate_dps=30.0, pivot_angle_deg=180.0)
    path = drive(VehicleState(0.0, 0.0, EAST), (-100.0, 100.0), params, 100)
    turns = [abs(wrap_angle(b.heading_rad - a.heading_rad)) for a, b in itertools.pairwise(path)]
    assert max(turns) == pytest.approx(math.radians(3.0))  # 30 deg/s x 0.1 s
    theta = math.atan2(100.0 - path[-1].y_m, -100.0 - path[-1].x_m)
    assert path[-1].heading_rad == pytest.approx(theta, abs=1e-6)  # locked on
    assert all(math.hypot(s.vx_mps, s.vy_mps) == pytest.approx(1.0) for s in path[1:])  # constant speed


def test_pivots_on_the_spot_beyond_the_pivot_angle_so_close_targets_are_reached() -> None:
    # a target just behind, inside the turning circle of 2 m/s at 90 deg/s (r = 1.3 m)
    params = VehicleParams(speed_mps=2.0, max_turn_rate_dps=90.0, pivot_angle_deg=60.0)
    path = drive(VehicleState(0.0, 0.0, EAST), (-0.5, 0.3), params, 40)
    pivoting = [s for s in path[1:] if (s.x_m, s.y_m) == (0.0, 0.0)]
    assert len(pivoting) >= 10  # ~ (180 - 31 - 60) deg at 9 deg per step
    assert (path[-1].x_m, path[-1].y_m) == pytest.approx((-0.5, 0.3))


def test_no_target_means_stay_put() -> None:
    state = VehicleState(3.0, 4.0, NORTH, vx_mps=1.0)
    after = step(state, None, VehicleParams(), 0.1)
    assert (after.x_m, after.y_m, after.heading_rad, after.vx_mps) == (3.0, 4.0, NORTH, 0.0)


def test_obstacles_block_motion_and_the_vehicle_slides_along_them() -> None:
    wall = (-10.0, 5.0, 10.0, 6.0)  # a wall across the way north
    params = VehicleParams(speed_mps=1.0)
    path = drive(VehicleState(0.0, 0.0, NORTH), (2.0, 20.0), params, 300, obstacles=(wall,))
    assert all(not (wall[1] <= s.y_m <= wall[3] and wall[0] <= s.x_m <= wall[2]) for s in path)
    assert all(s.y_m < 5.0 for s in path)  # never through
    assert any(s.blocked for s in path)
    assert path[-1].x_m > 1.0  # pressed against the wall, it slid east along it


def test_segment_hits() -> None:
    box = ((0.0, 0.0, 1.0, 1.0),)
    assert segment_hits(-1.0, 0.5, 2.0, 0.5, box)  # straight through
    assert segment_hits(-1.0, -1.0, 0.0, 0.0, box)  # touches the corner
    assert not segment_hits(-1.0, 1.5, 2.0, 1.5, box)  # passes above
    assert not segment_hits(1.5, -1.0, 1.5, 2.0, box)
    assert segment_hits(0.5, 0.5, 0.5, 0.5, box)  # a point inside
    assert not segment_hits(-1.0, 0.5, 2.0, 0.5, ())


def test_bad_vehicle_parameters_are_refused() -> None:
    with pytest.raises(ConfigError):
        VehicleParams(speed_mps=0.0)
    with pytest.raises(ConfigError):
        VehicleParams(max_turn_rate_dps=-1.0)
    with pytest.raises(ConfigError):
        VehicleParams(pivot_angle_deg=0.0)


def test_an_arrival_radius_stops_the_vehicle_short_of_its_target_as_ardupilot_does() -> None:
    params = VehicleParams(speed_mps=1.0, arrival_radius_m=2.0)
    path = drive(VehicleState(0.0, 0.0, EAST), (10.0, 0.0), params, 150)
    assert 8.0 <= path[-1].x_m < 8.2  # stopped within 2 m, the step that got it there at most 0.1 m in
    near = drive(VehicleState(0.0, 0.0, EAST), (1.5, 0.0), params, 10)
    assert (near[-1].x_m, near[-1].y_m) == (0.0, 0.0)  # a target inside the radius is not driven to
    with pytest.raises(ConfigError):
        VehicleParams(arrival_radius_m=-1.0)


def test_an_accelerating_autopilot_speeds_up_brakes_onto_its_target_and_stops_before_a_pivot() -> None:
    # 2 m/s at 1 m/s/s: 2 s (2 m) to speed up, 8 s at speed, 2 s (2 m) to brake onto a target 20 m
    # away, against 10 s at once
    params = VehicleParams(speed_mps=2.0, accel_mps2=1.0)
    path = drive(VehicleState(0.0, 0.0, EAST), (20.0, 0.0), params, 200)
    arrived = next(k for k, s in enumerate(path) if s.x_m == 20.0)
    assert 11.8 <= arrived * 0.1 <= 12.6
    speeds = [math.hypot(s.vx_mps, s.vy_mps) for s in path]
    assert max(speeds) == pytest.approx(2.0)
    assert all(b - a <= 1.0 * 0.1 + 1e-9 for a, b in itertools.pairwise(speeds[: arrived - 1]))
    assert speeds[5] == pytest.approx(0.5)
    # a target behind a moving rover: it brakes along its heading, then turns on the spot
    moving = VehicleState(0.0, 0.0, EAST, vx_mps=2.0)
    back = drive(moving, (-10.0, 0.0), params, 30)
    assert back[15].heading_rad == EAST  # still braking, on its heading
    assert back[-1].x_m == pytest.approx(2.0**2 / 2.0, abs=0.15)  # v^2 / 2a on, then stopped
    assert back[-1].heading_rad != EAST
    with pytest.raises(ConfigError):
        VehicleParams(accel_mps2=-1.0)


def test_a_speed_asked_below_the_cruise_is_kept_and_reached_by_braking() -> None:
    # MAV_CMD_DO_CHANGE_SPEED: a rover cruising at 3 m/s asked for 2 m/s
    far = (100.0, 0.0)
    instant = step(VehicleState(0.0, 0.0, EAST), far, VehicleParams(speed_mps=3.0), 0.1, (), 2.0)
    assert instant.vx_mps == pytest.approx(2.0)
    faster = step(VehicleState(0.0, 0.0, EAST), far, VehicleParams(speed_mps=3.0), 0.1, (), 5.0)
    assert faster.vx_mps == pytest.approx(3.0)  # never faster than its cruise
    braking, state = VehicleParams(speed_mps=3.0, accel_mps2=1.0), VehicleState(0.0, 0.0, EAST, vx_mps=3.0)
    speeds = []
    for _ in range(15):
        state = step(state, far, braking, 0.1, (), 2.0)
        speeds.append(state.vx_mps)
    assert speeds[0] == pytest.approx(2.9)  # sheds 1 m/s/s
    assert speeds[9:] == pytest.approx([2.0] * 6)
