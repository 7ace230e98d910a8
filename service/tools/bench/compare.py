"""Two runs of the world suite, mission by mission: is a change beyond the noise of the seeds?

``oslim bench suite --missions FILE`` writes one JSON line per mission (``mission_row``).
``oslim bench compare A B`` pairs two such files by class and seed, so that both sides of a pair
flew the same world, and counts per class the missions B gained (a success where A failed) and
lost. Missions that did the same on both sides say nothing about the change; the changed ones do.
Under "no difference" each changed mission is as likely gained as lost, so the number gained among
the n changed is Binomial(n, 1/2), and the exact two-sided sign test (McNemar's test on paired
outcomes) gives the chance of a split at least as uneven. A gain whose p is large is within the
noise of these seeds, however large it looks in percent.

Time is judged the same way, over the missions both sides succeeded in: each pair's difference in
time to the declaration, and the exact two-sided Wilcoxon signed-rank test of those differences
(ties at zero left out), so that a change meant to save time is not taken for one by the seeds'
luck either.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import binomtest, wilcoxon

from service.tools.bench.search import MissionResult

REQUIRED = ("class", "seed", "correct", "wrong", "time_s")
"""Keys every mission line needs."""
NOISE_P = 0.05
"""A difference whose sign-test p is at least this is reported as within the noise."""

Key = tuple[str, int]


def mission_row(name: str, result: MissionResult, limit_s: float) -> dict[str, Any]:
    """One line of ``oslim bench suite --missions``: the mission's class, seed and outcome."""
    failure = result.failure
    return {
        "class": name,
        "seed": result.seed,
        "correct": result.correct,
        "wrong": result.wrong,
        "declared": result.declared,
        "failure": None if failure is None else str(failure),
        "time_s": result.time_s,
        "limit_s": limit_s,
        "first_detection_s": result.first_detection_s,
        "reached_s": result.reached_s,
        "confidence": result.confidence,
        "radius_m": result.radius_m,
        "error_m": result.error_m,
        "path_m": result.path_m,
        "vehicle_speed_mps": result.vehicle_speed_mps,
        "check": result.check,
    }


def load_missions(path: str | Path) -> dict[Key, dict[str, Any]]:
    """The missions of one file by (class, seed); ValueError naming the line that is not one."""
    missions: dict[Key, dict[str, Any]] = {}
    with open(path, encoding="utf-8") as lines:
        for number, line in enumerate(lines, start=1):
            if not line.strip():
                continue
            where = f"{path}, line {number}"
            try:
                row = json.loads(line)
            except json.JSONDecodeError as e:
                raise ValueError(f"{where}: not JSON ({e.msg})") from None
            if not isinstance(row, dict):
                raise ValueError(f"{where}: not a mission line (a JSON object)")
            if missing := [k for k in REQUIRED if k not in row]:
                raise ValueError(f"{where}: not a mission line (no {', '.join(missing)})")
            key = (str(row["class"]), int(row["seed"]))
            if key in missions:
                raise ValueError(f"{where}: {key[0]} seed {key[1]} appears twice")
            missions[key] = row
    if not missions:
        raise ValueError(f"{path}: no missions")
    return missions


def sign_test(gained: int, lost: int) -> float:
    """Exact two-sided p of ``gained`` against ``lost`` under Binomial(gained + lost, 1/2); 1 with
    no changed mission."""
    changed = gained + lost
    return 1.0 if changed == 0 else float(binomtest(gained, changed, 0.5).pvalue)


def signed_rank_test(differences: Sequence[float]) -> float:
    """Two-sided p of the Wilcoxon signed-rank test of paired ``differences`` against a median of
    0, zeros left out; 1 when none is left."""
    changed = [d for d in differences if d != 0.0]
    return 1.0 if not changed else float(wilcoxon(changed).pvalue)


