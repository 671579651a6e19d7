"""Reading fields straight from serialized (CDR) messages, without deserializing them.

ROS 2 messages travel as XCDR1 ("CDR"): a 4-byte encapsulation header (byte 1
is 0x01 for little endian, 0x00 for big endian), then the fields in order,
each aligned to its own size counted from the end of the encapsulation header.

* :func:`stamp_ns`: the header stamp of a message whose first field is a
  ``std_msgs/Header`` (or a ``builtin_interfaces/Time``, as ``/clock``): the
  first 8 bytes after the encapsulation, ``int32 sec`` and ``uint32 nanosec``.
"""

from __future__ import annotations

from functools import cache
import struct

from .msgdefs import typestore

ENCAPSULATION = 4
_LE = struct.Struct('<iI')
_BE = struct.Struct('>iI')
_STAMPED_FIRST = ('std_msgs/msg/Header', 'builtin_interfaces/msg/Time')


@cache
def has_leading_stamp(msgtype: str) -> bool:
    """True when ``msgtype``'s first field is a Header or a Time (so its CDR starts
    with the stamp); False for other types and types the type store does not know."""
    store = typestore()
    if msgtype in _STAMPED_FIRST:
        return True
    definition = store.fielddefs.get(msgtype)
    if definition is None or not definition[1]:
        return False
    _, (_, detail) = definition[1][0]
    return isinstance(detail, str) and detail in _STAMPED_FIRST


def stamp_ns(data: bytes | memoryview, msgtype: str) -> int | None:
    """The leading stamp of a serialized message, in ns (None: the type has none, or
    the bytes are too short)."""
    if not has_leading_stamp(msgtype) or len(data) < ENCAPSULATION + 8:
        return None
    layout = _LE if data[1] == 1 else _BE
    sec, nanosec = layout.unpack_from(data, ENCAPSULATION)
    return int(sec) * 1_000_000_000 + int(nanosec)
