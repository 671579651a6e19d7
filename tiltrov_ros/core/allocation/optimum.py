"""The per-tick optimum: the least weighted wrench error over a box of tilts.

c(a, b) (:mod:`.thrusts`) is not convex: it has several basins, valleys along
which an exact solution moves, and sharp features near the tilts where the
thrust map is singular (both pairs level, both vertical). The search:

1. a grid over the box, spacing at most :data:`GRID_STEP`, evaluated with the
   cheap bounds of :meth:`.thrusts.TiltProblem.bounds` (one numpy pass), plus
   the caller's starts (exact solutions brought into the box, the previous
   tilts, a planner target);
2. the best few local minima of the upper bound (at most :data:`SEEDS`, in
   distinct cells) and the starts are refined by a projected Newton method on
   the exact c with its analytic gradient and Hessian (:mod:`.local`), with
   backtracking; a point that starts where an earlier one did (a start on a
   grid point, exact solutions clipped to the same corner of the box) is
   refined once;
3. the best refined point wins.

c is pi-periodic in each tilt (a tilt and its twin pi away are the same
thrust line, thrust negated), so a grid over any pi-wide window sees every
configuration; a box wider than pi is searched over one window and the
answer moved to the twin nearest to where the servos are.

An optional motion penalty adds (mu |theta - previous|)^2 to c, so the
servos do not chase differences that are tiny compared with the wrench.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

import numpy as np

from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.local import Evaluation, evaluate
from tiltrov_ros.core.allocation.thrusts import TiltProblem

#: rad, largest grid spacing of the search.
GRID_STEP = math.radians(7.5)
#: Local minima of the grid refined (besides the caller's starts).
SEEDS = 3
_NEWTON_STEPS = 20
_MIN_STEP = 1e-9          # rad: a smaller Newton step ends the search


def _grid(lo: float, hi: float, periodic: bool) -> FloatArray:
    if periodic:
        n = math.ceil(math.pi / GRID_STEP)
        grid: FloatArray = np.linspace(lo, lo + math.pi, n, endpoint=False)
        return grid
    n = max(2, math.ceil((hi - lo) / GRID_STEP) + 1)
    out: FloatArray = np.linspace(lo, hi, n)
    return out


def _best_cells(values: FloatArray, shape: tuple[int, int], count: int) -> list[int]:
    """Flat indices of the ``count`` best grid values at least two cells apart
    (one per basin, roughly)."""
    nb = shape[1]
    chosen: list[tuple[int, int]] = []
    for i in np.argsort(values, kind='stable')[:8 * count].tolist():
        ia, ib = divmod(i, nb)
        if all(abs(ia - ja) > 1 or abs(ib - jb) > 1 for ja, jb in chosen):
            chosen.append((ia, ib))
            if len(chosen) == count:
                break
    return [ia * nb + ib for ia, ib in chosen]


class Search:
    """The search over one box for one wrench (scaled units of ``problem``)."""

    def __init__(self, problem: TiltProblem, box: FloatArray,
                 anchor: FloatArray | None = None, penalty: float = 0.0,
                 periodic: tuple[bool, bool] = (False, False)) -> None:
        self.problem = problem
        self.box = box
        self.periodic = periodic
        # Bounds that the Newton steps respect (none along a periodic tilt).
        self.limits = [(-math.inf, math.inf) if periodic[p] else (float(box[p, 0]),
                                                                   float(box[p, 1]))
                       for p in range(2)]
        self.anchor = anchor              # previous tilts (for the motion penalty)
        self.mu2 = penalty * penalty if anchor is not None else 0.0
        self.evaluations = 0

    def value(self, e: Evaluation) -> float:
        """The objective: c plus the motion penalty."""
        if not self.mu2 or self.anchor is None:
            return e.cost
        da, db = e.a - float(self.anchor[0]), e.b - float(self.anchor[1])
        return e.cost + self.mu2 * (da * da + db * db)

    def _eval(self, a: float, b: float, hint: Sequence[int] | None = None) -> Evaluation:
        self.evaluations += 1
        return evaluate(self.problem, a, b, hint)

    def clip(self, a: float, b: float) -> tuple[float, float]:
        """(a, b) within the limits: where :meth:`refine` starts."""
        (alo, ahi), (blo, bhi) = self.limits
        return min(max(a, alo), ahi), min(max(b, blo), bhi)

    def refine(self, a: float, b: float, radius: float = 0.1) -> Evaluation:
        """Trust-region Newton from (a, b) within the box.

        The step minimises the quadratic model within a radius (exactly, in two
        dimensions: :func:`_trust_step`), so a saddle or a valley whose floor
        slopes towards the box is crossed as safely as a bowl; the radius grows
        and shrinks with how well the model predicted the decrease. A tilt
        within ``eps`` of a bound that the gradient pushes against is held there
        (Bertsekas' projected Newton), so an optimum on the edge of the box,
        the usual case when the servos cannot reach further, is found by a
        one-dimensional Newton method along the edge.
        """
        (alo, ahi), (blo, bhi) = self.limits
        eps = min(1e-3, 0.1 * (ahi - alo), 0.1 * (bhi - blo))
        a, b = self.clip(a, b)
        e = self._eval(a, b)
        best = self.value(e)
        mu2 = self.mu2
        anchor_a, anchor_b = ((float(self.anchor[0]), float(self.anchor[1]))
                              if self.anchor is not None else (0.0, 0.0))
        for _ in range(_NEWTON_STEPS):
            ga = e.grad[0] + 2.0 * mu2 * (e.a - anchor_a)
            gb = e.grad[1] + 2.0 * mu2 * (e.b - anchor_b)
            haa, hab, hbb = e.hess[0] + 2.0 * mu2, e.hess[1], e.hess[2] + 2.0 * mu2
            hold_a = (e.a - alo <= eps and ga > 0.0) or (ahi - e.a <= eps and ga < 0.0)
            hold_b = (e.b - blo <= eps and gb > 0.0) or (bhi - e.b <= eps and gb < 0.0)
            if hold_a and hold_b:
                da, db = (alo if ga > 0.0 else ahi) - e.a, (blo if gb > 0.0 else bhi) - e.b
            elif hold_a:
                da, db = (alo if ga > 0.0 else ahi) - e.a, _trust_step_1d(hbb, gb, radius)
            elif hold_b:
                da, db = _trust_step_1d(haa, ga, radius), (blo if gb > 0.0 else bhi) - e.b
            else:
                da, db = _trust_step(haa, hab, hbb, ga, gb, radius)
            ta, tb = min(max(e.a + da, alo), ahi), min(max(e.b + db, blo), bhi)
            da, db = ta - e.a, tb - e.b
            predicted = -(ga * da + gb * db + 0.5 * (haa * da * da + 2.0 * hab * da * db
                                                      + hbb * db * db))
            if predicted <= 1e-7 * best or max(abs(da), abs(db)) < _MIN_STEP:
                break
            trial = self._eval(ta, tb, e.bounds)
            v = self.value(trial)
            ratio = (best - v) / predicted
            size = max(abs(da), abs(db))
            if ratio < 0.25:
                radius = 0.25 * size
            elif ratio > 0.75 and size >= 0.9 * radius:
                radius = min(2.0 * radius, 1.0)
            if v < best:
                e, best = trial, v
            if radius < _MIN_STEP:
                break
        return e

    def run(self, starts: Sequence[FloatArray] = (), seeds: int = SEEDS) -> Evaluation:
        """The best point found from the grid's local minima and ``starts``."""
        (alo, ahi), (blo, bhi) = self.box.tolist()
        ga, gb = _grid(alo, ahi, self.periodic[0]), _grid(blo, bhi, self.periodic[1])
        A, B = np.repeat(ga, len(gb)), np.tile(gb, len(ga))
        _, upper = self.problem.bounds(A, B)
        if self.mu2 and self.anchor is not None:
            upper = upper + self.mu2 * ((A - self.anchor[0]) ** 2 + (B - self.anchor[1]) ** 2)
        points = [(float(A[i]), float(B[i]))
                  for i in _best_cells(upper, (len(ga), len(gb)), seeds)]
        points += [(float(s[0]), float(s[1])) for s in starts if np.all(np.isfinite(s))]
        best: Evaluation | None = None
        refined: set[tuple[float, float, float, float]] = set()
        for a, b in points:
            # A point that starts where one before did (a start on a grid point, two
            # exact solutions clipped to the same corner) repeats its refinement and
            # cannot beat it: skipped. Signs of zeros count (atan2 tells them apart).
            ca, cb = self.clip(a, b)
            key = (ca, cb, math.copysign(1.0, ca), math.copysign(1.0, cb))
            if key in refined:
                continue
            refined.add(key)
            e = self.refine(a, b)
            if best is None or self.value(e) < self.value(best):
                best = e
        assert best is not None
        return best

    def minima(self, count: int, below: float) -> list[Evaluation]:
        """Up to ``count`` distinct local minima of c with c < ``below``, best first."""
        return _minima(self, count, below)


def _trust_step_1d(h: float, g: float, radius: float) -> float:
    """argmin g s + h s^2 / 2 over |s| <= radius."""
    if h > 0.0 and abs(g) <= h * radius:
        return -g / h
    return -math.copysign(radius, g) if g != 0.0 else (radius if h < 0.0 else 0.0)


def _trust_step(haa: float, hab: float, hbb: float, ga: float, gb: float,
                radius: float) -> tuple[float, float]:
    """argmin g's + s'Hs/2 over |s| <= radius, exactly (2 x 2 H; More and Sorensen)."""
    # Eigen-decomposition of the symmetric 2 x 2 Hessian.
    mean, half = 0.5 * (haa + hbb), 0.5 * (haa - hbb)
    root = math.hypot(half, hab)
    l1, l2 = mean - root, mean + root
    if root > 0.0:
        theta = 0.5 * math.atan2(2.0 * hab, haa - hbb)
        c, s = math.cos(theta), math.sin(theta)
        q2, q1 = (c, s), (-s, c)            # eigenvectors of l2 and l1
    else:
        q1, q2 = (1.0, 0.0), (0.0, 1.0)
    g1, g2 = q1[0] * ga + q1[1] * gb, q2[0] * ga + q2[1] * gb

    def step(mu: float) -> tuple[float, float]:
        return -g1 / max(l1 + mu, 1e-300), -g2 / max(l2 + mu, 1e-300)

    if l1 > 0.0:
        x1, x2 = step(0.0)
        if x1 * x1 + x2 * x2 <= radius * radius:
            return x1 * q1[0] + x2 * q2[0], x1 * q1[1] + x2 * q2[1]
    lo = max(0.0, -l1)
    if g1 == 0.0 and g2 == 0.0 and lo == 0.0:
        return 0.0, 0.0                        # a stationary point with no descent
    if g1 == 0.0 and lo > 0.0:
        # Hard case: move along the direction of negative curvature.
        x2 = -g2 / (l2 + lo) if l2 + lo > 0.0 else 0.0
        x1 = math.sqrt(max(radius * radius - x2 * x2, 0.0))
        return x1 * q1[0] + x2 * q2[0], x1 * q1[1] + x2 * q2[1]
    hi = lo + math.hypot(g1, g2) / radius + 1e-300
    lo += 1e-300
    for _ in range(60):                       # bisection on |s(mu)| = radius
        mid = 0.5 * (lo + hi)
        x1, x2 = step(mid)
        if x1 * x1 + x2 * x2 > radius * radius:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hi:
            break
    x1, x2 = step(hi)
    return x1 * q1[0] + x2 * q2[0], x1 * q1[1] + x2 * q2[1]


def _minima(search: Search, count: int, below: float) -> list[Evaluation]:
    """Up to ``count`` refined local minima with c below ``below``, best first.

    Seeds are the best grid cells whose upper bound is below twice ``below``
    (the bound overestimates where the thrust limit binds).
    """
    (alo, ahi), (blo, bhi) = search.box.tolist()
    ga, gb = _grid(alo, ahi, search.periodic[0]), _grid(blo, bhi, search.periodic[1])
    A, B = np.repeat(ga, len(gb)), np.tile(gb, len(ga))
    _, upper = search.problem.bounds(A, B)
    found: list[Evaluation] = []
    for i in _best_cells(upper, (len(ga), len(gb)), count):
        if upper[i] >= 2.0 * below:
            break
        e = search.refine(float(A[i]), float(B[i]))
        if e.cost < below and all(abs(e.a - f.a) + abs(e.b - f.b) > 1e-3 for f in found):
            found.append(e)
    return sorted(found, key=lambda e: e.cost)
