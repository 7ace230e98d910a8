"""``oslim report RUN.mcap [-o FILE.png]``: one picture of a run, read back from its recording.

Above, the map: the final source likelihood π, the track coloured by mission state, the
detections, flow arrows along the track, the declared cell with the declaration radius and, in a
simulation (``/sim/source``), the true source. Below, a strip of the estimate's probability and
the map's entropy over time. Everything comes from the MCAP channels of ``recorder`` and
``foxglove_scene``; nothing is recomputed.

matplotlib is the optional ``report`` extra: imported here only, and only when drawing, so the
service never loads it.
"""

from __future__ import annotations

import argparse
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.exceptions import McapError
from mcap.stream_reader import CRCValidationError

from service.core.config import Config, build_config
from service.core.errors import OslimError
from service.core.grid import Grid
from service.edges.foxglove_scene import SOURCE_TOPIC, true_source
from service.edges.grid_message import decode_grid
from service.edges.recorder import (
    CONFIG_TOPIC,
    ESTIMATE_TOPIC,
    EVENT_TOPIC,
    OBS_TOPIC,
    SLIM_TOPIC,
    RecordingReader,
)

FIGSIZE_IN: Final = (9.0, 10.0)
DPI: Final = 100
"""The picture is FIGSIZE_IN * DPI pixels (900 x 1000), whatever the run."""

STATE_COLOURS: Final = {
    "search": "tab:blue", "trace": "tab:orange", "lost": "tab:gray", "declared": "tab:green",
}  # fmt: skip
FLOW_ARROWS: Final = 25
"""About this many flow arrows along the track."""


class ReportError(OslimError):
    """The recording cannot be drawn (unreadable, no configuration or no observation)."""


@dataclass
class Run:
    """What a recording says about its run, as plain arrays and values."""

    config: Config
    times_s: list[float] = field(default_factory=list)
    xy: list[tuple[float, float]] = field(default_factory=list)
    flow: list[tuple[float, float]] = field(default_factory=list)
    detected: list[bool] = field(default_factory=list)
    states: list[str] = field(default_factory=list)
    """Mission state at each observation (the estimate recorded in the same tick)."""
    estimate_times_s: list[float] = field(default_factory=list)
    probability: list[float] = field(default_factory=list)
    entropy: list[float] = field(default_factory=list)
    likelihood: npt.NDArray[np.float32] | None = None
    """The last recorded π."""
    declared: tuple[float, float] | None = None
    source: tuple[float, float] | None = None

    @property
    def grid(self) -> Grid:
        return Grid.from_config(self.config.area)


def read_run(path: str | Path) -> Run:
    """Read a recording (one cut short by a crash too) into a ``Run``."""
    run: Run | None = None
    state_by_tick: dict[int, str] = {}
    obs_ticks: list[int] = []
    try:
        for message in RecordingReader(path).messages():
            if message.topic == CONFIG_TOPIC:
                run = Run(build_config(_json(message.data), origin="recorded configuration"))
                continue
            if run is None:
                continue
            if message.topic == OBS_TOPIC:
                obs = _json(message.data)
                run.times_s.append(float(obs["time_s"]))
                run.xy.append((float(obs["x"]), float(obs["y"])))
                run.flow.append((float(obs["flow_x"]), float(obs["flow_y"])))
                run.detected.append(bool(obs["detected"]))
                obs_ticks.append(message.sequence)
            elif message.topic == ESTIMATE_TOPIC:
                estimate = _json(message.data)
                state_by_tick[message.sequence] = str(estimate["state"])
                run.estimate_times_s.append(float(estimate["time_s"]))
                run.probability.append(float(estimate["probability"]))
                run.entropy.append(float(estimate["entropy"]))
            elif message.topic == SLIM_TOPIC:
                run.likelihood = decode_grid(message.data)
            elif message.topic == EVENT_TOPIC:
                event = _json(message.data)
                if event.get("name") == "source_declared":
                    run.declared = (float(event["x"]), float(event["y"]))
            elif message.topic == SOURCE_TOPIC:
                update = SceneUpdate()
                update.ParseFromString(message.data)
                run.source = true_source(update) or run.source
    except (McapError, CRCValidationError, struct.error, KeyError, ValueError) as exc:
        raise ReportError(f"{path}: unreadable recording: {exc}") from None
    if run is None:
        raise ReportError(f"{path}: the recording has no configuration")
    if not run.xy:
        raise ReportError(f"{path}: the recording has no observation to draw")
    last = "search"
    for tick in obs_ticks:
        last = state_by_tick.get(tick, last)
        run.states.append(last)
    return run


