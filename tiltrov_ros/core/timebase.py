"""One time base for the headless runner, the ROS stack and the bag tools.

Simulated time is counted in integer nanoseconds (as ROS stamps are), and every
conversion goes through this module: to float seconds only by :func:`seconds`,
so the runner and the nodes evaluate references and controllers at
bit-identical times; between ns and a stamp's ``(sec, nanosec)`` only by
:func:`stamp_to_ns` and :func:`ns_to_stamp`; a serialized message's stamp
only by :func:`cdr_stamp_ns`.
"""

from __future__ import annotations

import struct

NS_PER_S = 1_000_000_000

#: Bytes of the CDR encapsulation header before a serialized message's fields.
CDR_ENCAPSULATION = 4
_STAMP_LE = struct.Struct('<iI')
_STAMP_BE = struct.Struct('>iI')


def seconds(ns: int) -> float:
    """Float seconds of an integer nanosecond time."""
    return ns / NS_PER_S


def to_ns(sec: float) -> int:
    """Integer nanoseconds of a float duration, rounded to the nearest ns."""
    return round(sec * NS_PER_S)


def stamp_to_ns(sec: int, nanosec: int) -> int:
    """Integer nanoseconds of a ROS stamp (``builtin_interfaces/Time`` fields)."""
    return int(sec) * NS_PER_S + int(nanosec)


def ns_to_stamp(ns: int) -> tuple[int, int]:
    """(sec, nanosec) of an integer nanosecond time, for a ROS stamp."""
    sec, nanosec = divmod(int(ns), NS_PER_S)
    return sec, nanosec


def cdr_stamp(data: bytes | memoryview) -> tuple[int, int]:
    """``(sec, nanosec)`` of the stamp at the start of a serialized message: the
    first field of a ``std_msgs/Header`` or a ``builtin_interfaces/Time``
    (``rosgraph_msgs/Clock``), as sent (not checked: ``sec`` may be negative).

    CDR: a 4-byte encapsulation (byte 1: 1 = little endian, 0 = big endian),
    then the stamp's ``int32 sec`` and ``uint32 nanosec``. Raises ValueError
    for bytes too short to hold one.
    """
    if len(data) < CDR_ENCAPSULATION + _STAMP_LE.size:
        raise ValueError(f'a serialized message of {len(data)} bytes has no stamp')
    layout = _STAMP_LE if data[1] == 1 else _STAMP_BE
    sec, nanosec = layout.unpack_from(data, CDR_ENCAPSULATION)
    return int(sec), int(nanosec)


def cdr_stamp_ns(data: bytes | memoryview) -> int:
    """The stamp (ns) at the start of a serialized message (:func:`cdr_stamp`)."""
    return stamp_to_ns(*cdr_stamp(data))


def format_ns(ns: int) -> str:
    """``12.345 s``: a time in ns as text, for logs and messages."""
    return f'{seconds(ns):.3f} s'
