"""The planner kernels (``kernels/plan.py``) against ``planner``.

Seeded cases (``allocation_cases``) with targets as the robust fallback makes
them: exact solutions (cost 0) and global minima (their cost) anywhere in
range, some within this call's reach (no route), some exactly one step away;
a kept target (a travel under way) or none; steps of 3, 7.5 and 20 deg and
infinite; horizons of 1, 5, the default two 180 deg travels and one long
enough that numpy's pairwise summation splits the path; local costs on both
sides of the best route's. Paths equal exactly; route costs to relative 1e-9;
the plan (None or the same tilts and target) equal.
"""

from __future__ import annotations

import math

from allocation_cases import RANGES, assert_close, atol, cases, count, make_case
import numpy as np

from tiltrov_ros.core.allocation.allocator import DEFAULT_WEIGHTS
from tiltrov_ros.core.allocation.kernels import plan as kplan
from tiltrov_ros.core.allocation.planner import Target, path, plan, routes

CASES = cases(seed=51, n=count(60, 15))
NO_KEPT = np.array([math.nan, math.nan])


def _targets(rng: np.random.Generator, case_index: int, start: np.ndarray, step: float,
             lo: float, hi: float) -> np.ndarray:
    """Rows (a, b, c): exact ones (c = 0), costed ones, one within reach, one a step away."""
    n = int(rng.integers(1, 6))
    rows = np.column_stack([rng.uniform(lo, hi, (n, 2)),
                            np.where(rng.random(n) < 0.5, 0.0, rng.uniform(0.0, 2.0, n))])
    near = np.r_[np.clip(start + rng.uniform(-step, step, 2), lo, hi), 0.0]
    edge = np.r_[start + np.array([step, 0.0]), rng.uniform(0.0, 1.0)]
    extra = [near] if case_index % 2 else [edge]
    return np.vstack([rows, *extra])


def test_paths_equal_the_reference() -> None:
    rng = np.random.default_rng(52)
    for _ in range(count(300, 60)):
        lo, hi = RANGES[int(rng.integers(3))]
        start, goal = rng.uniform(lo, hi, (2, 2))
        if rng.random() < 0.2:
            goal[rng.integers(2)] = start[rng.integers(2)]
        step = float(rng.choice([math.radians(3.0), math.radians(7.5), math.radians(20.0)]))
        for order in (0, 1, 2):
            ref = path(start, goal, step, order)
            n = kplan.path_length(start, goal, step, order)
            got = np.array([kplan.path_point(start, goal, step, order, k) for k in range(n)])
            assert n == len(ref)
            if n:
                np.testing.assert_array_equal(got, ref)


def test_routes_and_plans_equal_the_reference() -> None:
    rng = np.random.default_rng(53)
    out = np.empty(5)
    chosen = {'none': 0, 'travel': 0, 'kept': 0}
    for i, case in enumerate(CASES):
        lo, hi = RANGES[i % len(RANGES)]
        for _ in range(4):
            step = float(rng.choice([math.radians(3.0), math.radians(7.5), math.radians(20.0)]))
            horizon = int(rng.choice([1, 5, 2 * math.ceil(math.pi / step), 300]))
            start = rng.uniform(lo, hi, 2)
            rows = _targets(rng, i, start, step, lo, hi)
            targets = [Target((float(a), float(b)), float(c)) for a, b, c in rows]
            ref_routes = routes(case.reference, start, step, targets, horizon)
            got = np.empty((3 * len(rows), kplan.ROUTE_SIZE))
            n = kplan.routes(case.prob, start, step, rows, len(rows), horizon, got)
            assert n == len(ref_routes)
            for r, ref in zip(got[:n], ref_routes):
                assert targets[int(r[kplan.ROUTE_TARGET])] is ref.target
                assert r[kplan.ROUTE_TICKS] == ref.ticks
                np.testing.assert_array_equal(r[kplan.ROUTE_FIRST:kplan.ROUTE_FIRST + 2],
                                              ref.first)
                assert_close(r[kplan.ROUTE_COST], ref.cost, atol(case) * horizon, str(rows))
            best = min((r.cost for r in ref_routes), default=1.0)
            for factor in (0.5, 0.99, 1.01, 2.0):
                local = best * factor / horizon
                kept_row = int(rng.integers(len(rows)))
                for kept in (None, (float(rows[kept_row, 0]), float(rows[kept_row, 1]) + 5e-10)):
                    ref_plan = plan(case.reference, start, step, local, targets, horizon, kept)
                    found = kplan.plan(case.prob, start, step, local, rows, len(rows), horizon,
                                       NO_KEPT if kept is None else np.array(kept), out)
                    what = f'case {i} rows={rows.tolist()} local={local} kept={kept}'
                    assert found == (ref_plan is not None), what
                    if ref_plan is None:
                        chosen['none'] += 1
                        continue
                    chosen['travel' if kept is None else 'kept'] += 1
                    np.testing.assert_array_equal(out[:2], ref_plan.tilts, err_msg=what)
                    assert tuple(out[2:4]) == ref_plan.target.tilts, what
                    assert out[4] == ref_plan.target.cost, what
    assert all(chosen.values()), chosen


