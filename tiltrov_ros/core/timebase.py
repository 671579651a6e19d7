"""One time base for the headless runner and the ROS stack.

Simulated time is counted in integer nanoseconds (as ROS stamps are), and every
conversion to float seconds goes through :func:`seconds`, so the runner and the
nodes evaluate references and controllers at bit-identical times.
"""

from __future__ import annotations

NS_PER_S = 1_000_000_000


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
