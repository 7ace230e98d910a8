"""A stand-alone Zenoh subscriber that timestamps each grid it receives (used by ``oslim sim``).

``python -m service.tools.zenoh_probe ENDPOINT KEY OUT.jsonl``: connects to ENDPOINT (multicast
scouting off), prints ``ready`` once subscribed, then appends one line per sample:
``{"time_s": <the grid's own timestamp>, "wall": <time.time() on receipt>}`` until terminated.
"""

from __future__ import annotations

import json
import signal
import sys
import threading
import time
from typing import Any

import zenoh
from foxglove_schemas_protobuf.Grid_pb2 import Grid as GridProto


def main(argv: list[str]) -> int:
    endpoint, key, out_path = argv
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    with open(out_path, "a", encoding="utf-8") as out, zenoh.open(conf) as session:

        def on_sample(sample: Any) -> None:
            wall = time.time()
            grid = GridProto()
            grid.ParseFromString(sample.payload.to_bytes())
            t = grid.timestamp.seconds + grid.timestamp.nanos * 1e-9
            out.write(json.dumps({"time_s": round(t, 3), "wall": wall}) + "\n")
            out.flush()

        session.declare_subscriber(key, on_sample)
        print("ready", flush=True)
        done.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
