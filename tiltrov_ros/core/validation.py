"""Checks of the data a node receives and sends: the one implementation of each.

Pure functions on plain values (no rclpy): the nodes take the fields out of a
message and call these. An input check raises :class:`InvalidInput` with a
short machine-readable ``reason`` (one of :data:`REASONS`, the key under which
``/diagnostics`` counts it) and a sentence for the log; the node rejects the
message (docs/reliability.md).

Stamps are integer nanoseconds. The bounds are relative to the receiving
node's clock (sim time when the node runs on ``/clock``, the plant's own sim
time for the plant): a stamp more than ``max_future`` ahead of it or more than
``max_age`` behind it is rejected; a bound of 0 is not checked, and neither is
any bound while the clock is unknown (``now_ns`` None: a node on sim time that
has not received ``/clock`` yet reads time 0, ROS's "not initialised").
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
import math

from tiltrov_ros.core.errors import TiltrovError
from tiltrov_ros.core.paramtable import Param, ParamTable
from tiltrov_ros.core.timebase import NS_PER_S, format_ns, stamp_to_ns, to_ns

NON_FINITE = 'non_finite'          # NaN or infinity in a value the node uses
WRONG_LENGTH = 'wrong_length'      # a JointState array neither empty nor one per name
UNKNOWN_JOINT = 'unknown_joint'    # a joint name the topic does not carry
MISSING_JOINT = 'missing_joint'    # a joint the topic must carry is absent
DUPLICATE_JOINT = 'duplicate_joint'
WRONG_FRAME = 'wrong_frame'        # header.frame_id (or child_frame_id) not the contract's
BAD_QUATERNION = 'bad_quaternion'  # norm not within QUATERNION_TOLERANCE of 1
BAD_STAMP = 'bad_stamp'            # negative time or nanosec >= 1e9
FUTURE_STAMP = 'future_stamp'      # more than max_future ahead of the node's clock
OLD_STAMP = 'old_stamp'            # more than max_age behind the node's clock
MALFORMED = 'malformed'            # bytes that do not decode as the topic's type (cut CDR)

#: Every rejection reason, as counted on /diagnostics.
REASONS = (NON_FINITE, WRONG_LENGTH, UNKNOWN_JOINT, MISSING_JOINT, DUPLICATE_JOINT,
           WRONG_FRAME, BAD_QUATERNION, BAD_STAMP, FUTURE_STAMP, OLD_STAMP, MALFORMED)
#: Reasons that concern the stamp itself: a node never answers with such a stamp.
STAMP_REASONS = (BAD_STAMP, FUTURE_STAMP, OLD_STAMP)

#: |norm(q) - 1| allowed for an attitude quaternion (the plant and the reference
#: publish unit quaternions to rounding; float32 tools to about 1e-7).
QUATERNION_TOLERANCE = 1e-3


class InvalidInput(TiltrovError, ValueError):
    """A received message that a node rejects.

    Attributes
    ----------
    reason : str
        One of :data:`REASONS`.
    detail : str
        What is wrong, for the log (the topic is added by the node).
    """

    def __init__(self, reason: str, detail: str) -> None:
        if reason not in REASONS:
            raise ValueError(f'unknown rejection reason {reason!r}')
        self.reason = reason
        self.detail = detail
        super().__init__(f'{reason}: {detail}')


@dataclass(frozen=True)
class StampBounds:
    """How far a stamp may lie from the node's clock, ns (0: not checked)."""

    max_future_ns: int = 0
    max_age_ns: int = 0

    @classmethod
    def from_seconds(cls, max_future: float, max_age: float) -> StampBounds:
        return cls(to_ns(max_future), to_ns(max_age))


def checked_stamp_ns(sec: int, nanosec: int) -> int:
    """Integer ns of a ``builtin_interfaces/Time``; :data:`BAD_STAMP` if malformed."""
    if sec < 0 or not 0 <= nanosec < NS_PER_S:
        raise InvalidInput(BAD_STAMP, f'stamp sec={sec} nanosec={nanosec} is not a time '
                                      '(sec >= 0, 0 <= nanosec < 1e9)')
    return stamp_to_ns(sec, nanosec)


