"""The simulated world: flow, plume, detector and vehicle stepped together in simulated time.

One ``step`` is ``dt_s`` seconds (10 Hz by default, the plume's step). Within a step the plume
and the vehicle move with the flow as it was at the start of the step (explicit Euler), then
the flow and the detector advance. Nothing here knows about wall-clock time or sockets.
"""

from __future__ import annotations

import math

from service.core.grid import Rectangle
from sim_bridge import vehicle as kinematics
from sim_bridge.detector import BinaryDetector
from sim_bridge.flow import FlowField, velocity_at
from sim_bridge.flow_sensor import FlowSensor, FlowSensorParams
from sim_bridge.navigation import Navigation, NavigationParams
from sim_bridge.plume import PuffPlume
from sim_bridge.vehicle import VehicleParams, VehicleState


class World:
    """Flow + plume + detector + one vehicle, advanced by ``step()``."""

    def __init__(
        self,
        *,
        flow: FlowField,
        plume: PuffPlume,
        detector: BinaryDetector,
        vehicle: VehicleState,
        vehicle_params: VehicleParams,
        obstacles: tuple[Rectangle, ...] = (),
        dt_s: float = 0.1,
        flow_sensor: FlowSensor | None = None,
        navigation: Navigation | None = None,
    ) -> None:
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"dt_s must be positive and finite, got {dt_s}")
        self.flow = flow
        self.plume = plume
        self.detector = detector
        self.vehicle = vehicle
        self.vehicle_params = vehicle_params
        self.obstacles = obstacles
        self.dt_s = dt_s
        self.flow_sensor = flow_sensor or FlowSensor(FlowSensorParams())
        self.navigation = navigation or Navigation(NavigationParams())
        self.target_m: tuple[float, float] | None = None
        """Where the vehicle is driving to; None: stay put."""
        self.driving = False
        """Whether the vehicle may move (the stub sets it: GUIDED and armed)."""
        self.speed_mps: float | None = None
        """The guided speed asked of the vehicle (MAV_CMD_DO_CHANGE_SPEED); None: its cruise speed.
        A faster speed than the cruise is not reached."""
        self.distance_m = 0.0
        """Odometer: the length of the vehicle's track so far."""
        self._steps = 0

    @property
    def time_s(self) -> float:
        """Simulated time since the world started."""
        return self._steps * self.dt_s

    def step(self) -> None:
        """Advance the world by one ``dt_s``."""
        dt = self.dt_s
        self.plume.step(dt, self.flow)
        target = self.target_m if self.driving else None
        east, north = self.navigation.error_m
        if target is not None and (east or north):  # the autopilot steers its belief onto the target
            target = (target[0] - east, target[1] - north)
        before = self.vehicle
        params = self.vehicle_params
        self.vehicle = kinematics.step(before, target, params, dt, self.obstacles, self.speed_mps)
        self.distance_m += math.hypot(self.vehicle.x_m - before.x_m, self.vehicle.y_m - before.y_m)
        self.flow.advance(dt)
        if self.detector.lags:
            self.detector.sense(self.concentration_at_vehicle(), dt)
        self.detector.advance(dt)
        self.navigation.advance(dt)
        self._steps += 1

    def run(self, duration_s: float) -> None:
        """Step until ``duration_s`` more seconds have passed (rounded to whole steps)."""
        for _ in range(round(duration_s / self.dt_s)):
            self.step()

    def position_reading(self) -> tuple[float, float]:
        """Where the autopilot believes the vehicle is (map frame, m): what it reports."""
        east, north = self.navigation.error_m
        return self.vehicle.x_m + east, self.vehicle.y_m + north

    def flow_at_vehicle(self) -> tuple[float, float]:
        """Flow (u_x East, u_y North), m/s toward, at the vehicle, as its flow sensor reports it."""
        return self.flow_sensor.read(*self.true_flow_at_vehicle())

    def true_flow_at_vehicle(self) -> tuple[float, float]:
        """The flow that really moves the plume at the vehicle (no sensor error)."""
        return velocity_at(self.flow, self.vehicle.x_m, self.vehicle.y_m)

    def concentration_at_vehicle(self) -> float:
        """True instantaneous concentration at the vehicle."""
        return float(self.plume.concentration(self.vehicle.x_m, self.vehicle.y_m)[0])

    def chem_reading(self) -> float:
        """What the vehicle's chemical sensor reports now (detector misses and false alarms applied)."""
        return self.detector.read(self.concentration_at_vehicle())