def test_no_plan_without_targets_or_with_an_infinite_step() -> None:
    case = CASES[0]
    out = np.empty(5)
    start = np.zeros(2)
    rows = np.array([[1.0, -1.0, 0.0]])
    assert not kplan.plan(case.prob, start, math.inf, 1.0, rows, 1, 10, NO_KEPT, out)
    assert not kplan.plan(case.prob, start, 0.1, 1.0, rows, 0, 10, NO_KEPT, out)
    assert plan(case.reference, start, math.inf, 1.0, [Target((1.0, -1.0), 0.0)], 10) is None


def test_route_sums_add_in_numpys_order() -> None:
    """Bit for bit np.sum (pairwise) on every length up to 300 and a few long ones: the
    choice between two routes of nearly equal cost falls as in the reference."""
    rng = np.random.default_rng(54)
    for n in [*range(1, 301), 1000, 4099]:
        a = rng.normal(size=n) * 10.0 ** rng.uniform(-5, 5, n)
        assert kplan._pairwise_sum(a, n) == float(np.sum(a)), n


def test_a_travel_under_way_is_not_abandoned_for_a_slightly_better_target() -> None:
    """The planner does not chase: from (10, 10) deg, the route to (80, 85) deg costs
    0.1 % less than the route to (85, 80) deg; a fresh plan takes the cheaper, a travel
    under way to (85, 80) keeps going there (its target still beats staying). The
    kernels plan the same."""
    case = make_case(np.array([1.0, 0.0, 5.0, 0.0, 0.5, 0.0]), np.array(DEFAULT_WEIGHTS),
                     np.ones(4, dtype=bool))
    problem = case.reference
    start, step, horizon = np.radians([10.0, 10.0]), math.radians(7.5), 48
    going, better = (Target((math.radians(a), math.radians(b)), 0.0)
                     for a, b in ((85.0, 80.0), (80.0, 85.0)))
    costs = [min(r.cost for r in routes(problem, start, step, [t], horizon))
             for t in (going, better)]
    assert costs[1] < costs[0] < 1.01 * costs[1]
    local = 1.0                                   # staying is worse than either travel
    fresh = plan(problem, start, step, local, [going, better], horizon)
    kept = plan(problem, start, step, local, [going, better], horizon, going.tilts)
    assert fresh is not None and fresh.target is better
    assert kept is not None and kept.target is going
    rows = np.array([[*going.tilts, 0.0], [*better.tilts, 0.0]])
    out = np.empty(5)
    for keep, target in ((NO_KEPT, better), (np.array(going.tilts), going)):
        assert kplan.plan(case.prob, start, step, local, rows, 2, horizon, keep, out)
        np.testing.assert_array_equal(out[2:4], target.tilts)
