"""Kernels of the per-tick optimum's search: mirror :class:`..optimum.Search`.

* :func:`run`: ``Search(problem, box, anchor, penalty, periodic).run(starts)``,
  the best of the trust-region Newton refinements from the grid's best cells
  (cheap upper bounds of :mod:`.tiltcost` over a grid of at most 7.5 deg) and
  the caller's starts;
* :func:`minima`: ``Search(problem, box, periodic=...).minima(count, below)``.

A search is one call: the grid, the cells and every Newton step run here,
with every scratch array (that of :func:`.tiltcost.evaluate_into` too) carved
from one float and one int allocation per call.
Same operations in the same order as the reference (its constants are
imported from it), so the answers agree to rounding.
"""

from __future__ import annotations

import math

import numpy as np

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.kernels.activeset import (
    IWORK_SIZE,
    WORK_SIZE,
    IntArray,
    _py_max,
    _py_min,
)
from tiltrov_ros.core.allocation.kernels.layout import (
    REC_A,
    REC_B,
    REC_BOUNDS,
    REC_COST,
    REC_GRAD,
    REC_HESS,
    REC_SIZE,
)
from tiltrov_ros.core.allocation.kernels.tiltcost import bounds_trig, evaluate_into
from tiltrov_ros.core.allocation.optimum import _MIN_STEP, _NEWTON_STEPS, GRID_STEP, SEEDS

# Rows of the records of one search (float64[_RECS, REC_SIZE]).
_E, _TRIAL, _CAND, _BEST = 0, 1, 2, 3
_RECS = 4


# --------------------------------------------------------------------------- the grid

@jit.kernel()
def _grid_count(lo: float, hi: float, periodic: bool) -> int:
    """Points of ``..optimum._grid(lo, hi, periodic)``."""
    if periodic:
        return math.ceil(math.pi / GRID_STEP)
    return max(2, math.ceil((hi - lo) / GRID_STEP) + 1)


@jit.kernel()
def _grid_fill(lo: float, hi: float, periodic: bool, out: FloatArray) -> None:
    """``..optimum._grid`` into ``out`` (np.linspace's arithmetic)."""
    n = out.shape[0]
    stop = lo + math.pi if periodic else hi
    div = n if periodic else n - 1
    delta = stop - lo
    step = delta / div
    for i in range(n):
        out[i] = (i / div * delta if step == 0.0 else i * step) + lo
    if not periodic:
        out[n - 1] = stop


@jit.kernel()
def _grid_upper(prob: FloatArray, ga: FloatArray, gb: FloatArray, mu2: float, anchor_a: float,
                anchor_b: float, trig: FloatArray, upper: FloatArray) -> None:
    """The upper bound of c (plus the motion penalty) at every grid point, row-major
    (``TiltProblem.bounds(np.repeat(ga, nb), np.tile(gb, na))``); trig: (2, nb) scratch."""
    nb = gb.shape[0]
    for j in range(nb):
        trig[0, j], trig[1, j] = math.cos(gb[j]), math.sin(gb[j])
    for i in range(ga.shape[0]):
        ca, sa = math.cos(ga[i]), math.sin(ga[i])
        for j in range(nb):
            _, u = bounds_trig(prob, ca, sa, trig[0, j], trig[1, j])
            if mu2 != 0.0:
                da, db = ga[i] - anchor_a, gb[j] - anchor_b
                u = u + mu2 * (da * da + db * db)
            upper[i * nb + j] = u


@jit.kernel()
def _before(v: float, i: int, w: float, j: int) -> bool:
    """(v, i) precedes (w, j) in np.argsort(kind='stable') order (NaN last)."""
    if v != v:
        return w != w and i < j
    if w != w or v < w:
        return True
    return v == w and i < j


