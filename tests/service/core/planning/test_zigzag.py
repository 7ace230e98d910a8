import itertools
import math

import numpy as np
import pytest

from service.core.grid import Grid
from service.core.planning.cast import cast_vertices
from service.core.planning.crossflow import FlowFrame
from service.core.planning.zigzag import sweeps_upflow_first, zigzag_vertices

PAPER = Grid(0.0, 100.0, -50.0, 50.0, columns=40, rows=25)


def crossings(track: list[tuple[float, float]], frame: FlowFrame, s: float) -> list[float]:
    """Along-flow coordinates where the polyline crosses the cross-flow coordinate s."""
    out = []
    for (x0, y0), (x1, y1) in itertools.pairwise(track):
        s0, s1 = frame.cross(x0, y0), frame.cross(x1, y1)
        a0, a1 = frame.along(x0, y0), frame.along(x1, y1)
        if min(s0, s1) - 1e-9 <= s <= max(s0, s1) + 1e-9:
            t = 0.5 if s1 == s0 else (s - s0) / (s1 - s0)
            out.append(a0 + t * (a1 - a0))
    return out


def swept_band_gaps(
    grid: Grid, start: tuple[float, float], frame: FlowFrame, spacing: float, upflow: bool
) -> float:
    """The largest along-flow distance from a cell centre in the swept band to the track at the
    centre's own cross-flow position."""
    verts = zigzag_vertices(grid, *start, frame, spacing, upflow=upflow)
    track = [start] + [(v.x, v.y) for v in verts]
    a_start = frame.along(*start)
    a_end = frame.along(verts[-1].x, verts[-1].y)
    lo, hi = min(a_start, a_end), max(a_start, a_end)
    worst = 0.0
    for y in grid.y_centres:
        for x in grid.x_centres:
            a = frame.along(x, y)
            if not lo <= a <= hi:
                continue
            hits = crossings(track, frame, frame.cross(x, y))
            assert hits, f"the track never crosses the cross-flow position of ({x}, {y})"
            worst = max(worst, min(abs(a - h) for h in hits))
    return worst


@pytest.mark.parametrize(
    ("flow", "start", "upflow"),
    [
        ((1.0, 0.0), (90.0, 10.0), True),  # flow East: legs run North-South, advancing West
        ((0.0, 0.5), (40.0, 45.0), True),  # flow North from the north edge: advancing South
        ((-2.0, 0.0), (3.0, -49.0), True),  # flow West from the west edge
        ((0.0, -1.0), (60.0, 20.0), False),  # flow South, sweeping downflow
    ],
)
def test_zigzag_covers_the_area_across_the_flow(
    flow: tuple[float, float], start: tuple[float, float], upflow: bool
) -> None:
    frame = FlowFrame.from_flow(*flow)
    spacing = 10.0
    verts = zigzag_vertices(PAPER, *start, frame, spacing, upflow=upflow)
    x_lo, x_hi = PAPER.x_centres[0], PAPER.x_centres[-1]
    y_lo, y_hi = PAPER.y_centres[0], PAPER.y_centres[-1]
    # every turning point is inside the area, on the edge of the centre hull across the flow
    for v in verts:
        assert x_lo - 1e-9 <= v.x <= x_hi + 1e-9
        assert y_lo - 1e-9 <= v.y <= y_hi + 1e-9
    cross = [frame.cross(v.x, v.y) for v in verts]
    ends = sorted({round(c, 6) for c in cross})
    assert len(ends) == 2  # the two sides of the area across the flow...
    assert all(round(a, 6) != round(b, 6) for a, b in itertools.pairwise(cross))  # ...alternately
    hull_cross = sorted(frame.cross(x, y) for x in (x_lo, x_hi) for y in (y_lo, y_hi))
    assert ends[0] == pytest.approx(hull_cross[0])
    assert ends[1] == pytest.approx(hull_cross[-1])
    # successive legs advance by the spacing, the last one reaching the edge of the area
    along = [frame.along(v.x, v.y) for v in verts]
    steps = np.diff(along)
    direction = -1.0 if upflow else 1.0
    assert np.all(steps * direction > 0)
    assert np.all(np.abs(steps) <= spacing + 1e-9)
    hull_along = sorted(frame.along(x, y) for x in (x_lo, x_hi) for y in (y_lo, y_hi))
    assert along[-1] == pytest.approx(hull_along[0] if upflow else hull_along[-1])
    # coverage: every cell of the swept band is crossed within one spacing along the flow
    assert swept_band_gaps(PAPER, start, frame, spacing, upflow) <= spacing + 1e-9


