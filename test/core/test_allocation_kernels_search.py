"""The search kernels (``kernels/search.py``) against ``optimum.Search``.

Seeded cases (``allocation_cases``) searched over the boxes the allocator
uses: 7.5 deg of reach around previous tilts (clipped to the range), the
whole range with previous tilts and no rate limit, the whole range wrapped
through +-90 deg (periodic) without them; over +-90, +-120 and +-180 deg
ranges; with and without the anchor and its motion penalty; with the
caller's starts (the previous tilts, points on the box's corners where the
grid has its own points, random ones, non-finite ones to be skipped).

The answer's cost equals the reference's to relative 1e-9 (absolute floor
``allocation_cases.atol``), and so do its tilts, thrusts and
derivatives where the minimum is unique. A tie (another refined point within
1e-9 of the best value) may pick the other point: the test finds each one
among the reference's refined points and counts them; none is hidden.
"""

from __future__ import annotations

import math

from allocation_cases import HALF_PI, RANGES, STEP, assert_close, atol, cases, count
import numpy as np
import pytest

from tiltrov_ros.core.allocation.kernels import layout as lay
from tiltrov_ros.core.allocation.kernels import search
from tiltrov_ros.core.allocation.optimum import SEEDS, Search, _best_cells, _grid

CASES = cases(seed=41, n=count(90, 24))
BOXES = ('reach', 'full', 'periodic')


def _record(e: object) -> np.ndarray:
    a, b, cost, grad, hess, thrusts, bounds = e  # type: ignore[misc]
    return np.array([a, b, cost, *grad, *hess, *thrusts, *bounds], dtype=float)


def _setup(case_index: int, kind: str, rng: np.random.Generator
           ) -> tuple[np.ndarray, np.ndarray | None, float, bool, np.ndarray]:
    """(box, anchor, penalty, periodic, starts) as ``robust.per_tick_optimum`` makes them."""
    lo, hi = RANGES[case_index % len(RANGES)]
    prev = rng.uniform(lo, hi, 2)
    if case_index % 7 == 0:
        prev[rng.integers(2)] = rng.choice([lo, hi, 0.0])
    if kind == 'periodic':
        box = np.array([[lo, lo + math.pi]] * 2)
        starts = [rng.uniform(lo, hi, 2), rng.uniform(-math.pi, math.pi, 2)]
        return box, None, 0.0, True, np.array(starts)
    if kind == 'reach':
        box = np.column_stack([np.maximum(lo, prev - STEP), np.minimum(hi, prev + STEP)])
    else:
        box = np.array([[lo, hi]] * 2)
    corner = box[[0, 1], [rng.integers(2), rng.integers(2)]]
    starts = [prev, corner, rng.uniform(box[:, 0], box[:, 1]), np.array([math.nan, 0.0])]
    penalty = (0.0, 1e-3, 0.05)[case_index % 3]
    anchor = None if case_index % 4 == 3 else prev
    return box, anchor, penalty, False, np.array(starts)


def _refined(s: Search, starts: np.ndarray) -> list[tuple[float, np.ndarray]]:
    """Every point ``Search.run`` refines, as (value, record)."""
    (alo, ahi), (blo, bhi) = s.box.tolist()
    ga, gb = _grid(alo, ahi, s.periodic[0]), _grid(blo, bhi, s.periodic[1])
    A, B = np.repeat(ga, len(gb)), np.tile(gb, len(ga))
    _, upper = s.problem.bounds(A, B)
    if s.mu2 and s.anchor is not None:
        upper = upper + s.mu2 * ((A - s.anchor[0]) ** 2 + (B - s.anchor[1]) ** 2)
    points = [(A[i], B[i]) for i in _best_cells(upper, (len(ga), len(gb)), SEEDS)]
    points += [(p[0], p[1]) for p in starts if np.all(np.isfinite(p))]
    out = []
    for a, b in points:
        e = s.refine(float(a), float(b))
        out.append((s.value(e), _record(e)))
    return out


