"""The parameter tables: what each line allows, says and checks, and the file reader."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.paramtable import SHIPPED, UNSET, Param, ParamTable, ros_parameters

TABLE = ParamTable('sample', [
    Param('rate', 'float', 1.0, 'a rate', 's', low=0.0, high=10.0, low_open=True),
    Param('count', 'int', 3, 'a count', low=0, high=100),
    Param('mode', 'str', 'fast', 'a mode', choices=('fast', 'slow', 'off')),
    Param('flag', 'bool', False, 'a flag', read_only=True),
    Param('gains', 'floats', SHIPPED, 'six gains', 'N/m', size=6, low=0.0),
    Param('ids', 'ints', [], 'some ids', low=1, high=4, distinct=True, note=' (or none)'),
    Param('names', 'strs', UNSET, 'some names'),
], prefix='group')


@pytest.mark.parametrize(('name', 'text'), [
    ('rate', 'a number in (0, 10]'),
    ('count', 'an integer in [0, 100]'),
    ('mode', 'fast, slow or off'),
    ('flag', 'true or false'),
    ('gains', '6 finite numbers >= 0'),
    ('ids', 'distinct integers in [1, 4] (or none)'),
    ('names', 'a list of strings'),
])
def test_allowed_text(name: str, text: str) -> None:
    assert TABLE[name].allowed() == text


def test_unbounded_and_half_bounded_numbers_say_so() -> None:
    assert Param('x', 'float', 0.0, 'x').allowed() == 'a finite number'
    assert Param('x', 'float', 0.0, 'x', high=5.0, high_open=True).allowed() == 'a number < 5'
    assert Param('x', 'floats', UNSET, 'x', size=3).allowed() == '3 finite numbers'


@pytest.mark.parametrize(('name', 'value', 'expected'), [
    ('rate', 2, 2.0), ('rate', 10.0, 10.0), ('count', 0, 0), ('mode', 'slow', 'slow'),
    ('flag', True, True), ('gains', np.arange(6.0), (0.0, 1.0, 2.0, 3.0, 4.0, 5.0)),
    ('ids', [4, 1], (4, 1)), ('ids', [], ()), ('names', ['a', 'b'], ('a', 'b')),
])
def test_valid_values_are_normalised(name: str, value: object, expected: object) -> None:
    assert TABLE.check(name, value) == expected


@pytest.mark.parametrize(('name', 'value'), [
    ('rate', 0.0), ('rate', 10.5), ('rate', math.nan), ('rate', math.inf), ('rate', True),
    ('rate', '1.0'), ('count', 1.0), ('count', 101), ('count', False), ('mode', 'medium'),
    ('flag', 1), ('gains', [1.0] * 5), ('gains', [1.0, -1.0, 1, 1, 1, 1]),
    ('gains', [math.nan] * 6), ('gains', 'abcdef'), ('gains', {'kp': 1}), ('ids', [5]),
    ('ids', [2, 2]), ('ids', [1.0]), ('ids', 3), ('names', [1, 2]),
])
def test_invalid_values_name_the_parameter_the_value_and_what_is_allowed(
        name: str, value: object) -> None:
    with pytest.raises(ParameterError) as info:
        TABLE.check(name, value, source='f.yaml')
    err = info.value
    assert err.name == f'group.{name}' and err.source == 'f.yaml'
    assert f'allowed: {TABLE[name].allowed()}' in str(err) and 'f.yaml' in str(err)


def test_complete_fills_defaults_and_refuses_unknown_and_missing() -> None:
    values = TABLE.complete({'gains': [1.0] * 6, 'count': 7}, defaults={'names': ()})
    assert values == {'rate': 1.0, 'count': 7, 'mode': 'fast', 'flag': False,
                      'gains': (1.0,) * 6, 'ids': [], 'names': ()}
    with pytest.raises(ParameterError, match=r"'group\.gains'.*missing; allowed: 6 fin") as info:
        TABLE.complete({'names': ['a']})
    assert info.value.name == 'group.gains'
    with pytest.raises(ParameterError, match='unknown; known: rate, count') as info:
        TABLE.complete({'gains': [1.0] * 6, 'names': [], 'rat': 1.0})
    assert info.value.name == 'group.rat'
    assert TABLE.complete({'gains': [0.0] * 6, 'names': [], 'other': 1},
                          unknown=True)['count'] == 3


def test_a_table_refuses_a_name_listed_twice() -> None:
    with pytest.raises(ValueError, match='twice'):
        ParamTable('t', [Param('a', 'int', 1, 'a'), Param('a', 'int', 2, 'a again')])


def test_markdown_has_one_row_per_parameter_with_its_allowed_text() -> None:
    text = TABLE.markdown({'gains': (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)})
    lines = text.splitlines()
    assert lines[0].startswith('| parameter | default |') and len(lines) == 2 + 7
    assert ('| `group.gains` | `[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]` | 6 finite numbers >= 0 | N/m'
            in text)
    assert '| `group.names` | unset |' in text and '| `group.flag` | `false` |' in text
    assert "| `group.mode` | `fast` | fast, slow or off | - | yes |" in text
    assert len(TABLE.markdown(header=False).splitlines()) == 7


def test_ros_parameters_reads_a_node_section_or_the_first_having_a_key(tmp_path: Path) -> None:
    path = tmp_path / 'p.yaml'
    path.write_text('/**:\n  ros__parameters:\n    control_period: 0.1\n'
                    'node_a:\n  ros__parameters:\n    x: 1\n')
    assert ros_parameters(path, node='node_a') == {'x': 1}
    assert ros_parameters(path, having='control_period') == {'control_period': 0.1}
    assert ros_parameters(path, node='node_b') is None
    assert ros_parameters(path, having='y') is None
    path.write_text('- a list\n')
    assert ros_parameters(path, having='x') is None
