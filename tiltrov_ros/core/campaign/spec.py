"""What a campaign file says, validated: the dataclasses and the hold criterion.

See :mod:`tiltrov_ros.core.campaign` for the file and docs/campaign.md for
its format. Angles are in rad here, except in reference term templates,
which keep the file's unit (:attr:`CampaignSpec.angle_scale` converts).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from tiltrov_ros.core.errors import CampaignError
from tiltrov_ros.core.metrics import compute_metrics
from tiltrov_ros.core.runlog import CONTROL_FIELDS, PLANT_FIELDS, RunLog

#: Robot keys whose values are angles (tilt limits) or angular rates (the servo).
ROBOT_ANGLE_KEYS = frozenset({'tilt_min', 'tilt_max', 'tilt_rate_limit'})
#: Per-DOF metrics whose values are times (s), not errors: their bounds are not angles.
TIME_METRICS = frozenset({'settling_time'})


@dataclass(frozen=True)
class Distribution:
    """A number drawn per sample: ``constant`` (args: value), ``uniform`` (low, high),
    ``normal`` (mean, std) or ``choice`` (the values)."""

    kind: str
    args: tuple[float, ...]

    def draw(self, rng: np.random.Generator) -> float:
        """One value (a constant consumes nothing from ``rng``)."""
        if self.kind == 'constant':
            return self.args[0]
        if self.kind == 'uniform':
            return float(rng.uniform(self.args[0], self.args[1]))
        if self.kind == 'normal':
            return float(rng.normal(self.args[0], self.args[1]))
        return self.args[int(rng.integers(len(self.args)))]

    def values(self) -> tuple[float, ...] | None:
        """Every value it can take when that is a finite set (constant, choice)."""
        return self.args if self.kind in ('constant', 'choice') else None


@dataclass(frozen=True)
class TermTemplate:
    """A reference term (scenario term types) whose numbers are distributions,
    present in a sample with ``probability`` (None: always, nothing drawn for it)."""

    kind: str
    fields: tuple[tuple[str, Distribution], ...]
    probability: float | None = None


@dataclass(frozen=True)
class VectorDraw:
    """Three numbers: one distribution per axis, or a ``magnitude`` in a direction drawn
    uniformly on the sphere."""

    axes: tuple[Distribution, ...] = ()
    magnitude: Distribution | None = None


@dataclass(frozen=True)
class CurrentDraw:
    """The mean ocean current: horizontal ``speed`` (m/s) towards ``direction`` (rad from
    north towards east) and a ``down`` component (m/s); or per NED axis (``axes``)."""

    speed: Distribution | None = None
    direction: Distribution | None = None
    down: Distribution | None = None
    axes: VectorDraw | None = None


@dataclass(frozen=True)
class PulseDraw:
    """An external body wrench pulse, present in a sample with ``probability``."""

    probability: float
    start: Distribution
    duration: Distribution
    wrench: tuple[Distribution, ...]


@dataclass(frozen=True)
class FaultDraw:
    """A failed thruster (1..4), present in a sample with ``probability``."""

    probability: float
    thruster: Distribution
    at: Distribution
    detected_after: Distribution


RobotValue = float | tuple[float, ...]


@dataclass(frozen=True)
class Configuration:
    """One way of controlling (and building) the robot that every sample runs with.

    ``levels``: the level of each robot factor (``compare.robot``), in the file's
    order; ``robot``: the robot keys they set (SI units, rad), over the drawn ones.
    """

    controller: str
    allocator: str
    gains: str
    name: str           # e.g. 'pid-robust' (plus '-<gains>' with several gain sets,
    #                     '-<level>' per robot factor)
    levels: tuple[str, ...] = ()
    robot: tuple[tuple[str, RobotValue], ...] = ()


@dataclass(frozen=True)
class Bound:
    """``metric[key] <= limit`` for every (key, limit) (key '' for a scalar metric), on
    the runs of the configurations it names (empty: all)."""

    metric: str
    limits: tuple[tuple[str, float], ...]
    controllers: tuple[str, ...] = ()
    allocators: tuple[str, ...] = ()
    gains: tuple[str, ...] = ()

    def applies(self, config: Configuration) -> bool:
        return ((not self.controllers or config.controller in self.controllers)
                and (not self.allocators or config.allocator in self.allocators)
                and (not self.gains or config.gains in self.gains))

    def violations(self, metrics: Mapping[str, Any]) -> list[str]:
        out = []
        for key, limit in self.limits:
            value = metrics.get(self.metric)
            name = self.metric
            if key:
                value = value.get(key) if isinstance(value, Mapping) else None
                name = f'{self.metric}.{key}'
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                out.append(f'{name} is null')
            elif not value <= limit:
                out.append(f'{name} {value:.4g} > {limit:.4g}')
        return out


@dataclass(frozen=True)
class CampaignSpec:
    """A validated campaign file (:func:`~tiltrov_ros.core.campaign.load_campaign`)."""

    name: str
    description: str
    seed: int
    samples: int
    duration: float | None
    angle_scale: float                          # file's angle unit -> rad
    bases: tuple[tuple[str, Mapping[str, Any]], ...]   # (label, scenario document)
    reference: tuple[tuple[str, tuple[TermTemplate, ...]], ...]
    current: CurrentDraw | None
    current_std: VectorDraw | None
    current_time_constant: VectorDraw | None
    com_error: VectorDraw | None
    pulses: tuple[PulseDraw, ...]
    robot: tuple[tuple[str, Distribution | tuple[Distribution, ...]], ...]   # scalar | vector
    fault: FaultDraw | None
    configurations: tuple[Configuration, ...]
    gain_sets: tuple[tuple[str, Mapping[str, Any]], ...]
    hold: tuple[Bound, ...]
    source: str | None = None
    #: The robot factors (``compare.robot``): (factor, its level names), file order.
    factors: tuple[tuple[str, tuple[str, ...]], ...] = ()

    @property
    def angle_unit(self) -> str:
        return 'rad' if self.angle_scale == 1.0 else 'deg'

    def configuration(self, name: str) -> Configuration:
        for config in self.configurations:
            if config.name == name:
                return config
        raise CampaignError(f'{self.source or "campaign"}: no configuration {name!r}; '
                            f'known: {", ".join(c.name for c in self.configurations)}')

    def bounds(self, config: Configuration) -> tuple[Bound, ...]:
        """The ``hold`` bounds that apply to the runs of ``config``."""
        return tuple(bound for bound in self.hold if bound.applies(config))

    def violations(self, config: Configuration, metrics: Mapping[str, Any]) -> list[str]:
        """The ``hold`` bounds a run of ``config`` misses (empty: the run holds)."""
        return violations(self.bounds(config), metrics)


def violations(bounds: tuple[Bound, ...], metrics: Mapping[str, Any]) -> list[str]:
    """The bounds ``metrics`` misses, one line each (empty: the run holds)."""
    return [line for bound in bounds for line in bound.violations(metrics)]


#: A run's verdict (docs/campaign.md, "Verdicts"): it holds; it does not, and...
HELD = 'held'
SERVO_RANGE = 'servo_range'     # ...the same run with servos turning all the way round holds
PHYSICS = 'physics'             # ...no tilt on the full circle produces its steady wrench
CONTROL = 'control'             # ...neither: the controller's or the allocator's doing
VERDICTS = (HELD, SERVO_RANGE, PHYSICS, CONTROL)


def verdict(holds: bool, metrics: Mapping[str, Any] | None,
            counterfactual_holds: bool | None) -> str:
    """The verdict of a run: ``held``; else ``servo_range`` when its counterfactual (the
    same run, servos at +-180 deg; None: not run) holds; else ``physics`` when the
    steady-wrench oracle finds no tilt on the full circle that produces the steady
    wrench (``steady_shortfall_ratio_full_circle`` > 1); else ``control``."""
    if holds:
        return HELD
    if counterfactual_holds:
        return SERVO_RANGE
    ratio = (metrics or {}).get('steady_shortfall_ratio_full_circle')
    if isinstance(ratio, (int, float)) and ratio > 1.0:
        return PHYSICS
    return CONTROL


@cache
def metrics_template() -> Mapping[str, Any]:
    """The keys and nesting of ``metrics.json`` (values of a run without ticks): what a
    hold bound may name and what the campaign table's metric columns are."""
    empty: dict[str, Any] = {name: np.zeros((0, n) if n else 0) for name, n in
                             {**PLANT_FIELDS, **CONTROL_FIELDS}.items()}
    return compute_metrics(RunLog(**empty))