def test_zigzag_oblique_flows_cover_within_two_spacings() -> None:
    # An oblique flow makes the cross-section change along the flow: each leg spans the band
    # between the lines either side of it, so a cell is crossed within two spacings.
    rng = np.random.default_rng(1)
    for _ in range(8):
        angle = rng.uniform(0.0, 2.0 * math.pi)
        frame = FlowFrame(math.cos(angle), math.sin(angle))
        start = (float(rng.uniform(0.0, 100.0)), float(rng.uniform(-50.0, 50.0)))
        spacing = float(rng.uniform(5.0, 20.0))
        for upflow in (True, False):
            assert swept_band_gaps(PAPER, start, frame, spacing, upflow) <= 2.0 * spacing + 1e-9


def test_first_leg_goes_to_the_far_side() -> None:
    frame = FlowFrame.from_flow(1.0, 0.0)  # cross axis points North
    verts = zigzag_vertices(PAPER, 50.0, -40.0, frame, 10.0)
    assert verts[0].y == pytest.approx(PAPER.y_centres[-1])
    assert verts[0].x == pytest.approx(50.0)
    assert verts[1].y == pytest.approx(PAPER.y_centres[0])
    assert verts[1].x == pytest.approx(40.0)


def test_calm_water_uses_the_fallback_direction() -> None:
    east = FlowFrame.from_flow(0.0, 0.0)
    assert (east.ux, east.uy) == (1.0, 0.0)
    north = FlowFrame(0.0, 1.0)
    assert FlowFrame.from_flow(1e-9, 0.0, north) is north
    assert FlowFrame.from_flow(0.0, -3.0).angle_to(north) == pytest.approx(math.pi)


def test_bad_spacing() -> None:
    with pytest.raises(ValueError, match="spacing"):
        zigzag_vertices(PAPER, 1.0, 1.0, FlowFrame(1.0, 0.0), 0.0)


def test_cast_alternates_across_the_flow_and_widens() -> None:
    frame = FlowFrame.from_flow(0.0, 1.0)  # flow North: cross axis points West
    verts = cast_vertices(PAPER, 50.0, 0.0, frame, 10.0, 4)
    assert [(v.x, v.y) for v in verts] == [
        pytest.approx((40.0, 0.0)),
        pytest.approx((60.0, 0.0)),
        pytest.approx((30.0, 0.0)),
        pytest.approx((70.0, 0.0)),
    ]


def test_cast_is_clipped_to_the_area_and_merges_repeats() -> None:
    frame = FlowFrame.from_flow(1.0, 0.0)  # cross axis points North
    verts = cast_vertices(PAPER, 20.0, 40.0, frame, 10.0, 6)
    top, bottom = PAPER.y_centres[-1], PAPER.y_centres[0]
    # +10, +20 and +30 all clip to the northern row of centres: it is visited once
    assert [v.y for v in verts] == pytest.approx([top, 30.0, 20.0, 10.0])
    assert all(bottom <= v.y <= top and v.x == pytest.approx(20.0) for v in verts)
    assert cast_vertices(PAPER, 20.0, 40.0, frame, 10.0, 0) == ()


def test_a_start_near_the_upflow_edge_sweeps_downflow_first() -> None:
    east = FlowFrame.from_flow(1.0, 0.0)  # the upflow edge is the West one; centres from x = 1.25
    edge = PAPER.x_centres[0]
    assert not sweeps_upflow_first(PAPER, edge, 10.0, east, 30.0)
    assert not sweeps_upflow_first(PAPER, edge + 29.9, -40.0, east, 30.0)
    assert sweeps_upflow_first(PAPER, edge + 30.0, -40.0, east, 30.0)
    assert sweeps_upflow_first(PAPER, 98.75, 0.0, east, 30.0)
    # the same start, the flow reversed: now it is far from the upflow (East) edge
    assert sweeps_upflow_first(PAPER, edge, 10.0, FlowFrame.from_flow(-1.0, 0.0), 30.0)
    # a flow North: the upflow edge is the South one
    north = FlowFrame.from_flow(0.0, 2.0)
    assert not sweeps_upflow_first(PAPER, 50.0, -40.0, north, 10.0)
    assert sweeps_upflow_first(PAPER, 50.0, -30.0, north, 10.0)
    # "near" is a distance: 45 m takes in a start 40 m from the edge that 30 m leaves out
    assert not sweeps_upflow_first(PAPER, edge + 40.0, 0.0, east, 45.0)
