"""The live Foxglove view: a WebSocket client speaking Foxglove's protocol (foxglove.websocket.v1)
subscribes and decodes what the service publishes, with Foxglove's own protobuf classes."""

import asyncio
import json
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from websockets.asyncio.client import ClientConnection, connect

from service.core.config import build_config
from service.core.errors import ConfigError
from service.core.grid import Grid
from service.core.mapping.mapper import Estimate
from service.core.observation import Observation
from service.edges.foxglove_live import LiveView, parse_listen
from service.edges.foxglove_scene import SCHEMAS as SCENE_SCHEMAS
from service.edges.foxglove_scene import VEHICLE_TOPIC, SceneBuilder
from service.edges.grid_message import decode_grid
from service.edges.recorder import SLIM_TOPIC, Recorder
from service.tools.sim import closed_loop, free_port
from sim_bridge.scenarios import load_scenario

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
"""foxglove-sdk 0.30 accepts only foxglove.sdk.v1, the successor of foxglove.websocket.v1 with the
same advertise / subscribe / message-data frames; the client offers both, as Foxglove's app does."""
MESSAGE_DATA = 0x01
TIMEOUT_S = 30.0
CONFIG = build_config({}, ["area.columns=12", "area.rows=8"])


class FoxgloveClient:
    """The client side of the protocol, as far as the tests need it: advertise, subscribe, data."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.channels: dict[str, dict[str, Any]] = {}
        self.subscriptions: dict[int, str] = {}

    async def wait_for_topics(self, topics: set[str]) -> None:
        while not topics <= set(self.channels):
            frame = await self.ws.recv()
            if isinstance(frame, str):
                self._on_text(json.loads(frame))

    def _on_text(self, message: dict[str, Any]) -> None:
        if message.get("op") == "advertise":
            self.channels.update({c["topic"]: c for c in message["channels"]})

    async def subscribe(self, topics: list[str]) -> None:
        subscriptions = []
        for number, topic in enumerate(topics, start=len(self.subscriptions) + 1):
            self.subscriptions[number] = topic
            subscriptions.append({"id": number, "channelId": self.channels[topic]["id"]})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    async def first_message_of_each(self, topics: set[str]) -> dict[str, bytes]:
        received: dict[str, bytes] = {}
        while not topics <= set(received):
            frame = await self.ws.recv()
            if isinstance(frame, str):
                self._on_text(json.loads(frame))
                continue
            opcode, subscription, _log_time_ns = struct.unpack_from("<BIQ", frame)
            assert opcode == MESSAGE_DATA
            received.setdefault(self.subscriptions[subscription], bytes(frame[13:]))
        return received


def obs_of(k: int) -> Observation:
    return Observation(time_s=float(k), x=10.0 + k, y=-5.0, flow_x=0.5, flow_y=0.1, detected=k % 2 == 0)


async def record_until_received(live: LiveView, directory: Path) -> tuple[dict[str, Any], dict[str, bytes]]:
    """Record ticks (mirrored live) until a client has one grid and one pose; its channels, payloads."""
    grid = Grid.from_config(CONFIG.area)
    scene = SceneBuilder(cell_m=1.0, declared_radius_m=3.0)
    with Recorder(CONFIG, directory=directory, mirror=live) as rec:
        async with connect(f"ws://127.0.0.1:{live.port}", subprotocols=SUBPROTOCOLS) as ws:  # type: ignore[arg-type]
            assert ws.subprotocol in SUBPROTOCOLS
            client = FoxgloveClient(ws)
            await asyncio.wait_for(client.wait_for_topics({SLIM_TOPIC, VEHICLE_TOPIC}), TIMEOUT_S)
            await client.subscribe([SLIM_TOPIC, VEHICLE_TOPIC])
            wanted = asyncio.create_task(client.first_message_of_each({SLIM_TOPIC, VEHICLE_TOPIC}))
            k = 0
            # the server handles the subscription on its own thread: tick until the data arrives
            while not wanted.done() and k < 1000:
                k += 1
                slim = np.full(grid.shape, k, dtype=float)
                estimate = Estimate(cell=1, x=0.5, y=0.5, probability=0.5, entropy=1.0)
                rec.tick(obs_of(k), slim, slim, estimate=estimate, state="search")
                rec.write_messages(scene.tick(obs_of(k), 0.0, estimate=estimate, state="search"))
                await asyncio.wait([wanted], timeout=0.02)
            return client.channels, await asyncio.wait_for(wanted, TIMEOUT_S)


def test_a_client_subscribes_to_the_map_and_the_pose_and_decodes_them(tmp_path: Path) -> None:
    with LiveView("127.0.0.1:0") as live:
        channels, payloads = asyncio.run(record_until_received(live, tmp_path))
    # the channels are advertised with the recording's schemas
    slim = channels[SLIM_TOPIC]
    assert (slim["encoding"], slim["schemaName"]) == ("protobuf", "foxglove.Grid")
    assert channels[VEHICLE_TOPIC]["schemaName"] == "foxglove.PoseInFrame"
    assert set(SCENE_SCHEMAS) <= set(channels)
    grid = decode_grid(payloads[SLIM_TOPIC])
    assert grid.shape == (8, 12)
    k = int(grid[0, 0])
    assert np.all(grid == k)
    pose = PoseInFrame.FromString(payloads[VEHICLE_TOPIC])
    assert pose.frame_id == "map"
    assert pose.pose.position.y == -5.0


def test_the_server_is_stopped_on_exit() -> None:
    with LiveView("127.0.0.1:0") as live:
        port = live.port
    # the SDK closes its listener on its own thread: allow it a moment on a loaded machine
    deadline = time.monotonic() + 5.0
    while True:
        with socket.socket() as sock:
            refused = sock.connect_ex(("127.0.0.1", port)) != 0
        if refused or time.monotonic() > deadline:
            break
        time.sleep(0.05)
    assert refused


def test_a_busy_port_is_a_config_error_naming_the_key() -> None:
    with LiveView("127.0.0.1:0") as live, pytest.raises(ConfigError, match=r"foxglove\.listen"):
        LiveView(f"127.0.0.1:{live.port}").__enter__()


@pytest.mark.parametrize("listen", ["8765", "host:", ":8765", "host:port"])
def test_a_malformed_listen_address_names_the_key(listen: str) -> None:
    with pytest.raises(ConfigError, match=r"foxglove\.listen"):
        parse_listen(listen)


@pytest.mark.sim
def test_a_client_watches_a_simulated_mission_live(tmp_path: Path) -> None:
    port = free_port(socket.SOCK_STREAM)
    scenario = load_scenario("wang-laminar", [f'foxglove.listen="127.0.0.1:{port}"'])

    async def watch() -> dict[str, bytes]:
        wanted = {SLIM_TOPIC, VEHICLE_TOPIC}
        async with (
            closed_loop(scenario, 1, speed=10.0, recorder_dir=str(tmp_path)) as loop,
            connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS) as ws,  # type: ignore[arg-type]
        ):
            edges = loop.service.edges  # the live view is one of the service's edges
            assert edges is not None
            assert edges.live is not None
            assert edges.live.port == port
            client = FoxgloveClient(ws)
            await asyncio.wait_for(client.wait_for_topics(wanted), TIMEOUT_S)
            await client.subscribe(sorted(wanted))
            return await asyncio.wait_for(client.first_message_of_each(wanted), TIMEOUT_S)

    payloads = asyncio.run(watch())
    assert decode_grid(payloads[SLIM_TOPIC]).shape == scenario.grid.shape
    pose = PoseInFrame.FromString(payloads[VEHICLE_TOPIC])
    assert scenario.grid.x_min <= pose.pose.position.x <= scenario.grid.x_max
    with socket.socket() as sock:  # the service stopped its server with the mission
        assert sock.connect_ex(("127.0.0.1", port)) != 0


def test_the_view_is_off_by_default_and_its_key_is_checked_with_the_configuration() -> None:
    assert build_config({}).foxglove.listen == ""
    assert build_config({}, ['foxglove.listen="[::1]:8765"']).foxglove.listen == "[::1]:8765"
    for bad in ('"nohost"', '"127.0.0.1:70000"', "8765"):
        with pytest.raises(ConfigError, match=r"foxglove\.listen"):
            build_config({}, [f"foxglove.listen={bad}"])
    with pytest.raises(ConfigError, match=r"foxglove\.port: unknown key"):
        build_config({"foxglove": {"port": 8765}})


def test_the_service_does_not_load_the_sdk_or_matplotlib_while_the_view_is_off() -> None:
    code = (
        "import sys, service.cli, service.app.service; "
        "print('foxglove' in sys.modules, 'matplotlib' in sys.modules)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.split() == ["False", "False"]
