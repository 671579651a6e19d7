"""Disturbances acting on the plant (the controller knows none of them).

* Center-of-mass modeling error, the paper's disturbance (Section 4.1): the
  plant's true r_g is the nominal r_g plus ``com_error``; the controller only
  knows the nominal robot. The resulting restoring moment is a constant-ish
  moment the controller must resist.
* Ocean current in NED: a constant plus, optionally, a first-order Gauss-Markov
  process per axis, b_dot = -b / T_c + w, discretised exactly for the plant
  step h: b_{k+1} = phi b_k + sigma sqrt(1 - phi^2) n_k, phi = exp(-h / T_c),
  n_k ~ N(0, 1) from a numpy Generator seeded with ``seed`` (same seed, same
  run). sigma is the stationary standard deviation; b starts at 0. The current
  enters the dynamics only through the relative velocity in the damping
  (see :mod:`tiltrov_ros.core.dynamics`).
* An external body wrench (X Y Z K M N), constant or a callable of time (s),
  added to the thrusters' wrench.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
import math
from numbers import Integral
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.params import RobotParams

FloatArray = NDArray[np.float64]

#: [estimate] The center-of-mass error of the scenarios (true r_g minus nominal
#: r_g, m): the paper applies such an error but gives no value.
PAPER_COM_ERROR = (0.01, 0.0, 0.005)

WrenchFn = Callable[[float], ArrayLike]

# OceanCurrent.state: float64[CURRENT_STATE] (updated in place by the plant's kernel)
CURRENT_B = 0            # 3 entries: the Gauss-Markov part b [m/s]
CURRENT_VELOCITY = 3     # 3 entries: mean + b, the current now [m/s]
CURRENT_STATE = 6


def _vector(name: str, value: Any, n: int, *, low: float = -math.inf,
            low_open: bool = False, what: str = 'finite numbers') -> tuple[float, ...]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        arr = np.array([])
    ok = arr.shape == (n,) and bool(np.all(np.isfinite(arr)))
    if ok:
        ok = bool(np.all(arr > low)) if low_open else bool(np.all(arr >= low))
    if not ok:
        bound = '' if low == -math.inf else f', each {">" if low_open else ">="} {low:g}'
        raise ParameterError(name, f'got {value!r}; allowed: {n} {what}{bound}')
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class Disturbances:
    """What the plant suffers and the controller does not know (SI units).

    Parameters
    ----------
    com_error : tuple of 3 float
        True r_g minus nominal r_g, body frame, m.
    current : tuple of 3 float
        Mean ocean current in NED, m/s.
    current_std : tuple of 3 float
        Stationary standard deviation of the Gauss-Markov part per NED axis,
        m/s (>= 0; 0 switches that axis off).
    current_time_constant : tuple of 3 float
        Correlation time T_c of the Gauss-Markov part per axis, s (> 0).
        [estimate] 60 s: slow changes of a tidal current.
    seed : int
        Seed of the numpy Generator of the Gauss-Markov process (>= 0).
    external_wrench : tuple of 6 float or callable
        Body wrench (X Y Z K M N), N and N m, or a function of time (s)
        returning one.
    """

    com_error: tuple[float, ...] = (0.0, 0.0, 0.0)
    current: tuple[float, ...] = (0.0, 0.0, 0.0)
    current_std: tuple[float, ...] = (0.0, 0.0, 0.0)
    current_time_constant: tuple[float, ...] = (60.0, 60.0, 60.0)
    seed: int = 0
    external_wrench: tuple[float, ...] | WrenchFn = (0.0,) * 6

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, 'com_error', _vector('com_error', self.com_error, 3))
        set_(self, 'current', _vector('current', self.current, 3))
        set_(self, 'current_std', _vector('current_std', self.current_std, 3, low=0.0))
        set_(self, 'current_time_constant',
             _vector('current_time_constant', self.current_time_constant, 3, low=0.0,
                     low_open=True))
        seed: Any = self.seed  # may be anything at run time
        if isinstance(seed, bool) or not isinstance(seed, Integral) or int(seed) < 0:
            raise ParameterError('seed', f'got {seed!r}; allowed: an integer >= 0')
        set_(self, 'seed', int(seed))
        if not callable(self.external_wrench):
            set_(self, 'external_wrench',
                 _vector('external_wrench', self.external_wrench, 6))

    def true_params(self, nominal: RobotParams) -> RobotParams:
        """The plant's robot: ``nominal`` with r_g + com_error."""
        r_g = tuple(g + e for g, e in zip(nominal.center_of_gravity, self.com_error))
        return replace(nominal, center_of_gravity=r_g)

    def describe(self) -> dict[str, Any]:
        """JSON-serialisable summary for a RunLog's meta."""
        wrench = (repr(self.external_wrench) if callable(self.external_wrench)
                  else list(self.external_wrench))
        return {'com_error': list(self.com_error), 'current': list(self.current),
                'current_std': list(self.current_std),
                'current_time_constant': list(self.current_time_constant),
                'seed': int(self.seed), 'external_wrench': wrench,
                'external_wrench_lasting': self.lasting_wrench()}

    def lasting_wrench(self) -> list[float] | None:
        """The external wrench that lasts for ever (a constant, or the endless pulses of
        a callable that tells them: ``lasting()``); None when unknown."""
        if not callable(self.external_wrench):
            return list(self.external_wrench)
        lasting = getattr(self.external_wrench, 'lasting', None)
        return [float(v) for v in lasting()] if callable(lasting) else None


