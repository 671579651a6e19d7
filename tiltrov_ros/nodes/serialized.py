"""Messages the nodes exchange at every step, without rclpy's conversions of every field.

rclpy converts a message to its C form field by field at every ``publish``
(about 0.5 ms for the 17 markers of ``robot_markers``, 20 us for the five
transforms of ``/tf``, 10 us for ``odom``), and ``deserialize_message`` builds
a new message object field by field for every sample received (5 us for a
``/clock`` sample, 16 us for a ``WrenchStamped``, 45 us for an ``Odometry``).
Both ways here go through the serialized bytes instead:

* :class:`SerializedTemplate` (out): one template serialized with a distinct
  sentinel in every number that changes and in every stamp; the sentinels' byte
  offsets are found once, and each message is made by writing the new numbers
  there (a microsecond or two); the publisher sends the bytes as they are.
  rclpy leaves the CDR padding bytes as it finds them, so a sentinel could also
  show up in padding: offsets are kept only when each sentinel occurs once and a
  check message decodes to the one the fill function makes (else other
  sentinels are tried). ``serialize_message`` may return more bytes than the
  message takes (Fast DDS gives the size it estimated: a ``JointState`` with an
  empty ``velocity`` and ``effort`` came 8 bytes long, which rosbags and the
  bag readers refuse); the template is cut to the message, padded to 4 bytes as
  a writer pads it.
* :class:`MessageReader` (in): the first message of a topic is deserialized
  and its layout walked (bag/cdr.py: where each number is, which bytes fix the
  layout: strings, sequence lengths); a later message of the same size with the
  same layout bytes (the same frame ids, joint names and lengths, as a
  publisher's messages are) has its numbers read at those offsets into the same
  message object (a few microseconds). Any other message is deserialized as
  rclpy does, and becomes the layout for the next ones.
"""

from __future__ import annotations

import array
from collections.abc import Callable, Sequence
import re
import struct
import sys
from typing import Any

import numpy as np
from rclpy.serialization import deserialize_message, serialize_message

from tiltrov_ros.bag.cdr import LayoutError, python_fields, walk
from tiltrov_ros.core.timebase import NS_PER_S

#: ``fill(values, ns)``: a new message holding ``values`` (flat float array) stamped ``ns``.
Fill = Callable[[np.ndarray, int], Any]
#: The stamps (builtin_interfaces/Time) of a message, in a fixed order.
Stamps = Callable[[Any], list[Any]]

_STAMP = struct.Struct('<iI')
_DOUBLE = 8