@dataclass(frozen=True)
class Paired:
    """One class (or all of them) over the missions both files flew."""

    name: str
    missions: int
    a: int
    """Successes in A."""
    b: int
    gained: int
    """Missions B succeeded in and A did not."""
    lost: int
    wrong_a: int
    wrong_b: int
    time_changes: tuple[float, ...]
    """B's time less A's, over the missions both succeeded in."""

    @property
    def p_value(self) -> float:
        return sign_test(self.gained, self.lost)

    @property
    def both(self) -> int:
        """Missions both succeeded in."""
        return len(self.time_changes)

    @property
    def time_change_s(self) -> float | None:
        """Median of ``time_changes``; None when no mission succeeded on both sides."""
        return float(np.median(self.time_changes)) if self.time_changes else None

    @property
    def time_p_value(self) -> float:
        return signed_rank_test(self.time_changes)

    @classmethod
    def of(cls, name: str, pairs: Sequence[tuple[dict[str, Any], dict[str, Any]]]) -> Paired:
        both = tuple(b["time_s"] - a["time_s"] for a, b in pairs if a["correct"] and b["correct"])
        return cls(
            name=name,
            missions=len(pairs),
            a=sum(bool(a["correct"]) for a, _ in pairs),
            b=sum(bool(b["correct"]) for _, b in pairs),
            gained=sum(bool(b["correct"]) and not a["correct"] for a, b in pairs),
            lost=sum(bool(a["correct"]) and not b["correct"] for a, b in pairs),
            wrong_a=sum(bool(a["wrong"]) for a, _ in pairs),
            wrong_b=sum(bool(b["wrong"]) for _, b in pairs),
            time_changes=both,
        )

    def line(self) -> str:
        change = "-" if self.time_change_s is None else f"{self.time_change_s:+.1f}"
        return (
            f"{self.name:<16}{self.missions:>9}{self.a:>7}{self.b:>7}{self.gained:>8}{self.lost:>6}"
            f"{f'{self.wrong_a} / {self.wrong_b}':>12}{change:>9}{self.p_value:>8.2f}"
            f"{self.time_p_value:>8.2f}"
        )

    def as_row(self) -> dict[str, Any]:
        return {
            "class": self.name,
            "missions": self.missions,
            "successes_a": self.a,
            "successes_b": self.b,
            "gained": self.gained,
            "lost": self.lost,
            "wrong_a": self.wrong_a,
            "wrong_b": self.wrong_b,
            "time_change_s": self.time_change_s,
            "p_value": self.p_value,
            "both_succeeded": self.both,
            "time_p_value": self.time_p_value,
        }


HEADER = (
    f"{'class':<16}{'missions':>9}{'A':>7}{'B':>7}{'gained':>8}{'lost':>6}{'wrong A/B':>12}"
    f"{'d time':>9}{'p':>8}{'p time':>8}"
)


def _noise(p: float) -> str:
    return "within the noise of these seeds" if p >= NOISE_P else "beyond the noise of these seeds"


@dataclass(frozen=True)
class Comparison:
    classes: tuple[Paired, ...]
    total: Paired
    only_a: int
    """Missions in A with no partner in B (and the other way round)."""
    only_b: int

    def worst(self, side: str) -> tuple[str, float]:
        """The class with the lowest success rate on ``side`` ("a" or "b") and that rate."""
        rates = [(getattr(c, side) / c.missions, c.name) for c in self.classes]
        rate, name = min(rates)
        return name, rate

    def verdict(self) -> str:
        t = self.total
        p = t.p_value
        return (
            f"B - A = {t.b - t.a:+d} of {t.missions} missions ({t.gained} gained, {t.lost} lost); "
            f"sign test p = {p:.3g}: {_noise(p)} (p {'>=' if p >= NOISE_P else '<'} {NOISE_P})"
        )

    def time_verdict(self) -> str:
        t = self.total
        if t.time_change_s is None:
            return "no mission succeeded on both sides"
        return (
            f"median {t.time_change_s:+.1f} s over the {t.both} missions both succeeded in; "
            f"signed-rank p = {t.time_p_value:.3g}: {_noise(t.time_p_value)}"
        )

    def lines(self) -> list[str]:
        (worst_a, rate_a), (worst_b, rate_b) = self.worst("a"), self.worst("b")
        return [
            HEADER,
            *(c.line() for c in self.classes),
            self.total.line(),
            f"worst class: A {worst_a} {rate_a:.1%}, B {worst_b} {rate_b:.1%}; wrong declarations: "
            f"A {self.total.wrong_a}, B {self.total.wrong_b} of {self.total.missions}",
            f"verdict: {self.verdict()}",
            f"time: {self.time_verdict()}",
        ]


def compare(a: dict[Key, dict[str, Any]], b: dict[Key, dict[str, Any]]) -> Comparison:
    """Pair the missions of A and B by class and seed; ValueError when none pair."""
    keys = sorted(set(a) & set(b))
    if not keys:
        raise ValueError("the two files have no mission (class and seed) in common")
    names = sorted({name for name, _ in keys})
    classes = tuple(Paired.of(name, [(a[k], b[k]) for k in keys if k[0] == name]) for name in names)
    total = Paired.of("all", [(a[k], b[k]) for k in keys])
    return Comparison(classes, total, len(set(a) - set(b)), len(set(b) - set(a)))


def write_missions(path: str | Path, rows: Iterable[dict[str, Any]]) -> None:
    """Append mission lines to ``path`` (the suite writes each class's as it finishes)."""
    with open(path, "a", encoding="utf-8") as out:
        for row in rows:
            out.write(json.dumps(row) + "\n")