def _json(data: bytes) -> dict[str, Any]:
    value = json.loads(data)
    if not isinstance(value, dict):
        raise ValueError("not a JSON object")
    return value


def draw(run: Run, out: str | Path, *, title: str = "") -> Path:
    """Draw ``run`` into the PNG ``out`` (FIGSIZE_IN * DPI pixels); returns its path."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.collections import LineCollection
        from matplotlib.lines import Line2D
        from matplotlib.patches import Circle, Rectangle
    except ImportError:
        raise ReportError("pictures need matplotlib: pip install 'oslim[report]'") from None
    grid = run.grid
    fig, (ax_map, ax_time) = plt.subplots(2, 1, figsize=FIGSIZE_IN, height_ratios=[3.0, 1.0])
    extent = (grid.x_min, grid.x_max, grid.y_min, grid.y_max)
    if run.likelihood is not None:
        # row 0 of the map is the southern row (service.grid), hence origin="lower"
        image = ax_map.imshow(run.likelihood, origin="lower", extent=extent, cmap="Greys", aspect="equal")
        fig.colorbar(image, ax=ax_map, label="source likelihood π (last)", shrink=0.8)
    for x0, y0, x1, y1 in grid.obstacles:
        ax_map.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, hatch="//", ec="k"))
    xy = np.asarray(run.xy, dtype=float)
    segments = np.stack([xy[:-1], xy[1:]], axis=1) if len(xy) > 1 else np.empty((0, 2, 2))
    colours = [STATE_COLOURS.get(state, "k") for state in run.states[1:]]
    ax_map.add_collection(LineCollection(list(segments), colors=colours, linewidths=1.6))
    hits = xy[np.asarray(run.detected, dtype=bool)]
    ax_map.scatter(hits[:, 0], hits[:, 1], s=12, c="tab:red", zorder=3)
    step = max(1, len(xy) // FLOW_ARROWS)
    flow = np.asarray(run.flow, dtype=float)
    ax_map.quiver(xy[::step, 0], xy[::step, 1], flow[::step, 0], flow[::step, 1], color="tab:cyan",
                  angles="xy", scale_units="xy", scale=0.2, width=0.003, zorder=2)  # fmt: skip
    handles = [Line2D([], [], color=c, label=f"track: {s}") for s, c in STATE_COLOURS.items()]
    handles.append(Line2D([], [], ls="", marker="o", ms=4, color="tab:red", label="detection"))
    handles.append(Line2D([], [], color="tab:cyan", marker=">", label="flow (5 m per m/s)"))
    if run.declared is not None:
        radius = run.config.declaration.radius_m
        ax_map.add_patch(Circle(run.declared, radius, fill=False, ec="tab:green", lw=2, zorder=4))
        ax_map.plot(*run.declared, "x", ms=12, mew=2, c="tab:green", zorder=4)
        handles.append(Line2D([], [], ls="", marker="x", mew=2, color="tab:green",
                              label=f"declared (r {radius:g} m)"))  # fmt: skip
    if run.source is not None:
        ax_map.plot(*run.source, "*", ms=16, c="gold", mec="k", zorder=5)
        handles.append(Line2D([], [], ls="", marker="*", ms=12, color="gold", mec="k", label="true source"))
    ax_map.set(xlim=(grid.x_min, grid.x_max), ylim=(grid.y_min, grid.y_max), xlabel="x East (m)",
               ylabel="y North (m)", title=title or f"{run.config.vehicle.id}: {len(xy)} ticks")  # fmt: skip
    ax_map.legend(handles=handles, loc="upper left", fontsize=7, framealpha=0.8)
    ax_time.plot(run.estimate_times_s, run.probability, c="tab:purple", label="estimate probability")
    ax_time.set(xlabel="time (s)", ylabel="probability", ylim=(0.0, 1.0))
    twin = ax_time.twinx()
    twin.plot(run.estimate_times_s, run.entropy, c="tab:brown", label="map entropy")
    twin.set(ylabel="entropy")
    ax_time.legend(handles=[*ax_time.get_lines(), *twin.get_lines()], loc="upper right", fontsize=7)
    fig.tight_layout()
    target = Path(out)
    fig.savefig(target, dpi=DPI)
    plt.close(fig)
    return target


def write_report(recording: str | Path, out: str | Path | None = None) -> Path:
    """Read ``recording`` and draw it into ``out`` (default: the recording's name with .png)."""
    source = Path(recording)
    target = Path(out) if out is not None else source.with_suffix(".png")
    return draw(read_run(source), target, title=source.name)


def run(args: argparse.Namespace) -> int:
    path: Path = args.file
    if not path.is_file():
        raise ReportError(f"{path}: no such file")
    print(write_report(path, args.output))
    return 0
