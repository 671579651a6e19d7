"""The simulated robot: rigid body + actuators + disturbances, stepped at a fixed rate.

Step semantics (:meth:`Plant.step`), from t_i to t_{i+1} = t_i + h:

1. The actuator state a_i at t_i (actual thrusts and tilts) gives the wrench of
   eq. (4); the external wrench is evaluated at t_i and added. The sum is held
   constant over [t_i, t_{i+1}); so is the ocean current, at its t_i value.
2. The rigid body (:mod:`tiltrov_ros.core.dynamics`, with the *true*
   parameters: r_g + com_error) is integrated over the step with classical RK4
   (or forward Euler, the benchmark baseline); the quaternion is renormalised
   after the step.
3. The actuators advance to a_{i+1} toward the commands held at that moment
   (:mod:`tiltrov_ros.core.actuators`), and the current's Gauss-Markov part
   advances to t_{i+1}.

So a command given at t_i (before ``step``) first changes the wrench over
[t_{i+1}, t_{i+2}): the actuators, not the command, drive the body. Time is
integer nanoseconds (:attr:`Plant.time_ns`); the plant step ``h`` defaults to
10 ms, the paper's sampling time. Everything is deterministic (the only
randomness is the current's seeded Generator).

The step is compiled (:mod:`tiltrov_ros.core.plant_kernels`, when
:func:`tiltrov_ros.core.jit.compiled`): the state lives in float64 arrays the
kernel updates in place, and ``step(n, log=rows)`` runs n steps in one call,
writing one sample row per step (the runner logs every step this way). The
reference is the straight-line float arithmetic of :class:`~tiltrov_ros.core.
dynamics.RigidBody` with the actuator models' own ``step`` methods (the path
with the numpy backend), itself tested against :func:`rk4_step` and
:func:`euler_step` with :func:`tiltrov_ros.core.dynamics.f`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import math
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core import jit
from tiltrov_ros.core.actuators import THRUST, TILT, ThrusterBank, TiltServos, thruster_decay
from tiltrov_ros.core.disturbances import Disturbances, ExternalWrench, OceanCurrent
from tiltrov_ros.core.dynamics import RigidBody
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.kinematics import Rquat, euler_from_quat
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.plant_kernels import (
    LOG_THRUSTS,
    LOG_TILT_VELOCITIES,
    LOG_TILTS,
    LOG_WIDTH,
    LOG_X,
    WORK_SIZE,
    plant_config,
    plant_steps,
)
from tiltrov_ros.core.thrust_map import allocation_matrix
from tiltrov_ros.core.timebase import NS_PER_S, seconds

FloatArray = NDArray[np.float64]
Integrator = Literal['rk4', 'euler']

#: The paper's simulation step (Section 4), ns.
DEFAULT_STEP_NS = 10_000_000

StateFn = Callable[[float, FloatArray], FloatArray]

#: Columns of the sample rows ``Plant.step(n, log=rows)`` writes: t [s], position (3),
#: quaternion (4), nu (6), tilts (2), tilt velocities (2), thrusts (4).
SAMPLE_WIDTH = LOG_WIDTH
#: PlantSample field -> its column(s) in a sample row (``t``: seconds, not ns).
SAMPLE_COLUMNS: dict[str, int | slice] = {
    't': 0, 'position': slice(LOG_X, LOG_X + 3), 'quaternion': slice(LOG_X + 3, LOG_X + 7),
    'nu': slice(LOG_X + 7, LOG_X + 13), 'tilts': slice(LOG_TILTS, LOG_TILTS + 2),
    'tilt_velocities': slice(LOG_TILT_VELOCITIES, LOG_TILT_VELOCITIES + 2),
    'thrusts': slice(LOG_THRUSTS, LOG_THRUSTS + 4)}


def rk4_step(fun: StateFn, t: float, x: ArrayLike, h: float) -> FloatArray:
    """One classical Runge-Kutta 4 step of x_dot = fun(t, x) (reference, numpy)."""
    xv = np.asarray(x, dtype=float)
    k1 = fun(t, xv)
    k2 = fun(t + 0.5 * h, xv + 0.5 * h * k1)
    k3 = fun(t + 0.5 * h, xv + 0.5 * h * k2)
    k4 = fun(t + h, xv + h * k3)
    return xv + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def euler_step(fun: StateFn, t: float, x: ArrayLike, h: float) -> FloatArray:
    """One forward-Euler step of x_dot = fun(t, x) (reference, numpy)."""
    xv = np.asarray(x, dtype=float)
    return xv + h * fun(t, xv)


def normalize_state_quaternion(x: ArrayLike) -> FloatArray:
    """A copy of the 13-state with its quaternion (elements 3:7) scaled to unit norm."""
    out = np.array(x, dtype=float)
    out[3:7] /= np.linalg.norm(out[3:7])
    return out


class PlantSample(NamedTuple):
    """The plant at one instant, as plain floats (one RunLog plant row)."""

    t_ns: int
    position: tuple[float, ...]         # m, NED
    quaternion: tuple[float, ...]       # (w, x, y, z)
    nu: tuple[float, ...]               # m/s, rad/s, body
    tilts: tuple[float, ...]            # rad, actual (tilt_front, tilt_rear)
    tilt_velocities: tuple[float, ...]  # rad/s
    thrusts: tuple[float, ...]          # N, actual


def _floats(value: ArrayLike, n: int, name: str) -> list[float]:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ParameterError(name, f'got {value!r}; allowed: {n} finite numbers')
    return [float(v) for v in arr]


class Plant:
    """Rigid body + actuators + disturbances (see the module docstring for one step).

    Parameters
    ----------
    params : RobotParams
        The *nominal* robot (what the controller knows).
    disturbances : Disturbances, optional
        Center-of-mass error, current, external wrench (default: none).
    step_ns : int
        Plant step h, ns (default 10 ms).
    integrator : {'rk4', 'euler'}
        RK4 (default) or forward Euler (benchmark baseline only).
    position, quaternion, nu, tilts, thrusts : array_like
        Initial state: NED position (m), attitude (w, x, y, z; normalised here),
        body velocity (m/s, rad/s), actual tilts (rad; within the limits) and
        thrusts (N; within the limit). The held commands start equal to them.
    """

    def __init__(self, params: RobotParams, disturbances: Disturbances | None = None, *,
                 step_ns: int = DEFAULT_STEP_NS, integrator: Integrator = 'rk4',
                 position: ArrayLike = (0.0, 0.0, 0.0),
                 quaternion: ArrayLike = (1.0, 0.0, 0.0, 0.0),
                 nu: ArrayLike = (0.0,) * 6,
                 tilts: ArrayLike = (0.0, 0.0),
                 thrusts: ArrayLike = (0.0,) * 4) -> None:
        if isinstance(step_ns, bool) or not isinstance(step_ns, int) or step_ns <= 0:
            raise ParameterError('step_ns', f'got {step_ns!r}; allowed: an integer > 0 (ns)')
        if integrator not in ('rk4', 'euler'):
            raise ParameterError('integrator', f"got {integrator!r}; allowed: 'rk4', 'euler'")
        self.nominal_params = params
        self.disturbances = disturbances if disturbances is not None else Disturbances()
        #: The plant's true robot: nominal with r_g + com_error.
        self.params = self.disturbances.true_params(params)
        self.step_ns = step_ns
        self.integrator: Integrator = integrator
        self._h = step_ns / NS_PER_S
        self._t_ns = 0

        q = _floats(quaternion, 4, 'initial quaternion')
        qn = math.sqrt(sum(v * v for v in q))
        if qn == 0.0:
            raise ParameterError('initial quaternion', 'got a zero quaternion')
        #: x = [position (3), quaternion (4), nu (6)], updated in place.
        self._x = np.array(_floats(position, 3, 'initial position') + [v / qn for v in q]
                           + _floats(nu, 6, 'initial nu'))

        self.thrusters = ThrusterBank.from_params(self.params, thrusts)
        self.servos = TiltServos.from_params(self.params, tilts)
        self.current = OceanCurrent.from_disturbances(self.disturbances)
        self.external_wrench = ExternalWrench(self.disturbances.external_wrench)
        self.body = RigidBody(self.params)

        # Eq. (5), tau = A q, with A from thrust_map (the one source of the geometry).
        self._A_rows = tuple(tuple(float(a) for a in row)
                             for row in allocation_matrix(self.params.length, self.params.width))

        #: True: ``step`` runs the compiled kernel; False: the float reference (the
        #: numpy backend; tests set it to compare the two).
        self.compiled = jit.compiled()
        self._cfg = plant_config(self.params, self._h,
                                 thruster_decay(self.thrusters.time_constant, self._h),
                                 integrator == 'rk4', self.current.random,
                                 *self.current.coefficients(self._h), self.current.mean)
        self._work = np.zeros(WORK_SIZE)
        self._ext_rows = (np.array([self.external_wrench(0.0)])
                          if self.external_wrench.is_constant else np.zeros((1, 6)))
        self._noise = np.zeros((1, 3))
        self._no_log = np.zeros((0, LOG_WIDTH))
        if self.compiled:
            jit.warmup(('plant',))      # compiled (or loaded) now, never during a step

    # -- time -----------------------------------------------------------------

    @property
    def time_ns(self) -> int:
        """Simulated time t_i, integer ns."""
        return self._t_ns

    @property
    def time(self) -> float:
        """Simulated time, s (``seconds(time_ns)``)."""
        return seconds(self._t_ns)

    @property
    def step_size(self) -> float:
        """Plant step h, s."""
        return self._h

    # -- state (copies: mutating them does not touch the plant) ------------------

    @property
    def state(self) -> FloatArray:
        """x = [position NED (3), quaternion (w, x, y, z) (4), nu (6)]."""
        return self._x.copy()

    @property
    def position(self) -> FloatArray:
        """Body origin in NED, m."""
        return self._x[0:3].copy()

    @property
    def quaternion(self) -> FloatArray:
        """Body FRD orientation in NED, (w, x, y, z), unit norm."""
        return self._x[3:7].copy()

    @property
    def nu(self) -> FloatArray:
        """Body velocity (u v w p q r), m/s and rad/s."""
        return self._x[7:13].copy()

    @property
    def rotation(self) -> FloatArray:
        """Rotation matrix body -> NED."""
        return Rquat(self._x[3:7])

    @property
    def euler(self) -> FloatArray:
        """ZYX Euler angles (phi, theta, psi), rad, derived from the quaternion."""
        return euler_from_quat(self._x[3:7])

    @property
    def eta(self) -> FloatArray:
        """eta = (x, y, z, phi, theta, psi), m and rad."""
        return np.concatenate([self.position, self.euler])

    @property
    def thrusts(self) -> FloatArray:
        """Actual thrusts of thruster_1..4, N."""
        return np.array(self.thrusters.thrusts)

    @property
    def tilts(self) -> FloatArray:
        """Actual (tilt_front, tilt_rear), rad."""
        return np.array(self.servos.angles)

    @property
    def tilt_velocities(self) -> FloatArray:
        """Servo velocities, rad/s (backward difference over the last step)."""
        return np.array(self.servos.velocities)

    @property
    def current_velocity(self) -> FloatArray:
        """Ocean current in NED now, m/s."""
        return np.array(self.current.velocity)

    def sample(self) -> PlantSample:
        """The present state as plain floats (cheap; used for logging every step)."""
        x = self._x.tolist()
        return PlantSample(self._t_ns, tuple(x[0:3]), tuple(x[3:7]), tuple(x[7:13]),
                           self.servos.angles, self.servos.velocities, self.thrusters.thrusts)

    def write_sample(self, row: FloatArray) -> None:
        """The present state into a sample row (``SAMPLE_WIDTH`` columns, as ``step`` logs)."""
        s = self.sample()
        row[:] = [seconds(s.t_ns), *s.position, *s.quaternion, *s.nu, *s.tilts,
                  *s.tilt_velocities, *s.thrusts]

    def thrust_wrench(self) -> FloatArray:
        """Eq. (4) of the actual thrusts and tilts, body frame, N and N m."""
        return np.array(self._thrust_wrench())

    def applied_wrench(self) -> FloatArray:
        """The wrench applied over the next step: eq. (4) plus the external wrench at t_i."""
        ext = self.external_wrench(seconds(self._t_ns))
        return np.array([a + b for a, b in zip(self._thrust_wrench(), ext)])

    # -- commands and stepping ---------------------------------------------------

    def command(self, thrusts: ArrayLike | None = None,
                tilts: ArrayLike | None = None) -> bool:
        """Hold new thruster (4, N) and/or tilt (tilt_front, tilt_rear; rad) commands.

        Saturated and clipped by the actuator models; a command with a
        non-finite value is rejected and the previous one stays in force
        (see :mod:`tiltrov_ros.core.actuators`). Returns True if everything given
        was accepted.
        """
        ok = True
        if thrusts is not None:
            ok = self.thrusters.command(thrusts) and ok
        if tilts is not None:
            ok = self.servos.command(tilts) and ok
        return ok

    def set_failed_thrusters(self, indices: Sequence[int]) -> None:
        """Fail thrusters (indices 0..3; the others work): from now on they give no
        thrust whatever their command (spinning down with the thruster time constant)."""
        self.thrusters.set_failed(indices)

    @property
    def failed_thrusters(self) -> tuple[int, ...]:
        """Indices 0..3 of the failed thrusters."""
        return self.thrusters.failed

    def step(self, n: int = 1, log: FloatArray | None = None) -> None:
        """Advance n plant steps (see the module docstring).

        ``log``: a C-contiguous float64 array of at least n rows of
        ``SAMPLE_WIDTH`` columns; row k receives the sample after step k (what
        :meth:`sample` would give then, time in s).
        """
        if log is not None:
            _check_log(log, n)
        if n <= 0:
            return
        if not self.compiled:
            self._step_reference(n, log)
            return
        if self.external_wrench.is_constant:
            self._run_kernel(n, self._ext_rows, 0, log)
            return
        rows = self._ext_rows if len(self._ext_rows) >= n else np.zeros((n, 6))
        self._ext_rows = rows
        for k in range(n):
            try:
                rows[k] = self.external_wrench(seconds(self._t_ns + k * self.step_ns))
            except ValueError:
                self._run_kernel(k, rows, 1, log)       # the steps before it happen
                raise
        self._run_kernel(n, rows, 1, log)

    def _run_kernel(self, n: int, ext: FloatArray, stride: int,
                    log: FloatArray | None) -> None:
        noise = self._noise
        if self.current.random and n:
            if len(noise) < n:
                self._noise = noise = np.zeros((n, 3))
            self.current.draw(noise if len(noise) == n else noise[:n])
        plant_steps(n, self._t_ns, self.step_ns, self._x, self.thrusters.state,
                    self.servos.state, self.current.state, self._cfg, ext, stride, noise,
                    self._no_log if log is None else log, self._work)
        self._t_ns += n * self.step_ns

    def _step_reference(self, n: int, log: FloatArray | None) -> None:
        """The float path (numpy backend): RigidBody's derivative and the actuator models."""
        h = self._h
        deriv = self.body.derivative
        rk4 = self.integrator == 'rk4'
        x = self._x.tolist()
        try:
            for k in range(n):
                thr = self._thrust_wrench()
                ext = self.external_wrench(seconds(self._t_ns))
                tau = [a + b for a, b in zip(thr, ext)]
                vc = self.current.velocity
                if rk4:
                    x = _rk4(deriv, x, tau, vc, h)
                else:
                    k1 = deriv(x, tau, vc)
                    x = [a + h * b for a, b in zip(x, k1)]
                qw, qx, qy, qz = x[3:7]
                inv = 1.0 / math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
                x[3:7] = [qw * inv, qx * inv, qy * inv, qz * inv]
                self.thrusters.step(h)
                self.servos.step(h)
                self.current.advance(h)
                self._t_ns += self.step_ns
                if log is not None:
                    self._x[:] = x
                    self.write_sample(log[k])
        finally:
            self._x[:] = x

    def _thrust_wrench(self) -> list[float]:
        """Eq. (4) as A q of eq. (5), in floats."""
        f1, f2, f3, f4 = self.thrusters.state[THRUST:THRUST + 4].tolist()
        alpha, beta = self.servos.state[TILT:TILT + 2].tolist()
        sa, ca, sb, cb = math.sin(alpha), math.cos(alpha), math.sin(beta), math.cos(beta)
        q0, q1, q2, q3 = f1 * sa, f2 * sa, f3 * sb, f4 * sb
        q4, q5, q6, q7 = f1 * ca, f2 * ca, f3 * cb, f4 * cb
        return [a0 * q0 + a1 * q1 + a2 * q2 + a3 * q3 + a4 * q4 + a5 * q5 + a6 * q6 + a7 * q7
                for a0, a1, a2, a3, a4, a5, a6, a7 in self._A_rows]

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable description for a RunLog's meta."""
        p = self.nominal_params
        return {
            'robot': p.as_dict(),
            'true_center_of_gravity': list(self.params.center_of_gravity),
            'disturbances': self.disturbances.describe(),
            'step_size': self._h,
            'integrator': self.integrator,
            'max_thrust': p.max_thrust, 'tilt_min': p.tilt_min, 'tilt_max': p.tilt_max,
            'tilt_rate_limit': p.tilt_rate_limit,
        }


def _check_log(log: FloatArray, n: int) -> None:
    if not (isinstance(log, np.ndarray) and log.dtype == np.float64 and log.ndim == 2
            and log.shape[0] >= n and log.shape[1] == LOG_WIDTH
            and log.flags.c_contiguous and log.flags.writeable):
        raise ValueError(f'log: expected a writable C-contiguous float64 array of at least '
                         f'{n} rows of {LOG_WIDTH}, got {getattr(log, "shape", log)!r}')


def _rk4(deriv: Callable[[Sequence[float], Sequence[float], Sequence[float]], list[float]],
         x: list[float], tau: Sequence[float], vc: Sequence[float], h: float) -> list[float]:
    """Classical RK4 with (tau, vc) held over the step, in floats (same as :func:`rk4_step`)."""
    hh = 0.5 * h
    k1 = deriv(x, tau, vc)
    k2 = deriv([a + hh * b for a, b in zip(x, k1)], tau, vc)
    k3 = deriv([a + hh * b for a, b in zip(x, k2)], tau, vc)
    k4 = deriv([a + h * b for a, b in zip(x, k3)], tau, vc)
    h6 = h / 6.0
    return [a + h6 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
            for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
