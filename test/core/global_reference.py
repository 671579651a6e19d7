"""An independent, certified global optimum of the allocation error, for the tests.

The least weighted wrench error over the tilts in a box and the thrusts within
the limit, computed without any of the allocator's own machinery:

* the thrusts at given tilts: eq. (5) (``thrust_map.allocation_matrix``)
  column by column, and the exact box-constrained least squares by trying
  every active set (each thruster free, at -f_max or at +f_max; 3^4 sets);
* the tilts: a grid over the box, the best cells polished by Nelder-Mead
  (scipy), then branch and bound.

Certificate. For fixed thrusts f, ||W (B(theta) f - tau)|| is Lipschitz in
each tilt with constant ||W dB/dtheta f|| <= L_front (or L_rear), computed
from the columns of W A and |f_i| <= f_max; the minimum over f of such
functions has the same constants. So over a cell of half-widths (h_a, h_b)
around theta_c, the error is at least e(theta_c) - L_front h_a - L_rear h_b.
Cells are split until each one's bound is at least ``best / (1 + rtol)`` or
the cell lies within ``radius`` of a polished local minimum (where the
Lipschitz bound is too weak to be of use and the polish decides). The result
says whether that was achieved within the evaluation budget.
"""

from __future__ import annotations

from dataclasses import dataclass
import itertools
import math

import numpy as np
from scipy.optimize import minimize

from tiltrov_ros.core.thrust_map import allocation_matrix

_PATTERNS = np.array(list(itertools.product((0, 1, 2), repeat=4)))


@dataclass(frozen=True)
class Reference:
    error: float              # best weighted error found
    tilts: np.ndarray         # (2,) where
    certified: bool           # no configuration beats error / (1 + rtol) outside the balls
    evaluations: int


