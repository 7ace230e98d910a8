"""ArduPilot Rover SITL for the ``sitl`` tests: started per module in a scratch directory, always stopped.

Needs ``ARDUPILOT_SITL`` (the ``ardurover`` binary of a SITL build) and ``ARDUPILOT_DIR`` (the
source tree, for ``Tools/autotest/default_params/rover.parm``); without them every test here is
skipped with that reason. Run with ``pytest -m sitl tests/sitl``.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from service.edges.mavlink_dialect import dialect, mavutil

MAV = dialect()
REPO = Path(__file__).resolve().parents[2]
ROVER_GUIDED, ROVER_HOLD = 15, 4
BOOT_TIMEOUT_S = 60.0
ARM_TIMEOUT_S = 150.0
"""The EKF uses GPS only after about 40 s; arming is refused until then."""


def sitl_paths() -> tuple[Path, Path]:
    binary, source = os.environ.get("ARDUPILOT_SITL"), os.environ.get("ARDUPILOT_DIR")
    if not binary or not source:
        pytest.skip("ArduPilot SITL not available: set ARDUPILOT_SITL (ardurover binary) and ARDUPILOT_DIR")
    if not os.access(binary, os.X_OK):
        pytest.skip(f"ARDUPILOT_SITL={binary} is not an executable")
    defaults = Path(source) / "Tools" / "autotest" / "default_params" / "rover.parm"
    if not defaults.is_file():
        pytest.skip(f"ARDUPILOT_DIR={source} has no Tools/autotest/default_params/rover.parm")
    return Path(binary), defaults


def tcp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


def free_instance() -> int:
    """A SITL instance number whose ports (5760 + 10 I .. 5763 + 10 I) are free."""
    for instance in range(20, 60):
        if all(tcp_free(5760 + 10 * instance + k) for k in (0, 2, 3)):
            return instance
    raise RuntimeError("no free SITL instance ports")


def wait_until(condition: Callable[[], bool], timeout_s: float, what: str, poll_s: float = 0.1) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        time.sleep(poll_s)


@dataclass
class Pilot:
    """A ground station on SITL's first port, speaking plain pymavlink from the test's thread."""

    conn: Any

    def recv(self, kind: str, timeout_s: float = 5.0, where: Callable[[Any], bool] | None = None) -> Any:
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            msg = self.conn.recv_match(type=kind, blocking=True, timeout=left)
            if msg is not None and msg.get_srcComponent() == 1 and (where is None or where(msg)):
                return msg
        raise AssertionError(f"no {kind} from the autopilot within {timeout_s} s")

    def command(self, command: int, *params: float) -> int:
        padded = [*params, *[0.0] * (7 - len(params))]
        for _ in range(3):
            self.conn.mav.command_long_send(1, 1, command, 0, *padded)
            try:
                return int(self.recv("COMMAND_ACK", 2.0, where=lambda m: m.command == command).result)
            except AssertionError:
                continue
        raise AssertionError(f"no COMMAND_ACK for {command}")

    def mode(self, custom_mode: int) -> None:
        result = self.command(MAV.MAV_CMD_DO_SET_MODE, MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode)
        assert result == MAV.MAV_RESULT_ACCEPTED, f"mode {custom_mode} refused ({result})"
        self.recv("HEARTBEAT", 5.0, where=lambda m: m.custom_mode == custom_mode)

    def arm(self) -> None:
        """Arm as soon as the autopilot accepts it (it refuses until the EKF uses GPS)."""
        deadline = time.monotonic() + ARM_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.command(MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1) == MAV.MAV_RESULT_ACCEPTED:
                self.recv("HEARTBEAT", 5.0, where=lambda m: m.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED)
                return
            self.recv("HEARTBEAT", 5.0)  # about a second: the autopilot's own pace
        raise AssertionError(f"not armable within {ARM_TIMEOUT_S:.0f} s")

    def stream(self, message_id: int, rate_hz: float) -> None:
        self.command(MAV.MAV_CMD_SET_MESSAGE_INTERVAL, message_id, 1e6 / rate_hz)

    def position(self) -> tuple[float, float]:
        """Map frame (x East, y North) from the next LOCAL_POSITION_NED."""
        msg = self.recv("LOCAL_POSITION_NED", 3.0)
        return float(msg.y), float(msg.x)

    def param(self, name: str, value: float) -> None:
        for _ in range(3):
            self.conn.mav.param_set_send(1, 1, name.encode(), value, MAV.MAV_PARAM_TYPE_REAL32)
            try:
                self.recv("PARAM_VALUE", 2.0, where=lambda m: m.param_id == name)
                return
            except AssertionError:
                continue
        raise AssertionError(f"parameter {name} not acknowledged")

    def drive_to(self, x_m: float, y_m: float, tolerance_m: float = 1.5, timeout_s: float = 120.0) -> None:
        """In GUIDED and armed: position setpoints until the rover is within ``tolerance_m``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.conn.mav.set_position_target_local_ned_send(
                0, 1, 1, MAV.MAV_FRAME_LOCAL_NED, 3580, y_m, x_m, 0.0, 0, 0, 0, 0, 0, 0, 0, 0
            )
            px, py = self.position()
            if abs(px - x_m) <= tolerance_m and abs(py - y_m) <= tolerance_m:
                return
        raise AssertionError(f"did not reach ({x_m}, {y_m}) within {timeout_s:.0f} s")


@dataclass
class Sitl:
    instance: int
    workdir: Path
    pilot: Pilot

    @property
    def companion_port(self) -> int:
        """SERIAL1: where a companion computer on TELEM2 would be."""
        return 5762 + 10 * self.instance


@pytest.fixture(scope="module")
def sitl(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Sitl]:
    binary, rover_defaults = sitl_paths()
    workdir = tmp_path_factory.mktemp("sitl")
    (workdir / "scripts").mkdir()
    shutil.copy(REPO / "config" / "ardupilot" / "chem_sensor.lua", workdir / "scripts")
    instance = free_instance()
    # a rover sends WIND only with a windvane: SITL's simulated one, blowing as wang-laminar's flow
    # (1 m/s from the West); the bridge then injects CHEM only (BridgeOptions.wind_rate_hz = 0)
    wind = workdir / "wind.parm"
    wind.write_text("WNDVN_TYPE 10\nSIM_WIND_SPD 1\nSIM_WIND_DIR 270\nSIM_WIND_TURB 0\n")
    defaults = f"{rover_defaults},{REPO / 'config' / 'ardupilot' / 'sitl.parm'},{wind}"
    log = (workdir / "sitl.log").open("wb")
    proc = subprocess.Popen(
        [str(binary), "--model", "rover", "--speedup", "1", "--instance", str(instance), "--wipe",
         "--defaults", defaults, "--home", "-35.363262,149.165237,584,0"],
        cwd=workdir, stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    conn: Any = None
    try:
        wait_until(lambda: not tcp_free(5760 + 10 * instance), BOOT_TIMEOUT_S, "SITL's port 5760")
        conn = mavutil().mavlink_connection(
            f"tcp:127.0.0.1:{5760 + 10 * instance}", source_system=255, source_component=190
        )
        pilot = Pilot(conn)
        pilot.recv("HEARTBEAT", BOOT_TIMEOUT_S)
        pilot.stream(MAV.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 5.0)
        yield Sitl(instance, workdir, pilot)
    finally:
        if conn is not None:
            conn.close()
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()