def check_stamp(sec: int, nanosec: int, now_ns: int | None, bounds: StampBounds) -> int:
    """The stamp in ns, checked against the node's clock ``now_ns`` (None: unknown)."""
    ns = checked_stamp_ns(sec, nanosec)
    if now_ns is None:
        return ns
    if bounds.max_future_ns and ns - now_ns > bounds.max_future_ns:
        raise InvalidInput(FUTURE_STAMP, f'stamp {format_ns(ns)} is {format_ns(ns - now_ns)} '
                                         f'ahead of the node\'s clock ({format_ns(now_ns)}; '
                                         f'allowed: {format_ns(bounds.max_future_ns)}, '
                                         'stamp_max_future)')
    if bounds.max_age_ns and now_ns - ns > bounds.max_age_ns:
        raise InvalidInput(OLD_STAMP, f'stamp {format_ns(ns)} is {format_ns(now_ns - ns)} '
                                      f'behind the node\'s clock ({format_ns(now_ns)}; '
                                      f'allowed: {format_ns(bounds.max_age_ns)}, stamp_max_age)')
    return ns


def check_answerable(ns: int, state_ns: int, step_ns: int) -> None:
    """A command stamped ``ns`` must answer a state already published: the plant's,
    stamped ``state_ns`` at the latest. One plant step ``step_ns`` later is allowed (a
    watchdog's answer, stamped just after its node's clock); anything later is a
    command for a time that has not come, which would stand in for the real answers
    (rejected: ``future_stamp``, whatever ``stamp_max_future`` allows)."""
    if ns - state_ns > step_ns:
        raise InvalidInput(FUTURE_STAMP, f'stamp {format_ns(ns)} is after the latest state '
                                         f'({format_ns(state_ns)}): no state it can answer has '
                                         'been published')


def is_stale(stamp: int, now_ns: int | None, timeout_ns: int) -> bool:
    """True when data stamped ``stamp`` is older than ``timeout_ns`` on the clock ``now_ns``.

    A watchdog's test: never stale while the clock is unknown (None) or the
    timeout is 0 (off).
    """
    return now_ns is not None and timeout_ns > 0 and now_ns - stamp > timeout_ns


#: Characters of a string from a message shown in a log line or an error.
MAX_SHOWN = 64


def shown(text: str, limit: int = MAX_SHOWN) -> str:
    """``repr(text)``, cut to ``limit`` characters with the length said: strings from
    messages reach the logs only through this (a 1 MB frame_id must not)."""
    if len(text) <= limit:
        return repr(text)
    return f'{text[:limit]!r}... ({len(text)} characters)'


def check_frame(frame_id: str, expected: str, field: str = 'frame_id') -> None:
    if frame_id != expected:
        raise InvalidInput(WRONG_FRAME, f'{field} {shown(frame_id)}; expected {expected!r}')


def check_finite(values: Iterable[float], what: str) -> None:
    values = list(values)
    if not all(math.isfinite(v) for v in values):
        raise InvalidInput(NON_FINITE, f'{what} is not finite: {_short(values)}')


def check_quaternion(quaternion: Sequence[float], what: str = 'orientation') -> None:
    """Finite and of unit norm (within :data:`QUATERNION_TOLERANCE`)."""
    check_finite(quaternion, what)
    norm = math.sqrt(sum(v * v for v in quaternion))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise InvalidInput(BAD_QUATERNION, f'{what} has norm {norm:.6g}; a unit quaternion '
                                           'is expected')


