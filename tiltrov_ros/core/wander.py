"""The wander oracle: can the servos follow the demand as the current wanders?

:mod:`.steady` asks whether *one* wrench, the one that holds the setpoint in
the mean current, is attainable within the servo range. A current that
fluctuates moves that demand about, and a configuration that produces one
demand need not be reachable from the configuration that produced the
last one: with the paper's servos (+-90 deg) a thrust line that has to turn
past vertical needs its twin, 180 deg of servo travel away. This oracle asks
the question of the whole wander: is there, for every way the current can
wander, a continuous path of tilts within the servo range, at the servo
rate, along which the thrusters produce the demand within the wrench
tolerance all the time?

What it models
    The demand is the steady wrench of :func:`.steady.steady_wrench` (eqs.
    (1), (A.3), (A.4) at rest relative to the ground: drag and Munk moment of
    the current at the setpoint attitude, restoring forces with the true
    center of gravity, the lasting external wrench) for the current
    ``v_c = mean + delta``, delta in the *wander box* ``|delta_i| <= 2 sigma_i``
    per NED axis (:data:`WANDER_SIGMAS`; sigma the Gauss-Markov part's
    standard deviation, ``current_std``), sampled on a grid of
    :data:`WANDER_POINTS` per fluctuating axis (27 demands for the
    campaigns' three fluctuating axes).

    *Configurations* are tilt pairs (servo angles). At each grid point the
    candidates are every exact solution of eq. (4) (the closed form of
    :mod:`.allocation.closed_form`: the paper's Section 3.1, made complete),
    also of the demand with those of X, Y, K, N that are within their
    tolerance set to zero (:data:`RELAXED`: near a one-parameter family of
    solutions the roots move fast, the family's members are within
    tolerance), with each twin of its thrust lines within the range (a twin at most
    :data:`EDGE_REACH` past an edge is tried at the edge), the allocator's best
    configuration within the range, and those of the mean current; one
    counts when the least-squares thrusts within the thrust limit at its tilts
    (the allocator's own, :mod:`.allocation.thrusts`) leave every wrench
    component within its tolerance
    (:func:`~tiltrov_ros.core.allocation.shortfall_tolerances`: 0.4 N, 0.08 N m
    for the shipped robot).

    Two configurations at neighbouring grid points are *linked* when the servos
    can go from one to the other while the current goes from one demand to
    the other: the straight move is at most :data:`LINK_STEP`, within
    tolerance at the points :data:`PATH_CHECKS` along it for the demands
    along the current's step, and no faster than the servo rate while the
    current moves at :data:`SPEED_SIGMAS` of its one-second standard
    deviations per second. A configuration that moves further along a branch
    of exact solutions is followed through the step halved, :data:`DEPTH`
    times at most, with the exact solutions at the points in between (never
    to a twin on the other side of the range: that is a flip through the
    range's edge, during which the demand is not met).

    The current is the adversary: a configuration is *viable* when, whichever
    neighbouring grid point the current moves to, it is linked to a viable
    configuration there (the greatest such set, found by removing what fails
    until nothing does, as in arc consistency). The wander is *followable*
    when a viable configuration exists at the mean current. Hysteresis is
    allowed: which configuration follows may depend on the way the current
    came. A configuration within tolerance of every demand of the box (and of
    the halfway demands) needs no travel at all and is checked first.

What it does not model
    The controller: its reaction to the errors (the demand of a real run
    wanders further than the steady wrench does, and a controller may ask in
    directions the configuration cannot give quickly), the thrusters' lag,
    the travel to the first viable configuration after a setpoint change, and
    whether a controller that meets the demand within the tolerance but not
    exactly settles within a hold criterion. Between the grid's points and
    edges it trusts the grid: a hole in the attainable set smaller than a
    grid step can be missed. The current's direction is not turned with the
    robot's yaw (the setpoint attitude is fixed). A fixed current (no
    ``current_std``) is a single demand: followable is then attainable within
    the range, as the steady oracle says, up to the configurations tried. The
    servo rate binds only where configurations move fast with the demand: the
    campaigns' current (sigma 0.02 m/s, 60 s correlation time) moves 0.011
    m/s per second by the speed above, and a branch moving 10 deg per 0.01 m/s
    of current needs 11 deg/s.

:func:`wander_reach` answers for one run's final setpoint (:func:`from_meta`
from a run's meta). numpy only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import itertools
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core.allocation import (
    SHORTFALL_FRACTION,
    ThrustAllocator,
    shortfall_tolerances,
)
from tiltrov_ros.core.allocation.allocator import DEFAULT_WEIGHTS
from tiltrov_ros.core.allocation.closed_form import solve_batch
from tiltrov_ros.core.allocation.decomposition import Geometry
from tiltrov_ros.core.allocation.thrusts import TiltProblem
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.steady import run_setting, steady_wrench
from tiltrov_ros.core.thrust_map import thrust_wrench

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: The wander box: the mean current plus up to this many standard deviations of its
#: Gauss-Markov part per NED axis (a run of 60 s started at the mean, with the
#: scenarios' 60 s correlation time, stays within it on an axis 86 times in 100).
WANDER_SIGMAS = 2.0
#: Grid points per fluctuating axis of the wander box (odd: the mean is one). 5
#: gave the same answer on 142 of 143 runs that missed (one more grid point without
#: a configuration within tolerance) at 4 times the cost.
WANDER_POINTS = 3
#: rad: the largest tilt move between two linked configurations without bisecting.
LINK_STEP = math.radians(10.0)
#: Points along a straight move between two configurations, and of the current's
#: step meanwhile, at which the tolerance is checked (besides both ends).
PATH_CHECKS = (0.25, 0.5, 0.75)
#: rad: configurations further apart than this at neighbouring grid points are
#: never followed through a bisected step.
LINK_REACH = math.radians(45.0)
#: How many times a grid step is halved to follow a configuration that moves further
#: than LINK_STEP.
DEPTH = 3
#: The current's speed while it wanders: this many standard deviations of its change
#: over one second, per second (per axis: 3 sigma sqrt(1 - exp(-2 s / T_c)) / s).
SPEED_SIGMAS = 3.0
#: Wrench components (X, Y, K, N) that, within their tolerance, are also tried at zero:
#: the families of exact solutions (docs/allocation.md) are where they vanish.
RELAXED = (0, 1, 3, 5)
#: Configurations whose tilts agree to this (rad) are the same one.
SAME_TILTS = 1e-6
#: rad: a twin of an exact solution this far past an edge of the range is tried at
#: the edge (the tolerance may still hold there).
EDGE_REACH = math.radians(20.0)


@dataclass(frozen=True)
class Reach:
    """The wander oracle's answer (:func:`wander_reach`).

    followable : a viable configuration exists at the mean current
    points : grid points of the wander box (1 without fluctuation)
    viable : viable configurations at the mean current (distinct tilts)
    tilts : (tilt_front, tilt_rear) of the viable configuration nearest to the
        allocator's best one at the mean, rad; None when not followable
    reason : '' when followable; else why not: ``unattainable`` (some grid point
        has no configuration within tolerance at all; ``worst`` is its current
        deviation) or ``no path`` (every configuration is left behind somewhere)
    worst : NED deviation of the current (m/s) where it fails, or None
    """

    followable: bool
    points: int
    viable: int
    tilts: tuple[float, float] | None
    reason: str
    worst: tuple[float, float, float] | None


class _Demands:
    """The steady demand, its configurations within tolerance, per current deviation."""

    def __init__(self, robot: RobotParams, quaternion: ArrayLike, current: ArrayLike,
                 external: ArrayLike | None, weights: Sequence[float], fraction: float,
                 limits: tuple[float, float]) -> None:
        self.robot = robot
        self.quaternion = np.asarray(quaternion, dtype=float)
        self.current = np.asarray(current, dtype=float)
        self.external = None if external is None else np.asarray(external, dtype=float)
        self.weights = np.asarray(weights, dtype=float)
        self.tolerances = shortfall_tolerances(robot, fraction)
        self.lo, self.hi = limits
        self.geometry = Geometry(robot.length, robot.width)
        self.best = ThrustAllocator(robot.length, robot.width, robot.max_thrust, limits,
                                    math.inf, 'robust', tuple(self.weights), planning=False)
        self._tau: dict[tuple[float, ...], FloatArray] = {}
        self._problem: dict[tuple[float, ...], TiltProblem] = {}

    def tau(self, delta: FloatArray) -> FloatArray:
        key = tuple(delta.tolist())
        if key not in self._tau:
            self._tau[key] = steady_wrench(self.robot, self.quaternion, self.current + delta,
                                           self.external)
        return self._tau[key]

    def ratios(self, delta: FloatArray, tilts: FloatArray) -> FloatArray:
        """(m,) largest shortfall / tolerance of the least-squares thrusts at each of
        the (m, 2) tilts, for the demand at the current deviation ``delta``."""
        if len(tilts) == 0:
            return np.zeros(0)
        key = tuple(delta.tolist())
        tau = self.tau(delta)
        problem = self._problem.get(key)
        if problem is None:
            problem = TiltProblem(self.geometry, tau, self.robot.max_thrust, self.weights)
            self._problem[key] = problem
        scaled, _, _ = problem.exact(tilts[:, 0], tilts[:, 1])
        achieved = thrust_wrench(scaled * problem.scale, tilts[:, 0], tilts[:, 1],
                                 self.robot.length, self.robot.width)
        out: FloatArray = np.max(np.abs(achieved - tau) / self.tolerances, axis=1)
        return out

    def twins(self, angle: float) -> list[float]:
        """Servo angles in range with the thrust line ``angle`` (mod pi); a twin at most
        EDGE_REACH past an edge is taken at the edge."""
        out = []
        k = math.ceil((self.lo - EDGE_REACH - angle) / math.pi)
        while angle + k * math.pi <= self.hi + EDGE_REACH:
            out.append(min(max(angle + k * math.pi, self.lo), self.hi))
            k += 1
        return out

    def exact(self, tau: FloatArray) -> list[tuple[float, float]]:
        """Every twin in range of every exact solution of ``tau``, and of ``tau`` with
        any of its components X, Y, K, N that are within their tolerance set to zero
        (near a one-parameter family of solutions, which such a wrench is, the family's
        members are within tolerance too, where the roots of ``tau`` itself move
        fast)."""
        small = [k for k in RELAXED if abs(tau[k]) <= self.tolerances[k]]
        variants = []
        for count in range(len(small) + 1):
            for zeroed in itertools.combinations(small, count):
                variant = tau.copy()
                variant[list(zeroed)] = 0.0
                variants.append(variant)
        solved = solve_batch(self.geometry, np.array(variants))
        out: list[tuple[float, float]] = []
        for i, j in zip(*np.nonzero(solved.valid)):
            a, b = solved.tilts[i, j].tolist()
            out += list(itertools.product(self.twins(a), self.twins(b)))
        return out

    def best_tilts(self, tau: FloatArray) -> FloatArray:
        """(1, 2): the allocator's best configuration within the range."""
        result = self.best.allocate(tau)
        return np.array([[result.tilt_front, result.tilt_rear]])


