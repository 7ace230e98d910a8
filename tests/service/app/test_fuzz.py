"""Fuzz the service's MAVLink port while a stub-driven mission runs (issue 7, bad input).

A sender on loopback throws random bytes, truncated and corrupted MAVLink 2 frames and valid
frames with NaN, infinite or absurd values at the service's UDP port, for a bounded number of
inputs. The service must stay up, keep ticking and publishing, count what it rejected, keep its
maps finite and normalised, and keep commanding the real vehicle. The figures are printed
(run with ``-s``) for the reliability report.
"""

import asyncio
import json
import math
import random
import socket
import threading
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from service.edges.mavlink_dialect import dialect
from service.tools.sim import closed_loop
from sim_bridge.scenarios import load_scenario

pytestmark = pytest.mark.sim

NAN, INF = math.nan, math.inf


def absurd_frames(rng: random.Random) -> list[tuple[str, bytes]]:
    """Well-formed frames from the vehicle's ids whose values must be rejected or are harmless."""
    m = dialect()
    mav = m.MAVLink(None, srcSystem=1, srcComponent=1)
    boot = rng.choice([0, 1, 0xFFFFFFFF, rng.randrange(2**32)])  # times jumping back and forth
    messages = [
        ("position_nan", m.MAVLink_local_position_ned_message(boot, NAN, 1.0, 0, 0, 0, 0)),
        ("position_inf", m.MAVLink_local_position_ned_message(boot, 1.0, -INF, 0, 0, 0, 0)),
        ("position_1e9", m.MAVLink_local_position_ned_message(boot, 1e9, 1e9, 0, 0, 0, 0)),
        ("position_outside", m.MAVLink_local_position_ned_message(boot, 5e3, -7e3, 0, 0, 0, 0)),
        ("flow_1000", m.MAVLink_wind_cov_message(boot, 1000.0, 0.0, 0, 0, 0, 0, 0, 0)),
        ("flow_nan", m.MAVLink_wind_cov_message(boot, NAN, 1.0, 0, 0, 0, 0, 0, 0)),
        ("wind_negative", m.MAVLink_wind_message(90.0, -5.0, 0.0)),
        ("wind_inf", m.MAVLink_wind_message(INF, 1.0, 0.0)),
        ("chem_nan", m.MAVLink_named_value_float_message(boot, b"CHEM", NAN)),
        ("chem_inf", m.MAVLink_named_value_float_message(boot, b"CHEM", rng.choice([INF, -INF]))),
        ("detection_7", m.MAVLink_named_value_int_message(boot, b"CHEM_DET", 7)),
        ("foreign_heartbeat", m.MAVLink_heartbeat_message(10, 3, 128 | 1, 15, 4, 3)),
    ]
    frames = []
    for name, msg in messages:
        if name == "foreign_heartbeat":
            other = m.MAVLink(None, srcSystem=77, srcComponent=1)  # not our vehicle
            frames.append((name, bytes(msg.pack(other))))
        else:
            frames.append((name, bytes(msg.pack(mav))))
    return frames


def fuzz_input(rng: random.Random) -> tuple[str, bytes]:
    kind = rng.randrange(6)
    if kind == 0:
        return "random_bytes", rng.randbytes(rng.randrange(1, 300))
    if kind == 1:  # a MAVLink 2 start marker and a plausible header, then garbage
        return "random_after_magic", bytes([0xFD, rng.randrange(256), 0, 0]) + rng.randbytes(
            rng.randrange(0, 60)
        )
    name, frame = rng.choice(absurd_frames(rng))
    if kind == 2:
        return "truncated", frame[: rng.randrange(1, len(frame))]
    if kind == 3:
        corrupt = bytearray(frame)
        corrupt[rng.randrange(len(corrupt))] ^= 1 << rng.randrange(8)
        return "bit_flipped", bytes(corrupt)
    if kind == 4:  # several frames glued together, one cut short
        tail = absurd_frames(rng)[0][1]
        return "concatenated", frame + tail[: rng.randrange(len(tail))] + frame
    return f"absurd:{name}", frame


