"""What every part of the allocator shares: the robot's limits and how a result is made."""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from tiltrov_ros.core.allocation.decomposition import FloatArray, Geometry
from tiltrov_ros.core.allocation.results import FEASIBILITY_RTOL, AllocationResult, norm
from tiltrov_ros.core.thrust_map import allocation_matrix

# Slack on the limits when checking a candidate.
LIMIT_SLACK = 1e-12


@dataclass(frozen=True, eq=False)
class Limits:
    """Geometry, limits and weights of one allocator (validated by ``ThrustAllocator``).

    tilt_min, tilt_max : servo range [rad]; max_tilt_step : reach per call [rad]
    (inf: none); weights : (6,) per-DOF weights W; available : (4,) False for a
    failed thruster; mode : ``'paper'`` or ``'robust'``.
    """

    geometry: Geometry
    max_thrust: float
    tilt_min: float
    tilt_max: float
    max_tilt_step: float
    weights: FloatArray
    available: FloatArray
    mode: str

    def __post_init__(self) -> None:
        object.__setattr__(self, '_A', allocation_matrix(self.geometry.length,
                                                         self.geometry.width))

    @property
    def A(self) -> FloatArray:
        """The matrix A of eq. (5)."""
        out: FloatArray = self._A              # type: ignore[attr-defined]
        return out

    @property
    def failed(self) -> bool:
        return not bool(np.all(self.available))

    def box(self, prev: FloatArray | None) -> FloatArray:
        """[[lo, hi] front, [lo, hi] rear] reachable in this call."""
        lo, hi = self.tilt_min, self.tilt_max
        if prev is None or not math.isfinite(self.max_tilt_step):
            return np.array([[lo, hi], [lo, hi]])
        return np.column_stack([np.maximum(lo, prev - self.max_tilt_step),
                                np.minimum(hi, prev + self.max_tilt_step)])

    def make(self, tau: FloatArray, thrusts: FloatArray, tilts: FloatArray, method: str,
             discriminant: float = math.nan) -> AllocationResult:
        """The result for these thrusts and tilts: achieved wrench by eq. (5), error."""
        f = np.array(thrusts, dtype=float)
        f[~np.asarray(self.available, dtype=bool)] = 0.0
        a, b = float(tilts[0]), float(tilts[1])
        sa, ca, sb, cb = math.sin(a), math.cos(a), math.sin(b), math.cos(b)
        f1, f2, f3, f4 = f.tolist()
        # Eq. (5): tau = A q, the same map as eq. (4).
        q = np.array([f1 * sa, f2 * sa, f3 * sb, f4 * sb, f1 * ca, f2 * ca, f3 * cb, f4 * cb])
        achieved = self.A @ q
        diff = achieved - tau
        wmax = float(self.weights.max())
        error = norm(diff * (self.weights / wmax)) * wmax
        feasible = norm(diff) <= FEASIBILITY_RTOL * max(norm(tau), self.max_thrust)
        return AllocationResult(f, a, b, achieved, feasible, tau.copy(), method,
                                float(discriminant), error)

    def twins(self, angle: float) -> list[tuple[float, float]]:
        """(servo angle, thrust sign) of every tilt in range with the thrust line of
        ``angle``: angle + k pi, the thrust negated for odd k."""
        lo, hi = self.tilt_min, self.tilt_max
        k = math.ceil((lo - LIMIT_SLACK - angle) / math.pi)
        out = []
        while angle + k * math.pi <= hi + LIMIT_SLACK:
            out.append((min(max(angle + k * math.pi, lo), hi), -1.0 if k % 2 else 1.0))
            k += 1
        return out
