"""Thrusts at given tilts: weighted least squares within the thrust limit."""

from __future__ import annotations

import itertools

import numpy as np

from tiltrov_ros.core.allocation.decomposition import FloatArray

# Regularisation of the thrust least squares (relative to the Gram matrix).
_RIDGE = 1e-12


_PATTERNS = np.array(list(itertools.product((0, 1, 2), repeat=4)))


def bounded_lstsq(B: FloatArray, target: FloatArray, lower: FloatArray,
                   upper: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """min ||B x - target||^2 with lower <= x <= upper, exactly, for a stack B (m, 6, 4).

    The unconstrained solution is tried first; rows where it leaves the box
    try every active set (each variable free, at its lower or at its upper
    bound: 3^4 patterns) at once and keep the best one whose free variables
    stay within their bounds: for a convex quadratic that is the global
    minimum. A tiny ridge makes singular configurations (both tilts at 90 deg,
    say) pick the least-thrust solution.
    """
    G = np.einsum('mij,mik->mjk', B, B)
    G = G + _RIDGE * (np.trace(G, axis1=1, axis2=2)[:, None, None] + 1e-300) * np.eye(4)
    g = np.einsum('mij,i->mj', B, target)
    x = np.linalg.solve(G, g[..., None])[..., 0]
    slack = 1e-9 * (np.abs(upper) + 1.0)
    inside = np.all((x >= lower - slack) & (x <= upper + slack), axis=1) & (lower < upper).all()
    out = np.flatnonzero(~inside)
    if len(out):
        x[out] = _enumerate_active_sets(G[out], g[out], lower, upper)
    x = np.clip(x, lower, upper)
    resid = np.einsum('mij,mj->mi', B, x) - target
    return x, resid, np.sum(resid ** 2, axis=1)


def _enumerate_active_sets(G: FloatArray, g: FloatArray, lower: FloatArray,
                           upper: FloatArray) -> FloatArray:
    """Best feasible active-set solution of min x'Gx/2 - g'x for each row."""
    pats = _PATTERNS
    degenerate = lower == upper          # failed thrusters: only 'at the bound'
    allowed = ~np.any(degenerate & (pats != 1), axis=1)
    pats = pats[allowed]
    fixed = pats > 0                                                # (p, 4)
    value = np.where(pats == 1, lower, np.where(pats == 2, upper, 0.0))
    eye = np.eye(4)
    # Free rows: G_FF x_F = g_F - G_F,fix x_fix; fixed rows: x_i = bound.
    Gs = np.where(fixed[None, :, :, None], eye[None, None],
                  np.where(fixed[None, :, None, :], 0.0, G[:, None]))
    rhs = np.where(fixed[None], value[None],
                   g[:, None, :] - np.einsum('mjk,pk->mpj', G, value))
    x = np.linalg.solve(Gs, rhs[..., None])[..., 0]                 # (m, p, 4)
    slack = 1e-9 * (np.abs(upper) + 1.0)
    feasible = np.all((x >= lower - slack) & (x <= upper + slack), axis=2)
    x = np.clip(x, lower, upper)
    cost = 0.5 * np.einsum('mpj,mjk,mpk->mp', x, G, x) - np.einsum('mpj,mj->mp', x, g)
    cost = np.where(feasible, cost, np.inf)
    best = np.argmin(cost, axis=1)
    result: FloatArray = x[np.arange(len(G)), best]
    return result
