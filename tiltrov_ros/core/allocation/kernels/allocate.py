"""The top-level kernels, mirroring :mod:`..allocator`: one whole call per kernel call.

:func:`allocate` is ``ThrustAllocator.allocate`` from the cleaned wrench to the
checked result (``_finish``), :func:`allocate_fixed` and :func:`thrusts_at`
their namesakes, :func:`allocate_batch` ``allocate_batch`` (the vectorised
selection of ``selection.choose_batch`` row by row, the other rows through
:func:`allocate`). Python packs the arguments into the arrays of
:mod:`.layout` and unpacks ``out``; every scratch array is carved from one
``work`` buffer per allocator.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.kernels.exact import candidates, solve_row, symmetric_row
from tiltrov_ros.core.allocation.kernels.families import symmetric
from tiltrov_ros.core.allocation.kernels.layout import (
    BUF_AIMS,
    BUF_ANCHOR,
    BUF_BOX,
    BUF_CONFIGS,
    BUF_FULL,
    BUF_KEPT,
    BUF_KEYS,
    BUF_OUT,
    BUF_OUT2,
    BUF_PLAN,
    BUF_PREV,
    BUF_PROB,
    BUF_REC,
    BUF_RECS,
    BUF_SCRATCH,
    BUF_SEARCH_BOX,
    BUF_STARTS,
    BUF_TARGETS,
    BUF_TAU,
    BUF_UV,
    BUF_VALUES,
    CFG_AVAILABLE,
    CFG_FMAX,
    CFG_MODE,
    CFG_TILT_MAX,
    CFG_TILT_MIN,
    CFG_WEIGHTS,
    CONF_SIZE,
    IBUF_HINT,
    MAX_AIMS,
    MAX_CONFIGS,
    MAX_SLOTS,
    MAX_TARGETS,
    METHOD_CODE,
    MODE_ROBUST,
    OUT_DISC,
    OUT_FEASIBLE,
    OUT_METHOD,
    OUT_THRUSTS,
    OUT_TILTS,
    PREV_EXISTS,
    PREV_SIZE,
    PREV_STUCK,
    PREV_TARGET,
    PREV_TILTS,
    PREV_TRANSIT,
    PROB_SCALE,
    PROB_SIZE,
    REC_SIZE,
    REC_THRUSTS,
    TGT_SIZE,
)
from tiltrov_ros.core.allocation.kernels.limits import box, make, plain_norm6, wrench_of
from tiltrov_ros.core.allocation.kernels.paper import paper_fallback
from tiltrov_ros.core.allocation.kernels.robust import fallback
from tiltrov_ros.core.allocation.kernels.select import choose, pick, snapped
from tiltrov_ros.core.allocation.kernels.tiltcost import evaluate, problem
from tiltrov_ros.core.allocation.results import FEASIBILITY_RTOL
from tiltrov_ros.core.allocation.robust import GLOBAL_TARGETS

Ints = NDArray[np.int64]
#: The scratch arrays of one call (:func:`views`).
Views = tuple[Any, ...]

_FAMILY = METHOD_CODE['family']
_ZERO = METHOD_CODE['zero']
_FIXED = METHOD_CODE['fixed_tilt']


@jit.kernel()
def _matrix(work: FloatArray, start: int, rows: int, cols: int) -> FloatArray:
    return work[start:start + rows * cols].reshape((rows, cols))


@jit.kernel()
def views(work: FloatArray) -> Views:
    """The scratch arrays carved from ``work`` (layout ``BUF_*``)."""
    return (_matrix(work, BUF_CONFIGS, MAX_CONFIGS, CONF_SIZE),
            _matrix(work, BUF_SCRATCH, MAX_SLOTS, CONF_SIZE),
            _matrix(work, BUF_UV, MAX_SLOTS, 2),
            _matrix(work, BUF_BOX, 2, 2),
            _matrix(work, BUF_AIMS, 2, MAX_AIMS),
            work[BUF_TAU:BUF_TAU + 6],
            work[BUF_ANCHOR:BUF_ANCHOR + 2],
            work[BUF_VALUES:BUF_VALUES + 16],
            work[BUF_OUT:BUF_OUT + (BUF_OUT2 - BUF_OUT)],
            # the robust fallback's (kernels.robust.fallback)
            (work[BUF_PROB:BUF_PROB + PROB_SIZE],
             work[BUF_REC:BUF_REC + REC_SIZE],
             _matrix(work, BUF_RECS, GLOBAL_TARGETS, REC_SIZE),
             _matrix(work, BUF_SEARCH_BOX, 2, 2),
             _matrix(work, BUF_STARTS, MAX_CONFIGS + 3, 2),
             _matrix(work, BUF_TARGETS, MAX_TARGETS, TGT_SIZE),
             _matrix(work, BUF_KEYS, MAX_TARGETS, 2),
             _matrix(work, BUF_AIMS, 2, MAX_AIMS),
             _matrix(work, BUF_UV, MAX_SLOTS, 2),
             _matrix(work, BUF_SCRATCH, MAX_SLOTS, CONF_SIZE),
             _matrix(work, BUF_FULL, 2, 2),
             work[BUF_PLAN:BUF_PLAN + 5],
             work[BUF_KEPT:BUF_KEPT + 2]))


@jit.kernel()
def clean(tau: FloatArray) -> bool:
    """Non-finite wrench components read as 0 (in place); True when all were finite."""
    finite = True
    for i in range(6):
        if not math.isfinite(tau[i]):
            tau[i] = 0.0
            finite = False
    return finite


@jit.kernel()
def previous_tilts(cfg: FloatArray, prev: FloatArray) -> tuple[bool, float, float]:
    """``ThrustAllocator._previous_tilts``: (given, alpha, beta) clipped into range."""
    a, b = prev[PREV_TILTS], prev[PREV_TILTS + 1]
    if prev[PREV_EXISTS] == 0.0 or not (math.isfinite(a) and math.isfinite(b)):
        return False, 0.0, 0.0
    lo, hi = cfg[CFG_TILT_MIN], cfg[CFG_TILT_MAX]
    return True, min(max(a, lo), hi), min(max(b, lo), hi)


@jit.kernel()
def _safe(v: float, fmax: float) -> tuple[float, bool]:
    """A thrust within [-fmax, fmax] (non-finite: 0), and whether it changed."""
    f = min(max(v, -fmax), fmax) if math.isfinite(v) else 0.0
    return f, f != v


@jit.kernel()
def finish(cfg: FloatArray, tau: FloatArray, finite: bool, out: FloatArray) -> None:
    """``ThrustAllocator._finish``: limits hold and nothing non-finite leaves."""
    lo, hi, fmax = cfg[CFG_TILT_MIN], cfg[CFG_TILT_MAX], cfg[CFG_FMAX]
    a, b = out[OUT_TILTS], out[OUT_TILTS + 1]
    inside = lo <= a <= hi and lo <= b <= hi
    for i in range(4):
        inside = inside and -fmax <= out[OUT_THRUSTS + i] <= fmax
    if not inside:
        f1, c1 = _safe(out[OUT_THRUSTS], fmax)
        f2, c2 = _safe(out[OUT_THRUSTS + 1], fmax)
        f3, c3 = _safe(out[OUT_THRUSTS + 2], fmax)
        f4, c4 = _safe(out[OUT_THRUSTS + 3], fmax)
        ca = min(max(a, lo), hi) if a == a else 0.0
        cb = min(max(b, lo), hi) if b == b else 0.0
        if c1 or c2 or c3 or c4 or ca != a or cb != b:
            make(cfg, tau, f1, f2, f3, f4, ca, cb, out[OUT_METHOD], out[OUT_DISC], out)
    if not finite:
        out[OUT_FEASIBLE] = 0.0


@jit.kernel()
def solve(cfg: FloatArray, tau: FloatArray, prev: FloatArray, out: FloatArray, v: Views,
          hint: Ints) -> None:
    """``ThrustAllocator.allocate`` between the checked arguments and ``_finish``."""
    configs, scratch, uv, reach, aims, tau_s, anchor, values, incumbent, fallback_work = v
    has_prev, p0, p1 = previous_tilts(cfg, prev)
    anchor[0], anchor[1] = p0, p1
    ref0, ref1 = (p0, p1) if has_prev else (0.0, 0.0)
    box(cfg, has_prev, p0, p1, reach)
    robust = cfg[CFG_MODE] == MODE_ROBUST
    failed = False
    for i in range(4):
        failed = failed or cfg[CFG_AVAILABLE + i] == 0.0
    if robust and failed:
        # The closed form cannot hold a thruster at zero: optimise directly.
        fallback(cfg, tau, configs, 0, math.nan, prev, has_prev, anchor, reach, incumbent,
                 False, out, fallback_work, hint)
        return
    n, disc = candidates(cfg, tau, configs, 0)
    found = False
    if n < 0:
        # A family: the symmetric one in closed form, else the vectorised selector.
        n = 0
        m = symmetric(cfg, tau, has_prev, p0, p1, reach, values, scratch, 0)
        if m >= 0:
            found = choose(cfg, tau, scratch, 0, m, math.nan, ref0, ref1, reach, True, out)
        if not found:
            found = choose_family(cfg, tau, ref0, ref1, reach, aims, uv, scratch, out)
        if not found:
            n = solve_row(cfg, tau, aims, 0, uv, configs, 0)
    else:
        found = choose(cfg, tau, configs, 0, n, disc, ref0, ref1, reach, True, out)
    if not found and robust and snapped(tau, tau_s):
        m, _ = candidates(cfg, tau_s, configs, n)
        if m < 0:
            m = solve_row(cfg, tau_s, aims, 0, uv, configs, n)
        found = choose(cfg, tau, configs, n, m, disc, ref0, ref1, reach, False, out)
        found = found and out[OUT_FEASIBLE] != 0.0
        n += m
    if found:
        return
    if not robust:
        paper_fallback(cfg, tau, configs, n, disc, ref0, ref1, reach, out)
        return
    paper_fallback(cfg, tau, configs, n, disc, ref0, ref1, reach, incumbent)
    fallback(cfg, tau, configs, n, disc, prev, has_prev, anchor, reach, incumbent, True, out,
             fallback_work, hint)


@jit.kernel()
def choose_family(cfg: FloatArray, tau: FloatArray, ref0: float, ref1: float, reach: FloatArray,
                  aims: FloatArray, uv: FloatArray, scratch: FloatArray, out: FloatArray) -> bool:
    """``selection.choose_family``: the family member the vectorised selector picks,
    aiming at the previous tilts and the edges of their reach."""
    aims[0, 0], aims[0, 1], aims[0, 2] = ref0, reach[0, 0], reach[0, 1]
    aims[1, 0], aims[1, 1], aims[1, 2] = ref1, reach[1, 0], reach[1, 1]
    n = solve_row(cfg, tau, aims, 3, uv, scratch, 0)
    done, f1, f2, f3, f4, a, b = pick(cfg, tau, scratch, n, ref0, ref1, reach)
    if not done:
        return False
    zero = f1 == 0.0 and f2 == 0.0 and f3 == 0.0 and f4 == 0.0
    make(cfg, tau, f1, f2, f3, f4, a, b, _ZERO if zero else _FAMILY, math.nan, out)
    return True


@jit.kernel('void(f8[::1], f8[::1], f8[::1], f8[::1], f8[::1], i8[::1])', group='allocation')
def allocate(cfg: FloatArray, tau: FloatArray, prev: FloatArray, out: FloatArray, work: FloatArray,
             iwork: Ints) -> None:
    """One ``ThrustAllocator.allocate``: ``tau`` (6,) as given (cleaned in place: it
    becomes the result's ``requested``), ``prev`` (PREV_SIZE,), the result into ``out``
    (OUT_SIZE,)."""
    finite = clean(tau)
    solve(cfg, tau, prev, out, views(work), iwork[IBUF_HINT:IBUF_HINT + 4])
    finish(cfg, tau, finite, out)


@jit.kernel()
def _thrusts(cfg: FloatArray, tau: FloatArray, a: float, b: float, prob: FloatArray,
             rec: FloatArray, hint: Ints) -> tuple[float, float, float, float]:
    """``ThrustAllocator.thrusts_at``: the thrusts [N] with the least weighted error."""
    problem(cfg, tau, prob)
    evaluate(prob, a, b, hint, False, rec)
    s = prob[PROB_SCALE]
    return (rec[REC_THRUSTS] * s, rec[REC_THRUSTS + 1] * s, rec[REC_THRUSTS + 2] * s,
            rec[REC_THRUSTS + 3] * s)


@jit.kernel('void(f8[::1], f8[::1], f8, f8, f8[::1], f8[::1], i8[::1])', group='allocation')
def thrusts_at(cfg: FloatArray, tau: FloatArray, a: float, b: float, out: FloatArray,
               work: FloatArray, iwork: Ints) -> None:
    """One ``ThrustAllocator.thrusts_at`` (finite ``tau``): the thrusts into ``out[:4]``."""
    f1, f2, f3, f4 = _thrusts(cfg, tau, a, b, work[BUF_PROB:BUF_PROB + PROB_SIZE],
                              work[BUF_REC:BUF_REC + REC_SIZE],
                              iwork[IBUF_HINT:IBUF_HINT + 4])
    out[0], out[1], out[2], out[3] = f1, f2, f3, f4


@jit.kernel('void(f8[::1], f8[::1], f8[::1], f8, f8, f8[::1], f8[::1], i8[::1])',
            group='allocation')
def allocate_fixed(cfg: FloatArray, tau: FloatArray, prev: FloatArray, tilt_front: float,
                   tilt_rear: float, out: FloatArray, work: FloatArray, iwork: Ints) -> None:
    """One ``ThrustAllocator.allocate_fixed``, arguments as :func:`allocate`'s."""
    finite = clean(tau)
    has_prev, p0, p1 = previous_tilts(cfg, prev)
    reach = _matrix(work, BUF_BOX, 2, 2)
    box(cfg, has_prev, p0, p1, reach)
    a = tilt_front if math.isfinite(tilt_front) else (p0 if has_prev else 0.0)
    b = tilt_rear if math.isfinite(tilt_rear) else (p1 if has_prev else 0.0)
    a, b = min(max(a, reach[0, 0]), reach[0, 1]), min(max(b, reach[1, 0]), reach[1, 1])
    f1, f2, f3, f4 = _thrusts(cfg, tau, a, b, work[BUF_PROB:BUF_PROB + PROB_SIZE],
                              work[BUF_REC:BUF_REC + REC_SIZE],
                              iwork[IBUF_HINT:IBUF_HINT + 4])
    make(cfg, tau, f1, f2, f3, f4, a, b, _FIXED, math.nan, out)
    finish(cfg, tau, finite, out)


@jit.kernel('void(f8[::1], f8[:, ::1], f8[:, ::1], b1, f8[:, ::1], f8[::1], f8[::1], '
            'f8[:, ::1], b1[::1], f8[::1], f8[::1], i8[::1])', group='allocation')
def allocate_batch(cfg: FloatArray, taus: FloatArray, prevs: FloatArray, has_prevs: bool,
                   thrusts: FloatArray, tilt_front: FloatArray, tilt_rear: FloatArray,
                   achieved: FloatArray, feasible: NDArray[np.bool_], error: FloatArray,
                   work: FloatArray, iwork: Ints) -> None:
    """``ThrustAllocator.allocate_batch``: ``taus`` (n, 6) as given (cleaned in place),
    ``prevs`` (n, 2) when ``has_prevs``; the columns of the BatchResult out."""
    v = views(work)
    scratch, uv, reach, aims = v[1], v[2], v[3], v[4]
    prev = work[BUF_PREV:BUF_PREV + PREV_SIZE]
    out = work[BUF_OUT2:BUF_OUT2 + (BUF_OUT2 - BUF_OUT)]
    hint = iwork[IBUF_HINT:IBUF_HINT + 4]
    lo, hi, fmax = cfg[CFG_TILT_MIN], cfg[CFG_TILT_MAX], cfg[CFG_FMAX]
    robust = cfg[CFG_MODE] == MODE_ROBUST
    failed = False
    for i in range(4):
        failed = failed or cfg[CFG_AVAILABLE + i] == 0.0
    w = CFG_WEIGHTS
    for r in range(taus.shape[0]):
        tau = taus[r]
        finite = clean(tau)
        p0 = p1 = 0.0
        if has_prevs:
            p0 = prevs[r, 0] if math.isfinite(prevs[r, 0]) else 0.0
            p1 = prevs[r, 1] if math.isfinite(prevs[r, 1]) else 0.0
            p0, p1 = min(max(p0, lo), hi), min(max(p1, lo), hi)
        done = False
        if not (robust and failed) and not symmetric_row(cfg, tau):
            box(cfg, has_prevs, p0, p1, reach)
            aims[0, 0], aims[0, 1], aims[0, 2] = p0, reach[0, 0], reach[0, 1]
            aims[1, 0], aims[1, 1], aims[1, 2] = p1, reach[1, 0], reach[1, 1]
            n = solve_row(cfg, tau, aims, 3, uv, scratch, 0)
            done, f1, f2, f3, f4, a, b = pick(cfg, tau, scratch, n, p0, p1, reach)
        if not done:
            # allocate() from a previous result that carries only tilts.
            prev[PREV_EXISTS] = 1.0 if has_prevs else 0.0
            prev[PREV_TILTS], prev[PREV_TILTS + 1] = p0, p1
            prev[PREV_TRANSIT] = 0.0
            prev[PREV_TARGET] = prev[PREV_TARGET + 1] = math.nan
            prev[PREV_STUCK] = 0.0
            solve(cfg, tau, prev, out, v, hint)
            finish(cfg, tau, True, out)
            f1, f2, f3, f4 = (out[OUT_THRUSTS], out[OUT_THRUSTS + 1], out[OUT_THRUSTS + 2],
                              out[OUT_THRUSTS + 3])
            a, b = out[OUT_TILTS], out[OUT_TILTS + 1]
        f1 = f1 if cfg[CFG_AVAILABLE] != 0.0 else 0.0
        f2 = f2 if cfg[CFG_AVAILABLE + 1] != 0.0 else 0.0
        f3 = f3 if cfg[CFG_AVAILABLE + 2] != 0.0 else 0.0
        f4 = f4 if cfg[CFG_AVAILABLE + 3] != 0.0 else 0.0
        thrusts[r, 0], thrusts[r, 1], thrusts[r, 2], thrusts[r, 3] = f1, f2, f3, f4
        tilt_front[r], tilt_rear[r] = a, b
        X, Y, Z, K, M, N = wrench_of(cfg, f1, f2, f3, f4, a, b)
        achieved[r, 0], achieved[r, 1], achieved[r, 2] = X, Y, Z
        achieved[r, 3], achieved[r, 4], achieved[r, 5] = K, M, N
        d0, d1, d2 = X - tau[0], Y - tau[1], Z - tau[2]
        d3, d4, d5 = K - tau[3], M - tau[4], N - tau[5]
        error[r] = plain_norm6(d0 * cfg[w], d1 * cfg[w + 1], d2 * cfg[w + 2], d3 * cfg[w + 3],
                               d4 * cfg[w + 4], d5 * cfg[w + 5])
        size = max(plain_norm6(tau[0], tau[1], tau[2], tau[3], tau[4], tau[5]), fmax)
        miss = plain_norm6(d0, d1, d2, d3, d4, d5)
        feasible[r] = finite and not miss > FEASIBILITY_RTOL * size
