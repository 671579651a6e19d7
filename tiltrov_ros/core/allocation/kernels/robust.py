"""Kernels mirroring :mod:`..robust`: the robust mode's answer when no exact solution is in reach.

The glue of the reference around the numerical primitives of
:mod:`.tiltcost` (the tilt problem, one evaluation), :mod:`.search` (the
per-tick optimum's search, the global minima) and :mod:`.plan` (the
receding-horizon planner): warm starts, the twin in range, the planner's
targets (exact solutions in range, else the best configurations over the
range) and the result. Work arrays come from :mod:`.allocate`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.kernels.exact import solve_row
from tiltrov_ros.core.allocation.kernels.layout import (
    CFG_AVAILABLE,
    CFG_FMAX,
    CFG_HORIZON,
    CFG_PENALTY,
    CFG_PLANNING,
    CFG_STEP,
    CFG_TILT_MAX,
    CFG_TILT_MIN,
    CONF_FAMILY,
    CONF_TILTS,
    METHOD_CODE,
    OUT_ERROR,
    OUT_STUCK,
    OUT_TARGET,
    OUT_TILTS,
    PREV_EXISTS,
    PREV_STUCK,
    PREV_TARGET,
    PREV_TRANSIT,
    PROB_SCALE,
    REC_A,
    REC_B,
    REC_COST,
    REC_THRUSTS,
    TGT_A,
    TGT_B,
    TGT_COST,
    VARIANTS,
)
from tiltrov_ros.core.allocation.kernels.limits import make, twins
from tiltrov_ros.core.allocation.kernels.plan import plan
from tiltrov_ros.core.allocation.kernels.search import minima, run
from tiltrov_ros.core.allocation.kernels.select import variant
from tiltrov_ros.core.allocation.kernels.tiltcost import evaluate, problem
from tiltrov_ros.core.allocation.limits import LIMIT_SLACK
from tiltrov_ros.core.allocation.robust import GLOBAL_GAIN, GLOBAL_TARGETS

Ints = NDArray[np.int64]

_OPTIMIZED = METHOD_CODE['optimized']
_TRANSIT = METHOD_CODE['transit']


@jit.kernel()
def nearest_in_box(angle: float, lo: float, hi: float) -> float:
    """``robust._nearest_in_box`` for one tilt: of gamma and its twins, the one nearest
    to [lo, hi], clipped into it."""
    best, gap = 0.0, math.inf
    for s in range(3):
        option = angle + (0.0 if s == 0 else (math.pi if s == 1 else -math.pi))
        clipped = min(max(option, lo), hi)
        if abs(option - clipped) < gap:
            best, gap = clipped, abs(option - clipped)
    return best


@jit.kernel()
def in_range(cfg: FloatArray, angle: float) -> tuple[float, float]:
    """``robust._in_range`` for one tilt: the twin in the tilt range nearest to 0 and its
    thrust sign (a range narrower than pi without one: the nearest edge)."""
    n, t0, s0, t1, s1, t2, s2 = twins(cfg, angle)
    if n == 0:
        return min(max(angle, cfg[CFG_TILT_MIN]), cfg[CFG_TILT_MAX]), 1.0
    best, sign = t0, s0
    for i in range(1, n):
        t, s = (t1, s1) if i == 1 else (t2, s2)
        # min by (round(|t|, 12), -sign): the first of equals stays.
        if (round(abs(t), 12) < round(abs(best), 12)
                or (round(abs(t), 12) == round(abs(best), 12) and -s < -sign)):
            best, sign = t, s
    return best, sign


@jit.kernel()
def per_tick_optimum(cfg: FloatArray, prob: FloatArray, has_prev: bool, anchor: FloatArray,
                     box: FloatArray, search_box: FloatArray, starts: FloatArray,
                     n_starts: int, rec: FloatArray
                     ) -> tuple[float, float, float, float, float, float, float]:
    """``robust.per_tick_optimum``: (alpha, beta, f1..f4 [N], scaled cost c) of the least
    error within ``box``; ``starts[:n_starts]`` are the warm starts (rewritten)."""
    lo, hi = cfg[CFG_TILT_MIN], cfg[CFG_TILT_MAX]
    wide = hi - lo >= math.pi - LIMIT_SLACK
    periodic = not has_prev and wide
    if periodic:
        search_box[0, 0] = search_box[1, 0] = lo
        search_box[0, 1] = search_box[1, 1] = lo + math.pi
    else:
        search_box[:, :] = box
    n = 0
    for i in range(n_starts):
        a, b = starts[i, 0], starts[i, 1]
        if not (math.isfinite(a) and math.isfinite(b)):
            continue
        if not periodic:
            a = nearest_in_box(a, box[0, 0], box[0, 1])
            b = nearest_in_box(b, box[1, 0], box[1, 1])
        starts[n, 0], starts[n, 1] = a, b
        n += 1
    run(prob, search_box, anchor, has_prev, cfg[CFG_PENALTY], periodic, periodic, starts, n,
        rec)
    s = prob[PROB_SCALE]
    f1, f2 = rec[REC_THRUSTS] * s, rec[REC_THRUSTS + 1] * s
    f3, f4 = rec[REC_THRUSTS + 2] * s, rec[REC_THRUSTS + 3] * s
    a, b = rec[REC_A], rec[REC_B]
    if periodic:
        a, sign_a = in_range(cfg, a)
        b, sign_b = in_range(cfg, b)
        f1, f2, f3, f4 = f1 * sign_a, f2 * sign_a, f3 * sign_b, f4 * sign_b
    return a, b, f1, f2, f3, f4, rec[REC_COST]


@jit.kernel()
def _round9(x: float) -> float:
    return round(x, 9)


@jit.kernel()
def exact_targets(cfg: FloatArray, tau: FloatArray, conf: FloatArray, count: int, p0: float,
                  p1: float, aims: FloatArray, uv: FloatArray, scratch: FloatArray,
                  full: FloatArray, keys: FloatArray, targets: FloatArray) -> int:
    """``robust._exact_targets``: exact solutions in range (every twin) as targets of cost
    0 into ``targets``, first seen first; returns their count. ``keys``: scratch
    (MAX_TARGETS, 2) for the rounded tilts that tell targets apart."""
    pool, size = conf, count
    family = count == 0
    for j in range(count):
        if conf[j, CONF_FAMILY] != 0.0:
            family = True
    if family:
        aims[0, 0], aims[1, 0] = p0, p1
        size = solve_row(cfg, tau, aims, 1, uv, scratch, 0)
        pool = scratch
    full[0, 0] = full[1, 0] = cfg[CFG_TILT_MIN]
    full[0, 1] = full[1, 1] = cfg[CFG_TILT_MAX]
    fmax = cfg[CFG_FMAX] * (1.0 + LIMIT_SLACK)
    n = 0
    for j in range(size):
        for v in range(VARIANTS):
            exists, f1, f2, f3, f4, a, b = variant(cfg, pool, j, v, p0, p1, full)
            if not exists or max(abs(f1), abs(f2), abs(f3), abs(f4)) > fmax:
                continue
            ka, kb = _round9(a), _round9(b)
            seen = False
            for i in range(n):
                if keys[i, 0] == ka and keys[i, 1] == kb:
                    seen = True
                    break
            if seen:
                continue
            keys[n, 0], keys[n, 1] = ka, kb
            targets[n, TGT_A], targets[n, TGT_B], targets[n, TGT_COST] = a, b, 0.0
            n += 1
    return n


@jit.kernel()
def global_targets(cfg: FloatArray, prob: FloatArray, local_cost: float, search_box: FloatArray,
                   recs: FloatArray, targets: FloatArray, first: int) -> int:
    """``robust._global_targets``: the best configurations over the whole range (every
    twin) when they beat ``local_cost``, into ``targets[first:]``; returns the end."""
    lo, hi = cfg[CFG_TILT_MIN], cfg[CFG_TILT_MAX]
    wide = hi - lo >= math.pi - LIMIT_SLACK
    search_box[0, 0] = search_box[1, 0] = lo
    search_box[0, 1] = search_box[1, 1] = lo + math.pi if wide else hi
    found = minima(prob, search_box, wide, wide, GLOBAL_TARGETS, GLOBAL_GAIN * local_cost,
                   recs)
    n = first
    for m in range(found):
        a, b, cost = recs[m, REC_A], recs[m, REC_B], recs[m, REC_COST]
        na, a0, _, a1, _, a2, _ = twins(cfg, a) if wide else (1, a, 1.0, 0.0, 0.0, 0.0, 0.0)
        nb, b0, _, b1, _, b2, _ = twins(cfg, b) if wide else (1, b, 1.0, 0.0, 0.0, 0.0, 0.0)
        for i in range(na):
            fa = a0 if i == 0 else (a1 if i == 1 else a2)
            for k in range(nb):
                rb = b0 if k == 0 else (b1 if k == 1 else b2)
                targets[n, TGT_A], targets[n, TGT_B], targets[n, TGT_COST] = fa, rb, cost
                n += 1
    return n


@jit.kernel()
def fallback(cfg: FloatArray, tau: FloatArray, conf: FloatArray, count: int, disc: float,
             prev: FloatArray, has_prev: bool, anchor: FloatArray, box: FloatArray,
             incumbent: FloatArray, has_incumbent: bool, out: FloatArray,
             work: tuple[FloatArray, ...], hint: Ints) -> None:
    """``robust.fallback``: the robust mode's answer into ``out`` (see the reference).

    ``prev``: the previous result (layout ``PREV_*``); ``anchor``: its tilts clipped
    into range (valid when ``has_prev``); ``incumbent``: the paper mode's answer.
    ``work``: (prob, rec, recs, search_box, starts, targets, keys, aims, uv, scratch,
    full, plan_out, kept).
    """
    prob, rec, recs, search_box, starts, targets, keys, aims, uv, scratch, full, plan_out, \
        kept = work
    problem(cfg, tau, prob)
    n = 0
    for j in range(count):
        starts[n, 0], starts[n, 1] = conf[j, CONF_TILTS], conf[j, CONF_TILTS + 1]
        n += 1
    if has_incumbent:
        starts[n, 0], starts[n, 1] = incumbent[OUT_TILTS], incumbent[OUT_TILTS + 1]
        n += 1
    if has_prev:
        starts[n, 0], starts[n, 1] = anchor[0], anchor[1]
        n += 1
    previous = prev[PREV_EXISTS] != 0.0
    if previous and prev[PREV_TARGET] == prev[PREV_TARGET]:
        starts[n, 0], starts[n, 1] = prev[PREV_TARGET], prev[PREV_TARGET + 1]
        n += 1
    a, b, f1, f2, f3, f4, cost = per_tick_optimum(cfg, prob, has_prev, anchor, box,
                                                  search_box, starts, n, rec)
    make(cfg, tau, f1, f2, f3, f4, a, b, _OPTIMIZED, disc, out)
    if has_incumbent and incumbent[OUT_ERROR] <= out[OUT_ERROR]:
        out[:] = incumbent
        error = incumbent[OUT_ERROR] / prob[PROB_SCALE]
        cost = error * error
    stuck = (prev[PREV_STUCK] if previous else 0.0) + 1.0
    out[OUT_STUCK] = stuck
    failed = False
    for i in range(4):
        if cfg[CFG_AVAILABLE + i] == 0.0:
            failed = True
    step = cfg[CFG_STEP]
    if not (cfg[CFG_PLANNING] != 0.0 and has_prev and math.isfinite(step) and not failed):
        return
    n_targets = exact_targets(cfg, tau, conf, count, anchor[0], anchor[1], aims, uv, scratch,
                              full, keys, targets)
    if n_targets == 0:
        n_targets = global_targets(cfg, prob, cost, search_box, recs, targets, 0)
    kept[0] = kept[1] = math.nan
    if previous and prev[PREV_TRANSIT] != 0.0 and prev[PREV_TARGET] == prev[PREV_TARGET]:
        kept[0], kept[1] = prev[PREV_TARGET], prev[PREV_TARGET + 1]
        evaluate(prob, kept[0], kept[1], hint, False, rec)
        targets[n_targets, TGT_A], targets[n_targets, TGT_B] = kept[0], kept[1]
        targets[n_targets, TGT_COST] = rec[REC_COST]
        n_targets += 1
    if not plan(prob, anchor, step, cost, targets, n_targets, int(cfg[CFG_HORIZON]), kept,
                plan_out):
        return
    a, b = plan_out[0], plan_out[1]
    evaluate(prob, a, b, hint, False, rec)
    s = prob[PROB_SCALE]
    make(cfg, tau, rec[REC_THRUSTS] * s, rec[REC_THRUSTS + 1] * s, rec[REC_THRUSTS + 2] * s,
         rec[REC_THRUSTS + 3] * s, a, b, _TRANSIT, disc, out)
    out[OUT_TARGET], out[OUT_TARGET + 1] = plan_out[2], plan_out[3]
    out[OUT_STUCK] = stuck
