"""Robust mode when no exact solution is within reach: the per-tick optimum, then the planner.

1. The per-tick optimum (:mod:`.optimum`): the least weighted wrench error
   ||W (tau(f, alpha, beta) - tau_d)|| over the thrusts within the limit and
   the tilts within this call's reach (``max_tilt_step`` from ``previous``),
   or over the whole tilt range without ``previous``, where a tilt and its
   twin pi away are the same configuration (the search wraps through
   +-90 deg and the answer takes the twin in range nearest to 0). Warm
   starts: the exact solutions and the paper mode's answer brought into
   reach, the previous tilts, the planner's target. The paper mode's answer is
   kept if nothing beats it, so the robust error is never worse than the paper
   mode's.
2. The planner (:mod:`.planner`), with ``previous``, a finite reach and all
   four thrusters (with one failed it is off: measured in the
   ``thruster_failure`` scenario, its travels cost 11 deg of roll): the
   targets are the exact solutions in range (every twin; family members that
   keep one pair where it is), or, for a wrench no configuration produces,
   the best configurations over the whole range when they beat the per-tick
   optimum (by :data:`GLOBAL_GAIN`); the servos travel (method ``transit``)
   when that costs less over the horizon than staying.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math

import numpy as np

from tiltrov_ros.core.allocation.closed_form import solve_batch
from tiltrov_ros.core.allocation.decomposition import ExactConfig, FloatArray
from tiltrov_ros.core.allocation.limits import LIMIT_SLACK, Limits
from tiltrov_ros.core.allocation.local import evaluate
from tiltrov_ros.core.allocation.optimum import Search
from tiltrov_ros.core.allocation.planner import Target, plan
from tiltrov_ros.core.allocation.results import AllocationResult
from tiltrov_ros.core.allocation.selection import variants
from tiltrov_ros.core.allocation.thrusts import TiltProblem

#: Targets of the planner that are not exact must beat the per-tick optimum by
#: this factor (in squared error) to be considered.
GLOBAL_GAIN = 0.9
#: At most this many global minima become targets.
GLOBAL_TARGETS = 3


@dataclass(frozen=True)
class Options:
    """Robust-mode settings of one allocator (see ``ThrustAllocator``)."""

    motion_penalty: float
    planning: bool
    horizon: int


def _nearest_in_box(limits: Limits, tilts: FloatArray, box: FloatArray) -> FloatArray:
    """Per tilt, of gamma and its twins (the same thrust line), the one nearest to the
    box, clipped into it: a warm start."""
    out = np.empty(2)
    for p in range(2):
        options = np.float64(tilts[p]) + np.array([0.0, math.pi, -math.pi])
        clipped = np.clip(options, box[p, 0], box[p, 1])
        out[p] = clipped[int(np.argmin(np.abs(options - clipped)))]
    return out


def _in_range(limits: Limits, a: float, b: float, f: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The twin of (a, b) in the tilt range nearest to 0, thrusts signed accordingly."""
    tilts, out = np.zeros(2), np.array(f, dtype=float)
    for p, angle in enumerate((a, b)):
        twins = limits.twins(angle)
        if not twins:                        # range narrower than pi: nearest edge
            tilts[p] = min(max(angle, limits.tilt_min), limits.tilt_max)
            continue
        pick = min(twins, key=lambda t: (round(abs(t[0]), 12), -t[1]))
        tilts[p] = pick[0]
        out[2 * p:2 * p + 2] *= pick[1]
    return tilts, out


def per_tick_optimum(limits: Limits, problem: TiltProblem, prev: FloatArray | None,
                     box: FloatArray, starts: list[FloatArray], penalty: float
                     ) -> tuple[FloatArray, FloatArray, float]:
    """(tilts, thrusts [N], scaled cost c) of the least error within ``box``."""
    wide = limits.tilt_max - limits.tilt_min >= math.pi - LIMIT_SLACK
    periodic = prev is None and wide
    search_box = box
    if periodic:
        search_box = np.array([[limits.tilt_min, limits.tilt_min + math.pi]] * 2)
    points = [s if periodic else _nearest_in_box(limits, s, box) for s in starts
              if np.all(np.isfinite(s))]
    e = Search(problem, search_box, prev, penalty, (periodic, periodic)).run(points)
    f = np.array(e.thrusts) * problem.scale
    if periodic:
        tilts, f = _in_range(limits, e.a, e.b, f)
    else:
        tilts = np.array([e.a, e.b])
    return tilts, f, e.cost


