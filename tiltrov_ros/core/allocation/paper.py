"""The paper mode's answer when no exact solution qualifies (Section 3.2, case 3)."""

from __future__ import annotations

import numpy as np

from tiltrov_ros.core.allocation.decomposition import ExactConfig, FloatArray, fold_tilt
from tiltrov_ros.core.allocation.limits import Limits
from tiltrov_ros.core.allocation.results import AllocationResult
from tiltrov_ros.core.allocation.selection import variants


def paper_fallback(limits: Limits, tau: FloatArray, configs: list[ExactConfig], disc: float,
                    prev: FloatArray | None, box: FloatArray) -> AllocationResult:
    """Section 3.2 case 3, and saturation: a pseudo solution within the limits.

    With real roots that all violate the limits, the root the paper's rule
    picks (least tilt motion) is clipped to them. With no real root
    (Delta < 0), xi = 0: q = c, each thruster's own angle from (8), per pair
    the one of left/right closer to ``previous``, each thrust the signed
    projection of its (horizontal, vertical) component on that line, then
    clipped to the limits.
    """
    ref = prev if prev is not None else np.zeros(2)
    options = [v for cfg in configs for v in variants(limits, cfg, prev, box)]
    if options:
        f_best, t_best = min(options, key=lambda v: (
            (v[1][0] - ref[0]) ** 2 + (v[1][1] - ref[1]) ** 2, sum(x * x for x in v[0])))
        thrusts, tilts = np.array(f_best), np.array(t_best)
        method = 'saturated'
    else:
        c = np.linalg.pinv(limits.A) @ tau
        z, h = c[:4], c[4:]
        angles = fold_tilt(np.arctan2(z, h))
        strength = np.hypot(z, h)
        tilts = np.zeros(2)
        for p, (i, j) in enumerate(((0, 1), (2, 3))):
            left = angles[i] if strength[i] > 0 else ref[p]
            right = angles[j] if strength[j] > 0 else ref[p]
            tilts[p] = left if abs(left - ref[p]) <= abs(right - ref[p]) else right
        pair = np.array([0, 0, 1, 1])
        thrusts = h * np.cos(tilts[pair]) + z * np.sin(tilts[pair])
        method = 'pseudo'
    tilts = np.clip(np.clip(tilts, *(limits.tilt_min, limits.tilt_max)), box[:, 0], box[:, 1])
    thrusts = np.clip(thrusts, -limits.max_thrust, limits.max_thrust)
    return limits.make(tau, thrusts, tilts, method, disc)