class SerializedTemplate:
    """``serialize(ns, values)``: the bytes of ``fill(values, ns)``, fast (module docstring).

    ``count`` numbers (float64) change from one message to the next, and every stamp
    ``stamps(msg)`` lists takes the message's time. :meth:`message` makes the message
    object of the same values (what the bytes decode to).
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
        template = _trimmed(serialize_message(msg), msg, self.msg_type)
        n = len(stamps)
        doubles = self._offsets(template, [struct.pack('<d', v) for v in sentinels])
        secs = self._offsets(template, [struct.pack('<i', sec + i) for i in range(n)])
        nanosecs = self._offsets(template, [struct.pack('<I', nanosec + i) for i in range(n)])
        if doubles is None or secs is None or nanosecs is None:
            return False
        if any(b != a + 4 for a, b in zip(secs, nanosecs)):
            return False        # a stamp is (sec, nanosec), in that order, side by side
        self._buffer = bytearray(template)
        self._runs = _runs(doubles)
        self._stamp_at = tuple(secs)
        return True

    @staticmethod
    def _offsets(blob: bytes, patterns: list[bytes]) -> list[int] | None:
        """The byte offset of each pattern; None unless each occurs once."""
        out = []
        for pattern in patterns:
            at = blob.find(pattern)
            if at < 0 or blob.find(pattern, at + 1) >= 0:
                return None
            out.append(at)
        return out

    def _checks_out(self) -> bool:
        values = np.linspace(-3.0, 3.0, self.count)
        ns = 1_234_567_890_123
        expected = serialize_message(self._fill(values, ns))
        return bool(deserialize_message(self.serialize(ns, values), self.msg_type)
                    == deserialize_message(expected, self.msg_type))

    def message(self, values: Sequence[float], ns: int) -> Any:
        """The message object of ``values`` stamped ``ns`` (what :meth:`serialize` gives
        the bytes of)."""
        return self._fill(np.asarray(values, dtype=float), ns)

    def serialize(self, ns: int, values: Sequence[float] | np.ndarray) -> bytes:
        """The message of ``values`` (``count`` floats) stamped ``ns``, serialized."""
        buf = self._buffer
        numbers = values.tolist() if isinstance(values, np.ndarray) else values
        for packer, offset, start, stop in self._runs:
            packer.pack_into(buf, offset, *numbers[start:stop])
        sec, nanosec = divmod(ns, NS_PER_S)
        for offset in self._stamp_at:
            _STAMP.pack_into(buf, offset, sec, nanosec)
        return bytes(buf)


def _trimmed(blob: bytes, msg: Any, msg_type: type) -> bytes:
    """``blob`` (``msg`` serialized) without the bytes past the message's end, padded
    with zeros to a multiple of 4 (the payload a writer sends)."""
    end = len(blob)
    while end > 4:
        try:
            if deserialize_message(blob[:end - 1], msg_type) != msg:
                break
        except Exception:       # rclpy's RMWError: cut before the message's end
            break
        end -= 1
    padded = -(-end // 4) * 4
    return blob[:end] + bytes(padded - end)


def _runs(offsets: list[int]) -> tuple[tuple[struct.Struct, int, int, int], ...]:
    """The values' offsets as runs of consecutive values at consecutive doubles:
    (packer, byte offset, first value, end value)."""
    runs: list[tuple[struct.Struct, int, int, int]] = []
    start = 0
    for i in range(1, len(offsets) + 1):
        if i == len(offsets) or offsets[i] != offsets[i - 1] + _DOUBLE:
            runs.append((struct.Struct(f'<{i - start}d'), offsets[start], start, i))
            start = i
    return tuple(runs)


# --------------------------------------------------------------------------- reading

#: numpy dtype (little endian) -> (struct code, array.array type code) of the numbers a
#: :class:`MessageReader` reads straight from the bytes; other types are deserialized.
_READABLE = {'<f8': ('d', 'd'), '<f4': ('f', 'f'), '<i4': ('i', 'i'), '<u4': ('I', 'I'),
             '<i8': ('q', 'q'), '<u8': ('Q', 'Q')}
_ELEMENT = re.compile(r'^(?P<field>.+)\[(?P<index>\d+)\]$')


def type_name(msg_type: type) -> str:
    """``pkg/msg/Type`` of a generated message class."""
    return f'{msg_type.__module__.split(".")[0]}/msg/{msg_type.__name__}'


class MessageReader:
    """Serialized messages of one type, decoded fast into one message object (see the
    module docstring).

    :meth:`read` returns that object refilled in place (or a new one, when the layout
    changed): a callback may keep the numbers it reads from it, not the object.
    """

    def __init__(self, msg_type: type) -> None:
        self.msg_type = msg_type
        self._name = type_name(msg_type)
        self._size = -1                     # no layout yet: every message deserialized
        self._layout_bytes: struct.Struct = struct.Struct('')
        self._key: tuple[bytes, ...] = ()
        self._msg: Any = None
        self._scalars: struct.Struct = struct.Struct('')
        self._first = 0
        self._targets: list[tuple[Any, str]] = []
        self._blocks: list[tuple[Any, str, int, int, Callable[[bytes], Any]]] = []

    def read(self, data: bytes) -> Any:
        """The message ``data`` holds. Raises as ``deserialize_message`` does for bytes
        that are not a message of the type (only such bytes go to it)."""
        if len(data) == self._size and self._layout_bytes.unpack_from(data) == self._key:
            for (obj, attr), value in zip(self._targets,
                                          self._scalars.unpack_from(data, self._first)):
                setattr(obj, attr, value)
            for obj, attr, start, stop, make in self._blocks:
                setattr(obj, attr, make(data[start:stop]))
            return self._msg
        msg = deserialize_message(data, self.msg_type)
        self._learn(data, msg)
        return msg

    def _learn(self, data: bytes, msg: Any) -> None:
        """Make ``msg`` (just decoded from ``data``) the object refilled for the messages of
        ``data``'s layout, if every number of it can be read straight."""
        self._size = -1
        try:
            layout = walk(data, self._name, python_fields)
        except LayoutError:
            return
        if sys.byteorder != 'little':   # the numbers are read as little-endian CDR
            return
        scalars: list[tuple[int, str, Any, str]] = []
        blocks: dict[tuple[int, str], list[tuple[int, str]]] = {}
        owners: dict[int, Any] = {}
        for path, (offset, dtype) in layout.leaves.items():
            if dtype not in _READABLE:
                return
            element = _ELEMENT.match(path)
            if element is None:
                owner, _, attr = path.rpartition('.')
                scalars.append((offset, dtype, _resolve(msg, owner), attr))
                continue
            owner, _, attr = element['field'].rpartition('.')
            obj = _resolve(msg, owner)
            owners[id(obj)] = obj
            blocks.setdefault((id(obj), attr), []).append((offset, dtype))
        fmt, end = ['<'], None
        for offset, dtype, _, _ in scalars:
            if end is not None:
                fmt.append(f'{offset - end}x')
            fmt.append(_READABLE[dtype][0])
            end = offset + int(dtype[2:])
        self._scalars = struct.Struct(''.join(fmt))
        self._first = scalars[0][0] if scalars else 0
        self._targets = [(obj, attr) for _, _, obj, attr in scalars]
        self._blocks = []
        for (owner_id, attr), items in blocks.items():
            block = _block(owners[owner_id], attr, items)
            if block is None:
                return
            self._blocks.append(block)
        pieces, end = ['<'], 0
        for start, stop in layout.structure:
            pieces.append(f'{start - end}x{stop - start}s')
            end = stop
        self._layout_bytes = struct.Struct(''.join(pieces))
        self._key = self._layout_bytes.unpack_from(data)
        self._msg = msg
        self._size = len(data)


