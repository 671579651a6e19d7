"""Tilt planning: which way to move the servos when the best configuration is out of reach.

The per-tick optimum (:mod:`.optimum`) is the best the servos can do within
one step. When a better configuration lies further away (an exact solution
past the +-90 deg edge, whose twin is 180 deg of servo travel away; another
basin of the reduced cost; the configuration a new setpoint needs), the
greedy choice within one step can stay put for ever: every step towards the
better configuration first makes the error worse.

The planner looks ahead over a receding horizon of ``horizon`` calls with the
wrench held constant. For each target (:class:`Target`) out of reach it costs
three routes: both servos at full rate; the front pair first while the rear
holds; the rear first. A route's cost is the summed squared weighted error of
the best thrusts at each tick's tilts on the way (the cheap upper bound of
:meth:`.thrusts.TiltProblem.bounds`), then the target's error to the end of
the horizon. Travelling one pair at a time keeps the other pair working,
which is what usually makes a 180 deg flip affordable. The servos take the
first step of the cheapest route when it costs less than staying with the
per-tick optimum for the whole horizon, ``horizon * c_local``; the plan is made
again at the next call. A travel under way goes on while its target still
beats the per-tick optimum, so the servos do not turn back halfway when the
wrench moves a little.

Staying costs a little every tick, the travel a lot once: a small steady
error is kept until the controller's reaction to it has made it large enough
to pay for the travel within the horizon.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np

from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.thrusts import TiltProblem


@dataclass(frozen=True)
class Target:
    """Tilts (servo angles in range) worth travelling to, and their cost c (scaled)."""

    tilts: tuple[float, float]
    cost: float


@dataclass(frozen=True)
class Route:
    """One way to a target: its first step, its length (calls) and cost (scaled)."""

    target: Target
    first: FloatArray
    ticks: int
    cost: float          # summed along the path, then the target to the horizon


def path(start: FloatArray, goal: FloatArray, step: float, order: int) -> FloatArray:
    """(n, 2) tilts at each tick from ``start`` (excluded) to ``goal`` (included).

    order 0: both servos at full rate; 1: front first; 2: rear first.
    """
    distance = np.abs(goal - start)
    ticks = np.ceil(distance / step - 1e-9).astype(int)
    lo, hi = np.minimum(start, goal), np.maximum(start, goal)
    sign = np.sign(goal - start)
    if order == 0:
        k = np.arange(1, int(ticks.max()) + 1)[:, None]
        out: FloatArray = np.clip(start + sign * step * k, lo, hi)
        return out
    first, second = (0, 1) if order == 1 else (1, 0)
    n1, n2 = int(ticks[first]), int(ticks[second])
    out = np.empty((n1 + n2, 2))
    out[:n1, first] = np.clip(start[first] + sign[first] * step * np.arange(1, n1 + 1),
                              lo[first], hi[first])
    out[:n1, second] = start[second]
    out[n1:, first] = goal[first]
    out[n1:, second] = np.clip(start[second] + sign[second] * step * np.arange(1, n2 + 1),
                               lo[second], hi[second])
    return out


def routes(problem: TiltProblem, start: FloatArray, step: float, targets: Sequence[Target],
           horizon: int) -> list[Route]:
    """Every route to every target out of reach, costed over ``horizon`` calls."""
    paths: list[tuple[Target, FloatArray]] = []
    for target in targets:
        goal = np.array(target.tilts)
        away = np.abs(goal - start) > step * (1 + 1e-12)
        if not away.any():
            continue                                # within reach: the per-tick optimum
        for order in (0, 1, 2) if away.all() else (0,):
            paths.append((target, path(start, goal, step, order)))
    if not paths:
        return []
    points = np.vstack([p for _, p in paths])
    _, upper = problem.bounds(points[:, 0], points[:, 1])
    out = []
    offset = 0
    for target, way in paths:
        n = len(way)
        along = upper[offset:offset + n]
        offset += n
        cost = (float(np.sum(along[:horizon])) if n >= horizon
                else float(np.sum(along)) + (horizon - n) * target.cost)
        out.append(Route(target, way[0], n, cost))
    return out


@dataclass(frozen=True)
class Plan:
    """The first step of the chosen travel: this tick's tilts and where they lead."""

    tilts: FloatArray
    target: Target


def plan(problem: TiltProblem, start: FloatArray, step: float, local_cost: float,
         targets: Sequence[Target], horizon: int,
         kept: tuple[float, float] | None = None) -> Plan | None:
    """The travel to take, or None to stay with the per-tick optimum.

    ``start``: the tilts now; ``step``: servo reach per call; ``local_cost``: c of
    the per-tick optimum; ``targets``: configurations worth travelling to (one of
    them ``kept``, the target of a travel under way, if any).
    """
    if not targets or not math.isfinite(step):
        return None
    options = routes(problem, start, step, targets, horizon)
    if not options:
        return None
    if kept is not None:
        going = [r for r in options if abs(r.target.tilts[0] - kept[0]) <= 1e-9
                 and abs(r.target.tilts[1] - kept[1]) <= 1e-9]
        if going and going[0].target.cost < local_cost:
            route = min(going, key=lambda r: r.cost)
            return Plan(route.first, route.target)
    best = min(options, key=lambda r: r.cost)
    if best.cost < horizon * local_cost:
        return Plan(best.first, best.target)
    return None
