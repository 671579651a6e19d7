"""Where Python ends and the compiled allocation begins.

:class:`Compiled` holds what the kernels of :mod:`.kernels.allocate` need of one
:class:`~.allocator.ThrustAllocator` (its configuration as a flat array, built
once, and preallocated scratch buffers) and does one kernel call per
``allocate``, ``allocate_fixed``, ``thrusts_at`` or ``allocate_batch``: pack the
checked arguments into the arrays of :mod:`.kernels.layout`, call, unpack one
:class:`.AllocationResult`. The arguments are checked by the allocator, as
for the numpy reference; the answers are the reference's (tests pin them to
1e-9 relative).
"""

from __future__ import annotations

import math
import threading

import numpy as np

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.kernels import allocate as k
from tiltrov_ros.core.allocation.kernels import layout as lay
from tiltrov_ros.core.allocation.limits import Limits
from tiltrov_ros.core.allocation.results import AllocationResult, BatchResult

_METHODS = lay.METHODS


def pack_config(limits: Limits, penalty: float, planning: bool, horizon: int) -> FloatArray:
    """The allocator's configuration as the kernels read it (layout ``CFG_*``)."""
    cfg = np.zeros(lay.CFG_FULL_SIZE)
    cfg[lay.CFG_L] = limits.geometry.length
    cfg[lay.CFG_W] = limits.geometry.width
    cfg[lay.CFG_K] = limits.geometry.k
    cfg[lay.CFG_FMAX] = limits.max_thrust
    cfg[lay.CFG_TILT_MIN] = limits.tilt_min
    cfg[lay.CFG_TILT_MAX] = limits.tilt_max
    cfg[lay.CFG_STEP] = limits.max_tilt_step
    cfg[lay.CFG_WEIGHTS:lay.CFG_WEIGHTS + 6] = limits.weights
    cfg[lay.CFG_AVAILABLE:lay.CFG_AVAILABLE + 4] = np.asarray(limits.available, dtype=float)
    cfg[lay.CFG_MODE] = lay.MODE_ROBUST if limits.mode == 'robust' else lay.MODE_PAPER
    cfg[lay.CFG_PENALTY] = penalty
    cfg[lay.CFG_PLANNING] = 1.0 if planning else 0.0
    cfg[lay.CFG_HORIZON] = float(horizon)
    cfg[lay.CFG_PINV:lay.CFG_PINV + 48] = np.linalg.pinv(limits.A).ravel()
    return cfg


class Compiled:
    """The compiled allocation of one allocator (see the module docstring).

    Calls are serialised by a lock: the scratch buffers are shared, and the
    kernels release the GIL.
    """

    def __init__(self, limits: Limits, penalty: float, planning: bool, horizon: int) -> None:
        jit.warmup(['allocation'])         # compile or load now, never during a call
        self._cfg = pack_config(limits, penalty, planning, horizon)
        self._buf = np.zeros(lay.BUF_SIZE)
        self._ibuf = np.zeros(lay.IBUF_SIZE, dtype=np.int64)
        self._prev = np.zeros(lay.PREV_SIZE)
        self._no_prev = np.zeros((0, 2))
        self._lock = threading.Lock()

    def _pack(self, previous: AllocationResult | None) -> FloatArray:
        prev = self._prev
        if previous is None:
            prev[lay.PREV_EXISTS] = 0.0
            return prev
        prev[lay.PREV_EXISTS] = 1.0
        prev[lay.PREV_TILTS] = previous.tilt_front
        prev[lay.PREV_TILTS + 1] = previous.tilt_rear
        prev[lay.PREV_TRANSIT] = 1.0 if previous.method == 'transit' else 0.0
        target = previous.target
        if target is None:
            prev[lay.PREV_TARGET] = prev[lay.PREV_TARGET + 1] = math.nan
        else:
            prev[lay.PREV_TARGET], prev[lay.PREV_TARGET + 1] = target
        prev[lay.PREV_STUCK] = previous.stuck
        return prev

    @staticmethod
    def _result(out: FloatArray, tau: FloatArray) -> AllocationResult:
        v = out.tolist()
        target = v[lay.OUT_TARGET]
        return AllocationResult(out[lay.OUT_THRUSTS:lay.OUT_THRUSTS + 4],
                                v[lay.OUT_TILTS], v[lay.OUT_TILTS + 1],
                                out[lay.OUT_ACHIEVED:lay.OUT_ACHIEVED + 6],
                                v[lay.OUT_FEASIBLE] != 0.0, tau, _METHODS[int(v[lay.OUT_METHOD])],
                                v[lay.OUT_DISC], v[lay.OUT_ERROR],
                                None if target != target else (target, v[lay.OUT_TARGET + 1]),
                                int(v[lay.OUT_STUCK]))

    def allocate(self, tau: FloatArray, previous: AllocationResult | None) -> AllocationResult:
        """``tau``: a fresh (6,) float array (cleaned in place: the result's ``requested``)."""
        out = np.empty(lay.OUT_SIZE)
        with self._lock:
            k.allocate(self._cfg, tau, self._pack(previous), out, self._buf, self._ibuf)
        return self._result(out, tau)

    def allocate_fixed(self, tau: FloatArray, tilt_front: float, tilt_rear: float,
                       previous: AllocationResult | None) -> AllocationResult:
        """As :meth:`allocate`, the tilts held at the requested ones."""
        out = np.empty(lay.OUT_SIZE)
        with self._lock:
            k.allocate_fixed(self._cfg, tau, self._pack(previous), tilt_front, tilt_rear, out,
                             self._buf, self._ibuf)
        return self._result(out, tau)

    def thrusts_at(self, tau: FloatArray, tilt_front: float, tilt_rear: float) -> FloatArray:
        """(4,) thrusts [N] at the tilts; ``tau`` finite (6,)."""
        out = np.empty(4)
        with self._lock:
            k.thrusts_at(self._cfg, tau, tilt_front, tilt_rear, out, self._buf, self._ibuf)
        return out

    def allocate_batch(self, taus: FloatArray, prev: FloatArray | None) -> BatchResult:
        """``taus``: a fresh C-ordered (n, 6) array (cleaned in place); ``prev`` (n, 2)."""
        n = len(taus)
        thrusts, achieved = np.empty((n, 4)), np.empty((n, 6))
        tilt_front, tilt_rear, error = np.empty(n), np.empty(n), np.empty(n)
        feasible = np.empty(n, dtype=bool)
        given = prev is not None
        prevs = np.ascontiguousarray(prev, dtype=float) if prev is not None else self._no_prev
        with self._lock:
            k.allocate_batch(self._cfg, taus, prevs, given, thrusts, tilt_front, tilt_rear,
                             achieved, feasible, error, self._buf, self._ibuf)
        return BatchResult(thrusts, tilt_front, tilt_rear, achieved, feasible, error)
