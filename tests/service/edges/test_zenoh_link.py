"""Two Zenoh sessions on loopback: the service's link and a subscriber, multicast scouting off."""

import asyncio
import contextlib
import json
import socket
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import zenoh

from service.core.config import ZenohConfig
from service.core.errors import ConfigError, LinkError
from service.core.grid import Grid
from service.core.mapping.mapper import Estimate
from service.core.observation import Observation
from service.edges.grid_message import decode_grid
from service.edges.messages import ESTIMATE_KEYS, OBS_KEYS, PATH_KEYS
from service.edges.zenoh_link import ZenohLink, session_config

GRID = Grid(x_min=0.0, x_max=60.0, y_min=-20.0, y_max=15.0, columns=12, rows=7)  # n != m
VEHICLE = "rover-7"
NO_MULTICAST = {"scouting/multicast/enabled": False}
TIMEOUT_S = 10.0

README_SNIPPET = """
import zenoh
from service.edges.grid_message import decode_grid

with zenoh.open(zenoh.Config()) as session:  # peer mode: finds the vehicle by scouting
    subscriber = session.declare_subscriber("oslim/oslim-1/slim")
    for sample in subscriber:  # each new map, once a tick
        slim = decode_grid(sample.payload.to_bytes())  # numpy (rows, columns), row 0 = south
        print(slim.shape, float(slim.max()))
"""


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def link_config(port: int) -> ZenohConfig:
    return ZenohConfig(listen=[f"tcp/127.0.0.1:{port}"])


def peer_config(port: int) -> zenoh.Config:
    """A second peer that connects to the link only."""
    return session_config(ZenohConfig(connect=[f"tcp/127.0.0.1:{port}"]), NO_MULTICAST)


class Inbox:
    """Samples received by a subscriber callback (Zenoh thread), keyed by key expression."""

    def __init__(self) -> None:
        self.samples: dict[str, list[tuple[bytes, str]]] = {}
        self._changed = threading.Condition()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self._changed:
            entry = (sample.payload.to_bytes(), str(sample.encoding))
            self.samples.setdefault(str(sample.key_expr), []).append(entry)
            self._changed.notify_all()

    def wait_for(self, keys: set[str], publish: Callable[[], None]) -> None:
        """Publish until every key has arrived: declarations take a moment to propagate."""
        with self._changed:
            for _ in range(int(TIMEOUT_S / 0.05)):
                if keys <= set(self.samples):
                    return
                publish()
                self._changed.wait(0.05)
        raise AssertionError(f"nothing received on {keys - set(self.samples)} in {TIMEOUT_S} s")


ESTIMATE = Estimate(cell=47, x=27.5, y=-7.5, probability=0.125, entropy=3.25)
OBS = Observation(time_s=12.0, x=0.1 + 0.2, y=-1 / 3, flow_x=1e-300, flow_y=-0.5, detected=True)


def publish_all(link: ZenohLink, scale: float) -> None:
    slim = np.arange(GRID.size, dtype=np.float64).reshape(GRID.shape) * scale
    link.publish_maps(12.0, slim, slim[::-1] + 1.0)
    link.publish_estimate(12.0, "trace", ESTIMATE)
    link.publish_path(12.0, [(1.0, 2.0), (3.5, -4.25)])
    link.publish_obs(OBS)


def run(test: Callable[[ZenohLink, int], Any]) -> None:
    async def main() -> None:
        port = free_port()
        async with ZenohLink(link_config(port), VEHICLE, GRID, extra=NO_MULTICAST) as link:
            await asyncio.to_thread(test, link, port)

    asyncio.run(main())


def test_a_subscriber_decodes_slim_and_plume_into_the_same_arrays() -> None:
    slim = np.random.default_rng(3).random(GRID.shape)
    plume = slim**2

    def check(link: ZenohLink, port: int) -> None:
        inbox = Inbox()
        with zenoh.open(peer_config(port)) as session:
            session.declare_subscriber(f"oslim/{VEHICLE}/*", inbox)
            keys = {f"oslim/{VEHICLE}/slim", f"oslim/{VEHICLE}/plume"}
            inbox.wait_for(keys, lambda: link.publish_maps(5.0, slim, plume))
        for name, expected in (("slim", slim), ("plume", plume)):
            payload, encoding = inbox.samples[f"oslim/{VEHICLE}/{name}"][-1]
            assert encoding == "application/protobuf;foxglove.Grid"
            decoded = decode_grid(payload)
            assert decoded.shape == (7, 12)
            assert np.array_equal(decoded, expected.astype(np.float32))

    run(check)


def test_json_payloads_have_exactly_the_contract_keys() -> None:
    def check(link: ZenohLink, port: int) -> None:
        inbox = Inbox()
        names = ("estimate", "path", "obs")
        with zenoh.open(peer_config(port)) as session:
            session.declare_subscriber(f"oslim/{VEHICLE}/**", inbox)
            inbox.wait_for({f"oslim/{VEHICLE}/{n}" for n in names}, lambda: publish_all(link, 1.0))
        got = {}
        for name in names:
            payload, encoding = inbox.samples[f"oslim/{VEHICLE}/{name}"][-1]
            assert encoding == "application/json"
            got[name] = json.loads(payload)
        assert tuple(got["estimate"]) == ESTIMATE_KEYS
        assert got["estimate"] == {"time_s": 12.0, "state": "trace", "cell": 47, "x": 27.5, "y": -7.5,
                                   "probability": 0.125, "entropy": 3.25}  # fmt: skip
        assert tuple(got["obs"]) == OBS_KEYS
        assert got["obs"] == {"time_s": 12.0, "x": 0.1 + 0.2, "y": -1 / 3, "flow_x": 1e-300, "flow_y": -0.5,
                              "detected": True}  # fmt: skip
        assert tuple(got["path"]) == PATH_KEYS
        assert got["path"] == {"time_s": 12.0, "waypoints": [[1.0, 2.0], [3.5, -4.25]]}

    run(check)