@jit.kernel()
def _best_cells(values: FloatArray, nb: int, count: int, order: IntArray,
                cells: IntArray) -> int:
    """``..optimum._best_cells``: flat indices into ``cells`` of the ``count`` best values
    at least two cells apart among the 8 ``count`` best; returns how many.
    order: int64 scratch of at least 8 ``count``."""
    m = min(8 * count, values.shape[0])
    if m <= 0:
        return 0
    filled = 0
    for i in range(values.shape[0]):               # the m smallest, in sorted order
        v = values[i]
        if filled == m and not _before(v, i, values[order[m - 1]], order[m - 1]):
            continue
        k = filled if filled < m else m - 1
        while k > 0 and _before(v, i, values[order[k - 1]], order[k - 1]):
            order[k] = order[k - 1]
            k -= 1
        order[k] = i
        if filled < m:
            filled += 1
    found = 0
    for r in range(filled):
        ia, ib = order[r] // nb, order[r] % nb
        apart = True
        for c in range(found):
            ja, jb = cells[c] // nb, cells[c] % nb
            if not (abs(ia - ja) > 1 or abs(ib - jb) > 1):
                apart = False
                break
        if apart:
            cells[found] = order[r]
            found += 1
            if found == count:
                break
    return found


# --------------------------------------------------------------------------- Newton

@jit.kernel()
def _trust_step_1d(h: float, g: float, radius: float) -> float:
    """``..optimum._trust_step_1d``: argmin g s + h s^2 / 2 over |s| <= radius."""
    if h > 0.0 and abs(g) <= h * radius:
        return -g / h
    if g != 0.0:
        return -math.copysign(radius, g)
    return radius if h < 0.0 else 0.0


@jit.kernel()
def _trust_step(haa: float, hab: float, hbb: float, ga: float, gb: float,
                radius: float) -> tuple[float, float]:
    """``..optimum._trust_step``: argmin g's + s'Hs/2 over |s| <= radius, exactly."""
    # Python floats for the plain-Python backend: the bisection's first steps overflow
    # to inf (as the reference's floats do) where numpy scalars would warn.
    haa, hab, hbb, ga, gb = float(haa), float(hab), float(hbb), float(ga), float(gb)
    mean, half = 0.5 * (haa + hbb), 0.5 * (haa - hbb)
    root = math.hypot(half, hab)
    l1, l2 = mean - root, mean + root
    q1a, q1b, q2a, q2b = 1.0, 0.0, 0.0, 1.0          # eigenvectors of l1 and l2
    if root > 0.0:
        theta = 0.5 * math.atan2(2.0 * hab, haa - hbb)
        c, s = math.cos(theta), math.sin(theta)
        q2a, q2b, q1a, q1b = c, s, -s, c
    g1, g2 = q1a * ga + q1b * gb, q2a * ga + q2b * gb
    r2 = radius * radius
    if l1 > 0.0:
        x1, x2 = -g1 / _py_max(l1, 1e-300), -g2 / _py_max(l2, 1e-300)
        if x1 * x1 + x2 * x2 <= r2:
            return x1 * q1a + x2 * q2a, x1 * q1b + x2 * q2b
    lo = _py_max(0.0, -l1)
    if g1 == 0.0 and g2 == 0.0 and lo == 0.0:
        return 0.0, 0.0                              # a stationary point with no descent
    if g1 == 0.0 and lo > 0.0:
        # Hard case: move along the direction of negative curvature.
        x2 = -g2 / (l2 + lo) if l2 + lo > 0.0 else 0.0
        x1 = math.sqrt(_py_max(r2 - x2 * x2, 0.0))
        return x1 * q1a + x2 * q2a, x1 * q1b + x2 * q2b
    hi = lo + math.hypot(g1, g2) / radius + 1e-300
    lo += 1e-300
    for _ in range(60):                              # bisection on |s(mu)| = radius
        mid = 0.5 * (lo + hi)
        x1, x2 = -g1 / _py_max(l1 + mid, 1e-300), -g2 / _py_max(l2 + mid, 1e-300)
        if x1 * x1 + x2 * x2 > r2:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-12 * hi:
            break
    x1, x2 = -g1 / _py_max(l1 + hi, 1e-300), -g2 / _py_max(l2 + hi, 1e-300)
    return x1 * q1a + x2 * q2a, x1 * q1b + x2 * q2b


