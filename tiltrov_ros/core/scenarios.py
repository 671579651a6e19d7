"""Scenarios: reference, duration, disturbances and initial state, from YAML.

A scenario file (``config/scenarios/<name>.yaml``, or any path) is plain YAML::

    name: pitch_hold
    description: Section 4.1 of the paper ...
    duration: 60.0                  # s
    angle_unit: deg                 # unit of roll/pitch/yaw values (deg or rad)
    reference:                      # eta_d(t) per DOF: a sum of terms
      pitch:
        - {type: ramp, from: 0.0, to: -30.0, start: 0.0, duration: 30.0}
      z:
        - {type: sine, amplitude: 0.4, omega: 0.0785398, phase: 0.0, start: 0.0}
    disturbances:                     # see tiltrov_ros/core/disturbances.py
      com_error: [0.01, 0.0, 0.005]   # m, true CG minus nominal (the paper's disturbance)
      current: [0.0, 0.0, 0.0]        # mean ocean current in NED, m/s
      current_std: [0.0, 0.0, 0.0]    # Gauss-Markov stationary std per axis, m/s
      current_time_constant: [60.0, 60.0, 60.0]   # Gauss-Markov correlation time, s
      seed: 0                         # of the Gauss-Markov noise
      external_wrench:                # body wrench: 6 numbers, or pulses (N, N m)
        - {start: 10.0, end: 12.0, wrench: [20, 0, 0, 0, 0, 0]}
    initial_state:
      position: [0, 0, 0]             # m, NED
      euler: [0, 0, 0]                # roll, pitch, yaw in angle_unit
      nu: [0, 0, 0, 0, 0, 0]          # body velocity
    robot:                            # overrides of config/robot.yaml
      tilt_rate_limit: 1.0471975511965976
    faults:                           # actuator faults (docs/reliability.md)
      - {thruster: 2, at: 20.0, detected_after: 0.0}   # thruster_2 gives no thrust from
                                      # 20 s; the allocator knows from 20 s + detected_after

DOFs not listed in ``reference`` are held at 0. Term types (``t`` is the
scenario time, s):

* ``constant``: ``value``;
* ``ramp``: ``from`` -> ``to`` linearly over [``start``, ``start + duration``],
  held outside;
* ``sine``: ``amplitude * sin(omega (t - start) + phase)`` on
  [``start``, ``end``] (``end`` optional), held at its end values outside;
* ``step``: ``value`` from ``at`` on, 0 before.

The reference gives eta_d and its exact time derivative (the feed-forward of
``setpoint_velocity``); as messages carry it, the attitude goes out as a
quaternion. At the instant of a kink the rate is a one-sided derivative: a
ramp's rate is 0 at its start and at its end (the rate of the held pieces), a
sine's is its own rate at ``start`` and ``end``; a step's jump contributes no
rate. (Which side is taken matters more than it seems: see
docs/limitations.md on the allocator holding both pairs at the +-90 deg edge.)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core.controllers import Reference
from tiltrov_ros.core.disturbances import Disturbances
from tiltrov_ros.core.errors import ParameterError, ScenarioError, UnreadableFileError
from tiltrov_ros.core.kinematics import quat_from_euler
from tiltrov_ros.core.names import DOF_NAMES
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.yamlfile import read_yaml
from tiltrov_ros.paths import scenario_dir

FloatArray = NDArray[np.float64]

_ANGLES = ('roll', 'pitch', 'yaw')
_TERM_KEYS: dict[str, tuple[set[str], set[str]]] = {
    # type: (required keys, optional keys)
    'constant': ({'value'}, set()),
    'ramp': ({'from', 'to', 'duration'}, {'start'}),
    'sine': ({'amplitude', 'omega'}, {'phase', 'start', 'end'}),
    'step': ({'value', 'at'}, set()),
}
#: Term keys that carry the DOF's unit (scaled deg -> rad for angles with ``angle_unit: deg``).
TERM_UNIT_KEYS = frozenset({'value', 'from', 'to', 'amplitude'})


@dataclass(frozen=True)
class Term:
    """One additive term of a DOF's reference (see the module docstring)."""

    kind: str
    params: tuple[tuple[str, float], ...]

    def _p(self, key: str, default: float = 0.0) -> float:
        return dict(self.params).get(key, default)

    def value(self, t: float) -> tuple[float, float]:
        """(value, rate) at time ``t``."""
        if self.kind == 'constant':
            return self._p('value'), 0.0
        if self.kind == 'step':
            return (self._p('value'), 0.0) if t >= self._p('at') else (0.0, 0.0)
        if self.kind == 'ramp':
            start, duration = self._p('start'), self._p('duration')
            a, b = self._p('from'), self._p('to')
            if t <= start:
                return a, 0.0
            if t >= start + duration:
                return b, 0.0
            return a + (b - a) * (t - start) / duration, (b - a) / duration
        # sine
        amplitude, omega = self._p('amplitude'), self._p('omega')
        phase, start, end = self._p('phase'), self._p('start'), self._p('end', math.inf)
        tau = min(max(t, start), end) - start
        rate = amplitude * omega * math.cos(omega * tau + phase) if start <= t <= end else 0.0
        return amplitude * math.sin(omega * tau + phase), rate


