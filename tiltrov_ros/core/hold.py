"""Whether a run held its setpoint, and if not, why: ``metrics.json``'s ``hold``.

A run *holds* when it meets every bound of a hold criterion that applies to it
(:class:`HoldCriterion`: bounds on ``metrics.json``, :mod:`.bounds`). A single
run (``tiltrov sim``, ``tiltrov analyze``) is judged by the shipped
station-keeping criterion (the ``hold`` of
``config/campaigns/station_keeping.yaml``: :func:`shipped`) or the one it is
given; a campaign's runs by the campaign's own. One that does not hold gets a
verdict, judged in this order (docs/campaign.md, "Verdicts"):

1. ``physics``: no configuration of the robot produces the wrench that holds the
   final setpoint against the mean current, with servos turning all the way
   round either (``steady_shortfall_ratio_full_circle`` > 1: :mod:`.steady`), or
   the wander oracle (:mod:`.wander`) finds that even servos turning all the way
   round cannot follow that demand while the current wanders as the scenario
   says: the thrusters cannot, whatever the servos' range;
2. ``servo_range``: the servos' range is to blame: no configuration within
   the range produces that wrench (``steady_shortfall_ratio`` > 1), or the
   wander oracle finds that no path of tilts within the range, at the servo
   rate, follows the demand while the current wanders, where servos turning
   all the way round would;
3. ``control``: everything else: the servos could, the controller and the
   allocator did not.

The verdict never looks at the counterfactual run of a campaign (the same run
with servos at +-180 deg, ``counterfactual_holds`` in runs.csv): that is
evidence, not the judgement.

:func:`judge` gives ``metrics.json``'s ``hold``: ``{criterion, holds, verdict,
reach, reach_full_circle}`` for a pd or pid run whose final setpoint stands
still and which has no thruster fault (``reach``: the wander oracle's answer
within the range, ``reach_full_circle`` with servos turning all the way round
when the range's was no; None where they were not needed), None for any other
run (``switching``, a trajectory, a failed thruster). :func:`verdict` is the
same judgement for any run (a campaign's table has a verdict for every run).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from numpy.typing import ArrayLike

from tiltrov_ros.core import wander
from tiltrov_ros.core.bounds import Bound, Selection, violations
from tiltrov_ros.core.steady import FULL_CIRCLE
from tiltrov_ros.paths import config_dir

#: A run's verdict: it holds; it does not, and...
HELD = 'held'
SERVO_RANGE = 'servo_range'     # ...the servo range cannot produce or follow the demand
PHYSICS = 'physics'             # ...no tilt on the full circle produces its steady wrench
CONTROL = 'control'             # ...the servos could: the controller's or the allocator's doing
#: The verdicts in the order tables list them.
VERDICTS = (HELD, SERVO_RANGE, PHYSICS, CONTROL)
#: The controllers whose runs get a ``hold`` (the switching baseline fixes its tilts).
JUDGED_CONTROLLERS = ('pd', 'pid')
#: The keys of ``hold`` and the type of each (for tables: runs.csv's ``hold.*`` columns).
HOLD_TEMPLATE: Mapping[str, Any] = {'criterion': '', 'holds': False, 'verdict': '',
                                    'reach': False, 'reach_full_circle': False}
#: The shipped criterion: the station-keeping campaign's ``hold``.
SHIPPED_FILE = ('campaigns', 'station_keeping.yaml')


@dataclass(frozen=True)
class HoldCriterion:
    """A named set of bounds (``name``: the campaign file's name)."""

    name: str
    bounds: tuple[Bound, ...]

    def applicable(self, controller: str, allocator: str, gains: str = '') -> tuple[Bound, ...]:
        """The bounds that apply to a run of this controller, allocator mode and gain set."""
        selection = Selection(controller, allocator, gains)
        return tuple(b for b in self.bounds if b.applies(selection))


@cache
def shipped() -> HoldCriterion:
    """The station-keeping campaign's criterion (config/campaigns/station_keeping.yaml)."""
    # The campaign parser checks bounds against the keys of metrics.json, which call
    # this module: imported here, when first asked.
    from tiltrov_ros.core.campaign.parse import load_hold
    return load_hold(Path(config_dir(), *SHIPPED_FILE))


def _ratio(metrics: Mapping[str, Any] | None, key: str) -> float | None:
    value = (metrics or {}).get(key)
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) \
        else None