class OceanCurrent:
    """Ocean current in NED: constant mean plus a first-order Gauss-Markov part per axis.

    ``velocity`` is the value at the present time; :meth:`advance` moves it one
    step of h seconds ahead (exact discretisation, see the module docstring).
    b and the velocity live in ``state`` (layout ``CURRENT_B``,
    ``CURRENT_VELOCITY``); the plant's compiled step advances them in place
    with the normal draws of :meth:`draw`, the same sequence :meth:`advance` uses.
    """

    def __init__(self, mean: ArrayLike = (0.0, 0.0, 0.0), std: ArrayLike = (0.0, 0.0, 0.0),
                 time_constant: ArrayLike = (60.0, 60.0, 60.0),
                 rng: np.random.Generator | None = None) -> None:
        self.mean = _vector('current', mean, 3)
        self.std = _vector('current_std', std, 3, low=0.0)
        self.time_constant = _vector('current_time_constant', time_constant, 3, low=0.0,
                                     low_open=True)
        self._rng = rng if rng is not None else np.random.default_rng(0)
        self._random = any(s > 0.0 for s in self.std)
        self.state = np.zeros(CURRENT_STATE)
        self.state[CURRENT_VELOCITY:CURRENT_VELOCITY + 3] = self.mean
        self._h = -1.0
        self._phi: tuple[float, ...] = (1.0, 1.0, 1.0)
        self._gain: tuple[float, ...] = (0.0, 0.0, 0.0)

    @classmethod
    def from_disturbances(cls, d: Disturbances) -> OceanCurrent:
        return cls(d.current, d.current_std, d.current_time_constant,
                   np.random.default_rng(d.seed))

    @property
    def velocity(self) -> tuple[float, ...]:
        """Current velocity in NED now, m/s."""
        return tuple(self.state[CURRENT_VELOCITY:CURRENT_VELOCITY + 3].tolist())

    @property
    def gauss_markov(self) -> tuple[float, ...]:
        """The Gauss-Markov part b now, m/s."""
        return tuple(self.state[CURRENT_B:CURRENT_B + 3].tolist())

    @property
    def random(self) -> bool:
        """True when some axis has a Gauss-Markov part (``advance`` draws numbers)."""
        return self._random

    def coefficients(self, h: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """(phi, sigma sqrt(1 - phi^2)) per axis for a step of h s (see the module docstring)."""
        if h != self._h:
            self._h = h
            phis = tuple(math.exp(-h / tc) for tc in self.time_constant)
            self._phi = phis
            self._gain = tuple(s * math.sqrt(1.0 - p * p) for s, p in zip(self.std, phis))
        return self._phi, self._gain

    def draw(self, out: FloatArray) -> None:
        """Fill ``out`` (k, 3) with the standard normals of the next k :meth:`advance` calls
        (one call of the Generator gives the same sequence as k calls of 3)."""
        self._rng.standard_normal(out=out)

    def advance(self, h: float) -> None:
        """Move the process h seconds ahead."""
        if not self._random:
            return
        phis, gains = self.coefficients(h)
        n = self._rng.standard_normal(3)
        s = self.state
        b = [p * b + g * float(z)
             for p, b, g, z in zip(phis, s[CURRENT_B:CURRENT_B + 3].tolist(), gains, n)]
        s[CURRENT_B:CURRENT_B + 3] = b
        s[CURRENT_VELOCITY:CURRENT_VELOCITY + 3] = [m + v for m, v in zip(self.mean, b)]


class ExternalWrench:
    """External body wrench (X Y Z K M N), N and N m: a constant or a function of time (s)."""

    def __init__(self, wrench: tuple[float, ...] | WrenchFn | ArrayLike = (0.0,) * 6) -> None:
        self._fn: WrenchFn | None
        if callable(wrench):
            self._fn = wrench
            self._const: tuple[float, ...] = (0.0,) * 6
        else:
            self._fn = None
            self._const = _vector('external_wrench', wrench, 6)

    @property
    def is_constant(self) -> bool:
        return self._fn is None

    def __call__(self, t: float) -> tuple[float, ...]:
        """The wrench at time t (s). Raises ValueError if a callable returns a bad one."""
        if self._fn is None:
            return self._const
        value = np.asarray(self._fn(t), dtype=float)
        if value.shape != (6,) or not np.all(np.isfinite(value)):
            raise ValueError(f'external wrench at t = {t!r} s: expected 6 finite values, '
                             f'got {value!r}')
        return tuple(float(v) for v in value)