def sender(port: int, count: int, seed: int, done: threading.Event, sent: Counter[str]) -> None:
    rng = random.Random(seed)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setblocking(False)
        for k in range(count):
            if done.is_set():
                return
            kind, data = fuzz_input(rng)
            try:
                sock.sendto(data, ("127.0.0.1", port))
            except BlockingIOError:
                continue
            sent[kind] += 1
            if k % 50 == 49:
                done.wait(0.01)  # ~5000 inputs/s: heavy, but leaves the 2-core machine to the mission


async def until(condition: Callable[[], bool], timeout_s: float = 30.0) -> None:
    async with asyncio.timeout(timeout_s):
        while not condition():
            await asyncio.sleep(0.01)


def fuzz(tmp_path: Path, count: int, seed: int) -> dict[str, Any]:
    sent: Counter[str] = Counter()
    problems: list[str] = []

    async def body() -> dict[str, Any]:
        async with closed_loop(
            load_scenario("wang-laminar"), 1, speed=5.0, recorder_dir=str(tmp_path)
        ) as loop:
            service = loop.service
            await until(lambda: service.stats.setpoints >= 2)
            port = int(loop.config.mavlink.url.rsplit(":", 1)[1])
            done = threading.Event()
            thread = threading.Thread(target=sender, args=(port, count, seed, done, sent), daemon=True)
            ticks0, setpoints0 = service.stats.ticks, service.stats.setpoints
            thread.start()
            checks = 0
            try:
                while thread.is_alive() and not loop.task.done():
                    pi, alpha = service.mapper.likelihood, service.mapper.plume
                    if not (np.isfinite(pi).all() and np.isfinite(alpha).all()):
                        problems.append("non-finite map")
                    if not (pi.min() >= 0.0 and abs(pi.sum() - 1.0) < 1e-9):
                        problems.append(f"map not normalised (sum {pi.sum()!r})")
                    checks += 1
                    await asyncio.sleep(0.05)
            finally:
                done.set()
                await asyncio.to_thread(thread.join, 10)
            crashed = loop.task.done()
            edges: Any = service.edges
            reader = edges.link._thread if edges is not None else None
            reader_alive = reader is not None and reader.is_alive()
            ticks, setpoints = service.stats.ticks, service.stats.setpoints
            await until(lambda: service.stats.setpoints > setpoints)  # still commanding the vehicle
            published = set(edges.maps.latest())
            return {
                "inputs": sum(sent.values()),
                "by_kind": dict(sorted(sent.items())),
                "crashes": int(crashed) + int(not reader_alive),
                "map_checks": checks,
                "map_problems": len(problems),
                "ticks_during_fuzz": ticks - ticks0,
                "setpoints_during_fuzz": setpoints - setpoints0,
                "rejected": dict(service.stats.rejected),
                "link": dict(service.stats.link),
                "mapper_ignored": dict(service.mapper.ignored),
                "published": sorted(published),
            }

    report = asyncio.run(body())
    print("fuzz report: " + json.dumps(report))
    assert report["inputs"] == count
    assert report["crashes"] == 0
    assert not problems, problems[:5]
    assert report["ticks_during_fuzz"] > 0
    assert report["setpoints_during_fuzz"] > 0
    assert {"slim", "plume", "estimate", "obs"} <= set(report["published"])
    # what was rejected is counted: values by reason, frames by the link
    assert report["link"]["unparsable"] > 0
    assert any("non-finite" in reason for reason in report["rejected"])
    assert any("faster than" in reason for reason in report["rejected"])
    return report


def test_fuzz_mavlink_port(tmp_path: Path) -> None:
    fuzz(tmp_path, count=8_000, seed=7)


@pytest.mark.slow
def test_fuzz_mavlink_port_long(tmp_path: Path) -> None:
    fuzz(tmp_path, count=200_000, seed=11)
