"""Kernels mirroring :mod:`..selection`: the choice among exact solutions (Section 3.2, completed).

A candidate (a ``conf`` row) has up to nine variants, gamma + {0, pi, -pi} per
pair (:func:`options`, ``selection.variants``); a variant qualifies and
is ranked by :func:`key` with the reference's key (family: least thrust,
then least tilt motion; otherwise least tilt motion, ties to positive thrust).
The order of the reference's stable sort is (key, position): :func:`choose`
walks it without a buffer, taking the next variant in that order until one
passes. :func:`pick` is one row of ``selection.choose_rows``.
"""

from __future__ import annotations

import math

import numpy as np

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.closed_form import EXACT_RTOL
from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.kernels.layout import (
    CFG_FMAX,
    CFG_MODE,
    CFG_TILT_MAX,
    CFG_TILT_MIN,
    CONF_FAMILY,
    CONF_FREE,
    CONF_THRUSTS,
    CONF_TILTS,
    METHOD_CODE,
    MODE_ROBUST,
    OUT_ACHIEVED,
    VARIANTS,
)
from tiltrov_ros.core.allocation.kernels.limits import make, norm6, plain_norm6, wrench_of
from tiltrov_ros.core.allocation.limits import LIMIT_SLACK
from tiltrov_ros.core.allocation.results import FEASIBILITY_RTOL
from tiltrov_ros.core.allocation.selection import _MOVE_RESOLUTION, SNAP_RTOL

_EXACT = METHOD_CODE['exact']
_FAMILY = METHOD_CODE['family']
_ZERO = METHOD_CODE['zero']
_SATURATED = METHOD_CODE['saturated']


@jit.kernel()
def options(cfg: FloatArray, conf: FloatArray, j: int, p: int, rest: float, box: FloatArray
            ) -> tuple[bool, float, float, bool, float, float, bool, float, float]:
    """The variants of pair ``p`` of candidate ``j`` as ``selection.variants`` lists them:
    (exists, tilt, thrust sign) for gamma, gamma + pi, gamma - pi. A pair without thrust
    has one, its rest tilt clipped into its reach; a pair none of whose variants is in
    range keeps gamma."""
    if conf[j, CONF_FREE + p] != 0.0:
        return (True, min(max(rest, box[p, 0]), box[p, 1]), 1.0, False, 0.0, 0.0,
                False, 0.0, 0.0)
    lo, hi = cfg[CFG_TILT_MIN] - LIMIT_SLACK, cfg[CFG_TILT_MAX] + LIMIT_SLACK
    gamma = conf[j, CONF_TILTS + p]
    g0, g1, g2 = gamma + 0.0, gamma + math.pi, gamma + -math.pi
    in0, in1, in2 = lo <= g0 <= hi, lo <= g1 <= hi, lo <= g2 <= hi
    if not (in0 or in1 or in2):
        return True, gamma, 1.0, False, 0.0, 0.0, False, 0.0, 0.0
    return in0, g0, 1.0, in1, g1, -1.0, in2, g2, -1.0


@jit.kernel()
def _option(k: int, e0: bool, t0: float, s0: float, e1: bool, t1: float, s1: float, e2: bool,
            t2: float, s2: float) -> tuple[bool, float, float]:
    if k == 0:
        return e0, t0, s0
    if k == 1:
        return e1, t1, s1
    return e2, t2, s2