@dataclass(frozen=True)
class ReferenceProfile:
    """eta_d(t) and d(eta_d)/dt for the six DOFs (x, y, z in m; angles in rad)."""

    terms: tuple[tuple[Term, ...], ...]      # one tuple of terms per DOF

    def eta(self, t: float) -> tuple[FloatArray, FloatArray]:
        """(eta_d, eta_d_dot) at time ``t``."""
        eta = np.zeros(6)
        rate = np.zeros(6)
        for i, dof_terms in enumerate(self.terms):
            for term in dof_terms:
                v, r = term.value(t)
                eta[i] += v
                rate[i] += r
        return eta, rate

    def at(self, t: float) -> Reference:
        """The reference as the ``setpoint``/``setpoint_velocity`` messages carry it."""
        eta, rate = self.eta(t)
        return Reference(eta[:3].copy(), quat_from_euler(eta[3], eta[4], eta[5]), rate)


@dataclass(frozen=True)
class WrenchPulses:
    """An external body wrench made of pulses: ``wrench`` on [start, end)."""

    pulses: tuple[tuple[float, float, tuple[float, ...]], ...]

    def __call__(self, t: float) -> FloatArray:
        total = np.zeros(6)
        for start, end, wrench in self.pulses:
            if start <= t < end:
                total += np.array(wrench)
        return total

    def lasting(self) -> FloatArray:
        """The sum of the pulses that never end: the wrench that stays."""
        total = np.zeros(6)
        for _, end, wrench in self.pulses:
            if math.isinf(end):
                total += np.array(wrench)
        return total


@dataclass(frozen=True)
class InitialState:
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    euler: tuple[float, float, float] = (0.0, 0.0, 0.0)        # rad
    nu: tuple[float, ...] = (0.0,) * 6


@dataclass(frozen=True)
class ThrusterFault:
    """Thruster ``index`` (0..3: thruster_1..4) fails at ``at`` s; the allocator is
    told ``detected_after`` s later (it allocates without it from then on)."""

    index: int
    at: float
    detected_after: float = 0.0

    @property
    def detected_at(self) -> float:
        return self.at + self.detected_after


def failed_at(faults: Sequence[ThrusterFault], t: float, *, detected: bool = False
              ) -> tuple[int, ...]:
    """Indices of the thrusters failed (``detected``: known to the allocator) at ``t`` s."""
    return tuple(sorted({f.index for f in faults
                         if t >= (f.detected_at if detected else f.at)}))


@dataclass(frozen=True)
class Scenario:
    """A named run: reference, duration, disturbances, initial state, robot overrides."""

    name: str
    duration: float
    reference: ReferenceProfile
    disturbances: Disturbances = field(default_factory=Disturbances)
    initial_state: InitialState = field(default_factory=InitialState)
    robot_overrides: tuple[tuple[str, Any], ...] = ()
    description: str = ''
    source: str | None = field(default=None, compare=False)
    faults: tuple[ThrusterFault, ...] = ()

    def robot(self, base: RobotParams) -> RobotParams:
        """``base`` with this scenario's overrides applied (validated again)."""
        if not self.robot_overrides:
            return base
        values = base.as_dict()
        values.update(dict(self.robot_overrides))
        return RobotParams.from_mapping(values, source=self.source)

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any], *, source: str | None = None) -> Scenario:
        return _parse(doc, source)