def _exact_targets(limits: Limits, tau: FloatArray, configs: list[ExactConfig],
                   prev: FloatArray) -> list[Target]:
    """Exact solutions in range (every twin) as targets: the closed-form roots, and
    family members that keep one pair's tilt where it is."""
    full = np.array([[limits.tilt_min, limits.tilt_max]] * 2)
    pool = list(configs)
    if any(c.family for c in configs) or not configs:
        solved = solve_batch(limits.geometry, tau[None, :], prev[None, :, None])
        pool = [ExactConfig(solved.thrusts[0, j], solved.tilts[0, j],
                            bool(solved.family[0, j]),
                            (bool(solved.tilt_free[0, j, 0]), bool(solved.tilt_free[0, j, 1])))
                for j in np.flatnonzero(solved.valid[0])]
    fmax = limits.max_thrust * (1.0 + LIMIT_SLACK)
    out: dict[tuple[float, float], Target] = {}
    for cfg in pool:
        for f, (a, b) in variants(limits, cfg, prev, full):
            if max(abs(v) for v in f) > fmax:
                continue
            key = (round(a, 9), round(b, 9))
            out.setdefault(key, Target((a, b), 0.0))
    return list(out.values())


def _global_targets(limits: Limits, problem: TiltProblem, local_cost: float) -> list[Target]:
    """The best configurations over the whole range, when they beat ``local_cost``."""
    lo, hi = limits.tilt_min, limits.tilt_max
    wide = hi - lo >= math.pi - LIMIT_SLACK
    box = np.array([[lo, lo + math.pi if wide else hi]] * 2)
    search = Search(problem, box, periodic=(wide, wide))
    out: list[Target] = []
    for e in search.minima(GLOBAL_TARGETS, below=GLOBAL_GAIN * local_cost):
        fronts = limits.twins(e.a) if wide else [(e.a, 1.0)]
        rears = limits.twins(e.b) if wide else [(e.b, 1.0)]
        out.extend(Target((fa, rb), e.cost) for fa, _ in fronts for rb, _ in rears)
    return out


def _targets(limits: Limits, problem: TiltProblem, tau: FloatArray,
             configs: list[ExactConfig], prev: FloatArray, cost: float) -> list[Target]:
    """Exact solutions in range, else the best configurations over the range."""
    return _exact_targets(limits, tau, configs, prev) or _global_targets(limits, problem, cost)


def fallback(limits: Limits, options: Options, tau: FloatArray, configs: list[ExactConfig],
             disc: float, previous: AllocationResult | None, prev: FloatArray | None,
             box: FloatArray, incumbent: AllocationResult | None) -> AllocationResult:
    """Robust mode's answer when no exact solution qualifies (see the module docstring)."""
    problem = TiltProblem(limits.geometry, tau, limits.max_thrust, limits.weights,
                          limits.available)
    starts = [c.tilts for c in configs]
    if incumbent is not None:
        starts.append(incumbent.tilts)
    if prev is not None:
        starts.append(prev)
    if previous is not None and previous.target is not None:
        starts.append(np.array(previous.target))
    tilts, thrusts, cost = per_tick_optimum(limits, problem, prev, box, starts,
                                            options.motion_penalty)
    result = limits.make(tau, thrusts, tilts, 'optimized', disc)
    if incumbent is not None and incumbent.error <= result.error:
        result, cost = incumbent, (incumbent.error / problem.scale) ** 2
    stuck = (previous.stuck if previous is not None else 0) + 1
    result = replace(result, stuck=stuck)
    if not (options.planning and prev is not None and math.isfinite(limits.max_tilt_step)
            and not limits.failed):
        return result
    targets = _targets(limits, problem, tau, configs, prev, cost)
    travelling = previous is not None and previous.method == 'transit'
    kept = previous.target if travelling and previous is not None else None
    if kept is not None:
        targets.append(Target(kept, evaluate(problem, kept[0], kept[1]).cost))
    chosen = plan(problem, prev, limits.max_tilt_step, cost, targets, options.horizon, kept)
    if chosen is None:
        return result
    a, b = float(chosen.tilts[0]), float(chosen.tilts[1])
    e = evaluate(problem, a, b)
    transit = limits.make(tau, np.array(e.thrusts) * problem.scale, chosen.tilts, 'transit',
                          disc)
    return replace(transit, target=chosen.target.tilts, stuck=stuck)