def test_a_late_joiner_gets_the_latest_of_each_key() -> None:
    def check(link: ZenohLink, port: int) -> None:
        publish_all(link, 1.0)
        publish_all(link, 2.0)  # the latest
        with zenoh.open(peer_config(port)) as session:
            replies: dict[str, tuple[bytes, str]] = {}
            for _ in range(int(TIMEOUT_S / 0.05)):  # until the queryable's declaration has arrived
                for reply in session.get(f"oslim/{VEHICLE}/**", timeout=TIMEOUT_S):
                    assert reply.ok is not None, reply.err
                    replies[str(reply.ok.key_expr)] = (reply.ok.payload.to_bytes(), str(reply.ok.encoding))
                if replies:
                    break
                threading.Event().wait(0.05)
            only_slim = [str(r.ok.key_expr) for r in session.get(f"oslim/{VEHICLE}/slim") if r.ok]
        assert set(replies) == {f"oslim/{VEHICLE}/{k}" for k in ("slim", "plume", "estimate", "path", "obs")}
        for key, (payload, encoding) in replies.items():
            assert payload == link.latest()[key.rsplit("/", 1)[1]]
            assert encoding.startswith(
                "application/protobuf" if key.endswith(("slim", "plume")) else "application/json"
            )
        slim = decode_grid(replies[f"oslim/{VEHICLE}/slim"][0])
        assert np.array_equal(slim, (np.arange(GRID.size).reshape(GRID.shape) * 2.0).astype(np.float32))
        assert only_slim == [f"oslim/{VEHICLE}/slim"]

    run(check)


class StopReadingError(Exception):
    """Raised by the README snippet's print in the test: its loop would run forever."""


def test_the_readme_subscriber_decodes_a_grid() -> None:
    """The README's lines, run as written except for the loopback configuration and the key."""
    port = free_port()
    code = README_SNIPPET.replace("zenoh.Config()", "conf").replace("oslim-1", VEHICLE)
    printed: list[str] = []

    def print_once(*args: object) -> None:
        printed.append(" ".join(map(str, args)))
        raise StopReadingError

    def read() -> None:
        with contextlib.suppress(StopReadingError):
            exec(code, {"conf": peer_config(port), "print": print_once})

    slim = np.full(GRID.shape, 0.25)

    async def main() -> None:
        async with ZenohLink(link_config(port), VEHICLE, GRID, extra=NO_MULTICAST) as link:
            reader = threading.Thread(target=read, daemon=True)
            reader.start()
            for _ in range(int(TIMEOUT_S / 0.05)):
                if not reader.is_alive():
                    break
                link.publish_maps(1.0, slim, slim)
                await asyncio.to_thread(reader.join, 0.05)

    asyncio.run(main())
    assert printed == ["(7, 12) 0.25"]


def test_publishing_needs_an_open_link_and_valid_values() -> None:
    link = ZenohLink(ZenohConfig(), VEHICLE, GRID, extra=NO_MULTICAST)
    with pytest.raises(LinkError, match="not open"):
        link.publish_obs(OBS)

    def check(link: ZenohLink, port: int) -> None:
        with pytest.raises(ValueError, match="state 'wander'"):
            link.publish_estimate(1.0, "wander", ESTIMATE)
        with pytest.raises(ValueError, match=r"\(7, 12\)"):
            link.publish_maps(1.0, np.zeros((12, 7)), np.zeros((12, 7)))
        with pytest.raises(ValueError, match="finite"):
            link.publish_path(1.0, [(float("nan"), 0.0)])
        assert link.latest() == {}

    run(check)


def test_bad_extra_zenoh_settings_name_the_key() -> None:
    with pytest.raises(ConfigError, match="scouting/multicast/enabled"):
        session_config(ZenohConfig(), {"scouting/multicast/enabled": "perhaps"})


def test_a_port_in_use_is_a_link_error() -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]

        async def main() -> None:
            async with ZenohLink(link_config(port), VEHICLE, GRID, extra=NO_MULTICAST):
                pass

        with pytest.raises(LinkError, match="cannot open"):
            asyncio.run(main())


def test_connected_counts_the_peers_that_reached_the_link() -> None:
    port = free_port()

    async def body() -> None:
        async with ZenohLink(link_config(port), VEHICLE, GRID, extra=NO_MULTICAST) as link:
            assert link.connected() == (0, 0)
            with zenoh.open(peer_config(port)):
                async with asyncio.timeout(TIMEOUT_S):
                    while link.connected() != (0, 1):
                        await asyncio.sleep(0.05)

    asyncio.run(body())
    with pytest.raises(LinkError, match="not open"):
        ZenohLink(link_config(port), VEHICLE, GRID).connected()
