"""The one-parameter families of exact solutions (see :mod:`.closed_form`).

Hovering and other symmetric wrenches, where the printed closed form divides
by zero (the paper's (13) and (15)), have a continuum of exact solutions.
Within a family "moves the tilts least" has no minimiser worth having (it
pushes the thrusts to their limit to avoid any tilt motion), so the allocator
takes the member with the least thrust (sum f_i^2) among those that qualify;
the unconstrained least-thrust member is the pseudo-inverse solution xi = 0
(F1: V = H/2, F2: U = kappa/2, F3: U^2 = |P|).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from tiltrov_ros.core.allocation.decomposition import (
    BoolArray,
    ExactConfig,
    FloatArray,
    Geometry,
    pair_scalar,
)

#: Relative size under which P, Q, kappa, H count as zero (family detection).
FAMILY_RTOL = 1e-12
#: Samples along a one-parameter family of exact solutions.
FAMILY_SAMPLES = 33


def symmetric_family(geometry: Geometry, max_thrust: float, tau: FloatArray,
                     prev: FloatArray | None, box: FloatArray) -> list[ExactConfig] | None:
    """The members of family F1 that can be chosen, when Y = K = N = 0.

    Then each pair's two thrusters are alike: (h, z) = (V, Zf)/2 at the front
    and (H - V, Zr)/2 at the rear, so tan(alpha) = Zf / V,
    tan(beta) = Zr / (H - V), and the thrusts squared sum to
    (V^2 + (H - V)^2 + Zf^2 + Zr^2)/2, a convex quadratic in V. Its least
    value over the V that qualify (a union of intervals bounded by a tilt at
    an edge of its reach, a thrust at its limit, or a pair without
    horizontal force) is V = H/2 or one of those bounds: these few members
    are returned (None when the wrench is not of this kind), for
    the allocator to pick among, as it picks among exact roots.
    """
    scale = max(abs(float(v)) for v in tau)
    if scale == 0.0:
        return None
    Zf, Zr, Df, Dr, kappa, H = geometry.pair_terms_scalar(tau / scale)
    mag = max(abs(Zf), abs(Zr), abs(Df), abs(Dr), abs(kappa), abs(H))
    if max(abs(Df), abs(Dr), abs(kappa)) > FAMILY_RTOL * mag:
        return None
    values = {0.5 * H, 0.0, H}
    limit = 2.0 * max_thrust / scale          # |(h, z)| of a pair's thruster, x2
    for p, (Zp, sign, offset) in enumerate(((Zf, 1.0, 0.0), (Zr, -1.0, H))):
        tilts = [float(box[p, 0]), float(box[p, 1])]
        if prev is not None:
            tilts.append(float(prev[p]))
        for t in tilts:
            tan_t = math.tan(t)
            if abs(tan_t) > 1e-12 and abs(tan_t) < 1e12:
                values.add((Zp / tan_t - offset) * sign)     # h_p = Zp / tan(t)
        if limit > abs(Zp):
            reach = math.sqrt(limit * limit - Zp * Zp)
            values.update(((reach - offset) * sign, (-reach - offset) * sign))
    configs = []
    for V in sorted(values):
        f1, f2, alpha, free_f = pair_scalar(0.5 * Zf, 0.5 * V, 0.5 * Zf, 0.5 * V)
        f3, f4, beta, free_r = pair_scalar(0.5 * Zr, 0.5 * (H - V), 0.5 * Zr,
                                            0.5 * (H - V))
        with np.errstate(over='ignore'):
            thrusts = np.array([f1, f2, f3, f4]) * scale
        configs.append(ExactConfig(thrusts, np.array([alpha, beta]), True, (free_f, free_r)))
    return configs


def kink_points(fixed: FloatArray, slope: FloatArray, offset: FloatArray) -> FloatArray:
    """Where the largest of sqrt(a_i^2 + (s_i t / 2 + c_i)^2) over i can be least, per row.

    Along families F1 and F2 each thruster's force is sqrt(a_i^2 + (s_i t/2 + c_i)^2)
    with s_i = +-1: the squares share their leading coefficient, so two of them
    are equal where a *linear* equation holds. The minimiser of the largest
    force is where one term is least (s_i t/2 + c_i = 0) or two are equal:
    4 + 6 points, given here (n, 10) (NaN where two terms never meet).
    fixed, slope, offset: (n, 4) each.
    """
    points = [-2.0 * offset[:, i] / slope[:, i] for i in range(4)]
    for i, j in itertools.combinations(range(4), 2):
        num = (fixed[:, j] ** 2 + offset[:, j] ** 2) - (fixed[:, i] ** 2 + offset[:, i] ** 2)
        den = slope[:, i] * offset[:, i] - slope[:, j] * offset[:, j]
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            points.append(np.where(den != 0, num / den, np.nan))
    out = np.stack(points, axis=1)
    # A point beyond any sensible scale (a denominator at rounding level) is
    # useless and would overflow later: drop it.
    return np.where(np.abs(out) < 1e150, out, np.nan)


def family_samples(fam1: BoolArray, fam2: BoolArray, fam3: BoolArray,
                    geometry: tuple[FloatArray, ...], P: FloatArray, mag: FloatArray,
                    aims: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """(U, V) samples along the one-parameter families, NaN where a row has none.

    Spread around each family's least-thrust member, which is included
    (F1, U = 0: V = H/2; F2, V = 0: U = kappa/2; F3, V = P/U: U = +-sqrt|P|),
    plus, for F1 and F2, the candidates for the member whose largest thruster
    force is least (:func:`kink_points`): if any member is within the thrust
    limit, that one is, so solutions at the limit are not missed. ``aims``
    (n, 2, k): tilts per pair (front, rear) to aim at, e.g. the previous tilts
    and the edges of their reach; along F1 and F2 a pair's tilt is explicit
    in the family parameter (F1: tan(alpha) = Zf / V, tan(beta) = Zr / (H - V);
    F2: tan(alpha) = U / Df, tan(beta) = (U - kappa) / Dr), so the members with
    those tilts are added.
    """
    Zf, Zr, Df, Dr, kappa, H = geometry
    n, s = len(H), FAMILY_SAMPLES
    spread = mag[:, None] * np.tan(np.linspace(-1.5, 1.5, s))[None, :]
    ones = np.ones(n)
    # F1 (U = 0): z fixed, h_i = s_i V/2 + c_i.
    f1_kinks = kink_points(0.5 * np.stack([Zf, Zf, Zr - kappa, Zr + kappa], axis=1),
                            np.stack([ones, ones, -ones, -ones], axis=1),
                            0.5 * np.stack([Df, -Df, H + Dr, H - Dr], axis=1))
    # F2 (V = 0): h fixed, z_i = s_i U/2 + c_i.
    f2_kinks = kink_points(0.5 * np.stack([Df, -Df, H + Dr, H - Dr], axis=1),
                            np.stack([ones, -ones, ones, -ones], axis=1),
                            0.5 * np.stack([Zf, Zf, Zr - kappa, Zr + kappa], axis=1))
    f1_v = np.concatenate([0.5 * H[:, None] + spread, f1_kinks], axis=1)
    f2_u = np.concatenate([0.5 * kappa[:, None] + spread, f2_kinks], axis=1)
    if aims is not None:
        tan_f, tan_r = np.tan(aims[:, 0, :]), np.tan(aims[:, 1, :])
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            f1_v = np.concatenate([f1_v, Zf[:, None] / tan_f,
                                   H[:, None] - Zr[:, None] / tan_r], axis=1)
            f2_u = np.concatenate([f2_u, Df[:, None] * tan_f,
                                   kappa[:, None] + Dr[:, None] * tan_r], axis=1)
        f1_v = np.where(np.isfinite(f1_v), f1_v, np.nan)
        f2_u = np.where(np.isfinite(f2_u), f2_u, np.nan)
    m = f1_v.shape[1]
    nan = np.full((n, m), np.nan)
    f1_u = np.where(fam1[:, None], 0.0, nan)
    f1_v = np.where(fam1[:, None], f1_v, nan)
    f2_u = np.where(fam2[:, None], f2_u, nan)
    f2_v = np.where(fam2[:, None], 0.0, nan)
    half = (s + 1) // 2
    ratio = np.exp(np.linspace(-3.0, 3.0, half))
    sign = np.concatenate([np.ones(half), -np.ones(s - half)])
    ratio = np.concatenate([ratio, ratio[: s - half]])
    u3 = np.where(fam3[:, None], sign * np.sqrt(np.abs(P))[:, None] * ratio,
                  np.full((n, s), np.nan))
    with np.errstate(divide='ignore', invalid='ignore'):
        v3 = np.where(fam3[:, None], P[:, None] / u3, np.nan)
    return (np.concatenate([f1_u, f2_u, u3], axis=1),
            np.concatenate([f1_v, f2_v, v3], axis=1))
