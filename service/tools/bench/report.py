"""The search benchmark's markdown report and pictures (``oslim bench search --report DIR``).

The report puts our figures beside the papers': seed pomdp-astar Table I (searching time in the
laminar / turbulent scenarios: POMDP 135 / 184 s, HMM 160 / 270 s, Bayesian 121 / 140 s) and seed
hmm-plume-mapping §VI ("typically less than 300 s at 1 m/s"). The papers give one time per
method and scenario, without a number of runs or a success rate, so they are set beside our
medians. The pictures show one representative mission of the best configuration (the seed whose
time is the configuration's median): the final source likelihood map with the plume's puffs, the
track coloured by detection, the source and the declaration; and the estimate's distance to the
source and its probability over time.

matplotlib is an optional dependency (the ``report`` extra): it is imported here only, and only
when a picture is drawn.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from service.core.errors import OslimError
from service.tools.bench.search import MissionResult, SearchSummary, configure, run_mission

if TYPE_CHECKING:
    from sim_bridge.scenarios import Scenario

PAPER_TIMES_S: dict[str, dict[str, float]] = {
    "wang-laminar": {"pomdp": 135.0, "hmm": 160.0, "bayes": 121.0},
    "wang-turbulent": {"pomdp": 184.0, "hmm": 270.0, "bayes": 140.0},
}
"""Seed pomdp-astar Table I: searching time in seconds, per mapper (each paper's own planner)."""

FARRELL_TYPICAL_S = 300.0
"""Seed hmm-plume-mapping §VI: source declared "typically" in less than 300 s at 1 m/s."""


class ReportError(OslimError):
    """The report cannot be drawn (matplotlib missing)."""


def rank(summary: SearchSummary) -> tuple[float, float, float]:
    """Order of merit: success rate, then fewer wrong declarations, then a shorter median time."""
    median = summary.median_time_s if summary.median_time_s is not None else math.inf
    return (summary.success_rate, -summary.wrong_declarations, -median)


def _paper_line(scenario: str) -> str:
    times = PAPER_TIMES_S.get(scenario)
    if times is not None:
        shown = ", ".join(f"{m} {t:.0f} s" for m, t in times.items())
        return f"Seed pomdp-astar Table I, searching time for this scenario: {shown} (one figure per method)."
    if scenario == "farrell2003":
        return f'Seed hmm-plume-mapping §VI: "typically less than {FARRELL_TYPICAL_S:.0f} s at 1 m/s".'
    return "The papers give no figure for this scenario."


def _cell(value: float | None, spec: str) -> str:
    return "never" if value is None else format(value, spec)


def markdown(
    scenario: str,
    summaries: Sequence[SearchSummary],
    overrides: Sequence[str],
    max_time_s: float,
    first_seed: int = 0,
) -> str:
    """The report's text: our table, the papers' figures, how the figures were measured."""
    paper = PAPER_TIMES_S.get(scenario, {})
    last_seed = first_seed + (summaries[0].runs if summaries else 0) - 1
    lines = [
        f"# Search benchmark: {scenario}",
        "",
        _paper_line(scenario),
        "",
        f"Ours: seeds {first_seed}..{last_seed}, in-process closed loop, limit {max_time_s:g} s per mission."
        " Success: the declared cell within one cell of the source's, no wrong declaration. Times count"
        " failed runs as never (so a median is only finite with at least half the runs successful).",
    ]
    if overrides:
        lines += ["", "Overrides: " + ", ".join(f"`{o}`" for o in overrides)]
    lines += [
        "",
        "| mapper | planner | runs | success | median s | p90 s | median path m | wrong | undeclared "
        "| paper s |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for s in sorted(summaries, key=rank, reverse=True):
        paper_s = paper.get(s.mapper)
        lines.append(
            f"| {s.mapper} | {s.planner} | {s.runs} | {s.success_rate:.1%} | {_cell(s.median_time_s, '.0f')} "
            f"| {_cell(s.p90_time_s, '.0f')} | {s.median_path_m:.0f} | {s.wrong_declarations} "
            f"| {s.undeclared} | {'' if paper_s is None else f'{paper_s:.0f}'} |"
        )
    failed = [s for s in sorted(summaries, key=rank, reverse=True) if s.success_rate < 1.0]
    if failed:
        lines += ["", "Where the failed missions stopped:", ""]
        lines += [f"- {s.mapper} + {s.planner}: {s.failure_line()}" for s in failed]
    return "\n".join(lines) + "\n"


def representative_seed(results: Sequence[MissionResult]) -> int:
    """The seed of the successful run whose time is nearest the median (seed 0 if none succeeded)."""
    ok = sorted((r.time_s, r.seed) for r in results if r.correct)
    return ok[len(ok) // 2][1] if ok else 0


def draw_mission(scenario: Scenario, result: MissionResult, path: Path) -> None:
    """The mission picture: map, plume, track, source, declaration; estimate over time."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.patches import Rectangle
    except ImportError:
        raise ReportError("pictures need matplotlib: pip install 'oslim[report]'") from None
    trace = result.trace
    if trace is None:
        raise ValueError("the mission was not recorded")
    grid = scenario.grid
    fig, (ax_map, ax_time) = plt.subplots(1, 2, figsize=(13, 5.5), width_ratios=[1.2, 1.0])
    extent = (grid.x_min, grid.x_max, grid.y_min, grid.y_max)
    # row 0 of the likelihood is the southern row (service.core.grid), hence origin="lower"
    image = ax_map.imshow(trace.likelihood, origin="lower", extent=extent, cmap="Greys", aspect="auto")
    fig.colorbar(image, ax=ax_map, label="source likelihood π (end)")
    puffs = trace.plume_puffs
    ax_map.scatter(puffs[:, 0], puffs[:, 1], s=0.3, c="tab:orange", alpha=0.3, label="plume puffs (end)")
    for x0, y0, x1, y1 in grid.obstacles:
        ax_map.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, hatch="//", ec="k"))
    xs = [p.x for p in trace.track]
    ys = [p.y for p in trace.track]
    ax_map.plot(xs, ys, "-", color="tab:blue", lw=1.0, label="track")
    hits = [p for p in trace.track if p.detected]
    ax_map.scatter([p.x for p in hits], [p.y for p in hits], s=10, c="tab:red", label="detection", zorder=3)
    ax_map.plot(result.source_x, result.source_y, "*", ms=14, c="gold", mec="k", label="source")
    if result.declared_x is not None and result.declared_y is not None:
        ax_map.plot(result.declared_x, result.declared_y, "x", ms=12, mew=2, c="tab:green", label="declared")
    ax_map.set(xlim=(grid.x_min, grid.x_max), ylim=(grid.y_min, grid.y_max), xlabel="x East (m)",
               ylabel="y North (m)", title=f"{scenario.name}, seed {result.seed}")  # fmt: skip
    ax_map.legend(loc="lower right", fontsize=7)
    times = [p.time_s for p in trace.track]
    error = [math.hypot(p.estimate_x - result.source_x, p.estimate_y - result.source_y) for p in trace.track]
    ax_time.plot(times, error, c="tab:blue", label="estimate to source (m)")
    ax_time.set(xlabel="time (s)", ylabel="distance (m)", title="estimate over time")
    twin = ax_time.twinx()
    twin.plot(times, [p.probability for p in trace.track], c="tab:purple", alpha=0.7, label="π at estimate")
    twin.set(ylabel="π at the estimate", ylim=(0.0, 1.0))
    for t, p in zip(times, trace.track, strict=True):
        if p.detected:
            ax_time.axvline(t, color="tab:red", alpha=0.15, lw=1)
    ax_time.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(
    directory: str | Path,
    scenario: str,
    summaries: Sequence[SearchSummary],
    best: SearchSummary,
    *,
    results: Sequence[MissionResult] = (),
    overrides: Sequence[str] = (),
    max_time_s: float,
    first_seed: int = 0,
) -> Path:
    """Write ``<scenario>.md`` and ``<scenario>-mission.png`` into ``directory``; returns the .md."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    configured = configure(scenario, best.mapper, best.planner, overrides)
    seed = representative_seed(results)
    recorded = run_mission(configured, seed, max_time_s=max_time_s, record=True)
    picture = out / f"{configured.name}-mission.png"
    draw_mission(configured, recorded, picture)
    text = markdown(scenario, summaries, overrides, max_time_s, first_seed)
    text += (
        f"\nRepresentative mission ({best.mapper} + {best.planner}, seed {seed}): "
        f"![mission]({picture.name})\n"
    )
    report = out / f"{configured.name}.md"
    report.write_text(text, encoding="utf-8")
    return report
