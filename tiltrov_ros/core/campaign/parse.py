"""Reading a campaign file into a :class:`CampaignSpec`, with one-line errors.

Each error names the file and the key (``station_keeping.yaml: compare.controllers[1]:
got 'pdd'; allowed: pd, switching, pid``), as scenario files do.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import itertools
import math
from pathlib import Path
import re
from typing import Any

import yaml

from tiltrov_ros.core.bounds import Bound
from tiltrov_ros.core.campaign.sampling import draw_sample
from tiltrov_ros.core.campaign.spec import (
    ROBOT_ANGLE_KEYS,
    TIME_METRICS,
    CampaignSpec,
    Configuration,
    CurrentDraw,
    Distribution,
    FaultDraw,
    PulseDraw,
    RobotValue,
    TermTemplate,
    VectorDraw,
    metrics_template,
)
from tiltrov_ros.core.controllers import CONTROLLER_KINDS, Gains
from tiltrov_ros.core.errors import CampaignError, ParameterError, TiltrovError
from tiltrov_ros.core.hold import HoldCriterion
from tiltrov_ros.core.names import ALLOCATOR_MODES, DOF_NAMES
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.scenarios import load_scenario_document

#: A robot factor's level: its name and the robot keys it sets (SI units, rad).
Level = tuple[str, tuple[tuple[str, RobotValue], ...]]

_TOP_KEYS = {'name', 'description', 'seed', 'samples', 'duration', 'angle_unit', 'base',
             'reference', 'disturbances', 'robot', 'faults', 'compare', 'hold'}
#: The keys of a hold file (:func:`load_hold`).
_HOLD_KEYS = {'name', 'angle_unit', 'hold'}
_NAME = re.compile(r'^[A-Za-z0-9_]+$')


def load_campaign(path: str | Path) -> CampaignSpec:
    """Read and validate a campaign file (:class:`CampaignError` on any problem)."""
    file = Path(path)
    if not file.is_file():
        raise CampaignError(f'campaign file not found: {file}')
    try:
        doc = yaml.safe_load(file.read_text(encoding='utf-8'))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise CampaignError(f'{file}: not valid YAML: {" ".join(str(exc).split())}') from exc
    if not isinstance(doc, Mapping):
        raise CampaignError(f'{file}: a campaign is a YAML mapping')
    return parse_campaign(doc, source=str(file), folder=file.parent)


def load_hold(path: str | Path) -> HoldCriterion:
    """The hold criterion of a campaign file, or of a *hold file*: a mapping of ``name``
    (default: the file's stem), ``angle_unit`` and ``hold`` only (the bounds then
    name any allocator mode and gain set). :class:`CampaignError` on any problem."""
    file = Path(path)
    if not file.is_file():
        raise CampaignError(f'hold criterion file not found: {file}')
    try:
        doc = yaml.safe_load(file.read_text(encoding='utf-8'))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise CampaignError(f'{file}: not valid YAML: {" ".join(str(exc).split())}') from exc
    if not isinstance(doc, Mapping):
        raise CampaignError(f'{file}: a hold criterion is a YAML mapping')
    if not set(doc) <= _HOLD_KEYS:
        spec = parse_campaign(doc, source=str(file), folder=file.parent)
        return HoldCriterion(spec.name, spec.hold)
    parser = _Parser(str(file), file.parent)
    name, parser.scale = parser.identity(doc)
    if 'hold' not in doc:
        raise parser.fail('hold', 'missing (a list of bounds on metrics.json)')
    return HoldCriterion(name, parser.hold(doc['hold'], None))


def parse_campaign(doc: Mapping[str, Any], *, source: str | None = None,
                   folder: Path | None = None) -> CampaignSpec:
    """A :class:`CampaignSpec` from a mapping; base scenario paths are relative to
    ``folder`` (the campaign file's). Sample 0 is drawn and parsed as a scenario, so
    what only the scenario parser knows (a term's keys) is checked too."""
    spec = _Parser(source, folder).campaign(doc)
    draw_sample(spec, 0).scenario(f'{spec.source} (sample 0)')
    return spec


# --------------------------------------------------------------------------- parsing


class _Parser:
    def __init__(self, source: str | None, folder: Path | None) -> None:
        self.source = source or 'campaign'
        self.folder = folder
        self.scale = 1.0

    def fail(self, where: str, message: str) -> CampaignError:
        return CampaignError(f'{self.source}: {where}: {message}')

    def mapping(self, value: Any, where: str, allowed: set[str]) -> Mapping[str, Any]:
        if value is None:
            return {}
        if not isinstance(value, Mapping):
            raise self.fail(where, f'expected a mapping, got {value!r}')
        unknown = sorted(str(k) for k in set(value) - allowed)
        if unknown:
            raise self.fail(where, f'unknown key {unknown[0]!r}; allowed: '
                                   f'{", ".join(sorted(allowed))}')
        return value

    def sequence(self, value: Any, where: str, n: int | None = None) -> Sequence[Any]:
        if not isinstance(value, Sequence) or isinstance(value, str) or (
                n is not None and len(value) != n):
            raise self.fail(where, f'expected a list{f" of {n}" if n else ""}, got {value!r}')
        return value

    def number(self, value: Any, where: str, low: float = -math.inf,
               high: float = math.inf) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise self.fail(where, f'expected a finite number, got {value!r}')
        if not low <= value <= high:
            raise self.fail(where, f'got {value!r}; allowed: {low:g} .. {high:g}')
        return float(value)

    def names(self, value: Any, where: str, allowed: Sequence[str] | None = None
              ) -> tuple[str, ...]:
        items = [value] if isinstance(value, str) else self.sequence(value, where)
        out = []
        for i, item in enumerate(items):
            if not isinstance(item, str) or not _NAME.match(item) or (
                    allowed is not None and item not in allowed):
                hint = f'; allowed: {", ".join(allowed)}' if allowed is not None else \
                    ' (letters, digits, _)'
                raise self.fail(f'{where}[{i}]', f'got {item!r}{hint}')
            out.append(item)
        if not out or len(set(out)) != len(out):
            raise self.fail(where, f'expected distinct names, got {value!r}')
        return tuple(out)

    def dist(self, value: Any, where: str, scale: float = 1.0) -> Distribution:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return Distribution('constant', (self.number(value, where) * scale,))
        if isinstance(value, Mapping) and len(value) == 1:
            kind, args = next(iter(value.items()))
            if kind in ('uniform', 'normal'):
                low, high = (self.number(a, f'{where}.{kind}[{i}]') for i, a in
                             enumerate(self.sequence(args, f'{where}.{kind}', 2)))
                if kind == 'uniform' and low > high:
                    raise self.fail(f'{where}.uniform', f'low {low:g} > high {high:g}')
                if kind == 'normal' and high < 0:
                    raise self.fail(f'{where}.normal', f'std {high:g} < 0')
                return Distribution(kind, (low * scale, high * scale))
            if kind == 'choice':
                items = self.sequence(args, f'{where}.choice')
                if not items:
                    raise self.fail(f'{where}.choice', 'expected at least one value')
                return Distribution('choice', tuple(
                    self.number(a, f'{where}.choice[{i}]') * scale for i, a in enumerate(items)))
        raise self.fail(where, f'expected a number or one of {{uniform: [low, high]}}, '
                               f'{{normal: [mean, std]}}, {{choice: [...]}}; got {value!r}')

    def vector(self, value: Any, where: str, *, magnitude: bool = False) -> VectorDraw:
        if magnitude and isinstance(value, Mapping) and set(value) == {'magnitude'}:
            return VectorDraw(magnitude=self.dist(value['magnitude'], f'{where}.magnitude'))
        if isinstance(value, Sequence) and not isinstance(value, str) and len(value) == 3:
            return VectorDraw(tuple(self.dist(v, f'{where}[{i}]') for i, v in enumerate(value)))
        shape = 'a list of 3 distributions' + (' or {magnitude: distribution}' if magnitude
                                              else '')
        raise self.fail(where, f'expected {shape}, got {value!r}')

    # ---- sections

    def identity(self, doc: Mapping[str, Any]) -> tuple[str, float]:
        """The file's ``name`` and its angle unit's scale to rad."""
        name = doc.get('name', Path(self.source).stem)
        if not isinstance(name, str) or not _NAME.match(name):
            raise self.fail('name', f'got {name!r}; allowed: letters, digits, _')
        unit = doc.get('angle_unit', 'rad')
        if unit not in ('rad', 'deg'):
            raise self.fail('angle_unit', f"must be 'rad' or 'deg', got {unit!r}")
        return name, math.pi / 180.0 if unit == 'deg' else 1.0

    def campaign(self, doc: Mapping[str, Any]) -> CampaignSpec:
        doc = self.mapping(doc, 'top level', _TOP_KEYS)
        name, self.scale = self.identity(doc)
        seed = doc.get('seed')
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise self.fail('seed', f'got {seed!r}; allowed: an integer >= 0 (required)')
        samples = doc.get('samples', 100)
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
            raise self.fail('samples', f'got {samples!r}; allowed: an integer >= 1')
        duration = doc.get('duration')
        if duration is not None:
            duration = self.number(duration, 'duration')
            if duration <= 0:
                raise self.fail('duration', f'must be > 0 s, got {duration:g}')
        bases = self.bases(doc.get('base'))
        if duration is None and not bases:
            raise self.fail('duration', 'missing (seconds of each run; or give a base '
                                        'scenario, whose duration is used)')
        dist = self.mapping(doc.get('disturbances'), 'disturbances',
                            {'current', 'current_std', 'current_time_constant', 'com_error',
                             'external_wrench'})
        compare = self.mapping(doc.get('compare'), 'compare',
                               {'controllers', 'allocators', 'gains', 'robot'})
        gain_sets = self.gain_sets(compare.get('gains'))
        factors = self.factors(compare.get('robot'))
        configurations = self.configurations(compare, [g for g, _ in gain_sets], factors)
        hold = self.hold(doc.get('hold'), configurations)
        return CampaignSpec(
            name, str(doc.get('description', '')).strip(), seed, samples, duration,
            self.scale, bases, self.reference(doc.get('reference')),
            self.current(dist['current']) if 'current' in dist else None,
            self.vector(dist['current_std'], 'disturbances.current_std')
            if 'current_std' in dist else None,
            self.vector(dist['current_time_constant'], 'disturbances.current_time_constant')
            if 'current_time_constant' in dist else None,
            self.vector(dist['com_error'], 'disturbances.com_error', magnitude=True)
            if 'com_error' in dist else None,
            self.pulses(dist.get('external_wrench')), self.robot(doc.get('robot')),
            self.fault(doc.get('faults')), configurations, gain_sets, hold, self.source,
            tuple((name, tuple(level for level, _ in levels)) for name, levels in factors))

    def bases(self, value: Any) -> tuple[tuple[str, Mapping[str, Any]], ...]:
        if value is None:
            return ()
        items = [value] if isinstance(value, str) else self.sequence(value, 'base')
        out = []
        for i, item in enumerate(items):
            where = f'base[{i}]'
            if not isinstance(item, str) or not item:
                raise self.fail(where, f'expected a scenario name or file, got {item!r}')
            target: str | Path = item
            if Path(item).suffix and self.folder is not None and not Path(item).is_absolute():
                target = self.folder / item
            try:
                doc, _ = load_scenario_document(target)
            except (TiltrovError, OSError) as exc:
                raise self.fail(where, ' '.join(str(exc).split())) from exc
            out.append((Path(item).stem, doc))
        return tuple(out)

    def reference(self, value: Any) -> tuple[tuple[str, tuple[TermTemplate, ...]], ...]:
        doc = self.mapping(value, 'reference', set(DOF_NAMES))
        out = []
        for dof in DOF_NAMES:
            if dof not in doc:
                continue
            entries = doc[dof]
            entries = [entries] if isinstance(entries, Mapping) else \
                self.sequence(entries, f'reference.{dof}')
            terms = []
            for i, entry in enumerate(entries):
                where = f'reference.{dof}[{i}]'
                if not isinstance(entry, Mapping) or not isinstance(entry.get('type'), str):
                    raise self.fail(where, f'a term is a mapping with a type, got {entry!r}')
                probability = (self.probability(entry, where) if 'probability' in entry
                               else None)
                terms.append(TermTemplate(entry['type'], tuple(
                    (str(k), self.dist(v, f'{where}.{k}'))
                    for k, v in entry.items() if k not in ('type', 'probability')),
                    probability))
            out.append((dof, tuple(terms)))
        return tuple(out)

    def current(self, value: Any) -> CurrentDraw:
        where = 'disturbances.current'
        if not isinstance(value, Mapping):
            return CurrentDraw(axes=self.vector(value, where))
        doc = self.mapping(value, where, {'speed', 'direction', 'down'})
        if 'speed' not in doc or 'direction' not in doc:
            raise self.fail(where, 'needs speed (m/s) and direction (angle_unit from north '
                                   'towards east), or give 3 NED components')
        return CurrentDraw(self.dist(doc['speed'], f'{where}.speed'),
                           self.dist(doc['direction'], f'{where}.direction', self.scale),
                           self.dist(doc.get('down', 0.0), f'{where}.down'))

    def probability(self, doc: Mapping[str, Any], where: str) -> float:
        return self.number(doc.get('probability', 1.0), f'{where}.probability', 0.0, 1.0)

    def pulses(self, value: Any) -> tuple[PulseDraw, ...]:
        if value is None:
            return ()
        out = []
        for i, entry in enumerate(self.sequence(value, 'disturbances.external_wrench')):
            where = f'disturbances.external_wrench[{i}]'
            doc = self.mapping(entry, where, {'probability', 'start', 'duration', 'wrench'})
            for key in ('start', 'duration', 'wrench'):
                if key not in doc:
                    raise self.fail(where, f'needs {key!r}')
            wrench = self.sequence(doc['wrench'], f'{where}.wrench', 6)
            out.append(PulseDraw(self.probability(doc, where),
                                 self.dist(doc['start'], f'{where}.start'),
                                 self.dist(doc['duration'], f'{where}.duration'),
                                 tuple(self.dist(w, f'{where}.wrench[{k}]')
                                       for k, w in enumerate(wrench))))
        return tuple(out)

    def robot(self, value: Any, where: str = 'robot'
              ) -> tuple[tuple[str, Distribution | tuple[Distribution, ...]], ...]:
        known = {f for f in RobotParams.__dataclass_fields__ if f != 'source'}
        doc = self.mapping(value, where, known)
        out: list[tuple[str, Distribution | tuple[Distribution, ...]]] = []
        for key in sorted(doc):
            item = doc[key]
            if isinstance(item, Sequence) and not isinstance(item, str):
                out.append((str(key), tuple(self.dist(v, f'{where}.{key}[{i}]')
                                            for i, v in enumerate(item))))
            else:
                scale = self.scale if key in ROBOT_ANGLE_KEYS else 1.0
                out.append((str(key), self.dist(item, f'{where}.{key}', scale)))
        return tuple(out)

    def factors(self, value: Any) -> tuple[tuple[str, tuple[Level, ...]], ...]:
        """``compare.robot``: factors, each a mapping of level names to the robot keys
        the level sets (numbers, in the file's units, as in ``robot``)."""
        if value is None:
            return ()
        if not isinstance(value, Mapping) or not value:
            raise self.fail('compare.robot', 'expected robot factors, e.g. {servo_range: '
                                             '{r90: {tilt_min: -90, tilt_max: 90}, ...}}, '
                                             f'got {value!r}')
        out = []
        for factor, levels in value.items():
            where = f'compare.robot.{factor}'
            self.names([factor], 'compare.robot')
            if not isinstance(levels, Mapping) or not levels:
                raise self.fail(where, f'expected named levels, got {levels!r}')
            parsed = []
            for level, keys in levels.items():
                self.names([level], where)
                drawn = self.robot(keys, f'{where}.{level}')
                if not drawn:
                    raise self.fail(f'{where}.{level}', 'expected robot keys and values')
                values: list[tuple[str, RobotValue]] = []
                for key, dist in drawn:
                    constants = [d.args[0] if d.kind == 'constant' else None
                                 for d in (dist if isinstance(dist, tuple) else (dist,))]
                    if None in constants:
                        raise self.fail(f'{where}.{level}.{key}', 'a factor level sets '
                                        'numbers, not distributions')
                    values.append((key, tuple(constants) if isinstance(dist, tuple)  # type: ignore[arg-type]
                                   else float(constants[0])))  # type: ignore[arg-type]
                parsed.append((str(level), tuple(values)))
            out.append((str(factor), tuple(parsed)))
        return tuple(out)

    def fault(self, value: Any) -> FaultDraw | None:
        if value is None:
            return None
        doc = self.mapping(value, 'faults', {'probability', 'thruster', 'at', 'detected_after'})
        if 'at' not in doc:
            raise self.fail('faults', "needs 'at' (s)")
        thruster = self.dist(doc.get('thruster', {'choice': [1, 2, 3, 4]}), 'faults.thruster')
        values = thruster.values()
        if values is None or not set(values) <= {1.0, 2.0, 3.0, 4.0}:
            raise self.fail('faults.thruster', 'allowed: a number or a choice among 1, 2, 3, 4')
        return FaultDraw(self.probability(doc, 'faults'), thruster,
                         self.dist(doc['at'], 'faults.at'),
                         self.dist(doc.get('detected_after', 0.0), 'faults.detected_after'))

    def gain_sets(self, value: Any) -> tuple[tuple[str, Mapping[str, Any]], ...]:
        if value is None:
            return (('shipped', {}),)
        if not isinstance(value, Mapping) or not value:
            raise self.fail('compare.gains', 'expected named gain sets, e.g. {shipped: {}, '
                                             f'stiff: {{kp: [...]}}}}, got {value!r}')
        out = []
        for name, gains in value.items():
            where = f'compare.gains.{name}'
            self.names([name], 'compare.gains')
            body = self.mapping(gains, where, {'kp', 'kd', 'ki', 'integral_limit',
                                               'antiwindup'})
            if body:
                try:   # the same checks as the controller's parameter file
                    Gains.from_mapping({'kp': [1.0] * 6, 'kd': [1.0] * 6, **body})
                except ParameterError as exc:
                    key = exc.name.removeprefix('gains.')
                    detail = ' '.join(str(exc).split()).split(': ', 1)[-1]
                    raise self.fail(f'{where}.{key}', detail) from exc
            out.append((str(name), dict(body)))
        return tuple(out)

    def configurations(self, compare: Mapping[str, Any], gains: list[str],
                       factors: tuple[tuple[str, tuple[Level, ...]], ...] = ()
                       ) -> tuple[Configuration, ...]:
        controllers = self.names(compare.get('controllers', ['pd']), 'compare.controllers',
                                 CONTROLLER_KINDS)
        allocators = self.names(compare.get('allocators', ['robust']), 'compare.allocators')
        out = []
        for c, a, g in itertools.product(controllers, allocators, gains):
            for levels in itertools.product(*(levels for _, levels in factors)):
                names = [level for level, _ in levels]
                robot = tuple(item for _, keys in levels for item in keys)
                out.append(Configuration(
                    c, a, g, '-'.join([c, a] + ([g] if len(gains) > 1 else []) + names),
                    tuple(names), robot))
        return tuple(out)

    def hold(self, value: Any, configurations: tuple[Configuration, ...] | None
             ) -> tuple[Bound, ...]:
        """The bounds; their ``allocators`` and ``gains`` among the configurations' (any
        allocator mode and gain set name without configurations: a hold file)."""
        template = metrics_template()
        out = []
        for i, entry in enumerate(self.sequence(value if value is not None else [], 'hold')):
            where = f'hold[{i}]'
            if not isinstance(entry, Mapping):
                raise self.fail(where, f'expected a mapping, got {entry!r}')
            metric = entry.get('metric')
            shape = template.get(metric) if isinstance(metric, str) else None
            numeric = [k for k, v in template.items() if k not in ('run', 'hold')
                       and (isinstance(v, Mapping) or not isinstance(v, (str, bool)))]
            if metric not in numeric:
                raise self.fail(f'{where}.metric', f'got {metric!r}; allowed: the keys of '
                                                   f'metrics.json: {", ".join(numeric)}')
            select: dict[str, list[str] | None] = {
                'controllers': list(CONTROLLER_KINDS),
                'allocators': (list(ALLOCATOR_MODES) if configurations is None
                               else [c.allocator for c in configurations]),
                'gains': None if configurations is None else [c.gains for c in configurations]}
            keys = (set(shape) | ({'position', 'angle'} if set(shape) == set(DOF_NAMES)
                                  else set()) | {'max'}) if isinstance(shape, Mapping) \
                else {'max'}
            doc = self.mapping(entry, where, {'metric'} | set(select) | keys)
            limits = self.limits(doc, keys, shape, str(metric), where)
            chosen = {k: self.names(doc[k], f'{where}.{k}', None if v is None
                                    else sorted(set(v)))
                      if k in doc else () for k, v in select.items()}
            out.append(Bound(str(metric), limits, chosen['controllers'],
                             chosen['allocators'], chosen['gains']))
        return tuple(out)

    def limits(self, doc: Mapping[str, Any], keys: set[str], shape: Any, metric: str,
               where: str) -> tuple[tuple[str, float], ...]:
        limits: dict[str, float] = {}
        if not isinstance(shape, Mapping):
            if 'max' not in doc:
                raise self.fail(where, f'{metric} is a number: give its bound as max')
            return (('', self.number(doc['max'], f'{where}.max')),)
        angle = 1.0 if metric in TIME_METRICS else self.scale
        for group, members in (('max', tuple(shape)), ('position', DOF_NAMES[:3]),
                               ('angle', DOF_NAMES[3:])):
            if group in doc:
                value = self.number(doc[group], f'{where}.{group}')
                for key in members:
                    limits[key] = value * (angle if key in DOF_NAMES[3:] else 1.0)
        for key in shape:
            if key in doc:
                limits[key] = self.number(doc[key], f'{where}.{key}') * (
                    angle if key in DOF_NAMES[3:] else 1.0)
        if not limits:
            raise self.fail(where, f'no bound given; keys: {", ".join(sorted(keys))}')
        return tuple((k, limits[k]) for k in shape if k in limits)