@jit.kernel()
def _copy(src: FloatArray, dst: FloatArray) -> None:
    """dst[:REC_SIZE] = src[:REC_SIZE], as a loop (a slice assignment would compile
    numba's shape-mismatch error message, seconds of compile time)."""
    for i in range(REC_SIZE):
        dst[i] = src[i]


@jit.kernel()
def _value(rec: FloatArray, mu2: float, anchor_a: float, anchor_b: float) -> float:
    """``Search.value``: c plus the motion penalty (mu2 = 0 without an anchor)."""
    cost: float = rec[REC_COST]
    if mu2 == 0.0:
        return cost
    da, db = rec[REC_A] - anchor_a, rec[REC_B] - anchor_b
    penalised: float = cost + mu2 * (da * da + db * db)
    return penalised


@jit.kernel()
def _refine(prob: FloatArray, lim: FloatArray, mu2: float, anchor_a: float, anchor_b: float,
            a: float, b: float, recs: FloatArray, hint: IntArray, work: FloatArray,
            iwork: IntArray) -> None:
    """``Search.refine(a, b)`` (radius 0.1) into recs[_E]; lim: (alo, ahi, blo, bhi),
    infinite along a periodic tilt."""
    alo, ahi, blo, bhi = lim[0], lim[1], lim[2], lim[3]
    e, trial = recs[_E], recs[_TRIAL]
    radius = 0.1
    eps = _py_min(_py_min(1e-3, 0.1 * (ahi - alo)), 0.1 * (bhi - blo))
    a, b = _py_min(_py_max(a, alo), ahi), _py_min(_py_max(b, blo), bhi)
    evaluate_into(prob, a, b, hint, False, e, work, iwork)
    best = _value(e, mu2, anchor_a, anchor_b)
    for _ in range(_NEWTON_STEPS):
        ea, eb = e[REC_A], e[REC_B]
        ga = e[REC_GRAD] + 2.0 * mu2 * (ea - anchor_a)
        gb = e[REC_GRAD + 1] + 2.0 * mu2 * (eb - anchor_b)
        haa, hab, hbb = e[REC_HESS] + 2.0 * mu2, e[REC_HESS + 1], e[REC_HESS + 2] + 2.0 * mu2
        hold_a = (ea - alo <= eps and ga > 0.0) or (ahi - ea <= eps and ga < 0.0)
        hold_b = (eb - blo <= eps and gb > 0.0) or (bhi - eb <= eps and gb < 0.0)
        if hold_a and hold_b:
            da, db = (alo if ga > 0.0 else ahi) - ea, (blo if gb > 0.0 else bhi) - eb
        elif hold_a:
            da, db = (alo if ga > 0.0 else ahi) - ea, _trust_step_1d(hbb, gb, radius)
        elif hold_b:
            da, db = _trust_step_1d(haa, ga, radius), (blo if gb > 0.0 else bhi) - eb
        else:
            da, db = _trust_step(haa, hab, hbb, ga, gb, radius)
        ta, tb = _py_min(_py_max(ea + da, alo), ahi), _py_min(_py_max(eb + db, blo), bhi)
        da, db = ta - ea, tb - eb
        predicted = -(ga * da + gb * db + 0.5 * (haa * da * da + 2.0 * hab * da * db
                                                  + hbb * db * db))
        size = _py_max(abs(da), abs(db))
        if predicted <= 1e-7 * best or size < _MIN_STEP:
            break
        for i in range(4):
            hint[i] = int(e[REC_BOUNDS + i])
        evaluate_into(prob, ta, tb, hint, True, trial, work, iwork)
        v = _value(trial, mu2, anchor_a, anchor_b)
        ratio = (best - v) / predicted
        if ratio < 0.25:
            radius = 0.25 * size
        elif ratio > 0.75 and size >= 0.9 * radius:
            radius = _py_min(2.0 * radius, 1.0)
        if v < best:
            _copy(trial, e)
            best = v
        if radius < _MIN_STEP:
            break


