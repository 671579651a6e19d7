"""What a recording lost: the nodes' own message counts against the bag's.

Every stack node reports on ``/diagnostics`` how many messages it published
per topic (``published.<topic>``, its guarded publishers), and sends a final
report when it stops, after its readers acknowledged everything
(``nodes/executors.main_loop``). The recorder records ``/diagnostics`` too, so
a bag carries the evidence of its own completeness: a topic with fewer
messages than its publishers last reported lost the difference. The recorder
adds what it knows itself (``tiltrov.recorder`` custom data: write errors,
samples DDS reported lost). ``tiltrov bag info``, ``tiltrov launch --record``
and ``tiltrov soak`` read it from here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import json
from pathlib import Path
from typing import Any

from ..core.names import DIAGNOSTICS
from .bagfile import bag_info, iter_raw
from .msgdefs import typestore

#: custom_data key of the recorder's own account (JSON object).
RECORDER_KEY = 'tiltrov.recorder'


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

    def __bool__(self) -> bool:
        return bool(self.topics) or bool(self.recorder.get('write_errors')) or bool(
            self.recorder.get('lost_in_dds'))

    def lines(self) -> list[str]:
        """One line per finding (empty: nothing lost)."""
        out = [f'{topic}: {n} message(s) published but not recorded'
               for topic, n in self.topics.items()]
        if self.recorder.get('write_errors'):
            out.append(f'{self.recorder["write_errors"]} message(s) not written: '
                       f'{self.recorder.get("first_error", "")}')
        for topic, n in sorted((self.recorder.get('lost_in_dds') or {}).items()):
            out.append(f'{topic}: DDS reported {n} sample(s) lost')
        return out


def losses(bag: str | Path) -> Losses:
    """What ``bag`` lost (see the module docstring)."""
    info = bag_info(bag)
    counts = message_counts(bag, final_diagnostics(bag)[0])
    try:
        recorder = json.loads(info.custom_data.get(RECORDER_KEY, '{}'))
    except json.JSONDecodeError:
        recorder = {}
    return Losses({t: c['published'] - c['recorded'] for t, c in counts.items()
                   if c['published'] > c['recorded']},
                  recorder if isinstance(recorder, dict) else {})
