"""Vehicle kinematics: constant speed, a turn-rate limit, heading control toward a target.

Seed pomdp-astar §III-B: the vehicle moves at a constant speed and steers toward the target
heading theta = atan2(Y_t - Y_c, X_t - X_c) (eq. 10, taken with the quadrant-correct atan2),
turning by at most ``max_turn_rate_dps`` to cancel the heading error epsilon = phi - theta.
Like an ArduPilot rover (WP_PIVOT_ANGLE), it turns on the spot when the error exceeds
``pivot_angle_deg``; without that a target inside the turning circle would be orbited forever.
An AUV cannot turn on the spot: it keeps way on and slows in a turn instead (``slows_to_turn``:
surge speed scaled by the cosine of the heading error, at least a quarter of cruise), which keeps
its turning circle small enough to reach a waypoint beside it.
Obstacles block motion: a step that would enter one slides along it or stops.

Headings are in the map frame: radians counter-clockwise from East (x).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from service.core.errors import ConfigError
from service.core.grid import Rectangle

_LEAST_TURN_SPEED = 0.25
"""The least share of cruise speed an AUV keeps in a turn (it needs way on to steer)."""


@dataclass(frozen=True)
class VehicleParams:
    speed_mps: float = 1.0
    """Constant cruise speed (the papers use 1 and 2 m/s)."""
    max_turn_rate_dps: float = 90.0
    """Turn-rate limit, degrees per second."""
    pivot_angle_deg: float = 60.0
    """Heading errors above this are turned on the spot (ArduPilot Rover's WP_PIVOT_ANGLE)."""
    slows_to_turn: bool = False
    """AUV-like: surge speed x max(cos(heading error), 1/4) instead of full speed."""
    arrival_radius_m: float = 0.0
    """A target this close counts as reached and the vehicle stops short of it (ArduPilot's
    WP_RADIUS, 2 m on Rover by default); 0: it drives onto the target."""
    accel_mps2: float = 0.0
    """Acceleration and braking limit: the vehicle speeds up at most this fast, brakes so as to stop
    at its target (ArduPilot's position controller, ATC_ACCEL_MAX: 1 m/s/s on Rover), and brakes to
    a stop before it turns on the spot; 0: its speed changes at once."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.speed_mps) and self.speed_mps > 0):
            raise ConfigError(f"vehicle speed_mps must be positive, got {self.speed_mps}")
        if not (math.isfinite(self.max_turn_rate_dps) and self.max_turn_rate_dps > 0):
            raise ConfigError(f"vehicle max_turn_rate_dps must be positive, got {self.max_turn_rate_dps}")
        if not 0 < self.pivot_angle_deg <= 180:
            raise ConfigError(f"vehicle pivot_angle_deg must be in (0, 180], got {self.pivot_angle_deg}")
        if not (math.isfinite(self.arrival_radius_m) and self.arrival_radius_m >= 0):
            raise ConfigError(f"vehicle arrival_radius_m must be >= 0, got {self.arrival_radius_m}")
        if not (math.isfinite(self.accel_mps2) and self.accel_mps2 >= 0):
            raise ConfigError(f"vehicle accel_mps2 must be >= 0, got {self.accel_mps2}")


@dataclass(frozen=True)
class VehicleState:
    x_m: float
    y_m: float
    heading_rad: float
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    blocked: bool = False
    """True when the last step was stopped or deflected by an obstacle."""


def wrap_angle(angle_rad: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def segment_hits(x0: float, y0: float, x1: float, y1: float, obstacles: tuple[Rectangle, ...]) -> bool:
    """True when the segment (x0, y0) -> (x1, y1) touches any closed obstacle rectangle."""
    if not obstacles:
        return False
    box = np.asarray(obstacles, dtype=float)
    dx, dy = x1 - x0, y1 - y0
    # Liang-Barsky clipping against every rectangle at once: p t <= q for the four slabs
    p = np.array([-dx, dx, -dy, dy])
    q = np.column_stack([x0 - box[:, 0], box[:, 2] - x0, y0 - box[:, 1], box[:, 3] - y0])
    t_lo = np.zeros(len(box))
    t_hi = np.ones(len(box))
    for k in range(4):
        if p[k] == 0.0:
            t_hi = np.where(q[:, k] < 0, -1.0, t_hi)  # parallel to the slab and outside it
            continue
        t = q[:, k] / p[k]
        if p[k] < 0:
            t_lo = np.maximum(t_lo, t)
        else:
            t_hi = np.minimum(t_hi, t)
    return bool(np.any(t_lo <= t_hi))


def step(
    state: VehicleState,
    target_m: tuple[float, float] | None,
    params: VehicleParams,
    dt_s: float,
    obstacles: tuple[Rectangle, ...] = (),
    speed_mps: float | None = None,
) -> VehicleState:
    """One kinematic step of ``dt_s`` toward ``target_m``; no target means stay put. ``speed_mps``:
    the speed asked of the autopilot (MAV_CMD_DO_CHANGE_SPEED), below the cruise speed; None: the
    cruise speed. A vehicle that brakes (``accel_mps2``) sheds speed no faster than that."""
    still = replace(state, vx_mps=0.0, vy_mps=0.0, blocked=False)
    if target_m is None:
        return still
    dx, dy = target_m[0] - state.x_m, target_m[1] - state.y_m
    distance = math.hypot(dx, dy)
    if distance < 1e-6:  # there (up to rounding): sit exactly on the target
        return replace(still, x_m=target_m[0], y_m=target_m[1])
    if distance <= params.arrival_radius_m:
        return still
    theta = math.atan2(dy, dx)  # eq. 10, target heading
    error = wrap_angle(state.heading_rad - theta)  # epsilon = phi - theta
    max_turn = math.radians(params.max_turn_rate_dps) * dt_s
    heading = wrap_angle(state.heading_rad - max(-max_turn, min(max_turn, error)))
    accel = params.accel_mps2
    moving = math.hypot(state.vx_mps, state.vy_mps) if accel > 0.0 else 0.0
    pivot = abs(error) > math.radians(params.pivot_angle_deg)
    if pivot and accel > 0.0:
        # brake to a stop on the current heading before turning on the spot
        speed = max(moving - accel * dt_s, 0.0)
        if speed == 0.0:
            return replace(still, heading_rad=heading)
        heading, reach = state.heading_rad, speed * dt_s
    elif pivot:
        return replace(still, heading_rad=heading)
    else:
        cruise = params.speed_mps if speed_mps is None else min(params.speed_mps, speed_mps)
        if accel > 0.0 and moving > cruise:
            cruise = max(cruise, moving - accel * dt_s)
        reach = cruise * dt_s
        if params.slows_to_turn:
            reach *= max(math.cos(error), _LEAST_TURN_SPEED)
        if accel > 0.0:
            # speed up at most accel, and no faster than stops at the target: v^2 = 2 a d
            braking = math.sqrt(2.0 * accel * max(distance - params.arrival_radius_m, 0.0))
            reach = min(reach, (moving + accel * dt_s) * dt_s, braking * dt_s)
    if distance <= reach:
        moves = [(target_m[0], target_m[1])]
    else:
        ex, ey = reach * math.cos(heading), reach * math.sin(heading)
        # full step first, then slide along an obstacle edge (x only, y only)
        moves = [(state.x_m + ex, state.y_m + ey), (state.x_m + ex, state.y_m), (state.x_m, state.y_m + ey)]
    for k, (x, y) in enumerate(moves):
        if not segment_hits(state.x_m, state.y_m, x, y, obstacles):
            return VehicleState(
                x_m=x,
                y_m=y,
                heading_rad=heading,
                vx_mps=(x - state.x_m) / dt_s,
                vy_mps=(y - state.y_m) / dt_s,
                blocked=k > 0,
            )
    return replace(still, heading_rad=heading, blocked=True)
