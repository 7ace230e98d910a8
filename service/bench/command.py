"""``oslim bench``: rerunnable benchmarks that print what they measured."""

from __future__ import annotations

import argparse
import json
from typing import Any

from service.bench import mapping


def add_parser(subparsers: Any, name: str) -> None:
    parser = subparsers.add_parser(name, help="benchmarks (mapping speed and memory, ...)")
    kinds = parser.add_subparsers(dest="bench", required=True, metavar="BENCH")
    m = kinds.add_parser("mapping", help="time per tick and peak memory of each mapper")
    m.add_argument("--json", action="store_true", help="one JSON object per line")
    m.add_argument("--mapper", action="append", dest="mappers", help="mapper(s) to run (default: all)")
    m.add_argument(
        "--cells", type=int, action="append", choices=sorted(mapping.GRID_SHAPES), help="grid size(s)"
    )
    m.add_argument("--window", type=int, default=200, help="flow-history window, ticks (default 200)")
    m.add_argument("--ticks", type=int, default=None, help="timed ticks per configuration")


def run(args: argparse.Namespace) -> int:
    if args.bench == "mapping":
        return _run_mapping(args)
    raise AssertionError(args.bench)


def _run_mapping(args: argparse.Namespace) -> int:
    if not args.json:
        print(
            f"{'mapper':<8}{'cells':>9}{'window':>8}{'median ms':>11}{'p95 ms':>9}{'peak MB':>9}", flush=True
        )
    for result in mapping.run(args.mappers, args.cells, args.window, args.ticks):
        if args.json:
            print(json.dumps(mapping.as_row(result)), flush=True)
        else:
            print(
                f"{result.mapper:<8}{result.cells:>9}{result.window:>8}"
                f"{result.median_ms:>11.2f}{result.p95_ms:>9.2f}{result.peak_mb:>9.1f}",
                flush=True,
            )
    bandwidth = mapping.memory_bandwidth_gb_per_s()
    if args.json:
        print(json.dumps({"limit": "memory_bandwidth", "gb_per_s": bandwidth}))
    else:
        print(f"memory bandwidth (numpy copy, read + write): {bandwidth:.2f} GB/s")
    return 0