def _unique(tilts: FloatArray) -> FloatArray:
    if len(tilts) == 0:
        return tilts.reshape(0, 2)
    keys = np.round(tilts / SAME_TILTS).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    out: FloatArray = tilts[np.sort(first)]
    return out


def _grid(std: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The wander box's grid: (n, 3) deviations, the (3,) spacing per axis (0: fixed)."""
    axes, spacing = [], np.zeros(3)
    for i, s in enumerate(std.tolist()):
        if s > 0.0:
            axes.append(np.linspace(-WANDER_SIGMAS * s, WANDER_SIGMAS * s, WANDER_POINTS))
            spacing[i] = 2.0 * WANDER_SIGMAS * s / (WANDER_POINTS - 1)
        else:
            axes.append(np.zeros(1))
    grid = np.array(list(itertools.product(*axes)), dtype=float)
    return grid, spacing


def _followable(ta: FloatArray, tb: FloatArray) -> BoolArray:
    """(len(tb),): which of ``tb`` a branch of solutions from ``ta`` may reach through a
    bisected grid step: further than LINK_STEP, within LINK_REACH, and the same way
    round in servo angles as in thrust lines (a twin pi away, the same line from the
    other side of the range, is reached only through the edge: never)."""
    servo = np.max(np.abs(tb - ta), axis=1)
    turn = np.abs(tb - ta)
    line = np.max(np.minimum(turn % math.pi, math.pi - turn % math.pi), axis=1)
    out: BoolArray = (servo > LINK_STEP) & (servo <= LINK_REACH) & (servo - line < LINK_STEP)
    return out


def _neighbours(grid: FloatArray, spacing: FloatArray) -> list[list[int]]:
    """Each grid point's neighbours: one axis, one step."""
    out: list[list[int]] = [[] for _ in grid]
    for i, j in _edges(grid, spacing):
        out[i].append(j)
        out[j].append(i)
    return out


def _edges(grid: FloatArray, spacing: FloatArray) -> list[tuple[int, int]]:
    """Pairs of neighbouring grid points (one axis, one step), each once."""
    cells = np.round(grid / np.where(spacing > 0, spacing, 1.0)).astype(int)
    index = {tuple(c.tolist()): i for i, c in enumerate(cells)}
    out = []
    for key, i in index.items():
        for axis in np.flatnonzero(spacing > 0).tolist():
            other = list(key)
            other[axis] += 1
            j = index.get(tuple(other))
            if j is not None:
                out.append((i, j))
    return out


class _Follow:
    """Configurations within tolerance at a current deviation, and the links between
    those of neighbouring deviations (see the module docstring)."""

    def __init__(self, demands: _Demands, rate: float, std: FloatArray,
                 time_constant: FloatArray) -> None:
        self.d = demands
        self.rate = rate
        # m/s per s along each axis: SPEED_SIGMAS one-second standard deviations
        tc = np.where(time_constant > 0, time_constant, 1.0)
        self.speed = SPEED_SIGMAS * std * np.sqrt(1.0 - np.exp(-2.0 / tc))
        self._exact: dict[tuple[float, ...], FloatArray] = {}

    def feasible(self, delta: FloatArray, tilts: FloatArray) -> BoolArray:
        """Which rows of ``tilts`` are within tolerance of the demand at ``delta``."""
        out: BoolArray = self.d.ratios(delta, tilts) <= 1.0
        return out

    def exact(self, delta: FloatArray) -> FloatArray:
        """(m, 2) every twin in range of every exact solution at ``delta``, within
        tolerance there (the thrust limit)."""
        key = tuple(delta.tolist())
        if key not in self._exact:
            tilts = _unique(np.array(self.d.exact(self.d.tau(delta)),
                                     dtype=float).reshape(-1, 2))
            self._exact[key] = tilts[self.feasible(delta, tilts)]
        return self._exact[key]

    def seconds(self, da: FloatArray, db: FloatArray) -> float:
        """s the current takes from ``da`` to ``db`` (neighbours along one axis)."""
        step = np.abs(db - da)
        axis = int(np.argmax(step))
        return float(step[axis] / self.speed[axis]) if self.speed[axis] > 0 else math.inf

    def direct(self, da: FloatArray, ta: FloatArray, db: FloatArray, tb: FloatArray
               ) -> BoolArray:
        """(len(ta), len(tb)): configurations ``ta`` at ``da`` linked to ``tb`` at ``db``
        without bisecting (module docstring)."""
        move = np.max(np.abs(ta[:, None, :] - tb[None, :, :]), axis=2)
        close = (move <= LINK_STEP) & (move <= self.rate * self.seconds(da, db))
        out = np.zeros(move.shape, dtype=bool)
        pairs = np.argwhere(close)
        for f in PATH_CHECKS:
            if not len(pairs):
                break
            way = (1.0 - f) * ta[pairs[:, 0]] + f * tb[pairs[:, 1]]
            pairs = pairs[self.feasible((1.0 - f) * da + f * db, way)]
        out[pairs[:, 0], pairs[:, 1]] = True
        return out

    def components(self, delta: FloatArray, tilts: FloatArray) -> NDArray[np.intp]:
        """Labels of the configurations ``tilts`` at ``delta`` that the servos can move
        between while the demand stays there (chains of straight moves of at most
        LINK_STEP within tolerance all along: a family of exact solutions, a region the
        tolerance allows)."""
        n = len(tilts)
        label = np.arange(n)
        if n < 2:
            return label
        move = np.max(np.abs(tilts[:, None, :] - tilts[None, :, :]), axis=2)
        pairs = np.argwhere(np.triu(move <= LINK_STEP, 1))
        for f in PATH_CHECKS:
            if not len(pairs):
                break
            way = (1.0 - f) * tilts[pairs[:, 0]] + f * tilts[pairs[:, 1]]
            pairs = pairs[self.feasible(delta, way)]

        def root(k: int) -> int:
            while label[k] != k:
                label[k] = label[label[k]]
                k = int(label[k])
            return k

        for a, b in pairs.tolist():
            ra, rb = root(a), root(b)
            if ra != rb:
                label[max(ra, rb)] = min(ra, rb)
        return np.array([root(k) for k in range(n)], dtype=np.intp)

    def layered(self, da: FloatArray, ta: FloatArray, db: FloatArray, tb: FloatArray,
                depth: int) -> BoolArray:
        """(len(ta), len(tb)): linked through the grid step cut into 2**depth steps,
        following the exact solutions at the points in between."""
        n = 2 ** depth
        points = [da + (k / n) * (db - da) for k in range(n + 1)]
        layers = [ta] + [self.exact(x) for x in points[1:-1]] + [tb]
        reach = np.eye(len(ta), dtype=bool)
        for k in range(n):
            if 0 < k:               # moves within the layer's components
                label = self.components(points[k], layers[k])
                reach = reach | (reach.astype(np.int64) @ (
                    label[:, None] == label[None, :]).astype(np.int64) > 0)
            rows = reach.any(axis=0)
            step = np.zeros((len(layers[k]), len(layers[k + 1])), dtype=bool)
            step[rows] = self.direct(points[k], layers[k][rows], points[k + 1],
                                     layers[k + 1])
            reach = (reach.astype(np.int64) @ step.astype(np.int64)) > 0
            if not reach.any():
                return np.zeros((len(ta), len(tb)), dtype=bool)
        return reach


class _Game:
    """Arc consistency over the grid: a component of configurations (the servos move
    freely within one while the demand stays) stays while each neighbouring grid point
    has a viable configuration linked to one of its members. Links are found lazily: a
    configuration is checked against those of a neighbouring point only until one link
    to a viable one is found, and a grid step is bisected only when no direct link
    does."""

    def __init__(self, follow: _Follow, grid: FloatArray, nodes: list[FloatArray],
                 neighbours: list[list[int]]) -> None:
        self.f = follow
        self.grid = grid
        self.nodes = nodes
        self.neighbours = neighbours
        self.label = [follow.components(delta, n) for delta, n in zip(grid, nodes)]
        self.alive = [np.ones(len(n), dtype=bool) for n in nodes]
        # (i, a, j) -> per node of j: 1 linked, 0 not, -1 not yet known
        self._known: dict[tuple[int, int, int], NDArray[np.int8]] = {}
        self._layered: dict[tuple[int, int], tuple[int, BoolArray]] = {}

    def supported(self, i: int, a: int, j: int) -> bool:
        """Is configuration ``a`` of grid point ``i`` linked to a viable one of ``j``?"""
        known = self._known.get((i, a, j))
        if known is None:
            known = np.full(len(self.nodes[j]), -1, dtype=np.int8)
            self._known[(i, a, j)] = known
        alive = self.alive[j]
        if np.any((known == 1) & alive):
            return True
        ta, tb = self.nodes[i][a], self.nodes[j]
        todo = np.flatnonzero((known == -1) & alive)
        if len(todo):
            linked = self.f.direct(self.grid[i], ta[None, :], self.grid[j], tb[todo])[0]
            known[todo] = linked
            if linked.any():
                return True
        if not np.any(alive & (known != 1) & _followable(ta, tb)):
            return False
        # The edge's links through bisection, shared by both directions.
        key, flip = ((i, j), False) if i < j else ((j, i), True)
        depth, reach = self._layered.get(key, (0, np.zeros(
            (len(self.nodes[key[0]]), len(self.nodes[key[1]])), dtype=bool)))
        while True:
            linked = (reach[:, a] if flip else reach[a]) & alive
            if linked.any():
                known[linked] = 1
                return True
            if depth == DEPTH:
                return False
            depth += 1
            p, q = key
            reach = reach | self.f.layered(self.grid[p], self.nodes[p], self.grid[q],
                                           self.nodes[q], depth)
            self._layered[key] = (depth, reach)

    def solve(self) -> int:
        """Remove what is not viable, until nothing more is or a grid point has lost its
        last configuration: that point (then nothing is viable), else -1."""
        queue = [(i, j) for i in range(len(self.grid)) for j in self.neighbours[i]]
        queued = set(queue)
        while queue:
            i, j = queue.pop()
            queued.discard((i, j))
            removed = False
            for component in np.unique(self.label[i][self.alive[i]]).tolist():
                members = np.flatnonzero(self.alive[i] & (self.label[i] == component))
                if not any(self.supported(i, a, j) for a in members.tolist()):
                    self.alive[i][members] = False
                    removed = True
            if removed:
                if not self.alive[i].any():
                    return i
                for k in self.neighbours[i]:
                    if (k, i) not in queued:
                        queue.append((k, i))
                        queued.add((k, i))
        return -1


def wander_reach(robot: RobotParams, quaternion: ArrayLike, current: ArrayLike,
                 current_std: ArrayLike = (0.0, 0.0, 0.0),
                 current_time_constant: ArrayLike = (60.0, 60.0, 60.0),
                 external: ArrayLike | None = None,
                 weights: Sequence[float] = DEFAULT_WEIGHTS,
                 fraction: float = SHORTFALL_FRACTION,
                 limits: tuple[float, float] | None = None) -> Reach:
    """Whether the servos of ``robot`` (the true one: its r_g with the center-of-mass
    error) can follow the steady demand of the setpoint attitude ``quaternion`` as the
    NED ``current`` (m/s) wanders by its Gauss-Markov part (``current_std`` m/s,
    ``current_time_constant`` s per axis), against the lasting ``external`` wrench
    (module docstring). ``limits``: the servo range (default the robot's)."""
    rng = (robot.tilt_min, robot.tilt_max) if limits is None else limits
    demands = _Demands(robot, quaternion, current, external, weights, fraction, rng)
    std = np.asarray(current_std, dtype=float)
    grid, spacing = _grid(std)
    follow = _Follow(demands, robot.tilt_rate_limit, std,
                     np.asarray(current_time_constant, dtype=float))
    centre = len(grid) // 2
    best = demands.best_tilts(demands.tau(grid[centre]))
    neighbours = _neighbours(grid, spacing)
    # At each grid point: its exact solutions and the allocator's best configuration
    # there, those of its neighbours and those of the mean current (near a family of
    # solutions, or where the tolerance is wide, one configuration does for several
    # demands).
    own = [np.vstack([follow.exact(delta), demands.best_tilts(demands.tau(delta))])
           for delta in grid]
    nodes = []
    for i, delta in enumerate(grid):
        tried = _unique(np.vstack([own[i], own[centre], *(own[j] for j in neighbours[i])]))
        nodes.append(tried[follow.feasible(delta, tried)])
    empty = [i for i, n in enumerate(nodes) if len(n) == 0]
    if empty:
        worst = grid[max(empty, key=lambda i: float(np.sum(np.abs(grid[i]))))]
        return Reach(False, len(grid), 0, None, 'unattainable',
                     tuple(float(v) for v in worst))          # type: ignore[arg-type]
    # A configuration within tolerance of every demand of the box needs no travel.
    steady = _unique(np.vstack(own))
    for delta in [*grid, *(0.5 * (grid[i] + grid[j]) for i, j in _edges(grid, spacing))]:
        steady = steady[follow.feasible(delta, steady)]
        if len(steady) == 0:
            break
    if len(steady):
        nearest = steady[int(np.argmin(np.max(np.abs(steady - best[0]), axis=1)))]
        return Reach(True, len(grid), len(steady), (float(nearest[0]), float(nearest[1])),
                     '', None)
    game = _Game(follow, grid, nodes, neighbours)
    emptied = game.solve()
    viable = nodes[centre][game.alive[centre]]
    if emptied >= 0 or len(viable) == 0:
        # One grid point without a viable configuration leaves none anywhere (the grid
        # is connected): the game stops there.
        return Reach(False, len(grid), 0, None, 'no path',
                     tuple(float(v) for v in grid[emptied if emptied >= 0 else centre]))  # type: ignore[arg-type]
    nearest = viable[int(np.argmin(np.max(np.abs(viable - best[0]), axis=1)))]
    return Reach(True, len(grid), len(viable), (float(nearest[0]), float(nearest[1])), '',
                 None)


def from_meta(meta: Mapping[str, Any], quaternion: ArrayLike,
              limits: tuple[float, float] | None = None) -> Reach | None:
    """:func:`wander_reach` for a run's final setpoint attitude from its meta
    (:func:`~tiltrov_ros.core.steady.run_setting`); None when the meta lacks what it
    needs."""
    setting = run_setting(meta)
    if setting is None:
        return None
    dist = setting.disturbances
    try:
        return wander_reach(setting.robot, quaternion, dist['current'],
                            dist.get('current_std', (0.0, 0.0, 0.0)),
                            dist.get('current_time_constant', (60.0, 60.0, 60.0)),
                            setting.external, setting.weights, limits=limits)
    except (TypeError, ValueError, KeyError):     # ParameterError is a ValueError
        return None
