"""Choosing among exact solutions: the rule of Section 3.2, completed.

Among discrete solutions, the one whose tilts move least from ``previous``
(sum of squared tilt changes; from 0 without ``previous``), as in the paper,
ties going to positive thrust (at +-90 deg from neutral: the thrust line can
then turn on past vertical without a 180 deg flip); only solutions within the
thrust limit and the tilt range (and, in robust mode, within ``max_tilt_step``
of ``previous``) qualify. Within a family, the member with the least thrust
among those that qualify (:mod:`.families`), ties going to the least tilt
motion. :func:`choose` picks for one wrench in plain floats (the hot path of
every control cycle); :func:`choose_batch` for many wrenches at once, equal to
it row by row (a test keeps them so).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core.allocation.closed_form import (
    EXACT_RTOL,
    Solved,
    candidates,
    family_rows,
    solve_batch,
    symmetric_rows,
)
from tiltrov_ros.core.allocation.decomposition import ExactConfig, FloatArray
from tiltrov_ros.core.allocation.limits import LIMIT_SLACK, Limits
from tiltrov_ros.core.allocation.results import FEASIBILITY_RTOL, AllocationResult, norm
from tiltrov_ros.core.thrust_map import thrust_wrench

#: Robust mode: wrench components below this fraction of the largest one may be
#: read as zero to reach a family of solutions (see :func:`snapped_candidates`).
SNAP_RTOL = 1e-5
# Tilt motions (sum of squared changes, rad^2) closer than this are ties.
_MOVE_RESOLUTION = 1e-12


def variants(limits: Limits, cfg: ExactConfig, prev: FloatArray | None,
              box: FloatArray) -> list[tuple[tuple[float, ...], tuple[float, float]]]:
    """(thrusts, tilts) of a candidate for every equivalent tilt in range.

    gamma + pi turns the thrust line around: same line, thrust negated. A
    pair without thrust takes the previous tilt (or 0), clipped into reach.
    """
    lo, hi = limits.tilt_min, limits.tilt_max
    per_pair: list[list[tuple[float, float]]] = []
    for p in range(2):
        if cfg.tilt_free[p]:
            rest = float(prev[p]) if prev is not None else 0.0
            per_pair.append([(min(max(rest, float(box[p, 0])), float(box[p, 1])), 1.0)])
            continue
        gamma = float(cfg.tilts[p])
        options = [(gamma + shift, sign) for shift, sign in
                   ((0.0, 1.0), (math.pi, -1.0), (-math.pi, -1.0))
                   if lo - LIMIT_SLACK <= gamma + shift <= hi + LIMIT_SLACK]
        per_pair.append(options or [(gamma, 1.0)])
    f1, f2, f3, f4 = (float(v) for v in cfg.thrusts)
    return [((f1 * s_f, f2 * s_f, f3 * s_r, f4 * s_r), (alpha, beta))
            for (alpha, s_f), (beta, s_r) in itertools.product(*per_pair)]


def choose(limits: Limits, tau: FloatArray, configs: list[ExactConfig], disc: float,
            prev: FloatArray | None, box: FloatArray,
            strict: bool = True) -> AllocationResult | None:
    """The exact candidate the rule of Section 3.2 picks among those that qualify.

    Qualify: thrusts within the limit, tilts within the range and, in robust
    mode, within ``max_tilt_step`` of ``previous``. Paper mode then clips the
    tilts to ``max_tilt_step`` (losing exactness, reported as 'saturated').
    ``strict``: the pick must reproduce the wrench to rounding (the residual
    of (*) can hide an amplified error in nearly degenerate cases); a pick
    that does not is dropped and the next one taken.
    Plain floats: this is the hot path of every control cycle.
    """
    ref0, ref1 = (float(prev[0]), float(prev[1])) if prev is not None else (0.0, 0.0)
    fmax = limits.max_thrust * (1.0 + LIMIT_SLACK)
    lo, hi = limits.tilt_min, limits.tilt_max
    if limits.mode == 'robust':
        lo0, hi0 = float(box[0, 0]) - LIMIT_SLACK, float(box[0, 1]) + LIMIT_SLACK
        lo1, hi1 = float(box[1, 0]) - LIMIT_SLACK, float(box[1, 1]) + LIMIT_SLACK
    else:
        lo0 = lo1 = lo - LIMIT_SLACK
        hi0 = hi1 = hi + LIMIT_SLACK
    ranked = []
    for cfg in configs:
        for f, (a, b) in variants(limits, cfg, prev, box):
            if max(abs(f[0]), abs(f[1]), abs(f[2]), abs(f[3])) > fmax:
                continue
            if not (lo0 <= a <= hi0 and lo1 <= b <= hi1):
                continue
            # Tilt motions within _MOVE_RESOLUTION rad^2 count as ties.
            move = round(((a - ref0) ** 2 + (b - ref1) ** 2) / _MOVE_RESOLUTION)
            thrust2 = f[0] * f[0] + f[1] * f[1] + f[2] * f[2] + f[3] * f[3]
            # Ties (gamma = +-90 deg from neutral) go to positive thrust:
            # then the thrust line can turn on past vertical without a flip.
            reverse = -(f[0] + f[1] + f[2] + f[3])
            key = ((thrust2, move, reverse, 0.0) if cfg.family
                   else (0.0, move, reverse, thrust2))
            ranked.append((key, f, a, b, cfg.family))
    ranked.sort(key=lambda item: item[0])
    exact_tol = EXACT_RTOL * norm(tau)
    for _, f, a, b, family in ranked:
        a, b = min(max(a, lo), hi), min(max(b, lo), hi)
        result = limits.make(tau, np.array(f), np.array([a, b]),
                            'zero' if not any(f) else ('family' if family else 'exact'),
                            disc)
        if strict and norm(result.achieved - tau) > exact_tol:
            continue
        ca = min(max(a, float(box[0, 0])), float(box[0, 1]))
        cb = min(max(b, float(box[1, 0])), float(box[1, 1]))
        if (ca, cb) != (a, b):                   # paper mode only
            result = limits.make(tau, np.array(f), np.array([ca, cb]), 'saturated', disc)
        return result
    return None


def choose_family(limits: Limits, tau: FloatArray,
                   prev: FloatArray | None) -> AllocationResult | None:
    """The family member :func:`choose` would pick, by the vectorised selector."""
    rows, f, t = choose_rows(limits, tau[None, :], None if prev is None else prev[None, :])
    if not len(rows):
        return None
    method = 'family' if np.any(f[0]) else 'zero'
    return limits.make(tau, f[0], t[0], method, math.nan)


def snapped_candidates(limits: Limits, tau: FloatArray) -> list[ExactConfig]:
    """Exact candidates of tau with its tiny components (< SNAP_RTOL) set to zero.

    A wrench a hair away from a degenerate one (roll moment, sway and yaw
    at rounding level, as an integrator makes them) has only discrete
    solutions, ill-conditioned and far apart; the family of the wrench
    without those hairs is next to it. Robust mode only, and only taken when
    the true error of a candidate is within the feasibility tolerance.
    """
    peak = float(np.max(np.abs(tau)))
    snapped = np.where(np.abs(tau) <= SNAP_RTOL * peak, 0.0, tau)
    if np.array_equal(snapped, tau):
        return []
    configs, _ = candidates(limits.geometry, snapped)
    return configs_from_batch(limits, snapped) if configs is None else configs


def configs_from_batch(limits: Limits, tau: FloatArray) -> list[ExactConfig]:
    solved = solve_batch(limits.geometry, tau[None, :])
    return [ExactConfig(solved.thrusts[0, j], solved.tilts[0, j], bool(solved.family[0, j]),
                    (bool(solved.tilt_free[0, j, 0]), bool(solved.tilt_free[0, j, 1])))
            for j in np.flatnonzero(solved.valid[0])]


def choose_batch(limits: Limits, taus: FloatArray, prev: FloatArray | None
                  ) -> tuple[NDArray[np.intp], FloatArray, FloatArray]:
    """Vectorised :func:`choose` for the rows whose pick is exact.

    Returns the row indices done, their thrusts (k, 4) and tilts (k, 2).
    Rows on a family (many candidate slots) and the others (four slots)
    are solved apart, so a few hovering rows do not slow the rest down.
    """
    family = family_rows(limits.geometry, taus)
    # Symmetric family rows go through allocate() (closed form), so the
    # batch form answers exactly as single calls do.
    family &= ~symmetric_rows(limits.geometry, taus)
    symmetric = symmetric_rows(limits.geometry, taus)
    rows_out, f_out, t_out = [], [], []
    for subset in (np.flatnonzero(~family & ~symmetric), np.flatnonzero(family)):
        if len(subset) == 0:
            continue
        sub_prev = None if prev is None else prev[subset]
        rows, f, t = choose_rows(limits, taus[subset], sub_prev)
        rows_out.append(subset[rows])
        f_out.append(f)
        t_out.append(t)
    if not rows_out:
        return np.zeros(0, dtype=np.intp), np.zeros((0, 4)), np.zeros((0, 2))
    return np.concatenate(rows_out), np.concatenate(f_out), np.concatenate(t_out)


def choose_rows(limits: Limits, taus: FloatArray, prev: FloatArray | None
                 ) -> tuple[NDArray[np.intp], FloatArray, FloatArray]:
    n = len(taus)
    lo, hi = limits.tilt_min, limits.tilt_max
    ref = np.zeros((n, 2)) if prev is None else prev
    if prev is None or not math.isfinite(limits.max_tilt_step):
        box_lo, box_hi = np.full((n, 2), lo), np.full((n, 2), hi)
    else:
        box_lo = np.maximum(lo, prev - limits.max_tilt_step)
        box_hi = np.minimum(hi, prev + limits.max_tilt_step)
    aims = np.stack([ref, box_lo, box_hi], axis=2)           # (n, 2, 3)
    solved = solve_batch(limits.geometry, taus, aims)
    used = solved.valid.any(axis=0)                          # slots some row needs
    solved = Solved(solved.thrusts[:, used], solved.tilts[:, used], solved.valid[:, used],
                     solved.family[:, used], solved.tilt_free[:, used],
                     solved.discriminant)
    # Equivalent tilts gamma + {0, pi, -pi} per pair: 9 variants per candidate.
    shifts = np.array([0.0, math.pi, -math.pi])
    signs = np.array([1.0, -1.0, -1.0])
    va = np.repeat(np.arange(3), 3)                                 # (9,)
    vb = np.tile(np.arange(3), 3)
    tilts = solved.tilts[:, :, None, :] + np.stack([shifts[va], shifts[vb]], axis=1)
    sign = np.stack([signs[va], signs[va], signs[vb], signs[vb]], axis=1)  # (9, 4)
    thrusts = solved.thrusts[:, :, None, :] * sign                  # (n, m, 9, 4)
    free = solved.tilt_free[:, :, None, :]                          # (n, m, 1, 2)
    # A free pair rests at its previous tilt, once (variant 0 only).
    rest = np.clip(ref, box_lo, box_hi)[:, None, None, :]
    is_base = np.stack([va == 0, vb == 0], axis=1)[None, None]      # (1, 1, 9, 2)
    tilts = np.where(free, rest, tilts)
    ok = solved.valid[:, :, None] & np.all(~free | is_base, axis=3)
    fmax = limits.max_thrust * (1.0 + LIMIT_SLACK)
    ok &= np.all(np.abs(thrusts) <= fmax, axis=3)
    ok &= np.all((tilts >= lo - LIMIT_SLACK) & (tilts <= hi + LIMIT_SLACK), axis=3)
    if limits.mode == 'robust':
        ok &= np.all((tilts >= box_lo[:, None, None, :] - LIMIT_SLACK)
                     & (tilts <= box_hi[:, None, None, :] + LIMIT_SLACK), axis=3)
    fam = solved.family[:, :, None] & np.ones((1, 1, 9), dtype=bool)
    move = np.round(np.sum((tilts - ref[:, None, None, :]) ** 2, axis=3) / _MOVE_RESOLUTION)
    thrust2 = np.sum(thrusts ** 2, axis=3)
    reverse = -np.sum(thrusts, axis=3).reshape(n, -1)
    primary = np.where(ok, np.where(fam, thrust2, 0.0), np.inf).reshape(n, -1)
    secondary = move.reshape(n, -1)
    quaternary = np.where(fam, 0.0, thrust2).reshape(n, -1)
    rows = np.flatnonzero(ok.reshape(n, -1).any(axis=1))
    pick: NDArray[np.intp] = np.lexsort((quaternary, reverse, secondary, primary),
                                        axis=1)[rows, 0]
    f = thrusts.reshape(n, -1, 4)[rows, pick]
    t = np.clip(tilts.reshape(n, -1, 2)[rows, pick], lo, hi)
    if limits.mode == 'paper':
        t = np.clip(t, box_lo[rows], box_hi[rows])
    achieved = thrust_wrench(f, t[:, 0], t[:, 1], limits.geometry.length,
                              limits.geometry.width)
    tau = taus[rows]
    tol = FEASIBILITY_RTOL * np.maximum(np.linalg.norm(tau, axis=1), limits.max_thrust)
    good = np.linalg.norm(achieved - tau, axis=1) <= tol
    return rows[good], f[good], t[good]
