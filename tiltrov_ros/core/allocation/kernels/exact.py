"""Kernels mirroring :mod:`..closed_form`: the exact solutions of eq. (4).

The quadratic (**) that replaces the paper's (12)-(15) and its solution sets,
in plain float loops. :func:`candidates` mirrors
``closed_form.candidates`` (one wrench, the per-call path), :func:`solve_row`
one row of ``closed_form.solve_batch`` (with the sampled families of
:mod:`.families`). Solutions are written as rows of a ``conf`` array
(:mod:`.layout`, ``CONF_*``), in the reference's order.
"""

from __future__ import annotations

import math

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.closed_form import _DISC_RTOL, EXACT_RTOL
from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.families import FAMILY_RTOL
from tiltrov_ros.core.allocation.kernels.decomposition import (
    pair_scalar,
    pair_terms,
    pair_vector,
    peak,
)
from tiltrov_ros.core.allocation.kernels.families import family_uv
from tiltrov_ros.core.allocation.kernels.layout import (
    CONF_FAMILY,
    CONF_FREE,
    CONF_THRUSTS,
    CONF_TILTS,
    ROOT_SLOTS,
)
from tiltrov_ros.core.allocation.kernels.limits import wrench_sc


@jit.kernel()
def _write(conf: FloatArray, row: int, f1: float, f2: float, f3: float, f4: float,
           alpha: float, beta: float, family: bool, free_f: bool, free_r: bool) -> None:
    conf[row, CONF_THRUSTS] = f1
    conf[row, CONF_THRUSTS + 1] = f2
    conf[row, CONF_THRUSTS + 2] = f3
    conf[row, CONF_THRUSTS + 3] = f4
    conf[row, CONF_TILTS] = alpha
    conf[row, CONF_TILTS + 1] = beta
    conf[row, CONF_FAMILY] = 1.0 if family else 0.0
    conf[row, CONF_FREE] = 1.0 if free_f else 0.0
    conf[row, CONF_FREE + 1] = 1.0 if free_r else 0.0


@jit.kernel()
def candidates(cfg: FloatArray, tau: FloatArray, conf: FloatArray, first: int) -> tuple[int, float]:
    """``closed_form.candidates``: the exact solutions of (*) for one wrench into
    ``conf[first:]``; returns (count, discriminant of (**)); count -1: a family."""
    scale = peak(tau)
    if scale == 0.0:
        _write(conf, first, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, True, True)
        return 1, math.nan
    Zf, Zr, Df, Dr, kappa, H = pair_terms(cfg, tau, scale)
    P, Q = Zf * Df, Zr * Dr
    mag = max(abs(Zf), abs(Zr), abs(Df), abs(Dr), abs(kappa), abs(H))
    tol1, tol2 = FAMILY_RTOL * mag, FAMILY_RTOL * mag * mag
    small_P, small_Q = abs(P) <= tol2, abs(Q) <= tol2
    small_k, small_H = abs(kappa) <= tol1, abs(H) <= tol1
    if ((small_P and small_Q and (small_k or small_H))
            or (small_k and small_H and abs(P + Q) <= tol2)):
        return -1, math.nan
    a, b, c = H, -(P + Q + kappa * H), kappa * P
    disc = b * b - 4.0 * a * c
    nan = math.nan
    r1 = r2 = r3 = r4 = nan      # the roots tried, in the reference's order (NaN: none)
    slack = _DISC_RTOL * (abs(b) * (abs(P) + abs(Q) + abs(kappa * H)) + abs(4.0 * a * c))
    if disc >= -slack:
        sq = math.sqrt(max(disc, 0.0))
        qq = -0.5 * (b + (sq if b >= 0 else -sq))
        if a != 0.0:
            r1 = qq / a
        if qq != 0.0:
            r2 = c / qq
        elif a == 0.0:
            r2 = 0.0
    if small_P:
        r3 = 0.0
    if small_Q:
        r4 = kappa
    count = 0
    for r in range(4):
        U = r1 if r == 0 else (r2 if r == 1 else (r3 if r == 2 else r4))
        if U != U:
            continue
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
        f1, f2, alpha, free_f = pair_scalar(0.5 * (Zf + U), 0.5 * (V + Df),
                                            0.5 * (Zf - U), 0.5 * (V - Df))
        f3, f4, beta, free_r = pair_scalar(0.5 * (Zr + U - kappa), 0.5 * (H - V + Dr),
                                           0.5 * (Zr - U + kappa), 0.5 * (H - V - Dr))
        _write(conf, first + count, f1 * scale, f2 * scale, f3 * scale, f4 * scale,
               alpha, beta, False, free_f, free_r)
        count += 1
    return count, disc


@jit.kernel()
def classify(cfg: FloatArray, tau: FloatArray) -> tuple[float, float, float, float, float, float,
                                               float, float, float, int, float]:
    """One row of ``closed_form.classify``: (Zf, Zr, Df, Dr, kappa, H, P, Q, mag),
    the families (bits 1, 2, 4 for F1, F2, F3) and s."""
    top = peak(tau)
    s = top if top > 0 else 1.0
    Zf, Zr, Df, Dr, kappa, H = pair_terms(cfg, tau, s)
    P, Q = Zf * Df, Zr * Dr
    mag = max(abs(Zf), abs(Zr), abs(Df), abs(Dr), abs(kappa), abs(H), 1e-300)
    tol1, tol2 = FAMILY_RTOL * mag, FAMILY_RTOL * (mag * mag)
    small_P, small_Q = abs(P) <= tol2, abs(Q) <= tol2
    small_k, small_H = abs(kappa) <= tol1, abs(H) <= tol1
    families = 0
    if small_P and small_Q and small_k:
        families |= 1
    if small_P and small_Q and small_H:
        families |= 2
    if small_k and small_H and abs(P + Q) <= tol2 and not (small_P and small_Q):
        families |= 4
    return Zf, Zr, Df, Dr, kappa, H, P, Q, mag, families, s


