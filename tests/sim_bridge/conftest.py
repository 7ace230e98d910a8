"""Fixtures for the sim_bridge tests: loopback ports and a plain-pymavlink companion computer."""

from __future__ import annotations

import asyncio
import socket
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import pytest

from service.edges.mavlink_dialect import dialect, mavutil
from sim_bridge.stub import StubOptions, VehicleStub
from sim_bridge.world import World

T = TypeVar("T")
MAV = dialect()


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


class Companion:
    """What a companion computer does with plain pymavlink: listen, command, wait for answers."""

    def __init__(self, conn: Any) -> None:
        self.conn = conn

    def recv(self, kind: str, timeout_s: float = 3.0, where: Callable[[Any], bool] | None = None) -> Any:
        """The next ``kind`` message from the vehicle (1/1) satisfying ``where``; fails on timeout."""
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            msg = self.conn.recv_match(type=kind, blocking=True, timeout=left)
            if msg is None:
                break
            if msg.get_srcSystem() == 1 and msg.get_srcComponent() == 1 and (where is None or where(msg)):
                return msg
        raise AssertionError(f"no {kind} within {timeout_s} s")

    def command(self, command: int, *params: float, target_system: int = 1) -> Any:
        """COMMAND_LONG and its COMMAND_ACK (retried like a GCS would, on a lossy link)."""
        padded = [*params, *[0.0] * (7 - len(params))]
        for _attempt in range(3):
            self.conn.mav.command_long_send(target_system, 1, command, 0, *padded)
            try:
                return self.recv("COMMAND_ACK", 1.0, where=lambda m: m.command == command)
            except AssertionError:
                continue
        raise AssertionError(f"no COMMAND_ACK for command {command}")

    def guided_and_armed(self, guided: int = 15) -> None:
        mode = self.command(MAV.MAV_CMD_DO_SET_MODE, MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, guided)
        arm = self.command(MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        assert (mode.result, arm.result) == (MAV.MAV_RESULT_ACCEPTED, MAV.MAV_RESULT_ACCEPTED)

    def goto_ned(self, north_m: float, east_m: float, type_mask: int = 3580) -> None:
        self.conn.mav.set_position_target_local_ned_send(
            0, 1, 1, MAV.MAV_FRAME_LOCAL_NED, type_mask, north_m, east_m, 0.0, 0, 0, 0, 0, 0, 0, 0, 0
        )

    def collect(self, duration_s: float) -> list[tuple[float, Any]]:
        """Every message from the vehicle for ``duration_s`` wall seconds, with arrival times."""
        out = []
        end = time.monotonic() + duration_s
        while (left := end - time.monotonic()) > 0:
            msg = self.conn.recv_match(blocking=True, timeout=left)
            if msg is not None and msg.get_srcSystem() == 1:
                out.append((time.monotonic(), msg))
        return out


@contextmanager
def _companion(url: str) -> Iterator[Companion]:
    conn = mavutil().mavlink_connection(url, source_system=1, source_component=191)
    try:
        yield Companion(conn)
    finally:
        conn.close()


@pytest.fixture
def fly() -> Callable[..., Any]:
    """``fly(world, conversation, **options)``: run a stub speaking udpout to a udpin companion and
    play ``conversation(companion, stub)`` against it in a worker thread; returns its result."""

    def run(world: World, conversation: Callable[[Companion, VehicleStub], T], **options: Any) -> T:
        port = free_udp_port()

        async def main() -> T:
            with _companion(f"udpin:127.0.0.1:{port}") as companion:
                stub_options = StubOptions(url=f"udpout:127.0.0.1:{port}", **options)
                async with VehicleStub(world, stub_options) as stub:
                    return await asyncio.to_thread(conversation, companion, stub)

        return asyncio.run(main())

    return run


@pytest.fixture
def udp_port() -> int:
    """A loopback UDP port that was free a moment ago."""
    return free_udp_port()


@pytest.fixture
def companion_at() -> Callable[[str], Any]:
    """A context manager factory for a plain pymavlink companion on any connection string."""
    return _companion