def scenario_names() -> list[str]:
    """Names of the shipped scenarios (``config/scenarios/*.yaml``)."""
    return sorted(p.stem for p in scenario_dir().glob('*.yaml'))


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A shipped scenario by name (``pitch_hold``) or any scenario file by path."""
    doc, path = load_scenario_document(name_or_path)
    return _parse(doc, str(path))


def load_scenario_document(name_or_path: str | Path) -> tuple[Mapping[str, Any], Path]:
    """The YAML mapping of a scenario (shipped name or path), not yet validated, and its
    file. :func:`load_scenario` parses it; campaigns build samples on it."""
    path = Path(name_or_path)
    if not path.suffix:
        path = scenario_dir() / f'{name_or_path}.yaml'
        if not path.is_file():
            raise ScenarioError(f'no scenario named {str(name_or_path)!r}; shipped: '
                                f'{", ".join(scenario_names())}; or give a path to a .yaml file')
    if not path.is_file():
        raise ScenarioError(f'scenario file not found: {path}')
    try:
        doc = read_yaml(path)
    except UnreadableFileError as exc:
        raise ScenarioError(str(exc)) from None
    if not isinstance(doc, Mapping):
        raise ScenarioError(f'{path}: a scenario is a YAML mapping')
    return doc, path


# --------------------------------------------------------------------------- parsing


def _fail(source: str | None, where: str, message: str) -> ScenarioError:
    return ScenarioError(f'{source or "scenario"}: {where}: {message}')


def _float(value: Any, source: str | None, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(source, where, f'expected a number, got {value!r}')
    v = float(value)
    if not math.isfinite(v):
        raise _fail(source, where, f'expected a finite number, got {value!r}')
    return v


def _floats(value: Any, n: int, source: str | None, where: str) -> tuple[float, ...]:
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != n:
        raise _fail(source, where, f'expected {n} numbers, got {value!r}')
    return tuple(_float(v, source, f'{where}[{i}]') for i, v in enumerate(value))


def _check_keys(doc: Mapping[str, Any], allowed: set[str], source: str | None,
                where: str) -> None:
    unknown = set(doc) - allowed
    if unknown:
        raise _fail(source, where, f'unknown key {sorted(unknown)[0]!r}; allowed: '
                                   f'{", ".join(sorted(allowed))}')


def _term(doc: Any, scale: float, source: str | None, where: str) -> Term:
    if not isinstance(doc, Mapping) or 'type' not in doc:
        raise _fail(source, where, f'a term is a mapping with a type, got {doc!r}')
    kind = doc['type']
    if kind not in _TERM_KEYS:
        raise _fail(source, where, f'unknown term type {kind!r}; allowed: '
                                   f'{", ".join(sorted(_TERM_KEYS))}')
    required, optional = _TERM_KEYS[kind]
    _check_keys(doc, required | optional | {'type'}, source, where)
    missing = required - set(doc)
    if missing:
        raise _fail(source, where, f'{kind} term needs {sorted(missing)[0]!r}')
    params = []
    for key in sorted(required | optional):
        if key in doc:
            v = _float(doc[key], source, f'{where}.{key}')
            params.append((key, v * scale if key in TERM_UNIT_KEYS else v))
    out = Term(kind, tuple(params))
    if kind == 'ramp' and out._p('duration') <= 0:
        raise _fail(source, f'{where}.duration', 'must be > 0 s')
    if kind == 'sine' and out._p('end', math.inf) < out._p('start'):
        raise _fail(source, f'{where}.end', 'must not be before start')
    return out


def _parse(doc: Mapping[str, Any], source: str | None) -> Scenario:
    _check_keys(doc, {'name', 'description', 'duration', 'angle_unit', 'reference',
                      'disturbances', 'initial_state', 'robot', 'faults'}, source, 'top level')
    name = str(doc.get('name') or (Path(source).stem if source else 'scenario'))
    if 'duration' not in doc:
        raise _fail(source, 'duration', 'missing (seconds of simulated time)')
    duration = _float(doc['duration'], source, 'duration')
    if duration <= 0:
        raise _fail(source, 'duration', f'must be > 0 s, got {duration}')
    unit = doc.get('angle_unit', 'rad')
    if unit not in ('rad', 'deg'):
        raise _fail(source, 'angle_unit', f"must be 'rad' or 'deg', got {unit!r}")
    angle_scale = math.pi / 180.0 if unit == 'deg' else 1.0

    reference = doc.get('reference', {}) or {}
    if not isinstance(reference, Mapping):
        raise _fail(source, 'reference', 'must map DOF names to lists of terms')
    _check_keys(reference, set(DOF_NAMES), source, 'reference')
    terms = []
    for dof in DOF_NAMES:
        entries = reference.get(dof, [])
        if isinstance(entries, Mapping):
            entries = [entries]
        if not isinstance(entries, Sequence):
            raise _fail(source, f'reference.{dof}', 'must be a list of terms')
        scale = angle_scale if dof in _ANGLES else 1.0
        terms.append(tuple(_term(entry, scale, source, f'reference.{dof}[{i}]')
                           for i, entry in enumerate(entries)))

    dist_doc = doc.get('disturbances', {}) or {}
    if not isinstance(dist_doc, Mapping):
        raise _fail(source, 'disturbances', 'must be a mapping')
    _check_keys(dist_doc, {'com_error', 'current', 'current_std', 'current_time_constant',
                           'seed', 'external_wrench'}, source, 'disturbances')
    kwargs: dict[str, Any] = {key: value for key, value in dist_doc.items()
                              if key != 'external_wrench'}
    wrench = dist_doc.get('external_wrench')
    if (isinstance(wrench, Sequence) and not isinstance(wrench, str) and wrench
            and all(isinstance(p, Mapping) for p in wrench)):
        pulses = []
        for i, pulse in enumerate(wrench):
            where = f'disturbances.external_wrench[{i}]'
            _check_keys(pulse, {'start', 'end', 'wrench'}, source, where)
            start = _float(pulse.get('start', 0.0), source, f'{where}.start')
            end = _float(pulse['end'], source, f'{where}.end') if 'end' in pulse else math.inf
            if end <= start:
                raise _fail(source, f'{where}.end', 'must be after start')
            pulses.append((start, end, _floats(pulse.get('wrench'), 6, source,
                                               f'{where}.wrench')))
        kwargs['external_wrench'] = WrenchPulses(tuple(pulses))
    elif wrench is not None:
        kwargs['external_wrench'] = wrench
    try:
        disturbances = Disturbances(**kwargs)
    except ParameterError as exc:
        raise _fail(source, 'disturbances', str(exc)) from exc

    init_doc = doc.get('initial_state', {}) or {}
    if not isinstance(init_doc, Mapping):
        raise _fail(source, 'initial_state', 'must be a mapping')
    _check_keys(init_doc, {'position', 'euler', 'nu'}, source, 'initial_state')
    euler = _floats(init_doc.get('euler', [0.0, 0.0, 0.0]), 3, source, 'initial_state.euler')
    initial = InitialState(
        _floats(init_doc.get('position', [0.0, 0.0, 0.0]), 3, source,  # type: ignore[arg-type]
                'initial_state.position'),
        tuple(v * angle_scale for v in euler),  # type: ignore[arg-type]
        _floats(init_doc.get('nu', [0.0] * 6), 6, source, 'initial_state.nu'))

    robot = doc.get('robot', {}) or {}
    if not isinstance(robot, Mapping):
        raise _fail(source, 'robot', 'must map robot.yaml keys to values')
    known = set(RobotParams.__dataclass_fields__) - {'source'}
    unknown = set(robot) - known
    if unknown:
        raise _fail(source, 'robot', f'unknown key {sorted(unknown)[0]!r}; allowed: the keys '
                                     'of config/robot.yaml')
    return Scenario(name, duration, ReferenceProfile(tuple(terms)), disturbances,
                    initial, tuple(sorted(robot.items())), str(doc.get('description', '')),
                    source, _faults(doc.get('faults', []) or [], source))


def _faults(doc: Any, source: str | None) -> tuple[ThrusterFault, ...]:
    if not isinstance(doc, Sequence) or isinstance(doc, str):
        raise _fail(source, 'faults', 'must be a list of {thruster, at, detected_after}')
    out = []
    for i, entry in enumerate(doc):
        where = f'faults[{i}]'
        if not isinstance(entry, Mapping):
            raise _fail(source, where, f'expected a mapping, got {entry!r}')
        _check_keys(entry, {'thruster', 'at', 'detected_after'}, source, where)
        number = entry.get('thruster')
        if isinstance(number, bool) or number not in (1, 2, 3, 4):
            raise _fail(source, f'{where}.thruster', f'got {number!r}; allowed: 1, 2, 3, 4 '
                                                     '(thruster_1..thruster_4)')
        if 'at' not in entry:
            raise _fail(source, where, "needs 'at' (s)")
        at = _float(entry['at'], source, f'{where}.at')
        after = _float(entry.get('detected_after', 0.0), source, f'{where}.detected_after')
        if at < 0 or after < 0:
            raise _fail(source, where, 'at and detected_after must be >= 0 s')
        out.append(ThrusterFault(int(number) - 1, at, after))
    return tuple(out)
