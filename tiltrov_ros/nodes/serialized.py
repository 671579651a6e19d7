"""A message the plant publishes at a high rate, serialized once and rewritten in place.

rclpy converts a message to its C form field by field at every ``publish``
(about 0.5 ms for the 17 markers of ``robot_markers``, 20 us for the five
transforms of ``/tf``). :class:`SerializedTemplate` serializes one template
instead, with a distinct sentinel in every number that changes and in every
stamp, finds the sentinels' byte offsets once, and makes each message by
writing the new numbers there (a microsecond or two); the publisher sends the
bytes as they are. rclpy leaves the CDR padding bytes as it finds them, so a
sentinel could also show up in padding: offsets are kept only when each
sentinel occurs once and a check message decodes to the one the fill function
makes (else other sentinels are tried).
"""

from __future__ import annotations

from collections.abc import Callable
import struct
from typing import Any

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message

#: ``fill(values, ns)``: a new message holding ``values`` (flat float array) stamped ``ns``.
Fill = Callable[[np.ndarray, int], Any]
#: The stamps (builtin_interfaces/Time) of a message, in a fixed order.
Stamps = Callable[[Any], list[Any]]


class SerializedTemplate:
    """``serialize(ns, values)``: the bytes of ``fill(values, ns)``, fast (module docstring).

    ``count`` numbers (float64) change from one message to the next, and every stamp
    ``stamps(msg)`` lists takes the message's time.
    """

    def __init__(self, msg_type: type, fill: Fill, stamps: Stamps, count: int) -> None:
        self.msg_type = msg_type
        self.count = count
        self._fill, self._stamps = fill, stamps
        for attempt in range(8):
            if self._build(attempt) and self._checks_out():
                return
        raise RuntimeError(f'{msg_type.__name__}: no unique offsets in the serialized template')

    def _build(self, attempt: int) -> bool:
        sentinels = (1 + 2 * attempt) * 1e6 + np.arange(self.count, dtype=float)
        sec, nanosec = 0x5A5A0000 + 0x100 * attempt, 0x3A3A0000 + 0x100 * attempt
        msg = self._fill(sentinels, 0)
        stamps = self._stamps(msg)
        for i, stamp in enumerate(stamps):
            stamp.sec, stamp.nanosec = sec + i, nanosec + i
        template = serialize_message(msg)
        n = len(stamps)
        found = [self._offsets(template, [struct.pack('<d', v) for v in sentinels]),
                 self._offsets(template, [struct.pack('<i', sec + i) for i in range(n)]),
                 self._offsets(template, [struct.pack('<I', nanosec + i) for i in range(n)])]
        if any(f is None for f in found):
            return False
        self._template = np.frombuffer(template, dtype=np.uint8).copy()
        self._doubles, self._secs, self._nanosecs = found
        self._stamp_count = n
        return True

    @staticmethod
    def _offsets(blob: bytes, patterns: list[bytes]) -> np.ndarray | None:
        """Byte indices of each pattern, as one flat array; None unless each occurs once."""
        out = []
        for pattern in patterns:
            at = blob.find(pattern)
            if at < 0 or blob.find(pattern, at + 1) >= 0:
                return None
            out.append(np.arange(at, at + len(pattern)))
        return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)

    def _checks_out(self) -> bool:
        values = np.linspace(-3.0, 3.0, self.count)
        ns = 1_234_567_890_123
        expected = serialize_message(self._fill(values, ns))
        return bool(deserialize_message(self.serialize(ns, values), self.msg_type)
                    == deserialize_message(expected, self.msg_type))

    def serialize(self, ns: int, values: np.ndarray) -> bytes:
        """The message of ``values`` (``count`` floats) stamped ``ns``, serialized."""
        buf = self._template.copy()
        buf[self._doubles] = np.asarray(values, dtype='<f8').view(np.uint8)
        sec, nanosec = divmod(ns, 1_000_000_000)
        n = self._stamp_count
        buf[self._secs] = np.full(n, sec, dtype='<i4').view(np.uint8)
        buf[self._nanosecs] = np.full(n, nanosec, dtype='<u4').view(np.uint8)
        return buf.tobytes()