@pytest.mark.parametrize('kind', BOXES)
def test_run_equals_the_reference(kind: str) -> None:
    rng = np.random.default_rng({'reach': 42, 'full': 43, 'periodic': 44}[kind])
    rec = np.empty(lay.REC_SIZE)
    ties = []
    for i, case in enumerate(CASES):
        box, anchor, penalty, periodic, starts = _setup(i, kind, rng)
        s = Search(case.reference, box, anchor, penalty, (periodic, periodic))
        ref = _record(s.run(list(starts)))
        search.run(case.prob, np.ascontiguousarray(box),
                   np.zeros(2) if anchor is None else np.ascontiguousarray(anchor),
                   anchor is not None, penalty, periodic, periodic,
                   np.ascontiguousarray(starts), len(starts), rec)
        what = f'case {i} tau={case.tau.tolist()} box={box.tolist()} anchor={anchor}'
        floor = atol(case)
        assert_close(rec[lay.REC_COST:lay.REC_COST + 1], ref[lay.REC_COST:lay.REC_COST + 1],
                     floor, what)
        if np.allclose(rec[:2], ref[:2], rtol=0.0, atol=1e-9):
            assert rec[lay.REC_BOUNDS:].tolist() == ref[lay.REC_BOUNDS:].tolist(), what
            assert_close(rec, ref, floor, what)
            continue
        # Another point: only a tie may explain it, found among the refined points.
        best = s.value(s.run(list(starts)))
        tied = [r for v, r in _refined(s, starts)
                if abs(v - best) <= 1e-9 * abs(best) + floor
                and np.allclose(r[:2], rec[:2], rtol=0.0, atol=1e-9)]
        assert tied, what
        ties.append(i)
    print(f'{kind}: {len(ties)} ties of {len(CASES)} ({ties})')
    assert len(ties) <= len(CASES) // 10


@pytest.mark.parametrize('periodic', [True, False])
def test_minima_equal_the_reference(periodic: bool) -> None:
    """The global minima the planner's targets come from: the same number, each
    the same (best first), below thresholds that keep all, some or none. Over a
    range wider than pi a minimum and its twin pi away tie: either may come first;
    a minimum that differs must be one of the reference's own (its refinement
    stays there, at the same cost) and is counted."""
    rng = np.random.default_rng(45)
    recs = np.empty((4, lay.REC_SIZE))
    ties = 0
    for i, case in enumerate(CASES[::2]):
        lo, hi = RANGES[i % len(RANGES)]
        box = np.array([[lo, lo + math.pi if periodic else hi]] * 2)
        s = Search(case.reference, box, periodic=(periodic, periodic))
        scale = s.run().cost
        for below in (scale * rng.uniform(1.0, 3.0), scale * 1.2, scale * 0.5):
            for count_ in (0, 1, 3, 4):
                ref = [_record(e) for e in s.minima(count_, below)]
                found = search.minima(case.prob, box, periodic, periodic, count_, below, recs)
                what = f'case {i} periodic={periodic} below={below} count={count_}'
                assert found == len(ref), what
                for k, r in enumerate(ref):
                    if np.allclose(recs[k, :2], r[:2], rtol=0.0, atol=1e-9):
                        assert_close(recs[k], r, atol(case), what)
                        continue
                    assert_close(recs[k, lay.REC_COST], r[lay.REC_COST], atol(case), what)
                    own = _record(s.refine(float(recs[k, 0]), float(recs[k, 1])))
                    assert_close(own[:3], recs[k, :3], atol(case), what)
                    ties += 1
    print(f'minima, periodic={periodic}: {ties} tied minima in another order')


def test_narrow_boxes_at_the_range_edges() -> None:
    """Previous tilts exactly at +-90 deg and 0: a box clipped to 7.5 deg on one side,
    the Newton steps held on its edges."""
    rec = np.empty(lay.REC_SIZE)
    for i, case in enumerate(CASES[:count(30, 4)]):
        for prev in ((HALF_PI, -HALF_PI), (0.0, HALF_PI), (-HALF_PI, 0.0)):
            p = np.array(prev)
            box = np.column_stack([np.maximum(-HALF_PI, p - STEP), np.minimum(HALF_PI, p + STEP)])
            ref = _record(Search(case.reference, box, p, 1e-3).run([p]))
            search.run(case.prob, box, p, True, 1e-3, False, False, p[None].copy(), 1, rec)
            assert_close(rec, ref, atol(case), f'case {i} prev={prev}')


def test_a_start_repeated_is_refined_once() -> None:
    """Starts on the grid's corners and repeated ones (exact solutions clipped to the
    same corner) cost no refinement and change no answer, in both implementations."""
    rng = np.random.default_rng(46)
    rec_once, rec_twice = np.empty(lay.REC_SIZE), np.empty(lay.REC_SIZE)
    for i, case in enumerate(CASES[:count(30, 6)]):
        box, anchor, penalty, _, starts = _setup(i, 'reach', rng)
        s = Search(case.reference, box, anchor, penalty)
        once = s.run(list(starts[:2]))
        evaluations = s.evaluations
        twice = s.run([starts[1], *starts[:2], starts[1], starts[0] + 0.0])
        assert twice == once
        assert s.evaluations == 2 * evaluations
        for rows, rec in ((starts[:2], rec_once),
                          (np.vstack([starts[1], starts[:2], starts[1]]), rec_twice)):
            search.run(case.prob, box, np.zeros(2) if anchor is None else anchor,
                       anchor is not None, penalty, False, False, np.ascontiguousarray(rows),
                       len(rows), rec)
        np.testing.assert_array_equal(rec_twice, rec_once)