def _resolve(msg: Any, path: str) -> Any:
    """The object at ``path`` (``pose.pose.position``, ``transforms[2].header.stamp``)
    in ``msg``."""
    obj = msg
    for part in path.split('.') if path else ():
        element = _ELEMENT.match(part)
        obj = (getattr(obj, element['field'])[int(element['index'])] if element
               else getattr(obj, part))
    return obj


def _block(obj: Any, attr: str, items: list[tuple[int, str]]
           ) -> tuple[Any, str, int, int, Callable[[bytes], Any]] | None:
    """How to refill the number array ``obj.attr`` from its bytes: (obj, attr, start,
    stop, make) with ``make(bytes)`` the new value, of the type the field holds (a
    numpy array for a fixed-size array, an ``array.array`` for a sequence); None if it
    is not one contiguous run of one type."""
    dtype = items[0][1]
    size = int(dtype[2:])
    start = items[0][0]
    if any(d != dtype or o != start + i * size for i, (o, d) in enumerate(items)):
        return None
    current = getattr(obj, attr)
    stop = start + size * len(items)
    if isinstance(current, np.ndarray):
        numpy_type = np.dtype(dtype)
        return obj, attr, start, stop, lambda raw: np.frombuffer(raw, dtype=numpy_type).copy()
    if isinstance(current, array.array):
        code = _READABLE[dtype][1]
        return obj, attr, start, stop, lambda raw: array.array(code, raw)
    return None
