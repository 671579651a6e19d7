"""What a recording lost: the nodes' own message counts against the bag's.

Every stack node reports on ``/diagnostics`` how many messages it published
per topic (``published.<topic>``, its guarded publishers), and sends a final
report when it stops, after its readers acknowledged everything
(``nodes/executors.main_loop``). The recorder records ``/diagnostics`` too, so
a bag carries the evidence of its own completeness: a topic with fewer
messages than its publishers last reported lost the difference, and a node
whose final report (``final: true``) is not in the bag may have lost its last
messages unseen (the recorder was still behind when the node gave up waiting).
Both hold for a recording of the whole run (``tiltrov launch --record``: the
recorder starts first and stops last); of another bag only what the recorder
knows itself is said. The recorder adds that (``tiltrov.recorder`` custom data:
write errors, samples DDS reported lost). ``tiltrov bag info``, ``tiltrov
launch --record`` and ``tiltrov soak`` read it from here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import json
from pathlib import Path
from typing import Any

from ..core.names import (
    CLOCK,
    DIAGNOSTICS,
    FINAL_STATUS_KEY,
    JOINT_STATES,
    ODOM,
    SETPOINT,
    SETPOINT_VELOCITY,
    THRUST_CMD,
    TILT_CMD,
    WRENCH_ACHIEVED,
    WRENCH_CMD,
    join_namespace,
)
from .bagfile import bag_info, iter_raw
from .msgdefs import typestore

#: custom_data key of the recorder's own account (JSON object).
RECORDER_KEY = 'tiltrov.recorder'
#: run_info ``launcher`` of a recording of the whole run (stack/specs.run_info).
WHOLE_RUN_LAUNCHER = 'tiltrov launch'


def final_diagnostics(bag: str | Path) -> tuple[dict[str, dict[str, str]], list[dict[str, str]]]:
    """The last /diagnostics key values of each node in ``bag`` (by full node name),
    and every status in order (for series such as the plant's real-time factor)."""
    store = typestore()
    last: dict[str, dict[str, str]] = {}
    every: list[dict[str, str]] = []
    for raw in iter_raw(bag, [DIAGNOSTICS]):
        msg = store.deserialize_cdr(raw.data, raw.msgtype)
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            last[status.name] = values
            every.append({'_name': status.name, **values})
    return last, every


def resolve(node: str, topic: str) -> str:
    """The full name of ``topic`` as published by the node ``node`` (full name)."""
    if topic.startswith('/'):
        return topic
    namespace = node.rsplit('/', 1)[0]
    return f'{namespace}/{topic}'


def message_counts(bag: str | Path, diagnostics: Mapping[str, Mapping[str, str]]
                   ) -> dict[str, dict[str, int]]:
    """Per topic the nodes report: published (their last counts, summed) and recorded."""
    recorded = {name: t.count for name, t in bag_info(bag).topics.items()}
    published: dict[str, int] = {}
    for node, values in diagnostics.items():
        for key, value in values.items():
            if key.startswith('published.'):
                topic = resolve(node, key.removeprefix('published.'))
                published[topic] = published.get(topic, 0) + int(value)
    return {topic: {'published': n, 'recorded': recorded.get(topic, 0)}
            for topic, n in sorted(published.items())}


@dataclass
class Losses:
    """What a bag lost: per topic (published - recorded, where positive), and the
    recorder's own account (write errors, samples DDS reported lost)."""

    topics: dict[str, int] = field(default_factory=dict)
    recorder: dict[str, Any] = field(default_factory=dict)
    #: nodes whose final report is not in the bag (whole-run recordings)
    unfinished: list[str] = field(default_factory=list)
    #: the nodes' counts were compared (a recording of the whole run)
    whole_run: bool = False

    def __bool__(self) -> bool:
        return bool(self.topics) or bool(self.unfinished) or bool(
            self.recorder.get('write_errors')) or bool(self.recorder.get('lost_in_dds'))

    def lines(self) -> list[str]:
        """One line per finding (empty: nothing lost)."""
        out = [f'{topic}: {n} message(s) published but not recorded'
               for topic, n in self.topics.items()]
        out += [f'{node}: its final report is not in the bag: its last messages may be lost '
                '(the recorder was behind when it stopped)' for node in self.unfinished]
        if self.recorder.get('write_errors'):
            out.append(f'{self.recorder["write_errors"]} message(s) not written: '
                       f'{self.recorder.get("first_error", "")}')
        for topic, n in sorted((self.recorder.get('lost_in_dds') or {}).items()):
            out.append(f'{topic}: DDS reported {n} sample(s) lost')
        return out


def losses(bag: str | Path) -> Losses:
    """What ``bag`` lost (see the module docstring)."""
    info = bag_info(bag)
    try:
        recorder = json.loads(info.custom_data.get(RECORDER_KEY, '{}'))
    except json.JSONDecodeError:
        recorder = {}
    found = Losses(recorder=recorder if isinstance(recorder, dict) else {})
    if info.run_info.get('launcher') != WHOLE_RUN_LAUNCHER:
        return found
    found.whole_run = True
    last = final_diagnostics(bag)[0]
    counts = message_counts(bag, last)
    found.topics = {t: c['published'] - c['recorded'] for t, c in counts.items()
                    if c['published'] > c['recorded']}
    # The launcher names the nodes of the run; a node none of whose reports reached the
    # bag (the recorder stopped from the start) has no final report either.
    expected = info.run_info.get('nodes')
    reporting = {node for node, values in last.items()
                 if any(k.startswith('published.') for k in values)}
    if isinstance(expected, list):
        reporting |= {str(node) for node in expected}
    found.unfinished = sorted(node for node in reporting
                              if last.get(node, {}).get(FINAL_STATUS_KEY) != 'true')
    return found


#: The topics stamped at every plant step, and those stamped at every control tick.
STEP_TOPICS = (ODOM, JOINT_STATES, CLOCK)
TICK_TOPICS_RECORDED = (SETPOINT, SETPOINT_VELOCITY, WRENCH_CMD, THRUST_CMD, TILT_CMD,
                        WRENCH_ACHIEVED)


def missing_stamps(bag: str | Path, end_ns: int, step_ns: int, period_ns: int,
                   namespace: str = '') -> dict[str, int]:
    """Per topic of a lockstep run, how many stamps of its grid the bag lacks: every
    step from 0 to ``end_ns`` on the plant's state, every tick before ``end_ns`` on the
    control topics (a topic the bag does not have at all is skipped: e.g. no
    ``setpoint_velocity`` from a reference that does not publish it)."""
    from .cdr import leading_stamp_ns

    info = bag_info(bag)
    grids = {join_namespace(namespace, t): set(range(0, end_ns + 1, step_ns))
             for t in STEP_TOPICS}
    grids.update({join_namespace(namespace, t): set(range(0, end_ns, period_ns))
                  for t in TICK_TOPICS_RECORDED})
    grids = {t: g for t, g in grids.items() if t in info.topics}
    for raw in iter_raw(bag, set(grids)):
        stamp = leading_stamp_ns(raw.data, raw.msgtype)
        if stamp is not None:
            grids[raw.topic].discard(stamp)
    return {t: len(g) for t, g in sorted(grids.items()) if g}