class GlobalReference:
    """The global optimum of one allocation problem (see the module docstring)."""

    def __init__(self, length: float, width: float, max_thrust: float,
                 weights: np.ndarray, available: np.ndarray | None = None) -> None:
        self.A = allocation_matrix(length, width)
        self.w = np.asarray(weights, dtype=float)
        self.fmax = float(max_thrust)
        avail = np.ones(4, bool) if available is None else np.asarray(available, bool)
        self.upper = np.where(avail, self.fmax, 0.0)
        WA = self.A * self.w[:, None]
        front = WA[:, [0, 1, 4, 5]]
        rear = WA[:, [2, 3, 6, 7]]
        # |d/da ||W (B f - tau)||| <= ||W (A_z cos a - A_h sin a) f_front||
        #                          <= sigma_max([W A_z, W A_h] front) |f_front|.
        self.lipschitz = (np.linalg.norm(front, 2) * math.sqrt(2.0) * self.fmax,
                          np.linalg.norm(rear, 2) * math.sqrt(2.0) * self.fmax)

    def errors(self, tau: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Exact least weighted error at each pair of tilts (vectorised)."""
        a = np.atleast_1d(np.asarray(a, dtype=float))
        b = np.atleast_1d(np.asarray(b, dtype=float))
        out = np.empty(len(a))
        t = np.asarray(tau, dtype=float) * self.w
        for s in range(0, len(a), 256):
            sl = slice(s, s + 256)
            gam = np.stack([a[sl], a[sl], b[sl], b[sl]], axis=-1)
            B = (self.A[None, :, :4] * np.sin(gam)[:, None, :]
                 + self.A[None, :, 4:] * np.cos(gam)[:, None, :]) * self.w[None, :, None]
            out[sl] = self._box(B, t)
        return out

    def _box(self, B: np.ndarray, t: np.ndarray) -> np.ndarray:
        up = self.upper
        G = np.einsum('mij,mik->mjk', B, B)
        g = np.einsum('mij,i->mj', B, t)
        fixed = _PATTERNS > 0
        value = np.where(_PATTERNS == 1, -up, np.where(_PATTERNS == 2, up, 0.0))
        allowed = ~np.any((up == 0.0) & (_PATTERNS == 0), axis=1)     # failed: held at 0
        fixed, value = fixed[allowed], value[allowed]
        eye = np.eye(4)
        scale = np.trace(G, axis1=1, axis2=2)[:, None, None, None] + 1e-300
        M = np.where(fixed[None, :, :, None] | fixed[None, :, None, :], 0.0, G[:, None])
        M = M + fixed[None, :, :, None] * eye + 1e-13 * scale * eye
        rhs = np.where(fixed[None], value[None],
                       g[:, None, :] - np.einsum('mjk,pk->mpj', G, value))
        x = np.linalg.solve(M, rhs[..., None])[..., 0]
        ok = np.all(np.abs(x) <= up * (1 + 1e-9) + 1e-300, axis=2)
        x = np.clip(x, -up, up)
        r = np.einsum('mij,mpj->mpi', B, x) - t
        cost = np.where(ok, np.einsum('mpi,mpi->mp', r, r), np.inf)
        return np.sqrt(np.min(cost, axis=1))

    def optimum(self, tau: np.ndarray, box: np.ndarray, *, rtol: float = 5e-3,
                radius: float = math.radians(0.5), cells: int = 24, polish: int = 6,
                budget: int = 400_000) -> Reference:
        """The least error over tilts in ``box`` ([[a_lo, a_hi], [b_lo, b_hi]])."""
        tau = np.asarray(tau, dtype=float)
        (alo, ahi), (blo, bhi) = np.asarray(box, dtype=float)
        La, Lb = self.lipschitz

        def error_at(p: np.ndarray) -> float:
            q = np.clip(p, [alo, blo], [ahi, bhi])
            return float(self.errors(tau, q[:1], q[1:])[0])

        na = max(1, math.ceil(cells * (ahi - alo) / math.pi))
        nb = max(1, math.ceil(cells * (bhi - blo) / math.pi))
        ha, hb = (ahi - alo) / na, (bhi - blo) / nb
        A, B = np.meshgrid(alo + ha * (np.arange(na) + 0.5), blo + hb * (np.arange(nb) + 0.5),
                           indexing='ij')
        todo = np.column_stack([A.ravel(), B.ravel(), np.full(A.size, ha / 2),
                                np.full(A.size, hb / 2)])
        values = self.errors(tau, todo[:, 0], todo[:, 1])
        evaluations = len(todo)
        # Polish the best cells (and the box corners, which cell centres miss).
        corners = np.array([[alo, blo], [alo, bhi], [ahi, blo], [ahi, bhi]])
        starts = np.vstack([todo[np.argsort(values)[:polish], :2], corners])
        minima = []
        for p in starts:
            res = minimize(error_at, p, method='Nelder-Mead',
                           options={'xatol': 1e-10, 'fatol': 1e-14, 'maxiter': 2000})
            q = np.clip(res.x, [alo, blo], [ahi, bhi])
            minima.append((float(error_at(q)), q))
            evaluations += res.nfev
        best, best_t = min(minima, key=lambda m: m[0])
        if values.min() < best:
            k = int(np.argmin(values))
            best, best_t = float(values[k]), todo[k, :2]
        centres = np.array([m[1] for m in minima])
        certified = True
        while len(todo):
            lower = values - La * todo[:, 2] - Lb * todo[:, 3]
            reach = np.hypot(todo[:, 2], todo[:, 3])
            near = (np.min(np.hypot(todo[:, None, 0] - centres[None, :, 0],
                                    todo[:, None, 1] - centres[None, :, 1]), axis=1)
                    + reach) <= radius
            keep = (lower < best / (1 + rtol)) & ~near
            todo = todo[keep]
            if not len(todo):
                break
            if evaluations > budget:
                certified = False
                break
            # Split every open cell into four and evaluate the children.
            children = []
            for da, db in ((-0.5, -0.5), (-0.5, 0.5), (0.5, -0.5), (0.5, 0.5)):
                children.append(np.column_stack([todo[:, 0] + da * todo[:, 2],
                                                 todo[:, 1] + db * todo[:, 3],
                                                 todo[:, 2] / 2, todo[:, 3] / 2]))
            todo = np.vstack(children)
            values = self.errors(tau, todo[:, 0], todo[:, 1])
            evaluations += len(todo)
            k = int(np.argmin(values))
            if values[k] < best:
                res = minimize(error_at, todo[k, :2], method='Nelder-Mead',
                               options={'xatol': 1e-10, 'fatol': 1e-14, 'maxiter': 2000})
                q = np.clip(res.x, [alo, blo], [ahi, bhi])
                evaluations += res.nfev
                e = error_at(q)
                best, best_t = (e, q) if e < values[k] else (float(values[k]), todo[k, :2])
                centres = np.vstack([centres, best_t])
        return Reference(best, np.asarray(best_t, dtype=float), certified, evaluations)
