"""Thrusts at given tilts: the weighted least-squares thrusts within the thrust limit.

For tilts (a, b) the thrusts minimise ||W (B(a, b) f - tau)||^2 with
|f_i| <= f_max (eq. (4) with W = diag(weights)); the minimum is the reduced
cost c(a, b) that the tilt search (:mod:`.optimum`) and the planner
(:mod:`.planner`) work on. In the sum/difference coordinates of
:mod:`.decomposition` the weighted error splits into two blocks,
(S_f, S_r) -> (X, Z, M) and (D_f, D_r) -> (Y, K, N), each a 3 x 2 linear
least-squares problem whose normal equations are 2 x 2:

    G = [[A1 c1^2 + A2 s1^2,  B1 c1 c2 + B2 s1 s2],      g = (c1 u1 + s1 v1,
         [B1 c1 c2 + B2 s1 s2, A1 c2^2 + A2 s2^2]]            c2 u2 + s2 v2)

(c1, s1 = cos a, sin a; c2, s2 = cos b, sin b; the constants depend on the
weights, the geometry and the wrench, see :class:`TiltProblem`). So c(a, b)
without the limit is two 2 x 2 solves, evaluated on a whole grid of tilts in
one numpy expression, and its gradient follows by the envelope theorem
(dc/da = f' dG/da f - 2 dg/da' f at the optimal thrusts, valid with the limit
too, since the limit does not depend on the tilts).

With the limit (the pair diamonds |S_p| + |D_p| <= 2 f_max, i.e. the box
|f_i| <= f_max) the thrusts come from an active-set iteration on the box in
thruster coordinates, started from the violated bounds; rows it does not
settle in a few passes (rare) are solved by enumerating every active set
(3^4 of them), so the answer is always the exact minimum. Failed thrusters
are held at zero as bounds that never release.

Everything here works in scaled units (wrench and thrust limit divided by
s = max(max|tau_i|, f_max)) so that nothing overflows and tolerances are
relative; :class:`TiltProblem` records s.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core.allocation.decomposition import (
    SQRT2,
    BoolArray,
    FloatArray,
    Geometry,
)

# Regularisation of the normal equations, relative to their trace: singular
# tilts (both pairs level, say) take the least-thrust solution.
_RIDGE = 1e-12
# Relative slack on the thrust limit.
_SLACK = 1e-12
# Active-set passes before the enumeration fallback.
_PASSES = 6
# Active-set patterns of four thrusters: 0 free, 1 at the lower bound, 2 at the upper.
_PATTERNS = np.array(list(itertools.product((0, 1, 2), repeat=4)))
_EYE4 = np.eye(4)


class TiltProblem:
    """The thrust least squares of one wrench, ready to be evaluated at many tilts.

    Parameters
    ----------
    geometry : l and d
    tau : (6,) requested wrench (finite)
    max_thrust : f_max [N]
    weights : (6,) per-DOF weights W
    available : (4,) False for a failed thruster (held at zero)
    """

    def __init__(self, geometry: Geometry, tau: ArrayLike, max_thrust: float,
                 weights: ArrayLike, available: ArrayLike | None = None) -> None:
        values = [float(v) for v in np.asarray(tau, dtype=float).ravel()]
        self.scale = max(max(abs(v) for v in values), float(max_thrust))
        X, Y, Z, K, M, N = (v / self.scale for v in values)
        self.tau = np.array([X, Y, Z, K, M, N])               # scaled wrench
        self.fmax = float(max_thrust) / self.scale         # scaled limit (<= 1)
        self.weights = np.asarray(weights, dtype=float)
        avail = (np.ones(4, dtype=bool) if available is None
                 else np.asarray(available, dtype=bool))
        self.available = avail
        self.all_available = bool(avail.all())
        self.upper = np.where(avail, self.fmax, 0.0)
        wX, wY, wZ, wK, wM, wN = (float(v) ** 2 for v in self.weights)
        l, d, k = geometry.length, geometry.width, geometry.k
        # Block coefficients (A1, A2, B1, B2) of G; targets (u1, v1, u2, v2) of g.
        self.s_coef = (wX / 2, wZ + wM * l * l / 4, wX / 2, wZ - wM * l * l / 4)
        self.d_coef = (wY / 2 + wN * k * k, wK * d * d / 4, wY / 2 - wN * k * k,
                       -wK * d * d / 4)
        p = wX * X / SQRT2
        self.s_target = (p, -wZ * Z + wM * M * l / 2, p, -wZ * Z - wM * M * l / 2)
        q = wY * Y / SQRT2
        self.d_target = (q + wN * N * k, wK * K * d / 2, q - wN * N * k, -wK * K * d / 2)
        self.target_norm2 = (wX * X * X + wY * Y * Y + wZ * Z * Z + wK * K * K
                             + wM * M * M + wN * N * N)

    # ------------------------------------------------------------------ blocks

    def _blocks(self, ca: FloatArray, sa: FloatArray, cb: FloatArray, sb: FloatArray
                ) -> list[tuple[FloatArray, ...]]:
        """Per block (sums, differences): G11, G12, G22, g1, g2 at the tilts."""
        out: list[tuple[FloatArray, ...]] = []
        cc, ss = ca * cb, sa * sb
        ca2, sa2, cb2, sb2 = ca * ca, sa * sa, cb * cb, sb * sb
        for (A1, A2, B1, B2), (u1, v1, u2, v2) in ((self.s_coef, self.s_target),
                                                    (self.d_coef, self.d_target)):
            out.append((A1 * ca2 + A2 * sa2, B1 * cc + B2 * ss, A1 * cb2 + A2 * sb2,
                        ca * u1 + sa * v1, cb * u2 + sb * v2))
        return out

    @staticmethod
    def _solve2(G11: FloatArray, G12: FloatArray, G22: FloatArray, g1: FloatArray,
                g2: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Least-norm solution of the 2 x 2 normal equations, by their eigenvectors.

        The eigenvalues are Rayleigh quotients, so the large one is exact to
        rounding even when the other vanishes (both pairs level: the sums only
        make X); one below _RIDGE of the other counts as zero.
        """
        theta = 0.5 * np.arctan2(2.0 * G12, G11 - G22)
        c, s = np.cos(theta), np.sin(theta)
        big = G11 * c * c + 2.0 * G12 * c * s + G22 * s * s
        small = G11 * s * s - 2.0 * G12 * c * s + G22 * c * c
        big = np.where(big > 0.0, big, np.inf)
        small = np.where(small > _RIDGE * big, small, np.inf)
        with np.errstate(over='ignore'):
            p, q = (c * g1 + s * g2) / big, (c * g2 - s * g1) / small
        return c * p - s * q, s * p + c * q

    # ------------------------------------------------------------------ costs

    def bounds(self, a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(lower, upper) bounds of c at each pair of tilts, cheaply (scaled units).

        lower: the cost without the thrust limit. upper: the cost of a feasible
        point, the unconstrained thrusts scaled into the limit as a whole or one
        block at a time (exact where the unconstrained thrusts fit). With failed
        thrusters only the lower bound is meaningful (upper = lower).
        """
        ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
        (SG11, SG12, SG22, Sg1, Sg2), (DG11, DG12, DG22, Dg1, Dg2) = self._blocks(ca, sa, cb, sb)
        sf, sr = self._solve2(SG11, SG12, SG22, Sg1, Sg2)
        df, dr = self._solve2(DG11, DG12, DG22, Dg1, Dg2)
        yS = sf * Sg1 + sr * Sg2                      # reduction of the cost by each block
        yD = df * Dg1 + dr * Dg2
        lower = np.maximum(self.target_norm2 - yS - yD, 0.0)
        if not self.all_available:
            return lower, lower
        lim = 2.0 * self.fmax
        asf, asr, adf, adr = np.abs(sf), np.abs(sr), np.abs(df), np.abs(dr)
        load = np.maximum(asf + adf, asr + adr)
        s = np.minimum(1.0, lim / np.maximum(load, 1e-300))
        gain = s * (2.0 - s) * (yS + yD)
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            # Sums kept whole, differences scaled (and the other way round).
            t = np.clip(np.minimum((lim - asf) / adf, (lim - asr) / adr), 0.0, 1.0)
            keep_s = np.where((asf <= lim) & (asr <= lim), yS + t * (2.0 - t) * yD, 0.0)
            t = np.clip(np.minimum((lim - adf) / asf, (lim - adr) / asr), 0.0, 1.0)
            keep_d = np.where((adf <= lim) & (adr <= lim), yD + t * (2.0 - t) * yS, 0.0)
        gain = np.maximum(gain, np.nan_to_num(np.maximum(keep_s, keep_d)))
        return lower, np.maximum(self.target_norm2 - gain, lower)

    def exact(self, a: FloatArray, b: FloatArray, gradient: bool = False
              ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """Exact thrusts (m, 4) (scaled), cost c (m,) and, if asked, dc/d(a, b) (m, 2)."""
        a = np.asarray(a, dtype=float)
        b = np.asarray(b, dtype=float)
        ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
        blocks = self._blocks(ca, sa, cb, sb)
        (SG11, SG12, SG22, Sg1, Sg2), (DG11, DG12, DG22, Dg1, Dg2) = blocks
        sf, sr = self._solve2(SG11, SG12, SG22, Sg1, Sg2)
        df, dr = self._solve2(DG11, DG12, DG22, Dg1, Dg2)
        f = 0.5 * np.stack([sf + df, sf - df, sr + dr, sr - dr], axis=-1)
        out = ~np.all(np.abs(f) <= self.upper * (1.0 + _SLACK), axis=1)
        if not self.all_available:
            out[:] = True
        if np.any(out):
            rows = np.flatnonzero(out)
            G, g = self._normal_f(blocks, rows)
            f[rows] = self._box(G, g, f[rows])
            sf, df = f[:, 0] + f[:, 1], f[:, 0] - f[:, 1]
            sr, dr = f[:, 2] + f[:, 3], f[:, 2] - f[:, 3]
        cost = (self.target_norm2
                + sf * (SG11 * sf + 2.0 * SG12 * sr) + sr * SG22 * sr - 2.0 * (Sg1 * sf + Sg2 * sr)
                + df * (DG11 * df + 2.0 * DG12 * dr) + dr * DG22 * dr - 2.0 * (Dg1 * df + Dg2 * dr))
        cost = np.maximum(cost, 0.0)
        if not gradient:
            return f, cost, None
        grad = np.zeros((len(a), 2))
        for (A1, A2, B1, B2), (u1, v1, u2, v2), x1, x2 in (
                (self.s_coef, self.s_target, sf, sr), (self.d_coef, self.d_target, df, dr)):
            grad[:, 0] += (x1 * x1 * 2.0 * (A2 - A1) * sa * ca
                           + 2.0 * x1 * x2 * (-B1 * sa * cb + B2 * ca * sb)
                           - 2.0 * x1 * (-sa * u1 + ca * v1))
            grad[:, 1] += (x2 * x2 * 2.0 * (A2 - A1) * sb * cb
                           + 2.0 * x1 * x2 * (-B1 * ca * sb + B2 * sa * cb)
                           - 2.0 * x2 * (-sb * u2 + cb * v2))
        return f, cost, grad

    # ------------------------------------------------------------------ the box

    @staticmethod
    def _normal_f(blocks: list[tuple[FloatArray, ...]], rows: NDArray[np.intp]
                  ) -> tuple[FloatArray, FloatArray]:
        """Normal equations in thruster coordinates (k, 4, 4), (k, 4) for the rows.

        S_f = f1 + f2, D_f = f1 - f2, ...: G_f = P_S' G_S P_S + P_D' G_D P_D.
        """
        (SG11, SG12, SG22, Sg1, Sg2), (DG11, DG12, DG22, Dg1, Dg2) = (
            tuple(v[rows] for v in blk) for blk in blocks)
        a, b = SG11 + DG11, SG11 - DG11
        c, e = SG12 + DG12, SG12 - DG12
        m, n = SG22 + DG22, SG22 - DG22
        G = np.stack([np.stack([a, b, c, e], -1), np.stack([b, a, e, c], -1),
                      np.stack([c, e, m, n], -1), np.stack([e, c, n, m], -1)], -2)
        g = np.stack([Sg1 + Dg1, Sg1 - Dg1, Sg2 + Dg2, Sg2 - Dg2], -1)
        ridge = _RIDGE * (np.trace(G, axis1=1, axis2=2) + 1e-300)
        return G + ridge[:, None, None] * _EYE4, g

    def _box(self, G: FloatArray, g: FloatArray, start: FloatArray) -> FloatArray:
        """min f' G f - 2 g' f over |f_i| <= upper_i, exactly, row by row."""
        up = self.upper
        failed = ~self.available
        at_hi: BoolArray = (start > up) & ~failed
        at_lo: BoolArray = (start < -up) & ~failed
        fixed = at_hi | at_lo | failed
        x = np.clip(start, -up, up)
        done = np.zeros(len(G), dtype=bool)
        tol = 1e-9 * (np.abs(g).max(axis=1) + 1e-300)
        for _ in range(_PASSES):
            value = np.where(at_hi, up, np.where(at_lo, -up, 0.0))
            x = _solve_fixed(G, g, fixed, value)
            grad = np.einsum('kij,kj->ki', G, x) - g
            high = ~fixed & (x > up * (1.0 + _SLACK))
            low = ~fixed & (x < -up * (1.0 + _SLACK))
            # Multipliers of the bounds held: at the upper one the gradient must be
            # <= 0, at the lower one >= 0.
            wrong = (at_hi & (grad > tol[:, None])) | (at_lo & (grad < -tol[:, None]))
            done = ~(high | low).any(axis=1) & ~wrong.any(axis=1)
            if done.all():
                break
            # Violated bounds join; of the wrong multipliers, the worst leaves.
            release = np.zeros_like(wrong)
            worst = np.argmax(np.abs(grad) * wrong, axis=1)
            release[np.arange(len(G)), worst] = wrong.any(axis=1) & ~(high | low).any(axis=1)
            at_hi = (at_hi | high) & ~release
            at_lo = (at_lo | low) & ~release
            fixed = at_hi | at_lo | failed
        if not done.all():
            rows = np.flatnonzero(~done)
            x[rows] = _enumerate(G[rows], g[rows], -up, up)
        out: FloatArray = np.clip(x, -up, up)
        return out


def _solve_fixed(G: FloatArray, g: FloatArray, fixed: BoolArray,
                 value: FloatArray) -> FloatArray:
    """Solve G x = g for the free entries, the fixed ones held at ``value``."""
    M = np.where(fixed[:, :, None] | fixed[:, None, :], 0.0, G) + fixed[:, :, None] * _EYE4
    rhs = np.where(fixed, value, g - np.einsum('kij,kj->ki', G, value * fixed))
    x: FloatArray = np.linalg.solve(M.astype(float), rhs[..., None])[..., 0]
    return x


def _enumerate(G: FloatArray, g: FloatArray, lower: FloatArray,
               upper: FloatArray) -> FloatArray:
    """Best feasible active-set solution of min x'Gx - 2 g'x for each row (3^4 sets)."""
    pats = _PATTERNS
    degenerate = lower == upper          # failed thrusters: only 'at the bound'
    pats = pats[~np.any(degenerate & (pats != 1), axis=1)]
    fixed = pats > 0                                                # (p, 4)
    value = np.where(pats == 1, lower, np.where(pats == 2, upper, 0.0))
    Gs = np.where(fixed[None, :, :, None] | fixed[None, :, None, :], 0.0, G[:, None])
    Gs = Gs + fixed[None, :, :, None] * _EYE4
    rhs = np.where(fixed[None], value[None],
                   g[:, None, :] - np.einsum('mjk,pk->mpj', G, value))
    x = np.linalg.solve(Gs, rhs[..., None])[..., 0]                 # (m, p, 4)
    slack = 1e-9 * (np.abs(upper) + 1e-300)
    feasible = np.all((x >= lower - slack) & (x <= upper + slack), axis=2)
    x = np.clip(x, lower, upper)
    cost = np.einsum('mpj,mjk,mpk->mp', x, G, x) - 2.0 * np.einsum('mpj,mj->mp', x, g)
    cost = np.where(feasible, cost, np.inf)
    best = np.argmin(cost, axis=1)
    result: FloatArray = x[np.arange(len(G)), best]
    return result


def weighted_error(problem: TiltProblem, cost: FloatArray | float) -> FloatArray:
    """||W (achieved - tau)|| in the caller's units from a scaled cost."""
    out: FloatArray = np.sqrt(np.asarray(cost, dtype=float)) * problem.scale
    return out


def unscaled(problem: TiltProblem, thrusts: FloatArray) -> FloatArray:
    """Thrusts [N] from scaled ones."""
    out: FloatArray = thrusts * problem.scale
    return out


