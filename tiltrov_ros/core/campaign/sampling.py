"""The samples of a campaign: scenario documents drawn from a :class:`CampaignSpec`.

Sample ``i`` is drawn from ``numpy.random.default_rng([seed, i])``, in the
order of the file's sections (base, reference, disturbances, robot, faults),
every distribution every time (a pulse or a fault absent from a sample is
still drawn), so each sample has the same parameters and depends neither on
how many samples are drawn nor on the others.

A sample is the mapping a scenario file holds (:attr:`Sample.document`): the
base scenario's document with the drawn parts set or added. It becomes a
:class:`~tiltrov_ros.core.scenarios.Scenario` through the scenario parser,
so a run's scenario file (``yaml.safe_dump`` of the document; floats
round-trip exactly) gives ``tiltrov sim`` the same scenario the campaign ran.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import copy
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from tiltrov_ros.core.campaign.spec import (
    ROBOT_ANGLE_KEYS,
    CampaignSpec,
    CurrentDraw,
    Distribution,
    VectorDraw,
)
from tiltrov_ros.core.errors import CampaignError, TiltrovError
from tiltrov_ros.core.scenarios import TERM_UNIT_KEYS, Scenario

_ANGLE_DOFS = ('roll', 'pitch', 'yaw')

Param = float | str


@dataclass(frozen=True)
class Sample:
    """One draw: its index, its scenario document and its parameters.

    ``params`` maps each drawn value's place in the campaign file
    (``reference.x[0].value``, ``disturbances.current.speed``, ...; in the
    file's units) to the value, plus columns every sample has: ``base`` (the
    base scenario's label, '' without one), ``current_speed`` (m/s,
    horizontal) and ``current_direction`` (deg from north towards east) of the
    mean current the scenario ends up with.
    """

    index: int
    document: dict[str, Any]
    params: dict[str, Param]

    @property
    def name(self) -> str:
        return str(self.document['name'])

    def scenario(self, source: str | None = None) -> Scenario:
        """The scenario this sample runs (:class:`CampaignError` if the draw is invalid)."""
        try:
            return Scenario.from_mapping(self.document, source=source)
        except TiltrovError as exc:
            raise CampaignError(' '.join(str(exc).split())) from exc


def draw_samples(spec: CampaignSpec, count: int) -> list[Sample]:
    """Samples ``0 .. count - 1``."""
    return [draw_sample(spec, i) for i in range(count)]


def draw_sample(spec: CampaignSpec, index: int) -> Sample:
    """Sample ``index`` of ``spec`` (see the module docstring)."""
    return _Draw(spec, index).sample()


class _Draw:
    def __init__(self, spec: CampaignSpec, index: int) -> None:
        self.spec = spec
        self.index = index
        self.rng = np.random.default_rng([spec.seed, index])
        self.params: dict[str, Param] = {}

    def value(self, dist: Distribution, key: str) -> float:
        """A drawn value, recorded as a parameter unless it is a constant."""
        v = float(dist.draw(self.rng))
        if dist.kind != 'constant':
            self.params[key] = v
        return v

    def vector(self, draw: VectorDraw, key: str) -> list[float]:
        if draw.magnitude is None:
            return [self.value(d, f'{key}[{i}]') for i, d in enumerate(draw.axes)]
        size = self.value(draw.magnitude, f'{key}.magnitude')
        direction = self.rng.normal(size=3)
        norm = float(np.linalg.norm(direction))
        unit = direction / norm if norm > 0 else np.array([1.0, 0.0, 0.0])
        out = [float(size * u) for u in unit]
        for i, v in enumerate(out):
            self.params[f'{key}[{i}]'] = v
        return out

    def current(self, draw: CurrentDraw) -> list[float]:
        key = 'disturbances.current'
        if draw.axes is not None:
            return self.vector(draw.axes, key)
        assert draw.speed is not None and draw.direction is not None and draw.down is not None
        speed = self.value(draw.speed, f'{key}.speed')
        heading = self.value(draw.direction, f'{key}.direction')      # rad
        if draw.direction.kind != 'constant':      # the parameter in the file's unit
            self.params[f'{key}.direction'] = heading / self.spec.angle_scale
        down = self.value(draw.down, f'{key}.down')
        return [speed * math.cos(heading), speed * math.sin(heading), down]

    def sample(self) -> Sample:
        spec = self.spec
        label, base = spec.bases[self.index % len(spec.bases)] if spec.bases else ('', {})
        doc: dict[str, Any] = copy.deepcopy(dict(base))
        doc['name'] = f'{spec.name}-s{self.index:05d}'
        doc['description'] = (f'sample {self.index} of campaign {spec.name} (seed '
                              f'{spec.seed}){f", on {label}" if label else ""}')
        if spec.duration is not None:
            doc['duration'] = spec.duration
        if not spec.bases:
            doc['angle_unit'] = spec.angle_unit
        self.params['base'] = label
        self.reference(doc)
        self.disturbances(doc)
        self.robot(doc)
        self.fault(doc)
        current = (doc.get('disturbances') or {}).get('current', [0.0, 0.0, 0.0])
        north, east = _numbers(current, 2)
        self.params['current_speed'] = math.hypot(north, east)
        self.params['current_direction'] = math.degrees(math.atan2(east, north)) % 360.0
        return Sample(self.index, doc, self.params)

    def reference(self, doc: dict[str, Any]) -> None:
        if not self.spec.reference:
            return
        base_scale = math.pi / 180.0 if doc.get('angle_unit', 'rad') == 'deg' else 1.0
        to_doc = self.spec.angle_scale / base_scale
        reference = dict(doc.get('reference') or {})
        for dof, templates in self.spec.reference:
            entries = reference.get(dof, [])
            terms = [entries] if isinstance(entries, Mapping) else list(entries)
            for i, template in enumerate(templates):
                occurs = True
                if template.probability is not None:
                    occurs = bool(self.rng.random() < template.probability)
                    self.params[f'reference.{dof}[{i}].occurs'] = float(occurs)
                term: dict[str, Any] = {'type': template.kind}
                for key, dist in template.fields:
                    v = self.value(dist, f'reference.{dof}[{i}].{key}')
                    term[key] = v * to_doc if dof in _ANGLE_DOFS and key in TERM_UNIT_KEYS \
                        else v
                if occurs:
                    terms.append(term)
            reference[dof] = terms
        doc['reference'] = reference

    def disturbances(self, doc: dict[str, Any]) -> None:
        spec = self.spec
        dist = dict(doc.get('disturbances') or {})
        if spec.current is not None:
            dist['current'] = self.current(spec.current)
        if spec.current_std is not None:
            dist['current_std'] = self.vector(spec.current_std, 'disturbances.current_std')
            seed = int(self.rng.integers(2**31))
            self.params['disturbances.seed'] = float(seed)
            dist['seed'] = seed
        if spec.current_time_constant is not None:
            dist['current_time_constant'] = self.vector(
                spec.current_time_constant, 'disturbances.current_time_constant')
        if spec.com_error is not None:
            dist['com_error'] = self.vector(spec.com_error, 'disturbances.com_error')
        pulses = []
        for i, pulse in enumerate(spec.pulses):
            key = f'disturbances.external_wrench[{i}]'
            occurs = bool(self.rng.random() < pulse.probability)
            self.params[f'{key}.occurs'] = float(occurs)
            start = self.value(pulse.start, f'{key}.start')
            length = self.value(pulse.duration, f'{key}.duration')
            wrench = [self.value(w, f'{key}.wrench[{k}]') for k, w in enumerate(pulse.wrench)]
            if occurs:
                pulses.append({'start': start, 'end': start + length, 'wrench': wrench})
        if pulses:
            dist['external_wrench'] = _pulses(dist.get('external_wrench')) + pulses
        if dist:
            doc['disturbances'] = dist

    def robot(self, doc: dict[str, Any]) -> None:
        if not self.spec.robot:
            return
        robot = dict(doc.get('robot') or {})
        for key, dists in self.spec.robot:
            if isinstance(dists, Distribution):
                robot[key] = self.value(dists, f'robot.{key}')
                if key in ROBOT_ANGLE_KEYS and dists.kind != 'constant':   # in the file's unit
                    self.params[f'robot.{key}'] = robot[key] / self.spec.angle_scale
            else:
                robot[key] = [self.value(d, f'robot.{key}[{i}]') for i, d in enumerate(dists)]
        doc['robot'] = robot

    def fault(self, doc: dict[str, Any]) -> None:
        fault = self.spec.fault
        if fault is None:
            return
        occurs = bool(self.rng.random() < fault.probability)
        self.params['faults.occurs'] = float(occurs)
        thruster = int(self.value(fault.thruster, 'faults.thruster'))
        at = self.value(fault.at, 'faults.at')
        after = self.value(fault.detected_after, 'faults.detected_after')
        if occurs:
            doc['faults'] = [*(doc.get('faults') or []),
                             {'thruster': thruster, 'at': at, 'detected_after': after}]


def _numbers(value: Any, n: int) -> list[float]:
    if isinstance(value, Sequence) and len(value) >= n and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value[:n]):
        return [float(v) for v in value[:n]]
    return [0.0] * n


def _pulses(existing: Any) -> list[Any]:
    """A base scenario's external wrench as a list of pulses (a constant: one endless)."""
    if existing is None:
        return []
    if isinstance(existing, Sequence) and existing and all(
            isinstance(p, Mapping) for p in existing):
        return list(existing)
    return [{'start': 0.0, 'wrench': list(existing)}]
