"""The README's toy world over many random worlds: a plume model that is not the suite's.

Each world has a hidden source, a steady flow of 1 m/s in a random direction, and an intermittent
Gaussian plume with a sharp edge (odour above the threshold within about 1.8 widths of the axis,
the width growing with the square root of the distance downflow), on the default area. The
vehicle starts at a random point and flies at most 1 m toward its target each second, 600 s at
most. Run from the checkout::

    python examples/toy_worlds.py [--worlds 90] [--first-seed 0] [--set section.key=value ...]
                                  [--arrival-radius M]

It prints how many worlds were solved (declared within the stated radius), how many declarations
were wrong, and the median time of the solved ones.
"""

from __future__ import annotations

import argparse
import math
import random
import statistics

from service.api import Search, load_config


def toy_mission(seed: int, overrides: list[str], arrival_radius_m: float = 0.0) -> tuple[float | None, bool]:
    """One world: (time of the declaration or None, whether the source lies within its radius).
    ``arrival_radius_m``: the vehicle stops this far short of its target (ArduPilot Rover's
    WP_RADIUS)."""
    rng = random.Random(seed)
    search = Search(load_config(None, overrides))
    grid = search.grid
    sx, sy = rng.uniform(grid.x_min + 10, grid.x_max - 10), rng.uniform(grid.y_min + 10, grid.y_max - 10)
    heading = rng.uniform(0.0, 2.0 * math.pi)
    ux, uy = math.cos(heading), math.sin(heading)
    x, y = rng.uniform(grid.x_min + 5, grid.x_max - 5), rng.uniform(grid.y_min + 5, grid.y_max - 5)
    presence, widening = rng.uniform(0.4, 0.9), rng.uniform(0.15, 0.45)
    for t in range(600):
        along = (x - sx) * ux + (y - sy) * uy
        across = -(x - sx) * uy + (y - sy) * ux
        width = 0.5 + widening * math.sqrt(max(along, 0.0))
        present = along > 0.0 and rng.random() < presence
        search.add_position(t, x, y)
        search.add_flow(t, ux, uy)
        search.add_chemical(t, 5.0 * math.exp(-0.5 * (across / width) ** 2) if present else 0.0)
        step = search.tick(t)
        if step is None:
            continue
        if step.declared:
            d = step.declared
            return float(t), math.hypot(d.x - sx, d.y - sy) <= d.radius_m
        target = search.setpoint(t)
        if target is not None:
            gx, gy = target[0] - x, target[1] - y
            away = math.hypot(gx, gy)
            scale = min(1.0, away - arrival_radius_m) / max(away, 1e-9) if away > arrival_radius_m else 0.0
            x, y = x + gx * scale, y + gy * scale
    return None, False


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--worlds", type=int, default=90)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument(
        "--arrival-radius",
        type=float,
        default=0.0,
        metavar="M",
        help="the vehicle stops M m short of its targets (default 0: it drives onto them)",
    )
    args = parser.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.worlds)
    results = [toy_mission(seed, args.set, args.arrival_radius) for seed in seeds]
    solved = [t for t, right in results if t is not None and right]
    wrong = sum(1 for t, right in results if t is not None and not right)
    median = f"{statistics.median(solved):.0f} s" if solved else "-"
    print(f"toy worlds {args.worlds}: solved {len(solved)}, wrong declarations {wrong}, median {median}")


if __name__ == "__main__":
    main()