# --------------------------------------------------------------------------- the searches

@jit.kernel()
def _scratch(box: FloatArray, periodic_a: bool, periodic_b: bool, count: int, rows: int
             ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
                        FloatArray, FloatArray, IntArray, IntArray, IntArray, IntArray]:
    """Every array of one search, as views of one float and one int allocation:
    (ga, gb, upper, trig, lim, recs, work, refined, cells, order, hint, iwork) for
    ``count`` cells and ``rows`` points refined at most."""
    na = _grid_count(box[0, 0], box[0, 1], periodic_a)
    nb = _grid_count(box[1, 0], box[1, 1], periodic_b)
    o1 = na
    o2 = o1 + nb
    o3 = o2 + na * nb
    o4 = o3 + 2 * nb
    o5 = o4 + 4
    o6 = o5 + _RECS * REC_SIZE
    o7 = o6 + WORK_SIZE
    f = np.empty(o7 + 2 * rows)
    c = max(count, 1)
    k = np.empty(9 * c + 4 + IWORK_SIZE, dtype=np.int64)
    return (f[:o1], f[o1:o2], f[o2:o3], f[o3:o4].reshape((2, nb)), f[o4:o5],
            f[o5:o6].reshape((_RECS, REC_SIZE)), f[o6:o7], f[o7:].reshape((rows, 2)),
            k[:c], k[c:9 * c], k[9 * c:9 * c + 4], k[9 * c + 4:])


@jit.kernel()
def _grid(prob: FloatArray, box: FloatArray, periodic_a: bool, periodic_b: bool, mu2: float,
          anchor_a: float, anchor_b: float, count: int, ga: FloatArray, gb: FloatArray,
          upper: FloatArray, trig: FloatArray, cells: IntArray, order: IntArray) -> int:
    """The grid over ``box`` (ga, gb), its upper bounds and its ``count`` best cells;
    returns the number of cells."""
    _grid_fill(box[0, 0], box[0, 1], periodic_a, ga)
    _grid_fill(box[1, 0], box[1, 1], periodic_b, gb)
    _grid_upper(prob, ga, gb, mu2, anchor_a, anchor_b, trig, upper)
    return _best_cells(upper, gb.shape[0], count, order, cells)


@jit.kernel()
def _limits(box: FloatArray, periodic_a: bool, periodic_b: bool, lim: FloatArray) -> None:
    """``Search.limits`` into lim = (alo, ahi, blo, bhi): none along a periodic tilt."""
    lim[0], lim[1] = (-math.inf, math.inf) if periodic_a else (box[0, 0], box[0, 1])
    lim[2], lim[3] = (-math.inf, math.inf) if periodic_b else (box[1, 0], box[1, 1])


@jit.kernel()
def _started(refined: FloatArray, n: int, a: float, b: float) -> bool:
    """(a, b) is one of refined[:n], signs of zeros included."""
    for i in range(n):
        ra, rb = refined[i, 0], refined[i, 1]
        if (ra == a and rb == b and math.copysign(1.0, ra) == math.copysign(1.0, a)
                and math.copysign(1.0, rb) == math.copysign(1.0, b)):
            return True
    return False


@jit.kernel('void(float64[::1], float64[:, ::1], float64[::1], boolean, float64, boolean, '
            'boolean, float64[:, ::1], int64, float64[::1])', group='allocation')
