"""The bag recorder's parameters (:data:`RECORDER_PARAMS`, validated into a
:class:`RecorderConfig`) and the command line that starts it as a process
(:func:`recorder_command`, used by the launcher and the tests)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import json
from typing import Any

from rclpy.node import Node

from tiltrov_ros.bag.bagfile import parse_run_info
from tiltrov_ros.bag.writer import COMPRESSIONS
from tiltrov_ros.core.errors import BagError, ParameterError
from tiltrov_ros.core.names import RECORDER
from tiltrov_ros.core.paramtable import Param, ParamTable

from .parameters import check, declare


@dataclass(frozen=True)
class RecorderConfig:
    """The recorder's parameters, validated."""

    output: str
    topics: tuple[str, ...]
    exclude_topics: tuple[str, ...]
    include_hidden: bool
    compression: str
    queue_depth: int
    discovery_period: float
    flush_period: float
    run_info: str


#: The recorder's parameters (read-only but run_info, which may be set while recording).
RECORDER_PARAMS = ParamTable('bag_recorder', [
    Param('output', 'str', '', 'bag directory to create (must not exist); empty: '
          'rosbag2_YYYY_MM_DD-HH_MM_SS in the working directory', read_only=True),
    Param('topics', 'strs', (), 'topics to record (relative names resolve in the node '
          'namespace); empty: every topic', read_only=True),
    Param('exclude_topics', 'strs', (), 'topics never recorded when recording every topic',
          read_only=True),
    Param('include_hidden', 'bool', False, 'when recording every topic, also record hidden '
          'topics (a name token starting with _)', read_only=True),
    Param('compression', 'str', 'none', 'MCAP chunk compression', choices=COMPRESSIONS,
          read_only=True),
    Param('queue_depth', 'int', 10000, 'history depth of each subscription; 0: KEEP_ALL',
          low=0, high=1_000_000, read_only=True),
    Param('discovery_period', 'float', 0.5, 'seconds (wall clock) between polls of the ROS '
          'graph for new topics', 's', low=0.05, high=60.0, read_only=True),
    Param('flush_period', 'float', 1.0, 'seconds (wall clock) between writes of the pending '
          'MCAP chunk to disk, which bounds what a killed recorder loses; 0: only when a chunk '
          'is full (1 MiB)', 's', low=0.0, high=3600.0, read_only=True),
    Param('run_info', 'str', '{}', 'JSON object describing the run (scenario, controller, '
          'robot limits, ...), stored in the bag metadata as custom_data "tiltrov.run_info"'),
])


def declare_parameters(node: Node) -> RecorderConfig:
    """Declare the recorder's parameters on ``node`` and return them validated.

    Raises:
        ParameterError: a value outside its allowed set (ranges are enforced
            by rclpy's descriptors at declaration).

    """
    v = check(RECORDER_PARAMS, declare(node, RECORDER_PARAMS))
    try:
        parse_run_info(v['run_info'])
    except BagError as exc:
        raise ParameterError('run_info', str(exc)) from None
    return RecorderConfig(
        output=v['output'], topics=v['topics'], exclude_topics=v['exclude_topics'],
        include_hidden=v['include_hidden'], compression=v['compression'],
        queue_depth=v['queue_depth'], discovery_period=v['discovery_period'],
        flush_period=v['flush_period'], run_info=v['run_info'])


def recorder_command(output: str, *, run_info: Mapping[str, Any] | None = None,
                     params: Mapping[str, Any] | None = None,
                     executable: str = RECORDER) -> list[str]:
    """argv that starts the recorder as a process (e.g. for the launcher).

    ``params`` values are passed as ``-p name:=value`` with YAML quoting, so
    strings (JSON included) stay strings.
    """
    values: dict[str, Any] = {'output': output, **(params or {})}
    if run_info is not None:
        values['run_info'] = json.dumps(dict(run_info), sort_keys=True)
    argv = [executable, '--ros-args']
    for name, value in values.items():
        argv += ['-p', f'{name}:={_yaml_value(value)}']
    return argv


def _yaml_value(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    raise TypeError(f'unsupported parameter value {value!r}')