def joint_values(names: Sequence[str], arrays: dict[str, Sequence[float]],
                 required: Sequence[str], field: str,
                 allowed: Sequence[str] | None = None) -> list[float]:
    """Values of ``field`` for the joints ``required``, in that order, from a JointState.

    ``arrays`` maps position/velocity/effort to the message's arrays. Each
    array must be empty or hold one value per name (the JointState contract);
    names must be unique, every required one present, and none outside
    ``allowed`` (default: exactly ``required``); the values used must be finite.
    """
    permitted = set(required if allowed is None else allowed)
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise InvalidInput(DUPLICATE_JOINT, f'joint {shown(name)} appears twice')
        seen.add(name)
        if name not in permitted:
            raise InvalidInput(UNKNOWN_JOINT, f'unknown joint {shown(name)}; allowed: '
                                              f'{", ".join(sorted(permitted))}')
    missing = [name for name in required if name not in seen]
    if missing:
        raise InvalidInput(MISSING_JOINT, f'no {", ".join(missing)}')
    for key, values in arrays.items():
        if len(values) not in (0, len(names)) or (key == field and len(values) != len(names)):
            raise InvalidInput(WRONG_LENGTH, f'{len(values)} {key} value(s) for {len(names)} '
                                             f'joint(s)')
    index = {name: i for i, name in enumerate(names)}
    values = arrays[field]
    out = [float(values[index[name]]) for name in required]
    check_finite(out, f'{field} of {", ".join(required)}')
    return out


#: Relative excess over a limit that :func:`limit_command` treats as rounding.
LIMIT_TOLERANCE = 1e-9


def limit_command(thrusts: Sequence[float], tilts: Sequence[float], max_thrust: float,
                  tilt_min: float, tilt_max: float
                  ) -> tuple[list[float], list[float]] | None:
    """The command within the thrust limit and tilt range, or None if it is not one.

    Values beyond a limit by rounding (:data:`LIMIT_TOLERANCE` of the limit) are
    clipped onto it; a non-finite value or a real excess gives None (the caller
    publishes its safe command instead).
    """
    span = max(abs(tilt_min), abs(tilt_max), 1.0) * LIMIT_TOLERANCE
    out_f: list[float] = []
    for f in thrusts:
        if not (math.isfinite(f) and abs(f) <= max_thrust * (1.0 + LIMIT_TOLERANCE)):
            return None
        out_f.append(min(max(float(f), -max_thrust), max_thrust))
    out_a: list[float] = []
    for a in tilts:
        if not (math.isfinite(a) and tilt_min - span <= a <= tilt_max + span):
            return None
        out_a.append(min(max(float(a), tilt_min), tilt_max))
    return out_f, out_a


#: ``failed_thrusters`` (plant and allocator nodes): the thrusters that give no thrust.
FAILED_THRUSTERS = ParamTable('failed thrusters', [
    Param('failed_thrusters', 'ints', [], 'thrusters that give no thrust, by number: '
          '1..4 = thruster_1..thruster_4 (e.g. [2])', low=1, high=4, distinct=True,
          note=' (thruster numbers; [] for none)'),
])


def failed_thruster_indices(value: object) -> tuple[int, ...]:
    """Core indices 0..3 of a ``failed_thrusters`` value (:data:`FAILED_THRUSTERS`):
    thruster numbers 1..4 (thruster_1..thruster_4), or empty. Raises ParameterError."""
    if value is None:
        return ()
    numbers = FAILED_THRUSTERS.check('failed_thrusters', value)
    return tuple(sorted(n - 1 for n in numbers))


#: N and N m: wrench components beyond this are clipped before allocation. Far
#: beyond anything four thrusters make (a few hundred N), and small enough that the
#: allocator's squares and products stay finite.
MAX_WRENCH = 1e6


def clip_wrench(wrench: Sequence[float], bound: float = MAX_WRENCH) -> tuple[list[float], bool]:
    """The finite ``wrench`` with each component clipped to +-``bound``, and whether
    anything was clipped (the allocator answers such a wrench as well as it can)."""
    out = [min(max(float(v), -bound), bound) for v in wrench]
    return out, any(a != b for a, b in zip(out, wrench))


def _short(values: Iterable[float]) -> str:
    items = [f'{v:.6g}' for v in values]
    return '[' + ', '.join(items[:8]) + (', ...' if len(items) > 8 else '') + ']'