def needs_reach(holds: bool, metrics: Mapping[str, Any] | None) -> bool:
    """Whether the verdict of this run needs the wander oracle: it does not hold, and
    the steady wrench is produced within the range (a known ratio, at most 1)."""
    if holds:
        return False
    full = _ratio(metrics, 'steady_shortfall_ratio_full_circle')
    inside = _ratio(metrics, 'steady_shortfall_ratio')
    return full is not None and full <= 1.0 and inside is not None and inside <= 1.0


@dataclass(frozen=True)
class Reach:
    """The wander oracle's answers for a run: within its servo range, and with servos
    turning all the way round (asked only when the range's answer is no; the same
    answer for a robot whose range is the full circle). None: not asked, or it could
    not be."""

    in_range: bool | None = None
    full_circle: bool | None = None


def verdict(holds: bool, metrics: Mapping[str, Any] | None, reach: Reach | None) -> str:
    """``held``, ``physics``, ``servo_range`` or ``control`` (module docstring).

    ``metrics``: the run's ``metrics.json`` (None: the run raised); ``reach``: the
    wander oracle's answers (None: not asked: no verdict from it)."""
    if holds:
        return HELD
    full = _ratio(metrics, 'steady_shortfall_ratio_full_circle')
    if (full is not None and full > 1.0) or (reach is not None and reach.full_circle is False):
        return PHYSICS
    inside = _ratio(metrics, 'steady_shortfall_ratio')
    if (inside is not None and inside > 1.0) or (reach is not None and reach.in_range is False):
        return SERVO_RANGE
    return CONTROL


def reach(meta: Mapping[str, Any], quaternion: ArrayLike) -> Reach:
    """The wander oracle for a run's final setpoint attitude (:func:`.wander.from_meta`):
    whether the servos can follow the demand's wander within their range, and if not,
    whether servos turning all the way round could."""
    inside = wander.from_meta(meta, quaternion)
    if inside is None:
        return Reach()
    if inside.followable:
        return Reach(True)
    robot = meta.get('robot')
    limits = ((robot.get('tilt_min'), robot.get('tilt_max'))
              if isinstance(robot, Mapping) else None)
    if limits == FULL_CIRCLE:
        return Reach(False, False)
    full = wander.from_meta(meta, quaternion, limits=FULL_CIRCLE)
    return Reach(False, None if full is None else full.followable)


def judged(meta: Mapping[str, Any], still: bool) -> bool:
    """Whether a run gets a ``hold``: a pd or pid run, its final setpoint still, no
    failed thruster (the meta's ``faults`` empty; unknown without it)."""
    faults = meta.get('faults')
    return (still and meta.get('controller') in JUDGED_CONTROLLERS
            and isinstance(faults, list) and not faults)


def judge(metrics: Mapping[str, Any], meta: Mapping[str, Any], quaternion: ArrayLike | None,
          criterion: HoldCriterion | None = None, bounds: tuple[Bound, ...] | None = None
          ) -> dict[str, Any] | None:
    """``metrics.json``'s ``hold`` (module docstring) of a run with these ``metrics`` (every
    key but ``hold``), its ``meta`` and its final setpoint attitude ``quaternion`` (None:
    the setpoint moves at the end), judged by ``criterion`` (default :func:`shipped`).
    ``bounds``: those of ``criterion`` that apply to the run, when the caller knows them
    (a campaign's configuration), else chosen by the meta's controller and allocator
    mode."""
    if quaternion is None or not judged(meta, True):
        return None
    if criterion is None:
        criterion = shipped()
    if bounds is None:
        bounds = criterion.applicable(str(meta.get('controller')),
                                      str(meta.get('allocator_mode')))
    holds = not violations(bounds, metrics)
    answer = reach(meta, quaternion) if needs_reach(holds, metrics) else Reach()
    return {'criterion': criterion.name, 'holds': holds,
            'verdict': verdict(holds, metrics, answer), 'reach': answer.in_range,
            'reach_full_circle': answer.full_circle}
