"""``oslim bench``: rerunnable benchmarks that print what they measured."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from service.tools.bench import compare, mapping, search, suite
from service.tools.progress import progress_bar
from sim_bridge.scenarios import load_scenario

if TYPE_CHECKING:
    from service.tools.bench import estimate as estimate_types
    from service.tools.bench import phases as phases_types
    from service.tools.bench import reliability as reliability_types


def run(args: argparse.Namespace) -> int:
    if args.bench == "mapping":
        return _run_mapping(args)
    if args.bench == "search":
        return _run_search(args)
    if args.bench == "suite":
        return _run_suite(args)
    if args.bench == "plume":
        return _run_plume(args)
    if args.bench == "model":
        return _run_model(args)
    if args.bench == "estimate":
        return _run_estimate(args)
    if args.bench == "phases":
        return _run_phases(args)
    if args.bench == "compare":
        return _run_compare(args)
    if args.bench == "track":
        return _run_track(args)
    raise AssertionError(args.bench)


def _run_mapping(args: argparse.Namespace) -> int:
    params, model = None, mapping.PAPERS
    if args.config is not None or args.overrides:
        from service.core.config import load_config
        from service.core.mapping import MapperParams

        # a broken configuration stops here, naming the key
        params = MapperParams.from_config(load_config(args.config, tuple(args.overrides)))
        model = _configuration(args)
    if not args.json:
        print("model: " + ("the papers'" if params is None else model), flush=True)
        print(
            f"{'mapper':<8}{'cells':>9}{'window':>8}{'median ms':>11}{'p95 ms':>9}{'peak MB':>9}", flush=True
        )
    for result in mapping.run(args.mappers, args.cells, args.window, args.ticks, params, model):
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


ORACLE = "; ORACLE declaration (a perfect guard: a bound, not a result)"
TIME_SCALE = "; TIME LIMITS x {:g} (a diagnostic, not the suite's result)"


def _time_scale_note(scale: float) -> str:
    """What a title adds when the time limits are scaled (nothing at the suite's own limits)."""
    return TIME_SCALE.format(scale) if scale != 1.0 else ""


def _print_json(row: dict[str, Any], oracle: bool, time_scale: float = 1.0) -> None:
    """One JSON object of a search or suite run; a bound under the oracle, or a run with scaled
    time limits, says so."""
    marks = ({"oracle_declaration": True} if oracle else {}) | (
        {"time_scale": time_scale} if time_scale != 1.0 else {}
    )
    print(json.dumps({**row, **marks}), flush=True)


def _fmt(value: float | None, spec: str) -> str:
    return "never" if value is None else format(value, spec)


def _run_search(args: argparse.Namespace) -> int:
    if args.oracle_declaration and args.report:
        raise SystemExit("oslim bench search: --oracle-declaration gives a bound, not a result: no --report")
    scenario = load_scenario(args.scenario, args.overrides)
    mappers = search.expand(args.mappers, search.mapper_names(), str(scenario.config.mapping.method))
    planners = search.expand(args.planners, search.planner_names(), str(scenario.config.planning.method))
    if not args.json:
        print(
            f"{scenario.name}: {args.runs} runs per configuration (seeds {args.first_seed}.."
            f"{args.first_seed + args.runs - 1}), limit {args.max_time:g} s; "
            "times: failed runs count as never" + (ORACLE if args.oracle_declaration else ""),
            flush=True,
        )
        print(
            f"{'mapper':<7}{'planner':<12}{'runs':>5}{'success':>9}{'median s':>10}{'p90 s':>8}"
            f"{'path m':>8}{'wrong':>7}{'none':>6}",
            flush=True,
        )
    summaries = []
    results: dict[tuple[str, str], list[search.MissionResult]] = {}
    with progress_bar(args.runs * len(mappers) * len(planners), quiet=args.json) as progress:
        configurations = list(search.run_configurations(
            args.scenario, mappers, planners, args.runs, jobs=args.jobs, max_time_s=args.max_time,
            overrides=args.overrides, first_seed=args.first_seed, oracle=args.oracle_declaration,
            progress=progress,
        ))  # fmt: skip
    for summary, batch in configurations:
        summaries.append(summary)
        results[summary.mapper, summary.planner] = batch
        if args.json:
            _print_json(summary.as_row(), args.oracle_declaration)
        else:
            print(
                f"{summary.mapper:<7}{summary.planner:<12}{summary.runs:>5}{summary.success_rate:>9.1%}"
                f"{_fmt(summary.median_time_s, '.0f'):>10}{_fmt(summary.p90_time_s, '.0f'):>8}"
                f"{summary.median_path_m:>8.0f}{summary.wrong_declarations:>7}{summary.undeclared:>6}",
                flush=True,
            )
            if summary.success_rate < 1.0:
                print(f"  {summary.failure_line()}", flush=True)
    if args.report:
        from service.tools.bench import report  # matplotlib is optional: only the report needs it

        best = max(summaries, key=report.rank)
        written = report.write_report(
            args.report,
            args.scenario,
            summaries,
            best,
            results=results[best.mapper, best.planner],
            overrides=args.overrides,
            max_time_s=args.max_time,
            first_seed=args.first_seed,
        )
        if not args.json:
            print(f"report: {written}", flush=True)
    return 0


def _run_plume(args: argparse.Namespace) -> int:
    from sim_bridge.plume_bench import measure_plume

    result = measure_plume(puffs=args.puffs)
    row = dataclasses.asdict(result)
    if args.json:
        print(json.dumps(row))
    else:
        print(
            f"plume: {result.live_puffs} live puffs, dt {result.dt_s:g} s: "
            f"{result.median_step_ms:.2f} ms per step, "
            f"{result.steps_per_s:.0f} steps/s, real-time factor {result.real_time_factor:.1f} "
            f"(slowest repeat {result.worst_real_time_factor:.1f})"
        )
    return 0


def _class_files(command: str, suite_dir: str | None, names: list[str] | None) -> list[Path]:
    """The suite's class files, or the named ones (SystemExit naming an unknown class)."""
    files = suite.suite_classes(suite_dir)
    if not names:
        return files
    known = {path.stem: path for path in files}
    unknown = [name for name in names if name not in known]
    if unknown:
        raise SystemExit(f"oslim bench {command}: unknown class {unknown[0]!r}; known: {', '.join(known)}")
    return [known[name] for name in dict.fromkeys(names)]


def _missions(args: argparse.Namespace, files: list[Path]) -> str:
    """What a suite-wide run measures: classes, missions, seeds and configuration, in words."""
    return (
        f"{len(files)} classes x {args.runs} missions (seeds {args.first_seed}.."
        f"{args.first_seed + args.runs - 1}), configuration {_configuration(args)}"
    )


def _configuration(args: argparse.Namespace) -> str:
    """The service configuration a command runs with, as given: its file and ``--set`` overrides."""
    return "".join([args.config or "config/default.toml", *(f" --set {o}" for o in args.overrides)])


def _class_batches(
    args: argparse.Namespace, command: str, title: str, time_scale: float = 1.0
) -> list[tuple[str, list[suite.SuiteMission]]]:
    """The missions of a diagnostic over the suite's classes, each run to ``time_scale`` times its
    limit, announced by ``title`` (its ``{missions}`` filled in) unless the output is JSON."""
    files = _class_files(command, None, args.classes)
    batches = suite.class_missions(
        files, args.runs, args.first_seed, args.config, args.overrides, time_scale=time_scale
    )
    if not args.json:
        print(title.format(missions=_missions(args, files)) + _time_scale_note(time_scale), flush=True)
    return batches


def _run_model(args: argparse.Namespace) -> int:
    from service.tools.bench import reliability

    batches = _class_batches(
        args, "model", "the model's P(detection | the true source) against the detector: {missions}"
    )
    everything = []
    for name, ticks in reliability.run(batches, args.jobs):
        everything.append(ticks)
        _print_bands(name, reliability.bands(ticks), args.json)
    if len(everything) > 1:
        _print_bands("all", reliability.bands(reliability.Ticks.join(everything)), args.json)
    return 0


ESTIMATE_HEADER = (
    f"{'class':<16}{'outcome':<22}{'missions':>9}{'traced':>8}{'at source':>11}{'+ mass':>8}"
    f"{'downflow':>10}{'up/beside':>11}{'at odour':>10}{'flat':>6}"
)


def _run_estimate(args: argparse.Namespace) -> int:
    from service.tools.bench import estimate

    batches = _class_batches(
        args,
        "estimate",
        "where the map's estimate was in the ticks traced (trace, lost), by how the mission ended: "
        "{missions}; at source: within one cell of the source's, + mass: with the declaration's mass "
        f"around it (only a guard holds it back); at odour: within {estimate.AT_ODOUR_M:g} m of a "
        f"detection; flat: no cell above {estimate.FLAT_RATIO:g} times the uniform share",
    )
    if not args.json:
        print(ESTIMATE_HEADER, flush=True)
    ended: dict[str, list[tuple[str, estimate.Places]]] = {}
    for name, runs in estimate.run(batches, args.jobs):
        ended[name] = runs
        _print_outcomes(name, estimate.outcomes(runs), args.json)
    if len(ended) > 1:
        _print_outcomes("all", estimate.outcomes([e for runs in ended.values() for e in runs]), args.json)
    return 0


def _print_outcomes(name: str, outcomes: list[estimate_types.Outcome], as_json: bool) -> None:
    for o in outcomes:
        if as_json:
            print(json.dumps({"class": name, **o.as_row()}), flush=True)
            continue
        p = o.places
        print(
            f"{name:<16}{o.outcome:<22}{o.missions:>9}{p.traced:>8}{p.at_source:>11}{p.at_source_with_mass:>8}"
            f"{p.away_downflow:>10}{p.away_upflow_or_beside:>11}{p.at_odour:>10}{p.flat:>6}",
            flush=True,
        )


PHASES_HEADER = (
    f"{'group':<16}{'missions':>9}{'correct':>8}{'limit':>7}{'odour':>11}{'-> source':>11}"
    f"{'-> rule':>11}{'check':>11}{'source -> declared':>20}{'checks':>8}{'check s':>9}"
)


def _run_phases(args: argparse.Namespace) -> int:
    from service.tools.bench import phases

    batches = _class_batches(
        args,
        "phases",
        "where the time goes: {missions}; medians in s (missions that got there): odour: the first "
        "detection; -> source: on to within one cell of the source's cell; -> rule: on to the first "
        "check across the flow begun there (the rule fired); check: the check that vouched for a "
        "declared cell, begun to flown; checks: begun in all (call-offs begin another), flown for "
        "check s ticks; rover, auv: the missions of the classes that drew both kinds of vehicle",
        args.time_scale,
    )
    if not args.json:
        print(PHASES_HEADER, flush=True)
    done: dict[str, list[phases.Phases]] = {}
    for name, runs in phases.run(batches, args.jobs):
        done[name] = runs
        _print_summary(phases.summary(name, runs), args.json)
    for group, missions in phases.groups(done):
        _print_summary(phases.summary(group, missions), args.json)
    return 0


def _print_summary(s: phases_types.Summary, as_json: bool) -> None:
    if as_json:
        print(json.dumps(s.as_row()), flush=True)
        return

    def cell(phase: tuple[float | None, int]) -> str:
        median, count = phase
        return "-" if median is None else f"{median:.0f} ({count})"

    print(
        f"{s.group:<16}{s.missions:>9}{s.correct:>8}{s.limit_s:>7.0f}{cell(s.first_odour):>11}"
        f"{cell(s.to_source):>11}{cell(s.to_rule):>11}{cell(s.vouching):>11}"
        f"{cell(s.at_source_to_declared):>20}{s.checks:>8}{s.check_ticks:>9}",
        flush=True,
    )


def _print_bands(name: str, bands: list[reliability_types.Band], as_json: bool) -> None:
    if as_json:
        for band in bands:
            print(json.dumps({"class": name, **band.as_row()}), flush=True)
        return
    print(f"{name}: where the vehicle was (m)               ticks   model  detected", flush=True)
    for band in bands:
        model = "-" if band.predicted is None else f"{band.predicted:.2f}"
        seen = "-" if band.detected is None else f"{band.detected:.2f}"
        print(f"  {band.label:<44}{band.ticks:>6}{model:>8}{seen:>10}", flush=True)


def _run_suite(args: argparse.Namespace) -> int:
    files = _class_files("suite", args.suite, args.classes)
    suite.service_config(args.config, tuple(args.overrides))  # a broken configuration stops here
    if not args.json:
        print(
            f"suite {args.suite or 'config/suites'}: {_missions(args, files)}; "
            "times: median / p90 to a correct declaration"
            + (ORACLE if args.oracle_declaration else "")
            + _time_scale_note(args.time_scale),
            flush=True,
        )
        print(suite.HEADER, flush=True)
    if args.missions:
        Path(args.missions).write_text("", encoding="utf-8")  # this run's missions only
    with progress_bar(args.runs * len(files), quiet=args.json) as progress:
        for row in suite.timed(
            suite.run_suite(
                files, args.runs, first_seed=args.first_seed, config_path=args.config,
                overrides=args.overrides, jobs=args.jobs, scheduler=args.scheduler, progress=progress,
                oracle=args.oracle_declaration, arrival_radius_m=args.arrival_radius,
                time_scale=args.time_scale,
            )
        ):  # fmt: skip
            if args.json:
                _print_json(row.as_row(), args.oracle_declaration, args.time_scale)
            else:
                print(row.line(), flush=True)
            if args.missions and isinstance(row, suite.ClassSummary):
                compare.write_missions(
                    args.missions, (compare.mission_row(row.name, r, limit) for r, limit in row.outcomes)
                )
    return 0


TRACK_HEADER = (
    f"{'t s':>6}  {'state':<8}{'along':>8}{'across':>8}{'odour':>6}{'est along':>11}{'est across':>11}"
    f"{'cell':>7}{'mass':>7}"
)


def _run_track(args: argparse.Namespace) -> int:
    from service.tools.bench import track

    (path,) = _class_files("track", None, [args.class_name])
    ((_, (spec,)),) = suite.class_missions(
        [path], 1, args.seed, args.config, args.overrides, time_scale=args.time_scale
    )
    mission = track.mission_track(spec)
    ticks = track.shown(mission.ticks, args.every)
    if args.json:
        print(json.dumps({"class": args.class_name, **mission.summary()}), flush=True)
        for tick in ticks:
            print(json.dumps(tick.as_row()), flush=True)
        return 0
    m = mission.summary()
    print(
        f"{args.class_name} seed {args.seed}, configuration {_configuration(args)}"
        + _time_scale_note(args.time_scale)
        + f": {m['outcome']} at {m['time_s']:.0f} s of {m['limit_s']:.0f} s; first odour "
        f"{_fmt_s(m['first_odour_s'])}, within one cell of the source {_fmt_s(m['reached_s'])}, "
        f"{m['detections']} detections"
        + ("" if m["error_m"] is None else f", declared {m['error_m']:.1f} m from the source"),
        flush=True,
    )
    print(
        "positions in m along and across the mean flow from the true source (along > 0: downflow); "
        "cell: the estimated cell's share of the map; mass: the map within declaration.radius_m of it",
        flush=True,
    )
    print(TRACK_HEADER, flush=True)
    for t in ticks:
        print(
            f"{t.time_s:>6.0f}  {t.state:<8}{t.along_m:>8.1f}{t.across_m:>8.1f}"
            f"{'yes' if t.detected else '':>6}{t.estimate_along_m:>11.1f}{t.estimate_across_m:>11.1f}"
            f"{t.estimate_share:>7.2f}{t.mass:>7.2f}",
            flush=True,
        )
    return 0


def _fmt_s(value: float | None) -> str:
    return "never" if value is None else f"at {value:.0f} s"


def _run_compare(args: argparse.Namespace) -> int:
    try:
        result = compare.compare(compare.load_missions(args.a), compare.load_missions(args.b))
    except (OSError, ValueError) as e:
        raise SystemExit(f"oslim bench compare: {e}") from None
    if args.json:
        for paired in (*result.classes, result.total):
            print(json.dumps({**paired.as_row(), "only_a": result.only_a, "only_b": result.only_b}))
        return 0
    print(
        f"A {args.a}, B {args.b}: {result.total.missions} missions paired by class and seed "
        f"(unpaired: {result.only_a} in A, {result.only_b} in B); d time: median of B's time less A's "
        "where both succeeded; p: exact sign test over the missions that changed; p time: signed-rank "
        "test of the time changes"
    )
    for line in result.lines():
        print(line)
    return 0
