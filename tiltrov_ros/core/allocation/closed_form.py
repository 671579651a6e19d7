"""Exact solutions of eq. (4): the quadratic that replaces the paper's (12)-(15).

In the coordinates of :mod:`.decomposition`, two null-space coordinates are
free, U = D_f sin(alpha) and V = S_f cos(alpha) (U = c1 - c2 - 2 xi2 and
V = c5 + c6 - 2 xi1 in the paper's notation), and the pair constraint (9),
z1 h2 = z2 h1 per pair, is exactly

    U V = P,   (U - kappa)(H - V) = Q,   P = Zf Df,  Q = Zr Dr,        (*)

two rectangular hyperbolas. For U not in {0, kappa}, eliminating V gives the
quadratic that replaces (12)-(15):

    H U^2 - (P + Q + kappa H) U + kappa P = 0.                         (**)

Solution sets of (*):

* generic: the roots of (**) (one double root when its discriminant is zero,
  none when it is negative: the paper's Delta < 0), plus U = 0 or U = kappa when
  they solve (*);
* family F1 (P = Q = kappa = 0, e.g. surge + heave + pitch): U = 0, V free;
* family F2 (P = Q = H = 0, e.g. pure heave or pure pitch): V = 0, U free;
* family F3 (kappa = H = 0, P = -Q != 0): V = P/U, U free.

:func:`candidates` solves one wrench with plain floats (the per-call path),
:func:`solve_batch` many at once with the families sampled
(:mod:`.families`); a test keeps them equal.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from tiltrov_ros.core.allocation.decomposition import (
    BoolArray,
    ExactConfig,
    FloatArray,
    Geometry,
    pair_scalar,
    pairs_to_actuators,
)
from tiltrov_ros.core.allocation.families import FAMILY_RTOL, family_samples
from tiltrov_ros.core.thrust_map import thrust_wrench

# Slack on a negative discriminant of (**) read as a double root (rounding).
_DISC_RTOL = 1e-13
#: A candidate of the closed form must reproduce the wrench to this (relative).
EXACT_RTOL = 1e-10


def candidates(geometry: Geometry, tau: FloatArray) -> tuple[list[ExactConfig] | None, float]:
    """Exact solutions of (*) for one wrench, and the discriminant of (**).

    None instead of the list when the solutions form a one-parameter family
    (see :func:`solve_batch`, which samples them).
    """
    scale = max(abs(float(v)) for v in tau)
    if scale == 0.0:
        return [ExactConfig(np.zeros(4), np.zeros(2), False, (True, True))], math.nan
    Zf, Zr, Df, Dr, kappa, H = geometry.pair_terms_scalar(tau / scale)
    P, Q = Zf * Df, Zr * Dr
    mag = max(abs(Zf), abs(Zr), abs(Df), abs(Dr), abs(kappa), abs(H))
    tol1, tol2 = FAMILY_RTOL * mag, FAMILY_RTOL * mag * mag
    small_P, small_Q = abs(P) <= tol2, abs(Q) <= tol2
    small_k, small_H = abs(kappa) <= tol1, abs(H) <= tol1
    if ((small_P and small_Q and (small_k or small_H))
            or (small_k and small_H and abs(P + Q) <= tol2)):
        return None, math.nan
    a, b, c = H, -(P + Q + kappa * H), kappa * P
    disc = b * b - 4.0 * a * c
    roots: list[float] = []
    # Rounding in b comes from cancelling P + Q + kappa H, so the slack on
    # the discriminant scales with those terms, not with b^2 alone.
    slack = _DISC_RTOL * (abs(b) * (abs(P) + abs(Q) + abs(kappa * H)) + abs(4.0 * a * c))
    if disc >= -slack:
        sq = math.sqrt(max(disc, 0.0))
        qq = -0.5 * (b + (sq if b >= 0 else -sq))
        if a != 0.0:
            roots.append(qq / a)
        if qq != 0.0:
            roots.append(c / qq)
        elif a == 0.0:
            roots.append(0.0)
    if small_P:
        roots.append(0.0)
    if small_Q:
        roots.append(kappa)
    configs = []
    for U in roots:
        use_p = abs(U) >= abs(U - kappa)
        if (U if use_p else U - kappa) == 0.0:
            continue          # U = kappa = 0 leaves V free: a family, handled above
        V = P / U if use_p else H - Q / (U - kappa)
        if not (math.isfinite(U) and math.isfinite(V)):
            continue
        size = mag * mag + abs(U * V) + abs((U - kappa) * (H - V))
        if (abs(U * V - P) > 1e-9 * size
                or abs((U - kappa) * (H - V) - Q) > 1e-9 * size):
            continue
        z = (0.5 * (Zf + U), 0.5 * (Zf - U), 0.5 * (Zr + U - kappa),
             0.5 * (Zr - U + kappa))
        h = (0.5 * (V + Df), 0.5 * (V - Df), 0.5 * (H - V + Dr), 0.5 * (H - V - Dr))
        f1, f2, alpha, free_f = pair_scalar(z[0], h[0], z[1], h[1])
        f3, f4, beta, free_r = pair_scalar(z[2], h[2], z[3], h[3])
        with np.errstate(over='ignore'):      # inf thrusts fail the limit check
            thrusts = np.array([f1, f2, f3, f4]) * scale
        configs.append(ExactConfig(thrusts, np.array([alpha, beta]), False, (free_f, free_r)))
    return configs, disc


@dataclass(frozen=True)
class Solved:
    """Exact candidates for n wrenches, m candidate slots each."""

    thrusts: FloatArray       # (n, m, 4)
    tilts: FloatArray         # (n, m, 2)
    valid: BoolArray          # (n, m)
    family: BoolArray         # (n, m)
    tilt_free: BoolArray      # (n, m, 2)
    discriminant: FloatArray  # (n,)


def classify(geometry: Geometry, tau: FloatArray
             ) -> tuple[tuple[FloatArray, ...], tuple[BoolArray, BoolArray, BoolArray],
                        FloatArray]:
    """Pair quantities of tau / s and the family flags, for tau (n, 6).

    Returns ((Zf, Zr, Df, Dr, kappa, H, P, Q, mag), (fam1, fam2, fam3), s).
    """
    n = len(tau)
    peak = np.max(np.abs(tau), axis=1)
    s = np.where(peak > 0, peak, 1.0)
    Zf, Zr, Df, Dr, kappa, H = geometry.pair_terms(tau / s[:, None])
    P, Q = Zf * Df, Zr * Dr
    mag = np.maximum.reduce([np.abs(Zf), np.abs(Zr), np.abs(Df), np.abs(Dr),
                             np.abs(kappa), np.abs(H), np.full(n, 1e-300)])
    tol1, tol2 = FAMILY_RTOL * mag, FAMILY_RTOL * mag ** 2
    small_P, small_Q = np.abs(P) <= tol2, np.abs(Q) <= tol2
    small_k, small_H = np.abs(kappa) <= tol1, np.abs(H) <= tol1
    fam1 = small_P & small_Q & small_k
    fam2 = small_P & small_Q & small_H
    fam3 = small_k & small_H & (np.abs(P + Q) <= tol2) & ~(small_P & small_Q)
    return (Zf, Zr, Df, Dr, kappa, H, P, Q, mag), (fam1, fam2, fam3), s


def symmetric_rows(geometry: Geometry, tau: FloatArray) -> BoolArray:
    """Rows of family F1 with Y = K = N = 0 (see ThrustAllocator._symmetric_family)."""
    (_, _, Df, Dr, kappa, _, _, _, mag), _, _ = classify(geometry, tau)
    tol = FAMILY_RTOL * mag
    out: BoolArray = ((np.abs(Df) <= tol) & (np.abs(Dr) <= tol) & (np.abs(kappa) <= tol)
                      & (np.max(np.abs(tau), axis=1) > 0))
    return out


def family_rows(geometry: Geometry, tau: FloatArray) -> BoolArray:
    """Rows whose solutions form a one-parameter family (or the zero wrench)."""
    _, (fam1, fam2, fam3), _ = classify(geometry, tau)
    family: BoolArray = fam1 | fam2 | fam3
    return family


def solve_batch(geometry: Geometry, tau: FloatArray,
                aims: FloatArray | None = None) -> Solved:
    """All exact (U, V) of (*) for each row of tau (n, 6), mapped to actuators.

    The vectorised twin of :func:`candidates` (a test keeps
    them equal), with the one-parameter families sampled. The problem is
    homogeneous of degree one in tau: it is solved for tau / s
    (s = max |tau_i|) and the thrusts are scaled back, so huge wrenches do not
    overflow and tolerances are relative.
    """
    (Zf, Zr, Df, Dr, kappa, H, P, Q, mag), (fam1, fam2, fam3), s = classify(
        geometry, tau)
    peak = np.max(np.abs(tau), axis=1)
    tol2 = FAMILY_RTOL * mag ** 2
    small_P, small_Q = np.abs(P) <= tol2, np.abs(Q) <= tol2
    any_family = fam1 | fam2 | fam3

    # Roots of (**), a U^2 + b U + c = 0, in the cancellation-free form.
    a, b, c = H, -(P + Q + kappa * H), kappa * P
    disc = b * b - 4 * a * c
    slack = _DISC_RTOL * (np.abs(b) * (np.abs(P) + np.abs(Q) + np.abs(kappa * H))
                          + np.abs(4 * a * c))
    real = disc >= -slack
    sq = np.sqrt(np.maximum(disc, 0.0))
    qq = -0.5 * (b + np.where(b >= 0, sq, -sq))
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        u1 = np.where(a != 0, qq / a, np.nan)
        u2 = np.where(qq != 0, c / qq, np.where(a == 0, 0.0, np.nan))
    roots = [np.where(real, u1, np.nan), np.where(real, u2, np.nan),
             np.where(small_P, 0.0, np.nan), np.where(small_Q, kappa, np.nan)]
    U = np.stack(roots, axis=1)
    U = np.where(any_family[:, None], np.nan, U)
    with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
        v_p = P[:, None] / U
        v_q = H[:, None] - Q[:, None] / (U - kappa[:, None])
    V = np.where(np.abs(U) >= np.abs(U - kappa[:, None]), v_p, v_q)
    family = np.zeros(U.shape, dtype=bool)
    if np.any(any_family):
        fu, fv = family_samples(fam1, fam2, fam3, (Zf, Zr, Df, Dr, kappa, H), P, mag, aims)
        U = np.concatenate([U, fu], axis=1)
        V = np.concatenate([V, fv], axis=1)
        family = np.concatenate([family, np.ones(fu.shape, dtype=bool)], axis=1)

    valid = np.isfinite(U) & np.isfinite(V)
    U = np.where(valid, U, 0.0)
    V = np.where(valid, V, 0.0)
    kap, HH = kappa[:, None], H[:, None]
    size = mag[:, None] ** 2 + np.abs(U * V) + np.abs((U - kap) * (HH - V))
    valid &= np.abs(U * V - P[:, None]) <= 1e-9 * size
    valid &= np.abs((U - kap) * (HH - V) - Q[:, None]) <= 1e-9 * size

    z = 0.5 * np.stack([Zf[:, None] + U, Zf[:, None] - U,
                        Zr[:, None] + U - kap, Zr[:, None] - U + kap], axis=2)
    h = 0.5 * np.stack([V + Df[:, None], V - Df[:, None],
                        HH - V + Dr[:, None], HH - V - Dr[:, None]], axis=2)
    thrusts, tilts, free = pairs_to_actuators(z, h)
    # Verify every candidate on eq. (4) (scaled units): (*) can hide an amplified error.
    # Thrusts this far beyond the wrench's scale are of no use (and would overflow).
    valid &= np.all(np.abs(thrusts) < 1e100, axis=2)
    thrusts = np.where(valid[..., None], thrusts, 0.0)
    unit = tau / s[:, None]
    achieved = thrust_wrench(thrusts, tilts[..., 0], tilts[..., 1], geometry.length,
                              geometry.width)
    error = np.linalg.norm(achieved - unit[:, None, :], axis=2)
    valid &= error <= EXACT_RTOL * np.linalg.norm(unit, axis=1)[:, None]
    # The zero wrench: everything is zero and both tilts are free.
    zero_row = peak == 0
    valid[zero_row, 1:] = False
    valid[zero_row, 0] = True
    thrusts[zero_row] = 0.0
    free[zero_row] = True
    with np.errstate(over='ignore', invalid='ignore'):  # inf thrusts fail the limit check
        thrusts = thrusts * s[:, None, None]
    return Solved(thrusts, tilts, valid, family, free,
                   np.where(any_family | zero_row, np.nan, disc))