@jit.kernel()
def symmetric_row(cfg: FloatArray, tau: FloatArray) -> bool:
    """One row of ``closed_form.symmetric_rows``: family F1 with Y = K = N = 0."""
    _, _, Df, Dr, kappa, _, _, _, mag, _, _ = classify(cfg, tau)
    tol = FAMILY_RTOL * mag
    return (abs(Df) <= tol and abs(Dr) <= tol and abs(kappa) <= tol
            and peak(tau) > 0)


@jit.kernel()
def solve_row(cfg: FloatArray, tau: FloatArray, aims: FloatArray, n_aims: int, uv: FloatArray,
              conf: FloatArray, first: int) -> int:
    """One row of ``closed_form.solve_batch(geometry, tau[None], aims)``: its valid
    candidates, in slot order, into ``conf[first:]``; returns their count.

    ``aims``: (2, MAX_AIMS), the first ``n_aims`` columns used (0: no aims);
    ``uv``: scratch (MAX_SLOTS, 2).
    """
    Zf, Zr, Df, Dr, kappa, H, P, Q, mag, families, s = classify(cfg, tau)
    top = peak(tau)
    tol2 = FAMILY_RTOL * (mag * mag)
    small_P, small_Q = abs(P) <= tol2, abs(Q) <= tol2
    nan = math.nan
    slots = ROOT_SLOTS
    if families:
        for j in range(ROOT_SLOTS):
            uv[j, 0] = nan
            uv[j, 1] = nan
        slots = family_uv(Zf, Zr, Df, Dr, kappa, H, P, mag, families, aims, n_aims,
                          uv, ROOT_SLOTS)
    else:
        # Roots of (**), a U^2 + b U + c = 0, in the cancellation-free form.
        a, b, c = H, -(P + Q + kappa * H), kappa * P
        disc = b * b - 4 * a * c
        slack = _DISC_RTOL * (abs(b) * (abs(P) + abs(Q) + abs(kappa * H)) + abs(4 * a * c))
        real = disc >= -slack
        sq = math.sqrt(max(disc, 0.0)) if disc == disc else nan
        qq = -0.5 * (b + (sq if b >= 0 else -sq))
        root1 = qq / a if a != 0 else nan
        root2 = c / qq if qq != 0 else (0.0 if a == 0 else nan)
        uv[0, 0] = root1 if real else nan
        uv[1, 0] = root2 if real else nan
        uv[2, 0] = 0.0 if small_P else nan
        uv[3, 0] = kappa if small_Q else nan
        for j in range(ROOT_SLOTS):
            U = uv[j, 0]
            uv[j, 1] = P / U if abs(U) >= abs(U - kappa) else H - Q / (U - kappa)
    u0, u1, u2, u3, u4, u5 = (tau[0] / s, tau[1] / s, tau[2] / s, tau[3] / s, tau[4] / s,
                              tau[5] / s)
    unit_norm = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2 + u3 * u3 + u4 * u4 + u5 * u5)
    count = 0
    if top == 0.0:                    # the zero wrench: one slot, both tilts free
        _write(conf, first, 0.0, 0.0, 0.0, 0.0, nan, nan, False, True, True)
        return 1
    for j in range(slots):
        U, V = uv[j, 0], uv[j, 1]
        if not (math.isfinite(U) and math.isfinite(V)):
            continue
        size = mag * mag + abs(U * V) + abs((U - kappa) * (H - V))
        if not (abs(U * V - P) <= 1e-9 * size and abs((U - kappa) * (H - V) - Q) <= 1e-9 * size):
            continue
        f1, f2, alpha, free_f, sa, ca = pair_vector(0.5 * (Zf + U), 0.5 * (V + Df),
                                                    0.5 * (Zf - U), 0.5 * (V - Df))
        f3, f4, beta, free_r, sb, cb = pair_vector(0.5 * (Zr + U - kappa), 0.5 * (H - V + Dr),
                                                   0.5 * (Zr - U + kappa), 0.5 * (H - V - Dr))
        if not (abs(f1) < 1e100 and abs(f2) < 1e100 and abs(f3) < 1e100 and abs(f4) < 1e100):
            continue
        # Verify every candidate on eq. (4) (scaled units): (*) can hide an amplified error.
        X, Y, Z, K, M, N = wrench_sc(cfg, f1, f2, f3, f4, sa, ca, sb, cb)
        dX, dY, dZ, dK, dM, dN = X - u0, Y - u1, Z - u2, K - u3, M - u4, N - u5
        error = math.sqrt(dX * dX + dY * dY + dZ * dZ + dK * dK + dM * dM + dN * dN)
        if not error <= EXACT_RTOL * unit_norm:
            continue
        _write(conf, first + count, f1 * s, f2 * s, f3 * s, f4 * s, alpha, beta,
               j >= ROOT_SLOTS, free_f, free_r)
        count += 1
    return count