def run(prob: FloatArray, box: FloatArray, anchor: FloatArray, has_anchor: bool, penalty: float,
        periodic_a: bool, periodic_b: bool, starts: FloatArray, n_starts: int,
        rec: FloatArray) -> None:
    """``Search(problem, box, anchor if has_anchor else None, penalty,
    (periodic_a, periodic_b)).run(starts[:n_starts])`` into ``rec``."""
    n_starts = max(0, min(n_starts, starts.shape[0]))
    mu2 = penalty * penalty if has_anchor else 0.0
    anchor_a, anchor_b = (anchor[0], anchor[1]) if has_anchor else (0.0, 0.0)
    ga, gb, upper, trig, lim, recs, work, refined, cells, order, hint, iwork = _scratch(
        box, periodic_a, periodic_b, SEEDS, SEEDS + n_starts)
    _limits(box, periodic_a, periodic_b, lim)
    n = _grid(prob, box, periodic_a, periodic_b, mu2, anchor_a, anchor_b, SEEDS, ga, gb, upper,
              trig, cells, order)
    have = False
    nb = gb.shape[0]
    n_refined = 0                                   # refined[:n_refined]: where they started
    for k in range(n + n_starts):
        if k < n:
            a, b = ga[cells[k] // nb], gb[cells[k] % nb]
        else:
            a, b = starts[k - n, 0], starts[k - n, 1]
            if not (math.isfinite(a) and math.isfinite(b)):
                continue
        # A start where one before started repeats its refinement: skipped (Search.run).
        a, b = _py_min(_py_max(a, lim[0]), lim[1]), _py_min(_py_max(b, lim[2]), lim[3])
        if _started(refined, n_refined, a, b):
            continue
        refined[n_refined, 0], refined[n_refined, 1] = a, b
        n_refined += 1
        _refine(prob, lim, mu2, anchor_a, anchor_b, a, b, recs, hint, work, iwork)
        if not have or (_value(recs[_E], mu2, anchor_a, anchor_b)
                        < _value(recs[_BEST], mu2, anchor_a, anchor_b)):
            _copy(recs[_E], recs[_BEST])
            have = True
    _copy(recs[_BEST], rec)


@jit.kernel('int64(float64[::1], float64[:, ::1], boolean, boolean, int64, float64, '
            'float64[:, ::1])', group='allocation')
def minima(prob: FloatArray, box: FloatArray, periodic_a: bool, periodic_b: bool, count: int,
           below: float, recs: FloatArray) -> int:
    """``Search(problem, box, periodic=(periodic_a, periodic_b)).minima(count, below)``,
    best first, into recs[:found]; returns found (count: at most the rows of recs)."""
    count = max(0, min(count, recs.shape[0]))
    ga, gb, upper, trig, lim, own, work, _, cells, order, hint, iwork = _scratch(
        box, periodic_a, periodic_b, count, 0)
    _limits(box, periodic_a, periodic_b, lim)
    n = _grid(prob, box, periodic_a, periodic_b, 0.0, 0.0, 0.0, count, ga, gb, upper, trig,
              cells, order)
    nb = gb.shape[0]
    found = 0
    for k in range(n):
        i = cells[k]
        if upper[i] >= 2.0 * below:
            break
        _refine(prob, lim, 0.0, 0.0, 0.0, ga[i // nb], gb[i % nb], own, hint, work, iwork)
        e = own[_E]
        if not e[REC_COST] < below:
            continue
        apart = True
        for f in range(found):
            if not abs(e[REC_A] - recs[f, REC_A]) + abs(e[REC_B] - recs[f, REC_B]) > 1e-3:
                apart = False
        if not apart:
            continue
        # sorted(found, key=cost) is stable: a new minimum goes after equal costs.
        j = found
        while j > 0 and e[REC_COST] < recs[j - 1, REC_COST]:
            _copy(recs[j - 1], recs[j])
            j -= 1
        _copy(e, recs[j])
        found += 1
    return found