@jit.kernel()
def variant(cfg: FloatArray, conf: FloatArray, j: int, v: int, rest0: float, rest1: float,
            box: FloatArray) -> tuple[bool, float, float, float, float, float, float]:
    """Variant ``v`` (0..8, front-major) of candidate ``j``: (exists, f1..f4, alpha, beta)."""
    ok_a, a, sign_a = _option(v // 3, *options(cfg, conf, j, 0, rest0, box))
    ok_b, b, sign_b = _option(v % 3, *options(cfg, conf, j, 1, rest1, box))
    c = CONF_THRUSTS
    return (ok_a and ok_b, conf[j, c] * sign_a, conf[j, c + 1] * sign_a,
            conf[j, c + 2] * sign_b, conf[j, c + 3] * sign_b, a, b)


@jit.kernel()
def key(cfg: FloatArray, family: bool, f1: float, f2: float, f3: float, f4: float, a: float,
        b: float, ref0: float, ref1: float, box: FloatArray
        ) -> tuple[bool, float, float, float, float]:
    """Whether a variant qualifies, and its key (``selection.choose``'s ranking)."""
    fmax = cfg[CFG_FMAX] * (1.0 + LIMIT_SLACK)
    if max(abs(f1), abs(f2), abs(f3), abs(f4)) > fmax:
        return False, 0.0, 0.0, 0.0, 0.0
    lo, hi = cfg[CFG_TILT_MIN] - LIMIT_SLACK, cfg[CFG_TILT_MAX] + LIMIT_SLACK
    ok = lo <= a <= hi and lo <= b <= hi
    if cfg[CFG_MODE] == MODE_ROBUST:
        ok = ok and (box[0, 0] - LIMIT_SLACK <= a <= box[0, 1] + LIMIT_SLACK
                     and box[1, 0] - LIMIT_SLACK <= b <= box[1, 1] + LIMIT_SLACK)
    if not ok:
        return False, 0.0, 0.0, 0.0, 0.0
    # Tilt motions within _MOVE_RESOLUTION rad^2 count as ties.
    da, db = a - ref0, b - ref1
    move = np.rint((da * da + db * db) / _MOVE_RESOLUTION)
    thrust2 = f1 * f1 + f2 * f2 + f3 * f3 + f4 * f4
    # Ties (gamma = +-90 deg from neutral) go to positive thrust.
    reverse = -(f1 + f2 + f3 + f4)
    if family:
        return True, thrust2, move, reverse, 0.0
    return True, 0.0, move, reverse, thrust2


@jit.kernel()
def _before(k0: float, k1: float, k2: float, k3: float, i: int, m0: float, m1: float,
            m2: float, m3: float, mi: int) -> bool:
    """(k, i) < (m, mi), lexicographically."""
    if k0 != m0:
        return k0 < m0
    if k1 != m1:
        return k1 < m1
    if k2 != m2:
        return k2 < m2
    if k3 != m3:
        return k3 < m3
    return i < mi


@jit.kernel()
def _next(cfg: FloatArray, conf: FloatArray, first: int, count: int, ref0: float,
          ref1: float, box: FloatArray, l0: float, l1: float, l2: float, l3: float, li: int
          ) -> tuple[int, float, float, float, float]:
    """The qualifying variant that comes next after (l, li) in the reference's sorted
    order (positions count the variants of ``conf[first:]``, 9 a candidate): its
    position (-1: none) and key."""
    best, b0, b1, b2, b3 = -1, 0.0, 0.0, 0.0, 0.0
    for j in range(first, first + count):
        front = options(cfg, conf, j, 0, ref0, box)
        rear = options(cfg, conf, j, 1, ref1, box)
        family = conf[j, CONF_FAMILY] != 0.0
        c = CONF_THRUSTS
        for va in range(3):
            ok_a, a, sign_a = _option(va, *front)
            if not ok_a:
                continue
            for vb in range(3):
                ok_b, b, sign_b = _option(vb, *rear)
                if not ok_b:
                    continue
                ok, k0, k1, k2, k3 = key(cfg, family, conf[j, c] * sign_a,
                                         conf[j, c + 1] * sign_a, conf[j, c + 2] * sign_b,
                                         conf[j, c + 3] * sign_b, a, b, ref0, ref1, box)
                i = (j - first) * VARIANTS + 3 * va + vb
                if not ok or (li >= 0 and not _before(l0, l1, l2, l3, li, k0, k1, k2, k3, i)):
                    continue
                if best < 0 or _before(k0, k1, k2, k3, i, b0, b1, b2, b3, best):
                    best, b0, b1, b2, b3 = i, k0, k1, k2, k3
    return best, b0, b1, b2, b3


@jit.kernel()
def choose(cfg: FloatArray, tau: FloatArray, conf: FloatArray, first: int, count: int, disc: float,
           ref0: float, ref1: float, box: FloatArray, strict: bool, out: FloatArray) -> bool:
    """``selection.choose`` over ``conf[first:first + count]``: the exact candidate the
    rule of Section 3.2 picks, written into ``out``; False when none qualifies.
    ``ref0, ref1``: the previous tilts (0 without ``previous``)."""
    lo, hi = cfg[CFG_TILT_MIN], cfg[CFG_TILT_MAX]
    exact_tol = EXACT_RTOL * norm6(tau[0], tau[1], tau[2], tau[3], tau[4], tau[5])
    li, l0, l1, l2, l3 = -1, 0.0, 0.0, 0.0, 0.0
    while True:
        li, l0, l1, l2, l3 = _next(cfg, conf, first, count, ref0, ref1, box, l0, l1, l2, l3,
                                   li)
        if li < 0:
            return False
        j, v = first + li // VARIANTS, li % VARIANTS
        _, f1, f2, f3, f4, a, b = variant(cfg, conf, j, v, ref0, ref1, box)
        a, b = min(max(a, lo), hi), min(max(b, lo), hi)
        zero = f1 == 0.0 and f2 == 0.0 and f3 == 0.0 and f4 == 0.0
        method = _ZERO if zero else (_FAMILY if conf[j, CONF_FAMILY] != 0.0 else _EXACT)
        make(cfg, tau, f1, f2, f3, f4, a, b, method, disc, out)
        if strict:
            A = OUT_ACHIEVED
            miss = norm6(out[A] - tau[0], out[A + 1] - tau[1], out[A + 2] - tau[2],
                         out[A + 3] - tau[3], out[A + 4] - tau[4], out[A + 5] - tau[5])
            if miss > exact_tol:
                continue
        ca = min(max(a, box[0, 0]), box[0, 1])
        cb = min(max(b, box[1, 0]), box[1, 1])
        if ca != a or cb != b:                   # paper mode only
            make(cfg, tau, f1, f2, f3, f4, ca, cb, _SATURATED, disc, out)
        return True


@jit.kernel()
def pick(cfg: FloatArray, tau: FloatArray, conf: FloatArray, count: int, ref0: float, ref1: float,
         box: FloatArray) -> tuple[bool, float, float, float, float, float, float]:
    """One row of ``selection.choose_rows``: (done, f1..f4, alpha, beta) of the first
    variant in the sorted order, when it reproduces the wrench (FEASIBILITY_RTOL)."""
    best, _, _, _, _ = _next(cfg, conf, 0, count, ref0, ref1, box, 0.0, 0.0, 0.0, 0.0, -1)
    if best < 0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    _, f1, f2, f3, f4, a, b = variant(cfg, conf, best // VARIANTS, best % VARIANTS, ref0,
                                      ref1, box)
    lo, hi = cfg[CFG_TILT_MIN], cfg[CFG_TILT_MAX]
    a, b = min(max(a, lo), hi), min(max(b, lo), hi)
    if cfg[CFG_MODE] != MODE_ROBUST:
        a, b = min(max(a, box[0, 0]), box[0, 1]), min(max(b, box[1, 0]), box[1, 1])
    X, Y, Z, K, M, N = wrench_of(cfg, f1, f2, f3, f4, a, b)
    miss = plain_norm6(X - tau[0], Y - tau[1], Z - tau[2], K - tau[3], M - tau[4], N - tau[5])
    size = max(plain_norm6(tau[0], tau[1], tau[2], tau[3], tau[4], tau[5]), cfg[CFG_FMAX])
    return miss <= FEASIBILITY_RTOL * size, f1, f2, f3, f4, a, b


@jit.kernel()
def snapped(tau: FloatArray, out: FloatArray) -> bool:
    """``selection.snapped_candidates``' wrench: ``tau`` with its components below
    SNAP_RTOL of the largest set to zero, into ``out``; False when nothing changed."""
    top = 0.0
    for i in range(6):
        top = max(top, abs(tau[i]))
    changed = False
    for i in range(6):
        out[i] = 0.0 if abs(tau[i]) <= SNAP_RTOL * top else tau[i]
        if out[i] != tau[i]:
            changed = True
    return changed
