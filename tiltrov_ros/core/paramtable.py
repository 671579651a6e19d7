"""Parameters declared once: a table of :class:`Param` lines per parameter set.

Each line gives a parameter's name, type, default, allowed range, unit,
description and whether it is read-only. From the table come

* the validation (:meth:`Param.check`, :meth:`ParamTable.complete`): what the
  core's ``from_mapping`` constructors and YAML loaders and the nodes run, with
  one message format, ``parameter 'name' (in file): got X; allowed: Y``;
* the ROS ``ParameterDescriptor`` of each parameter
  (:func:`tiltrov_ros.nodes.parameters.descriptor`: description, range,
  ``read_only``, the allowed text as ``additional_constraints``);
* the documentation (:meth:`ParamTable.markdown`, ``docs/parameters.md``).

So a new parameter is one line here. :func:`ros_parameters` is the one
reader of ROS 2 parameter files (``<node or /**>: ros__parameters: ...``).
Pure Python: no ROS.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
import math
from numbers import Integral, Real
from pathlib import Path
from typing import Any, Literal

from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.yamlfile import read_yaml

#: float, int, bool, str, and arrays of floats, ints or strs.
Kind = Literal['float', 'int', 'bool', 'str', 'floats', 'ints', 'strs']

_INF = math.inf


class _Marker:
    def __init__(self, name: str) -> None:
        self._name = name

    def __repr__(self) -> str:
        return self._name


#: Default of a parameter whose value comes from a shipped file (the robot, the
#: gains): the caller passes it (``defaults=``).
SHIPPED: Any = _Marker('SHIPPED')
#: Default of a parameter declared without a value (ROS: by type; value None).
UNSET: Any = _Marker('UNSET')

_ARRAY_ITEM = {'floats': 'float', 'ints': 'int', 'strs': 'str'}


def _is_number(x: object) -> bool:
    return isinstance(x, Real) and not isinstance(x, bool)


def _g(x: float) -> str:
    return f'{x:g}'


@dataclass(frozen=True)
class Param:
    """One parameter: its line in the table (see the module docstring).

    ``low``/``high`` bound numbers (each element of an array), open at
    ``low_open``/``high_open``; ``size`` is an array's length (0: any);
    ``choices`` the allowed strings; ``distinct`` forbids repeated elements;
    ``note`` is appended to the allowed text (what a range cannot say).
    """

    name: str
    kind: Kind
    default: Any
    description: str
    unit: str = ''
    low: float = -_INF
    high: float = _INF
    low_open: bool = False
    high_open: bool = False
    size: int = 0
    choices: tuple[str, ...] = ()
    distinct: bool = False
    read_only: bool = False
    note: str = ''

    @property
    def is_array(self) -> bool:
        return self.kind in _ARRAY_ITEM

    @property
    def bounded(self) -> bool:
        return self.low > -_INF or self.high < _INF

    def bounds_text(self) -> str:
        """`` in [0, 1]``, `` > 0``, ``<= 5``, or '' (no bounds)."""
        lo, hi = self.low, self.high
        if lo == -_INF and hi == _INF:
            return ''
        if hi == _INF:
            return f' {">" if self.low_open else ">="} {_g(lo)}'
        if lo == -_INF:
            return f' {"<" if self.high_open else "<="} {_g(hi)}'
        return (f' in {"(" if self.low_open else "["}{_g(lo)}, '
                f'{_g(hi)}{")" if self.high_open else "]"}')

    def allowed(self) -> str:
        """What the parameter accepts, as error messages and docs say it."""
        if self.choices:
            text = ' or '.join(', '.join(self.choices).rsplit(', ', 1))
        elif self.kind == 'float':
            text = ('a number' if self.bounded else 'a finite number') + self.bounds_text()
        elif self.kind == 'int':
            text = 'an integer' + self.bounds_text()
        elif self.kind == 'bool':
            text = 'true or false'
        elif self.kind == 'str':
            text = 'a string'
        elif self.kind == 'strs':
            text = 'a list of strings'
        else:
            what = 'finite numbers' if self.kind == 'floats' else 'integers'
            count = f'{self.size} ' if self.size else ''
            text = f'{count}{"distinct " if self.distinct else ""}{what}{self.bounds_text()}'
        return text + self.note

    def _in_bounds(self, x: float) -> bool:
        if not math.isfinite(x):
            return False
        low_ok = x > self.low if self.low_open else x >= self.low
        high_ok = x < self.high if self.high_open else x <= self.high
        return low_ok and high_ok

    def _item(self, kind: str, x: object) -> bool:
        if kind == 'bool' or isinstance(x, bool):
            return kind == 'bool' and isinstance(x, bool)
        if kind == 'float':
            return isinstance(x, Real) and self._in_bounds(float(x))
        if kind == 'int':
            return isinstance(x, Integral) and self._in_bounds(float(x))
        return isinstance(x, str) and (not self.choices or x in self.choices)

    def check(self, value: Any, *, prefix: str = '', source: str | None = None) -> Any:
        """``value`` normalised (float, int, bool, str, or a tuple of them) if allowed,
        else :class:`ParameterError` naming ``prefix.name``, the value and what is
        allowed."""
        if not self.is_array:
            if self._item(self.kind, value):
                return {'float': float, 'int': int}.get(self.kind, lambda v: v)(value)
            raise self.error(value, prefix=prefix, source=source)
        if isinstance(value, (str, bytes, Mapping)) or not hasattr(value, '__iter__'):
            raise self.error(value, prefix=prefix, source=source)
        items = list(value)
        item = _ARRAY_ITEM[self.kind]
        if ((self.size and len(items) != self.size)
                or not all(self._item(item, x) for x in items)
                or (self.distinct and len(set(items)) != len(items))):
            raise self.error(value, prefix=prefix, source=source)
        convert = {'float': float, 'int': int}.get(item, str)
        return tuple(convert(x) for x in items)

    def error(self, value: Any, *, prefix: str = '', source: str | None = None,
              message: str | None = None) -> ParameterError:
        """The ParameterError of ``value`` (``message`` replaces 'got ...; allowed: ...')."""
        shown = value.tolist() if hasattr(value, 'tolist') else value
        return ParameterError(f'{prefix}.{self.name}' if prefix else self.name,
                              message or f'got {shown!r}; allowed: {self.allowed()}',
                              source=source)


class ParamTable:
    """An ordered parameter set; ``prefix`` (``robot``, ``gains``) namespaces its names."""

    def __init__(self, title: str, params: Sequence[Param], *, prefix: str = '') -> None:
        self.title = title
        self.prefix = prefix
        self._params = {p.name: p for p in params}
        if len(self._params) != len(params):
            raise ValueError(f'{title}: a parameter is listed twice')

    def __iter__(self) -> Iterator[Param]:
        return iter(self._params.values())

    def __getitem__(self, name: str) -> Param:
        return self._params[name]

    def __contains__(self, name: object) -> bool:
        return name in self._params

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._params)

    def full_name(self, name: str) -> str:
        """The parameter's name in the ROS parameter tree (``robot.length``)."""
        return f'{self.prefix}.{name}' if self.prefix else name

    def check(self, name: str, value: Any, *, source: str | None = None) -> Any:
        return self._params[name].check(value, prefix=self.prefix, source=source)

    def complete(self, values: Mapping[str, Any], *, source: str | None = None,
                 defaults: Mapping[str, Any] | None = None, unknown: bool = False
                 ) -> dict[str, Any]:
        """Every parameter of the table, checked, from ``values`` (keys without the
        prefix). A parameter absent from ``values`` takes its ``defaults`` entry,
        else its table default (SHIPPED and UNSET ones are then missing: an
        error); keys the table does not have are an error unless ``unknown``."""
        if not unknown:
            for key in values:
                if key not in self._params:
                    raise ParameterError(self.full_name(str(key)),
                                         f'unknown; known: {", ".join(self._params)}',
                                         source=source)
        out: dict[str, Any] = {}
        for p in self:
            if p.name in values:
                out[p.name] = p.check(values[p.name], prefix=self.prefix, source=source)
            elif defaults is not None and p.name in defaults:
                out[p.name] = defaults[p.name]
            elif p.default is SHIPPED or p.default is UNSET:
                raise p.error(None, prefix=self.prefix, source=source,
                              message=f'missing; allowed: {p.allowed()}')
            else:
                out[p.name] = p.default
        return out

    def markdown(self, defaults: Mapping[str, Any] | None = None, *,
                 header: bool = True) -> str:
        """The table as Markdown rows (docs/parameters.md), with the header line unless
        ``header`` is false (rows of several tables in one); ``defaults`` fill SHIPPED
        ones."""
        lines = ['| parameter | default | allowed | unit | changeable | meaning |',
                 '|---|---|---|---|---|---|'] if header else []
        for p in self:
            default = (defaults or {}).get(p.name, p.default)
            lines.append(f'| `{self.full_name(p.name)}` | {_shown(default)} | '
                         f'{p.allowed().replace("|", "/")} | {p.unit or "-"} | '
                         f'{"no" if p.read_only else "yes"} | {p.description} |')
        return '\n'.join(lines)


def _shown(value: Any) -> str:
    if value is UNSET:
        return 'unset'
    if value is SHIPPED:
        return 'the shipped file\'s'
    if isinstance(value, bool):
        return f'`{str(value).lower()}`'
    if isinstance(value, str):
        return f"`'{value}'`" if not value else f'`{value}`'
    if isinstance(value, (list, tuple)):
        return '`[' + ', '.join(repr(v) if _is_number(v) else str(v) for v in value) + ']`'
    if _is_number(value):
        return f'`{value!r}`'
    return f'`{value}`'


def ros_parameters(path: str | Path, *, node: str | None = None,
                   having: str | None = None) -> dict[str, Any] | None:
    """The ``ros__parameters`` of a ROS 2 parameter file section: the section of
    ``node``, or the first section that has the key ``having``; None if none.

    Raises :class:`~tiltrov_ros.core.errors.UnreadableFileError` for a file that
    cannot be read as YAML.
    """
    document = read_yaml(path)
    if not isinstance(document, Mapping):
        return None
    sections = [document.get(node)] if node is not None else list(document.values())
    for section in sections:
        params = section.get('ros__parameters') if isinstance(section, Mapping) else None
        if isinstance(params, Mapping) and (having is None or having in params):
            return dict(params)
    return None
