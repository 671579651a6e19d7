"""Topic and type names as the bag tools meet them in the ROS graph and in bags.

The stack's own names are :mod:`tiltrov_ros.core.names`.
"""

from __future__ import annotations


def is_hidden(name: str) -> bool:
    """True for names with a token starting with ``_`` (ROS 2 hidden topics)."""
    return any(token.startswith('_') for token in name.split('/'))


def normalize_type(msgtype: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type``; ``pkg/msg/Type`` is kept."""
    parts = msgtype.split('/')
    if len(parts) == 2:
        return f'{parts[0]}/msg/{parts[1]}'
    return msgtype
