"""Message definitions (``ros2msg`` schema text) and type hashes for the bag.

rosbag2 writes each channel's schema as the type's ``.msg`` text followed by
every type it depends on (``====`` separator, ``MSG: pkg/Type`` line), which
is what rosbags, the mcap ROS 2 decoder and Foxglove parse. This module gets
that text from rosbags' ROS 2 Jazzy type store; for a type the store does not
know (a custom package), it builds the text from the generated Python class's
field list (constants are not part of it; they do not affect the encoding).
"""

from __future__ import annotations

from functools import cache
import importlib
import re

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from ..core.errors import BagError
from .topics import normalize_type

SEPARATOR = '=' * 80

#: IDL names (as rosidl's Python classes report them) -> .msg names.
IDL_TO_MSG = {
    'double': 'float64', 'float': 'float32', 'long double': 'float64',
    'boolean': 'bool', 'octet': 'byte',
    'int8': 'int8', 'uint8': 'uint8', 'int16': 'int16', 'uint16': 'uint16',
    'int32': 'int32', 'uint32': 'uint32', 'int64': 'int64', 'uint64': 'uint64',
    'char': 'char', 'wchar': 'wchar', 'string': 'string', 'wstring': 'wstring',
}
_SEQUENCE = re.compile(r'^sequence<(?P<inner>.+?)(?:,\s*(?P<bound>\d+))?>$')
_ARRAY = re.compile(r'^(?P<inner>.+)\[(?P<size>\d+)\]$')


@cache
def typestore() -> Typestore:
    """The rosbags type store of ROS 2 Jazzy's message types (shared, read-only)."""
    return get_typestore(Stores.ROS2_JAZZY)


@cache
def message_definition(msgtype: str) -> tuple[str, str]:
    """``(ros2msg text, RIHS01 hash)`` of ``msgtype`` (``pkg/msg/Type``).

    For a type the store does not know, the text comes from the Python class
    and the hash from that text (RIHS01 covers field names and types only, so
    it equals the hash ROS computes).

    Raises:
        BagError: the type is neither in the type store nor importable.

    """
    msgtype = normalize_type(msgtype)
    store = typestore()
    if msgtype in store.fielddefs:
        text, _ = store.generate_msgdef(msgtype, ros_version=2)
        return text, store.hash_rihs01(msgtype)
    text = definition_from_python(msgtype)
    return text, hash_of_definition(msgtype, text)


def hash_of_definition(msgtype: str, text: str) -> str:
    """RIHS01 hash of ``msgtype`` from its ``ros2msg`` text (with dependencies)."""
    store = get_typestore(Stores.EMPTY)
    try:
        store.register(get_types_from_msg(text, normalize_type(msgtype)))
        return store.hash_rihs01(normalize_type(msgtype))
    except Exception as exc:  # rosbags raises several parser and key errors
        raise BagError(f'cannot parse the message definition of {msgtype!r}: {exc}') from exc


def message_class(msgtype: str) -> type:
    """The generated Python class of ``msgtype`` (``pkg/msg/Type`` or ``pkg/Type``)."""
    pkg, _, name = normalize_type(msgtype).split('/')
    try:
        return getattr(importlib.import_module(f'{pkg}.msg'), name)  # type: ignore[no-any-return]
    except (ImportError, AttributeError) as exc:
        raise BagError(f'no message definition for {msgtype!r}: not in the ROS 2 Jazzy '
                       f'type store and not importable ({exc})') from None


def _field_type(idl: str, deps: list[str]) -> str:
    """.msg spelling of one field type from rosidl's IDL spelling."""
    if match := _SEQUENCE.match(idl):
        inner = _field_type(match['inner'], deps)
        return f"{inner}[<={match['bound']}]" if match['bound'] else f'{inner}[]'
    if match := _ARRAY.match(idl):
        return f"{_field_type(match['inner'], deps)}[{match['size']}]"
    if idl.startswith(('string<=', 'wstring<=')):
        return idl
    if idl in IDL_TO_MSG:
        return IDL_TO_MSG[idl]
    if '/' in idl:  # nested message, 'pkg/Type'
        deps.append(idl)
        return idl
    raise BagError(f'unsupported field type {idl!r}')


def _fields_text(msgtype: str, deps: list[str]) -> str:
    cls = message_class(msgtype)
    fields = cls.get_fields_and_field_types()  # type: ignore[attr-defined]
    return ''.join(f'{_field_type(idl, deps)} {name}\n' for name, idl in fields.items())


def definition_from_python(msgtype: str) -> str:
    """rosbag2-style ``ros2msg`` text built from the Python class of ``msgtype``."""
    deps: list[str] = []
    parts = [_fields_text(msgtype, deps)]
    done = {normalize_type(msgtype)}
    while deps:
        dep = deps.pop(0)
        if normalize_type(dep) in done:
            continue
        done.add(normalize_type(dep))
        parts.append(f'{SEPARATOR}\nMSG: {dep}\n{_fields_text(dep, deps)}')
    return ''.join(parts)
